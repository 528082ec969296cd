"""Writes seed inputs for the `framer` fuzz target: valid telegrams at wire speed after start
pauses, in the target's input format (see fuzz_targets/framer.rs), so the fuzzer starts from
streams the framer accepts. Run from fuzz/: python3 seeds/make_framer_seeds.py"""

from functools import reduce
from pathlib import Path

STX = 0x02
PAUSE = 0x60  # op 0x60: a byte after 96/16 = 6 tz of silence
NEXT = 0x10  # op 0x10: a byte after 16/16 = 1 tz, back to back


def telegram(adr, net):
    body = bytes([STX, len(net) + 2, adr]) + bytes(net)
    return body + bytes([reduce(lambda a, b: a ^ b, body, 0)])


def steps(*telegrams):
    out = bytearray()
    for t in telegrams:
        out += bytes([PAUSE, t[0]])
        for b in t[1:]:
            out += bytes([NEXT, b])
    return bytes(out)


# Header: baud code (big endian; top bit clear = STANDARD[code % 13]), configuration byte.
AT_19200 = bytes([0x00, 6, 0x00])
AT_187500 = bytes([0x00, 12, 0x00])
READ_P2000 = telegram(4, [0x10, 0x00, 0x80, 0x00, 0, 0, 0, 0, 0x04, 0x7F, 0x19, 0x9A])
MM420_REPLY = telegram(0, [0x6B, 0x37, 0x19, 0x9A])
SEEDS = {
    "read_p2000": AT_19200 + steps(READ_P2000),
    "request_and_reply": AT_19200 + steps(READ_P2000, MM420_REPLY),
    "mirror_and_empty": AT_187500 + steps(telegram(0x45, []), telegram(31, [0x55] * 7)),
    "longest": AT_187500 + steps(telegram(0x9F, list(range(252)))),
}

for name, data in SEEDS.items():
    Path("seeds/framer", name).write_bytes(data)
