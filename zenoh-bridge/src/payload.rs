//! The payloads, JSON with a version field `v` (this is version 1): what any Zenoh client in any
//! language reads, never ussd's `#[repr(C)]` bytes. A field is only ever added within a version.

use crate::refusal::Refusal;
use serde::{Deserialize, Serialize};
use uss_client::uss_shm_types::diag::RtMode;
use uss_client::view::{BusView, DriveView, InfoView};
use uss_client::{
    BusStatus, DriveDiag, DriveInfo, Health, ParamValue, PzdInput, Quantity, Setpoint, StopCommand,
    state_name,
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
#[derive(Debug, Serialize, schemars::JsonSchema)]
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
    /// The bus status as `ussctl status --json` and Python show it (the client's one view,
    /// `uss_client::view::BusView`): every counter, the line's error, the real-time mode; null
    /// before ussd published one. The fields above are v1's own, the same figures.
    #[serde(rename = "bus_status")]
    pub view: Option<BusView>,
    /// Puts and queries the bridge refused on this bus since it started, per missing right
    /// (its access policy, or control and writes not allowed).
    pub refused: crate::gate::Refused,
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
            view: status.map(|s| BusView::new(bus, s)),
            refused: crate::gate::Refused::default(),
            published_unix_ns: unix_ns(),
        }
    }
}

/// `<prefix>/<bus>/drive/<addr>/in`: one input image.
#[derive(Debug, Serialize, schemars::JsonSchema)]
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
    /// Which latch (the image's `latch_id`; 0 while live): a remote controller re-arms a
    /// latched drive only by naming the latch it saw (`rearm`).
    pub latch_id: u64,
    /// The drive's watchdog time (`watchdog_ms` of ussd's configuration): a remote
    /// controller's samples must come closer together than this.
    pub watchdog_ms: u32,
    /// How often ussd polls the drive now, ms (0: not known yet): its share of the
    /// circulating list (its probe interval while offline).
    pub period_ms: f64,
    /// How long a remote controller waits for what the drive's next poll brings (a re-arm
    /// taken, a stop shown), and the longest gap between this drive's images before they are
    /// stale, ms: ussd's freshness limit for the drive, at least 1 s.
    pub handshake_ms: f64,
    /// S1..S4, `fault`, `not ready`.
    pub state: &'static str,
    pub zsw1: u16,
    pub hiw: u16,
    /// HIW in Hz; null while ussd reads the drive's reference frequency again (the drive came
    /// online, was reset or commissioned): no Hz are known then.
    pub actual_hz: Option<f32>,
    /// The setpoint and control word the poll sent (the setpoint in Hz, null likewise).
    pub setpoint_hz: Option<f32>,
    pub stw1: u16,
    /// PZD3.. as the drive sent them.
    pub words: &'a [u16],
    /// The drive's update period (time since its previous good reply), ms.
    pub age_ms: f64,
    /// How long ago the reply arrived, ms, when the bridge published it.
    pub reply_ms_ago: f64,
    pub published_unix_ns: u64,
    /// The bridge's host's `CLOCK_MONOTONIC` ns when it published this image: the clock of
    /// `latch_id` (a latch's id is the moment it began). A remote controller learns from it
    /// where that clock stands against its own (at least this much ahead: the image took time
    /// to arrive) and says in `asked_ns` of a re-arm, in this clock, when it was asked for.
    pub monotonic_ns: u64,
}

impl<'a> Input<'a> {
    pub fn new(bus: &'a str, drive: u8, i: &'a PzdInput, info: &DriveInfo, stale: bool) -> Self {
        let reference_hz = info.reference();
        let extra = usize::from(i.word_count.saturating_sub(2)).min(i.extra.len());
        let now = uss_client::monotonic_ns();
        Self {
            v: VERSION,
            bus,
            drive,
            sequence: i.sequence,
            stale,
            online: i.online != 0 && !stale,
            control: i.control_name(),
            latch_reason: i.latch_reason_name(),
            latch_id: i.latch_id,
            watchdog_ms: info.watchdog_ms,
            period_ms: i.period_ns as f64 / 1e6,
            handshake_ms: i.handshake_ns() as f64 / 1e6,
            state: state_name(i.zsw1),
            zsw1: i.zsw1,
            hiw: i.hiw,
            actual_hz: reference_hz.map(|r| Setpoint::from_word(i.hiw).hz(r)),
            setpoint_hz: reference_hz.map(|r| Setpoint::from_word(i.sent_setpoint).hz(r)),
            stw1: i.sent_stw1,
            words: &i.extra[..extra],
            age_ms: i.age_ns as f64 / 1e6,
            reply_ms_ago: now.saturating_sub(i.timestamp_ns) as f64 / 1e6,
            published_unix_ns: unix_ns(),
            monotonic_ns: now,
        }
    }
}

