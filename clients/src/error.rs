//! What can go wrong, and what to do about it. Every message ends with the next step.

use core::fmt;
use core::time::Duration;
use thiserror::Error;
use uss_shm_types::{
    CommandError, ContractError, DriveError, LatchReason, NameError, PathError, PzdInput,
    Rejection, RequestError, StopCommand,
};

/// Why and since when a drive is latched, as its input image says (see
/// `uss_shm_types::control`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Latch {
    pub reason: LatchReason,
    /// What the drive gets meanwhile (`None` only for an image that shows no latch).
    pub command: Option<StopCommand>,
    /// With [`LatchReason::Rejected`]: why the sample was refused.
    pub rejection: Rejection,
    /// The operator behind an override, or the controller whose sample caused the latch.
    pub by_pid: u32,
    /// How long ago the latch began.
    pub ago: Duration,
}

impl Latch {
    /// What the drive gets, for a message: `OFF1`, `OFF2`, `OFF3`.
    pub fn command_name(&self) -> &'static str {
        self.command.map_or("no stop command", StopCommand::name)
    }

    /// The latch an input image shows.
    pub fn of(input: &PzdInput) -> Self {
        let now = crate::link::monotonic_ns();
        Self {
            reason: LatchReason::try_from(input.latch_reason).unwrap_or(LatchReason::None),
            command: StopCommand::of_code(input.latch_command),
            rejection: Rejection::try_from(input.rejection).unwrap_or(Rejection::None),
            by_pid: input.latched_by_pid,
            ago: Duration::from_nanos(now.saturating_sub(input.latched_since_ns)),
        }
    }
}

impl fmt::Display for Latch {
    /// The cause in words: "its controller stopped publishing within the watchdog time".
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let pid = self.by_pid;
        match self.reason {
            LatchReason::None => f.write_str("not latched"),
            LatchReason::Startup => f.write_str("ussd started"),
            LatchReason::Stale => {
                f.write_str("its controller stopped publishing within the watchdog time")
            }
            LatchReason::Rejected => write!(f, "ussd refused a sample: {}", self.rejection),
            LatchReason::Released => write!(f, "its controller (process {pid}) released it"),
            LatchReason::Override => {
                write!(f, "an operator sent {} from process {pid}", self.command_name())
            }
            LatchReason::LineRestored => f.write_str("the bus line came back after it was down"),
            LatchReason::MonitoringOff => f.write_str(
                "an ON was refused: the drive's telegram monitoring is required but off or not verified",
            ),
            LatchReason::Paused => f.write_str(
                "ussd could not look for longer than the drive's watchdog time (paused, suspended or starved)",
            ),
            LatchReason::Replaced => write!(
                f,
                "its controller was replaced: process {pid} published while the drive ran under another controller, with no release in between (a killed controller's successor, or a restart loop)"
            ),
            LatchReason::ReferenceChanged => f.write_str(
                "the drive's reference frequency (P2000) changed while this controller held it (a reset, a commissioning, a power cycle): its setpoint was scaled with the old one; scale again and re-arm",
            ),
        }
    }
}

