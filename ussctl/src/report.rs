//! What ussctl prints: one report type per answer, shown as a table or text for people and
//! as JSON (`--json`) for machines. The JSON field names are part of ussctl's interface.

use crate::backup::Entry;
use serde::Serialize;
use std::fmt::Write as _;
use uss_client::uss_catalogue::{Bits, Param};
use uss_client::uss_protocol::ParamRef;
use uss_client::uss_protocol::Subindex;
use uss_client::{
    BusStatus, DriveDiag, FaultReport, LatchReason, Monitoring, ParamError, ParamValue, PzdInput,
    Setpoint, StopCommand, Typed, Value, state_name, zsw1_flags,
};
use uss_shm_types::DriveInfo;
use uss_shm_types::diag::{LastFailure, NEVER, RtMode};

/// S1..S4, "fault", "not ready" from ZSW1; "offline" while the drive does not answer (its last
/// ZSW1 is history then); "unknown" until ussd's first poll decided.
fn shown_state(known: u8, online: u8, zsw1: u16) -> &'static str {
    match (known, online) {
        (0, _) => "unknown",
        (_, 0) => "offline",
        _ => state_name(zsw1),
    }
}

/// Whether a drive is live or latched, and why (`uss_shm_types::control`).
#[derive(Debug, Clone, Serialize)]
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

/// The bus as a whole.
#[derive(Debug, Serialize)]
pub struct BusReport {
    pub bus: String,
    pub running: bool,
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
}

