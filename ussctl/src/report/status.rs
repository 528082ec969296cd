//! `status`: the bus and its drives, each drive's control (live or latched, why).

use super::shown_state;
use serde::Serialize;
use std::fmt::Write as _;
use uss_client::{DriveDiag, LatchReason, Monitoring, PzdInput, Setpoint, StopCommand, zsw1_flags};
use uss_shm_types::diag::LastFailure;

/// Whether a drive is live or latched, and why (`uss_shm_types::control`).
#[derive(Debug, Clone, Serialize, schemars::JsonSchema)]
pub struct ControlReport {
    /// "live" or "latched".
    pub state: &'static str,
    /// Why it is latched ("controller stale", "operator stop", ...); null while live.
    pub reason: Option<&'static str>,
    /// What a latched drive gets ("OFF1", "OFF2", "OFF3"); null while live.
    pub command: Option<&'static str>,
    /// The operator or controller process behind the latch; null if none.
    pub by_pid: Option<u32>,
    /// The refused sample's fault, with reason "sample rejected".
    pub rejection: Option<&'static str>,
}

impl ControlReport {
    fn new(control: u8, reason: u8, command: u8, by_pid: u32, rejection: u8) -> Self {
        let latched = control != uss_client::ControlState::Live.code();
        let name = |r: Result<&'static str, _>| r.ok();
        Self {
            state: if latched { "latched" } else { "live" },
            reason: latched
                .then(|| name(LatchReason::try_from(reason).map(LatchReason::name)))
                .flatten(),
            command: latched
                .then(|| name(StopCommand::try_from(command).map(StopCommand::name)))
                .flatten(),
            by_pid: (latched && by_pid != 0).then_some(by_pid),
            rejection: (latched && reason == LatchReason::Rejected.code())
                .then(|| {
                    name(
                        uss_client::Rejection::try_from(rejection).map(uss_client::Rejection::name),
                    )
                })
                .flatten(),
        }
    }

    pub(crate) fn of_diag(d: &DriveDiag) -> Self {
        Self::new(d.control, d.latch_reason, d.latch_command, 0, d.rejection)
    }

    pub(crate) fn of_input(i: &PzdInput) -> Self {
        Self::new(
            i.control,
            i.latch_reason,
            i.latch_command,
            i.latched_by_pid,
            i.rejection,
        )
    }

    /// `live`, or `latched: controller stale, OFF1`.
    pub fn human(&self) -> String {
        match (self.reason, self.command) {
            (Some(reason), Some(command)) => format!("latched: {reason}, {command}"),
            _ => self.state.to_owned(),
        }
    }
}

/// The bus as a whole: the client's one view of it ([`uss_client::view::BusView`]), as Python
/// shows it too.
pub use uss_client::view::BusView as BusReport;

/// The bus's line in `status` and `top`.
pub trait BusLine {
    fn human(&self) -> String;
}

impl BusLine for BusReport {
    fn human(&self) -> String {
        let mut out = format!(
            "bus {}: {}, {}{}, {} drives, {} cycles, {} exchanges ({} good), mean exchange {:.0} us",
            self.bus,
            if self.running { "running" } else { "stopped" },
            self.rt_mode,
            if self.rt_cpu >= 0 {
                format!(" on CPU {} priority {}", self.rt_cpu, self.rt_priority)
            } else {
                String::new()
            },
            self.drive_count,
            self.cycles,
            self.exchanges,
            self.good,
            self.mean_exchange_us,
        );
        if let Some(e) = self.efficiency {
            let _ = write!(out, ", efficiency {e:.2}");
        }
        if self.out_of_turn > 0 {
            let _ = write!(out, ", {} polls out of turn", self.out_of_turn);
        }
        if self.broadcasts > 0 {
            let _ = write!(out, ", {} broadcast stops", self.broadcasts);
        }
        if let Some(error) = &self.line_error {
            let _ = write!(
                out,
                "\nLINE DOWN ({error}): every drive offline; ussd reopens the device ({} attempts so far)",
                self.reopen_attempts
            );
        }
        out
    }
}

