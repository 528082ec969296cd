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
//! sim = { delay = 1, drop = 0.01 }  # only with device = "sim": uss-sim's drive keys
//! ```
//!
//! Every key but `name`, `device` and `address` has a default; [`Config::to_toml`] writes them
//! all out. serde reads the file (unknown keys refused in every table, each value range checked
//! by its type: [`keys`]), then [`rules`] checks what needs more than one value. Every
//! error names the file, line and column, the bus and drive, the key, and what is allowed
//! ([`errors`]); of several broken rules the one nearest the start of the file is reported.

mod allowed;
mod device;
mod errors;
mod keys;
mod rules;

pub use device::{Device, SerialPath};
pub use errors::ConfigError;
pub use keys::*;

use core::fmt::Write as _;
use errors::Reporter;
use serde::{Deserialize, Serialize};
use std::path::Path;
use toml::de::DeTable;
#[cfg(feature = "sim")]
use uss_drive_sim::SimOptions;
#[cfg(feature = "sim")]
use uss_drive_sim::spec::DriveSpec;
/// Without the simulated bus (`sim` feature off) a `sim` table is read only to be refused.
#[cfg(not(feature = "sim"))]
type SimOptions = toml::Table;
use uss_catalogue::Catalogue;
use uss_protocol::{Address, Baud, Layout, PkwMode, PzdCount};
use uss_shm_types::StopCommand;

/// A whole configuration: one or more buses, each run by its own real-time thread.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// A group whose members may use ussd's services as their own users (monitors and
    /// controllers): the root directory of the shared memory is made theirs to read and write
    /// (mode 2770, `uss_shm_types::service`). A group name, or a number (a gid). Without it
    /// only ussd's user (and root) may.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub access_group: Option<String>,
    #[serde(rename = "bus", default)]
    pub buses: Vec<BusConfig>,
}

/// How the RS485 driver is switched between sending and receiving (USS.md section 9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Rs485Mode {
    /// The kernel's RS485 mode (TIOCSRS485, RTS on send), for embedded UARTs.
    Kernel,
    /// The adapter switches by itself (most USB adapters).
    Auto,
    /// Nothing to switch (RS232 converters, ptys).
    #[default]
    None,
}

/// The level of RTS while sending in the kernel's RS485 mode (`SER_RS485_RTS_ON_SEND` or
/// `_AFTER_SEND`): as the transceiver's driver-enable is wired.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Rs485Rts {
    HighWhileSending,
    LowWhileSending,
}

/// What kind of USS slave a drive is: the contract's code table, one type from this file to the
/// catalogue lookup. Its profile (`Catalogue::of`: `catalogue/data/<family>.toml`) says which
/// parameters ussd reads of its own when the drive comes online (telegram monitoring, the
/// reference), which catalogue clients consult, and how they read parameters. `generic`: no
/// profile; nothing is read unasked, parameters are read by value alone (never a
/// description), every safety rule still holds.
pub use uss_shm_types::DriveFamily as Family;

/// A family as the file writes it: its name (`micromaster4`, `g110`, `g120`, `simoreg`,
/// `generic`).
mod family_name {
    use super::Family;
    use serde::{Deserialize, Deserializer, Serializer, de::Error as _};

    #[allow(
        clippy::trivially_copy_pass_by_ref,
        reason = "serde's `with` passes the field by reference"
    )]
    pub fn serialize<S: Serializer>(family: &Family, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(family.name())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Family, D::Error> {
        let name = String::deserialize(d)?;
        uss_catalogue::Catalogue::family_named(&name).ok_or_else(|| {
            let known: Vec<String> = Family::ALL
                .iter()
                .map(|f| format!("`{}`", f.name()))
                .collect();
            D::Error::custom(format!(
                "unknown variant `{name}`, expected one of {}",
                known.join(", ")
            ))
        })
    }
}

const fn default_family() -> Family {
    Family::Micromaster4
}

/// A parameter of a family's profile as the configuration names one (`""`: none).
fn profile_param(
    family: Family,
    role: impl Fn(&Catalogue) -> Option<uss_protocol::ParamRef>,
) -> ParamName {
    let param = Catalogue::of(family).and_then(role);
    ParamName::from(param.map_or_else(String::new, |p| p.to_string()))
}

