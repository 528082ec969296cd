//! The values of the configuration file's keys: each type says what it allows, refuses anything
//! else as it is read (in the words of [`ALLOWED`](Watchdog::ALLOWED)), has its default and
//! writes back what it read. Rules that need more than one value are in [`super::rules`].

use core::fmt;
use core::time::Duration;
use serde::de::Visitor;
use serde::{Deserialize, Deserializer, Serialize};
use uss_protocol::serde_impls::integer;
use uss_protocol::{Baud, NotationError, ParamRef, PkwMode, PzdCount};

/// A number of the file, integer or float; `allowed` says what is (for a wrong type too).
fn ms<'de, D: Deserializer<'de>>(d: D, allowed: &'static str) -> Result<Option<f64>, D::Error> {
    struct Number(&'static str);
    impl Visitor<'_> for Number {
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
    d.deserialize_any(Number(allowed)).map(Some)
}

/// A frequency: a number of the file ([`get`](ReferenceHz::get) as an `f32`).
fn hz<'de, D: Deserializer<'de>>(d: D, allowed: &'static str) -> Result<Option<f64>, D::Error> {
    ms(d, allowed)
}

/// An integer of the file, `None` when it does not fit `T`.
fn int<'de, D: Deserializer<'de>, T: TryFrom<i64>>(
    d: D,
    allowed: &'static str,
) -> Result<Option<T>, D::Error> {
    Ok(T::try_from(integer(d, allowed)?).ok())
}

/// Keys with a range: type and how the file writes it (`ms`: milliseconds, integer or float,
/// [`get`](Watchdog::get) as a `Duration`; `int`; `hz`: checked as read, used as `f32`), range,
/// default, what is allowed. Written back as read.
macro_rules! keys {
    ($($(#[$doc:meta])* $name:ident($t:ty, $read:ident): $range:expr, $default:literal, $allowed:literal;)*) => {$(
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Serialize)]
        pub struct $name(pub $t);

        impl $name {
            pub const ALLOWED: &'static str = $allowed;
        }

        keys!(@get $read $name $t);

        impl Default for $name {
            fn default() -> Self {
                Self($default)
            }
        }

        impl<'de> Deserialize<'de> for $name {
            fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
                let value: Option<$t> = $read(d, Self::ALLOWED)?;
                // NaN is in no range.
                value.filter(|v| ($range).contains(v)).map(Self).ok_or_else(|| {
                    serde::de::Error::custom(format_args!("is out of range: {}", Self::ALLOWED))
                })
            }
        }
    )*};
    (@get ms $name:ident $t:ty) => {
        impl $name {
            pub fn get(self) -> Duration {
                // Finite and non-negative (range checked): to the nanosecond.
                Duration::from_nanos((self.0 * 1e6).round() as u64)
            }
        }
    };
    (@get hz $name:ident $t:ty) => {
        impl $name {
            pub fn get(self) -> f32 {
                self.0 as f32
            }
        }
    };
    (@get $read:ident $name:ident $t:ty) => {
        impl $name {
            pub const fn get(self) -> $t {
                self.0
            }
        }
    };
}

