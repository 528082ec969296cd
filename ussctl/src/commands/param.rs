//! `param read`, `param write`, `faults`: parameters through ussd.

use crate::cli::{self, Kind, ParamRef, address, param_ref};
use crate::report::{FaultsReport, ParamReport, QuickReport, ResetReport, SaveReport};
use crate::{Failure, Output};
use uss_client::Address;
use uss_client::{Bus, ParamError, ParamValue, WriteOptions};

/// `param read`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Read {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
    /// The parameter as the manuals write it: P1082, p1082, r0021, 1082, P0947[3], r0947.3
    /// (an array without an index: every element).
    #[arg(value_name = "PARAM", value_parser = param_ref)]
    param: ParamRef,
    /// How to show the value of a parameter whose type neither the catalogue nor the
    /// drive describes. A parameter whose type is known is always shown as that type (a
    /// named type of another kind is refused).
    #[arg(long = "type", value_enum)]
    kind: Option<Kind>,
}

impl Read {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        read(bus, out, self.drive, self.param, self.kind)
    }
}

/// `param describe`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Describe {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
    /// The parameter as the manuals write it: P1082, p1082, r0021, 1082.
    #[arg(value_name = "PARAM", value_parser = param_ref)]
    param: ParamRef,
}

impl Describe {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        describe(bus, out, self.drive, self.param)
    }
}

/// `faults`' arguments.
#[derive(Debug, clap::Args)]
pub struct Faults {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
}

impl Faults {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        faults(bus, out, self.drive)
    }
}

fn read(
    bus: &Bus,
    out: &Output,
    drive: Address,
    param: ParamRef,
    kind: Option<Kind>,
) -> Result<(), Failure> {
    let failed = |source| Failure::Param {
        drive,
        param: param.to_string(),
        source,
    };
    let values = match kind {
        // The parameter's own type (catalogue, or asked from the drive); an array named
        // without an element is read whole, a line per element.
        None => bus.read_elements(drive, param).map_err(failed)?,
        // A type named for a parameter whose own type is known: the same kind, read as its own
        // (found once), or refused; else the type the user says, as the drive sent it.
        Some(kind) => match bus
            .named_type(drive, param, kind.data_type())
            .map_err(|source| Failure::Value { drive, source })?
        {
            Some(own) => bus
                .read_elements_described(drive, param, own)
                .map_err(failed)?,
            None => vec![ParamValue {
                param,
                raw: bus.read(drive, param).map_err(failed)?,
                data_type: kind.data_type(),
                info: None,
                digits: bus.param_digits(drive),
            }],
        },
    };
    for v in &values {
        out.show(&ParamReport::new(bus.name(), drive, v), ParamReport::human)?;
    }
    Ok(())
}

use std::fmt::Write as _;

/// `param describe DRIVE PARAM`: what the drive says the parameter is, and the catalogue.
fn describe(bus: &Bus, out: &Output, drive: Address, param: ParamRef) -> Result<(), Failure> {
    let pnu = param.pnu;
    let drive_says = bus
        .drive_description(drive, pnu)
        .map_err(|source| Failure::Param {
            drive,
            param: param.to_string(),
            source,
        })?;
    let entry = bus.catalogue_entry(drive, pnu);
    let report = DescribeReport {
        bus: bus.name().to_owned(),
        drive: drive.get(),
        param: bus.notation(drive, entry.map_or(param, |p| p.id)),
        family: bus.family(drive).name(),
        drive_type: format!("{:?}", drive_says.data_type),
        drive_elements: drive_says.elements,
        drive_read_only: drive_says.read_only,
        drive_min: drive_says.min,
        drive_max: drive_says.max,
        catalogue: entry.map(|p| CatalogueEntry {
            name: p.name.clone(),
            data_type: format!("{:?}", p.data_type),
            unit: p.unit.clone(),
            array: p.array,
            data_sets: p.data_sets,
            level: p.level,
            change: p.change.words(),
            min: p.min,
            max: p.max,
            default: p.default,
            agrees: p.data_type == drive_says.data_type,
        }),
    };
    out.show(&report, DescribeReport::human)
}

