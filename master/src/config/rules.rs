//! The rules that need more than one value, and the conversion of a read file into the
//! [`Config`] the daemon runs: unique bus names and drive addresses, the device, `seed` and
//! `sim` only on the simulated bus, a USS baud rate, an online CPU, a telegram monitoring that
//! can be verified. Each broken rule is an error at the value it is about; the one nearest the
//! start of the file is reported.

use super::file::{BusTable, DriveTable, File};
use super::{BusConfig, Config, Device, DriveEntry, SIM_DEVICE};
use core::ops::Range;
use std::path::{Path, PathBuf};
use toml::Spanned;
#[cfg(feature = "sim")]
use uss_drive_sim::spec::DriveSpec;
use uss_protocol::{Baud, Layout, ParamRef, PkwMode};

/// The longest bus name: it becomes part of shared-memory service names.
pub const BUS_NAME_MAX: usize = 32;

/// A broken rule: where (byte span; `None`: nowhere in the text), which key (the path below the
/// table, e.g. `name` or `drive`), and what is wrong and allowed.
#[derive(Debug)]
pub struct Broken {
    pub span: Option<Range<usize>>,
    /// `bus[0]`, `bus[0].drive[2]`, or empty for the file.
    pub table: String,
    pub key: String,
    pub kind: Kind,
    pub problem: String,
}

/// How a problem reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// About the value: "`key = value` problem".
    Value,
    /// A sentence of its own.
    Whole,
}

/// Whether `name` is a valid bus name: 1..=32 of `A-Z a-z 0-9 _ -`.
pub fn valid_bus_name(name: &str) -> bool {
    (1..=BUS_NAME_MAX).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// The rules' verdict on `file`, read from `text`: the configuration, or every broken rule.
pub fn check(file: File, text: &str) -> Result<Config, Vec<Broken>> {
    let mut broken = Vec::new();
    if file.bus.is_empty() {
        broken.push(Broken {
            span: None,
            table: String::new(),
            key: "bus".into(),
            kind: Kind::Whole,
            problem: "no [[bus]] table: a configuration needs at least one bus".into(),
        });
    }
    let online_cpus = std::thread::available_parallelism().ok().map(usize::from);
    let mut buses = Vec::new();
    for (i, bus) in file.bus.iter().enumerate() {
        let mut rules = Rules {
            text,
            table: format!("bus[{i}]"),
            broken: &mut broken,
        };
        if let Some(earlier) = file.bus[..i]
            .iter()
            .find(|b| b.get_ref().name.get_ref() == bus.get_ref().name.get_ref())
        {
            rules.name_twice(&bus.get_ref().name, earlier.get_ref().name.span());
        }
        if let Some(config) = rules.bus(bus, online_cpus) {
            buses.push(config);
        }
    }
    if broken.is_empty() {
        Ok(Config { buses, file })
    } else {
        Err(broken)
    }
}

struct Rules<'a> {
    text: &'a str,
    table: String,
    broken: &'a mut Vec<Broken>,
}