/// `<prefix>/<bus>/drive/<addr>/diag`: ussd's counters of the drive, by name.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct Diag<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// True when this is not the drive as it is now: ussd not serving, or the diagnostics
    /// older than ussd's limit for them (a paused ussd, a stalled bus thread); then `online`
    /// is false and the rest is the drive as it was.
    pub stale: bool,
    pub online: bool,
    pub counters: serde_json::Map<String, serde_json::Value>,
    /// Exchange time and response delay, µs: p50, p99, p99.9, max.
    pub exchange_us: [f64; 4],
    pub response_delay_us: [f64; 4],
    /// The drive as `ussctl status --json` shows it (the client's one view,
    /// `uss_client::view::DriveView`): state, ZSW1 and its flags, actual frequency, control
    /// (live or latched, why), monitoring, poll period, judged by the diagnostics' own age.
    #[serde(rename = "drive_status")]
    pub view: DriveView,
    pub published_unix_ns: u64,
}

impl<'a> Diag<'a> {
    /// The payload of `d` as read now; `not_serving`: ussd's heartbeat says it does not serve
    /// the bus. Stale diagnostics never show the drive online (rule 3), by their own age too:
    /// ussd may be paused for up to its heartbeat's limit before it stops counting as serving.
    pub fn new(bus: &'a str, d: &DriveDiag, not_serving: bool) -> Self {
        let us = |q: [u64; 4]| q.map(|n| n as f64 / 1e3);
        let view = DriveView::new(d, uss_client::monotonic_ns()).stale_when(not_serving);
        Self {
            v: VERSION,
            bus,
            drive: d.address,
            stale: view.stale,
            online: view.online,
            counters: d
                .counters
                .named()
                .iter()
                .map(|&(k, v)| (k.to_owned(), v.into()))
                .collect(),
            exchange_us: us(d.exchange_ns),
            response_delay_us: us(d.response_delay_ns),
            view,
            published_unix_ns: unix_ns(),
        }
    }
}

/// `<prefix>/<bus>/drive/<addr>/info`: the one view of what ussd knows of the drive.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct Info<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    #[serde(flatten)]
    pub view: InfoView,
}

impl<'a> Info<'a> {
    pub fn new(bus: &'a str, d: &DriveDiag) -> Self {
        Self {
            v: VERSION,
            bus,
            drive: d.address,
            view: InfoView::of(&d.info),
        }
    }
}

/// The reply to a parameter query: the value in the parameter's own type.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ParamReply<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// As the catalogue writes it: `P1082`, `r0947[2]`.
    pub param: String,
    /// The number, in the parameter's own type and unit (a fixed-point parameter, SIMOREG P303,
    /// as a float of its unit: raw 1000 is 10.0 s).
    #[schemars(with = "f64")]
    pub value: Quantity,
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
            param: p.id(),
            value: p.value(),
            raw: p.raw.as_u32(),
            data_type: p.data_type.to_string(),
            unit: p.unit(),
            name: p.name(),
            shown: p.shown(),
            written,
        }
    }
}

/// The reply to `.../drive/<addr>/describe/<P>`: what the drive says the parameter is (its
/// PROFIdrive descriptive elements), beside what the family's catalogue says.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DescribeReply<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// As the catalogue writes it: `P1120`.
    pub param: String,
    pub family: &'static str,
    /// The drive's data type (descriptive element 1).
    pub data_type: String,
    /// Its elements (element 2: 0 a plain parameter); null: not said.
    pub elements: Option<u16>,
    /// Whether the drive says it is read-only (element 4); null: not said.
    pub read_only: Option<bool>,
    /// Its limits (elements 7 and 8); null: not said (a 3-word channel cannot carry them).
    pub min: Option<f64>,
    pub max: Option<f64>,
    /// The catalogue's name, unit, when it can be changed and factory setting; null where the
    /// catalogue has no entry.
    pub name: Option<&'static str>,
    pub unit: Option<&'static str>,
    pub change: Option<&'static str>,
    pub default: Option<f64>,
}

