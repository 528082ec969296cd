//! The rules that need more than one value: unique bus names and drive addresses, the device,
//! `seed` and `sim` only on the simulated bus, a USS baud rate, a telegram monitoring that can be
//! verified. Each broken rule is an error at the value it is about, found again in the file by
//! the reporter.

use super::allowed::{BUS_NAMES, valid_bus_name};
use super::errors::{Broken, Reporter};
use super::{BusConfig, Config, Device, DriveEntry};
use core::ops::Range;
use uss_protocol::{Baud, PkwMode};

/// Every rule `config` breaks, placed in the file `reporter` reads.
pub fn check(config: &Config, reporter: &Reporter<'_>) -> Vec<Broken> {
    let mut rules = Rules {
        reporter,
        at: Vec::new(),
        broken: Vec::new(),
    };
    if config.buses.is_empty() {
        let problem = "no [[bus]] table: a configuration needs at least one bus";
        rules.push(None, "bus", problem.to_owned());
    }
    for (i, bus) in config.buses.iter().enumerate() {
        rules.at = vec![("bus", i)];
        if let Some(first) = config.buses[..i].iter().position(|b| b.name == bus.name) {
            let line = rules.line_of(&[("bus", first)], "name");
            let problem =
                format!("is used twice (first at line {line}): every bus needs its own name");
            rules.fail("name", &problem);
        }
        if let Some(first) = config.buses[..i]
            .iter()
            .position(|b| b.device.same_line(&bus.device))
        {
            let line = rules.line_of(&[("bus", first)], "device");
            let problem = format!(
                "is the device of bus \"{}\" too (line {line}): two buses cannot share one line \
                 (each would take the other's replies, and the second cannot open it)",
                config.buses[first].name
            );
            rules.fail("device", &problem);
        }
        rules.bus(bus);
    }
    rules.broken
}

struct Rules<'a> {
    reporter: &'a Reporter<'a>,
    /// The table the rules look at: `[("bus", 0), ("drive", 2)]`.
    at: Vec<(&'static str, usize)>,
    broken: Vec<Broken>,
}

