//! Drive specifications as written on the `uss-sim` command line:
//! `ADDR[:key=value,...]`, for example `3:pkw=4,pzd=2,delay=2,drop=0.05`.

use crate::drive::DriveConfig;
use crate::fault::{Fault, FaultPlan};
use core::time::Duration;
use thiserror::Error;
use uss_protocol::{Address, Layout, ParamError, PkwMode, PzdCount};

/// The keys a drive specification understands, for error messages and `--help`.
pub const KEYS: &str = "pkw=0|3|4|127, pzd=0..16, delay=MS, jitter=MS, eeprom-busy=N, busy=N, \
p2014=MS, dword-error=5|103, drop|bcc|byte|truncate|late|wrong-addr|noise=PROBABILITY, late-by=MS, \
unplug=FROM_MS..[TO_MS], hang=FROM_MS";

/// A drive and its fault plan, parsed from a specification.
#[derive(Debug, Clone)]
pub struct DriveSpec {
    pub config: DriveConfig,
    pub faults: FaultPlan,
}

/// What is wrong with a drive specification.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error("drive spec '{spec}': {problem}")]
pub struct SpecError {
    pub spec: String,
    pub problem: String,
}

impl core::str::FromStr for DriveSpec {
    type Err = SpecError;

    fn from_str(spec: &str) -> Result<Self, SpecError> {
        parse(spec).map_err(|problem| SpecError {
            spec: spec.to_owned(),
            problem,
        })
    }
}

fn parse(spec: &str) -> Result<DriveSpec, String> {
    let (addr, options) = spec.split_once(':').unwrap_or((spec, ""));
    let addr: u8 = addr
        .trim()
        .parse()
        .map_err(|_| format!("'{addr}' is not a drive address (0..=31)"))?;
    let address = Address::new(addr).map_err(|e| e.to_string())?;
    let mut pkw = PkwMode::Four;
    let mut pzd = 2usize;
    let mut config = DriveConfig::new(
        address,
        Layout::new(pkw, PzdCount::new(pzd).map_err(|e| e.to_string())?),
    );
    let mut faults = FaultPlan::new();
    for option in options.split(',').map(str::trim).filter(|o| !o.is_empty()) {
        let (key, value) = option
            .split_once('=')
            .ok_or_else(|| format!("'{option}' is not key=value (keys: {KEYS})"))?;
        let (key, value) = (key.trim(), value.trim());
        match key {
            "pkw" => {
                pkw = value
                    .parse()
                    .ok()
                    .and_then(PkwMode::from_p2013)
                    .ok_or_else(|| {
                        format!("pkw={value}: the PKW length (P2013) is 0, 3, 4 or 127")
                    })?;
            }
            "pzd" => {
                pzd = value.parse().ok().filter(|n| *n <= 16).ok_or_else(|| {
                    format!("pzd={value}: the PZD length (P2012) is 0..=16 words")
                })?;
            }
            "delay" => config.response_delay = millis(key, value)?,
            "jitter" => config.response_jitter = millis(key, value)?,
            "late-by" => faults.late_by = millis(key, value)?,
            "eeprom-busy" => config.eeprom_busy_telegrams = count(key, value)?,
            "busy" => config.task_busy_telegrams = count(key, value)?,
            "p2014" => {
                config.telegram_off_time_ms = value
                    .parse()
                    .map_err(|_| format!("p2014={value}: the telegram-off time is 0..=65535 ms"))?;
            }
            "dword-error" => {
                config.dword_over_three_words = match value {
                    "5" => ParamError::WrongDataType,
                    "103" => ParamError::DwordOverThreeWords,
                    _ => {
                        return Err(format!(
                            "dword-error={value}: use 5 (MICROMASTER) or 103 (MASTERDRIVES)"
                        ));
                    }
                };
            }
            "unplug" => {
                let (from, to) = value
                    .split_once("..")
                    .ok_or_else(|| format!("unplug={value}: write FROM_MS..TO_MS or FROM_MS.."))?;
                let from = millis(key, from)?;
                let to = if to.trim().is_empty() {
                    None
                } else {
                    Some(millis(key, to)?)
                };
                let duration = match to {
                    Some(to) => Some(to.checked_sub(from).filter(|d| !d.is_zero()).ok_or_else(
                        || format!("unplug={value}: the end must come after the start"),
                    )?),
                    None => None,
                };
                faults.unplug(from, duration);
            }
            "hang" => faults.hang(millis(key, value)?),
            other => {
                let fault = Fault::from_name(other)
                    .ok_or_else(|| format!("unknown key '{other}' (keys: {KEYS})"))?;
                let p: f64 = value
                    .parse()
                    .ok()
                    .filter(|p| (0.0..=1.0).contains(p))
                    .ok_or_else(|| format!("{other}={value}: a probability is 0..=1"))?;
                faults.set_probability(fault, p);
            }
        }
    }
    // Both came from validated values above.
    config.layout = Layout::new(pkw, PzdCount::new(pzd).map_err(|e| e.to_string())?);
    Ok(DriveSpec { config, faults })
}

