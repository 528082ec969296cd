//! A simulated drive's options: response timing, the PKW handshake, telegram monitoring and the
//! fault plan. One definition for both places they are written: `uss-sim --drive
//! ADDR:key=value,...` ([`crate::spec`]) and a `[bus.drive.sim]` table of ussd's configuration
//! (serde, with the same key names).

use crate::drive::{DriveConfig, Personality};
use crate::fault::{Fault, FaultPlan};
use core::time::Duration;
use serde::{Deserialize, Serialize};
use uss_protocol::ErrorNumber;

/// The keys, for messages and `--help`.
pub const KEYS: &str = "delay=MS, jitter=MS, eeprom-busy=N, busy=N, p2014=MS, p2000=HZ, dword-error=5|103, \
drop|bcc|byte|truncate|late|wrong-addr|noise=PROBABILITY, late-by=MS, unplug=\"FROM_MS..[TO_MS]\", \
hang=MS, broadcast=true|false, family=micromaster4|g110|g120|simoreg|generic, fragile=true|false, \
extra|extra-float|extra-r=FROM-TO";

/// What a simulated drive does besides its address and layout; every key is optional (the
/// simulator's default applies).
#[derive(Debug, Clone, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, rename_all = "kebab-case")]
pub struct SimOptions {
    /// Response delay, ms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delay: Option<f64>,
    /// Uniform jitter added to the response delay, ms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub jitter: Option<f64>,
    /// Telegrams answered with AK 0 "busy" before an EEPROM write completes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eeprom_busy: Option<u32>,
    /// Telegrams answered with AK 0 before any task completes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub busy: Option<u32>,
    /// The telegram-off time P2014, ms (0 = off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p2014: Option<u16>,
    /// The reference P2000: Hz (1..=650) on MICROMASTER 4 and G110, rpm (6..=210000) on G120
    /// (default 1500), the value 100 % of the setpoint stands for on SIMOREG (default 100).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p2000: Option<f64>,
    /// The error number for a double word over a 3-word PKW: 5 (MICROMASTER) or 103.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dword_error: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drop: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bcc: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub byte: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truncate: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub late: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wrong_addr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<f64>,
    /// How far past the 20 ms limit a late reply comes, ms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub late_by: Option<f64>,
    /// `FROM_MS..TO_MS` after start during which the drive is off the bus (`FROM_MS..` = for
    /// good).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unplug: Option<String>,
    /// Ms after start from which the whole line hangs for good ([`FaultPlan::hang`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hang: Option<f64>,
    /// `false`: the drive ignores broadcasts, as S110 and G120 firmware 4 do.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub broadcast: Option<bool>,
    /// The slave's personality: `micromaster4` (the default; on ussd's simulated bus, the drive
    /// entry's `family`), `g110`, `g120`, `simoreg`, or
    /// `generic` (a USS slave of no known family: three parameters of its own, error 0 to the
    /// rest).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub family: Option<String>,
    /// With `family = "generic"`: a task on a parameter it does not know makes it stop
    /// answering for good.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fragile: Option<bool>,
    /// `FROM-TO` (or one PNU): settable U16 parameters the drive has besides its profile, for
    /// the clients that let a drive describe itself ([`crate::drive::Extra`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub extra: Option<Pnus>,
    /// `FROM-TO`: settable Float arrays of three elements besides its profile.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub extra_float: Option<Pnus>,
    /// `FROM-TO`: read-only U16 parameters besides its profile.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub extra_r: Option<Pnus>,
}

/// Parameter numbers as `extra=` writes them: `701-706`, or one number.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize, Serialize)]
#[serde(untagged)]
pub enum Pnus {
    One(u16),
    Range(String),
}

/// The range `extra=` names.
fn pnus(key: &str, pnus: &Pnus) -> Result<(u16, u16), String> {
    let text = match pnus {
        Pnus::One(n) => &n.to_string(),
        Pnus::Range(text) => text.as_str(),
    };
    let number = |t: &str| {
        t.trim()
            .parse::<u16>()
            .ok()
            .filter(|&n| n > 0 && uss_protocol::Pnu::new(u32::from(n)).is_ok())
    };
    let (a, b) = text.split_once('-').unwrap_or((text, text));
    match (number(a), number(b)) {
        (Some(a), Some(b)) if a <= b && b - a < 64 => Ok((a, b)),
        _ => Err(format!(
            "{key}={text}: parameter numbers FROM-TO (at most 64 of them, each one USS can \
             address)"
        )),
    }
}

