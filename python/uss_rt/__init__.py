"""Python client of uss-rt's ``ussd``: drive images, parameters, control, stops.

The work is done by ``uss_rt._native``, the Rust client library of uss-rt built for Python
(PyO3): the heartbeat, generation, latch and request rules are the same code as in Rust and C,
not a Python copy. This module gives it its Python face: enums made from the contract's own
code tables, exception classes, parameter values::

    import uss_rt
    bus = uss_rt.open_bus("bus0")
    image = uss_rt.read_input(bus, 1)          # {'zsw1': 0x..., 'hiw': ..., 'sequence': ...}
    p1082 = uss_rt.read_param(bus, 1, 1082)    # ParamValue(0x42480000); .as_float() == 50.0
    uss_rt.stop_drive(bus, 1, uss_rt.StopCommand.OFF2)   # coast drive 1, whoever controls it

Every call that waits (a parameter request, a stop, a re-arm, a wait for the drive) releases
the GIL meanwhile. Errors are exceptions derived from :class:`UssError` (``_errors.py``, generated
from the Rust client's code table); each message is the Rust client's, and says what to do next.
"""

import enum
import struct

from . import _errors, _native
from ._errors import *  # noqa: F403  the exceptions, generated from the Rust client's code table

__all__ = _errors.__all__ + [
    "ALL_DRIVES",
    "Bus",
    "BusStatus",
    "BusState",
    "CommandError",
    "ControlState",
    "Controller",
    "Direction",
    "Health",
    "LAYOUT_VERSION",
    "LastFailure",
    "LatchReason",
    "LineFault",
    "LineState",
    "Monitoring",
    "Outcome",
    "ParamValue",
    "Rejection",
    "RequestError",
    "RtMode",
    "StopCommand",
    "Storage",
    "TaskCode",
    "Value",
    "backup",
    "batch",
    "control",
    "describe",
    "diff",
    "factory_reset",
    "fault_report",
    "fault_text",
    "open_bus",
    "parse_param",
    "process_start_ns",
    "read",
    "read_input",
    "read_elements",
    "read_param",
    "quick_commission",
    "restore",
    "save_to_rom",
    "scan",
    "stop_all",
    "stop_drive",
    "wait_stopped",
    "wait_exchange",
    "warning_text",
    "write",
]

LAYOUT_VERSION = _native.LAYOUT_VERSION
"""The layout version of the contract the native module speaks (ussd must speak the same)."""
MAX_ADDRESS = 31
ALL_DRIVES = 0xFF
DEFAULT_NODE_NAME = "uss-py-client"

# -------------------------------------------------------------------------------------------
# Code tables: made from the Rust crate's own tables, so the two cannot disagree
# -------------------------------------------------------------------------------------------

_TABLES = _native.code_tables()


def _table(name: str, doc: str):
    table = enum.IntEnum(name, _TABLES[name])
    table.__doc__ = doc
    table.__module__ = __name__
    return table


ControlState = _table("ControlState", "Whether a drive gets its controller's words.")
LatchReason = _table("LatchReason", "Why a drive is latched: a stop command until re-armed.")
Rejection = _table("Rejection", "Why ussd refused a controller's sample.")
StopCommand = _table("StopCommand", "A stop command: what a latched drive gets.")
Monitoring = _table("Monitoring", "The drive's own telegram monitoring as ussd read it.")
CommandError = _table("CommandError", "Why ussd refused an operator command.")
RequestError = _table("RequestError", "Why ussd refused a request or item before the bus.")
Outcome = _table("Outcome", "How one parameter item ended.")
TaskCode = _table("TaskCode", "What one parameter item asks.")
Storage = _table("Storage", "Where a change is stored.")
LastFailure = _table("LastFailure", "Why a drive's last failed attempt failed.")
LineState = _table("LineState", "Whether the bus line carries telegrams.")
LineFault = _table("LineFault", "Why the bus line went down.")
BusState = _table("BusState", "What ussd says of its bus.")
RtMode = _table("RtMode", "The scheduling ussd's bus thread obtained.")
Direction = _table("Direction", "Which way a captured telegram went.")

