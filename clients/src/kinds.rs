//! The one code table of what a client call can end with. Every front-end speaks it:
//!
//! - [`Status`] is the C ABI's `UssrtStatus` (`capi/src/status.rs` is generated from it);
//! - [`ErrorKind`] is the Python exception raised (`python/uss_rt/_errors.py` is generated from
//!   it), each with its [`Status`];
//! - [`ClientError::kind`] and [`ParamError::kind`] name the kind of every error, with no
//!   catch-all: a new error must be given its kind here.
//!
//! The messages themselves are the errors' `Display` text, in every language. After changing
//! the table, regenerate both files with `UPDATE_GENERATED=1 cargo test -p uss-client --test
//! generated`; the test fails while either file says anything else.

use crate::error::{ClientError, ParamError};
use uss_shm_types::{ContractError, DriveError, PathError};

macro_rules! statuses {
    ($( $(#[doc = $doc:literal])+ $name:ident = $code:literal, $snake:literal; )+) => {
        /// A status code of the C ABI: 0 is success, every other code is a kind of failure.
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum Status {
            $( $(#[doc = $doc])+ $name = $code, )+
        }

        impl Status {
            /// Every status, in code order.
            pub const ALL: &[Self] = &[$(Self::$name),+];

            /// Its number in the C ABI.
            pub const fn code(self) -> u8 {
                self as u8
            }

            /// Its name in CamelCase, as the C enum's variant (`NotArmed`).
            pub const fn name(self) -> &'static str {
                match self { $(Self::$name => stringify!($name)),+ }
            }

            /// Its name in snake case, for logs (`not_armed`).
            pub const fn snake(self) -> &'static str {
                match self { $(Self::$name => $snake),+ }
            }

            /// What it means, one line per line of its description.
            pub const fn doc(self) -> &'static [&'static str] {
                match self { $(Self::$name => &[$($doc),+]),+ }
            }
        }
    };
}

statuses! {
    /// Success.
    Ok = 0, "ok";
    /// A NULL pointer, a bus name or address that cannot exist, a parameter that is not
    /// written the manuals' way, a value of another type.
    InvalidArgument = 1, "invalid_argument";
    /// No ussd serves this bus.
    NotRunning = 2, "not_running";
    /// ussd does not poll this drive.
    UnknownDrive = 3, "unknown_drive";
    /// ussd's heartbeat stopped: it died or hangs. Images are stale.
    UssdGone = 4, "ussd_gone";
    /// ussd stopped cleanly.
    UssdStopped = 5, "ussd_stopped";
    /// ussd runs, but the bus line is down.
    LineDown = 6, "line_down";
    /// Another process controls the drive.
    Controlled = 7, "controlled";
    /// The drive latched since this controller last acknowledged a latch: re-arm it
    /// (`UssrtErrorInfo` says why).
    Tripped = 8, "tripped";
    /// An ON for a latched drive this controller has not re-armed: `ussrt_control_rearm_at` first.
    NotArmed = 9, "not_armed";
    /// This program made no call for longer than the drive's watchdog time: a trip; re-arm.
    Stalled = 10, "stalled";
    /// Words ussd would refuse (word count, STW1 bit 10): nothing was sent.
    InvalidSample = 11, "invalid_sample";
    /// This controller released the drive.
    Released = 12, "released";
    /// A wait, a parameter task or ussd's answer did not end in time.
    Timeout = 13, "timeout";
    /// The drive refused the parameter task (`UssrtErrorInfo::drive_error`: its number).
    DriveError = 14, "drive_error";
    /// ussd refused the request before the bus (write protection, a controlled drive, ...).
    Refused = 15, "refused";
    /// The task did not reach the drive or its answer did not come back (offline, line down,
    /// shutdown, cancelled).
    PathFailed = 16, "path_failed";
    /// A value that does not fit the parameter, refused before the bus.
    Value = 17, "value";
    /// The drive exchanges no process data (pzd = 0).
    NoProcessData = 18, "no_process_data";
    /// ussd speaks another layout version.
    Incompatible = 19, "incompatible";
    /// The shared memory failed otherwise (permissions, resources).
    Ipc = 20, "ipc";
    /// A defect in this library (a caught panic); the message says where.
    Internal = 21, "internal";
    /// The drive does not take its commands from this link (ZSW1 bit 9 = 0): a stop ussd sent
    /// is not obeyed.
    NotControllable = 22, "not_controllable";
    /// An ON that waited for ussd to take the re-arm was dropped: a stop of this program
    /// (another thread's call) came meanwhile.
    Superseded = 23, "superseded";
    /// A parameter write reached the drive but its answer did not come back (timeout, offline,
    /// line down, ussd shut down): the drive may hold the new value, or not; read it back.
    MaybeApplied = 24, "maybe_applied";
    /// A setpoint in Hz, while ussd reads the drive's reference frequency (again: it came
    /// online, was reset or commissioned): nothing was sent; wait for it, or give percent.
    ReferenceUnknown = 25, "reference_unknown";
    /// The serial device of a line ussd does not serve cannot be used (a scan): missing, busy,
    /// not a tty, no permission, or it failed.
    Device = 26, "device";
}

macro_rules! kinds {
    ($( $(#[doc = $doc:literal])+ $kind:ident => $status:ident, $class:literal ($base:literal); )+) => {
        /// A kind of failure, as finely as a script tells them apart: Python's exception
        /// classes, each with the C status it is.
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum ErrorKind {
            $( $(#[doc = $doc])+ $kind, )+
        }

        impl ErrorKind {
            /// Every kind, in table order.
            pub const ALL: &[Self] = &[$(Self::$kind),+];

            /// The C ABI's status of this kind.
            pub const fn status(self) -> Status {
                match self { $(Self::$kind => Status::$status),+ }
            }

            /// The Python exception class raised for it (`ValueError`: Python's own; empty:
            /// none, Python has its own).
            pub const fn python_class(self) -> &'static str {
                match self { $(Self::$kind => $class),+ }
            }

            /// The class it derives from (`UssError`, another class of this table, or, after
            /// a comma, a Python built-in too: `UssError, TimeoutError`).
            pub const fn python_base(self) -> &'static str {
                match self { $(Self::$kind => $base),+ }
            }

            /// What it means, one line per line of its description.
            pub const fn doc(self) -> &'static [&'static str] {
                match self { $(Self::$kind => &[$($doc),+]),+ }
            }
        }
    };
}

kinds! {
    /// An argument that cannot be right: a bus name or address that cannot exist, a NULL
    /// pointer, words of the wrong count.
    InvalidArgument => InvalidArgument, "ValueError"("");
    /// ussd's services for the bus do not exist.
    NotRunning => NotRunning, "NotRunning"("UssError");
    /// ussd runs the bus, but does not poll this drive.
    UnknownDrive => UnknownDrive, "UnknownDrive"("UssError");
    /// No heartbeat from ussd for 0.5 s: it died or hangs.
    UssdGone => UssdGone, "UssdGone"("UssError");
    /// ussd said it stops (a clean exit).
    UssdStopped => UssdStopped, "UssdStopped"("UssError");
    /// ussd runs, but the bus line is down.
    LineDown => LineDown, "LineDown"("UssError");
    /// The drive already has a controller (another process, or another controller here).
    Controlled => Controlled, "Controlled"("UssError");
    /// ussd latched the drive since this controller last acknowledged a latch (stale
    /// controller, rejected sample, operator stop, restart): it gets its stop command until
    /// re-armed. `reason` is a `LatchReason`, `command` a `StopCommand`, `by_pid` the
    /// process behind it.
    Tripped => Tripped, "Tripped"("UssError");
    /// An ON for a latched drive this controller has not re-armed: re-arm it first.
    NotArmed => NotArmed, "NotArmed"("Tripped");
    /// This program made no call for longer than the drive's watchdog time (it was paused,
    /// its loop blocked): a trip, not a fresh start. Re-arm it.
    Stalled => Stalled, "Stalled"("Tripped");
    /// Words ussd would refuse (their count, STW1 bit 10): nothing was sent.
    InvalidSample => InvalidSample, "ValueError"("");
    /// This controller released the drive: take control again.
    Released => Released, "Released"("UssError");
    /// The drive gave no matching reply within ussd's parameter timeout.
    ParamTimeout => Timeout, "ParamTimeout"("UssError, TimeoutError");
    /// ussd did not answer the request in time, or dropped it (it stopped).
    NoAnswer => Timeout, "NoAnswer"("UssError, TimeoutError");
    /// ussd dropped the request without answering (it stopped): the C ABI calls it a failed
    /// path.
    Dropped => PathFailed, "NoAnswer"("UssError, TimeoutError");
    /// A drive did not get where it was asked to in time, or its inputs stopped coming.
    WaitTimeout => Timeout, "WaitTimeout"("UssError, TimeoutError");
    /// The drive refused the task (reply 7) with USS error `number`; `hint` says what to do
    /// where the number and the family's catalogue tell it (the access level, quick
    /// commissioning, the limits), else None.
    DriveError => DriveError, "DriveError"("UssError");
    /// ussd refused the request (or one item) before the bus; `error` is a `RequestError`.
    Refused => Refused, "Refused"("UssError");
    /// ussd refused an operator stop command; `error` is a `CommandError`.
    CommandRefused => Refused, "CommandRefused"("UssError");
    /// An item ended without a value for another reason; `outcome` is an `Outcome`.
    ParamFailed => PathFailed, "ParamFailed"("UssError");
    /// The drive grants no parameter change rights over this link (reply 8).
    NoChangeRights => DriveError, "ParamFailed"("UssError");
    /// A value that does not fit the parameter, refused before the bus.
    Value => Value, "ValueError"("");
    /// The drive exchanges no process data (pzd = 0): there is nothing to control.
    NoProcessData => NoProcessData, "NoProcessData"("UssError");
    /// ussd speaks another layout of the payload types.
    Incompatible => Incompatible, "Incompatible"("UssError");
    /// The shared memory failed otherwise (permissions, resources).
    Ipc => Ipc, "IpcFailed"("UssError");
    /// A defect in the C library (a caught panic); Python raises its own `PanicException`.
    Internal => Internal, ""("");
    /// ussd sent a command, but the drive does not take its commands from this link (ZSW1 bit
    /// 9 = 0: its command source is elsewhere); it ignores it, stops included.
    NotControllable => NotControllable, "NotControllable"("UssError");
    /// An ON that waited for ussd to take the re-arm was dropped: a stop of this program
    /// (another thread's call) came meanwhile, and the drive keeps it.
    Superseded => Superseded, "Superseded"("UssError");
    /// A write reached the drive (`telegrams` telegrams carried it) but its answer did not
    /// come back (`outcome`): the drive may hold the new value, or not. Read it back.
    MaybeApplied => MaybeApplied, "MaybeApplied"("ParamFailed");
    /// A setpoint in Hz while ussd reads the drive's reference frequency again (it came
    /// online, was reset or commissioned): nothing was sent; wait, or give percent.
    ReferenceUnknown => ReferenceUnknown, "ReferenceUnknown"("UssError");
    /// A serial device a scan cannot use (missing, busy, not a tty, no permission) or that
    /// failed while it ran.
    Device => Device, "DeviceError"("UssError, OSError");
}

impl ClientError {
    /// The kind of this error (its C status, its Python exception).
    pub const fn kind(&self) -> ErrorKind {
        use ErrorKind as K;
        match self {
            // The caller's argument: a name, an address, a setpoint beyond the word.
            Self::Name(_) | Self::Address(_) | Self::InvalidSetpoint { .. } => K::InvalidArgument,
            Self::NotRunning { .. } => K::NotRunning,
            Self::UnknownDrive { .. } => K::UnknownDrive,
            Self::Controlled { .. } => K::Controlled,
            Self::Incompatible { .. }
            | Self::Contract(ContractError::Version { .. } | ContractError::Code(_)) => {
                K::Incompatible
            }
            Self::Access { .. } | Self::Ipc { .. } => K::Ipc,
            Self::UssdGone { .. } => K::UssdGone,
            Self::UssdStopped { .. } => K::UssdStopped,
            Self::LineDown { .. } => K::LineDown,
            Self::Stale { .. } | Self::WaitTimeout { .. } => K::WaitTimeout,
            Self::Tripped { .. } | Self::NotTheLatch { .. } => K::Tripped,
            Self::NotArmed { .. } => K::NotArmed,
            Self::Stalled { .. } => K::Stalled,
            Self::Released { .. } => K::Released,
            // Too many words for a drive is the caller's sample, not another layout.
            Self::InvalidSample { .. }
            | Self::PzdWords { .. }
            | Self::Contract(ContractError::PzdWords(_)) => K::InvalidSample,
            Self::NoProcessData { .. } => K::NoProcessData,
            Self::CommandRefused { .. } => K::CommandRefused,
            Self::NotControllable { .. } => K::NotControllable,
            Self::Superseded { .. } => K::Superseded,
            Self::ReferenceUnknown { .. } => K::ReferenceUnknown,
        }
    }
}

impl ParamError {
    /// The kind of this error (its C status, its Python exception).
    pub const fn kind(&self) -> ErrorKind {
        use ErrorKind as K;
        match self {
            Self::Drive(DriveError::Refused(_)) => K::DriveError,
            Self::Path(PathError::Timeout) => K::ParamTimeout,
            Self::Path(PathError::Refused(_))
            | Self::Refused { .. }
            | Self::Controlled { .. }
            | Self::Guarded { .. }
            | Self::NotOnFamily { .. } => K::Refused,
            Self::Drive(DriveError::NoChangeRights) => K::NoChangeRights,
            Self::Path(_) => K::ParamFailed,
            Self::MaybeApplied { .. } => K::MaybeApplied,
            Self::NoAnswer(_) => K::NoAnswer,
            Self::Dropped => K::Dropped,
            Self::Value { .. } => K::Value,
            Self::Client(c) => c.kind(),
            Self::Unexpected(_) => K::Incompatible,
        }
    }
}

#[cfg(feature = "scan")]
impl crate::scan::ScanError {
    /// The kind of this error (its C status, its Python exception).
    pub const fn kind(&self) -> ErrorKind {
        use crate::scan::ScanError as E;
        match self {
            E::Busy(_) | E::NotATty(_) | E::Open(_) | E::Line(_) => ErrorKind::Device,
            E::Options(_) => ErrorKind::InvalidArgument,
            E::Telegram(_) => ErrorKind::Internal,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn too_many_words_are_the_callers_sample_and_another_layout_is_incompatible() {
        let words = ClientError::Contract(ContractError::PzdWords(17));
        assert_eq!(words.kind(), ErrorKind::InvalidSample);
        assert_eq!(words.kind().status(), Status::InvalidSample);
        let layout = ClientError::Contract(ContractError::Version {
            expected: 1,
            found: 2,
        });
        assert_eq!(layout.kind(), ErrorKind::Incompatible);
    }

    #[test]
    fn statuses_are_numbered_in_order_and_every_one_but_ok_is_some_kind() {
        for (code, status) in Status::ALL.iter().enumerate() {
            assert_eq!(usize::from(status.code()), code, "{status:?}");
        }
        for status in &Status::ALL[1..] {
            assert!(
                ErrorKind::ALL.iter().any(|k| k.status() == *status),
                "{status:?} is no kind's status"
            );
        }
    }

    #[test]
    fn a_python_base_is_a_class_defined_before_it_and_a_class_has_one_base() {
        for (i, kind) in ErrorKind::ALL.iter().enumerate() {
            let first = kind.python_base().split(", ").next().unwrap_or_default();
            assert!(
                first.is_empty()
                    || first == "UssError"
                    || ErrorKind::ALL[..i]
                        .iter()
                        .any(|k| k.python_class() == first),
                "{kind:?} derives from {first}, not defined before it"
            );
            for other in &ErrorKind::ALL[..i] {
                if other.python_class() == kind.python_class() {
                    assert_eq!(other.python_base(), kind.python_base(), "{kind:?}");
                }
            }
        }
    }
}
