"""Python client of uss-rt's ``ussd``: read a drive's input image, read parameters, stop drives.

ussd publishes everything over iceoryx2 0.10 shared memory (crate ``uss-shm-types`` is the
contract; ``shm-types/include/uss_shm_types.h`` is the same contract for C and C++). This module
mirrors the payload types with ctypes, field for field and with the same iceoryx2 type names, so
iceoryx2 accepts the ports (it compares type name, size and alignment when a port is opened)::

    import uss_rt
    bus = uss_rt.open_bus("bus0")
    image = uss_rt.read_input(bus, 1)          # {'zsw1': 0x..., 'hiw': ..., 'sequence': ...}
    p1082 = uss_rt.read_param(bus, 1, 1082)    # ParamValue(0x42480000); .as_float() == 50.0
    uss_rt.stop_drive(bus, 1, uss_rt.StopCommand.OFF2)   # coast drive 1, whoever controls it

Errors are exceptions derived from :class:`UssError`; each message says what to do next.
"""

import ctypes
import enum
import os
import struct
import threading
import time

import iceoryx2 as iox2

__all__ = [
    "Bus",
    "BusStatus",
    "BlackboardKey",
    "CommandError",
    "CommandRefused",
    "BusState",
    "ControlState",
    "DriveCounters",
    "DriveDiag",
    "DriveInfo",
    "Heartbeat",
    "LineDown",
    "LineFault",
    "UssdGone",
    "UssdStopped",
    "DriveError",
    "Incompatible",
    "LastFailure",
    "LatchReason",
    "Monitoring",
    "NoAnswer",
    "NotRunning",
    "OperatorRequest",
    "OperatorResponse",
    "Outcome",
    "ParamFailed",
    "ParamItem",
    "ParamRequest",
    "ParamResponse",
    "ParamResult",
    "ParamTimeout",
    "ParamValue",
    "PzdInput",
    "PzdOutput",
    "Refused",
    "Rejection",
    "RequestError",
    "RtMode",
    "StopCommand",
    "Storage",
    "TaskCode",
    "UnknownDrive",
    "UssError",
    "open_bus",
    "read_input",
    "read_param",
    "stop_all",
    "stop_drive",
    "wait_stopped",
    "parse_param",
    "read",
    "write",
    "control",
    "Controller",
    "Controlled",
    "Tripped",
    "Value",
]

# -------------------------------------------------------------------------------------------
# Limits and names (uss_shm_types: lib.rs, pzd.rs, params.rs, names.rs)
# -------------------------------------------------------------------------------------------

LAYOUT_VERSION = 6
"""The layout version of every payload; its ``version`` field and the services' attribute."""
LAYOUT_VERSION_ATTRIBUTE = "uss.layout_version"
MAX_PZD_WORDS = 16
EXTRA_PZD_WORDS = MAX_PZD_WORDS - 2
MAX_PARAM_ITEMS = 39
MAX_ACTIVE_REQUESTS = 4
"""Requests one client port may have on their way at once: a bus's further requests (from
other threads) wait for a free slot."""
MAX_SUBINDEX = 254
NO_ITEM = 0xFF
"""``ParamResponse.error_item`` when the error concerns no single item."""
MAX_ADDRESS = 31
MAX_BUS_NAME_LEN = 32
NEVER = 0xFFFF_FFFF_FFFF_FFFF
"""``DriveDiag.last_good_ns`` of a drive that never replied."""
ALL_DRIVES = 0xFF
"""``OperatorRequest.address`` for every drive of the bus."""
OUTPUT_RELEASE = 0x01
"""``PzdOutput.flags``: the controller hands the drive back."""
REQUEST_FORCE = 0x01
"""``ParamRequest.flags``: write although another process controls the drive."""

HEARTBEAT_PERIOD_NS = 50_000_000
"""How often ussd publishes its heartbeat."""
GONE_AFTER_NS = 10 * HEARTBEAT_PERIOD_NS
"""A heartbeat older than this means ussd is gone (killed or hung)."""

DEFAULT_NODE_NAME = "uss-py-client"

# iceoryx2 reports at info level that it runs without a config file; keep its log to errors
# unless IOX2_LOG_LEVEL asks for more.
iox2.set_log_level_from_env_or(iox2.LogLevel.Error)


def heartbeat_service(bus: str) -> str:
    """Publish-subscribe, :class:`Heartbeat`: ussd's heartbeat; its generation names the rest."""
    return f"uss/{bus}/ussd"


def drive_out_service(bus: str, generation: int, address: int) -> str:
    """Publish-subscribe, :class:`PzdOutput`: the controller's output image (one publisher)."""
    return f"uss/{bus}/{generation:016x}/drive/{address}/out"


def drive_in_service(bus: str, generation: int, address: int) -> str:
    """Blackboard, key 0 -> :class:`PzdInput`: the drive's input image."""
    return f"uss/{bus}/{generation:016x}/drive/{address}/in"


def diag_service(bus: str, generation: int) -> str:
    """Blackboard, key = drive address -> :class:`DriveDiag`."""
    return f"uss/{bus}/{generation:016x}/diag"


def status_service(bus: str, generation: int) -> str:
    """Blackboard, key 0 -> :class:`BusStatus`."""
    return f"uss/{bus}/{generation:016x}/status"


def cycle_service(bus: str, generation: int) -> str:
    """Event: drive address (exchange completed), 32 cycle completed, 33 status published."""
    return f"uss/{bus}/{generation:016x}/cycle"


def params_service(bus: str, generation: int) -> str:
    """Request-response, :class:`ParamRequest` -> :class:`ParamResponse`."""
    return f"uss/{bus}/{generation:016x}/params"


def command_service(bus: str, generation: int) -> str:
    """Request-response, :class:`OperatorRequest` -> :class:`OperatorResponse`: stop commands."""
    return f"uss/{bus}/{generation:016x}/command"


def requests_service(bus: str, generation: int) -> str:
    """Event: a client notifies :data:`REQUEST_SENT` after sending on ``params`` or
    ``command``, so ussd takes the request at once (else within a few ms)."""
    return f"uss/{bus}/{generation:016x}/requests"