STOP_STW1 = {StopCommand(code): stw1 for code, stw1 in _TABLES["STOP_STW1"].items()}
"""The control word of each stop command (USS.md section 7), the contract's; bit 10 set."""


def _code(table, value: int):
    """The table's member for ``value``, or the bare number if the table has none."""
    try:
        return table(value)
    except ValueError:
        return value


class ParamValue(int):
    """A parameter value: the raw word or double word, with ``is_dword`` and :meth:`as_float`."""

    def __new__(cls, raw: int, is_dword: bool):
        value = super().__new__(cls, raw)
        value.is_dword = bool(is_dword)
        return value

    def as_float(self) -> float:
        """The double word as an IEEE-754 float (USS float parameters, e.g. P1082)."""
        if not self.is_dword:
            raise ValueError(f"word {int(self):#06x} is not a float: floats are double words")
        return struct.unpack("<f", struct.pack("<I", int(self)))[0]

    def __repr__(self):
        width = 10 if self.is_dword else 6
        return f"ParamValue({int(self):#0{width}x})"


class Health:
    """What ussd's heartbeat says: ``state`` is "running", "line down", "stopped" or "gone"."""

    def __init__(self, bus, state: str, pid: int, error):
        self.bus, self.state, self.pid, self._error = bus, state, pid, error

    @property
    def serving(self) -> bool:
        """Whether ussd serves the bus (running, or waiting for its line)."""
        return self.state in ("running", "line down")

    def error(self):
        """The error a call that needs a polling bus gets now, or None."""
        return self._error

    def __repr__(self):
        return f"Health({self.state!r}, pid={self.pid})"


class BusStatus:
    """The bus and its drives as ``ussctl status --json`` shows them
    (docs/schema/ussctl/status.json): ``status["bus"]`` and ``status["drives"]`` (one dict per
    drive: ``address``, ``online``, ``state``, ``zsw1_hex``, ``actual_hz``, ``control``, ...),
    as in that JSON. The bus's fields are attributes too (``bus``, ``running``, ``rt_mode``
    "realtime" or "best effort", ``drive_count``, ``cycles``, ``exchanges``, ``good``, the job
    counters, ``mean_exchange_us``, ``efficiency``, ``line`` "up" or "down" and
    ``line_error``, ...), with ``drives``, the contract's ``version`` and ``line_down``."""

    def __init__(self, fields: dict):
        self._json = {"bus": fields["bus"], "drives": fields["drives"]}
        self.__dict__.update(fields["bus"])
        self.drives = fields["drives"]
        self.version = fields["version"]
        self.line_down = fields["line_down"]

    def __getitem__(self, key):
        return self._json[key]

    def keys(self):
        return self._json.keys()

    def __repr__(self):
        return f"BusStatus({self._json})"


class Bus:
    """An open bus: ussd's heartbeat, and the services of the generation it names (followed by
    themselves when a restarted ussd serves a new one).

    When ussd died or hangs (no heartbeat for 0.5 s), stopped, or its line is down, images show
    the drives offline and calls that need a polling bus raise :class:`UssdGone`,
    :class:`UssdStopped` or :class:`LineDown`. :meth:`close` (or a ``with`` block) lets go of
    the bus's ports (controllers made from it keep theirs).
    """

    def __init__(self, native):
        self._native = native
        self.name = native.name

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.close()

    def close(self):
        """Lets go of the bus; it cannot be used afterwards."""
        self._native = None

    def _open(self):
        if self._native is None:
            raise UssError(f"bus {self.name} is closed")
        return self._native

    def health(self) -> Health:
        """What ussd's heartbeat says now."""
        native = self._open()
        state, pid, problem = native.health()
        error = None
        if problem is not None:
            try:
                native.check()
            except UssError as e:
                error = e
        return Health(self.name, state, pid, error)

    def status(self) -> BusStatus:
        """The bus status as ussd last published it (every 50 ms); raises UssdGone/UssdStopped."""
        return BusStatus(self._open().status())

    def drives(self):
        """The addresses ussd polls on this bus."""
        return self._open().drives()

    def diag(self, address: int) -> dict:
        """Drive ``address``'s diagnostics as ussd last published them: ``info``
        (``reference_hz``, ``watchdog_ms``, ``pzd_words``, ``family``, ...), ``counters`` (``latches``,
        ``watchdog_trips``, ...), its control and monitoring. ``stale`` is True (and ``online``
        False) when they are older than ussd's limit for them (a paused ussd, a stalled bus
        thread): the rest is the drive as it was, not as it is."""
        _check_address(address)
        d = self._open().diag(address)
        d["control"] = _code(ControlState, d["control"])
        d["latch_reason"] = _code(LatchReason, d["latch_reason"])
        d["monitoring"] = _code(Monitoring, d["monitoring"])
        return d