/// One drive in `status`: state and the main counters.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DriveRow {
    pub address: u8,
    /// Answering, as ussd's fresh diagnostics say (false while they are stale).
    pub online: bool,
    /// The diagnostics are older than ussd's limit for them (`stale_after_ms`: a paused ussd,
    /// a stalled bus thread): the rest of the row is the drive as it was, not as it is.
    pub stale: bool,
    /// S1..S4, "fault", "not ready"; "offline" while the drive does not answer.
    pub state: &'static str,
    pub zsw1: u16,
    pub zsw1_hex: String,
    pub flags: Vec<&'static str>,
    pub hiw: u16,
    pub actual_hz: f32,
    pub good: u64,
    pub rejected: u64,
    pub timeouts: u64,
    pub control: ControlReport,
    /// The drive's own telegram monitoring as ussd read it: "on", "off", ...
    pub monitoring: &'static str,
    /// Its telegram-off time in ms (0: off or not read).
    pub monitoring_ms: u32,
    /// The shortest telegram-off time that does not trip it between two of its polls, ms.
    pub monitoring_min_ms: u32,
    /// The process in the controller's latest sample; null before any.
    pub controller_pid: Option<u32>,
    pub last_error: &'static str,
    /// How often ussd polls the drive now, ms (its probe interval while offline); null until
    /// known.
    pub period_ms: Option<f64>,
    /// After how long without a poll ussd's image of the drive is stale, ms; null until known.
    pub stale_after_ms: Option<f64>,
    /// Whether the drive takes its commands from this link (ZSW1 bit 9, control requested);
    /// false: it ignores ussd's control words, stops included.
    pub takes_commands: bool,
    #[serde(skip)]
    pzd_words: u8,
    /// The drive's family profile (none for a generic slave).
    #[serde(skip)]
    profile: Option<&'static uss_client::Catalogue>,
}

impl DriveRow {
    /// The row of `d` as read at `now_ns` (`CLOCK_MONOTONIC`): stale where its poll is overdue.
    pub fn new(d: &DriveDiag, now_ns: u64) -> Self {
        let stale = d.is_overdue(now_ns);
        let online = d.is_online_at(now_ns);
        Self {
            address: d.address,
            online,
            stale,
            state: if stale {
                "stale"
            } else {
                shown_state(d.known, d.online, d.last_zsw1)
            },
            zsw1: d.last_zsw1,
            zsw1_hex: format!("{:#06X}", d.last_zsw1),
            flags: zsw1_flags(d.last_zsw1),
            hiw: d.last_hiw,
            actual_hz: Setpoint::from_word(d.last_hiw).hz(d.info.reference_hz),
            good: d.counters.good,
            rejected: d.counters.rejected,
            timeouts: d.counters.timeouts,
            control: ControlReport::of_diag(d),
            monitoring: d.monitoring().map_or("unknown", Monitoring::name),
            monitoring_ms: d.monitoring_ms,
            monitoring_min_ms: d.monitoring_min_ms,
            controller_pid: (d.controller_pid != 0).then_some(d.controller_pid),
            last_error: last_failure(d),
            period_ms: (d.period_ns != 0).then(|| d.period_ns as f64 / 1e6),
            stale_after_ms: (d.stale_after_ns != 0).then(|| d.stale_after_ns as f64 / 1e6),
            takes_commands: uss_client::Zsw1::from_bits_retain(d.last_zsw1)
                .contains(uss_client::Zsw1::CONTROL_REQUESTED),
            pzd_words: d.info.pzd_words,
            profile: uss_client::DriveFamily::try_from(d.info.family)
                .ok()
                .and_then(uss_client::Catalogue::of),
        }
    }

    /// A drive that answers but does not take its commands from this link.
    fn commands_warning(&self) -> Option<String> {
        (self.online && !self.takes_commands && d_has_pzd(self)).then(|| {
            format!(
                "drive {}: NOT CONTROLLABLE: it does not take its commands from this link (ZSW1 bit 9, control requested, is 0): it ignores ussd's control words, stops included; its command source is elsewhere{}",
                self.address,
                command_source_hint(self.profile)
            )
        })
    }

