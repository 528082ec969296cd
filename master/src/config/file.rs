//! The configuration file as serde reads and writes it: one struct per table, unknown keys
//! refused, every value range checked as it is read (the value types say what is allowed), every
//! optional key with its default. Rules that need more than one value are in [`super::rules`].

use super::{Rs485Mode, SafeCommand};
use core::fmt;
use core::time::Duration;
use serde::de::{Error as _, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use toml::Spanned;
#[cfg(feature = "sim")]
use uss_drive_sim::SimOptions;
/// Without the simulated bus (`sim` feature off) a `sim` table is read only to be refused.
#[cfg(not(feature = "sim"))]
type SimOptions = toml::Table;
use uss_protocol::{Address, Baud, PkwMode, PzdCount};

/// The whole file.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct File {
    #[serde(default)]
    pub bus: Vec<Spanned<BusTable>>,
}

/// A `[[bus]]` table.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct BusTable {
    pub name: Spanned<String>,
    pub device: Spanned<String>,
    #[serde(default = "default_baud")]
    pub baud: Spanned<Baud>,
    /// A rate USS does not name (USS.md section 2) is refused unless this says it is meant.
    #[serde(default)]
    pub nonstandard_baud: bool,
    #[serde(default)]
    pub rs485: Rs485Mode,
    #[serde(default)]
    pub echo: bool,
    #[serde(default)]
    pub response_timeout_ms: ResponseTimeout,
    #[serde(default)]
    pub timeout_margin_ms: TimeoutMargin,
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
    /// A drive with a parameter job waiting gets an extra poll after each regular one.
    #[serde(default)]
    pub param_priority: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu: Option<Spanned<i64>>,
    #[serde(default)]
    pub priority: Priority,
    /// Only on the simulated bus; written out there with its default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<Spanned<u64>>,
    #[serde(default)]
    pub drive: Vec<Spanned<DriveTable>>,
}

/// A `[[bus.drive]]` table.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DriveTable {
    pub address: Spanned<Address>,
    #[serde(default = "default_pkw")]
    pub pkw: PkwMode,
    #[serde(default = "default_pzd")]
    pub pzd: PzdCount,
    #[serde(default)]
    pub weight: Weight,
    #[serde(default)]
    pub reference_hz: ReferenceHz,
    #[serde(default)]
    pub watchdog_ms: Watchdog,
    #[serde(default)]
    pub safe_command: SafeCommand,
    #[serde(default = "yes")]
    pub params_writable: bool,
    /// The parameter in the manuals' notation, "" for no check.
    #[serde(default = "default_monitoring_param")]
    pub monitoring_param: Spanned<String>,
    #[serde(default)]
    pub monitoring_max_ms: MonitoringMax,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub require_monitoring: Option<Spanned<bool>>,
    /// Only on the simulated bus: the simulated drive's options (uss-sim's drive keys).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sim: Option<Spanned<SimOptions>>,
}

/// 115200 baud: the embedded default's rate.
pub const DEFAULT_BAUD: u32 = 115_200;
/// MICROMASTER 4 / G110 / CU240S: P2014, index 1 = the RS485 COM link (USS.md section 5).
pub const DEFAULT_MONITORING_PARAM: &str = "P2014.1";

fn default_baud() -> Spanned<Baud> {
    Spanned::new(
        0..0,
        Baud::new(DEFAULT_BAUD).unwrap_or_else(|_| unreachable!()),
    )
}

const fn default_pkw() -> PkwMode {
    PkwMode::Four
}

fn default_pzd() -> PzdCount {
    PzdCount::new(2).unwrap_or_else(|_| unreachable!())
}

const fn yes() -> bool {
    true
}

fn default_monitoring_param() -> Spanned<String> {
    Spanned::new(0..0, DEFAULT_MONITORING_PARAM.to_owned())
}

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