def _check_address(address: int):
    if not 0 <= address <= MAX_ADDRESS:
        raise ValueError(f"drive address {address} is out of range 0..=31 (USS.md section 1)")


def open_bus(name: str, node_name: str = DEFAULT_NODE_NAME) -> Bus:
    """Opens bus ``name`` (e.g. ``bus0``) of a running ussd: waits for its heartbeat (at most
    0.5 s). Raises :class:`NotRunning` when no ussd serves the bus, :class:`UssdGone` or
    :class:`UssdStopped` when its heartbeat says so, ``ValueError`` for a name that cannot
    exist."""
    return Bus(_native.open_bus(name, node_name))


# Code -> member of the tables an image carries (a dict lookup per field of every image).
_IMAGE_CODES = tuple(
    (field, {m.value: m for m in table})
    for field, table in (
        ("control", ControlState),
        ("latch_reason", LatchReason),
        ("latch_command", StopCommand),
        ("rejection", Rejection),
    )
)


def _image(raw: dict) -> dict:
    """A native image with its codes as enums (a code no table defines stays a number)."""
    for field, members in _IMAGE_CODES:
        code = raw[field]
        raw[field] = members.get(code, code)
    return raw


def read_input(bus: Bus, address: int) -> dict:
    """The input image of drive ``address`` as ussd last wrote it, as a dict of its fields.

    ``words`` holds the PZD words in use (ZSW1 first). ``sequence`` counts good replies (0 =
    none yet); ``online`` is 1 while the drive answers, and 0 whenever ussd does not poll the
    bus (``health`` says why: "gone", "stopped", "line down"; the image is then the last one
    read) and while the drive's poll is overdue by ussd's own limit (``health`` "stale": a
    stalled bus thread); ``known`` is 0 until ussd's first poll decided ``online``.
    ``period_ns`` is how often ussd polls the drive now, ``stale_after_ns`` the age
    (``timestamp_ns`` to now) beyond which the image is stale. Time stamps are
    CLOCK_MONOTONIC ns. ``control`` is a :class:`ControlState`; while latched,
    ``latch_reason`` (:class:`LatchReason`) says why, ``latch_command`` (:class:`StopCommand`)
    what the drive gets and ``latch_id`` which latch; ``sent_stw1`` is the control word that
    went out.
    """
    _check_address(address)
    return _image(_native.read_input(bus._open(), address))


def read_param(bus: Bus, address: int, pnu: int, index=None, timeout: float = 7.5) -> ParamValue:
    """Reads parameter ``pnu`` (or its array element ``index``) of drive ``address``, waiting
    at most ``timeout`` s for ussd's answer.

    Returns a :class:`ParamValue`. Raises :class:`DriveError` (with the USS error number) when
    the drive refuses, :class:`ParamTimeout` when the drive does not answer in ussd's parameter
    timeout, :class:`NoAnswer` when ussd does not answer within ``timeout``, :class:`Refused`
    when ussd refuses the request, :class:`ParamFailed` otherwise. :func:`uss_rt.read` reads a
    parameter in the manuals' notation as its own type.
    """
    _check_address(address)
    if not 0 <= pnu <= 0xFFFF:
        raise ValueError(f"PNU {pnu} is out of range 0..=65535")
    return ParamValue(*_native.read_param(bus._open(), address, pnu, index, timeout))