/// Opening a bus, reading drives, taking control.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum ClientError {
    /// A bus name that cannot exist.
    #[error(transparent)]
    Name(#[from] NameError),
    /// A drive address outside 0..=31.
    #[error(transparent)]
    Address(#[from] uss_protocol::AddressError),
    /// ussd's services for this bus do not exist; `served`: the buses ussd serves on this
    /// machine now (as far as this process may see them), which the message names.
    #[error("ussd is not running on {bus}{}", Served(.served))]
    NotRunning { bus: String, served: Vec<String> },
    /// ussd runs the bus, but not this drive.
    #[error("drive {address} is not on {bus} ({}): use one of those or add it to ussd's configuration", Known(.known))]
    UnknownDrive {
        bus: String,
        address: u8,
        /// The drives ussd polls on this bus.
        known: Vec<u8>,
    },
    /// Another controller holds the drive (one controller per drive, enforced by the service).
    #[error("drive {address} on {bus} is controlled by {}: only one controller per drive; stop that one first", Holder(*.pid, .node))]
    Controlled {
        bus: String,
        address: u8,
        /// The controlling process, if its node could be found.
        pid: Option<i32>,
        /// The controlling node's name, if known.
        node: Option<String>,
    },
    /// ussd was built against another `uss-shm-types` layout.
    #[error(
        "ussd on {bus} speaks another layout version ({service}): rebuild this program against the uss-shm-types of the running ussd"
    )]
    Incompatible { bus: String, service: String },
    /// This process may not use ussd's shared memory: its root directory is another user's
    /// (and group's, with `access_group`).
    #[error(
        "{} (ussd's shared memory) belongs to user {owner} and group {group}, mode {mode:04o}: this process may not use it: run ussd and this program as the same user (or root){}",
        root.display(),
        if mode & 0o070 == 0o070 { format!(", or as a member of group {group} (ussd's access_group)") } else { String::new() }
    )]
    Access {
        root: std::path::PathBuf,
        owner: String,
        group: String,
        mode: u32,
    },
    /// A payload breaks the contract.
    #[error(transparent)]
    Contract(#[from] ContractError),
    /// An iceoryx2 call failed for another reason.
    #[error("{what} failed: {detail}: {}", ipc_hint(detail))]
    Ipc { what: String, detail: String },
    /// No heartbeat from ussd for longer than `uss_shm_types::names::GONE_AFTER_NS`: it died
    /// or hangs. Images are stale (they show the drives offline). The bus reconnects by itself
    /// when a ussd serves it again.
    #[error(
        "ussd on {bus} is gone (no heartbeat for {:.2} s{}): the drives are not polled; only their own telegram monitoring stops them. If its process is gone, restart ussd (systemctl restart ussd); a paused or starved one goes on by itself",
        silent_for.as_secs_f64(), Pid(*.pid)
    )]
    UssdGone {
        bus: String,
        /// The process of its last heartbeat (0 if none was seen).
        pid: u32,
        silent_for: Duration,
    },
    /// ussd said it stops (a clean exit, e.g. SIGTERM): every drive got its safe command once.
    #[error(
        "ussd on {bus} stopped {:.2} s ago{}: start it again (`ussd`); this program reconnects by itself",
        ago.as_secs_f64(), Pid(*.pid)
    )]
    UssdStopped {
        bus: String,
        pid: u32,
        ago: Duration,
    },
    /// ussd runs, but the bus line is down: nothing reaches the drives until it reopens.
    #[error(
        "bus {bus}: line down ({fault}) for {:.2} s: ussd reopens the device; check the adapter and cable",
        down_for.as_secs_f64()
    )]
    LineDown {
        bus: String,
        /// Why, in words.
        fault: String,
        down_for: Duration,
    },
    /// ussd stopped updating the drive's input image (it stopped, or the drive is gone).
    #[error(
        "ussd did not update the inputs of drive {address} on {bus} for {timeout:?}: check that ussd still runs (`ussctl status`)"
    )]
    Stale {
        bus: String,
        address: u8,
        timeout: Duration,
    },
    /// The drive latched since this controller last looked: a trip (it stopped publishing in
    /// time, ussd refused a sample), an operator's stop, the line coming back, ussd's start. Every
    /// ON fails so until [`crate::Controller::rearm`] acknowledges it (a stop goes out).
    #[error(
        "drive {address} on {bus} latched {:.2} s ago: {latch}; it gets {} until its controller re-arms it (OFF1, then ON: Controller::rearm)",
        latch.ago.as_secs_f64(), latch.command_name()
    )]
    Tripped {
        bus: String,
        address: u8,
        latch: Latch,
    },
    /// An ON for a latched drive this controller has not re-armed (a relay's remote did not name
    /// the latch; ussd did not take a re-arm within the drive's handshake time).
    #[error(
        "drive {address} on {bus} is latched ({latch}, {:.2} s ago) and gets {}: re-arm it (Controller::rearm), then ON",
        latch.ago.as_secs_f64(), latch.command_name()
    )]
    NotArmed {
        bus: String,
        address: u8,
        latch: Latch,
    },
    /// The program made no call for longer than the drive's watchdog time (a paused process, a
    /// blocked loop): a trip, not a fresh start. ussd latches the drive (or has) with its safe
    /// command, `command` (the drive's `DriveInfo::safe_command`; `None` if ussd has not
    /// described the drive); every ON fails until [`crate::Controller::rearm`].
    #[error(
        "drive {address} on {bus}: this controller made no call for {:.3} s, longer than the drive's watchdog ({:.3} s): that is a trip, and ussd stops the drive with {}; re-arm it (OFF1, then ON: Controller::rearm)",
        gap.as_secs_f64(), watchdog.as_secs_f64(), command.map_or("its safe command", StopCommand::name)
    )]
    Stalled {
        bus: String,
        address: u8,
        gap: Duration,
        watchdog: Duration,
        command: Option<StopCommand>,
    },
    /// A relay named a latch the drive does not show now.
    #[error(
        "drive {address} on {bus}: latch {named} is not the drive's current latch ({}): nothing was re-armed; name the latch its image shows",
        if *.shown == 0 { "it is live".to_owned() } else { format!("latch {shown}") }
    )]
    NotTheLatch {
        bus: String,
        address: u8,
        named: u64,
        shown: u64,
    },
    /// The controller handed the drive back: take control again for more.
    #[error("drive {address} on {bus}: this controller released the drive; take control again")]
    Released { bus: String, address: u8 },
    /// A setpoint the word cannot carry (not a finite number, or beyond -200 % .. +199.99 % of
    /// the reference frequency): refused, never sent as full scale. `problem` says which.
    #[error("drive {address} on {bus}: {asked} {problem}; nothing was sent")]
    InvalidSetpoint {
        bus: String,
        address: u8,
        asked: String,
        problem: String,
    },
    /// A setpoint in Hz while the drive's reference frequency is not known: ussd reads it
    /// again (the drive came online, was reset or commissioned) and scales nothing with the
    /// old one. Nothing was sent.
    #[error(
        "drive {address} on {bus}: {asked} not sent: ussd is reading the drive's reference frequency (P2000) again (it came online, was reset or commissioned); try again in a moment, or give the setpoint in percent"
    )]
    ReferenceUnknown {
        bus: String,
        address: u8,
        asked: String,
    },
    /// Words ussd would refuse (and latch the drive for).
    #[error(
        "drive {address} on {bus}: ussd would refuse these words ({rejection}); nothing was sent"
    )]
    InvalidSample {
        bus: String,
        address: u8,
        rejection: Rejection,
    },
    /// A controller asked for another word count than the drive's PZD length.
    #[error(
        "drive {address} on {bus} exchanges {expected} PZD words (pzd in ussd's configuration), not {given}"
    )]
    PzdWords {
        bus: String,
        address: u8,
        given: usize,
        expected: usize,
    },
    /// The drive has no PZD (pzd = 0): there is nothing to control.
    #[error("drive {address} on {bus} has no process data (pzd = 0): there is nothing to control")]
    NoProcessData { bus: String, address: u8 },
    /// ussd refused an operator command.
    #[error("ussd on {bus} refused the stop command: {error}{}", command_hint(*.error))]
    CommandRefused { bus: String, error: CommandError },
    /// A drive did not get where it was asked to in time.
    #[error(
        "drive {address} on {bus} {} after {timeout:?} (wanted: {wanted}): check `ussctl status` and `ussctl faults {address}`",
        Still(*.online, *.zsw1)
    )]
    WaitTimeout {
        bus: String,
        address: u8,
        timeout: Duration,
        /// What was awaited, e.g. "S4".
        wanted: String,
        /// Whether the drive answered at the end.
        online: bool,
        /// ZSW1 at the end.
        zsw1: u16,
    },
    /// ussd sent the command, but the drive does not take its commands from this link: its
    /// ZSW1 bit 9 ("control requested") is 0, its command source is elsewhere. It ignores
    /// the command, stops included.
    #[error(
        "drive {address} on {bus} got {command} from ussd but does not take its commands from this link (ZSW1 {zsw1:#06X}, bit 9 control requested = 0): stop it where it takes its commands; its command source is not USS{}",
        setting.as_ref().map(|s| format!(" ({s} is)")).unwrap_or_default()
    )]
    NotControllable {
        bus: String,
        address: u8,
        command: String,
        zsw1: u16,
        /// The setting that takes commands from USS, as the drive's family profile names it
        /// ("P0700 = 5"), where known.
        setting: Option<String>,
    },
    /// An ON that waited for ussd to take the re-arm was dropped: a stop of this program
    /// (another thread's call) came meanwhile, and it is the program's later word.
    #[error(
        "drive {address} on {bus}: a stop of this program came while this ON waited for the re-arm: the ON was dropped, the drive keeps the stop"
    )]
    Superseded { bus: String, address: u8 },
}

