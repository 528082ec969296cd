//! One serializable view of what ussd publishes (feature `view`): the bus ([`BusView`]) and each
//! drive ([`DriveView`], [`ControlView`], [`InfoView`]) as every front-end that speaks JSON or a dynamic
//! language shows them (`ussctl status --json` and `top`, the Zenoh bridge's `status` and `diag`
//! payloads, Python's `Bus.status()`), with codes turned into words and nanoseconds into
//! microseconds, built in one place from the contract's `#[repr(C)]` [`BusStatus`] and
//! [`DriveDiag`]. A drive's view is judged at the time it is read: diagnostics older than
//! ussd's limit for them say `stale` and never show the drive online (rule 3).

use crate::{
    DriveDiag, DriveInfo, LatchReason, Monitoring, PzdInput, Setpoint, StopCommand, zsw1_flags,
};
use serde::Serialize;
use uss_shm_types::BusStatus;
use uss_shm_types::diag::{LastFailure, RtMode};

/// A drive's state in words: "unknown" before its first poll decided, "offline" while it does
/// not answer, else its ZSW1's (S1..S4, "fault", "not ready").
pub fn shown_state(known: u8, online: u8, zsw1: u16) -> &'static str {
    match (known, online) {
        (0, _) => "unknown",
        (_, 0) => "offline",
        _ => crate::state_name(zsw1),
    }
}

/// Why the drive's last failed attempt failed, in words.
pub fn last_failure(d: &DriveDiag) -> &'static str {
    LastFailure::try_from(d.last_failure).map_or("unknown", LastFailure::name)
}

/// The bus and its drives as `ussctl status --json` shows them (without its `"v"`), and
/// Python's `Bus.status()`: read once, each drive's view judged when it was read.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct StatusView {
    pub bus: BusView,
    pub drives: Vec<DriveView>,
}

impl StatusView {
    /// Reads the bus status and every drive's diagnostics of `bus`.
    ///
    /// # Errors
    /// What reading the status or a drive's diagnostics gives (ussd gone, ...).
    pub fn of(bus: &crate::Bus) -> Result<Self, crate::ClientError> {
        let status = bus.status()?;
        let drives = bus
            .drives()
            .into_iter()
            .map(|a| bus.diag(a))
            .collect::<Result<Vec<_>, _>>()?;
        let now = crate::monotonic_ns();
        Ok(Self {
            bus: BusView::new(bus.name(), &status),
            drives: drives.iter().map(|d| DriveView::new(d, now)).collect(),
        })
    }
}

/// The bus as a whole.
#[derive(Debug, Clone, PartialEq, Serialize, schemars::JsonSchema)]
pub struct BusView {
    pub bus: String,
    pub running: bool,
    /// `realtime` or `best effort` (`unknown`: a code this client does not know).
    pub rt_mode: &'static str,
    /// -1: not pinned.
    pub rt_cpu: i32,
    pub rt_priority: u8,
    pub drive_count: u8,
    pub cycles: u64,
    pub exchanges: u64,
    pub good: u64,
    pub cycle_overruns: u64,
    pub events_dropped: u64,
    pub results_lost: u64,
    pub jobs_accepted: u64,
    pub jobs_finished: u64,
    /// Parameter jobs of clients that died, taken out before they reached the wire.
    pub jobs_cancelled: u64,
    pub mean_exchange_us: f64,
    /// Wire-time floor over achieved exchange time; null until measured.
    pub efficiency: Option<f64>,
    /// "up" or "down".
    pub line: &'static str,
    /// Why the line is down; null while up.
    pub line_error: Option<String>,
    /// Attempts to reopen a line that is down.
    pub reopen_attempts: u32,
    /// Times the line went down since ussd started.
    pub line_downs: u64,
    /// Polls out of turn: a stop, a trip or a re-arm sent before the circulating list went on.
    pub out_of_turn: u64,
    /// Broadcast telegrams: stops of every drive.
    pub broadcasts: u64,
}

impl BusView {
    /// The view of bus `bus`'s status `s`.
    pub fn new(bus: &str, s: &BusStatus) -> Self {
        Self {
            bus: bus.to_owned(),
            running: s.running != 0,
            rt_mode: RtMode::try_from(s.rt_mode).map_or("unknown", RtMode::name),
            rt_cpu: s.rt_cpu,
            rt_priority: s.rt_priority,
            drive_count: s.drive_count,
            cycles: s.cycles,
            exchanges: s.exchanges,
            good: s.good,
            cycle_overruns: s.cycle_overruns,
            events_dropped: s.events_dropped,
            results_lost: s.results_lost,
            jobs_accepted: s.jobs_accepted,
            jobs_finished: s.jobs_finished,
            jobs_cancelled: s.jobs_cancelled,
            mean_exchange_us: s.mean_exchange_ns as f64 / 1e3,
            efficiency: s.efficiency(),
            line: if s.is_line_down() { "down" } else { "up" },
            line_error: s.line_fault_text(),
            reopen_attempts: s.reopen_attempts,
            line_downs: s.line_downs,
            out_of_turn: s.out_of_turn,
            broadcasts: s.broadcasts,
        }
    }
}

