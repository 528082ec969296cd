//! The values of the configuration file's keys: each type says what it allows, refuses anything
//! else as it is read (in the words of [`ALLOWED`](Watchdog::ALLOWED)), has its default and
//! writes back what it read. Rules that need more than one value are in [`super::rules`].

use super::{Device, SIM_DEVICE};
use core::fmt;
use core::time::Duration;
use serde::de::Visitor;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::path::PathBuf;
use uss_protocol::serde_impls::integer;
use uss_protocol::{Baud, NotationError, ParamRef, PkwMode, PzdCount};

/// A number read from the file (integer or float), with what is allowed for the messages.
struct NumberVisitor(&'static str);

impl Visitor<'_> for NumberVisitor {
    type Value = f64;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "a number: {}", self.0)
    }

    fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<f64, E> {
        Ok(v)
    }
    fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<f64, E> {
        Ok(v as f64)
    }
    fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<f64, E> {
        Ok(v as f64)
    }
}

/// `value` if it is allowed, else the error that says what is.
fn in_range<T, E: serde::de::Error>(value: Option<T>, allowed: &str) -> Result<T, E> {
    value.ok_or_else(|| E::custom(format_args!("is out of range: {allowed}")))
}

/// Time keys in milliseconds: range, default, what is allowed; read as an integer or a float,
/// written as the number they were read as.
macro_rules! ms_keys {
    ($($(#[$doc:meta])* $name:ident: $min:literal..=$max:literal, $default:literal, $allowed:literal;)*) => {$(
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq)]
        pub struct $name(pub f64);

        impl $name {
            pub const ALLOWED: &'static str = $allowed;

            pub fn get(self) -> Duration {
                // Finite and non-negative (range checked): to the nanosecond.
                Duration::from_nanos((self.0 * 1e6).round() as u64)
            }
        }

        impl Default for $name {
            fn default() -> Self {
                Self($default)
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let ms = d.deserialize_any(NumberVisitor(Self::ALLOWED))?;
                // NaN is in no range.
                in_range(Some(Self(ms)).filter(|_| ($min..=$max).contains(&ms)), Self::ALLOWED)
            }
        }

        impl Serialize for $name {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_f64(self.0)
            }
        }
    )*};
}

/// Integer keys: type, range, default, what is allowed.
macro_rules! int_keys {
    ($($(#[$doc:meta])* $name:ident: $t:ty, $min:literal..=$max:literal, $default:literal, $allowed:literal;)*) => {$(
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub struct $name(pub $t);

        impl $name {
            pub const ALLOWED: &'static str = $allowed;

            pub const fn get(self) -> $t {
                self.0
            }
        }

        impl Default for $name {
            fn default() -> Self {
                Self($default)
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let n = integer(d, Self::ALLOWED)?;
                let n = <$t>::try_from(n).ok().filter(|n| ($min..=$max).contains(n));
                in_range(n.map(Self), Self::ALLOWED)
            }
        }

        impl Serialize for $name {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_i64(i64::from(self.0))
            }
        }
    )*};
}

ms_keys! {
    /// The slave's response delay limit, 20 ms by the specification (USS.md section 4).
    ResponseTimeout: 1.0..=1000.0, 20.0,
        "the response timeout is 1..=1000 ms (USS.md section 4: a slave answers within 20 ms)";
    /// Added to the response timeout for adapters with latency (USS.md section 9).
    TimeoutMargin: 0.0..=1000.0, 0.0, "the timeout margin is 0..=1000 ms";
    /// An offline drive is polled at most this often.
    OfflineProbe: 10.0..=60_000.0, 500.0, "the poll interval of an offline drive is 10..=60000 ms";
    /// A fixed cycle time for the circulating list, waited out after its last entry; 0 = as fast
    /// as the wire allows (USS.md section 5).
    CycleTime: 0.0..=60_000.0, 0.0,
        "the cycle time (0 = as fast as the wire allows) is 0..=60000 ms";
    /// A parameter job with no matching reply in this time ends with a timeout (USS.md section 6).
    ParamTimeout: 10.0..=600_000.0, 2000.0, "the parameter job timeout is 10..=600000 ms";
    /// The controller must refresh the drive's PZD within this time, or the drive gets its safe
    /// command.
    Watchdog: 1.0..=60_000.0, 100.0, "the controller watchdog is 1..=60000 ms";
    /// The longest telegram-off time that counts as "on" (project policy; USS.md section 5).
    MonitoringMax: 1.0..=60_000.0, 1000.0,
        "the longest acceptable telegram-off time is 1..=60000 ms";
}