impl Rules<'_> {
    /// A problem with the value of `key` in the current table: "`key = value` problem" (at the
    /// table when the file does not write the key).
    fn fail(&mut self, key: &'static str, problem: &str) {
        let span = self.reporter.span(&self.at, Some(key));
        let text = format!("{key} = {} {problem}", self.reporter.written(span.as_ref()));
        self.push(span, key, text);
    }

    /// A problem with `key` of the current table, in a sentence of its own, placed at `span`.
    fn push(&mut self, span: Option<Range<usize>>, key: &'static str, text: String) {
        let at = self.at.clone();
        self.broken.push(Broken {
            span,
            at,
            key,
            text,
        });
    }

    /// The line where the table at `at` writes `key`, for "first at line N".
    fn line_of(&self, at: &[(&str, usize)], key: &str) -> usize {
        let offset = self.reporter.span(at, Some(key)).map_or(0, |s| s.start);
        super::errors::position(self.reporter.text, offset).0
    }

    fn bus(&mut self, bus: &BusConfig) {
        if !valid_bus_name(&bus.name) {
            self.fail("name", &format!("is not allowed: {BUS_NAMES}"));
        }
        let device = self.device(&bus.device).then_some(&bus.device);
        self.baud(bus);
        if let Some(cpu) = bus.cpu {
            let online = std::thread::available_parallelism().ok().map(usize::from);
            if cpu.0 < 0 || online.is_some_and(|online| cpu.get() >= online) {
                let allowed = match online {
                    Some(n) => format!(
                        "this machine has {n} online CPU{}: cpu is 0..={}",
                        if n == 1 { "" } else { "s" },
                        n - 1
                    ),
                    None => "cpu is a CPU number from 0".to_owned(),
                };
                self.fail("cpu", &format!("is out of range: {allowed}"));
            }
        }
        if bus.rs485 != super::Rs485Mode::Kernel {
            for (key, set) in [
                ("rs485_rts", bus.rs485_rts.is_some()),
                ("rs485_delay_before_ms", bus.rs485_delay_before_ms.is_some()),
                ("rs485_delay_after_ms", bus.rs485_delay_after_ms.is_some()),
            ] {
                if set {
                    self.fail(
                        key,
                        "applies to the kernel's RS485 mode only: set rs485 = \"kernel\"",
                    );
                }
            }
        } else if bus.echo {
            self.fail(
                "echo",
                "cannot be heard with rs485 = \"kernel\": the kernel turns the receiver off \
                 while sending (set echo = false)",
            );
        }
        if bus.seed.is_some() && device.is_some_and(Device::is_line) {
            self.fail("seed", ONLY_ON_SIM);
        }
        if bus.drives.is_empty() {
            // At the [[bus]] table, also when it writes `drive = []`.
            let span = self.reporter.span(&self.at, None);
            let problem = "no [[bus.drive]] table: every bus needs at least one drive";
            self.push(span, "drive", problem.to_owned());
        }
        let bus_at = self.at[0];
        for (i, drive) in bus.drives.iter().enumerate() {
            self.at = vec![bus_at, ("drive", i)];
            if let Some(first) = bus.drives[..i]
                .iter()
                .position(|d| d.address == drive.address)
            {
                let line = self.line_of(&[bus_at, ("drive", first)], "address");
                let problem = format!(
                    "is used twice (first at line {line}): every drive on a bus needs its own \
                     address"
                );
                self.fail("address", &problem);
            }
            self.drive(drive, device);
        }
    }

    /// Whether the bus's device is usable (its kind says: [`Device::problem`]).
    fn device(&mut self, device: &Device) -> bool {
        match device.problem() {
            Some(problem) => {
                self.fail("device", &problem);
                false
            }
            None => true,
        }
    }

    /// USS names 13 rates (USS.md section 2); another one only when the file says it is meant.
    fn baud(&mut self, bus: &BusConfig) {
        if !bus.baud.is_standard() && !bus.nonstandard_baud {
            let named: Vec<String> = Baud::STANDARD.iter().map(ToString::to_string).collect();
            let problem = format!(
                "is not a USS baud rate (USS.md section 2: {}): set nonstandard_baud = true \
                 for a drive and adapter that take it",
                named.join(", ")
            );
            self.fail("baud", &problem);
        }
    }

    fn drive(&mut self, drive: &DriveEntry, device: Option<&Device>) {
        let (monitoring, reference) = (drive.monitoring_param(), drive.reference_param());
        let params = [
            (
                "monitoring_param",
                &monitoring,
                "name the drive's telegram-off time as the manual writes it, e.g. \"P2014.0\" \
                 (MICROMASTER 4, COM link) or \"p2040\" (G120), or \"\" for no check",
            ),
            (
                "reference_param",
                &reference,
                "name the drive's reference frequency in Hz as the manual writes it, e.g. \
                 \"P2000\" (MICROMASTER 4, G110), or \"\" for no check (G120: p2000 is a speed \
                 in rpm)",
            ),
        ];
        for (key, name, hint) in params {
            if let Err(e) = &name.parsed {
                self.fail(key, &format!("is not a parameter: {e}; {hint}"));
                return;
            }
        }
        if let Some(problem) = another_link(drive.family, monitoring.param()) {
            self.fail("monitoring_param", &problem);
            return;
        }
        if let Some(problem) = too_many_pzd(drive.family, drive.pzd.get()) {
            self.fail("pzd", &problem);
            return;
        }
        for name in drive.writable.iter().flatten() {
            match &name.parsed {
                Err(e) => {
                    let problem = format!(
                        "names {:?}, which is not a parameter: {e}; list them as the manual \
                         writes them, e.g. [\"P1120\", \"P1121\"]",
                        String::from(name.clone())
                    );
                    self.fail("writable", &problem);
                    return;
                }
                Ok(None) => {
                    self.fail(
                        "writable",
                        "names \"\": list parameters as the manual writes them, e.g. [\"P1120\"]",
                    );
                    return;
                }
                Ok(Some(_)) => {}
            }
        }
        if drive.require_monitoring {
            let missing = if monitoring.param().is_none() {
                "needs monitoring_param (e.g. \"P2014.0\"): ussd cannot verify a monitoring it \
                 does not read"
            } else if drive.pkw == PkwMode::None {
                "needs a parameter channel (pkw = 3, 4 or 127) to read the drive's telegram \
                 monitoring"
            } else {
                ""
            };
            if !missing.is_empty() {
                self.fail("require_monitoring", missing);
            }
        }
        match drive.pole_pairs {
            Some(0 | 33..) => self.fail(
                "pole_pairs",
                "is 1..=32: the motor's pole pairs (2 for a 4-pole motor, whose 1500 rpm is 50 Hz)",
            ),
            Some(_)
                if drive.reference_param.is_none()
                    && uss_catalogue::Catalogue::of(drive.family)
                        .and_then(|c| c.reference_speed)
                        .is_none() =>
            {
                self.fail(
                    "pole_pairs",
                    "is only for a drive whose reference is a speed in rpm (family = \"g120\": \
                     p2000); this family's reference is in Hz",
                );
            }
            _ => {}
        }
        if drive.sim.is_some() && device.is_some_and(Device::is_line) {
            let span = self.reporter.span(&self.at, Some("sim"));
            self.push(span, "sim", format!("sim {ONLY_ON_SIM}"));
        }
        #[cfg(feature = "sim")]
        if device == Some(&Device::Sim)
            && let Err(problem) = drive.sim_spec()
        {
            let span = self.reporter.span(&self.at, Some("sim"));
            self.push(span, "sim", format!("sim: {problem}"));
        }
    }
}

const ONLY_ON_SIM: &str =
    "is only allowed with device = \"sim\": the drives on a serial bus are real";

/// Why `pzd` words are more than a drive of `family` takes: its profile's PZD length parameter
/// (MM4 P2012[0], G120 p2022) allows fewer.
fn too_many_pzd(family: super::Family, pzd: usize) -> Option<String> {
    let profile = uss_catalogue::Catalogue::of(family)?;
    let (param, max) = profile.max_pzd().filter(|&(_, max)| pzd > max)?;
    let name = profile
        .param(param.pnu.get())
        .map_or("", |p| p.name.as_str());
    Some(format!(
        "is more than a {} takes: its {name} {param} is at most {max}; give family = \
         \"generic\" for another slave",
        profile.family
    ))
}

/// Why `given` is not the telegram-off time of the link ussd talks over, where the family's
/// profile names that time and `given` is another element of the same parameter (a
/// MICROMASTER 4's P2014[1], the BOP link, for its P2014[0], the COM link).
fn another_link(family: super::Family, given: Option<uss_protocol::ParamRef>) -> Option<String> {
    let given = given?;
    let profile = uss_catalogue::Catalogue::of(family)?;
    let own = profile
        .monitoring
        .filter(|own| own.pnu == given.pnu && own.index != given.index)?;
    let named = |r: uss_protocol::ParamRef| {
        let element = r.index.and_then(|i| {
            profile
                .param(r.pnu.get())?
                .elements
                .get(usize::from(i.get()))
                .cloned()
        });
        element.map_or_else(|| r.to_string(), |e| format!("{r} ({e})"))
    };
    Some(format!(
        "names {}, not the telegram-off time of the link ussd talks over: {}; write \"{own}\", \
         or leave the key out",
        named(given),
        named(own)
    ))
}