fn command_hint(error: CommandError) -> &'static str {
    match error {
        CommandError::UnknownDrive => ": the address is not in ussd's configuration",
        CommandError::Shutdown => ": ussd is stopping; every drive gets its safe command",
        CommandError::Version => ": rebuild this program against the running ussd's uss-shm-types",
        CommandError::TooManyConnections => {
            ": this process holds too many connections to ussd's stop socket at once; close the idle ones (the stop of another process goes through)"
        }
        CommandError::Ok | CommandError::BadCommand => "",
    }
}

impl ClientError {
    /// [`ClientError::Tripped`] (`news`) or [`ClientError::NotArmed`] for the latch `input` shows.
    pub(crate) fn latched(bus: &str, address: u8, input: &PzdInput, news: bool) -> Self {
        let (bus, latch) = (bus.to_owned(), Latch::of(input));
        if news {
            Self::Tripped {
                bus,
                address,
                latch,
            }
        } else {
            Self::NotArmed {
                bus,
                address,
                latch,
            }
        }
    }

    pub(crate) fn ipc(what: impl Into<String>, detail: impl fmt::Debug) -> Self {
        Self::Ipc {
            what: what.into(),
            detail: format!("{detail:?}"),
        }
    }
}

/// `, it was process N`, or nothing for pid 0.
struct Pid(u32);