impl BusReport {
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
            mean_exchange_us: s.mean_exchange_ns as f64 / 1e3,
            efficiency: s.efficiency(),
            line: if s.is_line_down() { "down" } else { "up" },
            line_error: s.line_fault_text(),
            reopen_attempts: s.reopen_attempts,
            line_downs: s.line_downs,
        }
    }

    pub fn human(&self) -> String {
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
#[derive(Debug, Serialize)]
pub struct DriveRow {
    pub address: u8,
    pub online: bool,
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
    /// The process in the controller's latest sample; null before any.
    pub controller_pid: Option<u32>,
    pub last_error: &'static str,
}

impl DriveRow {
    pub fn new(d: &DriveDiag) -> Self {
        let online = d.online != 0;
        Self {
            address: d.address,
            online,
            state: shown_state(d.known, d.online, d.last_zsw1),
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
            controller_pid: (d.controller_pid != 0).then_some(d.controller_pid),
            last_error: last_failure(d),
        }
    }

    /// Whether the drive's own telegram monitoring deserves a warning.
    fn monitoring_warning(&self) -> Option<String> {
        match self.monitoring {
            "on" | "not read yet" | "not checked" => None,
            "off" => Some(format!(
                "drive {}: telegram monitoring is OFF: if ussd or its line dies, nothing stops this drive; set its telegram-off time (MICROMASTER 4: P2014.1, G120: p2040), e.g. 100 ms",
                self.address
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

fn last_failure(d: &DriveDiag) -> &'static str {
    LastFailure::try_from(d.last_failure).map_or("unknown", LastFailure::name)
}

/// `status`.
#[derive(Debug, Serialize)]
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
            "{:>4}  {:<6}  {:<9}  {:<6}  {:>9}  {:>10}  {:>8}  {:>8}  {:<16}  {:<32}  flags",
            "addr",
            "online",
            "state",
            "ZSW1",
            "actual Hz",
            "good",
            "rejected",
            "timeouts",
            "last error",
            "control"
        );
        for d in &self.drives {
            let _ = writeln!(
                out,
                "{:>4}  {:<6}  {:<9}  {:<6}  {:>9.2}  {:>10}  {:>8}  {:>8}  {:<16}  {:<32}  {}",
                d.address,
                if d.online { "yes" } else { "no" },
                d.state,
                d.zsw1_hex,
                d.actual_hz,
                d.good,
                d.rejected,
                d.timeouts,
                d.last_error,
                d.control.human(),
                d.flags.join(",")
            );
        }
        for warning in self.drives.iter().filter_map(DriveRow::monitoring_warning) {
            let _ = writeln!(out, "warning: {warning}");
        }
        if self.drives.iter().any(|d| d.control.state == "latched") {
            out.push_str(
                "latched: the drive gets the stop command shown until its controller re-arms it (OFF1, then ON)\n",
            );
        }
        out
    }
}

/// `stats`: the bus and every counter of every drive.
#[derive(Debug, Serialize)]
pub struct StatsReport {
    pub bus: BusReport,
    /// The bus's timing, µs: p50, p99, p99.9, max.
    pub timing: TimingReport,
    pub drives: Vec<DriveStats>,
}

/// Timing percentiles of a bus in µs: `[p50, p99, p99.9, max]`, zeros while none measured.
#[derive(Debug, Serialize)]
pub struct TimingReport {
    /// Line free -> reply complete.
    pub exchange: [f64; 4],
    /// End of the request -> the reply's STX.
    pub response_delay: [f64; 4],
    /// Reply complete -> next request written.
    pub turnaround: [f64; 4],
}

/// Timing percentiles of a drive in µs: `[p50, p99, p99.9, max]`, zeros while none measured.
#[derive(Debug, Serialize)]
pub struct DriveTiming {
    pub exchange: [f64; 4],
    pub response_delay: [f64; 4],
}

impl TimingReport {
    pub fn of(s: &BusStatus) -> Self {
        let us = |ns: [u64; 4]| ns.map(|n| n as f64 / 1e3);
        Self {
            exchange: us(s.exchange_ns),
            response_delay: us(s.response_delay_ns),
            turnaround: us(s.turnaround_ns),
        }
    }

    pub fn human(&self) -> String {
        [
            timing_row("exchange", self.exchange),
            timing_row("response delay", self.response_delay),
            timing_row("turnaround", self.turnaround),
        ]
        .concat()
    }
}

/// One line of percentiles in µs: `  exchange        p50 ... us  p99 ... max ... us`.
fn timing_row(name: &str, q: [f64; 4]) -> String {
    format!(
        "  {name:<15} p50 {:9.1} us  p99 {:9.1} us  p99.9 {:9.1} us  max {:9.1} us\n",
        q[0], q[1], q[2], q[3]
    )
}

#[derive(Debug, Serialize)]
pub struct DriveStats {
    pub address: u8,
    pub online: bool,
    pub no_reply: bool,
    pub control: ControlReport,
    pub last_error: &'static str,
    pub consecutive_failed_polls: u32,
    /// ms since the last good reply, by the bus status's clock; null: never.
    pub last_good_ms_ago: Option<f64>,
    /// What ussd knows of the drive from its configuration.
    pub info: InfoReport,
    /// Every counter by name.
    pub counters: serde_json::Map<String, serde_json::Value>,
    /// This drive's exchange time and response delay, µs: p50, p99, p99.9, max.
    pub timing: DriveTiming,
    /// The same, in the contract's order, for people.
    #[serde(skip)]
    ordered: [(&'static str, u64); 28],
}

/// Every counter of a drive, in the order of the contract (USS.md section 7's list plus
/// timeouts, retries and parameter jobs).
fn counters(d: &DriveDiag) -> [(&'static str, u64); 28] {
    let mut all = [("", 0); 28];
    all[..24].copy_from_slice(&d.counters.named());
    all[24..].copy_from_slice(&[
        ("since_ns", d.since_ns),
        ("last_good_ns", d.last_good_ns),
        ("last_zsw1", u64::from(d.last_zsw1)),
        ("last_hiw", u64::from(d.last_hiw)),
    ]);
    all
}

/// What ussd knows of a drive from its configuration.
#[derive(Debug, Serialize)]
pub struct InfoReport {
    /// P2000: the frequency of a setpoint or actual value of 0x4000 (100 %).
    pub reference_hz: f32,
    pub pzd_words: u8,
    /// P2013: 0, 3, 4, or 127 (variable).
    pub pkw: u8,
    pub watchdog_ms: u32,
    /// What a latched drive gets: "OFF1", "OFF2", "OFF3".
    pub safe_command: &'static str,
    pub params_writable: bool,
    pub weight: u8,
}

impl InfoReport {
    pub fn of(i: &DriveInfo) -> Self {
        Self {
            reference_hz: i.reference_hz,
            pzd_words: i.pzd_words,
            pkw: i.pkw_words,
            watchdog_ms: i.watchdog_ms,
            safe_command: i.safe_command().map_or("unknown", StopCommand::name),
            params_writable: i.params_writable != 0,
            weight: i.weight,
        }
    }

    pub fn human(&self) -> String {
        format!(
            "reference {} Hz, PZD {}, PKW {}, watchdog {} ms, safe command {}, weight {}, \
             parameters {}",
            self.reference_hz,
            self.pzd_words,
            self.pkw,
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

impl DriveStats {
    pub fn new(d: &DriveDiag, now_ns: u64) -> Self {
        Self {
            address: d.address,
            online: d.online != 0,
            no_reply: d.no_reply != 0,
            control: ControlReport::of_diag(d),
            last_error: last_failure(d),
            consecutive_failed_polls: d.consecutive_failed_polls,
            last_good_ms_ago: (d.last_good_ns != NEVER)
                .then(|| now_ns.saturating_sub(d.last_good_ns) as f64 / 1e6),
            info: InfoReport::of(&d.info),
            counters: counters(d)
                .iter()
                .map(|&(k, v)| (k.to_owned(), v.into()))
                .collect(),
            timing: DriveTiming {
                exchange: d.exchange_ns.map(|n| n as f64 / 1e3),
                response_delay: d.response_delay_ns.map(|n| n as f64 / 1e3),
            },
            ordered: counters(d),
        }
    }
}

impl StatsReport {
    pub fn human(&self) -> String {
        let b = &self.bus;
        let mut out = b.human();
        let _ = writeln!(
            out,
            "\n  cycle overruns {}, parameter jobs accepted {} finished {}, events dropped {}, results lost {}",
            b.cycle_overruns, b.jobs_accepted, b.jobs_finished, b.events_dropped, b.results_lost
        );
        out.push_str(&self.timing.human());
        for d in &self.drives {
            let _ = write!(
                out,
                "drive {}: {}, last error {}",
                d.address,
                if d.online { "online" } else { "offline" },
                d.last_error
            );
            if let Some(ms) = d.last_good_ms_ago {
                let _ = write!(out, ", last good reply {ms:.1} ms ago");
            }
            let _ = write!(out, ", {}", d.control.human());
            out.push('\n');
            let _ = writeln!(out, "  {}", d.info.human());
            out.push_str(&timing_row("exchange", d.timing.exchange));
            out.push_str(&timing_row("response delay", d.timing.response_delay));
            let line: Vec<String> = d
                .ordered
                .iter()
                .filter(|(k, _)| !k.ends_with("_ns") && !k.starts_with("last_"))
                .map(|(k, v)| format!("{k} {v}"))
                .collect();
            for chunk in line.chunks(8) {
                let _ = writeln!(out, "  {}", chunk.join("  "));
            }
        }
        out
    }
}

/// One drive in one round of `watch`.
#[derive(Debug, Serialize)]
pub struct WatchLine {
    /// Seconds since `watch` started.
    pub t: f64,
    pub drive: u8,
    pub online: bool,
    pub state: &'static str,
    pub zsw1: u16,
    pub hiw: u16,
    pub actual_hz: f32,
    /// Good replies so far.
    pub sequence: u64,
    /// The drive's update period (time between its last two good replies), ms.
    pub period_ms: f64,
    pub control: ControlReport,
    /// STW1 of the telegram that brought this reply.
    pub sent_stw1: u16,
    /// PZD3.. as the drive sent them.
    pub extra: Vec<u16>,
}

impl WatchLine {
    pub fn new(t: f64, drive: u8, i: &PzdInput, reference_hz: f32) -> Self {
        let online = i.online != 0;
        let extra_words = usize::from(i.word_count)
            .saturating_sub(2)
            .min(i.extra.len());
        Self {
            t,
            drive,
            online,
            state: shown_state(i.known, i.online, i.zsw1),
            zsw1: i.zsw1,
            hiw: i.hiw,
            actual_hz: Setpoint::from_word(i.hiw).hz(reference_hz),
            sequence: i.sequence,
            period_ms: i.age_ns as f64 / 1e6,
            control: ControlReport::of_input(i),
            sent_stw1: i.sent_stw1,
            extra: i.extra[..extra_words].to_vec(),
        }
    }

    pub fn human(&self) -> String {
        let mut out = format!(
            "{:8.3}s  drive {:>2}  {:<9}  ZSW1 {:#06X}  {:>8.2} Hz  replies {:>8}  period {:>6.2} ms",
            self.t,
            self.drive,
            self.state,
            self.zsw1,
            self.actual_hz,
            self.sequence,
            self.period_ms
        );
        if !self.extra.is_empty() {
            let words: Vec<_> = self.extra.iter().map(|w| format!("{w:#06X}")).collect();
            let _ = write!(out, "  PZD3.. {}", words.join(" "));
        }
        if self.control.state != "live" {
            let _ = write!(out, "  [{}]", self.control.human());
        }
        out
    }
}

/// `param read` / `param write`: the value in the parameter's own type and unit.
#[derive(Debug, Serialize)]
pub struct ParamReport {
    pub bus: String,
    pub drive: u8,
    /// As the manuals write it: `P1082`, `r0947[3]`.
    pub param: String,
    pub pnu: u16,
    pub index: Option<u8>,
    /// The catalogue's name; null for a parameter it does not know.
    pub name: Option<&'static str>,
    /// The data type: "float", "U16", "I16", "U32", "I32".
    #[serde(rename = "type")]
    pub data_type: String,
    /// "Hz", "s", ...; empty when none or not known.
    pub unit: &'static str,
    pub raw: u32,
    pub hex: String,
    /// The value in its type: a float for float, an integer otherwise.
    pub value: Typed,
    /// A status or control word's set bits by name (r0052, r0054).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub bits: Vec<&'static str>,
    /// Set for a write: whether it went to EEPROM too.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eeprom: Option<bool>,
    /// The value as shown to people: `50.00 Hz`.
    #[serde(skip)]
    shown: String,
}

impl ParamReport {
    pub fn new(bus: &str, drive: u8, v: &ParamValue) -> Self {
        let bits = match v.info.and_then(|p| p.bits) {
            Some(Bits::ZSW1) => zsw1_flags(v.raw.as_u32() as u16),
            Some(Bits::STW1) => stw1_bits(v.raw.as_u32() as u16),
            None => Vec::new(),
        };
        Self {
            bus: bus.to_owned(),
            drive,
            param: v.param.to_string(),
            pnu: v.param.pnu.get(),
            index: v.param.index.map(Subindex::get),
            name: v.name(),
            data_type: v.data_type.to_string(),
            unit: v.unit(),
            raw: v.raw.as_u32(),
            hex: match v.raw {
                Value::Word(w) => format!("{w:#06X}"),
                Value::Dword(d) => format!("{d:#010X}"),
            },
            value: v.typed(),
            bits,
            eeprom: None,
            shown: v.shown(),
        }
    }

    pub fn human(&self) -> String {
        let mut out = match self.eeprom {
            None => format!("drive {} {} = {}", self.drive, self.param, self.shown),
            Some(eeprom) => format!(
                "drive {} {} := {}{}",
                self.drive,
                self.param,
                self.shown,
                if eeprom { ", RAM and EEPROM" } else { ", RAM" }
            ),
        };
        if let Some(name) = self.name {
            let _ = write!(out, "  ({name})");
        }
        if !self.bits.is_empty() {
            let _ = write!(out, ": {}", self.bits.join(", "));
        }
        out
    }
}

/// The set bits of a control word 1 by name (USS.md section 7).
pub(crate) fn stw1_bits(stw1: u16) -> Vec<&'static str> {
    const NAMES: [&str; 16] = [
        "ON",
        "no-OFF2",
        "no-OFF3",
        "pulses-enabled",
        "RFG-enabled",
        "RFG-start",
        "setpoint-enabled",
        "fault-ack",
        "jog-right",
        "jog-left",
        "control-by-PLC",
        "reverse",
        "bit12",
        "motor-pot-up",
        "motor-pot-down",
        "local-remote",
    ];
    NAMES
        .iter()
        .enumerate()
        .filter(|&(i, _)| stw1 & (1 << i) != 0)
        .map(|(_, &n)| n)
        .collect()
}

/// `faults`.
#[derive(Debug, Serialize)]
pub struct FaultsReport {
    pub bus: String,
    pub drive: u8,
    /// r0947 with r0949, newest first; empty slots left out.
    pub faults: Vec<FaultEntry>,
    /// r2110; null when the drive has no r2110.
    pub warnings: Option<Vec<WarningEntry>>,
}

#[derive(Debug, Serialize)]
pub struct FaultEntry {
    /// Element of r0947: 0 is the newest.
    pub slot: u8,
    pub number: u16,
    /// `F0072`.
    pub code: String,
    /// r0949; null when the drive has no r0949.
    pub value: Option<u16>,
    /// r0948 of its trip as shown (`2026-11-22 20:31:05`, or `day 3 04:05:06` from a drive
    /// clock never set); null when the drive has no r0948 or left it empty.
    pub time: Option<String>,
    /// r0948's three words as read.
    pub time_words: Option<[u16; 3]>,
    pub text: Option<&'static str>,
}

#[derive(Debug, Serialize)]
pub struct WarningEntry {
    pub number: u16,
    /// `A0501`.
    pub code: String,
    pub text: Option<&'static str>,
}

impl FaultsReport {
    pub fn new(bus: &str, drive: u8, r: &FaultReport) -> Self {
        Self {
            bus: bus.to_owned(),
            drive,
            faults: r
                .faults
                .iter()
                .map(|f| FaultEntry {
                    slot: f.slot,
                    number: f.number,
                    code: format!("F{:04}", f.number),
                    value: f.value,
                    time: f.time.map(|t| t.to_string()),
                    time_words: f.time.map(|t| t.words),
                    text: f.text,
                })
                .collect(),
            warnings: r.warnings.as_ref().map(|w| {
                w.iter()
                    .map(|w| WarningEntry {
                        number: w.number,
                        code: format!("A{:04}", w.number),
                        text: w.text,
                    })
                    .collect()
            }),
        }
    }

    pub fn human(&self) -> String {
        let mut out = if self.faults.is_empty() {
            format!("drive {}: no faults recorded (r0947 empty)\n", self.drive)
        } else {
            format!("drive {} fault buffer r0947, newest first:\n", self.drive)
        };
        for f in &self.faults {
            let _ = write!(out, "  {}: {}", f.slot, f.code);
            if let Some(text) = f.text {
                let _ = write!(out, " {text}");
            }
            if let Some(v) = f.value {
                let _ = write!(out, " (fault value r0949 = {v})");
            }
            if let Some(t) = &f.time {
                let _ = write!(out, " at {t}");
            }
            out.push('\n');
        }
        match &self.warnings {
            None => {}
            Some(w) if w.is_empty() => out.push_str("active warnings (r2110): none\n"),
            Some(w) => {
                out.push_str("active warnings (r2110):\n");
                for w in w {
                    let _ = writeln!(out, "  {} {}", w.code, w.text.unwrap_or("(no text known)"));
                }
            }
        }
        out
    }
}

/// `stop`, `coast`, `quick-stop`: the drives that got the command and what they show now.
#[derive(Debug, Serialize)]
pub struct StopReport {
    pub bus: String,
    /// "OFF1", "OFF2" or "OFF3".
    pub command: &'static str,
    pub drives: Vec<StoppedDrive>,
}

/// One drive after an operator's stop command.
#[derive(Debug, Serialize)]
pub struct StoppedDrive {
    pub drive: u8,
    pub online: bool,
    pub state: &'static str,
    pub zsw1: u16,
    /// STW1 of the telegram the image came with: the command that went out.
    pub sent_stw1: u16,
    pub control: ControlReport,
}

impl StopReport {
    pub fn new(bus: &str, command: StopCommand) -> Self {
        Self {
            bus: bus.to_owned(),
            command: command.name(),
            drives: Vec::new(),
        }
    }

    pub fn push(&mut self, drive: u8, i: &PzdInput) {
        let online = i.online != 0;
        self.drives.push(StoppedDrive {
            drive,
            online,
            state: shown_state(i.known, i.online, i.zsw1),
            zsw1: i.zsw1,
            sent_stw1: i.sent_stw1,
            control: ControlReport::of_input(i),
        });
    }

    pub fn human(&self) -> String {
        let what = match self.command {
            "OFF2" => "it coasts",
            "OFF3" => "it stops quickly",
            _ => "it ramps down",
        };
        let mut out = String::new();
        for d in &self.drives {
            let _ = writeln!(
                out,
                "drive {}: {} sent (STW1 {:#06X}), {what}; now {} (ZSW1 {:#06X}); {} until its controller re-arms it (OFF1, then ON)",
                d.drive,
                d.control.command.unwrap_or(self.command),
                d.sent_stw1,
                d.state,
                d.zsw1,
                d.control.state,
            );
        }
        out
    }
}

/// The end of `run` or `ack`: what the drive shows now.
#[derive(Debug, Serialize)]
pub struct DriveReport {
    pub bus: String,
    pub drive: u8,
    /// What ussctl did: "run", "stop", "ack".
    pub action: &'static str,
    pub online: bool,
    pub state: &'static str,
    pub zsw1: u16,
    pub actual_hz: f32,
    /// `run`: the highest actual frequency seen.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peak_hz: Option<f32>,
}

impl DriveReport {
    pub fn new(bus: &str, action: &'static str, i: &PzdInput, drive: u8, ref_hz: f32) -> Self {
        let online = i.online != 0;
        Self {
            bus: bus.to_owned(),
            drive,
            action,
            online,
            state: shown_state(i.known, i.online, i.zsw1),
            zsw1: i.zsw1,
            actual_hz: Setpoint::from_word(i.hiw).hz(ref_hz),
            peak_hz: None,
        }
    }

    pub fn human(&self) -> String {
        let what = match self.action {
            "run" => "ran; OFF1 sent, it ramps down",
            _ => "fault acknowledge sent",
        };
        let mut out = format!(
            "drive {}: {what}; now {} (ZSW1 {:#06X}), {:.2} Hz",
            self.drive, self.state, self.zsw1, self.actual_hz
        );
        if let Some(p) = self.peak_hz {
            let _ = write!(out, ", peak {p:.2} Hz");
        }
        out
    }
}

/// One value of a restore: what the drive had, what the file says, what happened.
#[derive(Debug, Serialize)]
pub struct RestoreLine {
    pub param: String,
    pub was: Option<String>,
    pub wanted: String,
    /// "planned", "written", "refused: ...", "not written".
    pub result: String,
}

/// `param restore`.
#[derive(Debug, Serialize)]
pub struct RestoreReport {
    pub bus: String,
    pub drive: u8,
    pub file: String,
    pub dry_run: bool,
    /// Values the drive already held.
    pub equal: usize,
    pub written: usize,
    pub refused: usize,
    /// COM-link settings that differ but are kept (baud rate, address, PZD/PKW length).
    pub kept: usize,
    /// Why the restore stopped early (null: it ran to the end).
    pub cut_short: Option<String>,
    pub lines: Vec<RestoreLine>,
    pub seconds: f64,
}

impl RestoreReport {
    pub fn new(bus: &str, drive: u8, file: &std::path::Path, dry_run: bool) -> Self {
        Self {
            bus: bus.to_owned(),
            drive,
            file: file.display().to_string(),
            dry_run,
            equal: 0,
            written: 0,
            refused: 0,
            kept: 0,
            cut_short: None,
            lines: Vec::new(),
            seconds: 0.0,
        }
    }

    fn line(&mut self, e: &Entry) -> &mut RestoreLine {
        let name = e.param.to_string();
        if let Some(i) = self.lines.iter().position(|l| l.param == name) {
            return &mut self.lines[i];
        }
        self.lines.push(RestoreLine {
            param: name,
            was: None,
            wanted: e.info.show(e.value),
            result: "not written".into(),
        });
        let last = self.lines.len() - 1;
        &mut self.lines[last]
    }

    /// A differing value, to be written.
    pub fn plan(&mut self, e: &Entry, was: Option<Value>) {
        let line = self.line(e);
        line.was = was.map(|v| e.info.show(v));
        line.result = "planned".into();
    }

    /// A setting of the line ussd talks over that differs: kept.
    pub fn keep_link(&mut self, e: &Entry, held: Value) {
        let line = self.line(e);
        line.was = Some(e.info.show(held));
        line.result = "kept: the COM link ussd talks over (change it at the drive)".into();
        self.kept += 1;
    }

    /// Written; the drive holds `held` now (checked against the file's value).
    pub fn written(&mut self, e: &Entry, held: Value) {
        let ok = held == e.value;
        let line = self.line(e);
        line.result = if ok {
            "written".into()
        } else {
            format!("written, but the drive holds {}", e.info.show(held))
        };
        if ok {
            self.written += 1;
        } else {
            self.refused += 1;
        }
    }

    /// The drive refused the value (or does not have the parameter).
    pub fn refuse(&mut self, e: &Entry, error: &ParamError) {
        self.line(e).result = format!("refused: {error}");
        self.refused += 1;
    }

    /// The drive refused a value set on the way (access level, quick commissioning).
    pub fn helper_refused(&mut self, pnu: u16, value: u16, error: &ParamError) {
        self.lines.push(RestoreLine {
            param: format!("P{pnu:04}"),
            was: None,
            wanted: value.to_string(),
            result: format!("refused on the way: {error}"),
        });
        self.refused += 1;
    }

    /// Stopped before `rest` was written.
    pub fn cut_short(&mut self, why: &str, rest: &[crate::commands::backup::Step]) {
        self.cut_short = Some(format!(
            "{why}; not written: {}",
            rest.iter()
                .map(crate::commands::backup::Step::name)
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }

    pub fn is_complete(&self) -> bool {
        self.refused == 0 && self.cut_short.is_none()
    }

    pub fn human(&self) -> String {
        let mut out = String::new();
        for l in &self.lines {
            let _ = writeln!(
                out,
                "  {:<10} {} -> {}: {}",
                l.param,
                l.was.as_deref().unwrap_or("-"),
                l.wanted,
                l.result
            );
        }
        let what = if self.dry_run {
            format!("would write {}", self.lines.len() - self.kept)
        } else {
            format!("wrote {}, refused {}", self.written, self.refused)
        };
        let _ = writeln!(
            out,
            "drive {} from {}: {what}; {} already as in the file{} ({:.2} s)",
            self.drive,
            self.file,
            self.equal,
            if self.kept == 0 {
                String::new()
            } else {
                format!(", {} COM-link settings kept", self.kept)
            },
            self.seconds
        );
        if let Some(why) = &self.cut_short {
            let _ = writeln!(out, "cut short: {why}");
        }
        out
    }
}

/// One difference of `param diff`.
#[derive(Debug, Serialize)]
pub struct DiffLine {
    pub param: String,
    pub name: &'static str,
    /// The drive's value; null: the drive does not have it.
    pub drive: Option<String>,
    /// The other drive's or the file's value; null: it has none.
    pub other: Option<String>,
}

impl DiffLine {
    pub fn new(
        param: ParamRef,
        info: &'static Param,
        drive: Option<Value>,
        other: Option<Value>,
    ) -> Self {
        Self {
            param: param.to_string(),
            name: info.name.as_str(),
            drive: drive.map(|v| info.show(v)),
            other: other.map(|v| info.show(v)),
        }
    }
}

/// `param diff`.
#[derive(Debug, Serialize)]
pub struct DiffReport {
    pub bus: String,
    pub drive: u8,
    /// The file or the other drive's address.
    pub other: String,
    /// Values that are the same.
    pub same: usize,
    pub lines: Vec<DiffLine>,
}

impl DiffReport {
    pub fn new(bus: &str, drive: u8, other: &str) -> Self {
        Self {
            bus: bus.to_owned(),
            drive,
            other: other.to_owned(),
            same: 0,
            lines: Vec::new(),
        }
    }

    pub fn human(&self) -> String {
        let other = if self.other.parse::<u8>().is_ok() {
            format!("drive {}", self.other)
        } else {
            self.other.clone()
        };
        if self.lines.is_empty() {
            return format!(
                "drive {} and {other}: no differences ({} values compared)\n",
                self.drive, self.same
            );
        }
        let mut out = String::new();
        for l in &self.lines {
            let _ = writeln!(
                out,
                "  {:<10} drive {}: {:<14} {other}: {:<14} ({})",
                l.param,
                self.drive,
                l.drive.as_deref().unwrap_or("(none)"),
                l.other.as_deref().unwrap_or("(none)"),
                l.name
            );
        }
        let _ = writeln!(
            out,
            "drive {} and {other}: {} differences, {} values the same",
            self.drive,
            self.lines.len(),
            self.same
        );
        out
    }
}

/// One drive `scan` found.
#[derive(Debug, Serialize)]
pub struct ScannedDrive {
    pub baud: u32,
    pub address: u8,
    /// "0", "3", "4", "variable (127)", or "unknown" (it mirrored but answered no layout).
    pub pkw: String,
    pub pzd: usize,
    /// The ZSW1 it answered with.
    pub zsw1: Option<u16>,
    /// r0018, with a parameter channel.
    pub firmware: Option<f64>,
}

/// `scan`.
#[derive(Debug, Serialize)]
pub struct ScanReport {
    pub device: String,
    pub bauds: Vec<u32>,
    pub addresses: usize,
    pub drives: Vec<ScannedDrive>,
    /// Ctrl-C ended it early.
    pub cut_short: bool,
    pub seconds: f64,
}

impl ScanReport {
    pub fn new(
        device: &std::path::Path,
        bauds: &[uss_client::uss_protocol::Baud],
        addresses: usize,
    ) -> Self {
        Self {
            device: device.display().to_string(),
            bauds: bauds.iter().map(|b| b.get()).collect(),
            addresses,
            drives: Vec::new(),
            cut_short: false,
            seconds: 0.0,
        }
    }

    pub fn human(&self) -> String {
        let mut out = String::new();
        for d in &self.drives {
            let _ = write!(
                out,
                "{:>6} baud  drive {:2}: PKW {}, PZD {}",
                d.baud, d.address, d.pkw, d.pzd
            );
            if let Some(z) = d.zsw1 {
                let _ = write!(out, ", ZSW1 {z:#06X} ({})", state_name(z));
            }
            if let Some(f) = d.firmware {
                let _ = write!(out, ", firmware {f:.2}");
            }
            out.push('\n');
        }
        let plural =
            |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        let _ = writeln!(
            out,
            "{}: {} found, {} x {} in {:.2} s{}",
            self.device,
            plural(self.drives.len(), "drive", "drives"),
            plural(self.addresses, "address", "addresses"),
            plural(self.bauds.len(), "baud rate", "baud rates"),
            self.seconds,
            if self.cut_short {
                " (cut short by Ctrl-C)"
            } else {
                ""
            }
        );
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_shm_types::DriveCounters;

    fn diag() -> DriveDiag {
        DriveDiag {
            online: 1,
            known: 1,
            last_zsw1: 0xFB34,
            last_hiw: 0x2000,
            counters: DriveCounters {
                good: 10,
                rejected: 1,
                timeouts: 1,
                ..DriveCounters::default()
            },
            // 0x2000 = 50 % of this drive's P2000 as ussd's configuration gives it.
            info: DriveInfo {
                reference_hz: 60.0,
                pzd_words: 2,
                ..DriveInfo::UNKNOWN
            },
            last_failure: LastFailure::NoResponse.code(),
            latch_command: StopCommand::Off1.code(),
            ..DriveDiag::new(3)
        }
    }

    #[test]
    fn status_json_has_one_object_per_drive_with_decoded_zsw1() {
        let report = StatusReport {
            bus: BusReport::new("b0", &BusStatus::EMPTY),
            drives: vec![DriveRow::new(&diag())],
        };
        let v = serde_json::to_value(&report).unwrap();
        assert_eq!(v["bus"]["bus"], "b0");
        assert_eq!(v["bus"]["efficiency"], serde_json::Value::Null);
        let d = &v["drives"][0];
        assert_eq!(d["address"], 3);
        assert_eq!(d["online"], true);
        assert_eq!(d["state"], "S4");
        assert_eq!(d["zsw1"], 0xFB34);
        assert_eq!(d["zsw1_hex"], "0xFB34");
        assert_eq!(
            d["flags"],
            serde_json::json!(["at-setpoint", "control-requested", "running-right"])
        );
        assert_eq!(d["actual_hz"], 30.0);
        assert_eq!(
            (d["good"].as_u64(), d["rejected"].as_u64()),
            (Some(10), Some(1))
        );
        assert_eq!(d["last_error"], "no response");
        assert_eq!(d["control"]["state"], "latched");
        assert_eq!(d["control"]["reason"], "ussd started");
        assert_eq!(d["monitoring"], "not read yet");
        let text = report.human();
        assert!(
            text.contains("   3  yes     S4         0xFB34      30.00"),
            "{text}"
        );
        assert!(text.contains("latched: ussd started, OFF1"), "{text}");
    }

    #[test]
    fn a_drive_without_telegram_monitoring_is_warned_about() {
        let off = DriveRow::new(&DriveDiag {
            monitoring: Monitoring::Off.code(),
            control: uss_client::ControlState::Live.code(),
            ..diag()
        });
        let report = StatusReport {
            bus: BusReport::new("b0", &BusStatus::EMPTY),
            drives: vec![off],
        };
        let text = report.human();
        assert!(
            text.contains("warning: drive 3: telegram monitoring is OFF: if ussd or its line dies, nothing stops this drive"),
            "{text}"
        );
        assert!(text.contains("  live  "), "{text}");
    }

    #[test]
    fn a_drive_is_unknown_until_its_first_poll_decided() {
        let d = DriveRow::new(&DriveDiag {
            known: 0,
            online: 0,
            ..diag()
        });
        assert_eq!(d.state, "unknown");
    }

    #[test]
    fn offline_drives_show_offline_not_a_stale_state() {
        let d = DriveRow::new(&DriveDiag {
            online: 0,
            ..diag()
        });
        assert_eq!((d.online, d.state), (false, "offline"));
    }

    #[test]
    fn parameters_show_in_their_type_and_unit() {
        let info = uss_client::Catalogue::micromaster4().param(1082);
        let v = ParamValue {
            param: "P1082".parse().unwrap(),
            raw: Value::Dword(0x4248_0000),
            data_type: uss_client::DataType::Float,
            info,
        };
        let p = ParamReport::new("b0", 1, &v);
        assert_eq!(p.human(), "drive 1 P1082 = 50.00 Hz  (Max. frequency)");
        assert_eq!(
            serde_json::to_value(&p).unwrap(),
            serde_json::json!({"bus": "b0", "drive": 1, "param": "P1082", "pnu": 1082, "index": null,
                               "name": "Max. frequency", "type": "float", "unit": "Hz",
                               "raw": 1_112_014_848_u32, "hex": "0x42480000", "value": 50.0})
        );
        let zsw1 = ParamValue {
            param: "r0052".parse().unwrap(),
            raw: Value::Word(0xFB31),
            data_type: uss_client::DataType::U16,
            info: uss_client::Catalogue::micromaster4().param(52),
        };
        let mut p = ParamReport::new("b0", 1, &zsw1);
        assert!(
            p.human()
                .starts_with("drive 1 r0052 = 0xFB31  (CO/BO: Act. status word 1): at-setpoint, control-requested"),
            "{}",
            p.human()
        );
        p.eeprom = Some(true);
        assert!(
            p.human()
                .starts_with("drive 1 r0052 := 0xFB31, RAM and EEPROM")
        );
        assert_eq!(
            stw1_bits(0x047E),
            [
                "no-OFF2",
                "no-OFF3",
                "pulses-enabled",
                "RFG-enabled",
                "RFG-start",
                "setpoint-enabled",
                "control-by-PLC"
            ]
        );
    }

    #[test]
    fn faults_list_recorded_codes_with_texts_values_and_warnings() {
        let report = uss_client::FaultReport {
            faults: vec![
                uss_client::Fault {
                    slot: 0,
                    number: 70,
                    value: Some(3),
                    time: Some(uss_client::FaultTime {
                        words: [5 | 31 << 8, 20 | 22 << 8, 11 | 26 << 8],
                    }),
                    text: Some("CB setpoint fault"),
                },
                uss_client::Fault {
                    slot: 1,
                    number: 999,
                    value: None,
                    time: None,
                    text: None,
                },
            ],
            warnings: Some(vec![uss_client::Warning {
                number: 501,
                text: Some("Current limit"),
            }]),
        };
        let f = FaultsReport::new("b", 2, &report);
        assert_eq!(
            f.human(),
            "drive 2 fault buffer r0947, newest first:\n  0: F0070 CB setpoint fault (fault value r0949 = 3) at 2026-11-22 20:31:05\n  1: F0999\nactive warnings (r2110):\n  A0501 Current limit\n"
        );
        let v = serde_json::to_value(&f).unwrap();
        assert_eq!(
            v["faults"][0],
            serde_json::json!({"slot": 0, "number": 70, "code": "F0070", "value": 3, "time": "2026-11-22 20:31:05", "time_words": [7941, 5652, 6667], "text": "CB setpoint fault"})
        );
        assert_eq!(v["warnings"][0]["code"], "A0501");
        let none = FaultsReport::new(
            "b",
            2,
            &uss_client::FaultReport {
                faults: Vec::new(),
                warnings: None,
            },
        );
        assert_eq!(none.human(), "drive 2: no faults recorded (r0947 empty)\n");
    }

    #[test]
    fn watch_lines_carry_the_extra_words_in_use() {
        let mut i = PzdInput::from_words(&[0xFB31, 0, 5, 6], 9, 0, 2_000_000).unwrap();
        (i.online, i.known) = (1, 1);
        let w = WatchLine::new(0.5, 4, &i, 50.0);
        assert_eq!(
            (w.state, w.extra.as_slice(), w.period_ms),
            ("S2", &[5, 6][..], 2.0)
        );
        assert!(w.human().contains("PZD3.. 0x0005 0x0006"), "{}", w.human());
    }
}