/// A time key in milliseconds: its range, default and meaning; read as an integer or a float,
/// written as the number it was read as.
macro_rules! ms_key {
    ($(#[$doc:meta])* $name:ident, $min:expr, $max:expr, $default:expr, $allowed:expr) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq)]
        pub struct $name(pub f64);

        impl $name {
            pub const ALLOWED: &'static str = $allowed;

            pub fn duration(self) -> Duration {
                millis(self.0)
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
                if ($min..=$max).contains(&ms) {
                    Ok(Self(ms))
                } else {
                    Err(D::Error::custom(format_args!("is out of range: {}", Self::ALLOWED)))
                }
            }
        }

        impl Serialize for $name {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_f64(self.0)
            }
        }
    };
}

/// An integer key: its type, range, default and meaning.
macro_rules! int_key {
    ($(#[$doc:meta])* $name:ident, $t:ty, $min:expr, $max:expr, $default:expr, $allowed:expr) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub struct $name(pub $t);

        impl $name {
            pub const ALLOWED: &'static str = $allowed;
        }

        impl Default for $name {
            fn default() -> Self {
                Self($default)
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let n = uss_protocol::serde_impls::integer(d, Self::ALLOWED)?;
                <$t>::try_from(n)
                    .ok()
                    .filter(|n| ($min..=$max).contains(n))
                    .map(Self)
                    .ok_or_else(|| {
                        D::Error::custom(format_args!("is out of range: {}", Self::ALLOWED))
                    })
            }
        }

        impl Serialize for $name {
            fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
                s.serialize_i64(i64::from(self.0))
            }
        }
    };
}

ms_key!(
    /// The slave's response delay limit, 20 ms by the specification (USS.md section 4).
    ResponseTimeout,
    1.0,
    1000.0,
    20.0,
    "the response timeout is 1..=1000 ms (USS.md section 4: a slave answers within 20 ms)"
);
ms_key!(
    /// Added to the response timeout for adapters with latency (USS.md section 9).
    TimeoutMargin,
    0.0,
    1000.0,
    0.0,
    "the timeout margin is 0..=1000 ms"
);
ms_key!(
    OfflineProbe,
    10.0,
    60_000.0,
    500.0,
    "the poll interval of an offline drive is 10..=60000 ms"
);
ms_key!(
    /// USS.md section 5: a master may enforce a fixed cycle time; 0 = as fast as the wire allows.
    CycleTime,
    0.0,
    60_000.0,
    0.0,
    "the cycle time (0 = as fast as the wire allows) is 0..=60000 ms"
);
ms_key!(
    ParamTimeout,
    10.0,
    600_000.0,
    2000.0,
    "the parameter job timeout is 10..=600000 ms"
);
ms_key!(
    Watchdog,
    1.0,
    60_000.0,
    100.0,
    "the controller watchdog is 1..=60000 ms"
);
ms_key!(
    /// The longest telegram-off time that counts as "on" (project policy; USS.md section 5).
    MonitoringMax,
    1.0,
    60_000.0,
    1000.0,
    "the longest acceptable telegram-off time is 1..=60000 ms"
);
int_key!(
    /// Like the S7-1200 library's 2 (USS.md section 8).
    Retries,
    u8,
    0,
    10,
    2,
    "retries after a failed exchange are 0..=10"
);
int_key!(
    OfflineAfter,
    u32,
    1,
    100,
    1,
    "failed polls before a drive is marked offline are 1..=100"
);
int_key!(Priority, u8, 1, 99, 80, "SCHED_FIFO priorities are 1..=99");
int_key!(
    /// Entries in the circulating list (USS.md section 5).
    Weight,
    u8,
    1,
    16,
    1,
    "poll weights (entries in the circulating list) are 1..=16"
);

/// The reference frequency P2000: above 0, at most 650 Hz (the MICROMASTER/G120 range).
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
        if hz > 0.0 && hz <= 650.0 {
            Ok(Self(hz as f32))
        } else {
            Err(D::Error::custom(format_args!(
                "is out of range: {}",
                Self::ALLOWED
            )))
        }
    }
}

impl Serialize for ReferenceHz {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        // The shortest text that reads back as the same f32.
        let text = format!("{:?}", self.0);
        s.serialize_f64(text.parse().unwrap_or(f64::from(self.0)))
    }
}

/// A finite, non-negative time in milliseconds, to the nanosecond.
pub fn millis(ms: f64) -> Duration {
    Duration::from_nanos((ms * 1e6).round() as u64)
}