/// `param describe`'s report.
#[derive(Debug, serde::Serialize, schemars::JsonSchema)]
pub(crate) struct DescribeReport {
    bus: String,
    drive: u8,
    param: String,
    family: &'static str,
    /// The data type the drive describes (descriptive element 1).
    drive_type: String,
    /// Its elements as the drive describes them (element 2: 0 plain); null: not said.
    drive_elements: Option<u16>,
    /// Whether the drive says it is read-only (element 4); null: not said.
    drive_read_only: Option<bool>,
    /// Its limits as the drive describes them (elements 7 and 8); null: not said (a 3-word
    /// parameter channel cannot carry them).
    drive_min: Option<f64>,
    drive_max: Option<f64>,
    /// The catalogue's entry of the drive's family; null when it has none.
    catalogue: Option<CatalogueEntry>,
}

#[derive(Debug, serde::Serialize, schemars::JsonSchema)]
struct CatalogueEntry {
    name: String,
    data_type: String,
    unit: String,
    array: u16,
    /// Elements by data set on the drives that have them (0: none).
    data_sets: u8,
    level: u8,
    /// When it may be changed: "any time", "not while running", "in quick commissioning
    /// (P0010 = 1)", "never (read-only)".
    change: &'static str,
    min: Option<f64>,
    max: Option<f64>,
    /// The factory setting, where the catalogue knows it.
    default: Option<f64>,
    /// Whether the catalogue's data type is the drive's.
    agrees: bool,
}

/// `min..=max`, or "?" for a side not known.
fn limits(min: Option<f64>, max: Option<f64>) -> String {
    let side = |v: Option<f64>| v.map_or_else(|| "?".to_owned(), |v| v.to_string());
    format!("{}..={}", side(min), side(max))
}

impl DescribeReport {
    fn human(&self) -> String {
        let elements = match self.drive_elements {
            Some(0) | None => String::new(),
            Some(n) => format!(", {n} elements"),
        };
        let limits_said = if self.drive_min.is_some() || self.drive_max.is_some() {
            format!(", limits {}", limits(self.drive_min, self.drive_max))
        } else {
            String::new()
        };
        let read_only = if self.drive_read_only == Some(true) {
            ", read-only"
        } else {
            ""
        };
        let mut out = format!(
            "drive {} {} ({}): the drive describes it as {}{elements}{limits_said}{read_only}\n",
            self.drive, self.param, self.family, self.drive_type
        );
        match &self.catalogue {
            Some(c) => {
                let array = if c.array > 0 {
                    format!(", {} elements", c.array)
                } else {
                    String::new()
                };
                let unit = if c.unit.is_empty() {
                    String::new()
                } else {
                    format!(", {}", c.unit)
                };
                let array = if c.data_sets > 0 {
                    format!(
                        "{array}, one per data set ({} on a MICROMASTER 440)",
                        c.data_sets
                    )
                } else {
                    array
                };
                let default = c
                    .default
                    .map(|d| format!(", factory setting {d}"))
                    .unwrap_or_default();
                let _ = writeln!(
                    out,
                    "catalogue: {}, {}{unit}{array}, access level {}, changed {}, limits {}{default}{}",
                    c.name,
                    c.data_type,
                    c.level,
                    c.change,
                    limits(c.min, c.max),
                    if c.agrees {
                        ""
                    } else {
                        " (NOT the drive's data type: the catalogue is wrong for this drive)"
                    }
                );
            }
            None => {
                out.push_str("catalogue: none for this family: the drive's description is used\n");
            }
        }
        out
    }
}

