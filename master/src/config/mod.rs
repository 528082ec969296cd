//! The configuration of `ussd`: which buses to run, how to reach them, and the drives on each.
//!
//! The file is TOML with one `[[bus]]` table per bus and one `[[bus.drive]]` table per drive:
//!
//! ```toml
//! [[bus]]
//! name = "bus0"              # unique, [A-Za-z0-9_-]{1,32}
//! device = "sim"             # "sim" or a serial device path such as "/dev/ttyUSB0"
//! baud = 115200
//! response_timeout_ms = 20.0
//!
//! [[bus.drive]]
//! address = 1
//! pkw = 4
//! pzd = 2
//! sim = "delay=1,drop=0.01"  # only with device = "sim"
//! ```
//!
//! Every key but `name`, `device` and `address` has a default; [`Config::to_toml`] writes them
//! all out. Reading checks everything it can before the daemon starts (ranges, unknown keys,
//! duplicate names and addresses, the device path, the CPU number) and every error names the
//! file, line and column, the bus and drive, the key, and what is allowed. When a file has several
//! errors, the one nearest its start is reported.
//!
//! Spans come from the TOML parser ([`toml::de::DeTable`] holds every key and value as a
//! [`toml::Spanned`]), so line and column always point at the value or key in question. Unknown
//! keys are rejected, as serde's `deny_unknown_fields` would, but with the table they sit in.

use core::fmt;
use core::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Duration;
use toml::Spanned;
use toml::de::{DeTable, DeValue};
use uss_drive_sim::spec::{DriveSpec, SpecError};
use uss_drive_sim::{DriveConfig, FaultPlan};
use uss_protocol::{Address, Baud, Layout, ParamRef, PkwMode, PzdCount};
use uss_shm_types::StopCommand;

/// A whole configuration: one or more buses, each run by its own real-time thread.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    pub buses: Vec<BusConfig>,
}

/// Where a bus lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Device {
    /// The built-in simulated bus: `uss-drive-sim` drives on an in-process virtual wire.
    Sim,
    /// A serial device (RS485 adapter, embedded UART, or a pseudo-terminal).
    Serial(PathBuf),
}

/// How the RS485 driver is switched between sending and receiving (USS.md section 9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Rs485Mode {
    /// The kernel's RS485 mode (TIOCSRS485, RTS on send), for embedded UARTs.
    Kernel,
    /// The adapter switches by itself (most USB adapters).
    Auto,
    /// Nothing to switch (RS232 converters, ptys).
    None,
}

/// What a drive gets when its controller is gone or stopped refreshing within its watchdog time
/// (docs/ARCHITECTURE.md, "Failure model"); the STW1 words are those of USS.md section 7.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SafeCommand {
    /// OFF1: ramp down and stop (STW1 0x047E).
    Off1,
    /// OFF2: coast stop (STW1 0x047C).
    Off2,
    /// OFF3: quick stop (STW1 0x047A).
    Off3,
}

/// One bus: its device, line settings, polling and retry policy, real-time placement and drives.
#[derive(Debug, Clone, PartialEq)]
pub struct BusConfig {
    /// Unique, [`BUS_NAME_MAX`] characters at most from `A-Z a-z 0-9 _ -`: it becomes part of
    /// shared-memory service names.
    pub name: String,
    pub device: Device,
    /// Character rate; the frame is always 8E1 (USS.md section 2).
    pub baud: Baud,
    pub rs485: Rs485Mode,
    /// A 2-wire adapter returns our own bytes: discard them (USS.md section 9).
    pub echo: bool,
    /// The slave's response delay limit, 20 ms by the specification (USS.md section 4).
    pub response_timeout: Duration,
    /// Added to the response timeout for adapters with latency, e.g. 5 ms for USB
    /// (USS.md section 9).
    pub timeout_margin: Duration,
    /// Retries after a failed exchange, like the S7-1200 library's 2 (USS.md section 8).
    pub retries: u8,
    /// Consecutive polls that failed all their retries before a drive is marked offline. An
    /// offline drive stays in the circulating list (USS.md section 4).
    pub offline_after: u32,
    /// An offline drive is polled at most this often.
    pub offline_probe: Duration,
    /// A fixed cycle time for the circulating list, waited out after its last entry; `None` = as
    /// fast as the wire allows (USS.md section 5).
    pub cycle_time: Option<Duration>,
    /// A parameter job with no matching reply in this time ends with a timeout (USS.md section 6).
    pub param_timeout: Duration,
    /// The CPU to pin the bus thread to; `None` = not pinned.
    pub cpu: Option<usize>,
    /// The bus thread's `SCHED_FIFO` priority, 1..=99.
    pub priority: u8,
    /// Fault injector and jitter seed of the simulated bus (unused on a serial bus).
    pub seed: u64,
    pub drives: Vec<DriveEntry>,
}

/// One drive on a bus.
#[derive(Debug, Clone)]
pub struct DriveEntry {
    /// 0..=31, unique per bus (USS.md section 1).
    pub address: Address,
    /// PKW mode (P2013) and PZD words (P2012): must match the drive's settings (USS.md section 3).
    pub layout: Layout,
    /// How many times the drive appears in the circulating list, 1..=16 (USS.md section 5).
    pub weight: u8,
    /// The reference frequency P2000 in Hz: 0x4000 = 100 % (USS.md section 7).
    pub reference_hz: f32,
    /// The controller must refresh the drive's PZD within this time, or the drive gets
    /// [`DriveEntry::safe_command`].
    pub watchdog: Duration,
    pub safe_command: SafeCommand,
    /// `false`: parameter writes are refused (read-only monitoring deployments).
    pub params_writable: bool,
    /// The parameter holding the drive's own telegram-off time (USS.md section 5), read when
    /// the drive comes online; `None` (`monitoring_param = ""`): not checked.
    pub monitoring_param: Option<ParamRef>,
    /// A telegram-off time above this is reported as too long.
    pub monitoring_max: Duration,
    /// Refuse ON unless the drive's telegram monitoring was read and is on within the limit.
    pub require_monitoring: bool,
    /// The simulated drive (config + fault plan), only with `Device::Sim`; built from `sim` with
    /// this entry's address and layout.
    pub sim: Option<DriveSpec>,
    /// The `sim` keys as written (the `uss-sim` drive keys after the address, without `pkw` and
    /// `pzd`); empty for the simulator's defaults and on a serial bus. [`DriveEntry::sim`] is
    /// built from them, and [`Config::to_toml`] writes them back.
    pub sim_keys: String,
}

/// The fault plan inside [`DriveSpec`] has no `PartialEq` (it also counts injected faults), but
/// it is built from [`DriveEntry::sim_keys`] alone: comparing the drive config and those keys
/// compares the simulated drives as configured.
impl PartialEq for DriveEntry {
    fn eq(&self, other: &Self) -> bool {
        let sim_config = |e: &Self| e.sim.as_ref().map(|s| s.config);
        self.address == other.address
            && self.layout == other.layout
            && self.weight == other.weight
            && self.reference_hz.to_bits() == other.reference_hz.to_bits()
            && self.watchdog == other.watchdog
            && self.safe_command == other.safe_command
            && self.params_writable == other.params_writable
            && self.monitoring_param == other.monitoring_param
            && self.monitoring_max == other.monitoring_max
            && self.require_monitoring == other.require_monitoring
            && sim_config(self) == sim_config(other)
            && self.sim_keys == other.sim_keys
    }
}

/// Why a configuration was refused: where, which key, and what is allowed.
#[derive(Debug, thiserror::Error)]
#[error("{origin}{}: {message}", Position(*.line, *.column))]
pub struct ConfigError {
    /// The file name (or whatever [`Config::parse`] was given).
    pub origin: String,
    /// 1-based line; `None` when the error has no place in the text (unreadable file, no bus).
    pub line: Option<usize>,
    /// 1-based column in characters; `None` together with `line`.
    pub column: Option<usize>,
    /// The key the error is about, e.g. `bus[0].drive[2].pzd`; `None` for TOML syntax and I/O
    /// errors.
    pub path: Option<String>,
    /// What is wrong and what is allowed, with the bus and drive it concerns.
    pub message: String,
}

/// `:line:column`, or nothing.
struct Position(Option<usize>, Option<usize>);

impl fmt::Display for Position {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Position(Some(line), Some(column)) => write!(f, ":{line}:{column}"),
            Position(Some(line), None) => write!(f, ":{line}"),
            Position(None, _) => Ok(()),
        }
    }
}

/// The longest bus name.
pub const BUS_NAME_MAX: usize = 32;

impl Rs485Mode {
    pub const ALL: [Rs485Mode; 3] = [Rs485Mode::Kernel, Rs485Mode::Auto, Rs485Mode::None];

    /// The name in the configuration file.
    pub const fn name(self) -> &'static str {
        match self {
            Rs485Mode::Kernel => "kernel",
            Rs485Mode::Auto => "auto",
            Rs485Mode::None => "none",
        }
    }
}

impl SafeCommand {
    pub const ALL: [SafeCommand; 3] = [SafeCommand::Off1, SafeCommand::Off2, SafeCommand::Off3];

    /// The name in the configuration file.
    pub const fn name(self) -> &'static str {
        match self {
            SafeCommand::Off1 => "off1",
            SafeCommand::Off2 => "off2",
            SafeCommand::Off3 => "off3",
        }
    }

    /// The stop command it is; its STW1 (USS.md section 7) keeps bit 10 set so the drive does
    /// not ignore it.
    pub const fn command(self) -> StopCommand {
        match self {
            SafeCommand::Off1 => StopCommand::Off1,
            SafeCommand::Off2 => StopCommand::Off2,
            SafeCommand::Off3 => StopCommand::Off3,
        }
    }
}

/// An integer key: its range, its default (`None` = required) and what it means.
struct IntKey {
    key: &'static str,
    min: i64,
    max: i64,
    default: Option<i64>,
    /// What the key means; messages add " MIN..=MAX" and the note.
    what: &'static str,
    note: &'static str,
}

/// A time key in milliseconds (an integer or a float in the file).
struct MsKey {
    key: &'static str,
    min: f64,
    max: f64,
    default: f64,
    /// What the key means; messages add " MIN..=MAX ms" and the note.
    what: &'static str,
    note: &'static str,
}

/// USS.md section 1.
const ADDRESS: IntKey = IntKey {
    key: "address",
    min: 0,
    max: Address::MAX as i64,
    default: None,
    what: "USS addresses are",
    note: "",
};
/// USS.md section 2; `Baud::new` has the last word.
const BAUD: IntKey = IntKey {
    key: "baud",
    min: 300,
    max: 12_000_000,
    default: Some(115_200),
    what: "baud rates are",
    note: " (USS.md section 2 names 300 to 187500)",
};
/// The S7-1200 library retries twice (USS.md section 8).
const RETRIES: IntKey = IntKey {
    key: "retries",
    min: 0,
    max: 10,
    default: Some(2),
    what: "retries after a failed exchange are",
    note: "",
};
const OFFLINE_AFTER: IntKey = IntKey {
    key: "offline_after",
    min: 1,
    max: 100,
    default: Some(1),
    what: "failed polls before a drive is marked offline are",
    note: "",
};
const PRIORITY: IntKey = IntKey {
    key: "priority",
    min: 1,
    max: 99,
    default: Some(80),
    what: "SCHED_FIFO priorities are",
    note: "",
};
const SEED: IntKey = IntKey {
    key: "seed",
    min: 0,
    max: i64::MAX,
    default: Some(1),
    what: "seeds are",
    note: "",
};
/// P2012, USS.md section 3.
const PZD: IntKey = IntKey {
    key: "pzd",
    min: 0,
    max: 16,
    default: Some(2),
    what: "PZD words are",
    note: "",
};
/// A drive may appear several times in the circulating list (USS.md section 5).
const WEIGHT: IntKey = IntKey {
    key: "weight",
    min: 1,
    max: 16,
    default: Some(1),
    what: "poll weights (entries in the circulating list) are",
    note: "",
};