impl fmt::Display for Pid {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            0 => Ok(()),
            pid => write!(f, "; it was process {pid}"),
        }
    }
}

struct Known<'a>(&'a [u8]);

impl fmt::Display for Known<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            [] => f.write_str("ussd polls no drives there"),
            [one] => write!(f, "ussd polls drive {one} there"),
            many => {
                f.write_str("ussd polls drives ")?;
                for (i, a) in many.iter().enumerate() {
                    if i > 0 {
                        f.write_str(", ")?;
                    }
                    write!(f, "{a}")?;
                }
                f.write_str(" there")
            }
        }
    }
}

struct Holder<'a>(Option<i32>, &'a Option<String>);

impl fmt::Display for Holder<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.0, self.1) {
            (Some(pid), Some(node)) => write!(f, "process {pid} (node {node:?})"),
            (Some(pid), None) => write!(f, "process {pid}"),
            (None, _) => f.write_str("another process"),
        }
    }
}

struct Still(bool, u16);

impl fmt::Display for Still {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0 {
            let state = crate::state_name(self.1);
            write!(f, "is still in {state} (ZSW1 {:#06X})", self.1)
        } else {
            f.write_str("is offline")
        }
    }
}

/// A parameter access that did not deliver a value.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum ParamError {
    /// The drive refused the task: reply 7 with its error number, or reply 8 (USS.md
    /// section 6).
    #[error(transparent)]
    Drive(#[from] DriveError),
    /// The task did not get to the drive or its answer did not come back (timeout, offline,
    /// line down, ussd shut down, cancelled). A request ussd refused before the bus (as a whole,
    /// or for an item it names) is [`ParamError::Refused`].
    #[error(transparent)]
    Path(#[from] PathError),
    /// A write whose task reached the drive (`telegrams` telegrams carried it) but whose
    /// answer did not come back (`failure`: timeout, drive offline, line down, ussd shut
    /// down): the drive may hold the new value, or not. Read the parameter back to see which.
    #[error(
        "the write may have been applied: the drive received it ({telegrams} telegram{}) but its answer did not come back ({}); read the parameter back to see what the drive holds",
        if *.telegrams == 1 { "" } else { "s" },
        lost(*.failure)
    )]
    MaybeApplied { failure: PathError, telegrams: u32 },
    /// A value that does not fit the parameter (its type, or a read-only parameter), refused
    /// before the bus.
    #[error("{param}: {problem}")]
    Value { param: String, problem: String },
    /// A write to a drive another process controls, not marked deliberate (force).
    #[error(
        "drive {address} is controlled by process {pid}: a parameter write from another process is refused; stop that controller first, or force the write if it is deliberate (ussctl param write --force, Python force=True, C USSRT_WRITE_FORCE, Rust WriteOptions::force)"
    )]
    Controlled { address: u8, pid: u32 },
    /// ussd refused the request (or this item) before the bus.
    #[error("ussd refused the request{} before the bus: {error}{}", Item(*.item), refusal_hint(*.error))]
    Refused {
        error: RequestError,
        /// The item (0-based) the refusal is about, if it is about one.
        item: Option<u8>,
    },
    /// ussd did not answer within the client's timeout.
    #[error(
        "ussd did not answer within {0:?}: check that it runs (`ussctl status`) and read its log"
    )]
    NoAnswer(Duration),
    /// ussd dropped the request without answering (it stopped or crashed).
    #[error("ussd dropped the request without answering: check that it runs (`ussctl status`)")]
    Dropped,
    /// The bus could not be reached.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// ussd answered something the contract does not allow.
    #[error(
        "unexpected answer from ussd ({0}): check that ussd and this program are the same uss-rt version"
    )]
    Unexpected(String),
    /// A commissioning call (a restore, a factory reset, the end of quick commissioning) would
    /// change guarded parameters (command or setpoint source, COM link, ...) and was not asked
    /// as unsafe: nothing was written.
    #[error(
        "it changes {params}, which can take the drive away from ussd ({why}); nothing was written: do it deliberately as unsafe (ussctl --unsafe, Python unsafe=True, C USSRT_WRITE_UNSAFE or USSRT_RESTORE_UNSAFE, Rust unsafe_write)"
    )]
    Guarded { params: String, why: String },
    /// What was asked has no parameter on this drive's family that uss-rt knows (a copy of RAM
    /// to ROM on a generic slave or a SIMOREG): nothing was sent.
    #[error("drive {address} ({family}): {what}; nothing was sent")]
    NotOnFamily {
        address: u8,
        family: &'static str,
        what: &'static str,
    },
}