/// What a drive gets when its controller is gone or stopped refreshing within its watchdog time
/// (docs/ARCHITECTURE.md, "Failure model"); the STW1 words are those of USS.md section 7.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Deserialize, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SafeCommand {
    /// OFF1: ramp down and stop (STW1 0x047E).
    #[default]
    Off1,
    /// OFF2: coast stop (STW1 0x047C).
    Off2,
    /// OFF3: quick stop (STW1 0x047A).
    Off3,
}

impl SafeCommand {
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

/// A `[[bus]]` table: its device, line settings, polling and retry policy, real-time placement
/// and drives. The keys' types say what each allows and its default.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BusConfig {
    /// Unique, [`MAX_BUS_NAME_LEN`](uss_shm_types::names::MAX_BUS_NAME_LEN) characters at most
    /// from `A-Z a-z 0-9 _ -`: it becomes part of shared-memory service names.
    pub name: String,
    pub device: Device,
    /// Character rate; the frame is always 8E1 (USS.md section 2).
    #[serde(default = "default_baud")]
    pub baud: Baud,
    /// A rate USS does not name (USS.md section 2) is refused unless this says it is meant.
    #[serde(default)]
    pub nonstandard_baud: bool,
    #[serde(default)]
    pub rs485: Rs485Mode,
    /// With `rs485 = "kernel"`: the RTS level while sending and the delays around sending;
    /// unset, the port's own (device tree) values are kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rs485_rts: Option<Rs485Rts>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rs485_delay_before_ms: Option<Rs485Delay>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rs485_delay_after_ms: Option<Rs485Delay>,
    /// A 2-wire adapter returns our own bytes: discard them (USS.md section 9).
    #[serde(default)]
    pub echo: bool,
    #[serde(default)]
    pub response_timeout_ms: ResponseTimeout,
    #[serde(default)]
    pub timeout_margin_ms: TimeoutMargin,
    /// How late the adapter delivers received bytes; `None`: read from sysfs when the line is
    /// opened (FTDI `latency_timer`, 8250 FIFO trigger, one USB frame, 0 for a pty).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rx_latency_ms: Option<RxLatencyMs>,
    #[serde(default)]
    pub retries: Retries,
    #[serde(default)]
    pub offline_after: OfflineAfter,
    #[serde(default)]
    pub offline_probe_ms: OfflineProbe,
    #[serde(default)]
    pub cycle_time_ms: CycleTime,
    #[serde(default)]
    pub param_timeout_ms: ParamTimeout,
    /// A drive with a parameter job waiting gets an extra poll after each regular poll of the
    /// circulating list (no other drive's poll period more than doubles).
    #[serde(default)]
    pub param_priority: bool,
    /// How long a serial line may stay down before ussd stops feeding systemd's watchdog.
    #[serde(default)]
    pub line_down_limit_ms: LineDownLimit,
    /// `None` = not pinned.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu: Option<Cpu>,
    #[serde(default)]
    pub priority: Priority,
    /// Fault injector and jitter seed of the simulated bus (only there: [`BusConfig::seed`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    #[serde(rename = "drive", default)]
    pub drives: Vec<DriveEntry>,
}

impl BusConfig {
    /// The simulated bus's seed: as written, or 1.
    pub fn seed(&self) -> u64 {
        self.seed.unwrap_or(1)
    }
}