    /// Whether the drive's own telegram monitoring deserves a warning; the parameter and the
    /// fault are its family profile's.
    fn monitoring_warning(&self) -> Option<String> {
        let param = self
            .profile
            .and_then(|c| c.monitoring)
            .map_or_else(|| "its telegram-off time".to_owned(), |p| p.to_string());
        let fault = self
            .profile
            .and_then(uss_client::Catalogue::telegram_off_fault_name)
            .unwrap_or_else(|| "its telegram-off fault".to_owned());
        match self.monitoring {
            "on" | "not read yet" | "not checked" => None,
            "off" => Some(format!(
                "drive {}: telegram monitoring is OFF: if ussd or its line dies, nothing stops this drive; set {param}, e.g. to 100 ms",
                self.address
            )),
            "shorter than the poll period" => Some(format!(
                "drive {}: telegram monitoring is {} ms, shorter than the time between two polls of it on this bus (up to {} ms): it trips ({fault}) between polls; set {param} to at least {} ms, or poll it more often",
                self.address, self.monitoring_ms, self.monitoring_min_ms, self.monitoring_min_ms
            )),
            "longer than the limit" => Some(format!(
                "drive {}: telegram monitoring is {} ms, longer than monitoring_max_ms: after ussd or its line dies it runs on for that long",
                self.address, self.monitoring_ms
            )),
            other => Some(format!(
                "drive {}: telegram monitoring {other}: check monitoring_param in ussd's configuration",
                self.address
            )),
        }
    }
}

/// What makes a drive of `profile`'s family take its commands from USS: "(P0700 = 5 takes
/// them from USS)", or nothing where uss-rt does not know it.
fn command_source_hint(profile: Option<&uss_client::Catalogue>) -> String {
    profile
        .and_then(uss_client::Catalogue::command_source_setting)
        .map(|s| format!(" ({s} takes them from USS)"))
        .unwrap_or_default()
}

/// Whether the drive's images carry a ZSW1 at all (PZD words configured): a drive without
/// process data has no control word to take.
fn d_has_pzd(d: &DriveRow) -> bool {
    d.pzd_words > 0
}

pub(super) fn last_failure(d: &DriveDiag) -> &'static str {
    LastFailure::try_from(d.last_failure).map_or("unknown", LastFailure::name)
}

/// `status`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct StatusReport {
    pub bus: BusReport,
    pub drives: Vec<DriveRow>,
}

impl StatusReport {
    pub fn human(&self) -> String {
        let mut out = self.bus.human();
        out.push('\n');
        let _ = writeln!(
            out,
            "{:>4}  {:<6}  {:<9}  {:<6}  {:>9}  {:>10}  {:>8}  {:>8}  {:>9}  {:<16}  {:<32}  flags",
            "addr",
            "online",
            "state",
            "ZSW1",
            "actual Hz",
            "good",
            "rejected",
            "timeouts",
            "polled ms",
            "last error",
            "control"
        );
        for d in &self.drives {
            let _ = writeln!(
                out,
                "{:>4}  {:<6}  {:<9}  {:<6}  {:>9.2}  {:>10}  {:>8}  {:>8}  {:>9}  {:<16}  {:<32}  {}",
                d.address,
                if d.online { "yes" } else { "no" },
                d.state,
                d.zsw1_hex,
                d.actual_hz,
                d.good,
                d.rejected,
                d.timeouts,
                d.period_ms
                    .map_or_else(|| "-".to_owned(), |ms| format!("{ms:.0}")),
                d.last_error,
                d.control.human(),
                d.flags.join(",")
            );
        }
        for warning in self.drives.iter().filter_map(DriveRow::commands_warning) {
            let _ = writeln!(out, "warning: {warning}");
        }
        for warning in self.drives.iter().filter_map(DriveRow::monitoring_warning) {
            let _ = writeln!(out, "warning: {warning}");
        }
        if self.drives.iter().any(|d| d.control.state == "latched") {
            out.push_str(
                "latched: the drive gets the stop command shown until a controller re-arms it (its explicit rearm, `ussctl run`)\n",
            );
        }
        out
    }
}
