//! ussctl's command line: subcommands, and parsing of parameter references and values.

use crate::commands::{self, stop::Target};
use crate::{Failure, Output};
use clap::{Parser, Subcommand, ValueEnum};
use uss_client::{Address, Bus, Value};

/// The bus `--bus` names when it is not given.
pub const DEFAULT_BUS: &str = "bus0";

/// The ussctl command line that runs `rest` on `bus`, for a message: `ussctl param read 1
/// P1120`, with `--bus NAME` when it is not the default one.
pub fn command_line(bus: &str, rest: &str) -> String {
    if bus == DEFAULT_BUS {
        format!("ussctl {rest}")
    } else {
        format!("ussctl --bus {bus} {rest}")
    }
}

#[derive(Debug, Parser)]
#[command(
    name = "ussctl",
    version,
    about = "Look at and operate the drives of a bus that ussd runs",
    after_help = "Examples:\n  ussctl status\n  ussctl param read 1 1082\n  ussctl param write 1 1120 2.0\n  ussctl run 1 --hz 25 --for 10\n  ussctl --json status"
)]
pub struct Cli {
    /// The bus, as named in ussd's configuration (a shell that works on one bus sets `USS_BUS`).
    #[arg(long, global = true, env = "USS_BUS", default_value = DEFAULT_BUS)]
    pub bus: String,
    /// Machine-readable output: one JSON document (`watch`: one per line).
    #[arg(long, global = true)]
    pub json: bool,
    /// Seconds to wait for ussd to answer a parameter request (default: 5 + 2.5 per item).
    #[arg(long, global = true, value_name = "SECONDS")]
    pub timeout: Option<f64>,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Table of drives: online, state, ZSW1, actual frequency, telegram counters, last error.
    ///
    /// Hz are scaled by each drive's reference frequency P2000 as ussd's configuration gives it.
    Status,
    /// Live input images, until Ctrl-C or --count rounds.
    Watch(commands::watch::Watch),
    /// Read or write a parameter.
    #[command(subcommand)]
    Param(ParamCommand),
    /// Take control of a drive, run it at a frequency, stop it at the end (OFF1).
    Run(commands::run::Run),
    /// Stop a drive along its ramp (OFF1), whoever controls it; latched until its controller
    /// re-arms it.
    Stop(Target),
    /// Coast a drive (OFF2: the motor is switched off at once), whoever controls it; latched.
    Coast(Target),
    /// Quick-stop a drive (OFF3: along the OFF3 ramp), whoever controls it; latched.
    QuickStop(Target),
    /// Acknowledge a drive's fault (rising edge of STW1 bit 7).
    Ack(commands::ack::Ack),
    /// The drive's fault buffer with its fault values, newest first, and its active warnings,
    /// where its family keeps them (MICROMASTER 4: r0947, r0949, r2110; G120: r0945, r0949,
    /// r2122; SIMOREG: r947, r949).
    Faults(commands::param::Faults),
    /// Bus statistics and every drive's counters.
    Stats,
    /// Print a completion script for SHELL (bash, zsh, fish, elvish, powershell).
    Completions {
        /// The shell to complete for.
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff, for man).
    Man,
    /// Print the JSON Schema of a --json report (status, stats, watch, param, describe, faults,
    /// drive, stop, scan, capture, trace, restore, diff, save, reset), or list them; the same files are in
    /// docs/schema/ussctl/.
    Schema {
        /// The report; without it, the list.
        report: Option<String>,
    },
    /// Every telegram of the bus as ussd sends and receives it, decoded; optionally written to a
    /// pcapng file for Wireshark (tools/wireshark/uss.lua decodes it).
    Capture(commands::capture::Capture),
    /// Record every input image of some drives at bus rate (actual and set Hz, ZSW1, state,
    /// age) to CSV, optionally from a trigger on, and plot speed against setpoint over time with
    /// state changes and faults marked.
    Trace(commands::trace::Trace),
    /// A live monitor: per bus a status bar, the drives (changes and errors marked), the selected
    /// drive's counters, timing and fault buffer, and keys for the safe stops (s OFF1, c OFF2,
    /// x OFF3; S C X for every drive), each confirmed with y. Needs a terminal.
    Top(commands::top::Top),
    /// Find the drives on a line ussd does not serve: each address that answers at each baud
    /// rate, its PKW and PZD length, family and firmware, each line confirmed by two replies or
    /// marked UNSURE with why. Probes carry OFF1 (STW1 0x047E, bit 10 set): no drive is
    /// switched on, and a drive that runs under USS control on the line ramps down.
    Scan(commands::scan::Scan),
}

