"""The exceptions of uss_rt, generated from the Rust client's code table
(clients/src/kinds.rs) by `UPDATE_GENERATED=1 cargo test -p uss-client --test generated`: do not edit.

Every message is the Rust client's own text; what it is about is in attributes.
"""


class UssError(Exception):
    """Anything this module reports; the message says what to do."""

    def __init__(self, message: str = "", **details):
        super().__init__(message)
        self.__dict__.update(details)


class NotRunning(UssError):
    """ussd's services for the bus do not exist."""


class UnknownDrive(UssError):
    """ussd runs the bus, but does not poll this drive."""


class UssdGone(UssError):
    """No heartbeat from ussd for 0.5 s: it died or hangs."""


class UssdStopped(UssError):
    """ussd said it stops (a clean exit)."""


class LineDown(UssError):
    """ussd runs, but the bus line is down."""


class Controlled(UssError):
    """The drive already has a controller (another process, or another controller here)."""


class Tripped(UssError):
    """ussd latched the drive since this controller last acknowledged a latch (stale
    controller, rejected sample, operator stop, restart): it gets its stop command until
    re-armed. `reason` is a `LatchReason`, `command` a `StopCommand`, `by_pid` the
    process behind it."""


class NotArmed(Tripped):
    """An ON for a latched drive this controller has not re-armed: re-arm it first."""


class Stalled(Tripped):
    """This program made no call for longer than the drive's watchdog time (it was paused,
    its loop blocked): a trip, not a fresh start. Re-arm it."""


class Released(UssError):
    """This controller released the drive: take control again."""


class ParamTimeout(UssError, TimeoutError):
    """The drive gave no matching reply within ussd's parameter timeout."""


class NoAnswer(UssError, TimeoutError):
    """ussd did not answer the request in time, or dropped it (it stopped)."""


class WaitTimeout(UssError, TimeoutError):
    """A drive did not get where it was asked to in time, or its inputs stopped coming."""


class DriveError(UssError):
    """The drive refused the task (reply 7) with USS error `number`; `hint` says what to do
    where the number and the family's catalogue tell it (the access level, quick
    commissioning, the limits), else None."""


class Refused(UssError):
    """ussd refused the request (or one item) before the bus; `error` is a `RequestError`."""


class CommandRefused(UssError):
    """ussd refused an operator stop command; `error` is a `CommandError`."""


class ParamFailed(UssError):
    """An item ended without a value for another reason; `outcome` is an `Outcome`."""


class NoProcessData(UssError):
    """The drive exchanges no process data (pzd = 0): there is nothing to control."""


class Incompatible(UssError):
    """ussd speaks another layout of the payload types."""


class IpcFailed(UssError):
    """The shared memory failed otherwise (permissions, resources)."""


class NotControllable(UssError):
    """ussd sent a command, but the drive does not take its commands from this link (ZSW1 bit
    9 = 0: its command source is elsewhere); it ignores it, stops included."""


class Superseded(UssError):
    """An ON that waited for ussd to take the re-arm was dropped: a stop of this program
    (another thread's call) came meanwhile, and the drive keeps it."""


class MaybeApplied(ParamFailed):
    """A write reached the drive (`telegrams` telegrams carried it) but its answer did not
    come back (`outcome`): the drive may hold the new value, or not. Read it back."""


class ReferenceUnknown(UssError):
    """A setpoint in Hz while ussd reads the drive's reference frequency again (it came
    online, was reset or commissioned): nothing was sent; wait, or give percent."""


class DeviceError(UssError, OSError):
    """A serial device a scan cannot use (missing, busy, not a tty, no permission) or that
    failed while it ran."""


__all__ = [
    "UssError",
    "NotRunning",
    "UnknownDrive",
    "UssdGone",
    "UssdStopped",
    "LineDown",
    "Controlled",
    "Tripped",
    "NotArmed",
    "Stalled",
    "Released",
    "ParamTimeout",
    "NoAnswer",
    "WaitTimeout",
    "DriveError",
    "Refused",
    "CommandRefused",
    "ParamFailed",
    "NoProcessData",
    "Incompatible",
    "IpcFailed",
    "NotControllable",
    "Superseded",
    "MaybeApplied",
    "ReferenceUnknown",
    "DeviceError",
]