/// A `[[bus.drive]]` table: one drive on a bus.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DriveEntry {
    /// 0..=31, unique per bus (USS.md section 1).
    pub address: Address,
    /// PKW mode (P2013) and PZD words (P2012): must match the drive's settings (USS.md section 3).
    #[serde(default = "default_pkw")]
    pub pkw: PkwMode,
    #[serde(default = "default_pzd")]
    pub pzd: PzdCount,
    #[serde(default)]
    pub weight: Weight,
    #[serde(default)]
    pub reference_hz: ReferenceHz,
    /// What kind of slave it is ([`Family`]).
    #[serde(default = "default_family", with = "family_name")]
    pub family: Family,
    /// The drive's reference frequency in Hz, read when it comes online; the drive's value is
    /// published (clients scale Hz by it) and a difference from `reference_hz` is reported.
    /// Unset: the family profile's, filled in as the file is read.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_param: Option<ParamName>,
    /// The motor's pole pairs (1..=32) for a drive whose reference is a speed (G120: p2000 in
    /// rpm): ussd reads p2000 and publishes `p2000 x pole_pairs / 60` Hz, which clients scale
    /// Hz by. Unset on a G120: Hz are scaled by `reference_hz`, unverified (ussd warns).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pole_pairs: Option<u8>,
    #[serde(default)]
    pub watchdog_ms: Watchdog,
    #[serde(default)]
    pub safe_command: SafeCommand,
    /// `false`: parameter writes are refused (read-only monitoring deployments).
    #[serde(default = "yes")]
    pub params_writable: bool,
    /// Read when the drive comes online; a telegram-off time above `monitoring_max_ms` is
    /// reported as too long. Unset: the family profile's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub monitoring_param: Option<ParamName>,
    #[serde(default)]
    pub monitoring_max_ms: MonitoringMax,
    /// Refuse ON unless the drive's telegram monitoring was read and is on within the limit.
    #[serde(default)]
    pub require_monitoring: bool,
    /// The drive takes broadcasts (ADR bit 5): a stop of every drive reaches it in one
    /// telegram. `false` for S110 and G120 firmware 4, which ignore them: they get their own.
    #[serde(default = "yes")]
    pub broadcast: bool,
    /// The parameters a write may change without `--unsafe` (`"P1120"`: every element,
    /// `"P2014.0"`: that one). A drive without a catalogue (`family = "generic"`) takes no
    /// write without it; for a family with a catalogue it narrows what the catalogue allows
    /// (its guarded parameters stay guarded). Unset: the family's catalogue decides.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub writable: Option<Vec<ParamName>>,
    /// Only on the simulated bus: the simulated drive's options (uss-sim's drive keys).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim: Option<SimOptions>,
}

impl DriveEntry {
    pub fn layout(&self) -> Layout {
        Layout::new(self.pkw, self.pzd)
    }

    /// The parameters `writable` names, as checked by the rules (`None`: unset).
    pub fn writable(&self) -> Option<Vec<uss_protocol::ParamRef>> {
        self.writable
            .as_ref()
            .map(|names| names.iter().filter_map(ParamName::param).collect())
    }

    /// The telegram-off time parameter: as written, else the family's.
    pub fn monitoring_param(&self) -> ParamName {
        self.monitoring_param
            .clone()
            .unwrap_or_else(|| profile_param(self.family, |c| c.monitoring))
    }

    /// The reference parameter: as written, else the family's (a G120's p2000 in rpm when its
    /// `pole_pairs` are given).
    pub fn reference_param(&self) -> ParamName {
        self.reference_param.clone().unwrap_or_else(|| {
            if self.pole_pairs.is_some() {
                profile_param(self.family, |c| c.reference_speed)
            } else {
                profile_param(self.family, |c| c.reference)
            }
        })
    }

    /// The unit of the reference parameter: rpm when `pole_pairs` are given, else Hz.
    pub fn reference_unit(&self) -> uss_engine::reference::ReferenceUnit {
        use uss_engine::reference::ReferenceUnit;
        self.pole_pairs
            .map_or(ReferenceUnit::Hz, |pole_pairs| ReferenceUnit::Rpm {
                pole_pairs,
            })
    }

    /// The simulated drive (config + fault plan) at this entry's address and layout with its
    /// `[bus.drive.sim]` options; the error says which option is wrong (checked as read).
    #[cfg(feature = "sim")]
    pub fn sim_spec(&self) -> Result<DriveSpec, String> {
        let mut options = self.sim.clone().unwrap_or_default();
        // The simulated drive is of the entry's family unless its options name another.
        options
            .family
            .get_or_insert_with(|| self.family.name().to_owned());
        DriveSpec::new(self.address, self.layout(), &options)
    }
}

/// What `ussd` runs with no arguments: one simulated bus at 115200 baud with four drives, the
/// third with a variable-length PKW, each watching its telegrams as we recommend real drives
/// to (P2014.0 = 100 ms, USS.md section 5).
#[cfg(feature = "sim")]
const EMBEDDED_DEFAULT: &str = r#"
[[bus]]
name = "bus0"
device = "sim"
drive = [
    { address = 1, sim = { p2014 = 100 } },
    { address = 2, sim = { p2014 = 100 } },
    { address = 3, pkw = 127, sim = { p2014 = 100 } },
    { address = 4, sim = { p2014 = 100 } },
]
"#;

