"""Parameters the way a drives engineer writes them, and exclusive control of a drive.

- :func:`read` / :func:`write`: a parameter in the manuals' notation (``P1082``, ``p1082``,
  ``r0021``, ``1082``, ``P0947[3]``, ``r0947.3``) as its own type and unit (``P1082 = 50.00 Hz``);
  a write converts the value to the parameter's type and refuses what does not fit before the
  bus. What a parameter is comes from the catalogue (the same ``micromaster4.toml`` as the Rust
  crate ``uss-catalogue``).
- :func:`control`: the drive's one controller: ``enable``, ``run_hz``, ``stop``, ``coast``,
  ``quick_stop``, ``acknowledge``, ``release``; a thread refreshes the watchdog.
"""

import math
import os
import re
import struct
import threading
import time
from pathlib import Path

try:
    import tomllib
except ImportError:  # Python < 3.11
    import tomli as tomllib

import uss_rt as _u

CATALOGUE_FILE = Path(__file__).with_name("micromaster4.toml")

_RANGES = {
    "U16": (0, 0xFFFF),
    "I16": (-0x8000, 0x7FFF),
    "U32": (0, 0xFFFF_FFFF),
    "I32": (-0x8000_0000, 0x7FFF_FFFF),
}


def _load_catalogue():
    with CATALOGUE_FILE.open("rb") as f:
        data = tomllib.load(f)
    return {parse_param(p["id"])[0]: p for p in data["param"]}, data


def parse_param(text: str):
    """``(pnu, index, prefix)`` of a parameter as the manuals write it: ``P1082``, ``p1082``,
    ``r0021``, ``1082``, ``P0947[3]``, ``r0947.3``. Raises :class:`ValueError` otherwise."""
    m = re.fullmatch(r"([PpRr]?)(\d{1,6})(?:\[(\d{1,3})\]|\.(\d{1,3}))?", text.strip())
    if m is None:
        raise ValueError(
            f"{text!r}: write a parameter as P1082, p1082, r0021 or 1082, an element as "
            "P0947[3] or r0947.3"
        )
    pnu = int(m.group(2))
    if pnu > 0xFFFF:
        raise ValueError(f"{text!r}: parameter numbers are 0..=65535")
    index = m.group(3) or m.group(4)
    index = None if index is None else int(index)
    if index is not None and index > _u.MAX_SUBINDEX:
        raise ValueError(f"{text!r}: array indices are 0..=254")
    prefix = {"": "P", "R": "r"}.get(m.group(1), m.group(1))
    return pnu, index, prefix


_CATALOGUE, _DATA = _load_catalogue()
FAMILY = _DATA["family"]


def describe(pnu: int):
    """The catalogue's entry of parameter ``pnu`` (a dict: id, name, type, unit, ...) or None."""
    return _CATALOGUE.get(pnu)


def fault_text(number: int):
    """The text of fault ``number`` (F0072 -> 72), or None."""
    return next((f["text"] for f in _DATA["fault"] if f["number"] == number), None)


def warning_text(number: int):
    """The text of warning ``number`` (A0501 -> 501), or None."""
    return next((w["text"] for w in _DATA["warning"] if w["number"] == number), None)


class Value:
    """A parameter value in its own type: ``value`` (float or int), ``raw`` (the word or
    double word), ``unit`` and ``name`` from the catalogue. ``repr`` is ``P1082 = 50.00 Hz``."""

    def __init__(self, param: str, raw: int, data_type: str, info):
        self.param, self.raw, self.data_type, self.info = param, raw, data_type, info
        if data_type == "Float":
            self.value = struct.unpack("<f", struct.pack("<I", raw))[0]
        elif data_type in ("I16", "I32"):
            bits = 16 if data_type == "I16" else 32
            self.value = raw - (1 << bits) if raw >> (bits - 1) else raw
        else:
            self.value = raw
        self.unit = (info or {}).get("unit", "")
        self.name = (info or {}).get("name")

    def shown(self) -> str:
        """``50.00 Hz``, ``5``, ``0xFB31`` (a status or control word)."""
        if (self.info or {}).get("bits"):
            text = f"{self.raw:#06X}".replace("0X", "0x")
        elif self.data_type == "Float":
            text = f"{self.value:.2f}"
        else:
            text = str(self.value)
        return f"{text} {self.unit}" if self.unit else text

    def __float__(self):
        return float(self.value)

    def __int__(self):
        return int(self.value)

    def __eq__(self, other):
        if isinstance(other, Value):
            return (self.param, self.raw) == (other.param, other.raw)
        return self.value == other

    def __repr__(self):
        return f"{self.param} = {self.shown()}"


