"""Read a drive's parameter through uss-zenoh from any host, with the eclipse-zenoh package.

    python3 read_param.py tcp/10.0.0.2:7447 uss/plant/line1/drive/1/param/P1082
    50.0 Hz (P1082 Max. frequency)
"""

import json
import sys

import zenoh


def main(endpoint: str, key: str) -> int:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        for reply in session.get(key, timeout=10.0):
            if reply.ok is None:
                print(reply.err.payload.to_string(), file=sys.stderr)
                return 1
            p = json.loads(reply.ok.payload.to_string())
            print(f"{p['value']} {p['unit']} ({p['param']} {p['name']})")
            return 0
    print(f"{key}: no uss-zenoh answers this key", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))
