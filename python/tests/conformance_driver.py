"""The Python front-end of the safety conformance suite (tests/tests/conformance.rs,
docs/SAFETY.md): a controller of ``uss_rt`` driven line by line from stdin, so the suite runs the
same scenario against every language with real processes and signals.

The same protocol as the C driver (capi/tests/c/conformance.c): a command per line (``open BUS
ADDRESS``, ``keepalive``, ``run HZ``, ``rearm [MS]``, ...; ``&`` first: on a thread of its own),
answered by ``<< ok`` or ``<< err KIND MESSAGE`` (``<&`` for a thread's), KIND being the
exception's class name in snake case (``Tripped`` -> ``tripped``).
"""

import re
import sys
import threading
import time

import uss_rt

# ZSW1 bits of the PROFIdrive states S1..S4 (USS.md section 7).
STATES = {
    1: lambda z: z & 0x40 != 0,
    2: lambda z: z & 0x47 == 0x01,
    3: lambda z: z & 0x47 == 0x03,
    4: lambda z: z & 0x47 == 0x07,
}

bus = None
drive = None
out = threading.Lock()


def answer(tag: str, error):
    with out:
        if error is None:
            print(f"{tag} ok", flush=True)
        else:
            # Words the client refuses are a ValueError in Python (the Rust client's
            # InvalidSample, C's INVALID_SAMPLE).
            name = "InvalidSample" if isinstance(error, ValueError) else type(error).__name__
            kind = re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()
            message = str(error).replace("\n", " ")
            print(f"{tag} err {kind} {message}", flush=True)


def call(words):
    cmd, args = words[0], words[1:]
    if cmd in ("keepalive", "enable", "stop", "coast", "quick_stop", "check", "release"):
        getattr(drive, cmd)()
    elif cmd == "rearm":
        # Asked for when the line arrives; ``rearm MS`` calls MS later (a program that re-arms
        # once it is set up): a stop meanwhile is not re-armed.
        asked = time.monotonic_ns()
        time.sleep(int(args[0]) / 1000.0 if args else 0)
        drive.rearm(asked)
    elif cmd == "run":
        drive.run_hz(float(args[0]))
    elif cmd == "acknowledge":
        drive.acknowledge(int(args[0]) / 1000.0)
    elif cmd == "set_words":
        drive.set_words([int(w, 0) for w in args])
    elif cmd == "wait_state":
        wanted = STATES[int(args[0])]
        drive.wait_for(lambda i: i["online"] and wanted(i["zsw1"]), int(args[1]) / 1000.0)
    else:
        sys.exit(f"conformance: unknown command {cmd}")


def run(tag: str, words):
    try:
        call(words)
        answer(tag, None)
    except (uss_rt.UssError, ValueError) as e:
        answer(tag, e)


def main():
    global bus, drive
    threads = []
    for line in sys.stdin:
        background = line.startswith("&")
        words = line.lstrip("&").split()
        if not words:
            continue
        if words[0] == "open":
            try:
                bus = uss_rt.open_bus(words[1])
                drive = uss_rt.control(bus, int(words[2]))
                answer("<<", None)
            except uss_rt.UssError as e:
                answer("<<", e)
        elif words[0] == "exit":
            break
        elif background:
            t = threading.Thread(target=run, args=("<&", words))
            t.start()
            threads.append(t)
        else:
            run("<<", words)
    for t in threads:
        t.join()
    if drive is not None:
        try:
            drive.release()  # hands the drive back
        except uss_rt.UssError:
            pass


if __name__ == "__main__":
    main()