def batch(bus: Bus, address: int, items, eeprom: bool = False, force: bool = False,
          timeout: float = 7.5) -> list:
    """Up to 39 raw parameter items of drive ``address`` in one request, run one after the
    other with no other client's task between them, whole or not at all (Rust's
    ``Bus::batch``, C's ``ussrt_param_batch``). Each item is ``(pnu, index)`` (a read; ``index`` None for none) or
    ``(pnu, index, value, is_dword)`` (a write of the raw word or double word to RAM, with
    ``eeprom`` to RAM and EEPROM, with ``force`` while another process controls the drive).

    Returns one entry per item, in order: a :class:`ParamValue`, or the exception that item
    ended with (not raised: :class:`DriveError`, :class:`MaybeApplied`, ...). A failure of the
    request as a whole (:class:`Refused`, :class:`NoAnswer`, ...) is raised."""
    _check_address(address)
    raw = []
    for item in items:
        if len(item) == 2:
            pnu, index = item
            raw.append((pnu, index, None, False))
        elif len(item) == 4:
            pnu, index, value, is_dword = item
            raw.append((pnu, index, int(value), bool(is_dword)))
        else:
            raise ValueError(f"{item!r}: an item is (pnu, index) or (pnu, index, value, is_dword)")
        if not 0 <= pnu <= 0xFFFF:
            raise ValueError(f"PNU {pnu} is out of range 0..=65535")
    results = _native.batch(bus._open(), address, raw, eeprom, force, timeout)
    return [r if isinstance(r, BaseException) else ParamValue(*r) for r in results]


def fault_report(bus: Bus, address: int) -> dict:
    """The drive's fault buffer with fault values, times and texts, and its active warnings, in
    one request, where the drive's family keeps them (MICROMASTER 4: r0947, r0949, r0948, r2110;
    G120: r0945, r0949, r2122; SIMOREG: r947, r949): ``{"codes": "r0947", "values": "r0949",
    "warnings_from": "r2110", "faults": [{"slot", "number", "value", "time", "text"}, ...],
    "warnings": [(number, text), ...] or None}``. A generic slave has none: ValueError."""
    _check_address(address)
    return _native.fault_report(bus._open(), address)


def save_to_rom(bus: Bus, address: int) -> dict:
    """Copies every setting of drive ``address`` from RAM to ROM (MICROMASTER 4 P0971, G120
    p0971) and returns once the drive is done: what it holds now survives a power cycle. The
    access level the copy needs is raised and put back, in EEPROM too. A G120 stores no single
    value in EEPROM (``write(..., eeprom=True)`` raises :class:`Refused`): write to RAM, then
    call this. ``{"param": "P0971", "raised": "P0003 1 -> 3 -> 1" or None}``; a family without
    a known copy (generic, SIMOREG): :class:`Refused`."""
    _check_address(address)
    return _native.save_to_rom(bus._open(), address)


def backup(bus: Bus, address: int, discover: "tuple[int, int] | None" = None) -> str:
    """Every setting of drive ``address`` as STARTER uploads it: each setting of its family's
    catalogue with every element the drive has (its data sets included) and its firmware, as
    the backup file's TOML text (what ``ussctl param backup`` writes and ``ussctl param
    restore`` reads). The drive's state (P0010, P0004) and commands are left out. With
    ``discover=(first, last)`` the drive is also asked for every parameter number of that range
    the catalogue does not list (one exchange each), and the settable ones it has are saved
    under ``[described]``, typed as it describes them (``ussctl param backup --discover``). A
    generic slave: :class:`Refused`."""
    _check_address(address)
    if discover is not None:
        first, last = discover
        if not (0 <= first <= 65535 and 0 <= last <= 65535):
            raise ValueError(f"discover={discover!r}: (first, last) parameter numbers")
        return _native.backup(bus._open(), address, (first, last))
    return _native.backup(bus._open(), address)


def diff(bus: Bus, address: int, other) -> dict:
    """Compares drive ``address`` with ``other``: a backup file's TOML text (a str, as
    :func:`backup` gives it) or another drive of the same family (an int). ``{"same": 51,
    "differ": [{"param": "P1120[2]", "name": "Ramp-up time", "drive": "2.50 s", "other":
    "10.00 s"}], "ignored": []}`` (``drive``/``other`` None where that side does not have it).
    A file that fails its checks (another family or firmware's values, a value beyond its
    limits) raises ValueError naming its line."""
    _check_address(address)
    if isinstance(other, int):
        _check_address(other)
    return _native.diff(bus._open(), address, other)