#[derive(Debug, Subcommand)]
pub enum ParamCommand {
    /// Read a parameter or an array element, e.g. `P1082`, `r0021`, `P0947[3]`, `r0947.3`; an
    /// array without an index is read whole, a line per element.
    Read(commands::param::Read),
    /// What a parameter is: what the drive itself says (its data type, descriptive element
    /// 1) and the catalogue's entry for its family, if any.
    Describe(commands::param::Describe),
    /// Write VALUE to a parameter or an array element; an array is written by its element only
    /// (P2014[0]), never by its name alone.
    Write(commands::param::Write),
    /// Copy every setting of a drive from RAM to ROM (P0971 on MICROMASTER 4, p0971 on
    /// SINAMICS G120), so that what it holds now survives a power cycle; the access level it
    /// needs is raised and put back.
    Save(commands::param::Save),
    /// Put every setting of a drive back to its factory value as its manual gives it (P0010 =
    /// 30, then P0970 = 1), wait until it is done and until ussd has read the drive again
    /// (its reference and telegram monitoring), and say what it read. Needs --unsafe.
    FactoryReset(commands::param::FactoryReset),
    /// Quick commissioning as the drive's manual gives it: P0010 = 1, the motor data given
    /// with --set, then P3900 (3: the motor model only); waits until the drive is done and
    /// ussd has read it again, and says what it read. Needs --unsafe.
    QuickCommission(commands::param::QuickCommission),
    /// Save every settable parameter of a drive (the catalogue's, array elements included) to
    /// a TOML file (stdout without -o).
    Backup(commands::backup::Backup),
    /// Write a backup to a drive: only what differs, in a safe order, each value checked
    /// against the drive's answer. Refused while another process controls the drive.
    Restore(commands::backup::Restore),
    /// Compare a drive's settings with a backup file, or with another drive (an address) of
    /// the same family. Exits 0 when they are the same, 1 when they differ, 2 when they cannot
    /// be compared (as diff(1)).
    Diff(commands::backup::Diff),
}

impl ParamCommand {
    /// Runs `param ...` on `bus`.
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        match self {
            Self::Read(c) => c.run(bus, out),
            Self::Describe(c) => c.run(bus, out),
            Self::Write(c) => c.run(bus, out),
            Self::Save(c) => c.run(bus, out),
            Self::FactoryReset(c) => c.run(bus, out),
            Self::QuickCommission(c) => c.run(bus, out),
            Self::Backup(c) => c.run(bus, out),
            Self::Restore(c) => c.run(bus, out),
            Self::Diff(c) => c.run(bus, out),
        }
    }
}

impl Kind {
    /// The data type a `--type` stands for.
    pub const fn data_type(self) -> uss_client::DataType {
        match self {
            Self::Word => uss_client::DataType::U16,
            Self::Dword => uss_client::DataType::U32,
            Self::Float => uss_client::DataType::Float,
        }
    }
}

/// A parameter's type on the wire (USS.md section 6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Kind {
    /// 16 bits.
    Word,
    /// 32 bits.
    Dword,
    /// IEEE-754 single precision in a double word.
    Float,
}

/// A parameter as the manuals write it (`P1082`, `r0021`, `1082`, `P0947[3]`, `r0947.3`).
pub use uss_client::uss_protocol::ParamRef;

/// Baud rates given to `scan`.
#[derive(Debug, Clone)]
pub struct BaudList(pub Vec<uss_client::uss_protocol::Baud>);

/// Addresses given to `scan`.
#[derive(Debug, Clone)]
pub struct AddressList(pub Vec<uss_client::uss_protocol::Address>);

