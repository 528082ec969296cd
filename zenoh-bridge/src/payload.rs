//! The payloads, JSON with a version field `v` (this is version 1): what any Zenoh client in any
//! language reads, never ussd's `#[repr(C)]` bytes. A field is only ever added within a version.

use serde::Serialize;
use uss_client::uss_shm_types::diag::RtMode;
use uss_client::{
    BusStatus, ControlState, DriveDiag, Health, LatchReason, ParamValue, PzdInput, Setpoint,
    StopCommand, Typed, state_name,
};

/// The payload version.
pub const VERSION: u32 = 1;

/// Wall-clock time now, ns since the Unix epoch (comparable across hosts with synchronised
/// clocks, unlike ussd's `CLOCK_MONOTONIC` stamps).
pub fn unix_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// What the bridge can say of ussd: `running`, `line down`, `stopped`, `gone`, `not running`.
pub fn ussd_state(health: Option<&Health>) -> &'static str {
    match health {
        Some(Health::Running { .. }) => "running",
        Some(Health::LineDown { .. }) => "line down",
        Some(Health::Stopped { .. }) => "stopped",
        Some(Health::Gone { .. }) => "gone",
        None => "not running",
    }
}

/// `<prefix>/<bus>/status`.
#[derive(Debug, Serialize)]
pub struct Status<'a> {
    pub v: u32,
    pub bus: &'a str,
    /// See [`ussd_state`]; anything but `running` means the rest is the last known.
    pub ussd: &'static str,
    pub stale: bool,
    pub pid: Option<u32>,
    pub rt_mode: Option<&'static str>,
    pub drives: Option<u8>,
    pub exchanges: Option<u64>,
    pub cycles: Option<u64>,
    pub efficiency: Option<f64>,
    pub mean_exchange_us: Option<f64>,
    pub line_up: Option<bool>,
    pub published_unix_ns: u64,
}

impl<'a> Status<'a> {
    pub fn new(bus: &'a str, health: Option<&Health>, status: Option<&BusStatus>) -> Self {
        let pid = match health {
            Some(
                Health::Running { pid }
                | Health::LineDown { pid, .. }
                | Health::Stopped { pid, .. }
                | Health::Gone { pid, .. },
            ) => Some(*pid),
            None => None,
        };
        Self {
            v: VERSION,
            bus,
            ussd: ussd_state(health),
            stale: !health.is_some_and(Health::is_serving),
            pid,
            rt_mode: status.map(|s| RtMode::try_from(s.rt_mode).map_or("unknown", RtMode::name)),
            drives: status.map(|s| s.drive_count),
            exchanges: status.map(|s| s.exchanges),
            cycles: status.map(|s| s.cycles),
            efficiency: status.and_then(BusStatus::efficiency),
            mean_exchange_us: status.map(|s| s.mean_exchange_ns as f64 / 1e3),
            line_up: status.map(|s| !s.is_line_down()),
            published_unix_ns: unix_ns(),
        }
    }
}

/// `<prefix>/<bus>/drive/<addr>/in`: one input image.
#[derive(Debug, Serialize)]
pub struct Input<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// Good replies of this ussd so far (0: none yet; a restarted ussd counts from 0).
    pub sequence: u64,
    /// True when this is not the drive as it is now: ussd gone, stopped or its line down (then
    /// `online` is false and the rest is the last image).
    pub stale: bool,
    pub online: bool,
    /// `live`, or `latched` (the drive gets its stop command until re-armed).
    pub control: &'static str,
    /// Why it is latched (`none` while live).
    pub latch_reason: &'static str,
    /// S1..S4, `fault`, `not ready`.
    pub state: &'static str,
    pub zsw1: u16,
    pub hiw: u16,
    pub actual_hz: f32,
    /// The setpoint and control word the poll sent.
    pub setpoint_hz: f32,
    pub stw1: u16,
    /// PZD3.. as the drive sent them.
    pub words: &'a [u16],
    /// The drive's update period (time since its previous good reply), ms.
    pub age_ms: f64,
    /// How long ago the reply arrived, ms, when the bridge published it.
    pub reply_ms_ago: f64,
    pub published_unix_ns: u64,
}