/// `param write`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Write {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    pub(crate) drive: Address,
    /// The parameter as the manuals write it: P1082, p1082, 1082, P2014[0], P2014.0 (an
    /// array by its element only).
    #[arg(value_name = "PARAM", value_parser = param_ref)]
    pub(crate) param: ParamRef,
    /// A number, converted to the parameter's type: decimal (-3, 45.5, 1e3; a whole number
    /// however written for an integer type) or 0x hex, the type's bits (0x41200000 is 10.0
    /// for a float).
    #[arg(allow_negative_numbers = true)]
    pub(crate) value: String,
    /// Store in EEPROM as well as RAM (survives a power cycle). A SINAMICS G120 stores no
    /// single value so (ussd refuses it): write to RAM, then `param save`.
    #[arg(long)]
    pub(crate) eeprom: bool,
    /// The type to send to a parameter whose type neither the catalogue nor the drive
    /// describes. Otherwise VALUE is converted to the parameter's own type and refused
    /// when it does not fit (a named type of another kind is refused too).
    #[arg(long = "type", value_enum)]
    pub(crate) kind: Option<Kind>,
    /// Write even though another process controls the drive (a deliberate act).
    #[arg(long)]
    pub(crate) force: bool,
    /// Write even a parameter that takes the drive away from ussd: its command or setpoint
    /// source, its COM link, telegram monitoring off, a factory reset (the family's
    /// catalogue marks them). ussd logs it; the value is read back and verified.
    #[arg(long = "unsafe")]
    pub(crate) guarded: bool,
}

impl Write {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        write(bus, out, self)
    }
}

fn write(bus: &Bus, out: &Output, w: &Write) -> Result<(), Failure> {
    let options = WriteOptions {
        eeprom: w.eeprom,
        force: w.force,
        unsafe_write: w.guarded,
    };
    let (drive, param) = (w.drive, w.param);
    let failed = |source| match source {
        ParamError::Value { .. } => Failure::Value { drive, source },
        ParamError::MaybeApplied { .. } => Failure::MaybeApplied {
            drive,
            param: param.to_string(),
            source: Box::new(source),
            check: cli::command_line(bus.name(), &format!("param read {drive} {param}")),
        },
        source => match bus.refusal_hint(drive, param, &source) {
            Some(hint) => Failure::Refused {
                drive,
                param: param.to_string(),
                source: Box::new(source),
                hint,
            },
            None => Failure::Param {
                drive,
                param: param.to_string(),
                source,
            },
        },
    };
    // A type named for a parameter whose own type is known: the same kind, written as its own
    // (found once), or refused.
    let own = match w.kind {
        Some(kind) => bus
            .named_type(drive, param, kind.data_type())
            .map_err(|source| Failure::Value { drive, source })?,
        None => None,
    };
    let now = match (w.kind, own) {
        // Converted to the parameter's own type; what does not fit is refused before the bus.
        (None, _) => bus
            .write_param(drive, param, &w.value, options)
            .map_err(failed)?,
        (Some(_), Some(own)) => bus
            .write_param_described(drive, param, &w.value, options, own)
            .map_err(failed)?,
        // The type the user says, for a parameter whose own is not known here.
        (Some(kind), None) => {
            let (value, _) = cli::parse_value(&w.value, Some(kind)).map_err(Failure::Usage)?;
            ParamValue {
                param,
                raw: bus
                    .write_with(drive, param, value, options)
                    .map_err(failed)?,
                data_type: kind.data_type(),
                info: None,
                digits: bus.param_digits(drive),
            }
        }
    };
    let mut report = ParamReport::new(bus.name(), drive, &now);
    report.eeprom = Some(w.eeprom);
    out.show(&report, ParamReport::human)
}

/// `param save`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Save {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
}

impl Save {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        let drive = self.drive;
        // Ctrl-C does not cut the copy between its raise of the access level and its put-back.
        crate::catch_signals()?;
        let saved = bus.save_to_rom(drive).map_err(|source| Failure::Param {
            drive,
            param: "copy RAM to ROM".to_owned(),
            source,
        })?;
        out.show(
            &SaveReport::new(bus.name(), drive, &saved),
            SaveReport::human,
        )
    }
}

/// `param factory-reset`'s arguments.
#[derive(Debug, clap::Args)]
pub struct FactoryReset {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
    /// Required: the reset takes the drive's command source, COM link and telegram monitoring
    /// back to their factory values (ussd logs it).
    #[arg(long = "unsafe")]
    unsafe_write: bool,
    /// Reset even though another process controls the drive (a deliberate act).
    #[arg(long)]
    force: bool,
}