impl SimOptions {
    /// The slave these options name: a drive of their `family` (a MICROMASTER 4 without one),
    /// or a generic slave, fragile or not.
    fn personality(&self) -> Result<Personality, String> {
        Ok(match (self.family.as_deref(), self.fragile) {
            (Some("generic"), fragile) => Personality::Generic {
                fragile: fragile.unwrap_or(false),
            },
            (_, Some(_)) => {
                return Err("fragile=...: only a family=generic slave can be fragile".to_owned());
            }
            (None, None) => Personality::MICROMASTER4,
            (Some(name), None) => Personality::Drive(
                uss_catalogue::Catalogue::family_named(name).ok_or_else(|| {
                    format!(
                        "family={name}: the simulator has the families {}",
                        uss_catalogue::Catalogue::family_names()
                    )
                })?,
            ),
        })
    }

    /// Sets these options on a drive and its fault plan; what is wrong, if anything, in the
    /// words of the key (`"delay=-1: a time in milliseconds, 0..=3600000"`).
    pub fn apply(&self, config: &mut DriveConfig, faults: &mut FaultPlan) -> Result<(), String> {
        if let Some(ms) = self.delay {
            config.response_delay = millis("delay", ms)?;
        }
        if let Some(ms) = self.jitter {
            config.response_jitter = millis("jitter", ms)?;
        }
        if let Some(ms) = self.late_by {
            faults.late_by = millis("late-by", ms)?;
        }
        if let Some(n) = self.eeprom_busy {
            config.eeprom_busy_telegrams = n;
        }
        if let Some(n) = self.busy {
            config.task_busy_telegrams = n;
        }
        if let Some(ms) = self.p2014 {
            config.telegram_off_time_ms = ms;
        }
        if let Some(code) = self.dword_error {
            config.dword_over_three_words = match code {
                5 => ErrorNumber::WrongDataType,
                103 => ErrorNumber::DwordOverThreeWords,
                _ => {
                    return Err(format!(
                        "dword-error={code}: use 5 (MICROMASTER) or 103 (MASTERDRIVES)"
                    ));
                }
            };
        }
        for (fault, p) in [
            (Fault::DropReply, self.drop),
            (Fault::CorruptBcc, self.bcc),
            (Fault::CorruptByte, self.byte),
            (Fault::Truncate, self.truncate),
            (Fault::Late, self.late),
            (Fault::WrongAddress, self.wrong_addr),
            (Fault::Noise, self.noise),
        ] {
            if let Some(p) = p {
                if !(0.0..=1.0).contains(&p) {
                    return Err(format!("{}={p}: a probability is 0..=1", fault.name()));
                }
                faults.set_probability(fault, p);
            }
        }
        if let Some(window) = &self.unplug {
            let (from, to) = unplug_window(window)?;
            faults.unplug(from, to);
        }
        if let Some(ms) = self.hang {
            faults.hang(millis("hang", ms)?);
        }
        if let Some(takes) = self.broadcast {
            config.takes_broadcasts = takes;
        }
        config.personality = self.personality()?;
        let range = |key, v: &Option<Pnus>| v.as_ref().map(|p| pnus(key, p)).transpose();
        config.extra = crate::drive::Extra {
            words: range("extra", &self.extra)?,
            floats: range("extra-float", &self.extra_float)?,
            read_only: range("extra-r", &self.extra_r)?,
        };
        if config.extra != crate::drive::Extra::default() {
            if matches!(config.personality, Personality::Generic { .. }) {
                return Err("extra=...: a generic slave has its own three parameters".to_owned());
            }
            config.extra.param_set(config.personality)?;
        }
        let (range, unit, default) = reference_of(config.personality, config.reference_hz);
        config.reference_hz = default as f32;
        if let Some(value) = self.p2000 {
            if !range.contains(&value) {
                return Err(format!(
                    "p2000={value}: {}..={} {unit} on this family",
                    range.start(),
                    range.end()
                ));
            }
            config.reference_hz = value as f32;
        }
        Ok(())
    }
}

