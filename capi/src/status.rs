//! The C ABI's status codes, generated from the one code table
//! (`uss_client::kinds::Status`) by `UPDATE_GENERATED=1 cargo test -p uss-client --test generated`: do not edit.

use core::ffi::CStr;
use uss_client::kinds::Status;

/// What a call came to. `USSRT_STATUS_OK` is 0; every other code has a message
/// (`ussrt_last_error`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UssrtStatus {
    /// Success.
    Ok = 0,
    /// A NULL pointer, a bus name or address that cannot exist, a parameter that is not
    /// written the manuals' way, a value of another type.
    InvalidArgument = 1,
    /// No ussd serves this bus.
    NotRunning = 2,
    /// ussd does not poll this drive.
    UnknownDrive = 3,
    /// ussd's heartbeat stopped: it died or hangs. Images are stale.
    UssdGone = 4,
    /// ussd stopped cleanly.
    UssdStopped = 5,
    /// ussd runs, but the bus line is down.
    LineDown = 6,
    /// Another process controls the drive.
    Controlled = 7,
    /// The drive latched since this controller last acknowledged a latch: re-arm it
    /// (`UssrtErrorInfo` says why).
    Tripped = 8,
    /// An ON for a latched drive this controller has not re-armed: `ussrt_control_rearm_at` first.
    NotArmed = 9,
    /// This program made no call for longer than the drive's watchdog time: a trip; re-arm.
    Stalled = 10,
    /// Words ussd would refuse (word count, STW1 bit 10): nothing was sent.
    InvalidSample = 11,
    /// This controller released the drive.
    Released = 12,
    /// A wait, a parameter task or ussd's answer did not end in time.
    Timeout = 13,
    /// The drive refused the parameter task (`UssrtErrorInfo::drive_error`: its number).
    DriveError = 14,
    /// ussd refused the request before the bus (write protection, a controlled drive, ...).
    Refused = 15,
    /// The task did not reach the drive or its answer did not come back (offline, line down,
    /// shutdown, cancelled).
    PathFailed = 16,
    /// A value that does not fit the parameter, refused before the bus.
    Value = 17,
    /// The drive exchanges no process data (pzd = 0).
    NoProcessData = 18,
    /// ussd speaks another layout version.
    Incompatible = 19,
    /// The shared memory failed otherwise (permissions, resources).
    Ipc = 20,
    /// A defect in this library (a caught panic); the message says where.
    Internal = 21,
    /// The drive does not take its commands from this link (ZSW1 bit 9 = 0): a stop ussd sent
    /// is not obeyed.
    NotControllable = 22,
    /// An ON that waited for ussd to take the re-arm was dropped: a stop of this program
    /// (another thread's call) came meanwhile.
    Superseded = 23,
    /// A parameter write reached the drive but its answer did not come back (timeout, offline,
    /// line down, ussd shut down): the drive may hold the new value, or not; read it back.
    MaybeApplied = 24,
    /// A setpoint in Hz, while ussd reads the drive's reference frequency (again: it came
    /// online, was reset or commissioned): nothing was sent; wait for it, or give percent.
    ReferenceUnknown = 25,
    /// The serial device of a line ussd does not serve cannot be used (a scan): missing, busy,
    /// not a tty, no permission, or it failed.
    Device = 26,
}

impl UssrtStatus {
    /// Every status, in code order.
    pub(crate) const ALL: [Self; 27] = [
        Self::Ok,
        Self::InvalidArgument,
        Self::NotRunning,
        Self::UnknownDrive,
        Self::UssdGone,
        Self::UssdStopped,
        Self::LineDown,
        Self::Controlled,
        Self::Tripped,
        Self::NotArmed,
        Self::Stalled,
        Self::InvalidSample,
        Self::Released,
        Self::Timeout,
        Self::DriveError,
        Self::Refused,
        Self::PathFailed,
        Self::Value,
        Self::NoProcessData,
        Self::Incompatible,
        Self::Ipc,
        Self::Internal,
        Self::NotControllable,
        Self::Superseded,
        Self::MaybeApplied,
        Self::ReferenceUnknown,
        Self::Device,
    ];

    /// The code of the table's `status`.
    pub(crate) const fn of(status: Status) -> Self {
        match status {
            Status::Ok => Self::Ok,
            Status::InvalidArgument => Self::InvalidArgument,
            Status::NotRunning => Self::NotRunning,
            Status::UnknownDrive => Self::UnknownDrive,
            Status::UssdGone => Self::UssdGone,
            Status::UssdStopped => Self::UssdStopped,
            Status::LineDown => Self::LineDown,
            Status::Controlled => Self::Controlled,
            Status::Tripped => Self::Tripped,
            Status::NotArmed => Self::NotArmed,
            Status::Stalled => Self::Stalled,
            Status::InvalidSample => Self::InvalidSample,
            Status::Released => Self::Released,
            Status::Timeout => Self::Timeout,
            Status::DriveError => Self::DriveError,
            Status::Refused => Self::Refused,
            Status::PathFailed => Self::PathFailed,
            Status::Value => Self::Value,
            Status::NoProcessData => Self::NoProcessData,
            Status::Incompatible => Self::Incompatible,
            Status::Ipc => Self::Ipc,
            Status::Internal => Self::Internal,
            Status::NotControllable => Self::NotControllable,
            Status::Superseded => Self::Superseded,
            Status::MaybeApplied => Self::MaybeApplied,
            Status::ReferenceUnknown => Self::ReferenceUnknown,
            Status::Device => Self::Device,
        }
    }

    /// Its name in snake case, for logs: the same word as the table's.
    pub(crate) const fn name(self) -> &'static CStr {
        match self {
            Self::Ok => c"ok",
            Self::InvalidArgument => c"invalid_argument",
            Self::NotRunning => c"not_running",
            Self::UnknownDrive => c"unknown_drive",
            Self::UssdGone => c"ussd_gone",
            Self::UssdStopped => c"ussd_stopped",
            Self::LineDown => c"line_down",
            Self::Controlled => c"controlled",
            Self::Tripped => c"tripped",
            Self::NotArmed => c"not_armed",
            Self::Stalled => c"stalled",
            Self::InvalidSample => c"invalid_sample",
            Self::Released => c"released",
            Self::Timeout => c"timeout",
            Self::DriveError => c"drive_error",
            Self::Refused => c"refused",
            Self::PathFailed => c"path_failed",
            Self::Value => c"value",
            Self::NoProcessData => c"no_process_data",
            Self::Incompatible => c"incompatible",
            Self::Ipc => c"ipc",
            Self::Internal => c"internal",
            Self::NotControllable => c"not_controllable",
            Self::Superseded => c"superseded",
            Self::MaybeApplied => c"maybe_applied",
            Self::ReferenceUnknown => c"reference_unknown",
            Self::Device => c"device",
        }
    }
}