impl ParamError {
    /// For the result of a write: whether the drive may hold the new value although no
    /// answer said so. [`ParamError::MaybeApplied`] (the task went out, its answer was lost),
    /// and a request ussd took but did not answer ([`ParamError::NoAnswer`],
    /// [`ParamError::Dropped`]: it may have put the task on the wire before it stopped). Every
    /// other error proves the drive did not take it (it refused it, or it never left).
    pub const fn may_be_applied(&self) -> bool {
        matches!(
            self,
            Self::MaybeApplied { .. } | Self::NoAnswer(_) | Self::Dropped
        )
    }
}

/// Why an answer did not come back, in a few words.
const fn lost(failure: PathError) -> &'static str {
    match failure {
        PathError::Timeout => "no matching reply within ussd's parameter timeout",
        PathError::DriveOffline => "the drive went offline",
        PathError::LineDown => "the bus line went down",
        PathError::Shutdown => "ussd shut down",
        PathError::MailboxFull | PathError::Cancelled | PathError::Refused(_) => "the task ended",
    }
}

struct Item(Option<u8>);

impl fmt::Display for Item {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Some(i) => write!(f, " (item {})", u32::from(i) + 1),
            None => Ok(()),
        }
    }
}

/// What to do about a refusal.
fn refusal_hint(error: RequestError) -> &'static str {
    match error {
        RequestError::UnknownDrive => ": the address is not in ussd's configuration",
        RequestError::BadCount => ": send 1 to 39 items",
        RequestError::ValueType => ": a word value is at most 65535; reads carry no value",
        RequestError::WritesDisabled => {
            ": ussd's configuration sets params_writable = false for this drive"
        }
        RequestError::Busy => ": retry once earlier requests finished",
        RequestError::Shutdown => ": retry once ussd runs again",
        RequestError::Version | RequestError::BadFlags => {
            ": rebuild this program against the running ussd's uss-shm-types"
        }
        RequestError::BadSubindex => ": array indices are 0..=254",
        RequestError::NoParameterChannel => ": the drive is configured with pkw = 0",
        RequestError::DwordOverThreeWords => {
            ": the drive has a 3-word parameter channel; write a word, or configure pkw = 4"
        }
        RequestError::Controlled => {
            ": another process controls the drive; force the write if it is deliberate \
             (ussctl --force, Python force=True, C USSRT_WRITE_FORCE, Rust WriteOptions::force)"
        }
        RequestError::Guarded => {
            " (its command or setpoint source, COM link, telegram monitoring off or a factory \
             reset); write it deliberately as unsafe (ussctl --unsafe, Python unsafe=True, C \
             USSRT_WRITE_UNSAFE, Rust WriteOptions::unsafe_write): ussd logs it"
        }
        RequestError::Unlisted => {
            ": ussd has no catalogue of this drive's family (or its drive table's `writable` \
             list does not name the parameter), so it cannot tell whether the write takes the \
             drive away from it; list the parameters safe to write in `writable`, or write it \
             deliberately as unsafe (ussctl --unsafe, Python unsafe=True, C \
             USSRT_WRITE_UNSAFE, Rust WriteOptions::unsafe_write): ussd logs it"
        }
        RequestError::ImpossibleValue => ": a float parameter holds finite numbers only",
        RequestError::IndexRequired => {
            ": name the element, as in P2014[0] or P2014.0 (`ussctl param describe` says how \
             many there are)"
        }
        RequestError::LineDown => {
            ": the bus line is down; ussd reopens it, retry once `ussctl status` shows it up"
        }
        RequestError::NoEepromTask => {
            " (its task table has no EEPROM writes, SINAMICS G120): write it to RAM, then copy \
             RAM to ROM, which makes every setting permanent (ussctl param save, Rust \
             Bus::save_to_rom, Python save_to_rom, C ussrt_param_save)"
        }
        RequestError::Ok
        | RequestError::PnuOutOfRange
        | RequestError::BadTask
        | RequestError::BadStorage => "",
    }
}