def _shown_name(pnu: int, index, info, prefix: str) -> str:
    letter = info["id"][0] if info else prefix
    name = f"{letter}{pnu:04}"
    return name if index is None else f"{name}[{index}]"


def _type_of(bus, address: int, pnu: int, info, timeout: float) -> str:
    """The parameter's data type: the catalogue's, or the drive's own description (AK 4,
    element 1), asked once per bus, drive and parameter."""
    if info:
        return info["type"]
    cache = bus._services.setdefault("described", {})
    key = (address, pnu)
    if key not in cache:
        code = int(_u._request(bus, address, [_u._item(_u.TaskCode.READ_DESCRIPTION, pnu, 1)], timeout)[0])
        names = {3: "I16", 4: "I32", 6: "U16", 7: "U32", 8: "Float"}
        if code not in names:
            raise _u.UssError(f"drive {address} describes P{pnu:04} with data type {code}, which uss_rt does not read")
        cache[key] = names[code]
    return cache[key]


def read(bus, address: int, param: str, timeout: float = 7.5) -> Value:
    """Reads ``param`` (the manuals' notation) of drive ``address`` as its own type."""
    pnu, index, prefix = parse_param(param)
    info = describe(pnu)
    data_type = _type_of(bus, address, pnu, info, timeout)
    raw = _u.read_param(bus, address, pnu, index, timeout)
    return Value(_shown_name(pnu, index, info, prefix), int(raw), data_type, info)


def encode(data_type: str, value) -> tuple:
    """``(raw, is_dword)`` of ``value`` (a number, or text such as ``"45"``, ``"0x1F"``) in
    ``data_type``; raises :class:`ValueError` when it does not fit."""
    if isinstance(value, str):
        text = value.strip()
        if data_type == "Float":
            value = float(text)
        elif text.lower().startswith("0x"):
            value = int(text, 16)
        else:
            try:
                value = int(text)
            except ValueError:
                raise ValueError(f"{text} is not a whole number, and {data_type} holds only whole numbers") from None
    if data_type == "Float":
        f = float(value)
        if not math.isfinite(f) or abs(f) > 3.4028234663852886e38:
            raise ValueError(f"{value} does not fit float (a finite single-precision number)")
        return struct.unpack("<I", struct.pack("<f", f))[0], True
    if isinstance(value, float):
        if not value.is_integer():
            raise ValueError(f"{value} is not a whole number, and {data_type} holds only whole numbers")
        value = int(value)
    low, high = _RANGES[data_type]
    if not low <= value <= high:
        raise ValueError(f"{value} does not fit {data_type} ({low}..={high})")
    bits = 16 if data_type in ("U16", "I16") else 32
    return value & ((1 << bits) - 1), bits == 32


def write(bus, address: int, param: str, value, eeprom: bool = False, force: bool = False, timeout: float = 7.5) -> Value:
    """Writes ``value`` (a number or text) to ``param`` of drive ``address``, converted to the
    parameter's type (45 is 45.0 for a float parameter); what does not fit, or a read-only
    parameter, raises :class:`ValueError` before the bus. Returns the value the drive now holds.
    ``force`` writes while another process controls the drive (a deliberate act)."""
    pnu, index, prefix = parse_param(param)
    info = describe(pnu)
    name = _shown_name(pnu, index, info, prefix)
    if info and info["change"] == "read-only":
        raise ValueError(f"{name}: read-only: a monitoring (r) parameter cannot be written")
    data_type = _type_of(bus, address, pnu, info, timeout)
    try:
        raw, dword = encode(data_type, value)
    except ValueError as e:
        raise ValueError(f"{name}: {e}") from None
    task = {
        (False, False): _u.TaskCode.WRITE_WORD,
        (False, True): _u.TaskCode.WRITE_DWORD,
        (True, False): _u.TaskCode.WRITE_ARRAY_WORD,
        (True, True): _u.TaskCode.WRITE_ARRAY_DWORD,
    }[(index is not None, dword)]
    item = _u._item(task, pnu, index or 0, raw, _u.Storage.RAM_AND_EEPROM if eeprom else _u.Storage.RAM)
    held = _u._request(bus, address, [item], timeout, force)[0]
    return Value(name, int(held), data_type, info)