/// One value a diff found different: as the drive and the other side (a backup, another
/// drive) hold it, shown in its unit; null where that side does not have it.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct Differs {
    pub param: String,
    pub name: &'static str,
    pub drive: Option<String>,
    pub other: Option<String>,
}

/// The reply to `.../drive/<addr>/diff`: the drive compared with the backup file (or drive)
/// the query's payload names.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DiffReply<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// The values that are the same.
    pub same: usize,
    pub differ: Vec<Differs>,
    /// What the file holds that is not compared (the drive's state: P0010, P0004).
    pub ignored: Vec<String>,
}

/// The reply to `.../drive/<addr>/restore`: what the download did (the report of `ussctl
/// param restore`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct RestoreReply<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// Every value of the file is on the drive (and stored, with `eeprom`); false: ask again
    /// to complete it (`cut_short` says why it ended).
    pub complete: bool,
    pub dry_run: bool,
    pub equal: usize,
    pub written: usize,
    pub refused: usize,
    /// Writes whose answer was lost: the drive may hold the value.
    pub unknown: usize,
    /// Link settings kept (address, baud rate, PZD/PKW length).
    pub kept: usize,
    pub cut_short: Option<String>,
    /// What a restore cut short raised and could not put back (the access level, quick
    /// commissioning), in words.
    pub left_raised: Vec<String>,
    /// With `eeprom`: whether RAM was copied to ROM, in words.
    pub stored: Option<String>,
    pub ignored: Vec<String>,
    pub lines: Vec<uss_client::restore::RestoreLine>,
    pub seconds: f64,
}

/// The reply to `.../drive/<addr>/save`: the copy of RAM to ROM.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct SaveReply<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// The parameter that copied (`P0971`).
    pub param: String,
    /// The access level raised for it and put back (`P0003 1 -> 3 -> 1`); null: none needed.
    pub raised: Option<String>,
}

/// `<prefix>/<bus>/drive/<addr>/out`: one sample of a remote controller (only with
/// `--allow-control`). Either `stw1` (with `hz`, the setpoint in Hz of the drive's reference
/// frequency; further PZD words 0) or `words` (every PZD word, STW1 first), or `release`.
#[derive(Debug, Clone, PartialEq, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Out {
    pub v: u32,
    /// Who sends (e.g. `hmi-1:4711`): the bridge takes the drive for the first sender and
    /// refuses every other one until that one releases the drive or falls silent.
    pub from: String,
    /// Grows with every sample of the controller (its clock in ns at start plus a count suits):
    /// a sample not newer than the last one taken is refused as old or repeated.
    pub seq: u64,
    pub stw1: Option<u16>,
    pub hz: Option<f32>,
    pub words: Option<Vec<u16>>,
    /// Hands the drive back: ussd sends its safe command, latched as "released".
    #[serde(default)]
    pub release: bool,
    /// The `latch_id` of the latch this sample acknowledges: a latched drive is re-armed only
    /// by an OFF1 that names its current latch (so a sample sent before the latch, delivered
    /// late, or one that never saw it, re-arms nothing).
    pub rearm: Option<u64>,
    /// With `rearm`, and needed by it: when the deliberate act that asked for the re-arm
    /// happened (the remote program's start, an operator's button), on the bridge's clock (the
    /// images' `monotonic_ns`; a remote converts its own time with the offset they show, taken
    /// so that it errs early). A latch that began after it is not re-armed (docs/SAFETY.md,
    /// REARM): a stop that lands between the ask and the re-arm wins.
    pub asked_ns: Option<u64>,
}