impl Rules<'_> {
    /// A problem with the value of `key` at `span`.
    fn fail(&mut self, span: Option<Range<usize>>, key: &str, problem: String) {
        self.push(span, key, Kind::Value, problem);
    }

    /// A problem that reads as a sentence of its own.
    fn fail_whole(&mut self, span: Option<Range<usize>>, key: &str, problem: String) {
        self.push(span, key, Kind::Whole, problem);
    }

    fn push(&mut self, span: Option<Range<usize>>, key: &str, kind: Kind, problem: String) {
        self.broken.push(Broken {
            span,
            table: self.table.clone(),
            key: key.to_owned(),
            kind,
            problem,
        });
    }

    /// The line of a byte offset, for "first at line N".
    fn line(&self, offset: usize) -> usize {
        super::errors::position(self.text, offset).0
    }

    fn name_twice(&mut self, name: &Spanned<String>, first: Range<usize>) {
        let problem = format!(
            "is used twice (first at line {}): every bus needs its own name",
            self.line(first.start)
        );
        self.fail(Some(name.span()), "name", problem);
    }

    fn bus(&mut self, table: &Spanned<BusTable>, online_cpus: Option<usize>) -> Option<BusConfig> {
        let bus = table.get_ref();
        let name = bus.name.get_ref();
        if !valid_bus_name(name) {
            let problem = format!(
                "is not allowed: a bus name is 1..={BUS_NAME_MAX} characters from A-Z, a-z, \
                 0-9, _ and - (it becomes part of shared-memory service names)"
            );
            self.fail(Some(bus.name.span()), "name", problem);
        }
        let device = self.device(&bus.device);
        let on_sim = device == Some(Device::Sim);
        self.baud(bus);
        if let Some(cpu) = &bus.cpu {
            let n = *cpu.get_ref();
            if n < 0 || online_cpus.is_some_and(|online| n as usize >= online) {
                let allowed = match online_cpus {
                    Some(n) => format!(
                        "this machine has {n} online CPU{}: cpu is 0..={}",
                        if n == 1 { "" } else { "s" },
                        n - 1
                    ),
                    None => "cpu is a CPU number from 0".to_owned(),
                };
                self.fail(
                    Some(cpu.span()),
                    "cpu",
                    format!("is out of range: {allowed}"),
                );
            }
        }
        if let Some(seed) = bus.seed.as_ref().filter(|_| device.is_some() && !on_sim) {
            self.fail(Some(seed.span()), "seed", only_on_sim());
        }
        if bus.drive.is_empty() {
            let problem = "no [[bus.drive]] table: every bus needs at least one drive".to_owned();
            self.fail_whole(Some(table.span()), "drive", problem);
        }
        let bus_table = self.table.clone();
        let mut drives = Vec::new();
        for (i, drive) in bus.drive.iter().enumerate() {
            self.table = format!("{bus_table}.drive[{i}]");
            if let Some(first) = bus.drive[..i]
                .iter()
                .find(|d| d.get_ref().address.get_ref() == drive.get_ref().address.get_ref())
            {
                let problem = format!(
                    "is used twice (first at line {}): every drive on a bus needs its own address",
                    self.line(first.get_ref().address.span().start)
                );
                self.fail(Some(drive.get_ref().address.span()), "address", problem);
            }
            drives.push(self.drive(drive.get_ref(), device.as_ref()));
        }
        self.table = bus_table;
        let device = device?;
        let drives = drives.into_iter().collect::<Option<Vec<_>>>()?;
        Some(BusConfig {
            name: name.clone(),
            device,
            baud: *bus.baud.get_ref(),
            rs485: bus.rs485,
            echo: bus.echo,
            response_timeout: bus.response_timeout_ms.duration(),
            timeout_margin: bus.timeout_margin_ms.duration(),
            retries: bus.retries.0,
            offline_after: bus.offline_after.0,
            offline_probe: bus.offline_probe_ms.duration(),
            cycle_time: Some(bus.cycle_time_ms.duration()).filter(|d| !d.is_zero()),
            param_timeout: bus.param_timeout_ms.duration(),
            param_priority: bus.param_priority,
            cpu: bus.cpu.as_ref().map(|c| *c.get_ref() as usize),
            priority: bus.priority.0,
            seed: bus.seed.as_ref().map_or(1, |s| *s.get_ref()),
            drives,
        })
    }

    /// "sim", or a serial device: one that exists, or an absolute path that may appear later
    /// (ussd starts that bus line down and opens the device when it appears).
    fn device(&mut self, device: &Spanned<String>) -> Option<Device> {
        let path = device.get_ref();
        if path == SIM_DEVICE && cfg!(feature = "sim") {
            return Some(Device::Sim);
        }
        if !path.is_empty() && (Path::new(path).exists() || Path::new(path).is_absolute()) {
            return Some(Device::Serial(PathBuf::from(path)));
        }
        let problem = if path == SIM_DEVICE {
            "is not available: this ussd was built without the simulated bus (the `sim` \
             feature of uss-master)"
        } else if path.is_empty() {
            "is not allowed"
        } else {
            "does not exist (a device that may be absent when ussd starts needs its absolute \
             path)"
        };
        let allowed = if cfg!(feature = "sim") {
            "device is \"sim\" (the built-in simulated bus) or the path of a serial device"
        } else {
            "device is the path of a serial device"
        };
        self.fail(
            Some(device.span()),
            "device",
            format!("{problem}: {allowed}"),
        );
        None
    }

    /// USS names 13 rates (USS.md section 2); another one only when the file says it is meant.
    fn baud(&mut self, bus: &BusTable) {
        let baud = *bus.baud.get_ref();
        if !baud.is_standard() && !bus.nonstandard_baud {
            let named: Vec<String> = Baud::STANDARD.iter().map(ToString::to_string).collect();
            let problem = format!(
                "is not a USS baud rate (USS.md section 2: {}): set nonstandard_baud = true \
                 for a drive and adapter that take it",
                named.join(", ")
            );
            self.fail(Some(bus.baud.span()), "baud", problem);
        }
    }

    fn drive(&mut self, drive: &DriveTable, device: Option<&Device>) -> Option<DriveEntry> {
        let layout = Layout::new(drive.pkw, drive.pzd);
        let address = *drive.address.get_ref();
        let written = drive.monitoring_param.get_ref();
        let monitoring_param = match written.parse::<ParamRef>() {
            _ if written.is_empty() => None,
            Ok(param) => Some(param),
            Err(e) => {
                let problem = format!(
                    "is not a parameter: {e}; name the drive's telegram-off time as the manual \
                     writes it, e.g. \"P2014.1\" (MICROMASTER 4, COM link) or \"p2040\" \
                     (G120), or \"\" for no check"
                );
                self.fail(
                    Some(drive.monitoring_param.span()),
                    "monitoring_param",
                    problem,
                );
                return None;
            }
        };
        let require = drive.require_monitoring.as_ref();
        if let Some(required) = require.filter(|r| *r.get_ref()) {
            let missing = if monitoring_param.is_none() {
                Some(
                    "needs monitoring_param (e.g. \"P2014.1\"): ussd cannot verify a monitoring \
                     it does not read",
                )
            } else if drive.pkw == PkwMode::None {
                Some(
                    "needs a parameter channel (pkw = 3, 4 or 127) to read the drive's telegram \
                     monitoring",
                )
            } else {
                None
            };
            if let Some(missing) = missing {
                self.fail(
                    Some(required.span()),
                    "require_monitoring",
                    missing.to_owned(),
                );
            }
        }
        if let (Some(sim), Some(Device::Serial(_))) = (&drive.sim, device) {
            let problem = format!("sim {}", only_on_sim());
            self.fail_whole(Some(sim.span()), "sim", problem);
        }
        #[cfg(feature = "sim")]
        let sim = match (&drive.sim, device) {
            (sim, Some(Device::Sim)) => {
                let options = sim
                    .as_ref()
                    .map(|s| s.get_ref().clone())
                    .unwrap_or_default();
                match DriveSpec::new(address, layout, &options) {
                    Ok(spec) => Some(spec),
                    Err(problem) => {
                        let span = sim.as_ref().map(Spanned::span);
                        self.fail_whole(span, "sim", format!("sim: {problem}"));
                        None
                    }
                }
            }
            _ => None,
        };
        Some(DriveEntry {
            address,
            layout,
            weight: drive.weight.0,
            reference_hz: drive.reference_hz.0,
            watchdog: drive.watchdog_ms.duration(),
            safe_command: drive.safe_command,
            params_writable: drive.params_writable,
            monitoring_param,
            monitoring_max: drive.monitoring_max_ms.duration(),
            require_monitoring: require.is_some_and(|r| *r.get_ref()),
            #[cfg(feature = "sim")]
            sim,
        })
    }
}

fn only_on_sim() -> String {
    "is only allowed with device = \"sim\": the drives on a serial bus are real".to_owned()
}