int_keys! {
    /// Retries after a failed exchange, like the S7-1200 library's 2 (USS.md section 8).
    Retries: u8, 0..=10, 2, "retries after a failed exchange are 0..=10";
    /// Consecutive polls that failed all their retries before a drive is marked offline.
    OfflineAfter: u32, 1..=100, 1, "failed polls before a drive is marked offline are 1..=100";
    /// The bus thread's `SCHED_FIFO` priority.
    Priority: u8, 1..=99, 80, "SCHED_FIFO priorities are 1..=99";
    /// Entries in the circulating list (USS.md section 5).
    Weight: u8, 1..=16, 1, "poll weights (entries in the circulating list) are 1..=16";
}

/// A fixed cycle time, if one is set.
impl CycleTime {
    pub fn period(self) -> Option<Duration> {
        Some(self.get()).filter(|d| !d.is_zero())
    }
}

/// The reference frequency P2000 in Hz, 0x4000 = 100 % (USS.md section 7): above 0, at most
/// 650 Hz (the MICROMASTER/G120 range).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceHz(pub f32);

impl ReferenceHz {
    const ALLOWED: &'static str = "the reference frequency (P2000) is above 0 and at most 650 Hz";
}

impl Default for ReferenceHz {
    fn default() -> Self {
        Self(50.0)
    }
}

impl<'de> Deserialize<'de> for ReferenceHz {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let hz = d.deserialize_any(NumberVisitor(Self::ALLOWED))?;
        in_range(
            Some(Self(hz as f32)).filter(|_| hz > 0.0 && hz <= 650.0),
            Self::ALLOWED,
        )
    }
}

impl Serialize for ReferenceHz {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        // The shortest text that reads back as the same f32.
        let text = format!("{:?}", self.0);
        s.serialize_f64(text.parse().unwrap_or(f64::from(self.0)))
    }
}

/// The CPU to pin a bus thread to, as written: whether this machine has it is a rule
/// ([`super::rules`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Serialize)]
#[serde(transparent)]
pub struct Cpu(pub i64);

impl Cpu {
    /// The CPU number; the rules let only an online CPU (0 or more) through.
    pub fn get(self) -> usize {
        usize::try_from(self.0).unwrap_or_default()
    }
}

/// The parameter holding the drive's own telegram-off time (USS.md section 5) as the manuals
/// write it (and as the file wrote it); `""`: not checked. MICROMASTER 4 / G110 / CU240S: P2014,
/// index 1 = the RS485 COM link. What is not a parameter is refused by the rules, with its error.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MonitoringParam {
    /// The parameter, `None` for `""`; or why the text is not a parameter.
    pub parsed: Result<Option<ParamRef>, NotationError>,
    written: String,
}

impl MonitoringParam {
    fn new(written: String) -> Self {
        let parsed = if written.is_empty() {
            Ok(None)
        } else {
            written.parse().map(Some)
        };
        Self { parsed, written }
    }

    /// The parameter to read; `None` when not checked (the rules refuse a text that is not a
    /// parameter).
    pub fn param(&self) -> Option<ParamRef> {
        self.parsed.ok().flatten()
    }
}

impl Default for MonitoringParam {
    fn default() -> Self {
        Self::new("P2014.1".to_owned())
    }
}

impl<'de> Deserialize<'de> for MonitoringParam {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        String::deserialize(d).map(Self::new)
    }
}

impl Serialize for MonitoringParam {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.written)
    }
}

/// `"sim"` or a path; whether the path is usable is a rule ([`super::rules`]).
impl<'de> Deserialize<'de> for Device {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let written = String::deserialize(d)?;
        Ok(if written == SIM_DEVICE {
            Device::Sim
        } else {
            Device::Serial(PathBuf::from(written))
        })
    }
}

impl Serialize for Device {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Device::Sim => s.serialize_str(SIM_DEVICE),
            Device::Serial(path) => s.collect_str(&path.display()),
        }
    }
}

/// 115200 baud: the embedded default's rate.
pub fn default_baud() -> Baud {
    Baud::new(115_200).unwrap_or_else(|_| unreachable!("115200 is a baud rate"))
}

pub const fn default_pkw() -> PkwMode {
    PkwMode::Four
}

pub fn default_pzd() -> PzdCount {
    PzdCount::new(2).unwrap_or_else(|_| unreachable!("2 is a PZD count"))
}

pub const fn yes() -> bool {
    true
}