/// The specification's limit is 20 ms (USS.md section 4).
const RESPONSE_TIMEOUT: MsKey = MsKey {
    key: "response_timeout_ms",
    min: 1.0,
    max: 1000.0,
    default: 20.0,
    what: "the response timeout is",
    note: " (USS.md section 4: a slave answers within 20 ms)",
};
/// USB adapters add latency (USS.md section 9).
const TIMEOUT_MARGIN: MsKey = MsKey {
    key: "timeout_margin_ms",
    min: 0.0,
    max: 1000.0,
    default: 0.0,
    what: "the timeout margin is",
    note: "",
};
const OFFLINE_PROBE: MsKey = MsKey {
    key: "offline_probe_ms",
    min: 10.0,
    max: 60_000.0,
    default: 500.0,
    what: "the poll interval of an offline drive is",
    note: "",
};
/// USS.md section 5: a master may enforce a fixed cycle time.
const CYCLE_TIME: MsKey = MsKey {
    key: "cycle_time_ms",
    min: 0.0,
    max: 60_000.0,
    default: 0.0,
    what: "the cycle time (0 = as fast as the wire allows) is",
    note: "",
};
const PARAM_TIMEOUT: MsKey = MsKey {
    key: "param_timeout_ms",
    min: 10.0,
    max: 600_000.0,
    default: 2000.0,
    what: "the parameter job timeout is",
    note: "",
};
const WATCHDOG: MsKey = MsKey {
    key: "watchdog_ms",
    min: 1.0,
    max: 60_000.0,
    default: 100.0,
    what: "the controller watchdog is",
    note: "",
};
/// The longest telegram-off time that counts as "on" (USS.md section 5).
const MONITORING_MAX: MsKey = MsKey {
    key: "monitoring_max_ms",
    min: 1.0,
    max: 60_000.0,
    default: 1000.0,
    what: "the longest acceptable telegram-off time is",
    note: "",
};
/// MICROMASTER 4 / G110 / CU240S: P2014, index 1 = the RS485 COM link (USS.md section 5).
const MONITORING_PARAM_DEFAULT: &str = "P2014.1";

/// The reference frequency P2000 is above 0 Hz and at most this (the MICROMASTER/G120 range of P2000; scaling in USS.md section 7).
const REFERENCE_HZ_MAX: f32 = 650.0;
const REFERENCE_HZ_DEFAULT: f32 = 50.0;

const BUS_KEYS: [&str; 16] = [
    "name",
    "device",
    "baud",
    "rs485",
    "echo",
    "response_timeout_ms",
    "timeout_margin_ms",
    "retries",
    "offline_after",
    "offline_probe_ms",
    "cycle_time_ms",
    "param_timeout_ms",
    "cpu",
    "priority",
    "seed",
    "drive",
];
const DRIVE_KEYS: [&str; 12] = [
    "address",
    "pkw",
    "pzd",
    "weight",
    "reference_hz",
    "watchdog_ms",
    "safe_command",
    "params_writable",
    "monitoring_param",
    "monitoring_max_ms",
    "require_monitoring",
    "sim",
];

/// The `sim` keys of the embedded default's drives.
const EMBEDDED_SIM_KEYS: &str = "p2014=100";

/// The device name of the built-in simulated bus.
const SIM_DEVICE: &str = "sim";

/// PKW 4, PZD 2: the layout without `pkw`/`pzd` keys, and the simulator's default.
const DEFAULT_LAYOUT: Layout = Layout::new(PkwMode::Four, DEFAULT_PZD);

/// Checked at compile time: an `Err` fails the build, not the daemon.
const DEFAULT_PZD: PzdCount = match PzdCount::new(2) {
    Ok(pzd) => pzd,
    Err(_) => panic!("2 PZD words are in range"),
};
/// Checked at compile time: an `Err` fails the build, not the daemon.
const DEFAULT_BAUD: Baud = match Baud::new(115_200) {
    Ok(baud) => baud,
    Err(_) => panic!("115200 baud is in range"),
};

impl Config {
    /// Reads and checks a configuration file. An unreadable file is a [`ConfigError`] without a
    /// line.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let origin = path.display().to_string();
        match std::fs::read_to_string(path) {
            Ok(text) => Config::parse(&text, &origin),
            Err(e) => Err(ConfigError {
                origin,
                line: None,
                column: None,
                path: None,
                message: format!("cannot read the configuration: {e}"),
            }),
        }
    }

    /// Parses and checks a configuration; `origin` names it in errors (usually the file name).
    pub fn parse(text: &str, origin: &str) -> Result<Config, ConfigError> {
        let root = DeTable::parse(text).map_err(|e| {
            let (line, column) = e.span().map(|s| position(text, s.start)).unzip();
            ConfigError {
                origin: origin.to_owned(),
                line,
                column,
                path: None,
                message: format!("invalid TOML: {}", e.message()),
            }
        })?;
        let mut checker = Checker::new(text, origin);
        let config = checker.config(root.get_ref());
        match (checker.first, config) {
            (Some((_, error)), _) => Err(error),
            (None, Ok(config)) => Ok(config),
            // `Reported` is only made by `Checker::fail`, which always records an error.
            (None, Err(Reported)) => unreachable!("a check failed without recording an error"),
        }
    }

    /// What `ussd` runs with no arguments: one simulated bus "bus0" at 115200 baud with four
    /// drives at addresses 1..=4 (PKW 4, PZD 2; drive 3 with pkw = 127), each with the
    /// simulator's defaults.
    pub fn embedded_default() -> Config {
        let drives = Address::all()
            .filter(|a| (1..=4).contains(&a.get()))
            .map(|address| {
                let layout = if address.get() == 3 {
                    Layout::new(PkwMode::Variable, DEFAULT_PZD)
                } else {
                    DEFAULT_LAYOUT
                };
                // The simulated drives watch their telegrams as we recommend real ones to
                // (P2014.1 = 100 ms, USS.md section 5): ussd reports the monitoring on.
                let keys = EMBEDDED_SIM_KEYS;
                DriveEntry {
                    sim: sim_drive(address, layout, keys).ok(),
                    sim_keys: keys.to_owned(),
                    ..DriveEntry::with_defaults(address, layout)
                }
            })
            .collect();
        Config {
            buses: vec![BusConfig::with_defaults("bus0", Device::Sim, drives)],
        }
    }

    /// The effective configuration with every default filled in, as TOML that [`Config::parse`]
    /// accepts again (for `ussd --check-config`). Times are written in exact decimal
    /// milliseconds, so a configuration that came from [`Config::parse`] round-trips unchanged.
    pub fn to_toml(&self) -> String {
        self.to_string()
    }
}

impl BusConfig {
    /// A bus with every optional key at its default.
    pub fn with_defaults(name: &str, device: Device, drives: Vec<DriveEntry>) -> BusConfig {
        BusConfig {
            name: name.to_owned(),
            device,
            baud: DEFAULT_BAUD,
            rs485: Rs485Mode::None,
            echo: false,
            response_timeout: millis(RESPONSE_TIMEOUT.default),
            timeout_margin: millis(TIMEOUT_MARGIN.default),
            retries: RETRIES.default_value() as u8,
            offline_after: OFFLINE_AFTER.default_value() as u32,
            offline_probe: millis(OFFLINE_PROBE.default),
            cycle_time: None,
            param_timeout: millis(PARAM_TIMEOUT.default),
            cpu: None,
            priority: PRIORITY.default_value() as u8,
            seed: SEED.default_value() as u64,
            drives,
        }
    }
}

impl DriveEntry {
    /// A drive with every optional key at its default and no simulated counterpart.
    pub fn with_defaults(address: Address, layout: Layout) -> DriveEntry {
        DriveEntry {
            address,
            layout,
            weight: WEIGHT.default_value() as u8,
            reference_hz: REFERENCE_HZ_DEFAULT,
            watchdog: millis(WATCHDOG.default),
            safe_command: SafeCommand::Off1,
            params_writable: true,
            monitoring_param: MONITORING_PARAM_DEFAULT.parse().ok(),
            monitoring_max: millis(MONITORING_MAX.default),
            require_monitoring: false,
            sim: None,
            sim_keys: String::new(),
        }
    }
}

impl IntKey {
    /// The default of an optional key, for [`BusConfig::with_defaults`] and
    /// [`DriveEntry::with_defaults`] (a required key has none and reads as its minimum).
    const fn default_value(&self) -> i64 {
        match self.default {
            Some(default) => default,
            None => self.min,
        }
    }
}

/// A checked, finite, non-negative time in milliseconds, to the nanosecond.
fn millis(ms: f64) -> Duration {
    Duration::from_nanos((ms * 1e6).round() as u64)
}

/// A duration as exact decimal milliseconds with at least one decimal (`20.0`, `0.0955`).
fn millis_text(d: Duration) -> String {
    let nanos = d.as_nanos();
    let (whole, fraction) = (nanos / 1_000_000, nanos % 1_000_000);
    let fraction = format!("{fraction:06}");
    let fraction = fraction.trim_end_matches('0');
    if fraction.is_empty() {
        format!("{whole}.0")
    } else {
        format!("{whole}.{fraction}")
    }
}

/// A TOML string literal.
fn quoted(s: &str) -> String {
    toml::Value::String(s.to_owned()).to_string()
}

/// The simulator's drive with its own defaults (what `uss-sim --drive N` builds) at `layout`.
fn default_sim_drive(address: Address, layout: Layout) -> DriveSpec {
    DriveSpec {
        config: DriveConfig::new(address, layout),
        faults: FaultPlan::new(),
    }
}

/// The simulated drive for `sim` keys; the address and layout come from the drive table.
fn sim_drive(address: Address, layout: Layout, keys: &str) -> Result<DriveSpec, SpecError> {
    if keys.trim().is_empty() {
        return Ok(default_sim_drive(address, layout));
    }
    let mut spec: DriveSpec = format!("{address}:{keys}").parse()?;
    spec.config.layout = layout;
    Ok(spec)
}

/// The first `pkw` or `pzd` key in `sim` keys, if any.
fn layout_key_in_sim(keys: &str) -> Option<&str> {
    keys.split(',')
        .map(|option| option.split_once('=').map_or(option, |(key, _)| key).trim())
        .find(|key| matches!(*key, "pkw" | "pzd"))
}