/// Baud rates for `scan`: `all`, or a comma-separated list of rates USS names.
pub fn baud_list(s: &str) -> Result<BaudList, String> {
    use uss_client::uss_protocol::Baud;
    let rates: Vec<u32> = if s == "all" {
        Baud::STANDARD.to_vec()
    } else {
        s.split(',')
            .map(|r| {
                r.trim()
                    .parse::<u32>()
                    .map_err(|_| format!("{r:?} is not a baud rate"))
            })
            .collect::<Result<_, _>>()?
    };
    rates
        .into_iter()
        .map(|r| {
            Baud::new(r)
                .ok()
                .filter(|b| b.is_standard())
                .ok_or_else(|| format!("{r} is not a USS baud rate (USS.md section 2)"))
        })
        .collect::<Result<_, _>>()
        .map(BaudList)
}

/// Addresses for `scan`: `0-31`, or a comma-separated list.
pub fn address_list(s: &str) -> Result<AddressList, String> {
    let number = |t: &str| address(t.trim());
    if let Some((from, to)) = s.split_once('-') {
        let range = number(from)?..=number(to)?;
        Ok(AddressList(
            Address::all().filter(|a| range.contains(a)).collect(),
        ))
    } else {
        s.split(',')
            .map(number)
            .collect::<Result<_, _>>()
            .map(AddressList)
    }
}

/// A drive's address, 0..=31 (USS.md section 3), checked where it enters.
pub fn address(s: &str) -> Result<Address, String> {
    let n: u8 = s
        .parse()
        .map_err(|_| format!("{s:?} is not a drive address: write a number 0..=31"))?;
    Address::new(n).map_err(|e| e.to_string())
}

/// Parses a parameter reference for clap, naming what was written.
pub fn param_ref(s: &str) -> Result<ParamRef, String> {
    s.parse().map_err(|e| format!("{s:?}: {e}"))
}

/// The value to write and its type: `kind` given, or float when `text` has a '.', else word.
pub fn parse_value(text: &str, kind: Option<Kind>) -> Result<(Value, Kind), String> {
    let kind = kind.unwrap_or(if text.contains('.') {
        Kind::Float
    } else {
        Kind::Word
    });
    let bad = |what: &str| format!("{text:?} is not {what}");
    let value = match kind {
        Kind::Float => text
            .parse::<f32>()
            .ok()
            .filter(|f| f.is_finite())
            .map(Value::from_f32)
            .ok_or_else(|| bad("a finite float")),
        Kind::Word => integer(text)
            .and_then(|n| {
                u16::try_from(n)
                    .ok()
                    .or_else(|| i16::try_from(n).ok().map(|n| n as u16))
            })
            .map(Value::Word)
            .ok_or_else(|| {
                bad("a word (-32768..=65535, or 0x0000..=0xFFFF); use --type dword or float for wider values")
            }),
        Kind::Dword => integer(text)
            .and_then(|n| {
                u32::try_from(n)
                    .ok()
                    .or_else(|| i32::try_from(n).ok().map(|n| n as u32))
            })
            .map(Value::Dword)
            .ok_or_else(|| bad("a double word (-2147483648..=4294967295, or 0x hex)")),
    }?;
    Ok((value, kind))
}

/// Decimal (optionally negative) or `0x` hex.
fn integer(text: &str) -> Option<i64> {
    match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => i64::from_str_radix(hex, 16).ok(),
        None => text.parse().ok(),
    }
}

/// What starts a trace (`--trigger`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Trigger {
    /// ZSW1 bit 3.
    Fault,
    /// ZSW1 bit N set.
    Zsw1Bit(u8),
    /// Actual frequency above F Hz.
    HzAbove(f32),
    /// Actual frequency below F Hz.
    HzBelow(f32),
}

impl core::fmt::Display for Trigger {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Fault => f.write_str("fault"),
            Self::Zsw1Bit(n) => write!(f, "zsw1-bit={n}"),
            Self::HzAbove(hz) => write!(f, "hz>{hz}"),
            Self::HzBelow(hz) => write!(f, "hz<{hz}"),
        }
    }
}

/// Parses `fault`, `zsw1-bit=N` (0..=15), `hz>F`, `hz<F`.
pub fn trigger(s: &str) -> Result<Trigger, String> {
    let hz = |f: &str| {
        f.trim()
            .parse::<f32>()
            .ok()
            .filter(|f| f.is_finite())
            .ok_or_else(|| format!("{s:?}: {f:?} is not a frequency in Hz"))
    };
    if s == "fault" {
        Ok(Trigger::Fault)
    } else if let Some(n) = s.strip_prefix("zsw1-bit=") {
        n.parse::<u8>()
            .ok()
            .filter(|&n| n < 16)
            .map(Trigger::Zsw1Bit)
            .ok_or_else(|| format!("{s:?}: ZSW1 bits are 0..=15"))
    } else if let Some(f) = s.strip_prefix("hz>") {
        hz(f).map(Trigger::HzAbove)
    } else if let Some(f) = s.strip_prefix("hz<") {
        hz(f).map(Trigger::HzBelow)
    } else {
        Err(format!(
            "{s:?} is not a trigger: give fault, zsw1-bit=N, hz>F or hz<F"
        ))
    }
}