def capture_service(bus: str, generation: int) -> str:
    """Publish-subscribe, :class:`TelegramRecord`: every telegram of the bus."""
    return f"uss/{bus}/{generation:016x}/capture"


def answers_service(bus: str, generation: int) -> str:
    """Event: ussd notifies :data:`ANSWER_SENT` after each answer on ``params`` and
    ``command``, so a waiting client receives it at once."""
    return f"uss/{bus}/{generation:016x}/answers"


REQUEST_SENT = 0
ANSWER_SENT = 0


# -------------------------------------------------------------------------------------------
# Code tables: the u8 fields with a fixed meaning (payloads keep them as plain integers)
# -------------------------------------------------------------------------------------------


class LastFailure(enum.IntEnum):
    """Why a drive's last failed attempt failed (``DriveDiag.last_failure``)."""

    NONE = 0
    NO_RESPONSE = 1
    MISSING_STX = 2
    START_PAUSE = 3
    BAD_LGE = 4
    BCC = 5
    RESIDUAL = 6
    LENGTH = 7
    WRONG_ADDRESS = 8
    PARITY = 9
    FRAMING = 10
    OVERRUN = 11
    ECHO = 12


class LineState(enum.IntEnum):
    """Whether the bus line carries telegrams (``BusStatus.line_state``)."""

    UP = 0
    DOWN = 1


class LineFault(enum.IntEnum):
    """Why the bus line went down."""

    NONE = 0
    CLOSED = 1
    IO = 2


class Direction(enum.IntEnum):
    """Which way a captured telegram went (``TelegramRecord.direction``)."""

    REQUEST = 0
    REPLY = 1


class BusState(enum.IntEnum):
    """What ussd says of its bus (``Heartbeat.state``)."""

    RUNNING = 0
    LINE_DOWN = 1
    STOPPING = 2


class RtMode(enum.IntEnum):
    """The scheduling ussd's bus thread obtained (``BusStatus.rt_mode``)."""

    BEST_EFFORT = 0
    REALTIME = 1


class TaskCode(enum.IntEnum):
    """What one parameter item asks (``ParamItem.task``)."""

    READ = 1
    WRITE_WORD = 2
    WRITE_DWORD = 3
    READ_ARRAY = 4
    WRITE_ARRAY_WORD = 5
    WRITE_ARRAY_DWORD = 6
    READ_ELEMENT_COUNT = 7
    READ_DESCRIPTION = 8


class Storage(enum.IntEnum):
    """Where a change is stored (``ParamItem.storage``)."""

    RAM = 0
    RAM_AND_EEPROM = 1


class RequestError(enum.IntEnum):
    """Why ussd refused a request or an item before the bus."""

    OK = 0
    UNKNOWN_DRIVE = 1
    BAD_COUNT = 2
    PNU_OUT_OF_RANGE = 3
    VALUE_TYPE = 4
    WRITES_DISABLED = 5
    BUSY = 6
    SHUTDOWN = 7
    VERSION = 8
    BAD_TASK = 9
    BAD_STORAGE = 10
    BAD_SUBINDEX = 11
    NO_PARAMETER_CHANNEL = 12
    DWORD_OVER_THREE_WORDS = 13
    CONTROLLED = 14
    BAD_FLAGS = 15
    LINE_DOWN = 16


class Outcome(enum.IntEnum):
    """How one parameter item ended (``ParamResult.outcome``)."""

    NOT_RUN = 0
    VALUE = 1
    ELEMENT_COUNT = 2
    DESCRIPTION = 3
    DRIVE_ERROR = 4
    NO_CHANGE_RIGHTS = 5
    TIMEOUT = 6
    DRIVE_OFFLINE = 7
    MAILBOX_FULL = 8
    SHUTDOWN = 9
    REFUSED = 10
    LINE_DOWN = 11
    CANCELLED = 12


class ControlState(enum.IntEnum):
    """Whether a drive gets its controller's words (``control`` of images and diagnostics)."""

    LIVE = 0
    LATCHED = 1


class LatchReason(enum.IntEnum):
    """Why a drive is latched: it gets a stop command until its controller re-arms it."""

    NONE = 0
    STARTUP = 1
    STALE = 2
    REJECTED = 3
    RELEASED = 4
    OVERRIDE = 5
    LINE_RESTORED = 6
    MONITORING_OFF = 7


class Rejection(enum.IntEnum):
    """Why ussd refused a controller's sample."""

    NONE = 0
    VERSION = 1
    WORD_COUNT = 2
    NO_PLC_CONTROL = 3
    FLAGS = 4


class StopCommand(enum.IntEnum):
    """A stop command: what a latched drive gets, what an operator asks for."""

    NONE = 0
    OFF1 = 1
    OFF2 = 2
    OFF3 = 3


STOP_STW1 = {StopCommand.OFF1: 0x047E, StopCommand.OFF2: 0x047C, StopCommand.OFF3: 0x047A}
"""The control word of each stop command (USS.md section 7); bit 10 set."""


class Monitoring(enum.IntEnum):
    """The drive's own telegram monitoring (P2014 / p2040) as ussd read it."""

    UNKNOWN = 0
    ON = 1
    OFF = 2
    TOO_LONG = 3
    UNREADABLE = 4
    NOT_CHECKED = 5


class CommandError(enum.IntEnum):
    """Why ussd refused an operator command (``OperatorResponse.error``)."""

    OK = 0
    UNKNOWN_DRIVE = 1
    BAD_COMMAND = 2
    VERSION = 3
    SHUTDOWN = 4


# The drive's error numbers with reply 7 (USS.md section 6).
_DRIVE_ERRORS = {
    0: "illegal parameter number",
    1: "value cannot be changed",
    2: "limit exceeded",
    3: "faulty subindex",
    4: "not an array",
    5: "wrong data type",
    6: "setting not allowed",
    7: "descriptive element cannot be changed",
    11: "no master control",
    12: "keyword missing",
    17: "not possible in this operating state",
    101: "parameter deactivated",
    102: "channel too narrow",
    103: "double word over a 3-word parameter channel",
    104: "illegal value",
    106: "task not implemented",
    200: "modified minimum exceeded",
    201: "modified maximum exceeded",
    204: "access level too low",
}

