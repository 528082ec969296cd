//! Drive specifications as written on the `uss-sim` command line:
//! `ADDR[:key=value,...]`, for example `3:pkw=4,pzd=2,delay=2,drop=0.05`.

use crate::drive::DriveConfig;
use crate::fault::FaultPlan;
use crate::options::SimOptions;
use serde::Deserialize as _;
use thiserror::Error;
use uss_protocol::{Address, Layout, PkwMode, PzdCount};

/// The keys a drive specification understands, for error messages and `--help`.
pub const KEYS: &str = "pkw=0|3|4|127, pzd=0..16, delay=MS, jitter=MS, eeprom-busy=N, busy=N, \
p2014=MS, p2000=HZ, dword-error=5|103, drop|bcc|byte|truncate|late|wrong-addr|noise=PROBABILITY, late-by=MS, \
unplug=FROM_MS..[TO_MS], hang=MS, broadcast=true|false, family=micromaster4|g110|g120|simoreg|generic, fragile=true|false, \
extra|extra-float|extra-r=FROM-TO";

/// A drive and its fault plan, parsed from a specification.
#[derive(Debug, Clone)]
pub struct DriveSpec {
    pub config: DriveConfig,
    pub faults: FaultPlan,
}

impl DriveSpec {
    /// The drive at `address` with `layout` and `options` (a `[bus.drive.sim]` table).
    pub fn new(address: Address, layout: Layout, options: &SimOptions) -> Result<Self, String> {
        let mut config = DriveConfig::new(address, layout);
        let mut faults = FaultPlan::new();
        options.apply(&mut config, &mut faults)?;
        Ok(Self { config, faults })
    }
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
    let mut pzd = PzdCount::new(2).map_err(|e| e.to_string())?;
    // Every other key goes into the options' table, typed as TOML would type it, so the
    // command line and a configuration file read the same keys the same way.
    let mut table = toml::Table::new();
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
                pzd = value
                    .parse()
                    .ok()
                    .and_then(|n| PzdCount::new(n).ok())
                    .ok_or_else(|| {
                        format!("pzd={value}: the PZD length (P2012) is 0..=16 words")
                    })?;
            }
            _ => {
                let typed = if let Ok(n) = value.parse::<i64>() {
                    toml::Value::Integer(n)
                } else if let Ok(x) = value.parse::<f64>() {
                    toml::Value::Float(x)
                } else if let Ok(b) = value.parse::<bool>() {
                    toml::Value::Boolean(b)
                } else {
                    toml::Value::String(value.to_owned())
                };
                table.insert(key.to_owned(), typed);
            }
        }
    }
    let options = SimOptions::deserialize(table).map_err(|e| {
        let message = e.message().trim_end().to_owned();
        if message.starts_with("unknown field") {
            format!("{message} (keys: {KEYS})")
        } else {
            message
        }
    })?;
    DriveSpec::new(address, Layout::new(pkw, pzd), &options)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fault::Fault;
    use core::time::Duration;
    use uss_protocol::ErrorNumber;

    #[test]
    fn a_generic_slave_may_be_fragile_and_only_it() {
        use crate::drive::Personality;
        let d: DriveSpec = "4:family=generic,fragile=true,pzd=6".parse().unwrap();
        assert_eq!(d.config.personality, Personality::Generic { fragile: true });
        let d: DriveSpec = "4".parse().unwrap();
        assert_eq!(d.config.personality, Personality::MICROMASTER4);
        assert_eq!(
            "4:fragile=true".parse::<DriveSpec>().unwrap_err().problem,
            "fragile=...: only a family=generic slave can be fragile"
        );
        assert_eq!(
            "4:family=g150".parse::<DriveSpec>().unwrap_err().problem,
            "family=g150: the simulator has the families micromaster4, g110, g120, simoreg, \
             generic"
        );
    }

    #[test]
    fn a_drive_may_ignore_broadcasts() {
        let d: DriveSpec = "7:broadcast=false".parse().unwrap();
        assert!(!d.config.takes_broadcasts);
        let d: DriveSpec = "7".parse().unwrap();
        assert!(d.config.takes_broadcasts);
    }

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
            p2000=60,dword-error=103,drop=0.1,late=0.2,late-by=7,unplug=1000..1500,hang=2000"
            .parse()
            .unwrap();
        let c = d.config;
        assert_eq!(c.layout.pkw, PkwMode::Variable);
        assert_eq!(c.layout.pzd.get(), 8);
        assert_eq!(c.response_delay, Duration::from_micros(2500));
        assert_eq!(c.response_jitter, Duration::from_micros(500));
        assert_eq!((c.eeprom_busy_telegrams, c.task_busy_telegrams), (5, 1));
        assert_eq!(c.telegram_off_time_ms, 200);
        assert_eq!(c.reference_hz.to_bits(), 60.0_f32.to_bits());
        assert_eq!(c.dword_over_three_words, ErrorNumber::DwordOverThreeWords);
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
        assert!(err("1:colour=red").contains("unknown field `colour`"));
        assert!(err("1:pkw").contains("is not key=value"));
        assert!(err("1:unplug=500..100").contains("end must come after"));
        assert!(err("1:delay=-1").contains("milliseconds"));
        assert!(
            err("1:p2000=0.5")
                .contains("p2000=0.5: 1..=650 Hz (the reference frequency) on this family")
        );
    }
}