/// Parses a duration: seconds (`10`, `2.5`), or with a unit (`10s`, `500ms`).
pub fn duration(s: &str) -> Result<core::time::Duration, String> {
    let (number, scale) = if let Some(ms) = s.strip_suffix("ms") {
        (ms, 1e-3)
    } else {
        (s.strip_suffix('s').unwrap_or(s), 1.0)
    };
    number
        .trim()
        .parse::<f64>()
        .ok()
        .and_then(|n| core::time::Duration::try_from_secs_f64(n * scale).ok())
        .ok_or_else(|| format!("{s:?} is not a duration: give seconds (10, 2.5s) or 500ms"))
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // the values compared are exactly representable
mod tests {
    use super::*;
    use clap::CommandFactory;
    use uss_client::uss_protocol::Subindex;

    #[test]
    fn param_refs_take_the_manuals_notation() {
        let r = |s: &str| param_ref(s).map(|p| (p.pnu.get(), p.index.map(Subindex::get)));
        assert_eq!(r("1082"), Ok((1082, None)));
        assert_eq!(r("P2000"), Ok((2000, None)));
        assert_eq!(r("r0947.3"), Ok((947, Some(3))));
        assert_eq!(r("P0947[3]"), Ok((947, Some(3))));
        for bad in ["", "P", "65536", "947.255", "947.", "x12", "-1"] {
            assert!(r(bad).is_err(), "{bad:?}");
        }
        assert_eq!(param_ref("r947.3").unwrap().to_string(), "r0947[3]");
    }

    fn value(text: &str, kind: Option<Kind>) -> Result<Value, String> {
        parse_value(text, kind).map(|(v, _)| v)
    }

    #[test]
    fn values_are_float_with_a_dot_else_word() {
        assert_eq!(parse_value("2.5", None).map(|(_, k)| k), Ok(Kind::Float));
        assert_eq!(parse_value("2", None).map(|(_, k)| k), Ok(Kind::Word));
        assert_eq!(value("2.0", None), Ok(Value::Dword(0x4000_0000)));
        assert_eq!(value("50.", None), Ok(Value::Dword(0x4248_0000)));
        assert_eq!(value("100", None), Ok(Value::Word(100)));
        assert_eq!(value("0xFFFF", None), Ok(Value::Word(0xFFFF)));
        assert_eq!(value("-1", None), Ok(Value::Word(0xFFFF)));
        assert!(value("65536", None).is_err());
        assert!(value("-32769", None).is_err());
        assert_eq!(
            value("50", Some(Kind::Float)),
            Ok(Value::Dword(0x4248_0000))
        );
        assert_eq!(value("70000", Some(Kind::Dword)), Ok(Value::Dword(70_000)));
        assert_eq!(value("-1", Some(Kind::Dword)), Ok(Value::Dword(u32::MAX)));
        assert_eq!(
            value("0x42480000", Some(Kind::Dword)),
            Ok(Value::Dword(0x4248_0000))
        );
        assert!(value("1.5", Some(Kind::Word)).is_err());
        assert!(value("nan", Some(Kind::Float)).is_err());
        assert!(value("abc", None).is_err());
    }

    #[test]
    fn command_line_parses_as_documented() {
        Cli::command().debug_assert();
        let cli = Cli::try_parse_from([
            "ussctl", "--bus", "b1", "param", "write", "3", "1120.0", "-2.5", "--eeprom",
        ])
        .unwrap();
        assert_eq!(cli.bus, "b1");
        match cli.command {
            Command::Param(ParamCommand::Write(w)) => {
                assert!(!w.guarded);
                let index = w.param.index.map(Subindex::get);
                assert_eq!(
                    (w.drive.get(), w.param.pnu.get(), index),
                    (3, 1120, Some(0))
                );
                assert_eq!(
                    (w.value.as_str(), w.eeprom, w.kind, w.force),
                    ("-2.5", true, None, false)
                );
            }
            other => panic!("{other:?}"),
        }
        for (words, drive, all) in [
            (&["ussctl", "coast", "4"][..], Some(4), false),
            (&["ussctl", "quick-stop", "--all"][..], None, true),
            (&["ussctl", "stop", "2"][..], Some(2), false),
        ] {
            let cli = Cli::try_parse_from(words).unwrap();
            let (Command::Stop(t) | Command::Coast(t) | Command::QuickStop(t)) = cli.command else {
                panic!("{words:?}")
            };
            assert_eq!(
                (t.drive.map(Address::get), t.all),
                (drive, all),
                "{words:?}"
            );
        }
        assert!(
            Cli::try_parse_from(["ussctl", "stop"]).is_err(),
            "a drive or --all"
        );
        assert!(Cli::try_parse_from(["ussctl", "stop", "1", "--all"]).is_err());
        let cli =
            Cli::try_parse_from(["ussctl", "run", "5", "--hz", "-10", "--for", "2", "--json"])
                .unwrap();
        assert!(cli.json);
        assert!(matches!(
            cli.command,
            Command::Run(ref r)
                if r.drive.get() == 5 && r.hz == Some(-10.0) && r.duration == Some(2.0)
        ));
        assert!(Cli::try_parse_from(["ussctl", "param", "read", "1", "99999"]).is_err());
    }

    #[test]
    fn trace_takes_triggers_and_durations_as_written() {
        use core::time::Duration;
        assert_eq!(trigger("fault"), Ok(Trigger::Fault));
        assert_eq!(trigger("zsw1-bit=11"), Ok(Trigger::Zsw1Bit(11)));
        assert_eq!(trigger("hz>12.5"), Ok(Trigger::HzAbove(12.5)));
        assert_eq!(trigger("hz<-3"), Ok(Trigger::HzBelow(-3.0)));
        for bad in ["zsw1-bit=16", "hz>fast", "hz>inf", "speed>3", ""] {
            assert!(trigger(bad).is_err(), "{bad}");
        }
        assert_eq!(duration("10s"), Ok(Duration::from_secs(10)));
        assert_eq!(duration("2.5"), Ok(Duration::from_millis(2500)));
        assert_eq!(duration("500ms"), Ok(Duration::from_millis(500)));
        for bad in ["-1", "ten", "5 min", "NaN"] {
            assert!(duration(bad).is_err(), "{bad}");
        }
        let cli = Cli::try_parse_from([
            "ussctl",
            "trace",
            "1",
            "3",
            "--trigger",
            "fault",
            "--pre",
            "2s",
            "-o",
            "run.csv",
        ])
        .unwrap();
        assert!(matches!(
            cli.command,
            Command::Trace(ref t)
                if t.drives.iter().map(|a| a.get()).eq([1, 3])
                    && t.trigger == Some(Trigger::Fault)
                    && t.pre == Some(Duration::from_secs(2))
                    && t.duration == Duration::from_secs(10)
        ));
        assert!(Cli::try_parse_from(["ussctl", "trace"]).is_err(), "a drive");
        assert!(
            Cli::try_parse_from(["ussctl", "trace", "1", "--pre", "1"]).is_err(),
            "--pre needs a trigger"
        );
    }

    proptest::proptest! {
        /// A trigger reads back as it prints; any text parses or is refused, never panics.
        #[test]
        fn triggers_round_trip(bit in 0u8..16, hz in -650.0f32..650.0, text in ".{0,16}") {
            for t in [Trigger::Fault, Trigger::Zsw1Bit(bit), Trigger::HzAbove(hz), Trigger::HzBelow(hz)] {
                proptest::prop_assert_eq!(trigger(&t.to_string()), Ok(t));
            }
            let _ = trigger(&text);
            let _ = duration(&text);
        }

        #[test]
        fn durations_in_seconds_and_milliseconds_agree(ms in 0u32..10_000_000) {
            let a = duration(&format!("{ms}ms")).unwrap();
            let b = duration(&format!("{}s", f64::from(ms) / 1000.0)).unwrap();
            proptest::prop_assert!(a.abs_diff(b) < core::time::Duration::from_micros(1));
        }
    }
}