fn millis(key: &str, value: &str) -> Result<Duration, String> {
    value
        .trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= 0.0 && *v <= 3_600_000.0)
        .map(|v| Duration::from_secs_f64(v / 1000.0))
        .ok_or_else(|| format!("{key}={value}: a time in milliseconds, 0..=3600000"))
}

fn count(key: &str, value: &str) -> Result<u32, String> {
    value
        .parse()
        .map_err(|_| format!("{key}={value}: a number of telegrams"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn address_alone_gives_pkw4_pzd2() {
        let d: DriveSpec = "7".parse().unwrap();
        assert_eq!(d.config.address.get(), 7);
        assert_eq!(d.config.layout.pkw, PkwMode::Four);
        assert_eq!(d.config.layout.pzd.get(), 2);
    }

    #[test]
    fn every_key_is_understood() {
        let d: DriveSpec = "3:pkw=127,pzd=8,delay=2.5,jitter=0.5,eeprom-busy=5,busy=1,p2014=200,\
            dword-error=103,drop=0.1,late=0.2,late-by=7,unplug=1000..1500,hang=2000"
            .parse()
            .unwrap();
        let c = d.config;
        assert_eq!(c.layout.pkw, PkwMode::Variable);
        assert_eq!(c.layout.pzd.get(), 8);
        assert_eq!(c.response_delay, Duration::from_micros(2500));
        assert_eq!(c.response_jitter, Duration::from_micros(500));
        assert_eq!((c.eeprom_busy_telegrams, c.task_busy_telegrams), (5, 1));
        assert_eq!(c.telegram_off_time_ms, 200);
        assert_eq!(c.dword_over_three_words, ParamError::DwordOverThreeWords);
        assert!((d.faults.probability(Fault::DropReply) - 0.1).abs() < 1e-12);
        assert!((d.faults.probability(Fault::Late) - 0.2).abs() < 1e-12);
        assert_eq!(d.faults.late_by, Duration::from_millis(7));
        assert!(!d.faults.is_unplugged(Duration::from_millis(999)));
        assert!(d.faults.is_unplugged(Duration::from_secs(1)));
        assert!(!d.faults.is_unplugged(Duration::from_millis(1500)));
        assert!(!d.faults.hangs(Duration::from_millis(1999)));
        assert!(d.faults.hangs(Duration::from_secs(2)));
    }

    #[test]
    fn bad_specs_say_what_is_wrong() {
        let err = |s: &str| s.parse::<DriveSpec>().unwrap_err().to_string();
        assert_eq!(
            err("40:pkw=4"),
            "drive spec '40:pkw=4': slave address 40 is out of range: USS addresses are 0..=31"
        );
        assert_eq!(
            err("x"),
            "drive spec 'x': 'x' is not a drive address (0..=31)"
        );
        assert!(err("1:pkw=5").contains("P2013) is 0, 3, 4 or 127"));
        assert!(err("1:pzd=17").contains("0..=16 words"));
        assert!(err("1:drop=2").contains("a probability is 0..=1"));
        assert!(err("1:colour=red").contains("unknown key 'colour'"));
        assert!(err("1:pkw").contains("is not key=value"));
        assert!(err("1:unplug=500..100").contains("end must come after"));
        assert!(err("1:delay=-1").contains("milliseconds"));
    }
}