/// Whether `name` is a valid bus name: 1..=32 of `A-Z a-z 0-9 _ -`.
fn valid_bus_name(name: &str) -> bool {
    (1..=BUS_NAME_MAX).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// 1-based line and character column of a byte offset.
fn position(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (
        before.matches('\n').count() + 1,
        before[line_start..].chars().count() + 1,
    )
}

impl fmt::Display for Config {
    /// The TOML of [`Config::to_toml`].
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "# ussd configuration: the effective settings, every default filled in"
        )?;
        for bus in &self.buses {
            writeln!(f)?;
            write_bus(f, bus)?;
        }
        Ok(())
    }
}

fn write_bus(f: &mut fmt::Formatter<'_>, bus: &BusConfig) -> fmt::Result {
    let device = match &bus.device {
        Device::Sim => SIM_DEVICE.into(),
        // Paths from `Config::parse` came from TOML strings, so they are UTF-8.
        Device::Serial(path) => path.to_string_lossy(),
    };
    writeln!(f, "[[bus]]")?;
    writeln!(f, "name = {}", quoted(&bus.name))?;
    writeln!(f, "device = {}", quoted(&device))?;
    writeln!(f, "baud = {}", bus.baud)?;
    writeln!(f, "rs485 = {}", quoted(bus.rs485.name()))?;
    writeln!(f, "echo = {}", bus.echo)?;
    writeln!(
        f,
        "response_timeout_ms = {}",
        millis_text(bus.response_timeout)
    )?;
    writeln!(f, "timeout_margin_ms = {}", millis_text(bus.timeout_margin))?;
    writeln!(f, "retries = {}", bus.retries)?;
    writeln!(f, "offline_after = {}", bus.offline_after)?;
    writeln!(f, "offline_probe_ms = {}", millis_text(bus.offline_probe))?;
    let cycle_time = bus.cycle_time.unwrap_or_default();
    writeln!(f, "cycle_time_ms = {}", millis_text(cycle_time))?;
    writeln!(f, "param_timeout_ms = {}", millis_text(bus.param_timeout))?;
    match bus.cpu {
        Some(cpu) => writeln!(f, "cpu = {cpu}")?,
        None => writeln!(f, "# cpu: not pinned")?,
    }
    writeln!(f, "priority = {}", bus.priority)?;
    if bus.device == Device::Sim {
        writeln!(f, "seed = {}", bus.seed)?;
    }
    for drive in &bus.drives {
        writeln!(f)?;
        writeln!(f, "[[bus.drive]]")?;
        writeln!(f, "address = {}", drive.address)?;
        writeln!(f, "pkw = {}", drive.layout.pkw.p2013())?;
        writeln!(f, "pzd = {}", drive.layout.pzd.get())?;
        writeln!(f, "weight = {}", drive.weight)?;
        // Debug keeps the ".0" and prints the shortest text that reads back as the same f32.
        writeln!(f, "reference_hz = {:?}", drive.reference_hz)?;
        writeln!(f, "watchdog_ms = {}", millis_text(drive.watchdog))?;
        writeln!(f, "safe_command = {}", quoted(drive.safe_command.name()))?;
        writeln!(f, "params_writable = {}", drive.params_writable)?;
        let param = drive
            .monitoring_param
            .map(|p| p.to_string())
            .unwrap_or_default();
        writeln!(f, "monitoring_param = {}", quoted(&param))?;
        writeln!(
            f,
            "monitoring_max_ms = {}",
            millis_text(drive.monitoring_max)
        )?;
        writeln!(f, "require_monitoring = {}", drive.require_monitoring)?;
        if bus.device == Device::Sim {
            writeln!(f, "sim = {}", quoted(&drive.sim_keys))?;
        }
    }
    Ok(())
}

/// A check failed and its error is recorded in the [`Checker`]: only [`Checker::fail`] makes
/// one, and other checks pass it on.
#[derive(Debug, Clone, Copy)]
struct Reported;

type Checked<T> = Result<T, Reported>;

/// Where in the file a check is: the key path (`bus[0].drive[2]`) and the words for messages
/// (`bus "bus0" drive 3`).
#[derive(Debug, Clone)]
struct Scope {
    path: String,
    label: String,
}

/// One table of the file, with the scope its keys belong to.
struct Table<'a, 't> {
    entries: &'a DeTable<'t>,
    /// The table's span: its `[[header]]`, or the whole inline table.
    span: Range<usize>,
    scope: Scope,
}

type Value<'t> = Spanned<DeValue<'t>>;

/// The tables of an array of tables, each with its span.
type Tables<'a, 't> = Vec<(Range<usize>, &'a DeTable<'t>)>;

impl<'a, 't> Table<'a, 't> {
    fn get(&self, key: &str) -> Option<&'a Value<'t>> {
        self.entries.get(key)
    }

    /// The string value of `key`, if it is one (for labels and device kinds, before checking).
    fn str(&self, key: &str) -> Option<&'a str> {
        match self.get(key).map(Spanned::get_ref) {
            Some(DeValue::String(s)) => Some(s.as_ref()),
            _ => None,
        }
    }
}

/// Checks a parsed file and records the error nearest its start.
struct Checker<'t> {
    text: &'t str,
    origin: &'t str,
    /// CPUs this process may run on; `None` when the system does not say.
    online_cpus: Option<usize>,
    /// The error with the smallest byte offset so far (errors without a place sort last).
    first: Option<(usize, ConfigError)>,
}

impl<'t> Checker<'t> {
    fn new(text: &'t str, origin: &'t str) -> Self {
        Checker {
            text,
            origin,
            online_cpus: std::thread::available_parallelism().ok().map(usize::from),
            first: None,
        }
    }

    /// Records an error at `span` (or nowhere) about `path`.
    fn fail<T>(&mut self, span: Option<Range<usize>>, path: &str, message: String) -> Checked<T> {
        let offset = span.as_ref().map_or(usize::MAX, |s| s.start);
        if self.first.as_ref().is_none_or(|(first, _)| offset < *first) {
            let (line, column) = span.map(|s| position(self.text, s.start)).unzip();
            let error = ConfigError {
                origin: self.origin.to_owned(),
                line,
                column,
                path: Some(path.to_owned()),
                message,
            };
            self.first = Some((offset, error));
        }
        Err(Reported)
    }

    /// Records an error about `key` of the table in `scope`.
    fn fail_at<T>(
        &mut self,
        scope: &Scope,
        key: &str,
        span: Range<usize>,
        problem: &str,
    ) -> Checked<T> {
        let path = if scope.path.is_empty() {
            key.to_owned()
        } else {
            format!("{}.{key}", scope.path)
        };
        let message = if scope.label.is_empty() {
            problem.to_owned()
        } else {
            format!("{}: {problem}", scope.label)
        };
        self.fail(Some(span), &path, message)
    }

    /// The value as written in the file.
    fn written(&self, value: &Value<'_>) -> &'t str {
        self.text.get(value.span()).unwrap_or_default().trim()
    }

    fn wrong_type<T>(
        &mut self,
        t: &Table<'_, '_>,
        key: &str,
        value: &Value<'_>,
        expected: &str,
        allowed: &str,
    ) -> Checked<T> {
        let what = match value.get_ref() {
            DeValue::Table(_) => format!("{key} is a table, not"),
            DeValue::Array(_) => format!("{key} is an array, not"),
            _ => format!("{key} = {} is not", self.written(value)),
        };
        let problem = format!("{what} {expected}: {allowed}");
        self.fail_at(&t.scope, key, value.span(), &problem)
    }

    fn out_of_range<T>(
        &mut self,
        t: &Table<'_, '_>,
        key: &str,
        value: &Value<'_>,
        allowed: &str,
    ) -> Checked<T> {
        let problem = format!("{key} = {} is out of range: {allowed}", self.written(value));
        self.fail_at(&t.scope, key, value.span(), &problem)
    }

    /// Unknown keys are errors, like serde's `deny_unknown_fields`.
    fn known_keys(&mut self, t: &Table<'_, '_>, known: &[&str], table: &str) {
        for key in t.entries.keys() {
            if !known.contains(&key.get_ref().as_ref()) {
                let problem = format!(
                    "unknown key `{}`: {table} takes {}",
                    key.get_ref(),
                    known.join(", ")
                );
                // The error is recorded; checking goes on with the known keys.
                let _ = self.fail_at::<()>(&t.scope, key.get_ref(), key.span(), &problem);
            }
        }
    }

    /// An integer key, range checked, then made a `T` by `convert` (a `None` from it is out of
    /// range too).
    fn int<T>(
        &mut self,
        t: &Table<'_, '_>,
        rule: &IntKey,
        convert: impl FnOnce(i64) -> Option<T>,
    ) -> Checked<T> {
        let allowed = format!("{} {}..={}{}", rule.what, rule.min, rule.max, rule.note);
        let (n, value) = match (t.get(rule.key), rule.default) {
            (Some(value), _) => (self.integer(t, rule.key, value, &allowed)?, Some(value)),
            (None, Some(default)) => (default, None),
            (None, None) => {
                let problem = format!("{} is missing: {allowed}", rule.key);
                return self.fail_at(&t.scope, rule.key, t.span.clone(), &problem);
            }
        };
        match (rule.min..=rule.max)
            .contains(&n)
            .then(|| convert(n))
            .flatten()
        {
            Some(converted) => Ok(converted),
            None => match value {
                Some(value) => self.out_of_range(t, rule.key, value, &allowed),
                // Defaults are in range; a failing default is reported at the table.
                None => self.fail_at(&t.scope, rule.key, t.span.clone(), &allowed),
            },
        }
    }

    /// The value of an integer, or a wrong-type error.
    fn integer(
        &mut self,
        t: &Table<'_, '_>,
        key: &str,
        value: &Value<'_>,
        allowed: &str,
    ) -> Checked<i64> {
        match value.get_ref() {
            DeValue::Integer(i) => match i64::from_str_radix(i.as_str(), i.radix()) {
                Ok(n) => Ok(n),
                Err(_) => self.out_of_range(t, key, value, allowed),
            },
            _ => self.wrong_type(t, key, value, "an integer", allowed),
        }
    }

    /// A number (integer or float), parsed from its own text so an `f32` reads exactly.
    fn number<N: core::str::FromStr>(
        &mut self,
        t: &Table<'_, '_>,
        key: &str,
        value: &Value<'_>,
        allowed: &str,
    ) -> Checked<N> {
        let parsed = match value.get_ref() {
            DeValue::Integer(i) => i64::from_str_radix(i.as_str(), i.radix())
                .ok()
                .and_then(|n| n.to_string().parse().ok()),
            DeValue::Float(x) => x.as_str().parse().ok(),
            _ => return self.wrong_type(t, key, value, "a number", allowed),
        };
        match parsed {
            Some(n) => Ok(n),
            None => self.out_of_range(t, key, value, allowed),
        }
    }

    /// A time in milliseconds, range checked.
    fn ms(&mut self, t: &Table<'_, '_>, rule: &MsKey) -> Checked<Duration> {
        let allowed = format!("{} {}..={} ms{}", rule.what, rule.min, rule.max, rule.note);
        let Some(value) = t.get(rule.key) else {
            return Ok(millis(rule.default));
        };
        let ms: f64 = self.number(t, rule.key, value, &allowed)?;
        // NaN is in no range.
        if (rule.min..=rule.max).contains(&ms) {
            Ok(millis(ms))
        } else {
            self.out_of_range(t, rule.key, value, &allowed)
        }
    }

    /// A string key and its span; `None` when absent.
    fn string<'a>(
        &mut self,
        t: &Table<'a, 't>,
        key: &str,
        allowed: &str,
    ) -> Checked<Option<(&'a str, Range<usize>)>> {
        let Some(value) = t.get(key) else {
            return Ok(None);
        };
        match value.get_ref() {
            DeValue::String(s) => Ok(Some((s.as_ref(), value.span()))),
            _ => self.wrong_type(t, key, value, "a string", allowed),
        }
    }

