"""Read a drive's parameter through uss-zenoh from any host, with the eclipse-zenoh package.

    python3 read_param.py tcp/10.0.0.2:7447 uss/plant/line1/drive/1/param/P1082
    50.0 Hz (P1082 Max. frequency)

Against a bridge on mutual TLS, with this host's certificate and the plant's CA:

    python3 read_param.py tls/10.0.0.2:7447 uss/plant/line1/drive/1/param/P1082 \\
        --cert hmi.pem --key hmi.key --ca ca.pem

With a certificate the query goes out under its common name
(uss/plant/line1/as/<name>/drive/1/param/P1082), the name a bridge's access policy grants rights
to; --as NAME names it otherwise.
"""

import argparse
import json
import ssl
import sys

import zenoh


def common_name(cert: str):
    """The common name of the PEM certificate `cert`, or None if it cannot be read."""
    try:
        # The decoder Python's own ssl tests use: no package beyond the standard library.
        subject = ssl._ssl._test_decode_cert(cert)["subject"]
    except (AttributeError, OSError, ssl.SSLError, KeyError):
        return None
    return next((v for rdn in subject for (k, v) in rdn if k == "commonName"), None)


def named(key: str, name) -> str:
    """`key` under the sender's name: as/<name> before the last /drive/ (or after a bus's key)."""
    if not name:
        return key
    at = key.rfind("/drive/")
    return f"{key[:at]}/as/{name}{key[at:]}" if at >= 0 else f"{key}/as/{name}"


def main(endpoint: str, key: str, cert=None, private_key=None, ca=None, name=None) -> int:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if cert:
        for setting, path in [
            ("connect_certificate", cert),
            ("connect_private_key", private_key),
            ("root_ca_certificate", ca),
        ]:
            conf.insert_json5(f"transport/link/tls/{setting}", json.dumps(path))
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    if name is None and cert:
        name = common_name(cert)
    key = named(key, name)
    with zenoh.open(conf) as session:
        for reply in session.get(key, timeout=10.0):
            if reply.ok is None:
                # The bridge's words and the kind of failure (the error table's, as the C
                # status and the Python exception name it).
                said = reply.err.payload.to_string()
                try:
                    error = json.loads(said)
                    print(f"{error['error']} [{error['kind']}]", file=sys.stderr)
                except (ValueError, KeyError, TypeError):
                    print(said, file=sys.stderr)
                return 1
            p = json.loads(reply.ok.payload.to_string())
            print(f"{p['value']} {p['unit']} ({p['param']} {p['name']})")
            return 0
    print(f"{key}: no uss-zenoh answers this key", file=sys.stderr)
    return 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("endpoint")
    parser.add_argument("key")
    parser.add_argument("--cert", help="this host's certificate (PEM), for mutual TLS")
    parser.add_argument("--key", dest="private_key", help="its private key (PEM)")
    parser.add_argument("--ca", help="the CA (PEM) the bridge's certificate is signed by")
    parser.add_argument(
        "--as", dest="name", help="send under this name (default: the certificate's common name)"
    )
    a = parser.parse_args()
    if a.cert and not (a.private_key and a.ca):
        parser.error("--cert needs --key and --ca")
    sys.exit(main(a.endpoint, a.key, a.cert, a.private_key, a.ca, a.name))