impl Out {
    /// Reads a sample, or says what is wrong with it.
    pub fn parse(bytes: &[u8]) -> Result<Out, SampleError> {
        let out: Out = serde_json::from_slice(bytes).map_err(SampleError::Unreadable)?;
        if out.v != VERSION {
            return Err(SampleError::Version(out.v));
        }
        match (&out.words, out.stw1, out.release) {
            (Some(_), Some(_), _) => Err(SampleError::WordsAndStw1),
            (None, None, false) => Err(SampleError::Empty),
            (Some(_), None, _) if out.hz.is_some() => Err(SampleError::WordsAndHz),
            _ if out.hz.is_some_and(|hz| !hz.is_finite()) => Err(SampleError::HzNotFinite),
            _ => Ok(out),
        }
    }

    /// The PZD words to send to a drive of `pzd` words and reference frequency `reference_hz`.
    pub fn pzd(&self, pzd: usize, reference_hz: f32) -> Result<Vec<u16>, SampleError> {
        if let Some(words) = &self.words {
            return Ok(words.clone());
        }
        let stw1 = self.stw1.unwrap_or(0);
        let mut words = vec![0; pzd.max(1)];
        words[0] = stw1;
        match (self.hz, pzd) {
            (Some(hz), 1) if hz != 0.0 => return Err(SampleError::NoSetpoint),
            // 0 Hz is 0 in any scale: a stop needs no reference.
            (Some(hz), 2..) if hz != 0.0 && (reference_hz <= 0.0 || !reference_hz.is_finite()) => {
                return Err(SampleError::ReferenceUnknown);
            }
            (Some(hz), 2..) if hz != 0.0 => {
                // Refused, never sent as full scale.
                words[1] = Setpoint::try_from_hz(hz, reference_hz)
                    .ok_or(SampleError::HzOutOfRange { hz, reference_hz })?
                    .word();
            }
            _ => {}
        }
        Ok(words)
    }
}

/// What is wrong with a remote controller's sample (the bridge's report says it in these
/// words).
#[derive(Debug, thiserror::Error)]
pub enum SampleError {
    #[error(
        "not a sample: {0}; send e.g. {{\"v\":1,\"from\":\"hmi-1\",\"seq\":1,\"stw1\":1150,\"hz\":0.0}}"
    )]
    Unreadable(serde_json::Error),
    #[error("payload version {0} is not {VERSION}: this uss-zenoh speaks version {VERSION}")]
    Version(u32),
    #[error("give stw1 (and hz) or words, not both")]
    WordsAndStw1,
    #[error("give stw1 (and hz), words, or release")]
    Empty,
    #[error("hz goes with stw1; with words, the setpoint is words[1]")]
    WordsAndHz,
    #[error("hz is not a finite number")]
    HzNotFinite,
    #[error("the drive exchanges only STW1 (pzd = 1): no setpoint")]
    NoSetpoint,
    #[error(
        "hz {hz} is beyond the setpoint's range: -200 % .. +199.99 % of P2000 = {reference_hz:.2} Hz"
    )]
    HzOutOfRange { hz: f32, reference_hz: f32 },
    #[error(
        "hz not sent: ussd is reading the drive's reference frequency (P2000) again (it came online, was reset or commissioned); send again in a moment"
    )]
    ReferenceUnknown,
}

impl SampleError {
    /// Its kind in the error table every front-end speaks: a sample that cannot be right, or
    /// hz while the reference is read again.
    pub const fn kind(&self) -> uss_client::ErrorKind {
        match self {
            Self::ReferenceUnknown => uss_client::ErrorKind::ReferenceUnknown,
            _ => uss_client::ErrorKind::InvalidSample,
        }
    }
}

/// `<prefix>/<bus>/drive/<addr>/control`: what the bridge does with a remote controller's
/// samples of the drive; on every change, and every second while the bridge holds the drive.
#[derive(Debug, Clone, PartialEq, Serialize, schemars::JsonSchema)]
pub struct ControlReport<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// `idle` (the bridge holds no controller for the drive), `controlling` (it does, and
    /// passed the last sample on), `refused` (the last sample was not passed on: `error`
    /// says why), `released` (the remote controller handed the drive back).
    pub state: &'static str,
    /// The remote controller the bridge holds the drive for (its `from`).
    pub holder: Option<String>,
    /// Who sent the last sample, taken or refused (what `state` and `error` are about).
    pub sender: Option<String>,
    /// That sender as the bridge knows it: the name its key carried (`.../as/<name>/...`),
    /// and whether a certificate vouches for it.
    pub peer: Option<String>,
    /// The holder as the bridge knows it (like `peer`).
    pub holder_peer: Option<String>,
    /// The drive as ussd shows it: `live` or `latched`, why, and the latch to name in `rearm`.
    pub control: &'static str,
    pub latch_reason: &'static str,
    pub latch_id: u64,
    /// The sequence number of the last sample passed on.
    pub seq: Option<u64>,
    /// Why the last sample was not passed on, in ussctl's words.
    pub error: Option<String>,
    /// Its kind from the error table every front-end speaks (the C status's snake-case name,
    /// as in an error reply: `refused`, `controlled`, `tripped`, `invalid_sample`, ...) and
    /// that status's number; null while `error` is.
    pub error_kind: Option<&'static str>,
    pub error_code: Option<u8>,
    /// Samples passed on and refused since the bridge started.
    pub taken: u64,
    pub refused: u64,
    pub published_unix_ns: u64,
}