impl Config {
    /// Reads and checks a configuration file. An unreadable file is a [`ConfigError`] without a
    /// line.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let origin = path.display().to_string();
        let text =
            std::fs::read_to_string(path).map_err(|e| ConfigError::unreadable(&origin, &e))?;
        Config::parse(&text, &origin)
    }

    /// Parses and checks a configuration; `origin` names it in errors (usually the file name).
    pub fn parse(text: &str, origin: &str) -> Result<Config, ConfigError> {
        let mut reporter = Reporter::new(text, origin);
        // Parsed once: the reporter keeps the tables with their spans, serde reads a copy.
        let root = DeTable::parse(text).map_err(|e| reporter.syntax(&e))?;
        reporter.root = Some(root.get_ref().clone());
        reporter.arrays_for_tables()?;
        let mut config: Config = serde_path_to_error::deserialize(toml::Deserializer::from(root))
            .map_err(|e| reporter.serde(&e))?;
        let broken = rules::check(&config, &reporter);
        // Of several broken rules, the one nearest the start of the file.
        if let Some(b) = broken
            .iter()
            .min_by_key(|b| b.span.as_ref().map_or(usize::MAX, |s| s.start))
        {
            return Err(reporter.rule(b));
        }
        for bus in config.buses.iter_mut().filter(|b| b.device == Device::Sim) {
            bus.seed = Some(bus.seed());
        }
        // The effective parameters, written back by `--check-config`.
        for drive in config.buses.iter_mut().flat_map(|b| b.drives.iter_mut()) {
            drive.monitoring_param = Some(drive.monitoring_param());
            drive.reference_param = Some(drive.reference_param());
        }
        Ok(config)
    }

    /// What `ussd` runs with no arguments (see [`EMBEDDED_DEFAULT`]): a simulated bus, so only
    /// in a build with the simulator.
    #[cfg(feature = "sim")]
    pub fn embedded_default() -> Config {
        match Config::parse(EMBEDDED_DEFAULT, "the embedded default") {
            Ok(config) => config,
            Err(e) => unreachable!("the embedded default is valid (tested): {e}"),
        }
    }

    /// What will not stop ussd but a user should know before it runs: each serial device that
    /// does not exist now (a USB adapter plugged in later: the line starts down).
    pub fn warnings(&self) -> Vec<String> {
        self.buses
            .iter()
            .filter_map(|bus| match &bus.device {
                Device::Serial(path) if SerialPath::of(path) == SerialPath::Absent => Some(
                    format!("bus {}: device {} {ABSENT}", bus.name, path.display()),
                ),
                _ => None,
            })
            .collect()
    }

    /// The effective configuration with every default filled in, as TOML that [`Config::parse`]
    /// accepts again (for `ussd --check-config`), after a comment on each serial device: a
    /// character device, something else, or not there now (ussd then opens it when it
    /// appears).
    pub fn to_toml(&self) -> String {
        let mut text =
            "# ussd configuration: the effective settings, every default filled in\n".to_owned();
        for bus in &self.buses {
            match &bus.device {
                Device::Serial(path) => {
                    let _ = writeln!(text, "# bus {}: {}", bus.name, device_note(path));
                }
                Device::Tcp(_) => {
                    let _ = writeln!(
                        text,
                        "# bus {}: {} is a serial device server's port (set to 8E1 and the \
                         bus's rate there); while it does not answer the bus is line down",
                        bus.name, bus.device
                    );
                }
                Device::Sim => {}
            }
        }
        text.push('\n');
        // Plain data of known types: serialising cannot fail.
        text.push_str(&toml::to_string(self).unwrap_or_default());
        text
    }
}

/// What ussd does with a serial device that is not there: `--check-config`'s warning and the
/// effective configuration's comment say it alike.
const ABSENT: &str =
    "does not exist now: ussd starts this bus line down and opens it when it appears";

/// What is at a serial device's path now.
fn device_note(path: &Path) -> String {
    let shown = path.display();
    match SerialPath::of(path) {
        SerialPath::Tty => format!("{shown} is a serial device (a tty)"),
        SerialPath::Absent => format!("warning: {shown} {ABSENT}"),
        SerialPath::Unknown => {
            format!("{shown} exists; this machine does not say whether it is a tty")
        }
        SerialPath::NotATty(what) => format!("{shown} is {what}"),
    }
}

#[cfg(test)]
#[cfg(feature = "sim")]
mod tests;
#[cfg(test)]
#[cfg(not(feature = "sim"))]
mod tests_without_sim;
