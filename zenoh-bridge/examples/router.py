"""A Zenoh router from the eclipse-zenoh package, for sites without `zenohd`: every uss-zenoh and
every client connects to it, so neither needs to reach the other directly.

    python3 router.py tls/0.0.0.0:7447 --cert router.pem --key router.key --ca ca.pem

With a certificate of the plant's CA (and that CA) it takes only peers that show one too (mutual
TLS); without, on a tcp/ endpoint, it takes anyone. It prints `router <its Zenoh id> listening on
<endpoint>` and routes until SIGTERM or Ctrl-C.
"""

import argparse
import json
import signal
import sys
import threading

import zenoh


def main(endpoint: str, cert=None, private_key=None, ca=None) -> int:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if cert:
        for setting, path in [
            ("listen_certificate", cert),
            ("listen_private_key", private_key),
            ("root_ca_certificate", ca),
        ]:
            conf.insert_json5(f"transport/link/tls/{setting}", json.dumps(path))
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    with zenoh.open(conf) as session:
        print(f"router {session.zid()} listening on {endpoint}", flush=True)
        done.wait()
    return 0


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("endpoint")
    parser.add_argument("--cert", help="the router's certificate (PEM), for mutual TLS")
    parser.add_argument("--key", dest="private_key", help="its private key (PEM)")
    parser.add_argument("--ca", help="the CA (PEM) every peer's certificate is signed by")
    a = parser.parse_args()
    if a.cert and not (a.private_key and a.ca):
        parser.error("--cert needs --key and --ca")
    sys.exit(main(a.endpoint, a.cert, a.private_key, a.ca))