# -------------------------------------------------------------------------------------------
# Payload types: _fields_ in memory order, exactly as uss_shm_types::layout::LAYOUTS
# -------------------------------------------------------------------------------------------

u8, u16, u32, u64, i32, f32 = (
    ctypes.c_uint8,
    ctypes.c_uint16,
    ctypes.c_uint32,
    ctypes.c_uint64,
    ctypes.c_int32,
    ctypes.c_float,
)


class BlackboardKey(ctypes.Structure):
    """The key of every ussd blackboard: 0 for ``in`` and ``status``, the address for ``diag``."""

    _fields_ = [("value", u32)]

    def __eq__(self, other):
        return isinstance(other, BlackboardKey) and self.value == other.value

    @staticmethod
    def type_name() -> str:
        return "UssBlackboardKey"


class PzdOutput(ctypes.Structure):
    """The controller's output image of one drive (``uss/<bus>/drive/<addr>/out``)."""

    _fields_ = [
        ("version", u32),
        ("controller_pid", u32),
        ("sequence", u64),
        ("timestamp_ns", u64),
        ("stw1", u16),
        ("setpoint", u16),
        ("extra", u16 * EXTRA_PZD_WORDS),
        ("word_count", u8),
        ("flags", u8),
        ("reserved", u8 * 6),
        ("latch_id", u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssPzdOutputV6"


class PzdInput(ctypes.Structure):
    """The drive's input image (``uss/<bus>/drive/<addr>/in``), written after every poll."""

    _fields_ = [
        ("version", u32),
        ("online", u8),
        ("control", u8),
        ("word_count", u8),
        ("latch_reason", u8),
        ("sequence", u64),
        ("timestamp_ns", u64),
        ("age_ns", u64),
        ("zsw1", u16),
        ("hiw", u16),
        ("extra", u16 * EXTRA_PZD_WORDS),
        ("sent_stw1", u16),
        ("sent_setpoint", u16),
        ("latches", u32),
        ("latched_since_ns", u64),
        ("latched_by_pid", u32),
        ("latch_command", u8),
        ("rejection", u8),
        ("known", u8),
        ("reserved", u8),
        ("taken_sequence", u64),
        ("latch_id", u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssPzdInputV6"


class DriveInfo(ctypes.Structure):
    """What ussd knows of a drive from its configuration (``DriveDiag.info``): scale Hz with
    ``reference_hz`` (P2000), send exactly ``pzd_words``."""

    _fields_ = [
        ("reference_hz", f32),
        ("watchdog_ms", u32),
        ("safe_command", u8),
        ("params_writable", u8),
        ("pkw_words", u8),
        ("pzd_words", u8),
        ("weight", u8),
        ("reserved", u8 * 3),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssDriveInfoV6"


class DriveCounters(ctypes.Structure):
    """What ussd counted for a drive (``DriveDiag.counters``)."""

    _fields_ = [
        (name, u64)
        for name in (
            "requests",
            "good",
            "rejected",
            "timeouts",
            "retries",
            "failed_polls",
            "missing_stx",
            "start_pause",
            "bad_lge",
            "bcc",
            "residual",
            "length",
            "wrong_address",
            "parity",
            "framing",
            "overrun",
            "echo",
            "pkw_busy",
            "jobs_done",
            "watchdog_trips",
            "latches",
            "rejected_outputs",
            "releases",
            "overrides",
        )
    ]

    @staticmethod
    def type_name() -> str:
        return "UssDriveCountersV6"


class DriveDiag(ctypes.Structure):
    """The master's view of one drive (``uss/<bus>/diag``, key = address)."""

    _fields_ = [
        ("version", u32),
        ("consecutive_failed_polls", u32),
        ("last_zsw1", u16),
        ("last_hiw", u16),
        ("address", u8),
        ("online", u8),
        ("no_reply", u8),
        ("control", u8),
        ("last_failure", u8),
        ("latch_reason", u8),
        ("latch_command", u8),
        ("rejection", u8),
        ("monitoring", u8),
        ("known", u8),
        ("reserved", u8 * 2),
        ("monitoring_ms", u32),
        ("controller_pid", u32),
        ("since_ns", u64),
        ("last_good_ns", u64),
        ("latched_since_ns", u64),
        ("info", DriveInfo),
        ("counters", DriveCounters),
        ("exchange_ns", u64 * 4),
        ("response_delay_ns", u64 * 4),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssDriveDiagV6"


EXCHANGE_BUCKETS = 12
# Upper bounds of BusStatus.exchange_le, ns.
EXCHANGE_BUCKETS_NS = (
    500_000, 1_000_000, 2_000_000, 3_000_000, 5_000_000, 7_500_000,
    10_000_000, 20_000_000, 50_000_000, 100_000_000, 250_000_000, 1_000_000_000,
)


class BusStatus(ctypes.Structure):
    """The state of the bus as a whole (``uss/<bus>/status``)."""

    _fields_ = [
        ("version", u32),
        ("rt_cpu", i32),
        ("rt_mode", u8),
        ("rt_priority", u8),
        ("drive_count", u8),
        ("running", u8),
        ("efficiency_ppm", u32),
    ] + [
        (name, u64)
        for name in (
            "exchanges",
            "good",
            "cycles",
            "cycle_overruns",
            "events_dropped",
            "results_lost",
            "jobs_accepted",
            "jobs_finished",
            "mean_exchange_ns",
            "bus_clock_ns",
            "timestamp_ns",
        )
    ] + [
        ("line_state", u8),
        ("line_fault", u8),
        ("reserved", u8 * 2),
        ("line_errno", i32),
        ("line_down_since_ns", u64),
        ("line_downs", u64),
        ("reopen_attempts", u32),
        ("reserved2", u32),
        ("jobs_cancelled", u64),
        ("exchange_ns", u64 * 4),
        ("response_delay_ns", u64 * 4),
        ("turnaround_ns", u64 * 4),
        ("exchange_count", u64),
        ("exchange_sum_ns", u64),
        ("exchange_le", u64 * EXCHANGE_BUCKETS),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssBusStatusV6"


class ParamItem(ctypes.Structure):
    """One parameter access."""

    _fields_ = [
        ("task", u8),
        ("storage", u8),
        ("pnu", u16),
        ("index", u16),
        ("reserved", u16),
        ("value", u32),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssParamItemV6"


class ParamRequest(ctypes.Structure):
    """A request for up to 39 parameter accesses on one drive."""

    _fields_ = [
        ("version", u32),
        ("address", u8),
        ("count", u8),
        ("flags", u8),
        ("reserved", u8),
        ("items", ParamItem * MAX_PARAM_ITEMS),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssParamRequestV6"


class ParamResult(ctypes.Structure):
    """The result of one item."""

    _fields_ = [
        ("outcome", u8),
        ("value_is_dword", u8),
        ("drive_error", u16),
        ("value", u32),
        ("telegrams", u32),
        ("refusal", u8),
        ("reserved", u8 * 3),
        ("on_wire_ns", u64),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssParamResultV6"


class ParamResponse(ctypes.Structure):
    """The one response to a :class:`ParamRequest`."""

    _fields_ = [
        ("version", u32),
        ("error", u8),
        ("error_item", u8),
        ("address", u8),
        ("count", u8),
        ("controller_pid", u32),
        ("reserved", u32),
        ("results", ParamResult * MAX_PARAM_ITEMS),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssParamResponseV6"


class Heartbeat(ctypes.Structure):
    """ussd's heartbeat on ``uss/<bus>/ussd``: which generation serves the bus, and its state."""

    _fields_ = [
        ("version", u32),
        ("pid", u32),
        ("generation", u64),
        ("sequence", u64),
        ("timestamp_ns", u64),
        ("exchanges", u64),
        ("line_down_since_ns", u64),
        ("state", u8),
        ("line_fault", u8),
        ("reserved", u8 * 2),
        ("line_errno", i32),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssHeartbeatV6"


class OperatorRequest(ctypes.Structure):
    """An operator's stop command for one drive or every drive (``uss/<bus>/command``)."""

    _fields_ = [
        ("version", u32),
        ("address", u8),
        ("command", u8),
        ("reserved", u8 * 2),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssOperatorRequestV6"


class OperatorResponse(ctypes.Structure):
    """The one answer to an :class:`OperatorRequest`: the drives it reached (bit = address)."""

    _fields_ = [
        ("version", u32),
        ("error", u8),
        ("command", u8),
        ("reserved", u8 * 2),
        ("drives", u32),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssOperatorResponseV6"


CAPTURE_BYTES = 264
CAPTURE_TRUNCATED = 1 << 0
CAPTURE_TASK = 1 << 1
CAPTURE_BUFFER = 1024
CAPTURE_MAX_SUBSCRIBERS = 4


class TelegramRecord(ctypes.Structure):
    """One telegram of the bus as ussd's bus thread sent or received it (``uss/<bus>/capture``)."""

    _fields_ = [
        ("version", u32),
        ("len", u16),
        ("direction", u8),
        ("outcome", u8),
        ("address", u8),
        ("pkw", u8),
        ("pzd", u8),
        ("flags", u8),
        ("reserved", u8 * 4),
        ("sequence", u64),
        ("start_ns", u64),
        ("end_ns", u64),
        ("bytes", u8 * CAPTURE_BYTES),
    ]

    @staticmethod
    def type_name() -> str:
        return "UssTelegramRecordV6"


PAYLOAD_TYPES = (
    BlackboardKey,
    PzdOutput,
    PzdInput,
    DriveInfo,
    DriveCounters,
    DriveDiag,
    BusStatus,
    ParamItem,
    ParamRequest,
    ParamResult,
    ParamResponse,
    Heartbeat,
    OperatorRequest,
    OperatorResponse,
    TelegramRecord,
)

# -------------------------------------------------------------------------------------------
# Errors
# -------------------------------------------------------------------------------------------


class UssError(Exception):
    """Anything this module reports; the message says what to do."""


class NotRunning(UssError):
    """ussd's services for the bus do not exist."""

    def __init__(self, bus: str):
        self.bus = bus
        super().__init__(
            f"ussd is not running on {bus}: start it with `ussd` (or `ussd --config FILE`)"
        )


class UnknownDrive(UssError):
    """ussd runs the bus, but does not poll this drive."""

    def __init__(self, bus: str, address: int, known):
        self.bus, self.address, self.known = bus, address, list(known)
        polled = ", ".join(str(a) for a in self.known) or "no drives"
        super().__init__(
            f"drive {address} is not on {bus} (ussd polls {polled} there): use one of those "
            "or add it to ussd's configuration"
        )


class Incompatible(UssError):
    """ussd was built against another layout of the payload types."""

    def __init__(self, bus: str, service: str, detail: str = ""):
        self.bus, self.service = bus, service
        more = f" ({detail})" if detail else ""
        super().__init__(
            f"ussd on {bus} speaks another layout version ({service}{more}): use the uss_rt "
            "module of the running ussd's uss-rt version"
        )


class DriveError(UssError):
    """The drive refused the task (reply 7) with USS error ``number``."""

    def __init__(self, number: int):
        self.number = number
        meaning = _DRIVE_ERRORS.get(number, "unknown error number")
        super().__init__(f"the drive refused the task with error {number}: {meaning}")


class ParamTimeout(UssError, TimeoutError):
    """The drive gave no matching reply within ussd's parameter timeout."""

    def __init__(self):
        super().__init__(
            "no matching reply within ussd's parameter timeout: check the drive's PKW length "
            "(P2013); raise param_timeout_ms for slow EEPROM writes"
        )


class NoAnswer(UssError, TimeoutError):
    """ussd did not answer the request in time, or dropped it (it stopped)."""

    def __init__(self, bus: str, detail: str):
        self.bus = bus
        super().__init__(f"ussd on {bus} {detail}: check that it runs (`ussctl status`)")


class Refused(UssError):
    """ussd refused the request (or one item) before the bus; ``error`` is a RequestError."""

    _HINTS = {
        RequestError.WRITES_DISABLED: "ussd's configuration sets params_writable = false for "
        "this drive",
        RequestError.BUSY: "too many parameter jobs outstanding: retry once results arrived",
        RequestError.SHUTDOWN: "ussd is shutting down",
        RequestError.VERSION: "ussd speaks another layout version: use the uss_rt module of "
        "the running ussd's uss-rt version",
        RequestError.NO_PARAMETER_CHANNEL: "the drive has no parameter channel (PKW length 0)",
    }

    def __init__(self, error: int, item=None):
        self.error, self.item = _code(RequestError, error), item
        which = f" (item {item + 1})" if item is not None else ""
        hint = self._HINTS.get(self.error)
        super().__init__(
            f"ussd refused the request{which} before the bus: {_name(self.error)}"
            + (f": {hint}" if hint else "")
        )


class UssdGone(UssError):
    """No heartbeat from ussd for longer than GONE_AFTER_NS: it died or hangs."""

    def __init__(self, bus: str, pid: int, silent_for: float):
        self.bus, self.pid, self.silent_for = bus, pid, silent_for
        was = f"; it was process {pid}" if pid else ""
        super().__init__(
            f"ussd on {bus} is gone (no heartbeat for {silent_for:.2f} s{was}): the drives are "
            "not polled; only their own telegram monitoring stops them. Restart ussd"
        )


class UssdStopped(UssError):
    """ussd said it stops (a clean exit)."""

    def __init__(self, bus: str, pid: int, ago: float):
        self.bus, self.pid = bus, pid
        super().__init__(
            f"ussd on {bus} stopped {ago:.2f} s ago; it was process {pid}: start it again; "
            "this module reconnects by itself"
        )


class LineDown(UssError):
    """ussd runs, but the bus line is down."""

    def __init__(self, bus: str, fault: str, down_for: float):
        self.bus, self.fault = bus, fault
        super().__init__(
            f"bus {bus}: line down ({fault}) for {down_for:.2f} s: ussd reopens the device; "
            "check the adapter and cable"
        )


class CommandRefused(UssError):
    """ussd refused an operator stop command; ``error`` is a :class:`CommandError`."""

    def __init__(self, bus: str, error: int):
        self.bus, self.error = bus, _code(CommandError, error)
        super().__init__(f"ussd on {bus} refused the stop command: {_name(self.error)}")


class ParamFailed(UssError):
    """An item ended without a value for another reason; ``outcome`` is an Outcome."""

    _HINTS = {
        Outcome.NO_CHANGE_RIGHTS: "the drive grants no parameter change rights over USS (P0927)",
        Outcome.DRIVE_OFFLINE: "the drive is offline: check `ussctl status`, its wiring, "
        "address and baud rate",
        Outcome.MAILBOX_FULL: "ussd's parameter queue for the drive is full: retry once "
        "earlier requests finished",
        Outcome.SHUTDOWN: "ussd shut down before the task finished: retry once ussd runs again",
    }

    def __init__(self, outcome: int):
        self.outcome = _code(Outcome, outcome)
        hint = self._HINTS.get(self.outcome, "unexpected answer from ussd: check that ussd "
                               "and this module are the same uss-rt version")
        super().__init__(f"parameter task ended with {_name(self.outcome)}: {hint}")


def _code(table, value: int):
    """The table's member for ``value``, or the bare number if the table has none."""
    try:
        return table(value)
    except ValueError:
        return value


def _name(code) -> str:
    return code.name.lower().replace("_", " ") if isinstance(code, enum.Enum) else str(code)


# -------------------------------------------------------------------------------------------
# The client
# -------------------------------------------------------------------------------------------


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


def _monotonic_ns() -> int:
    """CLOCK_MONOTONIC in ns: the clock of every time stamp of the contract."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


class Health:
    """What ussd's heartbeat says: ``state`` is "running", "line down", "stopped" or "gone"."""

    def __init__(self, bus: str, beat: Heartbeat, now_ns: int):
        self.bus, self.pid = bus, beat.pid
        self.at_ns = beat.timestamp_ns
        if now_ns - beat.timestamp_ns > GONE_AFTER_NS:
            self.state = "gone"
        elif beat.state == BusState.STOPPING:
            self.state = "stopped"
        elif beat.state == BusState.LINE_DOWN:
            self.state = "line down"
        else:
            self.state = "running"
        self.line_down_since_ns = beat.line_down_since_ns
        self.line_fault = _code(LineFault, beat.line_fault)
        self.line_errno = beat.line_errno

    @property
    def serving(self) -> bool:
        """Whether ussd serves the bus (running, or waiting for its line)."""
        return self.state in ("running", "line down")

    def error(self):
        """The error a call that needs a polling bus gets now, or None."""
        now = _monotonic_ns()
        if self.state == "gone":
            return UssdGone(self.bus, self.pid, (now - self.at_ns) / 1e9)
        if self.state == "stopped":
            return UssdStopped(self.bus, self.pid, (now - self.at_ns) / 1e9)
        if self.state == "line down":
            if self.line_fault == LineFault.IO:
                fault = f"serial I/O failed: {os.strerror(self.line_errno)}"
            else:
                fault = "the serial device was closed or unplugged"
            return LineDown(self.bus, fault, (now - self.line_down_since_ns) / 1e9)
        return None

    def __repr__(self):
        return f"Health({self.state!r}, pid={self.pid})"


class Bus:
    """An open bus: one iceoryx2 node, ussd's heartbeat, and the services of the generation it
    names (reopened by themselves when a restarted ussd serves a new one).

    Every read looks at the heartbeat: when ussd died or hangs (no heartbeat for 0.5 s), stopped,
    or its line is down, images show the drives offline and calls that need a polling bus raise
    :class:`UssdGone`, :class:`UssdStopped` or :class:`LineDown`. :meth:`close` (or a ``with``
    block) lets go of every service at once.
    """

    def __init__(self, name: str, node, heartbeat_service, subscriber, beat: Heartbeat):
        self.name = name
        self.node = node
        self._heartbeat_service = heartbeat_service
        self._heartbeat = subscriber
        self._beat = beat
        self._generation = None
        self._services = {}
        self._request_slots = threading.BoundedSemaphore(MAX_ACTIVE_REQUESTS)

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.close()

    def close(self):
        """Drops every port and service of this bus; the bus cannot be used afterwards."""
        self._services = {}
        self._heartbeat = self._heartbeat_service = None

    def health(self) -> Health:
        """What ussd's heartbeat says now."""
        while True:
            sample = self._heartbeat.receive()
            if sample is None:
                break
            beat = Heartbeat.from_buffer_copy(sample.payload().contents)
            if beat.version == LAYOUT_VERSION:
                self._beat = beat
        return Health(self.name, self._beat, _monotonic_ns())

    def _current(self):
        """The services of the generation that serves the bus, opened on first use; raises
        what the heartbeat says when ussd does not poll."""
        health = self.health()
        error = health.error()
        if error is not None and not isinstance(error, LineDown):
            raise error
        if self._generation != self._beat.generation:
            # A restarted ussd: drop the old generation's ports, open the new one's.
            self._services = {}
            self._generation = self._beat.generation
            self._services["status"], self._services["diag"] = (
                self._blackboard(status_service(self.name, self._generation)),
                self._blackboard(diag_service(self.name, self._generation)),
            )
            reader = self._services["status"].reader_builder().create()
            self._services["status_reader"] = reader
            self._services["status_entry"] = reader.entry(BlackboardKey(0), BusStatus)
        return self._services, health

    def _blackboard(self, service: str):
        return _open(
            self.node,
            self.name,
            service,
            lambda b: b.blackboard_opener(BlackboardKey),
            lambda: NotRunning(self.name),
        )

    def status(self) -> BusStatus:
        """The bus status as ussd last published it (every 50 ms); raises UssdGone/UssdStopped."""
        services, _ = self._current()
        return services["status_entry"].get().decode_as(BusStatus)

    def drives(self):
        """The addresses ussd polls on this bus (the keys of its ``diag`` blackboard)."""
        services, _ = self._current()
        keys = services["diag"].list_keys()
        return sorted(k.decode_as(BlackboardKey).value for k in keys)

    def _input_entry(self, address: int):
        """The entry of drive ``address``'s input blackboard, opened on first use."""
        services, _ = self._current()
        key = ("in", address)
        if key not in services:
            service = _open(
                self.node,
                self.name,
                drive_in_service(self.name, self._generation, address),
                lambda b: b.blackboard_opener(BlackboardKey),
                lambda: UnknownDrive(self.name, address, self.drives()),
            )
            reader = service.reader_builder().create()
            services[key] = (service, reader, reader.entry(BlackboardKey(0), PzdInput))
        return services[key][2]

    def _client(self, kind: str, service, request_type, response_type):
        """The client of a request-response service of the current generation."""
        services, health = self._current()
        error = health.error()
        if error is not None:
            raise error
        if kind not in services:
            factory = _open(
                self.node,
                self.name,
                service(self.name, self._generation),
                lambda b: b.request_response(request_type, response_type),
                lambda: NotRunning(self.name),
            )
            services[kind] = (factory, factory.client_builder().create())
        if "events" not in services:
            services["events"] = self._events()
        return services[kind][1]

    def _events(self):
        """The notifier of ``requests`` and the listener of ``answers`` of the current
        generation; ``None`` for either that cannot be had (the request is then found by
        ussd's own poll, the answer polled for)."""
        def port(service, make):
            try:
                factory = _open(
                    self.node,
                    self.name,
                    service(self.name, self._generation),
                    lambda b: b.event(),
                    lambda: NotRunning(self.name),
                )
                return factory, make(factory)
            except Exception:  # noqa: BLE001 - events only speed things up
                return None

        return (
            port(
                requests_service,
                lambda f: f.notifier_builder()
                .default_event_id(iox2.EventId.new(REQUEST_SENT))
                .create(),
            ),
            port(answers_service, lambda f: f.listener_builder().create()),
        )

    def _params(self):
        """The client of the ``params`` service."""
        return self._client("params", params_service, ParamRequest, ParamResponse)

    def _commands(self):
        """The client of the ``command`` service."""
        return self._client("command", command_service, OperatorRequest, OperatorResponse)


def _open(node, bus: str, service: str, pattern, missing):
    """Opens ussd's ``service`` as ``pattern(builder)`` requires, with the layout attribute
    ``uss.layout_version`` = LAYOUT_VERSION; ``missing()`` is the error if it does not exist."""
    builder = pattern(node.service_builder(iox2.ServiceName.new(service)))
    verifier = iox2.AttributeVerifier.new().require(
        iox2.AttributeKey.new(LAYOUT_VERSION_ATTRIBUTE),
        iox2.AttributeValue.new(str(LAYOUT_VERSION)),
    )
    try:
        return builder.open_with_attributes(verifier)
    except Exception as e:  # the binding's *OpenError classes share no base but Exception
        # They carry the Rust variant's name: BlackboardOpenError('DoesNotExist').
        variant = str(e.args[0]) if e.args else ""
        if variant in ("DoesNotExist", "IsMarkedForDestruction"):
            raise missing() from e
        if variant.startswith("Incompatible"):
            raise Incompatible(bus, service, variant) from e
        raise UssError(
            f"opening {service} failed: {e!r}: run ussd and this program as the "
            "same user (or root): iceoryx2 keeps its state owner-only in /dev/shm and /tmp/iceoryx2"
        ) from e


def _check_address(address: int):
    if not 0 <= address <= MAX_ADDRESS:
        raise ValueError(f"drive address {address} is out of range 0..=31 (USS.md section 1)")


def open_bus(name: str, node_name: str = DEFAULT_NODE_NAME) -> Bus:
    """Opens bus ``name`` (e.g. ``bus0``) of a running ussd: waits for its heartbeat (at most
    0.5 s). Raises :class:`NotRunning` when no ussd ever served the bus (or all its clients are
    gone), :class:`UssdGone` or :class:`UssdStopped` when its heartbeat says so."""
    charset = all(c.isascii() and (c.isalnum() or c in "_-") for c in name)
    if not (1 <= len(name) <= MAX_BUS_NAME_LEN and charset):
        raise ValueError(
            f"bus name {name!r} must be 1 to 32 characters of A-Z, a-z, 0-9, '_' or '-'"
        )
    # Without signal handling iceoryx2 leaves SIGINT and SIGTERM to the Python program.
    node = (
        iox2.NodeBuilder.new()
        .name(iox2.NodeName.new(node_name))
        .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
        .create(iox2.ServiceType.Ipc)
    )
    service = _open(
        node,
        name,
        heartbeat_service(name),
        lambda b: b.publish_subscribe(Heartbeat),
        lambda: NotRunning(name),
    )
    subscriber = service.subscriber_builder().buffer_size(1).create()
    # A new subscriber is connected at ussd's next heartbeat.
    deadline = time.monotonic() + GONE_AFTER_NS / 1e9
    while True:
        sample = subscriber.receive()
        if sample is not None:
            beat = Heartbeat.from_buffer_copy(sample.payload().contents)
            if beat.version == LAYOUT_VERSION:
                break
        if time.monotonic() >= deadline:
            raise UssdGone(name, 0, GONE_AFTER_NS / 1e9)
        time.sleep(2e-3)
    bus = Bus(name, node, service, subscriber, beat)
    bus._current()
    return bus


def read_input(bus: Bus, address: int) -> dict:
    """The input image of drive ``address`` as ussd last wrote it, as a dict of its fields.

    ``words`` holds the PZD words in use (ZSW1 first); ``extra`` and ``reserved`` are left
    out. ``sequence`` counts good replies (0 = none yet); ``online`` is 1 while the drive
    answers, and 0 whenever ussd does not poll the bus (``health`` says why: "gone",
    "stopped", "line down"; the image is then the last one read); ``known`` is 0 until ussd's
    first poll decided ``online``. Time stamps are CLOCK_MONOTONIC ns. ``control`` is a :class:`ControlState`; while
    latched, ``latch_reason`` (:class:`LatchReason`) says why and ``latch_command``
    (:class:`StopCommand`) what the drive gets; ``sent_stw1`` is the control word that went out.
    """
    _check_address(address)
    health = bus.health()
    image = None
    if health.serving:
        try:
            image = bus._input_entry(address).get().decode_as(PzdInput)
            bus._services[("last", address)] = image
        except (UssdGone, UssdStopped):
            # The heartbeat aged past its limit between the two looks: ussd is gone now, and
            # the image says so like any other stale one.
            health = bus.health()
    if image is None:
        # The last image read, or an empty one: offline either way.
        image = bus._services.get(("last", address)) or PzdInput(version=LAYOUT_VERSION)
    if image.version != LAYOUT_VERSION:
        service = drive_in_service(bus.name, bus._generation, address)
        raise Incompatible(bus.name, service, f"version {image.version}")
    # A stale picture is never shown: ussd gone, stopped or its line down means offline.
    stale = health.error()
    count = min(image.word_count, MAX_PZD_WORDS)
    words = ([image.zsw1, image.hiw] + list(image.extra))[:count]
    return {
        "address": address,
        "online": 0 if stale is not None else image.online,
        "known": image.known,
        "health": health.state,
        "control": _code(ControlState, image.control),
        "latch_reason": _code(LatchReason, image.latch_reason),
        "latch_command": _code(StopCommand, image.latch_command),
        "latches": image.latches,
        "latched_since_ns": image.latched_since_ns,
        "latch_id": image.latch_id,
        "latched_by_pid": image.latched_by_pid,
        "rejection": _code(Rejection, image.rejection),
        "sent_stw1": image.sent_stw1,
        "sent_setpoint": image.sent_setpoint,
        "taken_sequence": image.taken_sequence,
        "sequence": image.sequence,
        "timestamp_ns": image.timestamp_ns,
        "age_ns": image.age_ns,
        "zsw1": image.zsw1,
        "hiw": image.hiw,
        "word_count": image.word_count,
        "words": words,
    }


def read_param(bus: Bus, address: int, pnu: int, index=None, timeout: float = 7.5) -> ParamValue:
    """Reads parameter ``pnu`` (or its array element ``index``) of drive ``address``.

    Returns a :class:`ParamValue`. Raises :class:`DriveError` (with the USS error number) when
    the drive refuses, :class:`ParamTimeout` when the drive does not answer in ussd's parameter
    timeout, :class:`NoAnswer` when ussd does not answer within ``timeout`` seconds,
    :class:`Refused` when ussd refuses the request, :class:`ParamFailed` otherwise.
    :func:`uss_rt.read` reads a parameter in the manuals' notation as its own type.
    """
    task = TaskCode.READ if index is None else TaskCode.READ_ARRAY
    return _request(bus, address, [_item(task, pnu, index or 0)], timeout)[0]


def _item(task, pnu: int, index: int = 0, value: int = 0, storage=Storage.RAM) -> ParamItem:
    """One item of a parameter request, its numbers checked."""
    if not 0 <= pnu <= 0xFFFF:
        raise ValueError(f"PNU {pnu} is out of range 0..=65535")
    if not 0 <= index <= MAX_SUBINDEX:
        raise ValueError(f"subindex {index} is out of range 0..=254 (USS.md section 6)")
    return ParamItem(task=task, storage=storage, pnu=pnu, index=index, value=value)


def _request(bus: Bus, address: int, items, timeout: float, force: bool = False):
    """Sends one request of ``items`` for drive ``address``; the value of each item, or the
    error of the first that failed."""
    _check_address(address)
    request = ParamRequest(
        version=LAYOUT_VERSION,
        address=address,
        count=len(items),
        flags=REQUEST_FORCE if force else 0,
    )
    for i, item in enumerate(items):
        request.items[i] = item
    response = _send(bus, request, timeout)
    if response.version != LAYOUT_VERSION:
        service = params_service(bus.name, bus._generation)
        raise Incompatible(bus.name, service, f"version {response.version}")
    if response.error != RequestError.OK:
        item = None if response.error_item == NO_ITEM else response.error_item
        raise _refused(bus, address, response.error, item)
    if response.address != address or response.count != len(items):
        raise UssError(
            f"ussd answered for drive {response.address} with {response.count} results a "
            f"request for drive {address} with {len(items)} items: check that ussd and this "
            "module are the same uss-rt version"
        )
    values = []
    for result in response.results[: len(items)]:
        if result.outcome == Outcome.REFUSED:
            raise _refused(bus, address, result.refusal, None)
        values.append(_value(result))
    return values


def _refused(bus: Bus, address: int, error: int, item) -> UssError:
    if error == RequestError.UNKNOWN_DRIVE:
        return UnknownDrive(bus.name, address, bus.drives())
    return Refused(error, item)


def stop_drive(bus: Bus, address: int, command=StopCommand.OFF1, timeout: float = 2.0):
    """Stops drive ``address`` with ``command`` (OFF1 ramp, OFF2 coast, OFF3 quick stop),
    whoever controls it: the drive gets it from its next poll on, latched until its controller
    re-arms it (OFF1, then ON). Returns once ussd has taken the command; :func:`wait_stopped`
    waits until it went out. Raises :class:`CommandRefused` (e.g. an unknown drive)."""
    _check_address(address)
    return _operator(bus, address, command, timeout)


def stop_all(bus: Bus, command=StopCommand.OFF1, timeout: float = 2.0):
    """Stops every drive of the bus with ``command``; returns their addresses."""
    return _operator(bus, ALL_DRIVES, command, timeout)


def wait_stopped(bus: Bus, address: int, command=StopCommand.OFF1, timeout: float = 3.0) -> dict:
    """Waits until drive ``address``'s image shows an operator's stop at least as strong as
    ``command`` and the control word that went out; returns that image (:func:`read_input`)."""
    strength = {StopCommand.NONE: 0, StopCommand.OFF1: 1, StopCommand.OFF3: 2, StopCommand.OFF2: 3}
    deadline = time.monotonic() + timeout
    while True:
        image = read_input(bus, address)
        got = image["latch_command"]
        if (
            image["latch_reason"] == LatchReason.OVERRIDE
            and strength.get(got, 0) >= strength[StopCommand(command)]
            and STOP_STW1.get(got) == image["sent_stw1"]
        ):
            return image
        if time.monotonic() >= deadline:
            raise UssError(
                f"drive {address} on {bus.name} does not show {StopCommand(command).name} "
                f"after {timeout} s: check `ussctl status`"
            )
        time.sleep(1e-3)


def _operator(bus: Bus, address: int, command, timeout: float):
    command = StopCommand(command)
    if command == StopCommand.NONE:
        raise ValueError("a stop command is OFF1, OFF2 or OFF3")
    request = OperatorRequest(version=LAYOUT_VERSION, address=address, command=command)
    response = _round_trip(bus, bus._commands(), request, timeout)
    response = OperatorResponse.from_buffer_copy(response)
    if response.version != LAYOUT_VERSION:
        service = command_service(bus.name, bus._generation)
        raise Incompatible(bus.name, service, f"version {response.version}")
    if response.error != CommandError.OK:
        if response.error == CommandError.UNKNOWN_DRIVE:
            raise UnknownDrive(bus.name, address, bus.drives())
        raise CommandRefused(bus.name, response.error)
    return [a for a in range(MAX_ADDRESS + 1) if response.drives & (1 << a)]


def _send(bus: Bus, request: ParamRequest, timeout: float) -> ParamResponse:
    """Sends ``request`` and waits for ussd's one response."""
    return ParamResponse.from_buffer_copy(_round_trip(bus, bus._params(), request, timeout))


def _round_trip(bus: Bus, client, request, timeout: float):
    """Sends ``request`` through ``client`` and returns the bytes of ussd's one answer (the
    wait for a free request slot counts into ``timeout``)."""
    deadline = time.monotonic() + timeout
    if not bus._request_slots.acquire(timeout=timeout):
        raise NoAnswer(bus.name, f"did not answer within {timeout} s (all request slots busy)")
    try:
        pending = client.send_copy(request)
        requests, answers = bus._services.get("events", (None, None))
        if requests is not None:
            try:
                requests[1].notify()
            except Exception:  # noqa: BLE001, S110 - ussd polls for requests anyway
                pass
        return _answer(bus, pending, deadline, timeout, answers and answers[1])
    finally:
        bus._request_slots.release()


def _answer(bus: Bus, pending, deadline: float, timeout: float, answers=None):
    """Waits until ``deadline`` for the answer to ``pending``, woken by ussd's ``answers``
    events where the listener ``answers`` is given."""
    if pending.number_of_server_connections == 0:
        raise NotRunning(bus.name)
    pause = 50e-6
    while True:
        # Looked at before `receive`, so an answer sent just before ussd let go of the request
        # is still received.
        connected = pending.is_connected
        response = pending.receive()
        if response is not None:
            return bytes(response.payload().contents)
        if not connected:
            raise NoAnswer(bus.name, "dropped the request without answering")
        left = deadline - time.monotonic()
        if left <= 0:
            raise NoAnswer(bus.name, f"did not answer within {timeout} s")
        if answers is not None:
            # Woken by any answer of ussd (then looked again), at least every 2 ms.
            try:
                answers.timed_wait(iox2.Duration.from_secs_f64(min(left, 2e-3)))
                continue
            except Exception:  # noqa: BLE001 - poll instead
                answers = None
        # No events: poll, backing off to 2 ms.
        time.sleep(min(pause, left))
        pause = min(pause * 2, 2e-3)


def _value(result: ParamResult) -> ParamValue:
    outcome = result.outcome
    if outcome in (Outcome.VALUE, Outcome.DESCRIPTION):
        dword = result.value_is_dword != 0
        return ParamValue(result.value if dword else result.value & 0xFFFF, dword)
    if outcome == Outcome.ELEMENT_COUNT:
        return ParamValue(result.value & 0xFFFF, False)
    if outcome == Outcome.DRIVE_ERROR:
        raise DriveError(result.drive_error)
    if outcome == Outcome.TIMEOUT:
        raise ParamTimeout()
    raise ParamFailed(outcome)


# Parameters in the manuals' notation and exclusive control (drive.py uses the names above).
from .drive import (  # noqa: E402
    Controlled,
    Controller,
    Tripped,
    Value,
    control,
    fault_text,
    parse_param,
    read,
    warning_text,
    write,
)
