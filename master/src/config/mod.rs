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
//! all out. serde reads the file ([`file`]: unknown keys refused in every table, each value
//! range checked by its type), then [`rules`] checks what needs more than one value. Every
//! error names the file, line and column, the bus and drive, the key, and what is allowed
//! ([`errors`]); of several broken rules the one nearest the start of the file is reported.

mod errors;
mod file;
mod rules;

pub use errors::ConfigError;
pub use rules::BUS_NAME_MAX;

use core::fmt::Write as _;
use errors::Reporter;
use file::File;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Duration;
use toml::Spanned;
use toml::de::DeTable;
#[cfg(feature = "sim")]
use uss_drive_sim::spec::DriveSpec;
use uss_protocol::{Address, Baud, Layout, ParamRef};
use uss_shm_types::StopCommand;

/// A whole configuration: one or more buses, each run by its own real-time thread.
#[derive(Debug, Clone)]
pub struct Config {
    pub buses: Vec<BusConfig>,
    /// The file as read, with every default: what [`Config::to_toml`] writes.
    file: File,
}

/// Two configurations are the same when they run the same buses.
impl PartialEq for Config {
    fn eq(&self, other: &Self) -> bool {
        self.buses == other.buses
    }
}

/// Where a bus lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Device {
    /// The built-in simulated bus: `uss-drive-sim` drives on an in-process virtual wire.
    Sim,
    /// A serial device (RS485 adapter, embedded UART, or a pseudo-terminal).
    Serial(PathBuf),
}

/// The device name of the built-in simulated bus.
const SIM_DEVICE: &str = "sim";

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
    /// Added to the response timeout for adapters with latency (USS.md section 9).
    pub timeout_margin: Duration,
    /// Retries after a failed exchange, like the S7-1200 library's 2 (USS.md section 8).
    pub retries: u8,
    /// Consecutive polls that failed all their retries before a drive is marked offline.
    pub offline_after: u32,
    /// An offline drive is polled at most this often.
    pub offline_probe: Duration,
    /// A fixed cycle time for the circulating list, waited out after its last entry; `None` = as
    /// fast as the wire allows (USS.md section 5).
    pub cycle_time: Option<Duration>,
    /// A parameter job with no matching reply in this time ends with a timeout (USS.md section 6).
    pub param_timeout: Duration,
    /// A drive with a parameter job waiting gets an extra poll after each regular poll of the
    /// circulating list (no other drive's poll period more than doubles).
    pub param_priority: bool,
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
    /// The simulated drive (config + fault plan), only with `Device::Sim`: this entry's address
    /// and layout with its `[bus.drive.sim]` options.
    #[cfg(feature = "sim")]
    pub sim: Option<DriveSpec>,
}

/// The fault plan inside [`DriveSpec`] has no `PartialEq` (it also counts injected faults);
/// comparing the simulated drives' configurations compares what the file set.
impl PartialEq for DriveEntry {
    fn eq(&self, other: &Self) -> bool {
        #[cfg(feature = "sim")]
        let same_sim = self.sim.as_ref().map(|s| s.config) == other.sim.as_ref().map(|s| s.config);
        #[cfg(not(feature = "sim"))]
        let same_sim = true;
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
            && same_sim
    }
}

/// What `ussd` runs with no arguments: one simulated bus at 115200 baud with four drives, the
/// third with a variable-length PKW, each watching its telegrams as we recommend real drives
/// to (P2014.1 = 100 ms, USS.md section 5).
#[cfg(feature = "sim")]
const EMBEDDED_DEFAULT: &str = r#"
[[bus]]
name = "bus0"
device = "sim"

[[bus.drive]]
address = 1
sim = { p2014 = 100 }

[[bus.drive]]
address = 2
sim = { p2014 = 100 }

[[bus.drive]]
address = 3
pkw = 127
sim = { p2014 = 100 }

[[bus.drive]]
address = 4
sim = { p2014 = 100 }
"#;

impl Config {
    /// Reads and checks a configuration file. An unreadable file is a [`ConfigError`] without a
    /// line.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let origin = path.display().to_string();
        match std::fs::read_to_string(path) {
            Ok(text) => Config::parse(&text, &origin),
            Err(e) => Err(Reporter {
                text: "",
                origin: &origin,
                root: None,
            }
            .io(&e)),
        }
    }

    /// Parses and checks a configuration; `origin` names it in errors (usually the file name).
    pub fn parse(text: &str, origin: &str) -> Result<Config, ConfigError> {
        let mut reporter = Reporter {
            text,
            origin,
            root: None,
        };
        let root = DeTable::parse(text).map_err(|e| reporter.syntax(&e))?;
        reporter.root = Some(root.into_inner());
        let file: File = toml::from_str(text).map_err(|e| reporter.serde(&e))?;
        rules::check(file, text).map_err(|broken| {
            let nearest = broken
                .iter()
                .min_by_key(|b| b.span.as_ref().map_or(usize::MAX, |s| s.start));
            // `check` fails only with something broken.
            nearest.map_or_else(
                || unreachable!("a refused configuration names what is broken"),
                |b| reporter.rule(b),
            )
        })
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

    /// The effective configuration with every default filled in, as TOML that [`Config::parse`]
    /// accepts again (for `ussd --check-config`), after a comment on each serial device: a
    /// character device, something else, or not there now (ussd then opens it when it
    /// appears).
    pub fn to_toml(&self) -> String {
        let mut file = self.file.clone();
        for (table, bus) in file.bus.iter_mut().zip(&self.buses) {
            let table = table.get_mut();
            table.seed = match bus.device {
                Device::Sim => Some(Spanned::new(0..0, bus.seed)),
                Device::Serial(_) => None,
            };
            for drive in &mut table.drive {
                let drive = drive.get_mut();
                if drive.require_monitoring.is_none() {
                    drive.require_monitoring = Some(Spanned::new(0..0, false));
                }
            }
        }
        let mut text =
            "# ussd configuration: the effective settings, every default filled in\n".to_owned();
        for bus in &self.buses {
            if let Device::Serial(path) = &bus.device {
                let _ = writeln!(text, "# bus {}: {}", bus.name, device_note(path));
            }
        }
        text.push('\n');
        // Plain data of known types: serialising cannot fail.
        text.push_str(&toml::to_string(&file).unwrap_or_default());
        text
    }
}

/// What is at a serial device's path now.
fn device_note(path: &Path) -> String {
    use std::os::unix::fs::FileTypeExt as _;
    let shown = path.display();
    match std::fs::metadata(path) {
        Ok(m) if m.file_type().is_char_device() => format!("{shown} is a character device"),
        Ok(_) => format!("{shown} is not a character device: a serial adapter or pty is one"),
        Err(_) => format!(
            "{shown} does not exist now: ussd starts this bus line down and opens it when it \
             appears"
        ),
    }
}

#[cfg(test)]
#[cfg(feature = "sim")]
mod tests;
#[cfg(test)]
#[cfg(not(feature = "sim"))]
mod tests_without_sim;