/// The start of an IPC failure's detail when ussd did not answer in time.
pub(crate) const NO_ANSWER: &str = "no answer within";

/// What to do about a failed iceoryx2 call, by what iceoryx2 said.
fn ipc_hint(detail: &str) -> &'static str {
    if detail.starts_with(NO_ANSWER) {
        "ussd took the connection but did not answer: it hangs or is paused (`ussctl status` says whether its heartbeat goes on); if it is gone, only the drive's own telegram monitoring stops the drive"
    } else if detail.contains("ExceedsMax") {
        "the bus's services admit no more ports of this kind (too many clients at once): close some; stops take their own path and are never refused for this"
    } else {
        "run ussd and this program as the same user (or root), or in ussd's access_group: iceoryx2 keeps its state in /dev/shm/uss-rt"
    }
}

/// `: start it with ...`, or `; on this machine ussd serves sim: ...`.
struct Served<'a>(&'a [String]);

impl core::fmt::Display for Served<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.0 {
            [] => f.write_str(
                ": start it with `ussd` (or `ussd --config FILE`; the package's service: \
                 `systemctl start ussd`)",
            ),
            [one] => write!(
                f,
                "; on this machine ussd serves {one}: name it (ussctl --bus {one})"
            ),
            [first, rest @ ..] => {
                let mut all: Vec<&str> = vec![first.as_str()];
                all.extend(rest.iter().map(String::as_str));
                let last = all.pop().unwrap_or_default();
                write!(
                    f,
                    "; on this machine ussd serves {} and {last}: name one of those (ussctl --bus \
                     {first})",
                    all.join(", ")
                )
            }
        }
    }
}