def describe(bus: Bus, address: int, param: str, timeout: float = 7.5) -> dict:
    """What drive ``address`` says ``param`` (the manuals' notation, ``"P1120"``) is, by its
    PROFIdrive descriptive elements (data type, elements, read-only, limits), beside what the
    family's catalogue says (name, unit, data sets, access level, when it can be changed,
    limits, factory setting, and whether its type agrees): ``{"param", "family", "drive":
    {"data_type", "elements", "read_only", "min", "max"}, "catalogue": None or {...}}``. A
    value the drive does not give (limits over a 3-word channel) is None. A parameter the drive
    does not have: :class:`DriveError`; a generic slave is never asked: ValueError."""
    _check_address(address)
    return _native.describe(bus._open(), address, param, timeout)


def scan(device: str, bauds=None, addresses=None, tries: int = 4) -> dict:
    """Which drives answer on ``device``, a serial line ussd does not serve (no bus, no ussd):
    at each baud rate (``bauds``, default MICROMASTER's P2010 rates 1200..115200) each address
    (``addresses``, default 0..31) is asked by a mirror telegram, and each slave that answers
    is identified: ``{"drives": [{"baud": 19200, "address": 3, "pkw": 4 (0, 3, 4, 127, or None:
    not known), "pzd": 2, "zsw1": 0xBB31, "firmware": 2.09, "family": "micromaster4" or None,
    "unsure": None or why the line may not be right}], "seconds"}``. Every probe carries OFF1
    (STW1 0x047E, setpoint 0): a drive that runs under USS control there ramps down and stays
    off. A silent address is asked ``tries`` times (1..20). Ctrl-C (in the main thread) ends it
    after the address under way with KeyboardInterrupt. A line that cannot be used (missing,
    busy, not a tty, no permission): :class:`DeviceError` (an ``OSError`` too)."""
    return _native.scan(device, bauds, addresses, tries)


def restore(
    bus: Bus,
    address: int,
    text: str,
    eeprom: bool = False,
    dry_run: bool = False,
    force: bool = False,
    unsafe: bool = False,
    other_firmware: bool = False,
    put_back_within: float = 30.0,
) -> dict:
    """Writes a backup (the TOML text :func:`backup` gives) to drive ``address`` as STARTER
    downloads it: the whole file checked first (family, firmware, every value; a guarded
    parameter such as the command source only with ``unsafe``), then only what differs, in a
    safe order (the access level raised and quick commissioning entered where needed, and put
    back), each value checked against the drive's answer; the COM link ussd talks over is kept.
    ``eeprom`` copies RAM to ROM once every value is in RAM. Ctrl-C (in the main thread) cuts
    it short between two writes: it puts back what it raised (Ctrl-C again leaves that) and
    then raises KeyboardInterrupt. Returns the report:
    ``{"complete": True, "equal", "written", "refused", "unknown", "kept", "cut_short",
    "left_raised": [(param, raised_to, was, meaning)], "stored", "ignored", "lines": [{"param",
    "was", "wanted", "result"}], "seconds"}``; an incomplete restore is not raised: run it
    again to complete it. Nothing written: :class:`Refused` (guarded, another controller, a
    generic slave), ValueError (a file that fails its checks, another family or firmware)."""
    _check_address(address)
    return _native.restore(
        bus._open(),
        address,
        text,
        eeprom,
        dry_run,
        force,
        unsafe,
        other_firmware,
        put_back_within,
    )


def factory_reset(bus: Bus, address: int, unsafe: bool = False, force: bool = False) -> dict:
    """Puts every setting of drive ``address`` back to its factory value as its manual gives it
    (MICROMASTER 4 and G120: P0010 = 30, then P0970 = 1), waits until the drive is done and
    until ussd has read again what it scales and judges the drive by, and says what it read:
    ``{"writes": ["P0010 := 30", "P0970 := 1"], "seconds": 0.04, "reference_hz": 50.0 (None:
    still being read), "monitoring": "off", "monitoring_ms": 0}``. The reset takes the command
    source, the COM link and the telegram monitoring back to their defaults: only with
    ``unsafe=True`` (:class:`Refused` without it, nothing written; ussd logs the writes);
    ``force`` resets while another process controls the drive. RAM only: :func:`save_to_rom`
    stores it. A family without a known reset: :class:`Refused`."""
    _check_address(address)
    return _native.factory_reset(bus._open(), address, unsafe, force)