# -------------------------------------------------------------------------------------------
# Exclusive control
# -------------------------------------------------------------------------------------------

STW1_OFF1 = 0x047E
STW1_RUN = 0x047F
STW1_OFF2 = 0x047C
STW1_OFF3 = 0x047A
STW1_ACK = 0x0080
REFRESH = 0.02
"""How often the refresher publishes: well inside the default 100 ms watchdog."""


class Controlled(_u.UssError):
    """The drive already has a controller (another process, or another controller here)."""

    def __init__(self, bus: str, address: int):
        super().__init__(
            f"drive {address} on {bus} is controlled by another process: stop that controller "
            "first, or stop the drive with stop_drive (an operator's stop works whoever controls it)"
        )


class Tripped(_u.UssError):
    """ussd latched the drive (stale controller, rejected sample, operator stop, restart):
    it gets its safe command until :meth:`Controller.rearm`."""

    def __init__(self, address: int, image: dict):
        self.reason = image["latch_reason"]
        self.command = image["latch_command"]
        super().__init__(
            f"drive {address} is latched ({_u._name(self.reason)}): it gets "
            f"{_u._name(self.command)}; re-arm it with rearm() (OFF1, then ON)"
        )


class Controller:
    """The one controller of a drive: publishes its control word and setpoint, refreshed
    every 20 ms by a thread (the watchdog), until :meth:`release`. Every call first checks the
    drive's latch: a trip since the last call raises :class:`Tripped`."""

    def __init__(self, bus, address: int):
        _u._check_address(address)
        services, _ = bus._current()
        self.bus, self.address = bus, address
        diag = services["diag"].reader_builder().create().entry(_u.BlackboardKey(address), _u.DriveDiag)
        self._diag = diag
        info = diag.get().decode_as(_u.DriveDiag).info
        self.words_count = info.pzd_words
        if self.words_count == 0:
            raise _u.UssError(f"drive {address} on {bus.name} exchanges no process data (PZD length 0)")
        service = _u._open(
            bus.node,
            bus.name,
            _u.drive_out_service(bus.name, bus._generation, address),
            lambda b: b.publish_subscribe(_u.PzdOutput),
            lambda: _u.UnknownDrive(bus.name, address, bus.drives()),
        )
        try:
            publisher = service.publisher_builder().create()
        except Exception as e:
            raise Controlled(bus.name, address) from e
        self._service, self._publisher = service, publisher
        self._words = [STW1_OFF1] + [0] * (self.words_count - 1)
        self._sequence = time.clock_gettime_ns(time.CLOCK_MONOTONIC)
        self._lock = threading.Lock()
        self._known_latch = self._latch_id(_u.read_input(bus, address))
        self._released = False
        self._stop = threading.Event()
        self._publish()
        self._thread = threading.Thread(target=self._refresh, daemon=True)
        self._thread.start()

    @staticmethod
    def _latch_id(image: dict):
        latched = image["control"] == _u.ControlState.LATCHED
        return image["latch_id"] if latched else None

    def _publish(self, flags: int = 0):
        with self._lock:
            self._sequence += 1
            out = _u.PzdOutput(
                version=_u.LAYOUT_VERSION,
                controller_pid=os.getpid(),
                sequence=self._sequence,
                timestamp_ns=time.clock_gettime_ns(time.CLOCK_MONOTONIC),
                word_count=0 if flags else self.words_count,
                flags=flags,
                # The latch this controller acknowledged: ussd re-arms only by a stop naming it.
                latch_id=self._known_latch or 0,
            )
            if not flags:
                out.stw1, out.setpoint = self._words[0], self._words[1] if self.words_count > 1 else 0
                for i, w in enumerate(self._words[2:]):
                    out.extra[i] = w
            self._publisher.send_copy(out)

    def _news(self, image: dict) -> bool:
        """Whether ``image`` shows a latch this controller has not acknowledged."""
        latch = self._latch_id(image)
        return latch is not None and latch != self._known_latch

    def _refresh(self):
        # While the drive shows a latch this controller has not acknowledged (an operator's
        # stop, a trip), the refresher publishes nothing: a republished stop word would re-arm
        # the latch behind the controller's back. The next call raises Tripped; rearm() goes on.
        while not self._stop.wait(REFRESH):
            if not self._news(self.inputs()):
                self._publish()

    def inputs(self) -> dict:
        """The drive's input image (:func:`uss_rt.read_input`)."""
        return _u.read_input(self.bus, self.address)

    def _check(self):
        image = self.inputs()
        if self._news(image):
            raise Tripped(self.address, image)
        return image

    def _command(self, stw1: int, setpoint=None):
        if self._released:
            raise _u.UssError(f"drive {self.address}: this controller has released the drive")
        self._check()
        with self._lock:
            self._words[0] = stw1
            if setpoint is not None and self.words_count > 1:
                self._words[1] = setpoint & 0xFFFF
        self._publish()

    def wait_for(self, predicate, timeout: float = 3.0, what: str = "the drive") -> dict:
        """Waits until ``predicate(image)`` holds; the refresher keeps the watchdog fed."""
        deadline = time.monotonic() + timeout
        while True:
            image = self._check()
            if predicate(image):
                return image
            if time.monotonic() >= deadline:
                raise _u.UssError(f"drive {self.address}: {what} not reached within {timeout} s")
            time.sleep(2e-3)

    def enable(self):
        """OFF1 (STW1 0x047E): arms the drive; S1 -> S2 (a latched drive needs :meth:`rearm`)."""
        self._command(STW1_OFF1)

    def rearm(self) -> dict:
        """OFF1 after a trip, then waits until ussd passes this controller's words again."""
        with self._lock:
            # Acknowledges the latch the image shows, so the refresher repeats the OFF1 until
            # ussd takes it; a later latch is news again.
            self._known_latch = self._latch_id(self.inputs())
            self._words[0] = STW1_OFF1
        self._publish()
        image = None
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            image = self.inputs()
            if image["control"] == _u.ControlState.LIVE:
                self._known_latch = None
                return image
            time.sleep(2e-3)
        raise _u.UssError(f"drive {self.address} is still latched after OFF1: {image}")

    @property
    def reference_hz(self) -> float:
        """The reference frequency P2000 ussd publishes now (0x4000 = 100 %): the drive's own
        value once ussd has read it, until then the configuration's ``reference_hz``."""
        return self._diag.get().decode_as(_u.DriveDiag).info.reference_hz

    def run_hz(self, hz: float):
        """ON (STW1 0x047F) with a setpoint in Hz, scaled by the reference frequency P2000 that
        ussd publishes (:attr:`reference_hz`)."""
        self._command(STW1_RUN, _setpoint(hz / self.reference_hz * 100.0))

    def stop(self):
        """OFF1: ramp down, then S2."""
        self._command(STW1_OFF1, 0)

    def coast(self):
        """OFF2: pulses off at once, the motor coasts."""
        self._command(STW1_OFF2, 0)

    def quick_stop(self):
        """OFF3: the quick-stop ramp."""
        self._command(STW1_OFF3, 0)

    def acknowledge(self):
        """Acknowledges a fault: a rising edge of STW1 bit 7, then OFF1."""
        self._command(STW1_OFF1 | STW1_ACK, 0)
        self.wait_for(lambda i: i["sent_stw1"] & STW1_ACK, 1.0, "the acknowledge on the wire")
        self._command(STW1_OFF1, 0)

    def release(self):
        """Hands the drive back cleanly: ussd sends its safe command and shows it "released",
        which is not a watchdog trip."""
        if self._released:
            return
        self._stop.set()
        self._thread.join()
        self._publish(flags=_u.OUTPUT_RELEASE)
        self._released = True
        self._publisher = self._service = None

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.release()

    def __repr__(self):
        return f"Controller(bus={self.bus.name!r}, drive={self.address}, stw1={self._words[0]:#06x})"


def _setpoint(percent: float) -> int:
    """A setpoint in % as the signed word 0x4000 = 100 % (-200..+199.99 %)."""
    raw = round(percent / 100.0 * 0x4000)
    return max(-0x8000, min(0x7FFF, raw)) & 0xFFFF


def control(bus, address: int) -> Controller:
    """Takes exclusive control of drive ``address``; raises :class:`Controlled` while another
    controller holds it."""
    return Controller(bus, address)
