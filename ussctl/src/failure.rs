//! Why ussctl ends early: one variant per kind of failure, each saying what to do. All exit 1
//! (clap's usage errors exit 2), except a closed output, which ends quietly.

use core::time::Duration;
use uss_client::{Address, ClientError, Latch, ParamError, StopCommand};

#[derive(Debug, thiserror::Error)]
pub(crate) enum Failure {
    /// The bus or ussd (not running, gone, stopped, line down), or a refusal of the client API.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// The same, while running one drive (ussd gone, stopped, line down).
    #[error("drive {drive}: {source}")]
    OfDrive { drive: Address, source: ClientError },
    /// A parameter access of a drive; `param` as the manuals write it, e.g. `P1082`.
    #[error("drive {drive} {param}: {source}")]
    Param {
        drive: Address,
        param: String,
        source: ParamError,
    },
    /// A write the drive refused, with what to do (`Bus::refusal_hint`: the access level, quick
    /// commissioning, the limits).
    #[error("drive {drive} {param}: {source}: {hint}")]
    Refused {
        drive: Address,
        param: String,
        source: Box<ParamError>,
        hint: String,
    },
    /// A write whose task reached the drive but whose answer did not come back: the value
    /// may be applied; says how to check.
    #[error("drive {drive} {param}: {source}: `{check}`")]
    MaybeApplied {
        drive: Address,
        param: String,
        source: Box<ParamError>,
        /// The command that reads it back (on its bus).
        check: String,
    },
    /// A value that does not fit the parameter, refused before the bus.
    #[error("drive {drive} {source}")]
    Value { drive: Address, source: ParamError },
    /// An operator's stop went to ussd but the drive's image does not show it yet.
    #[error("drive {drive}: {command} sent, not yet confirmed: {source}")]
    StopUnconfirmed {
        drive: Address,
        command: StopCommand,
        source: ClientError,
    },
    #[error(
        "drive {drive} on {bus} is offline: check `ussctl status`, its wiring, address and baud rate"
    )]
    Offline { drive: Address, bus: String },
    #[error(
        "drive {drive} went offline while running and did not come back within {} s: check `ussctl status`, its wiring and power",
        .grace.as_secs()
    )]
    WentOffline { drive: Address, grace: Duration },
    #[error(
        "drive {drive} is in fault (ZSW1 {zsw1:#06X}): see `ussctl faults {drive}`, then acknowledge with `ussctl ack {drive}`"
    )]
    Faulted { drive: Address, zsw1: u16 },
    #[error(
        "drive {drive}: the fault is still active after the acknowledge, so its cause persists: see `ussctl faults {drive}`"
    )]
    FaultPersists { drive: Address },
    /// ussd latched the drive while `run` ran it: it gets its stop command until re-armed.
    #[error(
        "drive {drive} on {bus} tripped after {:.2} s: {latch} ({:.2} s ago); it gets {}, latched: run `ussctl run {drive}` again to re-arm it (OFF1, then ON)",
        .after.as_secs_f64(), .latch.ago.as_secs_f64(), .latch.command_name()
    )]
    Tripped {
        drive: Address,
        bus: String,
        after: Duration,
        latch: Latch,
    },
    /// A backup file that cannot be read or written.
    #[error("{path}: {source}")]
    File {
        path: String,
        source: std::io::Error,
    },
    /// A backup file that fails its checks: nothing was written.
    #[error("{0}; nothing was written")]
    Backup(#[from] uss_client::backup::FileError),
    /// A scan's line (missing, busy, not a tty, failed).
    #[error(transparent)]
    Scan(#[from] uss_client::scan::ScanError),
    /// A restore that did not write everything (refused values, or cut short): the report says
    /// which; running it again completes what can be.
    #[error("drive {drive}: the restore is incomplete (see above); run it again to complete it")]
    Incomplete { drive: Address },
    /// `param diff` found differences (listed above): a script sees them in the exit status.
    #[error("drive {drive}: {differ} value{} differ{} (see above)", if *.differ == 1 { "" } else { "s" }, if *.differ == 1 { "s" } else { "" })]
    Differ { drive: Address, differ: usize },
    /// A backup or restore of a drive whose family has no parameter catalogue in uss-rt, or a
    /// restore of another family's backup.
    #[error("drive {drive}: {problem}")]
    Family { drive: Address, problem: String },
    /// A restore that would change guarded parameters, without `--unsafe`: nothing written.
    #[error(
        "drive {drive}: the backup changes {params}, which can take the drive away from ussd ({why}); nothing was written: restore with --unsafe if it is deliberate"
    )]
    Guarded {
        drive: Address,
        params: String,
        why: String,
    },
    /// A value on the command line that clap cannot check by itself.
    #[error("{0}")]
    Usage(String),
    /// The drive latched after this ussctl was started (or within the 10 ms before, which the
    /// kernel's start time cannot tell apart): its re-arm clears only an older latch.
    #[error(
        "drive {drive} on {bus} was stopped while this ussctl started ({latch}): `ussctl {command}` re-arms only a stop older than itself (its start is known to 10 ms), so it re-armed nothing; run it again if the stop is over"
    )]
    StoppedWhileStarting {
        /// The command that would have re-armed the drive (`run`, `ack`).
        command: &'static str,
        drive: Address,
        bus: String,
        latch: Latch,
    },
    /// When this ussctl started, which a re-arm carries, cannot be read.
    #[error("cannot tell when this ussctl started (/proc/self/stat): {0}; nothing was re-armed")]
    StartTime(std::io::Error),
    #[error("cannot install a handler of signal {signal}: {source}")]
    Signal { signal: i32, source: std::io::Error },
    #[error("cannot write JSON: {0}")]
    Json(#[from] serde_json::Error),
    #[error("no --json report is called {report:?}: {known}")]
    NoSchema { report: String, known: String },
    #[error("cannot write the output: {0}")]
    Output(std::io::Error),
    /// The trace's CSV cannot be written.
    #[error("cannot write the CSV: {0}")]
    Csv(csv::Error),
    /// The trace's plot cannot be rendered or written.
    #[error("{path}: cannot plot: {reason}")]
    Plot { path: String, reason: String },
    /// Neither the trigger fired nor was anything recorded.
    #[error("the trigger {trigger} {why}; nothing was written")]
    NotTriggered { trigger: String, why: String },
    /// Whoever reads our output went away (`ussctl watch | head`): end quietly.
    #[error("the output was closed")]
    Closed,
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_client::{LatchReason, Rejection};

    #[test]
    fn each_failure_says_what_happened_and_what_to_do() {
        let latch = Latch {
            reason: LatchReason::Stale,
            command: Some(StopCommand::Off1),
            rejection: Rejection::None,
            by_pid: 0,
            ago: Duration::from_millis(250),
        };
        let tripped = Failure::Tripped {
            drive: Address::new(2).unwrap(),
            bus: "line1".into(),
            after: Duration::from_millis(1500),
            latch,
        };
        assert!(
            tripped.to_string().starts_with(&format!(
                "drive 2 on line1 tripped after 1.50 s: {latch} (0.25 s ago); it gets OFF1, latched: run `ussctl run 2` again"
            )),
            "{tripped}"
        );
        let fault = Failure::Faulted {
            drive: Address::new(3).unwrap(),
            zsw1: 0xFB38,
        };
        assert_eq!(
            fault.to_string(),
            "drive 3 is in fault (ZSW1 0xFB38): see `ussctl faults 3`, then acknowledge with `ussctl ack 3`"
        );
        let gone = Failure::WentOffline {
            drive: Address::new(1).unwrap(),
            grace: Duration::from_secs(3),
        };
        assert!(gone.to_string().contains("did not come back within 3 s"));
    }
}