/// The reference a drive of `personality` scales its setpoint by: the limits, unit and factory
/// setting of its family profile's reference parameter (`default`: a generic slave's); a family
/// without one (SIMOREG) scales 0x4000 to 100 % of its setpoint.
fn reference_of(
    personality: Personality,
    default: f32,
) -> (core::ops::RangeInclusive<f64>, &'static str, f64) {
    let profile = uss_catalogue::Catalogue::of(personality.family());
    let reference = profile.and_then(|c| {
        let (param, unit) = match (c.reference, c.reference_speed) {
            (Some(p), _) => (p, "Hz (the reference frequency)"),
            (None, Some(p)) => (p, "rpm (the reference speed)"),
            (None, None) => return None,
        };
        let p = c.param(param.pnu.get())?;
        Some((p.min?..=p.max?, unit, p.default?))
    });
    match (personality, reference) {
        (Personality::Drive(_), Some(found)) => found,
        (Personality::Drive(_), None) => (1.0..=1000.0, "(100 % of the setpoint)", 100.0),
        (Personality::Generic { .. }, _) => (
            1.0..=650.0,
            "Hz (the reference frequency)",
            f64::from(default),
        ),
    }
}

/// `FROM..TO` or `FROM..` in ms: when the drive goes off the bus, and for how long.
fn unplug_window(value: &str) -> Result<(Duration, Option<Duration>), String> {
    let (from, to) = value
        .split_once("..")
        .ok_or_else(|| format!("unplug={value}: write FROM_MS..TO_MS or FROM_MS.."))?;
    let number = |s: &str| {
        s.trim()
            .parse::<f64>()
            .map_err(|_| format!("unplug={value}: {s:?} is not a number of milliseconds"))
    };
    let from = millis("unplug", number(from)?)?;
    if to.trim().is_empty() {
        return Ok((from, None));
    }
    let to = millis("unplug", number(to)?)?;
    to.checked_sub(from)
        .filter(|d| !d.is_zero())
        .map(|d| (from, Some(d)))
        .ok_or_else(|| format!("unplug={value}: the end must come after the start"))
}

fn millis(key: &str, ms: f64) -> Result<Duration, String> {
    if ms.is_finite() && (0.0..=3_600_000.0).contains(&ms) {
        Ok(Duration::from_secs_f64(ms / 1000.0))
    } else {
        Err(format!("{key}={ms}: a time in milliseconds, 0..=3600000"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::DriveConfig;
    use uss_protocol::{Address, Layout, PkwMode, PzdCount};

    fn apply(options: &SimOptions) -> Result<(DriveConfig, FaultPlan), String> {
        let layout = Layout::new(PkwMode::Four, PzdCount::new(2).unwrap());
        let mut config = DriveConfig::new(Address::new(1).unwrap(), layout);
        let mut faults = FaultPlan::new();
        options.apply(&mut config, &mut faults)?;
        Ok((config, faults))
    }

    #[test]
    fn a_table_reads_with_the_command_line_names_and_refuses_unknown_keys() {
        let options: SimOptions =
            toml::from_str("delay = 2\neeprom-busy = 3\nwrong-addr = 0.5\nunplug = \"10..20\"")
                .unwrap();
        let (config, faults) = apply(&options).unwrap();
        assert_eq!(config.response_delay, Duration::from_millis(2));
        assert_eq!(config.eeprom_busy_telegrams, 3);
        assert!((faults.probability(Fault::WrongAddress) - 0.5).abs() < 1e-12);
        assert!(faults.is_unplugged(Duration::from_millis(15)));
        let unknown = toml::from_str::<SimOptions>("colour = 1").unwrap_err();
        assert!(
            unknown.message().contains("unknown field `colour`"),
            "{unknown}"
        );
        // Written back, only what was set.
        assert_eq!(
            toml::to_string(&options).unwrap(),
            "delay = 2.0\neeprom-busy = 3\nwrong-addr = 0.5\nunplug = \"10..20\"\n"
        );
    }

    #[test]
    fn out_of_range_values_say_which_key_and_what_is_allowed() {
        let bad = |o: SimOptions| apply(&o).unwrap_err();
        assert_eq!(
            bad(SimOptions {
                drop: Some(2.0),
                ..SimOptions::default()
            }),
            "drop=2: a probability is 0..=1"
        );
        assert_eq!(
            bad(SimOptions {
                delay: Some(-1.0),
                ..SimOptions::default()
            }),
            "delay=-1: a time in milliseconds, 0..=3600000"
        );
        assert_eq!(
            bad(SimOptions {
                dword_error: Some(7),
                ..SimOptions::default()
            }),
            "dword-error=7: use 5 (MICROMASTER) or 103 (MASTERDRIVES)"
        );
        assert_eq!(
            bad(SimOptions {
                unplug: Some("500..100".into()),
                ..SimOptions::default()
            }),
            "unplug=500..100: the end must come after the start"
        );
    }
}