impl ClientError {
    /// [`ClientError::NotRunning`] of `bus`, naming the buses ussd serves on this machine.
    pub fn not_running(bus: impl Into<String>) -> Self {
        Self::NotRunning {
            bus: bus.into(),
            served: crate::link::served_buses(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn controlled_message_names_the_process() {
        let e = ClientError::Controlled {
            bus: "bus0".into(),
            address: 5,
            pid: Some(1234),
            node: None,
        };
        assert!(
            e.to_string()
                .starts_with("drive 5 on bus0 is controlled by process 1234:"),
            "{e}"
        );
        let e = ClientError::Controlled {
            bus: "bus0".into(),
            address: 5,
            pid: Some(1234),
            node: Some("ussctl".into()),
        };
        assert!(
            e.to_string()
                .starts_with("drive 5 on bus0 is controlled by process 1234 (node \"ussctl\")"),
            "{e}"
        );
    }

    #[test]
    fn not_running_says_how_to_start_ussd_or_which_buses_it_serves() {
        let e = ClientError::NotRunning {
            bus: "bus0".into(),
            served: Vec::new(),
        };
        assert_eq!(
            e.to_string(),
            "ussd is not running on bus0: start it with `ussd` (or `ussd --config FILE`; the \
             package's service: `systemctl start ussd`)"
        );
        let e = ClientError::NotRunning {
            bus: "bus0".into(),
            served: vec!["sim".into(), "line1".into()],
        };
        assert_eq!(
            e.to_string(),
            "ussd is not running on bus0; on this machine ussd serves sim and line1: name one of \
             those (ussctl --bus sim)"
        );
    }

    #[test]
    fn unknown_drive_lists_the_known_ones() {
        let e = ClientError::UnknownDrive {
            bus: "b".into(),
            address: 9,
            known: vec![1, 2, 3],
        };
        assert_eq!(
            e.to_string(),
            "drive 9 is not on b (ussd polls drives 1, 2, 3 there): use one of those or add it to ussd's configuration"
        );
    }

    #[test]
    fn drive_errors_carry_number_and_name() {
        let e = ParamError::Drive(DriveError::Refused(uss_protocol::ErrorNumber::from_number(
            2,
        )));
        assert_eq!(
            e.to_string(),
            "the drive refused the task with error 2: limit exceeded"
        );
        let e = ParamError::Refused {
            error: RequestError::WritesDisabled,
            item: Some(0),
        };
        assert_eq!(
            e.to_string(),
            "ussd refused the request (item 1) before the bus: writes disabled: ussd's configuration sets params_writable = false for this drive"
        );
    }
}