keys! {
    /// The slave's response delay limit, 20 ms by the specification (USS.md section 4).
    ResponseTimeout(f64, ms): 1.0..=1000.0, 20.0,
        "the response timeout is 1..=1000 ms (USS.md section 4: a slave answers within 20 ms)";
    /// How late the adapter delivers received bytes (default: from sysfs).
    RxLatencyMs(f64, ms): 0.0..=100.0, 0.0, "the receive latency is 0..=100 ms";
    /// Added to the response timeout for adapters with latency (USS.md section 9).
    TimeoutMargin(f64, ms): 0.0..=1000.0, 0.0, "the timeout margin is 0..=1000 ms";
    /// An offline drive is polled at most this often.
    OfflineProbe(f64, ms): 10.0..=60_000.0, 500.0,
        "the poll interval of an offline drive is 10..=60000 ms";
    /// A fixed cycle time for the circulating list, waited out after its last entry; 0 = as fast
    /// as the wire allows (USS.md section 5).
    CycleTime(f64, ms): 0.0..=60_000.0, 0.0,
        "the cycle time (0 = as fast as the wire allows) is 0..=60000 ms";
    /// A serial line down this long makes ussd withhold systemd's watchdog keep-alive, so
    /// systemd restarts it; 0 = never.
    LineDownLimit(f64, ms): 0.0..=86_400_000.0, 30_000.0,
        "the line-down limit (0 = never) is 0..=86400000 ms";
    /// A parameter job with no matching reply in this time ends with a timeout (USS.md section 6).
    ParamTimeout(f64, ms): 10.0..=600_000.0, 2000.0, "the parameter job timeout is 10..=600000 ms";
    /// The controller must refresh the drive's PZD within this time, or the drive gets its safe
    /// command.
    Watchdog(f64, ms): 1.0..=60_000.0, 100.0, "the controller watchdog is 1..=60000 ms";
    /// The longest telegram-off time that counts as "on" (project policy; USS.md section 5).
    MonitoringMax(f64, ms): 1.0..=60_000.0, 1000.0,
        "the longest acceptable telegram-off time is 1..=60000 ms";
    /// Retries after a failed exchange, like the S7-1200 library's 2 (USS.md section 8).
    Retries(u8, int): 0..=10, 2, "retries after a failed exchange are 0..=10";
    /// Consecutive polls that failed all their retries before a drive is marked offline.
    OfflineAfter(u32, int): 1..=100, 1, "failed polls before a drive is marked offline are 1..=100";
    /// RTS delay before or after sending in the kernel's RS485 mode, in whole ms (the kernel
    /// takes at most 100).
    Rs485Delay(u32, int): 0..=100, 0, "RS485 delays are 0..=100 ms (whole ms)";
    /// The bus thread's `SCHED_FIFO` priority.
    Priority(u8, int): 1..=99, 80, "SCHED_FIFO priorities are 1..=99";
    /// Entries in the circulating list (USS.md section 5).
    Weight(u8, int): 1..=16, 1, "poll weights (entries in the circulating list) are 1..=16";
    /// The reference frequency P2000 in Hz, 0x4000 = 100 % (USS.md section 7), up to 650 Hz
    /// (the MICROMASTER/G120 range).
    ReferenceHz(f64, hz): f64::from(f32::MIN_POSITIVE)..=650.0, 50.0,
        "the reference frequency (P2000) is above 0 and at most 650 Hz";
}

/// A fixed cycle time, if one is set.
impl CycleTime {
    pub fn period(self) -> Option<Duration> {
        Some(self.get()).filter(|d| !d.is_zero())
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

/// A drive parameter ussd reads itself, as the manuals write it (and as the file wrote it);
/// `""`: not read. `monitoring_param`: the drive's own telegram-off time (USS.md section 5;
/// MICROMASTER 4 / G110 / CU240S: P2014, index 0 = the RS485 COM link). `reference_param`: the
/// reference frequency in Hz (P2000). What is not a parameter is refused by the rules, with its
/// error.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(from = "String", into = "String")]
pub struct ParamName {
    /// The parameter, `None` for `""`; or why the text is not a parameter.
    pub parsed: Result<Option<ParamRef>, NotationError>,
    written: String,
}

impl From<String> for ParamName {
    fn from(written: String) -> Self {
        let parsed = if written.is_empty() {
            Ok(None)
        } else {
            written.parse().map(Some)
        };
        Self { parsed, written }
    }
}

impl From<ParamName> for String {
    fn from(m: ParamName) -> Self {
        m.written
    }
}

impl ParamName {
    /// The parameter to read; `None` when not checked (the rules refuse a text that is not a
    /// parameter).
    pub fn param(&self) -> Option<ParamRef> {
        self.parsed.ok().flatten()
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