/// Whether a drive is live or latched, and why (`uss_shm_types::control`).
#[derive(Debug, Clone, Serialize, schemars::JsonSchema)]
pub struct ControlView {
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

impl ControlView {
    fn new(control: u8, reason: u8, command: u8, by_pid: u32, rejection: u8) -> Self {
        let latched = control != crate::ControlState::Live.code();
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
                .then(|| name(crate::Rejection::try_from(rejection).map(crate::Rejection::name)))
                .flatten(),
        }
    }

    pub fn of_diag(d: &DriveDiag) -> Self {
        Self::new(d.control, d.latch_reason, d.latch_command, 0, d.rejection)
    }

    pub fn of_input(i: &PzdInput) -> Self {
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

/// One drive as `ussctl status --json` and the bridge's diagnostics show it: its state, the main
/// counters, its control and monitoring, judged at the time it was read (rule 3: stale
/// diagnostics never show it online).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DriveView {
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
    pub control: ControlView,
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
    /// PZD words the drive's telegrams carry (0: no process data, so no control word).
    pub pzd_words: u8,
    /// The drive's family profile (none for a generic slave).
    #[serde(skip)]
    #[schemars(skip)]
    pub profile: Option<&'static crate::Catalogue>,
}

impl DriveView {
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
            actual_hz: d
                .info
                .reference()
                .map_or(f32::NAN, |r| Setpoint::from_word(d.last_hiw).hz(r)),
            good: d.counters.good,
            rejected: d.counters.rejected,
            timeouts: d.counters.timeouts,
            control: ControlView::of_diag(d),
            monitoring: d.monitoring().map_or("unknown", Monitoring::name),
            monitoring_ms: d.monitoring_ms,
            monitoring_min_ms: d.monitoring_min_ms,
            controller_pid: (d.controller_pid != 0).then_some(d.controller_pid),
            last_error: last_failure(d),
            period_ms: (d.period_ns != 0).then(|| d.period_ns as f64 / 1e6),
            stale_after_ms: (d.stale_after_ns != 0).then(|| d.stale_after_ns as f64 / 1e6),
            takes_commands: crate::Zsw1::from_bits_retain(d.last_zsw1)
                .contains(crate::Zsw1::CONTROL_REQUESTED),
            pzd_words: d.info.pzd_words,
            profile: crate::DriveFamily::try_from(d.info.family)
                .ok()
                .and_then(crate::Catalogue::of),
        }
    }

    /// The view marked stale (and not online) when `stale` says what the diagnostics cannot
    /// know of themselves: ussd no longer serves the bus, the drive's image is overdue.
    #[must_use]
    pub fn stale_when(mut self, stale: bool) -> Self {
        if stale {
            (self.online, self.stale, self.state) = (false, true, "stale");
        }
        self
    }
}

/// What ussd knows of a drive from its configuration and the drive itself ([`DriveInfo`]), as
/// `ussctl stats` (its `info`), `ussctl top` and the bridge's `info` payload show it.
#[derive(Debug, Clone, PartialEq, Serialize, schemars::JsonSchema)]
pub struct InfoView {
    /// P2000: the frequency of a setpoint or actual value of 0x4000 (100 %); 0 while ussd reads
    /// it again (the drive came online, was reset or commissioned): no Hz are known then.
    pub reference_hz: f32,
    pub pzd_words: u8,
    /// The PKW channel's words, P2013: 0, 3, 4, or 127 (variable).
    pub pkw_words: u8,
    pub watchdog_ms: u32,
    /// What a latched drive gets: "OFF1", "OFF2", "OFF3".
    pub safe_command: &'static str,
    pub params_writable: bool,
    /// How often the drive appears in each cycle of the circulating list.
    pub weight: u8,
}

impl InfoView {
    pub fn of(i: &DriveInfo) -> Self {
        Self {
            reference_hz: i.reference_hz,
            pzd_words: i.pzd_words,
            pkw_words: i.pkw_words,
            watchdog_ms: i.watchdog_ms,
            safe_command: i.safe_command().map_or("unknown", StopCommand::name),
            params_writable: i.params_writable != 0,
            weight: i.weight,
        }
    }

    /// One line for a person: `reference 50 Hz, PZD 2, PKW 4, watchdog 100 ms, ...`.
    pub fn human(&self) -> String {
        format!(
            "reference {}, PZD {}, PKW {}, watchdog {} ms, safe command {}, weight {}, \
             parameters {}",
            if self.reference_hz > 0.0 {
                format!("{} Hz", self.reference_hz)
            } else {
                "not known (being read)".to_owned()
            },
            self.pzd_words,
            self.pkw_words,
            self.watchdog_ms,
            self.safe_command,
            self.weight,
            if self.params_writable {
                "writable"
            } else {
                "read-only"
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_shm_types::diag::{LineFault, LineState};

    #[test]
    fn codes_become_words_and_a_down_line_says_why() {
        let mut s = BusStatus {
            running: 1,
            rt_mode: RtMode::Realtime.code(),
            mean_exchange_ns: 2_500,
            ..BusStatus::EMPTY
        };
        let v = BusView::new("b0", &s);
        assert_eq!((v.running, v.rt_mode, v.line), (true, "realtime", "up"));
        assert_eq!((v.mean_exchange_us, v.line_error), (2.5, None));
        (s.line_state, s.line_fault) = (LineState::Down.code(), LineFault::Stalled.code());
        s.rt_mode = 9;
        let v = BusView::new("b0", &s);
        assert_eq!((v.line, v.rt_mode), ("down", "unknown"));
        assert!(v.line_error.unwrap().contains("stalled"));
    }
}