impl<'a> Input<'a> {
    pub fn new(bus: &'a str, drive: u8, i: &'a PzdInput, reference_hz: f32, stale: bool) -> Self {
        let extra = usize::from(i.word_count.saturating_sub(2)).min(i.extra.len());
        let now = uss_client::monotonic_ns();
        Self {
            v: VERSION,
            bus,
            drive,
            sequence: i.sequence,
            stale,
            online: i.online != 0 && !stale,
            control: ControlState::try_from(i.control).map_or("unknown", ControlState::name),
            latch_reason: LatchReason::try_from(i.latch_reason)
                .map_or("unknown", LatchReason::name),
            state: state_name(i.zsw1),
            zsw1: i.zsw1,
            hiw: i.hiw,
            actual_hz: Setpoint::from_word(i.hiw).hz(reference_hz),
            setpoint_hz: Setpoint::from_word(i.sent_setpoint).hz(reference_hz),
            stw1: i.sent_stw1,
            words: &i.extra[..extra],
            age_ms: i.age_ns as f64 / 1e6,
            reply_ms_ago: now.saturating_sub(i.timestamp_ns) as f64 / 1e6,
            published_unix_ns: unix_ns(),
        }
    }
}

/// `<prefix>/<bus>/drive/<addr>/diag`: ussd's counters of the drive, by name.
#[derive(Debug, Serialize)]
pub struct Diag<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    pub stale: bool,
    pub online: bool,
    pub counters: serde_json::Map<String, serde_json::Value>,
    /// Exchange time and response delay, µs: p50, p99, p99.9, max.
    pub exchange_us: [f64; 4],
    pub response_delay_us: [f64; 4],
    pub published_unix_ns: u64,
}

impl<'a> Diag<'a> {
    pub fn new(bus: &'a str, d: &DriveDiag, stale: bool) -> Self {
        let us = |q: [u64; 4]| q.map(|n| n as f64 / 1e3);
        Self {
            v: VERSION,
            bus,
            drive: d.address,
            stale,
            online: d.online != 0 && !stale,
            counters: d
                .counters
                .named()
                .iter()
                .map(|&(k, v)| (k.to_owned(), v.into()))
                .collect(),
            exchange_us: us(d.exchange_ns),
            response_delay_us: us(d.response_delay_ns),
            published_unix_ns: unix_ns(),
        }
    }
}

/// `<prefix>/<bus>/drive/<addr>/info`.
#[derive(Debug, Serialize)]
pub struct Info<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// P2000: the frequency of 100 % (0x4000).
    pub reference_hz: f32,
    pub pzd_words: u8,
    pub pkw_words: u8,
    pub watchdog_ms: u32,
    /// What a latched drive gets: OFF1, OFF2, OFF3.
    pub safe_command: &'static str,
    pub params_writable: bool,
}

impl<'a> Info<'a> {
    pub fn new(bus: &'a str, d: &DriveDiag) -> Self {
        let i = &d.info;
        Self {
            v: VERSION,
            bus,
            drive: d.address,
            reference_hz: i.reference_hz,
            pzd_words: i.pzd_words,
            pkw_words: i.pkw_words,
            watchdog_ms: i.watchdog_ms,
            safe_command: i.safe_command().map_or("unknown", StopCommand::name),
            params_writable: i.params_writable != 0,
        }
    }
}

/// The reply to a parameter query: the value in the parameter's own type.
#[derive(Debug, Serialize)]
pub struct ParamReply<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// As the catalogue writes it: `P1082`, `r0947[2]`.
    pub param: String,
    /// The number, in the parameter's own type.
    pub value: Typed,
    /// The word or double word on the wire.
    pub raw: u32,
    pub data_type: String,
    pub unit: &'static str,
    pub name: Option<&'static str>,
    /// As `ussctl param read` shows it: `50.00 Hz`.
    pub shown: String,
    /// For a write: whether it went to EEPROM as well (null for a read).
    pub written: Option<bool>,
}

impl<'a> ParamReply<'a> {
    pub fn new(bus: &'a str, drive: u8, p: &ParamValue, written: Option<bool>) -> Self {
        Self {
            v: VERSION,
            bus,
            drive,
            param: p.param.to_string(),
            value: p.typed(),
            raw: p.raw.as_u32(),
            data_type: p.data_type.to_string(),
            unit: p.unit(),
            name: p.name(),
            shown: p.shown(),
            written,
        }
    }
}