    fn boolean(&mut self, t: &Table<'_, '_>, key: &str, default: bool) -> Checked<bool> {
        let Some(value) = t.get(key) else {
            return Ok(default);
        };
        match value.get_ref() {
            DeValue::Boolean(b) => Ok(*b),
            _ => self.wrong_type(t, key, value, "a boolean", "write true or false"),
        }
    }

    /// One of a few names (`rs485`, `safe_command`).
    fn choice<T: Copy>(
        &mut self,
        t: &Table<'_, 't>,
        key: &str,
        options: &[T],
        name: fn(T) -> &'static str,
        allowed: &str,
    ) -> Checked<Option<T>> {
        let Some((written, span)) = self.string(t, key, allowed)? else {
            return Ok(None);
        };
        if let Some(option) = options.iter().copied().find(|o| name(*o) == written) {
            Ok(Some(option))
        } else {
            let problem = format!("{key} = {written:?} is not allowed: {allowed}");
            self.fail_at(&t.scope, key, span, &problem)
        }
    }

    /// The tables of an array-of-tables key (`bus`, `drive`) with their spans; `Ok(None)` when
    /// the key is absent.
    fn tables<'a>(
        &mut self,
        t: &Table<'a, 't>,
        key: &str,
        header: &str,
    ) -> Checked<Option<Tables<'a, 't>>> {
        let Some(value) = t.get(key) else {
            return Ok(None);
        };
        let allowed = format!("write a {header} table for each");
        let DeValue::Array(items) = value.get_ref() else {
            return self.wrong_type(t, key, value, &format!("{header} tables"), &allowed);
        };
        if items.is_empty() {
            let problem = format!("{key} = [] is empty: {allowed}");
            return self.fail_at(&t.scope, key, value.span(), &problem);
        }
        let mut tables = Vec::with_capacity(items.len());
        let mut all_tables = Ok(());
        for (i, item) in items.iter().enumerate() {
            if let DeValue::Table(table) = item.get_ref() {
                tables.push((item.span(), table));
            } else {
                let problem = format!("{key}[{i}] is not a table: {allowed}");
                all_tables = self.fail_at(&t.scope, key, item.span(), &problem);
            }
        }
        all_tables.map(|()| Some(tables))
    }

    fn config(&mut self, root: &DeTable<'t>) -> Checked<Config> {
        let root = Table {
            entries: root,
            span: 0..0,
            scope: Scope {
                path: String::new(),
                label: String::new(),
            },
        };
        self.known_keys(&root, &["bus"], "the file");
        let Some(tables) = self.tables(&root, "bus", "[[bus]]")? else {
            let problem = "no [[bus]] table: a configuration needs at least one bus";
            return self.fail(None, "bus", problem.to_owned());
        };
        let mut names = Vec::with_capacity(tables.len());
        let buses: Vec<_> = tables
            .into_iter()
            .enumerate()
            .map(|(index, (span, entries))| self.bus(index, span, entries, &mut names))
            .collect();
        Ok(Config {
            buses: buses.into_iter().collect::<Checked<_>>()?,
        })
    }

    /// One `[[bus]]` table; `names` holds the bus names seen so far with their lines.
    fn bus<'a>(
        &mut self,
        index: usize,
        span: Range<usize>,
        entries: &'a DeTable<'t>,
        names: &mut Vec<(&'a str, usize)>,
    ) -> Checked<BusConfig> {
        let path = format!("bus[{index}]");
        let mut t = Table {
            entries,
            span,
            scope: Scope {
                label: path.clone(),
                path,
            },
        };
        let name = self.bus_name(&t, names);
        if let Some(name) = t.str("name") {
            t.scope.label = format!("bus {name:?}");
        }
        self.known_keys(&t, &BUS_KEYS, "a [[bus]] table");
        // Whether the text asks for the simulated bus, even when the device is bad: the `seed`
        // and `sim` checks depend on it.
        let on_sim = t.str("device").map(|d| d == SIM_DEVICE);
        let device = self.device(&t);
        let baud = self.int(&t, &BAUD, |n| Baud::new(u32::try_from(n).ok()?).ok());
        let rs485 = self.choice(
            &t,
            "rs485",
            &Rs485Mode::ALL,
            Rs485Mode::name,
            "use \"kernel\" (TIOCSRS485, RTS on send), \"auto\" (the adapter switches itself) \
             or \"none\"",
        );
        let echo = self.boolean(&t, "echo", false);
        let response_timeout = self.ms(&t, &RESPONSE_TIMEOUT);
        let timeout_margin = self.ms(&t, &TIMEOUT_MARGIN);
        let retries = self.int(&t, &RETRIES, |n| u8::try_from(n).ok());
        let offline_after = self.int(&t, &OFFLINE_AFTER, |n| u32::try_from(n).ok());
        let offline_probe = self.ms(&t, &OFFLINE_PROBE);
        let cycle_time = self.ms(&t, &CYCLE_TIME);
        let param_timeout = self.ms(&t, &PARAM_TIMEOUT);
        let cpu = self.cpu(&t);
        let priority = self.int(&t, &PRIORITY, |n| u8::try_from(n).ok());
        let seed = self
            .only_on_sim(&t, "seed", on_sim)
            .and_then(|()| self.int(&t, &SEED, |n| u64::try_from(n).ok()));
        let drives = self.drives(&t, on_sim);
        Ok(BusConfig {
            name: name?.to_owned(),
            device: device?,
            baud: baud?,
            rs485: rs485?.unwrap_or(Rs485Mode::None),
            echo: echo?,
            response_timeout: response_timeout?,
            timeout_margin: timeout_margin?,
            retries: retries?,
            offline_after: offline_after?,
            offline_probe: offline_probe?,
            cycle_time: Some(cycle_time?).filter(|d| !d.is_zero()),
            param_timeout: param_timeout?,
            cpu: cpu?,
            priority: priority?,
            seed: seed?,
            drives: drives?,
        })
    }

    fn bus_name<'a>(
        &mut self,
        t: &Table<'a, 't>,
        names: &mut Vec<(&'a str, usize)>,
    ) -> Checked<&'a str> {
        let allowed = format!(
            "a bus name is 1..={BUS_NAME_MAX} characters from A-Z, a-z, 0-9, _ and - \
             (it becomes part of shared-memory service names)"
        );
        let Some((name, span)) = self.string(t, "name", &allowed)? else {
            let problem = format!("name is missing: {allowed}");
            return self.fail_at(&t.scope, "name", t.span.clone(), &problem);
        };
        if !valid_bus_name(name) {
            let problem = format!("name = {name:?} is not allowed: {allowed}");
            return self.fail_at(&t.scope, "name", span, &problem);
        }
        if let Some((_, first)) = names.iter().find(|(n, _)| *n == name) {
            let problem = format!(
                "name {name:?} is used twice (first at line {first}): every bus needs its own name"
            );
            return self.fail_at(&t.scope, "name", span, &problem);
        }
        names.push((name, position(self.text, span.start).0));
        Ok(name)
    }

    fn device(&mut self, t: &Table<'_, 't>) -> Checked<Device> {
        let allowed =
            "device is \"sim\" (the built-in simulated bus) or the path of a serial device";
        let Some((device, span)) = self.string(t, "device", allowed)? else {
            let problem = format!("device is missing: {allowed}");
            return self.fail_at(&t.scope, "device", t.span.clone(), &problem);
        };
        if device == SIM_DEVICE {
            Ok(Device::Sim)
        } else if device.is_empty() {
            let problem = format!("device = \"\" is not allowed: {allowed}");
            self.fail_at(&t.scope, "device", span, &problem)
        } else if Path::new(device).exists() || Path::new(device).is_absolute() {
            // An absolute path may be absent now (an adapter plugged in later, a udev name):
            // ussd starts that bus line down and opens the device when it appears.
            Ok(Device::Serial(PathBuf::from(device)))
        } else {
            let problem = format!(
                "unknown device: {device} does not exist (a device that may be absent when ussd \
                 starts needs its absolute path): {allowed}"
            );
            self.fail_at(&t.scope, "device", span, &problem)
        }
    }

    /// `cpu` must name an online CPU; not checked when the system does not say how many.
    fn cpu(&mut self, t: &Table<'_, '_>) -> Checked<Option<usize>> {
        let Some(value) = t.get("cpu") else {
            return Ok(None);
        };
        let allowed = match self.online_cpus {
            Some(n) => format!(
                "this machine has {n} online CPU{}: cpu is 0..={}",
                if n == 1 { "" } else { "s" },
                n - 1
            ),
            None => "cpu is a CPU number from 0".to_owned(),
        };
        let cpu = self.integer(t, "cpu", value, &allowed)?;
        match usize::try_from(cpu) {
            Ok(cpu) if self.online_cpus.is_none_or(|n| cpu < n) => Ok(Some(cpu)),
            _ => self.out_of_range(t, "cpu", value, &allowed),
        }
    }

    /// `seed` and `sim` belong to the simulated bus; `on_sim` is `None` when the device is
    /// missing or not a string (that error is reported already).
    fn only_on_sim(&mut self, t: &Table<'_, '_>, key: &str, on_sim: Option<bool>) -> Checked<()> {
        match t.get(key) {
            Some(value) if on_sim == Some(false) => {
                let problem = format!(
                    "{key} = {} is only allowed with device = \"sim\": the drives on a serial \
                     bus are real",
                    self.written(value)
                );
                self.fail_at(&t.scope, key, value.span(), &problem)
            }
            _ => Ok(()),
        }
    }

    /// The `[[bus.drive]]` tables of a bus.
    fn drives(&mut self, bus: &Table<'_, 't>, on_sim: Option<bool>) -> Checked<Vec<DriveEntry>> {
        let Some(tables) = self.tables(bus, "drive", "[[bus.drive]]")? else {
            let problem = "no [[bus.drive]] table: every bus needs at least one drive";
            return self.fail_at(&bus.scope, "drive", bus.span.clone(), problem);
        };
        let mut addresses = Vec::with_capacity(tables.len());
        let drives: Vec<_> = tables
            .into_iter()
            .enumerate()
            .map(|(index, (span, entries))| {
                let t = Table {
                    entries,
                    span,
                    scope: Scope {
                        path: format!("{}.drive[{index}]", bus.scope.path),
                        label: format!("{} drive[{index}]", bus.scope.label),
                    },
                };
                self.drive(t, &bus.scope, on_sim, &mut addresses)
            })
            .collect();
        drives.into_iter().collect()
    }

    /// One `[[bus.drive]]` table; `addresses` holds the addresses seen on this bus with their
    /// lines.
    fn drive(
        &mut self,
        mut t: Table<'_, 't>,
        bus: &Scope,
        on_sim: Option<bool>,
        addresses: &mut Vec<(Address, usize)>,
    ) -> Checked<DriveEntry> {
        let address = self.int(&t, &ADDRESS, |n| Address::new(u8::try_from(n).ok()?).ok());
        if let Ok(address) = address {
            t.scope.label = format!("{} drive {address}", bus.label);
        }
        let address = address.and_then(|address| self.unique_address(&t, bus, address, addresses));
        self.known_keys(&t, &DRIVE_KEYS, "a [[bus.drive]] table");
        let pkw = self.pkw(&t);
        let pzd = self.int(&t, &PZD, |n| PzdCount::new(usize::try_from(n).ok()?).ok());
        let weight = self.int(&t, &WEIGHT, |n| u8::try_from(n).ok());
        let reference_hz = self.reference_hz(&t);
        let watchdog = self.ms(&t, &WATCHDOG);
        let safe_command = self.choice(
            &t,
            "safe_command",
            &SafeCommand::ALL,
            SafeCommand::name,
            "use \"off1\" (ramp down), \"off2\" (coast) or \"off3\" (quick stop)",
        );
        let params_writable = self.boolean(&t, "params_writable", true);
        let monitoring_param = self.monitoring_param(&t);
        let monitoring_max = self.ms(&t, &MONITORING_MAX);
        let require_monitoring = self.boolean(&t, "require_monitoring", false);
        let layout = pkw.and_then(|pkw| Ok(Layout::new(pkw, pzd?)));
        if let (Ok(true), Ok(param), Ok(layout)) = (require_monitoring, monitoring_param, layout) {
            self.monitoring_checkable(&t, param, layout)?;
        }
        let (sim, sim_keys) = self.sim(&t, on_sim, address, layout)?;
        Ok(DriveEntry {
            address: address?,
            layout: layout?,
            weight: weight?,
            reference_hz: reference_hz?,
            watchdog: watchdog?,
            safe_command: safe_command?.unwrap_or(SafeCommand::Off1),
            params_writable: params_writable?,
            monitoring_param: monitoring_param?,
            monitoring_max: monitoring_max?,
            require_monitoring: require_monitoring?,
            sim,
            sim_keys,
        })
    }

    /// `monitoring_param`: a parameter in the manuals' notation, or "" for no check.
    fn monitoring_param(&mut self, t: &Table<'_, 't>) -> Checked<Option<ParamRef>> {
        const KEY: &str = "monitoring_param";
        let allowed = "name the drive's telegram-off time as the manual writes it, \
                       e.g. \"P2014.1\" (MICROMASTER 4, COM link) or \"p2040\" (G120), or \"\" for no check";
        let Some((written, span)) = self.string(t, KEY, allowed)? else {
            return Ok(MONITORING_PARAM_DEFAULT.parse().ok());
        };
        if written.is_empty() {
            return Ok(None);
        }
        match written.parse::<ParamRef>() {
            Ok(p) => Ok(Some(p)),
            Err(e) => {
                let problem = format!("{KEY} = {written:?}: {e}; {allowed}");
                self.fail_at(&t.scope, KEY, span, &problem)
            }
        }
    }

    /// `require_monitoring = true` needs a parameter to read and a channel to read it on.
    fn monitoring_checkable(
        &mut self,
        t: &Table<'_, 't>,
        param: Option<ParamRef>,
        layout: Layout,
    ) -> Checked<()> {
        let span = t
            .get("require_monitoring")
            .map_or(t.span.clone(), Spanned::span);
        if param.is_none() {
            let problem = "require_monitoring = true needs monitoring_param (e.g. \"P2014.1\"): \
                           ussd cannot verify a monitoring it does not read";
            return self.fail_at(&t.scope, "require_monitoring", span, problem);
        }
        if layout.pkw == PkwMode::None {
            let problem = "require_monitoring = true needs a parameter channel (pkw = 3, 4 or \
                           127) to read the drive's telegram monitoring";
            return self.fail_at(&t.scope, "require_monitoring", span, problem);
        }
        Ok(())
    }

    /// Every drive on a bus needs its own address (USS.md section 1).
    fn unique_address(
        &mut self,
        t: &Table<'_, '_>,
        bus: &Scope,
        address: Address,
        addresses: &mut Vec<(Address, usize)>,
    ) -> Checked<Address> {
        let span = t.get(ADDRESS.key).map(Spanned::span).unwrap_or_default();
        if let Some((_, first)) = addresses.iter().find(|(a, _)| *a == address) {
            let scope = Scope {
                path: t.scope.path.clone(),
                label: bus.label.clone(),
            };
            let problem = format!(
                "address {address} is used twice (first at line {first}): every drive on a bus \
                 needs its own address"
            );
            return self.fail_at(&scope, ADDRESS.key, span, &problem);
        }
        addresses.push((address, position(self.text, span.start).0));
        Ok(address)
    }

    /// P2013: 0, 3, 4 or 127 (USS.md section 3).
    fn pkw(&mut self, t: &Table<'_, '_>) -> Checked<PkwMode> {
        let allowed = "the PKW length (P2013) is 0, 3, 4 or 127 (variable)";
        let Some(value) = t.get("pkw") else {
            return Ok(DEFAULT_LAYOUT.pkw);
        };
        let n = self.integer(t, "pkw", value, allowed)?;
        if let Some(pkw) = u16::try_from(n).ok().and_then(PkwMode::from_p2013) {
            Ok(pkw)
        } else {
            let problem = format!("pkw = {} is not allowed: {allowed}", self.written(value));
            self.fail_at(&t.scope, "pkw", value.span(), &problem)
        }
    }

    /// P2000: above 0, at most 650 Hz (the MICROMASTER/G120 range of P2000).
    fn reference_hz(&mut self, t: &Table<'_, '_>) -> Checked<f32> {
        let allowed =
            format!("the reference frequency (P2000) is above 0 and at most {REFERENCE_HZ_MAX} Hz");
        let Some(value) = t.get("reference_hz") else {
            return Ok(REFERENCE_HZ_DEFAULT);
        };
        let hz: f32 = self.number(t, "reference_hz", value, &allowed)?;
        // NaN fails both comparisons.
        if hz > 0.0 && hz <= REFERENCE_HZ_MAX {
            Ok(hz)
        } else {
            self.out_of_range(t, "reference_hz", value, &allowed)
        }
    }

    /// The simulated drive of a drive on the simulated bus, and its `sim` keys as written.
    fn sim(
        &mut self,
        t: &Table<'_, 't>,
        on_sim: Option<bool>,
        address: Checked<Address>,
        layout: Checked<Layout>,
    ) -> Checked<(Option<DriveSpec>, String)> {
        self.only_on_sim(t, "sim", on_sim)?;
        let allowed = "sim holds uss-sim drive keys without the address, pkw and pzd, e.g. \
                       \"delay=1,drop=0.01\"";
        let (keys, span) = self
            .string(t, "sim", allowed)?
            .unwrap_or(("", t.span.clone()));
        if let Some(key) = layout_key_in_sim(keys) {
            let problem = format!(
                "sim = {keys:?} sets {key}: the drive's {key} comes from this table's `{key}` key"
            );
            return self.fail_at(&t.scope, "sim", span, &problem);
        }
        if keys.contains(':') {
            let problem = format!(
                "sim = {keys:?} has an address: the address comes from this table's `address` \
                 key; {allowed}"
            );
            return self.fail_at(&t.scope, "sim", span, &problem);
        }
        if on_sim != Some(true) {
            return Ok((None, String::new()));
        }
        // Without a valid address and layout (their errors are recorded) the keys wait.
        match sim_drive(address?, layout?, keys) {
            Ok(spec) => Ok((Some(spec), keys.to_owned())),
            Err(e) => {
                let problem = format!("sim = {keys:?}: {}", e.problem);
                self.fail_at(&t.scope, "sim", span, &problem)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(
        clippy::float_cmp,
        reason = "a value parsed from the same decimal text is the same float, bit for bit"
    )]
    use super::*;
    use uss_drive_sim::Fault;

    fn parse(text: &str) -> Config {
        match Config::parse(text, "bus.toml") {
            Ok(config) => config,
            Err(e) => panic!("{e}"),
        }
    }

    fn error(text: &str) -> ConfigError {
        Config::parse(text, "bus.toml").unwrap_err()
    }

    /// A simulated bus with `line` as its line 4 and one drive at address 3.
    fn bus_key(line: &str) -> String {
        format!(
            "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n{line}\n\n[[bus.drive]]\naddress = 3\n"
        )
    }

    /// A simulated bus with one drive at address 3 that has `line` as line 7.
    fn drive_key(line: &str) -> String {
        format!(
            "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 3\n{line}\n"
        )
    }

    /// The message and field path of the error `text` gets.
    fn refused(text: &str) -> (String, Option<String>) {
        let e = error(text);
        (e.to_string(), e.path)
    }

    fn ms(ms: u64) -> Duration {
        Duration::from_millis(ms)
    }

    const FULL: &str = r#"# two buses, every key set
[[bus]]
name = "line-A_1"
device = "sim"
baud = 19200
rs485 = "kernel"
echo = true
response_timeout_ms = 25.5
timeout_margin_ms = 5
retries = 3
offline_after = 4
offline_probe_ms = 1000.0
cycle_time_ms = 12.25
param_timeout_ms = 3000.0
cpu = 0
priority = 70
seed = 42

[[bus.drive]]
address = 0x1F
pkw = 127
pzd = 6
weight = 3
reference_hz = 60.1
watchdog_ms = 250
safe_command = "off3"
params_writable = false
sim = "delay=2.5,jitter=0.5,drop=0.05,bcc=0.1,unplug=1000..1500"

[[bus.drive]]
address = 2
pkw = 0
pzd = 0

[[bus]]
name = "serial"
device = "/dev/null"
rs485 = "auto"

[[bus.drive]]
address = 7
pkw = 3
pzd = 16
safe_command = "off2"
"#;

    #[test]
    fn embedded_default_is_one_simulated_bus_with_four_drives() {
        let c = Config::embedded_default();
        assert_eq!(c.buses.len(), 1);
        let bus = &c.buses[0];
        assert_eq!(bus.name, "bus0");
        assert_eq!(bus.device, Device::Sim);
        assert_eq!(bus.baud.get(), 115_200);
        let shape: Vec<_> = bus
            .drives
            .iter()
            .map(|d| (d.address.get(), d.layout.pkw.p2013(), d.layout.pzd.get()))
            .collect();
        assert_eq!(shape, [(1, 4, 2), (2, 4, 2), (3, 127, 2), (4, 4, 2)]);
        for d in &bus.drives {
            let sim = d
                .sim
                .as_ref()
                .expect("a simulated bus has simulated drives");
            let recommended = DriveConfig {
                telegram_off_time_ms: 100,
                ..DriveConfig::new(d.address, d.layout)
            };
            assert_eq!(sim.config, recommended, "P2014.1 = 100 ms");
            assert_eq!(sim.faults.probability(Fault::DropReply), 0.0);
            assert_eq!(d.sim_keys, "p2014=100");
        }
    }

    #[test]
    fn missing_keys_get_their_documented_defaults() {
        let c = parse(&bus_key(""));
        let bus = &c.buses[0];
        assert_eq!(bus.baud.get(), 115_200);
        assert_eq!(bus.rs485, Rs485Mode::None);
        assert!(!bus.echo);
        assert_eq!(bus.response_timeout, ms(20));
        assert_eq!(bus.timeout_margin, Duration::ZERO);
        assert_eq!(bus.retries, 2);
        assert_eq!(bus.offline_after, 1);
        assert_eq!(bus.offline_probe, ms(500));
        assert_eq!(bus.cycle_time, None);
        assert_eq!(bus.param_timeout, ms(2000));
        assert_eq!(bus.cpu, None);
        assert_eq!(bus.priority, 80);
        assert_eq!(bus.seed, 1);
        let d = &bus.drives[0];
        assert_eq!(d.address.get(), 3);
        assert_eq!(d.layout, DEFAULT_LAYOUT);
        assert_eq!((d.layout.pkw, d.layout.pzd.get()), (PkwMode::Four, 2));
        assert_eq!(d.weight, 1);
        assert_eq!(d.reference_hz, 50.0);
        assert_eq!(d.watchdog, ms(100));
        assert_eq!(d.safe_command, SafeCommand::Off1);
        assert!(d.params_writable);
        assert_eq!(d.sim_keys, "");
        let sim = d
            .sim
            .as_ref()
            .expect("a simulated bus has simulated drives");
        assert_eq!(sim.config, DriveConfig::new(d.address, DEFAULT_LAYOUT));
        assert_eq!(
            bus,
            &BusConfig::with_defaults(
                "bus0",
                Device::Sim,
                vec![DriveEntry {
                    sim: Some(default_sim_drive(d.address, DEFAULT_LAYOUT)),
                    ..DriveEntry::with_defaults(d.address, DEFAULT_LAYOUT)
                }]
            )
        );
    }

    #[test]
    fn every_key_is_read_as_written() {
        let c = parse(FULL);
        let [sim, serial] = &c.buses[..] else {
            panic!("two buses expected");
        };
        assert_eq!(sim.name, "line-A_1");
        assert_eq!(sim.baud.get(), 19200);
        assert_eq!(sim.rs485, Rs485Mode::Kernel);
        assert!(sim.echo);
        assert_eq!(sim.response_timeout, Duration::from_micros(25_500));
        assert_eq!(sim.timeout_margin, ms(5));
        assert_eq!((sim.retries, sim.offline_after), (3, 4));
        assert_eq!(sim.offline_probe, ms(1000));
        assert_eq!(sim.cycle_time, Some(Duration::from_micros(12_250)));
        assert_eq!(sim.param_timeout, ms(3000));
        assert_eq!((sim.cpu, sim.priority, sim.seed), (Some(0), 70, 42));
        let d = &sim.drives[0];
        assert_eq!(d.address.get(), 31);
        assert_eq!((d.layout.pkw, d.layout.pzd.get()), (PkwMode::Variable, 6));
        assert_eq!(d.weight, 3);
        assert_eq!(d.reference_hz, 60.1_f32);
        assert_eq!(d.watchdog, ms(250));
        assert_eq!(d.safe_command, SafeCommand::Off3);
        assert!(!d.params_writable);
        let d = &sim.drives[1];
        assert_eq!((d.layout.pkw, d.layout.pzd.get()), (PkwMode::None, 0));

        assert_eq!(serial.device, Device::Serial(PathBuf::from("/dev/null")));
        assert_eq!(serial.rs485, Rs485Mode::Auto);
        let d = &serial.drives[0];
        assert_eq!((d.layout.pkw, d.layout.pzd.get()), (PkwMode::Three, 16));
        assert_eq!(d.safe_command, SafeCommand::Off2);
        assert!(d.sim.is_none());
        assert_eq!(d.sim_keys, "");
    }

    #[test]
    fn simulated_drive_takes_address_and_layout_from_the_entry_and_faults_from_sim() {
        let c = parse(FULL);
        let d = &c.buses[0].drives[0];
        let sim = d
            .sim
            .as_ref()
            .expect("a simulated bus has simulated drives");
        assert_eq!(sim.config.address.get(), 31);
        assert_eq!(sim.config.layout, d.layout);
        assert_eq!(sim.config.response_delay, Duration::from_micros(2500));
        assert_eq!(sim.config.response_jitter, Duration::from_micros(500));
        assert_eq!(sim.faults.probability(Fault::DropReply), 0.05);
        assert_eq!(sim.faults.probability(Fault::CorruptBcc), 0.1);
        assert_eq!(sim.faults.probability(Fault::Late), 0.0);
        assert!(sim.faults.is_unplugged(ms(1200)));
        assert!(!sim.faults.is_unplugged(ms(1500)));
        assert_eq!(
            d.sim_keys,
            "delay=2.5,jitter=0.5,drop=0.05,bcc=0.1,unplug=1000..1500"
        );
        // Without `sim`, the simulator's defaults at the entry's layout.
        let d = &c.buses[0].drives[1];
        let sim = d
            .sim
            .as_ref()
            .expect("a simulated bus has simulated drives");
        let pzd0 = Layout::new(PkwMode::None, PzdCount::new(0).unwrap());
        assert_eq!(sim.config, DriveConfig::new(d.address, pzd0));
    }

    #[test]
    fn embedded_default_round_trips_through_to_toml() {
        let c = Config::embedded_default();
        assert_eq!(Config::parse(&c.to_toml(), "default").unwrap(), c);
    }

    #[test]
    fn full_example_round_trips_through_to_toml() {
        let c = parse(FULL);
        let text = c.to_toml();
        assert_eq!(Config::parse(&text, "check").unwrap(), c);
        // And the second trip writes the same text.
        assert_eq!(parse(&text).to_toml(), text);
    }

    #[test]
    fn to_toml_writes_every_default() {
        assert_eq!(
            parse(&bus_key("")).to_toml(),
            r#"# ussd configuration: the effective settings, every default filled in

[[bus]]
name = "bus0"
device = "sim"
baud = 115200
rs485 = "none"
echo = false
response_timeout_ms = 20.0
timeout_margin_ms = 0.0
retries = 2
offline_after = 1
offline_probe_ms = 500.0
cycle_time_ms = 0.0
param_timeout_ms = 2000.0
# cpu: not pinned
priority = 80
seed = 1

[[bus.drive]]
address = 3
pkw = 4
pzd = 2
weight = 1
reference_hz = 50.0
watchdog_ms = 100.0
safe_command = "off1"
params_writable = true
monitoring_param = "P2014[1]"
monitoring_max_ms = 1000.0
require_monitoring = false
sim = ""
"#
        );
    }

    #[test]
    fn times_are_written_as_exact_milliseconds() {
        assert_eq!(millis_text(Duration::ZERO), "0.0");
        assert_eq!(millis_text(ms(20)), "20.0");
        assert_eq!(millis_text(Duration::from_nanos(95_500)), "0.0955");
        assert_eq!(
            millis_text(Duration::from_nanos(600_000_000_001)),
            "600000.000001"
        );
        assert_eq!(millis(0.0955), Duration::from_nanos(95_500));
    }

    #[test]
    fn a_zero_cycle_time_means_as_fast_as_the_wire_allows() {
        assert_eq!(
            parse(&bus_key("cycle_time_ms = 0")).buses[0].cycle_time,
            None
        );
        assert_eq!(
            parse(&bus_key("cycle_time_ms = 10")).buses[0].cycle_time,
            Some(ms(10))
        );
    }

    #[test]
    fn safe_commands_send_the_stw1_of_uss_md_section_7() {
        assert_eq!(SafeCommand::Off1.command().stw1(), Some(0x047E));
        assert_eq!(SafeCommand::Off2.command().stw1(), Some(0x047C));
        assert_eq!(SafeCommand::Off3.command().stw1(), Some(0x047A));
    }

    #[test]
    fn load_reads_a_file_and_names_it_in_errors() {
        let dir = std::env::temp_dir().join(format!("uss-config-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.toml");
        std::fs::write(&good, bus_key("")).unwrap();
        assert_eq!(Config::load(&good).unwrap(), parse(&bus_key("")));
        let bad = dir.join("bad.toml");
        std::fs::write(&bad, bus_key("retries = 11")).unwrap();
        let e = Config::load(&bad).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "{}:4:11: bus \"bus0\": retries = 11 is out of range: retries after a failed \
                 exchange are 0..=10",
                bad.display()
            )
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn unreadable_file_is_an_error_without_a_line() {
        let e = Config::load(Path::new("/nonexistent/ussd.toml")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "/nonexistent/ussd.toml: cannot read the configuration: No such file or directory \
             (os error 2)"
        );
        assert_eq!((e.line, e.column, e.path), (None, None, None));
    }

    #[test]
    fn toml_syntax_error_keeps_tomls_message_and_position() {
        let e = error(&drive_key("pzd = 3 x"));
        assert_eq!(
            e.to_string(),
            "bus.toml:7:7: invalid TOML: string values must be quoted, expected literal string"
        );
        assert_eq!((e.line, e.column, e.path), (Some(7), Some(7), None));
        assert_eq!(
            error(&drive_key("address = 4")).to_string(),
            "bus.toml:7:1: invalid TOML: duplicate key"
        );
    }

    #[test]
    fn telegram_monitoring_is_checked_as_configured() {
        let d = |line: &str| parse(&drive_key(line)).buses[0].drives[0].clone();
        let p2014 = d("");
        assert_eq!(
            p2014.monitoring_param.map(|p| p.to_string()),
            Some("P2014[1]".into())
        );
        assert_eq!(
            (p2014.monitoring_max, p2014.require_monitoring),
            (ms(1000), false)
        );
        let g120 =
            d("monitoring_param = \"p2040\"\nmonitoring_max_ms = 200\nrequire_monitoring = true");
        assert_eq!(
            g120.monitoring_param.map(|p| p.to_string()),
            Some("p2040".into())
        );
        assert_eq!(
            (g120.monitoring_max, g120.require_monitoring),
            (ms(200), true)
        );
        assert_eq!(d("monitoring_param = \"\"").monitoring_param, None);
    }

    #[test]
    fn a_monitoring_that_cannot_be_verified_cannot_be_required() {
        assert_eq!(
            refused(&drive_key("monitoring_param = \"P20x4\"")),
            (
                "bus.toml:7:20: bus \"bus0\" drive 3: monitoring_param = \"P20x4\": write a parameter \
                 as P1082, p1082, r0021 or 1082, an element as P0947[3] or r0947.3; name the drive's \
                 telegram-off time as the manual writes it, e.g. \"P2014.1\" (MICROMASTER 4, COM \
                 link) or \"p2040\" (G120), or \"\" for no check"
                    .to_owned(),
                Some("bus[0].drive[0].monitoring_param".to_owned())
            )
        );
        let (message, path) = refused(&drive_key(
            "monitoring_param = \"\"\nrequire_monitoring = true",
        ));
        assert!(
            message.starts_with("bus.toml:8:22: bus \"bus0\" drive 3: require_monitoring = true needs monitoring_param"),
            "{message}"
        );
        assert_eq!(path.as_deref(), Some("bus[0].drive[0].require_monitoring"));
        let (message, _) = refused(&drive_key("pkw = 0\nrequire_monitoring = true"));
        assert!(
            message.contains("require_monitoring = true needs a parameter channel"),
            "{message}"
        );
    }

    #[test]
    fn unknown_keys_are_named_with_their_table() {
        assert_eq!(
            refused(&drive_key("colour = \"red\"")),
            (
                "bus.toml:7:1: bus \"bus0\" drive 3: unknown key `colour`: a [[bus.drive]] table \
                 takes address, pkw, pzd, weight, reference_hz, watchdog_ms, safe_command, \
                 params_writable, monitoring_param, monitoring_max_ms, require_monitoring, sim"
                    .to_owned(),
                Some("bus[0].drive[0].colour".to_owned())
            )
        );
        let (message, path) = refused(&bus_key("baudrate = 9600"));
        assert!(
            message.starts_with(
                "bus.toml:4:1: bus \"bus0\": unknown key `baudrate`: a [[bus]] table takes name, \
                 device, baud,"
            ),
            "{message}"
        );
        assert_eq!(path.as_deref(), Some("bus[0].baudrate"));
        assert_eq!(
            refused(&format!("version = 2\n{}", bus_key(""))),
            (
                "bus.toml:1:1: unknown key `version`: the file takes bus".to_owned(),
                Some("version".to_owned())
            )
        );
    }

    #[test]
    fn wrong_types_say_what_is_expected() {
        assert_eq!(
            refused(&drive_key("pzd = \"two\"")),
            (
                "bus.toml:7:7: bus \"bus0\" drive 3: pzd = \"two\" is not an integer: PZD words \
                 are 0..=16"
                    .to_owned(),
                Some("bus[0].drive[0].pzd".to_owned())
            )
        );
        assert_eq!(
            error(&drive_key("pzd = 2.0")).to_string(),
            "bus.toml:7:7: bus \"bus0\" drive 3: pzd = 2.0 is not an integer: PZD words are 0..=16"
        );
        assert_eq!(
            error(&bus_key("echo = \"yes\"")).to_string(),
            "bus.toml:4:8: bus \"bus0\": echo = \"yes\" is not a boolean: write true or false"
        );
        assert_eq!(
            error(&bus_key("response_timeout_ms = \"20\"")).to_string(),
            "bus.toml:4:23: bus \"bus0\": response_timeout_ms = \"20\" is not a number: the \
             response timeout is 1..=1000 ms (USS.md section 4: a slave answers within 20 ms)"
        );
        assert_eq!(
            error("[[bus]]\nname = 7\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n").to_string(),
            "bus.toml:2:8: bus[0]: name = 7 is not a string: a bus name is 1..=32 characters \
             from A-Z, a-z, 0-9, _ and - (it becomes part of shared-memory service names)"
        );
        assert_eq!(
            refused("[bus]\nname = \"bus0\"\n"),
            (
                "bus.toml:1:1: bus is a table, not [[bus]] tables: write a [[bus]] table for each"
                    .to_owned(),
                Some("bus".to_owned())
            )
        );
        assert_eq!(
            error("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\ndrive = 3\n").to_string(),
            "bus.toml:4:9: bus \"bus0\": drive = 3 is not [[bus.drive]] tables: write a \
             [[bus.drive]] table for each"
        );
    }

    #[test]
    fn address_must_be_0_to_31() {
        assert_eq!(
            refused("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 32\n"),
            (
                "bus.toml:6:11: bus \"bus0\" drive[0]: address = 32 is out of range: USS \
                 addresses are 0..=31"
                    .to_owned(),
                Some("bus[0].drive[0].address".to_owned())
            )
        );
        assert_eq!(
            error("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = -1\n")
                .to_string(),
            "bus.toml:6:11: bus \"bus0\" drive[0]: address = -1 is out of range: USS addresses \
             are 0..=31"
        );
    }

    #[test]
    fn address_is_required() {
        assert_eq!(
            refused("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\npzd = 4\n"),
            (
                "bus.toml:5:1: bus \"bus0\" drive[0]: address is missing: USS addresses are 0..=31"
                    .to_owned(),
                Some("bus[0].drive[0].address".to_owned())
            )
        );
    }

    #[test]
    fn an_address_used_twice_names_the_first_line() {
        let text = "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 3\n\n\
                    [[bus.drive]]\naddress = 3\n";
        assert_eq!(
            refused(text),
            (
                "bus.toml:9:11: bus \"bus0\": address 3 is used twice (first at line 6): every \
                 drive on a bus needs its own address"
                    .to_owned(),
                Some("bus[0].drive[1].address".to_owned())
            )
        );
        // The same address on two buses is fine.
        let two_buses = "[[bus]]\nname = \"a\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n\
                         [[bus]]\nname = \"b\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n";
        assert_eq!(parse(two_buses).buses.len(), 2);
    }

    #[test]
    fn a_bus_name_used_twice_names_the_first_line() {
        let text = "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n\n\
                    [[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n";
        assert_eq!(
            refused(text),
            (
                "bus.toml:8:8: bus[1]: name \"bus0\" is used twice (first at line 2): every bus \
                 needs its own name"
                    .to_owned(),
                Some("bus[1].name".to_owned())
            )
        );
    }

    #[test]
    fn bus_names_are_1_to_32_of_letters_digits_underscore_and_dash() {
        let named = |name: &str| {
            format!("[[bus]]\nname = {name}\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n")
        };
        let allowed = "a bus name is 1..=32 characters from A-Z, a-z, 0-9, _ and - (it becomes \
                       part of shared-memory service names)";
        assert_eq!(
            refused(&named("\"bus 0\"")),
            (
                format!("bus.toml:2:8: bus[0]: name = \"bus 0\" is not allowed: {allowed}"),
                Some("bus[0].name".to_owned())
            )
        );
        assert_eq!(
            error(&named("\"\"")).to_string(),
            format!("bus.toml:2:8: bus[0]: name = \"\" is not allowed: {allowed}")
        );
        let long = "b".repeat(33);
        assert_eq!(
            error(&named(&format!("\"{long}\""))).to_string(),
            format!("bus.toml:2:8: bus[0]: name = \"{long}\" is not allowed: {allowed}")
        );
        assert_eq!(
            parse(&named(&format!("\"{}\"", "b".repeat(32)))).buses[0]
                .name
                .len(),
            32
        );
        assert_eq!(
            error("[[bus]]\ndevice = \"sim\"\n[[bus.drive]]\naddress = 1\n").to_string(),
            format!("bus.toml:1:1: bus[0]: name is missing: {allowed}")
        );
    }

    #[test]
    fn pzd_above_16_is_refused() {
        assert_eq!(
            refused(&drive_key("pzd = 17")),
            (
                "bus.toml:7:7: bus \"bus0\" drive 3: pzd = 17 is out of range: PZD words are 0..=16"
                    .to_owned(),
                Some("bus[0].drive[0].pzd".to_owned())
            )
        );
        assert_eq!(
            parse(&drive_key("pzd = 16")).buses[0].drives[0]
                .layout
                .pzd
                .get(),
            16
        );
    }

    #[test]
    fn pkw_must_be_a_p2013_value() {
        assert_eq!(
            refused(&drive_key("pkw = 5")),
            (
                "bus.toml:7:7: bus \"bus0\" drive 3: pkw = 5 is not allowed: the PKW length \
                 (P2013) is 0, 3, 4 or 127 (variable)"
                    .to_owned(),
                Some("bus[0].drive[0].pkw".to_owned())
            )
        );
        assert_eq!(
            error(&drive_key("pkw = -4")).to_string(),
            "bus.toml:7:7: bus \"bus0\" drive 3: pkw = -4 is not allowed: the PKW length (P2013) \
             is 0, 3, 4 or 127 (variable)"
        );
    }

    #[test]
    fn weight_is_1_to_16() {
        let message = |w: &str| {
            format!(
                "bus.toml:7:10: bus \"bus0\" drive 3: weight = {w} is out of range: poll weights \
                 (entries in the circulating list) are 1..=16"
            )
        };
        assert_eq!(error(&drive_key("weight = 0")).to_string(), message("0"));
        assert_eq!(error(&drive_key("weight = 17")).to_string(), message("17"));
        assert_eq!(
            parse(&drive_key("weight = 16")).buses[0].drives[0].weight,
            16
        );
    }

    #[test]
    fn baud_rate_must_be_one_the_protocol_crate_accepts() {
        let message = |b: &str| {
            format!(
                "bus.toml:4:8: bus \"bus0\": baud = {b} is out of range: baud rates are \
                 300..=12000000 (USS.md section 2 names 300 to 187500)"
            )
        };
        assert_eq!(error(&bus_key("baud = 299")).to_string(), message("299"));
        assert_eq!(
            error(&bus_key("baud = 12000001")).to_string(),
            message("12000001")
        );
        assert_eq!(
            error(&bus_key("baud = 99999999999")).to_string(),
            message("99999999999")
        );
        assert_eq!(parse(&bus_key("baud = 9600")).buses[0].baud.get(), 9600);
    }

    #[test]
    fn unknown_rs485_mode_and_safe_command_list_the_choices() {
        assert_eq!(
            refused(&bus_key("rs485 = \"rts\"")),
            (
                "bus.toml:4:9: bus \"bus0\": rs485 = \"rts\" is not allowed: use \"kernel\" \
                 (TIOCSRS485, RTS on send), \"auto\" (the adapter switches itself) or \"none\""
                    .to_owned(),
                Some("bus[0].rs485".to_owned())
            )
        );
        assert_eq!(
            refused(&drive_key("safe_command = \"stop\"")),
            (
                "bus.toml:7:16: bus \"bus0\" drive 3: safe_command = \"stop\" is not allowed: use \
                 \"off1\" (ramp down), \"off2\" (coast) or \"off3\" (quick stop)"
                    .to_owned(),
                Some("bus[0].drive[0].safe_command".to_owned())
            )
        );
    }

    #[test]
    fn a_relative_serial_device_must_exist_an_absolute_one_may_come_later() {
        let text = "[[bus]]\nname = \"bus0\"\ndevice = \"ttyXYZ\"\n[[bus.drive]]\naddress = 1\n";
        let later = text.replace("ttyXYZ", "/dev/ttyXYZ");
        assert_eq!(
            parse(&later).buses[0].device,
            Device::Serial(PathBuf::from("/dev/ttyXYZ"))
        );
        assert_eq!(
            refused(text),
            (
                "bus.toml:3:10: bus \"bus0\": unknown device: ttyXYZ does not exist (a device \
                 that may be absent when ussd starts needs its absolute path): device is \"sim\" \
                 (the built-in simulated bus) or the path of a serial device"
                    .to_owned(),
                Some("bus[0].device".to_owned())
            )
        );
        assert_eq!(
            error("[[bus]]\nname = \"bus0\"\n[[bus.drive]]\naddress = 1\n").to_string(),
            "bus.toml:1:1: bus \"bus0\": device is missing: device is \"sim\" (the built-in \
             simulated bus) or the path of a serial device"
        );
    }

    /// A serial bus on /dev/null with `bus_line` as line 4 and a drive at address 3 with
    /// `drive_line` as line 7.
    fn serial(bus_line: &str, drive_line: &str) -> String {
        format!(
            "[[bus]]\nname = \"bus1\"\ndevice = \"/dev/null\"\n{bus_line}\n\n[[bus.drive]]\n\
             address = 3\n{drive_line}\n"
        )
    }

    #[test]
    fn sim_and_seed_are_refused_on_a_serial_bus() {
        assert_eq!(
            refused(&serial("", "sim = \"delay=1\"")),
            (
                "bus.toml:8:7: bus \"bus1\" drive 3: sim = \"delay=1\" is only allowed with \
                 device = \"sim\": the drives on a serial bus are real"
                    .to_owned(),
                Some("bus[0].drive[0].sim".to_owned())
            )
        );
        assert_eq!(
            refused(&serial("seed = 7", "")),
            (
                "bus.toml:4:8: bus \"bus1\": seed = 7 is only allowed with device = \"sim\": the \
                 drives on a serial bus are real"
                    .to_owned(),
                Some("bus[0].seed".to_owned())
            )
        );
        // Also when the serial device is absent (it may appear later): the text asked for a
        // serial bus.
        let text = "[[bus]]\nname = \"bus1\"\ndevice = \"/dev/ttyXYZ\"\n[[bus.drive]]\n\
                    address = 1\nsim = \"delay=1\"\n";
        let e = error(text);
        assert_eq!(e.line, Some(6));
        assert!(
            e.to_string().contains("only allowed with device = \"sim\""),
            "{e}"
        );
        let c = parse(&serial("", ""));
        assert!(c.buses[0].drives[0].sim.is_none());
    }

    #[test]
    fn a_bad_sim_spec_carries_the_simulators_message() {
        assert_eq!(
            refused(&drive_key("sim = \"delay=x\"")),
            (
                "bus.toml:7:7: bus \"bus0\" drive 3: sim = \"delay=x\": delay=x: a time in \
                 milliseconds, 0..=3600000"
                    .to_owned(),
                Some("bus[0].drive[0].sim".to_owned())
            )
        );
        assert_eq!(
            error(&drive_key("sim = \"drop=2\"")).to_string(),
            "bus.toml:7:7: bus \"bus0\" drive 3: sim = \"drop=2\": drop=2: a probability is 0..=1"
        );
        assert_eq!(
            error(&drive_key("sim = 1")).to_string(),
            "bus.toml:7:7: bus \"bus0\" drive 3: sim = 1 is not a string: sim holds uss-sim drive \
             keys without the address, pkw and pzd, e.g. \"delay=1,drop=0.01\""
        );
    }

    #[test]
    fn a_sim_spec_must_not_set_the_layout_or_the_address() {
        assert_eq!(
            refused(&drive_key("sim = \"delay=1, pzd=4\"")),
            (
                "bus.toml:7:7: bus \"bus0\" drive 3: sim = \"delay=1, pzd=4\" sets pzd: the \
                 drive's pzd comes from this table's `pzd` key"
                    .to_owned(),
                Some("bus[0].drive[0].sim".to_owned())
            )
        );
        assert_eq!(
            error(&drive_key("sim = \"pkw=3\"")).to_string(),
            "bus.toml:7:7: bus \"bus0\" drive 3: sim = \"pkw=3\" sets pkw: the drive's pkw comes \
             from this table's `pkw` key"
        );
        assert_eq!(
            error(&drive_key("sim = \"3:delay=1\"")).to_string(),
            "bus.toml:7:7: bus \"bus0\" drive 3: sim = \"3:delay=1\" has an address: the address \
             comes from this table's `address` key; sim holds uss-sim drive keys without the \
             address, pkw and pzd, e.g. \"delay=1,drop=0.01\""
        );
    }

    #[test]
    fn timeouts_out_of_range_name_their_limits() {
        let cases = [
            (
                "response_timeout_ms = 0.5",
                "response_timeout_ms = 0.5 is out of range: the response timeout is 1..=1000 ms \
                 (USS.md section 4: a slave answers within 20 ms)",
            ),
            (
                "timeout_margin_ms = -1",
                "timeout_margin_ms = -1 is out of range: the timeout margin is 0..=1000 ms",
            ),
            (
                "offline_probe_ms = 5",
                "offline_probe_ms = 5 is out of range: the poll interval of an offline drive is \
                 10..=60000 ms",
            ),
            (
                "cycle_time_ms = 60001",
                "cycle_time_ms = 60001 is out of range: the cycle time (0 = as fast as the wire \
                 allows) is 0..=60000 ms",
            ),
            (
                "param_timeout_ms = 1e9",
                "param_timeout_ms = 1e9 is out of range: the parameter job timeout is \
                 10..=600000 ms",
            ),
            (
                "response_timeout_ms = nan",
                "response_timeout_ms = nan is out of range: the response timeout is 1..=1000 ms \
                 (USS.md section 4: a slave answers within 20 ms)",
            ),
            (
                "offline_after = 0",
                "offline_after = 0 is out of range: failed polls before a drive is marked \
                 offline are 1..=100",
            ),
        ];
        for (line, problem) in cases {
            let (key, _) = line.split_once(" = ").unwrap();
            let column = key.len() + 4;
            assert_eq!(
                refused(&bus_key(line)),
                (
                    format!("bus.toml:4:{column}: bus \"bus0\": {problem}"),
                    Some(format!("bus[0].{key}"))
                )
            );
        }
        assert_eq!(
            refused(&drive_key("watchdog_ms = 0")),
            (
                "bus.toml:7:15: bus \"bus0\" drive 3: watchdog_ms = 0 is out of range: the \
                 controller watchdog is 1..=60000 ms"
                    .to_owned(),
                Some("bus[0].drive[0].watchdog_ms".to_owned())
            )
        );
        assert_eq!(
            error(&drive_key("reference_hz = 0")).to_string(),
            "bus.toml:7:16: bus \"bus0\" drive 3: reference_hz = 0 is out of range: the reference \
             frequency (P2000) is above 0 and at most 650 Hz"
        );
        assert_eq!(error(&drive_key("reference_hz = 650.5")).line, Some(7));
        assert_eq!(
            parse(&drive_key("reference_hz = 650")).buses[0].drives[0].reference_hz,
            650.0
        );
    }

    #[test]
    fn cpu_must_be_online() {
        let online = std::thread::available_parallelism().unwrap().get();
        let plural = if online == 1 { "" } else { "s" };
        assert_eq!(
            refused(&bus_key(&format!("cpu = {online}"))),
            (
                format!(
                    "bus.toml:4:7: bus \"bus0\": cpu = {online} is out of range: this machine \
                     has {online} online CPU{plural}: cpu is 0..={}",
                    online - 1
                ),
                Some("bus[0].cpu".to_owned())
            )
        );
        assert_eq!(error(&bus_key("cpu = -1")).line, Some(4));
        assert_eq!(parse(&bus_key("cpu = 0")).buses[0].cpu, Some(0));
    }

    #[test]
    fn priority_is_1_to_99() {
        let message = |p: &str| {
            format!(
                "bus.toml:4:12: bus \"bus0\": priority = {p} is out of range: SCHED_FIFO \
                 priorities are 1..=99"
            )
        };
        assert_eq!(error(&bus_key("priority = 0")).to_string(), message("0"));
        assert_eq!(
            error(&bus_key("priority = 100")).to_string(),
            message("100")
        );
        assert_eq!(parse(&bus_key("priority = 99")).buses[0].priority, 99);
    }

    #[test]
    fn a_configuration_needs_a_bus() {
        let e = error("# nothing here\n");
        assert_eq!(
            e.to_string(),
            "bus.toml: no [[bus]] table: a configuration needs at least one bus"
        );
        assert_eq!((e.line, e.path.as_deref()), (None, Some("bus")));
        assert_eq!(
            error("bus = []\n").to_string(),
            "bus.toml:1:7: bus = [] is empty: write a [[bus]] table for each"
        );
    }

    #[test]
    fn a_bus_needs_a_drive() {
        assert_eq!(
            refused("# a bus\n[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n"),
            (
                "bus.toml:2:1: bus \"bus0\": no [[bus.drive]] table: every bus needs at least one \
                 drive"
                    .to_owned(),
                Some("bus[0].drive".to_owned())
            )
        );
        assert_eq!(
            error("[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\ndrive = []\n").to_string(),
            "bus.toml:4:9: bus \"bus0\": drive = [] is empty: write a [[bus.drive]] table for each"
        );
    }

    #[test]
    fn the_error_nearest_the_start_of_the_file_is_reported() {
        // Checked later than `pzd` and on a later table, but first in the file.
        let text = "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\nretries = 11\n\n[[bus.drive]]\n\
                    address = 3\npzd = 17\n";
        assert_eq!(error(text).line, Some(4));
        // Within a table the file order counts, not the order of the checks (address first).
        let text = "[[bus]]\nname = \"bus0\"\ndevice = \"sim\"\n\n[[bus.drive]]\nweight = 0\n\
                    address = 40\n";
        assert_eq!(error(text).path.as_deref(), Some("bus[0].drive[0].weight"));
        // A later bus with a bad name does not hide an earlier bus's error.
        let text = "[[bus]]\nname = \"a\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\npzd = 99\n\
                    [[bus]]\nname = \"b b\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 3\n";
        assert_eq!(error(text).line, Some(6));
    }

    #[test]
    fn inline_tables_are_checked_like_headers() {
        let text = "bus = [{ name = \"bus0\", device = \"sim\", drive = [{ address = 1 }, \
                    { address = 2, pzd = 17 }] }]\n";
        assert_eq!(
            refused(text),
            (
                "bus.toml:1:88: bus \"bus0\" drive 2: pzd = 17 is out of range: PZD words are \
                 0..=16"
                    .to_owned(),
                Some("bus[0].drive[1].pzd".to_owned())
            )
        );
        let ok = text.replace("pzd = 17", "pzd = 4");
        assert_eq!(parse(&ok).buses[0].drives[1].layout.pzd.get(), 4);
    }

    #[test]
    fn integers_may_be_written_in_hex_and_times_as_integers() {
        let c = parse(&drive_key("watchdog_ms = 0x10"));
        assert_eq!(c.buses[0].drives[0].watchdog, ms(16));
        let c = parse("[[bus]]\nname = \"b\"\ndevice = \"sim\"\n[[bus.drive]]\naddress = 0x1f\n");
        assert_eq!(c.buses[0].drives[0].address.get(), 31);
    }

    #[test]
    fn columns_count_characters_not_bytes() {
        assert_eq!(position("aé\nxéy", 7), (2, 3));
        assert_eq!(position("abc", 0), (1, 1));
        assert_eq!(position("abc", 99), (1, 4));
        // A serial device whose path has a two-byte character before the error on the same line.
        let device = std::env::temp_dir().join(format!("uss-config-é-{}", std::process::id()));
        std::fs::write(&device, "").unwrap();
        let text = format!(
            "bus = [{{ name = \"b\", device = \"{}\", drive = [{{ address = 3, pzd = 17 }}] }}]\n",
            device.display()
        );
        let e = error(&text);
        std::fs::remove_file(&device).unwrap();
        // Search for the whole key: the process id in the path may contain "17" too.
        let at = text.find("pzd = 17").unwrap() + "pzd = ".len();
        let column = text[..at].chars().count() + 1;
        assert_eq!((e.line, e.column), (Some(1), Some(column)));
        assert_eq!(at + 1, column + 1, "the path holds one two-byte character");
    }
}