/// The error reply to a query the bridge could not carry out: its words (as `ussctl` says
/// them) and the kind of failure from the error table every front-end speaks: the C status's
/// snake-case name and number, which the Python exception of the same kind is raised for.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ErrorReply<'a> {
    pub v: u32,
    pub error: &'a str,
    /// `refused`, `invalid_argument`, `not_running`, `unknown_drive`, `drive_error`, `timeout`,
    /// ... (`uss_client::kinds::Status`).
    pub kind: &'static str,
    pub code: u8,
}

/// The reply to a stop query, per drive: the command, and the image that shows it went out, or
/// why that was not seen in time (the command was sent all the same).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct StopReply<'a> {
    pub v: u32,
    pub bus: &'a str,
    pub drive: u8,
    /// The stop asked: `OFF1`, `OFF2`, `OFF3`.
    pub command: &'static str,
    /// The stop the drive gets, from the control word that went out: the one asked, or the
    /// stronger one it kept (OFF2 over OFF3 over OFF1: OFF3 asked of a coasting drive leaves it
    /// coasting); null when not confirmed.
    pub sent: Option<&'static str>,
    /// Whether the drive's image showed the command within the bridge's wait.
    pub confirmed: bool,
    /// Why it was not confirmed.
    pub error: Option<String>,
    /// Its kind and number from the error table (as a control report's `error_kind` and
    /// `error_code`: `wait_timeout`, `not_running`, ...); null while `error` is.
    pub error_kind: Option<&'static str>,
    pub error_code: Option<u8>,
    /// The control word that went out.
    pub stw1: Option<u16>,
    pub control: Option<&'static str>,
    pub latch_reason: Option<&'static str>,
    pub state: Option<&'static str>,
}

impl<'a> StopReply<'a> {
    pub fn new(
        bus: &'a str,
        drive: u8,
        command: StopCommand,
        shown: Result<PzdInput, Refusal>,
    ) -> Self {
        let i = shown.as_ref().ok();
        let status = shown.as_ref().err().map(|r| r.kind.status());
        Self {
            v: VERSION,
            bus,
            drive,
            command: command.name(),
            sent: i
                .and_then(|i| StopCommand::of_stw1(i.sent_stw1))
                .map(StopCommand::name),
            confirmed: i.is_some(),
            stw1: i.map(|i| i.sent_stw1),
            control: i.map(PzdInput::control_name),
            latch_reason: i.map(PzdInput::latch_reason_name),
            state: i.map(|i| state_name(i.zsw1)),
            error: shown.err().map(|r| r.text),
            error_kind: status.map(uss_client::kinds::Status::snake),
            error_code: status.map(uss_client::kinds::Status::code),
        }
    }
}

impl<'a> ControlReport<'a> {
    /// A drive the bridge holds no controller for and has taken no sample of.
    pub fn new(bus: &'a str, drive: u8) -> Self {
        Self {
            v: VERSION,
            bus,
            drive,
            state: "idle",
            holder: None,
            sender: None,
            peer: None,
            holder_peer: None,
            control: "unknown",
            latch_reason: "unknown",
            latch_id: 0,
            seq: None,
            error: None,
            error_kind: None,
            error_code: None,
            taken: 0,
            refused: 0,
            published_unix_ns: 0,
        }
    }