impl FactoryReset {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        let drive = self.drive;
        // Ctrl-C does not cut the reset between P0010 = 30 and its end.
        crate::catch_signals()?;
        let reset = bus
            .factory_reset(drive, deliberate(self.force, self.unsafe_write))
            .map_err(commissioning_failed(drive, "factory reset", || {
                format!(
                    "drive {drive}: a factory reset puts every setting back to its factory value, the command source, the COM link and the telegram monitoring included; give --unsafe to do it deliberately (nothing was written)"
                )
            }))?;
        out.show(
            &ResetReport::new(bus.name(), drive, &reset),
            ResetReport::human,
        )
    }
}

/// A commissioning call's writes, RAM only: `--force`, and `--unsafe` for its guarded write.
const fn deliberate(force: bool, unsafe_write: bool) -> WriteOptions {
    WriteOptions {
        eeprom: false,
        force,
        unsafe_write,
    }
}

/// A commissioning call's error as ussctl reports it: the library's refusal of the guarded
/// write without --unsafe as a usage error that says `without_unsafe`; the rest naming `what`.
fn commissioning_failed<'a>(
    drive: Address,
    what: &'a str,
    without_unsafe: impl FnOnce() -> String + 'a,
) -> impl FnOnce(ParamError) -> Failure + 'a {
    move |source| match source {
        ParamError::Guarded { .. } => Failure::Usage(without_unsafe()),
        source => Failure::Param {
            drive,
            param: what.to_owned(),
            source,
        },
    }
}

/// `param quick-commission`'s arguments.
#[derive(Debug, clap::Args)]
pub struct QuickCommission {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
    /// A motor value from its rating plate, PARAM=VALUE in the parameter's own unit, written
    /// in the order given (e.g. --set P0304=400 --set P0305=1.9 --set P0307=0.75 --set
    /// P0310=50 --set P0311=1395).
    #[arg(long = "set", value_name = "PARAM=VALUE", value_parser = param_value)]
    set: Vec<(ParamRef, String)>,
    /// The end of quick commissioning (P3900): 3 calculates the motor model only; 2 also puts
    /// the I/O back to factory values; 1 also every other setting, the command source, the COM
    /// link and the telegram monitoring included.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=3))]
    end: u16,
    /// Required: the end of quick commissioning is a guarded write (1 takes the drive off
    /// this link; every end recalculates the motor model). ussd logs it.
    #[arg(long = "unsafe")]
    unsafe_write: bool,
    /// Commission even though another process controls the drive (a deliberate act).
    #[arg(long)]
    force: bool,
}

/// `P0304=400`: a parameter and the text of its value.
fn param_value(s: &str) -> Result<(ParamRef, String), String> {
    let (param, value) = s
        .split_once('=')
        .ok_or_else(|| format!("{s}: give PARAM=VALUE, e.g. P0304=400"))?;
    let param = param_ref(param.trim())?;
    Ok((param, value.trim().to_owned()))
}

impl QuickCommission {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        let drive = self.drive;
        // Ctrl-C does not cut it between P0010 = 1 and its end.
        crate::catch_signals()?;
        let motor: Vec<(ParamRef, &str)> = self.set.iter().map(|(p, v)| (*p, v.as_str())).collect();
        let done = bus
            .quick_commission(
                drive,
                &motor,
                self.end,
                deliberate(self.force, self.unsafe_write),
            )
            .map_err(commissioning_failed(drive, "quick commissioning", || {
                format!(
                    "drive {drive}: the end of quick commissioning (P3900 = {}) recalculates the motor model{}; give --unsafe to do it deliberately (nothing was written)",
                    self.end,
                    if self.end == 1 {
                        " and puts every other setting back to its factory value, the command source, the COM link and the telegram monitoring included"
                    } else {
                        ""
                    }
                )
            }))?;
        out.show(
            &QuickReport::new(bus.name(), drive, &done),
            QuickReport::human,
        )
    }
}

fn faults(bus: &Bus, out: &Output, drive: Address) -> Result<(), Failure> {
    let report = bus.fault_report(drive).map_err(|source| Failure::Param {
        drive,
        param: "r0947".to_owned(),
        source,
    })?;
    out.show(
        &FaultsReport::new(bus.name(), drive, &report),
        FaultsReport::human,
    )
}
