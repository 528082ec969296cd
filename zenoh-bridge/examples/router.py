"""A Zenoh router from the eclipse-zenoh package, for sites without `zenohd`: every uss-zenoh and
every client connects to it, so neither needs to reach the other directly.

    python3 router.py tcp/0.0.0.0:7447

It prints `router <its Zenoh id> listening on <endpoint>` and routes until SIGTERM or Ctrl-C.
"""

import json
import signal
import sys
import threading

import zenoh


def main(endpoint: str) -> int:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    with zenoh.open(conf) as session:
        print(f"router {session.zid()} listening on {endpoint}", flush=True)
        done.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