    /// Why the last sample was not passed on (its text, kind and code), or none.
    pub fn set_error(&mut self, refusal: Option<&Refusal>) {
        let status = refusal.map(|r| r.kind.status());
        self.error = refusal.map(|r| r.text.clone());
        self.error_kind = status.map(uss_client::kinds::Status::snake);
        self.error_code = status.map(uss_client::kinds::Status::code);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rule 3 at the bridge: diagnostics whose drive's last good reply is older than ussd's
    /// limit for it (a paused ussd, a stalled bus thread) are not the drive as it is, even
    /// while ussd's heartbeat still counts as serving (it may for up to its own, longer limit).
    #[test]
    fn overdue_diagnostics_say_stale_and_not_online_while_ussd_still_counts_as_serving() {
        let now = uss_client::monotonic_ns();
        let d = DriveDiag {
            online: 1,
            last_good_ns: now - 2_000_000_000,
            stale_after_ns: 250_000_000,
            ..DriveDiag::new(1)
        };
        let p = Diag::new("b0", &d, false);
        assert_eq!((p.online, p.stale), (false, true));
        assert_eq!(
            (p.view.online, p.view.stale, p.view.state),
            (false, true, "stale")
        );
        let fresh = DriveDiag {
            last_good_ns: uss_client::monotonic_ns(),
            ..d
        };
        let p = Diag::new("b0", &fresh, false);
        assert_eq!((p.online, p.stale), (true, false));
        // Fresh, but ussd no longer serves the bus: the payload and its view say stale alike.
        let p = Diag::new("b0", &fresh, true);
        assert_eq!((p.online, p.stale), (false, true));
        assert_eq!(
            (p.view.online, p.view.stale, p.view.state),
            (false, true, "stale")
        );
    }

    /// The schema of a payload of type `T`, for `what`: as the bridge writes it (`write`), or
    /// as it reads it (a remote controller's sample).
    fn schema<T: schemars::JsonSchema>(what: &str, write: bool) -> schemars::Schema {
        let settings = schemars::generate::SchemaSettings::draft2020_12();
        let settings = if write {
            settings.for_serialize()
        } else {
            settings.for_deserialize()
        };
        let mut schema = settings.into_generator().into_root_schema_for::<T>();
        schema.insert("description".to_owned(), what.into());
        schema
    }

    /// The shipped schemas (docs/schema/zenoh/) are the ones the payload types make: a changed
    /// field changes a file, which needs a new [`VERSION`] and a line in
    /// docs/schema/CHANGELOG.md.
    #[test]
    fn the_shipped_schemas_are_what_the_payload_types_make() {
        let all = [
            (
                "status",
                schema::<Status<'_>>("<prefix>/<bus>/status", true),
            ),
            (
                "in",
                schema::<Input<'_>>("<prefix>/<bus>/drive/<addr>/in", true),
            ),
            (
                "diag",
                schema::<Diag<'_>>("<prefix>/<bus>/drive/<addr>/diag", true),
            ),
            (
                "info",
                schema::<Info<'_>>("<prefix>/<bus>/drive/<addr>/info", true),
            ),
            (
                "control",
                schema::<ControlReport<'_>>("<prefix>/<bus>/drive/<addr>/control", true),
            ),
            (
                "param",
                schema::<ParamReply<'_>>(
                    "A reply on <prefix>/<bus>/drive/<addr>/param/<P> or .../set/<P>",
                    true,
                ),
            ),
            (
                "describe",
                schema::<DescribeReply<'_>>("<prefix>/<bus>/drive/<addr>/describe/<P>", true),
            ),
            (
                "diff",
                schema::<DiffReply<'_>>("<prefix>/<bus>/drive/<addr>/diff", true),
            ),
            (
                "restore",
                schema::<RestoreReply<'_>>("<prefix>/<bus>/drive/<addr>/restore", true),
            ),
            (
                "save",
                schema::<SaveReply<'_>>("<prefix>/<bus>/drive/<addr>/save", true),
            ),
            (
                "stop",
                schema::<StopReply<'_>>(
                    "A reply on <prefix>/<bus>/drive/<addr>/stop (an array of them on <prefix>/<bus>/stop)",
                    true,
                ),
            ),
            (
                "error",
                schema::<ErrorReply<'_>>("The error reply to any query of uss-zenoh", true),
            ),
            (
                "out",
                schema::<Out>(
                    "A remote controller's sample on <prefix>/<bus>/drive/<addr>/out",
                    false,
                ),
            ),
        ];
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/schema/zenoh");
        let update = std::env::var_os("UPDATE_SCHEMAS").is_some();
        if update {
            std::fs::create_dir_all(&dir).unwrap();
        }
        for (name, schema) in all {
            let made = serde_json::to_string_pretty(&schema).unwrap() + "\n";
            let path = dir.join(format!("{name}.json"));
            if update {
                std::fs::write(&path, &made).unwrap();
                continue;
            }
            assert!(
                std::fs::read_to_string(&path).unwrap_or_default() == made,
                "{}: not what the payload type makes. If a field changed, raise \
                 payload::VERSION, say what changed in docs/schema/CHANGELOG.md and run \
                 `UPDATE_SCHEMAS=1 cargo test -p uss-zenoh schemas`",
                path.display()
            );
        }
    }

    /// A stop's reply says the stop the drive gets, which is the stronger one it kept where it
    /// had one: OFF3 asked of a coasting drive leaves it coasting (OFF2), as `ussctl` says (the
    /// adversarial run saw the reply name only the OFF3 asked).
    /// A remote controller tells a refusal of its sample by its kind, as a local program
    /// tells a `ClientError`'s: a drive held by another controller, a latched drive, a sample
    /// that cannot be right; and a stop not confirmed says why in the same table.
    #[test]
    fn a_refused_sample_and_an_unconfirmed_stop_carry_the_error_tables_kind_and_code() {
        use uss_client::ErrorKind;
        let mut report = ControlReport::new("b", 3);
        let held = Refusal::new(ErrorKind::Controlled, "drive 3 is controlled remotely");
        report.set_error(Some(&held));
        let json = serde_json::to_value(&report).unwrap();
        assert_eq!(json["error"], "drive 3 is controlled remotely");
        assert_eq!(json["error_kind"], ErrorKind::Controlled.status().snake());
        assert_eq!(json["error_code"], ErrorKind::Controlled.status().code());
        report.set_error(None);
        let json = serde_json::to_value(&report).unwrap();
        assert!(json["error"].is_null() && json["error_kind"].is_null());
        assert_eq!(
            SampleError::ReferenceUnknown.kind(),
            ErrorKind::ReferenceUnknown
        );
        assert_eq!(SampleError::HzNotFinite.kind(), ErrorKind::InvalidSample);
        let why = Refusal::new(ErrorKind::WaitTimeout, "sent; not confirmed");
        let reply = StopReply::new("b", 3, StopCommand::Off1, Err(why));
        let json = serde_json::to_value(&reply).unwrap();
        assert_eq!(json["error_kind"], ErrorKind::WaitTimeout.status().snake());
        assert_eq!(json["confirmed"], false);
    }

    #[test]
    fn a_stop_reply_says_the_stronger_stop_a_drive_kept() {
        let coasting = PzdInput {
            sent_stw1: 0x047C,
            latch_command: StopCommand::Off2.code(),
            ..PzdInput::EMPTY
        };
        let reply = StopReply::new("b", 1, StopCommand::Off3, Ok(coasting));
        let json = serde_json::to_value(&reply).unwrap();
        assert_eq!(
            (&json["command"], &json["sent"]),
            (&serde_json::json!("OFF3"), &serde_json::json!("OFF2")),
            "{json}"
        );
        let stopping = PzdInput {
            sent_stw1: 0x047A,
            ..coasting
        };
        let json = serde_json::to_value(StopReply::new("b", 1, StopCommand::Off3, Ok(stopping)));
        assert_eq!(json.unwrap()["sent"], "OFF3");
        let unconfirmed = StopReply::new(
            "b",
            1,
            StopCommand::Off3,
            Err(Refusal::new(uss_client::ErrorKind::WaitTimeout, "gone")),
        );
        assert_eq!(
            serde_json::to_value(unconfirmed).unwrap()["sent"],
            serde_json::Value::Null
        );
    }

    /// SCALE: while ussd reads the drive's reference again (the images say `actual_hz`: null,
    /// the drive's info 0 Hz) a remote's Hz are not scaled by anything: refused, named; a stop
    /// (0 Hz, the same word in any scale) still goes.
    #[test]
    fn hz_are_refused_while_the_reference_is_being_read_and_a_stop_goes() {
        let run = Out::parse(br#"{"v":1,"from":"t","seq":7,"stw1":1151,"hz":25.0}"#).unwrap();
        let unknown = uss_client::DriveInfo::REFERENCE_NOT_KNOWN;
        assert!(matches!(
            run.pzd(2, unknown),
            Err(SampleError::ReferenceUnknown)
        ));
        let stop = Out::parse(br#"{"v":1,"from":"t","seq":8,"stw1":1150,"hz":0.0}"#).unwrap();
        assert_eq!(stop.pzd(2, unknown).unwrap(), [0x047E, 0]);
        let image = PzdInput {
            hiw: 0x2000,
            ..PzdInput::default()
        };
        let info = uss_client::DriveInfo {
            reference_hz: unknown,
            ..uss_client::DriveInfo::UNKNOWN
        };
        let shown = Input::new("b", 1, &image, &info, false);
        assert_eq!((shown.actual_hz, shown.setpoint_hz), (None, None));
    }

    #[test]
    fn a_sample_says_stw1_and_hz_or_words() {
        let out = Out::parse(br#"{"v":1,"from":"t","seq":7,"stw1":1151,"hz":25.0}"#).unwrap();
        assert_eq!(out.pzd(2, 50.0).unwrap(), [0x047F, 0x2000]);
        assert_eq!(out.pzd(4, 50.0).unwrap(), [0x047F, 0x2000, 0, 0]);
        assert!(out.pzd(1, 50.0).is_err());
        // Beyond the word's -200 % .. +199.99 %: refused, not sent as full scale.
        let out = Out::parse(br#"{"v":1,"from":"t","seq":8,"stw1":1151,"hz":5000.0}"#).unwrap();
        assert!(matches!(
            out.pzd(2, 50.0),
            Err(SampleError::HzOutOfRange { .. })
        ));
        let out =
            Out::parse(br#"{"v":1,"from":"t","seq":8,"words":[1150,0,5],"rearm":12}"#).unwrap();
        assert_eq!(out.pzd(2, 50.0).unwrap(), [0x047E, 0, 5]);
        assert!(
            Out::parse(br#"{"v":1,"from":"t","seq":9,"release":true}"#)
                .unwrap()
                .release
        );
        assert_eq!(
            Out::parse(br#"{"v":1,"from":"t","seq":8,"words":[1150],"rearm":12}"#)
                .unwrap()
                .rearm,
            Some(12)
        );
        for bad in [
            &br#"{"v":1,"seq":1,"stw1":1150}"#[..],
            br#"{"v":2,"from":"t","seq":1,"stw1":1150}"#,
            br#"{"v":1,"from":"t","seq":1}"#,
            br#"{"v":1,"from":"t","seq":1,"stw1":1150,"words":[1150]}"#,
            br#"{"v":1,"from":"t","seq":1,"words":[1150],"hz":3}"#,
            br#"{"v":1,"from":"t","seq":1,"stw1":1150,"speed":3}"#,
            br#"{"v":1,"from":"t","seq":-1,"stw1":1150}"#,
            b"run",
        ] {
            assert!(Out::parse(bad).is_err(), "{}", String::from_utf8_lossy(bad));
        }
    }

    proptest::proptest! {
        /// Any payload is read or refused with a reason, never a panic; a read one gives words
        /// or a reason for any drive.
        #[test]
        fn any_payload_is_read_or_refused(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..80),
                                          pzd in 0usize..9, reference in 1.0f32..650.0) {
            if let Ok(out) = Out::parse(&bytes) {
                let _ = out.pzd(pzd, reference);
            }
        }

        #[test]
        fn any_json_sample_is_read_or_refused(seq: u64, stw1: u16, hz in proptest::num::f32::ANY,
                                              pzd in 0usize..9) {
            let text = format!(r#"{{"v":1,"from":"p","seq":{seq},"stw1":{stw1},"hz":{hz}}}"#);
            if let Ok(out) = Out::parse(text.as_bytes()) {
                let words = out.pzd(pzd, 50.0);
                if let Ok(words) = words {
                    proptest::prop_assert_eq!(words[0], stw1);
                }
            }
        }
    }
}