def quick_commission(
    bus: Bus, address: int, motor, end: int = 3, unsafe: bool = False, force: bool = False
) -> dict:
    """Quick commissioning as the drive's manual gives it: P0010 = 1, the motor data ``motor``
    (``[("P0304", "400"), ("P0305", "1.9"), ...]`` or a dict, in the parameters' own units,
    written in order), then P3900 = ``end`` (3: the motor model only; 2: and the I/O back to
    factory values; 1: and every other setting, the command source, the COM link and the
    telegram monitoring included). Waits until the drive is done and ussd has read it again:
    ``{"writes": ["P0010 := 1", "P0304 := 400 V", ..., "P3900 := 3"], "raised": "P0003 1 ->
    2 -> 1" or None, "seconds", "reference_hz", "monitoring", "monitoring_ms"}``. A value the
    drive refuses raises (:class:`DriveError`) with the drive out of quick commissioning (P0010
    back to 0) and the access level put back; values written before stay in RAM. The end of
    quick commissioning is a guarded write: only with ``unsafe=True`` (:class:`Refused`
    without it, nothing written); the motor values are written as any write is (a guarded one
    among them is :class:`Refused`)."""
    _check_address(address)
    items = motor.items() if isinstance(motor, dict) else motor
    pairs = [(str(p), str(v)) for p, v in items]
    return _native.quick_commission(bus._open(), address, pairs, end, unsafe, force)


def stop_drive(bus: Bus, address: int, command=StopCommand.OFF1, timeout: float = 2.0):
    """Stops drive ``address`` with ``command`` (OFF1 ramp, OFF2 coast, OFF3 quick stop),
    whoever controls it: the drive gets it from its next poll on, latched until its controller
    re-arms it (OFF1, then ON). Returns once ussd has taken the command (ussd answers within
    2 s; ``timeout`` is kept for scripts that pass it); :func:`wait_stopped` waits until it went
    out. Raises :class:`CommandRefused` or :class:`UnknownDrive`."""
    _check_address(address)
    _native.stop_drive(bus._open(), address, int(StopCommand(command)))


def stop_all(bus: Bus, command=StopCommand.OFF1, timeout: float = 2.0):
    """Stops every drive of the bus with ``command``; returns their addresses."""
    return _native.stop_all(bus._open(), int(StopCommand(command)))


def wait_stopped(bus: Bus, address: int, command=StopCommand.OFF1, timeout=None) -> dict:
    """Waits until drive ``address``'s image shows an operator's stop at least as strong as
    ``command`` and the control word that went out; returns that image (:func:`read_input`).
    ``timeout`` None waits as long as the drive's next poll may take (its ``stale_after_ns``,
    at least 1 s; an offline drive's next probe)."""
    _check_address(address)
    return _image(
        _native.wait_stopped(bus._open(), address, int(StopCommand(command)), timeout)
    )


def wait_exchange(bus: Bus, address: int, count: int = 1, timeout: float = 1.0) -> dict:
    """Waits for ``count`` more exchanges with drive ``address`` (a loop in step with the
    bus); the image after them. :class:`WaitTimeout` when they do not come in ``timeout`` s."""
    _check_address(address)
    return _image(_native.wait_exchange(bus._open(), address, count, timeout))


def process_start_ns() -> int:
    """When this process started, ``CLOCK_MONOTONIC`` ns (the kernel's start time, rounded down
    to its 10 ms tick): what a script that re-arms once it is set up passes to
    :meth:`Controller.rearm`, so a stop while it starts (imports, opening the bus) stays."""
    return _native.process_start_ns()


# Parameters in the manuals' notation and exclusive control.
from .drive import (  # noqa: E402
    Controller,
    Value,
    control,
    fault_text,
    parse_param,
    read,
    read_elements,
    warning_text,
    write,
)
