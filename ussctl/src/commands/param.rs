//! `param read`, `param write`, `faults`: parameters through ussd.

use crate::cli::{self, Kind, ParamRef};
use crate::report::{FaultsReport, ParamReport};
use crate::{Failure, Output};
use uss_client::uss_protocol::Subindex;
use uss_client::{Bus, WriteOptions};

pub(crate) fn read(
    bus: &Bus,
    out: &Output,
    drive: u8,
    param: ParamRef,
    kind: Option<Kind>,
) -> Result<(), Failure> {
    let v = bus
        .read(drive, param.pnu.get(), param.index.map(Subindex::get))
        .map_err(|source| Failure::Param {
            drive,
            param: param.to_string(),
            source,
        })?;
    out.show(
        &ParamReport::new(bus.name(), drive, param, v, kind),
        ParamReport::human,
    )
}

/// What `param write` was asked to do.
pub(crate) struct Write<'a> {
    pub drive: u8,
    pub param: ParamRef,
    pub value: &'a str,
    pub eeprom: bool,
    pub kind: Option<Kind>,
    pub force: bool,
}

pub(crate) fn write(bus: &Bus, out: &Output, w: &Write<'_>) -> Result<(), Failure> {
    let (value, kind) = cli::parse_value(w.value, w.kind).map_err(Failure::Usage)?;
    let options = WriteOptions {
        eeprom: w.eeprom,
        force: w.force,
    };
    let (drive, param) = (w.drive, w.param);
    let now = bus
        .write_with(
            drive,
            param.pnu.get(),
            param.index.map(Subindex::get),
            value,
            options,
        )
        .map_err(|source| Failure::Param {
            drive,
            param: param.to_string(),
            source,
        })?;
    // The value the drive now holds, read as the type it was written as.
    let mut report = ParamReport::new(bus.name(), drive, param, now, Some(kind));
    report.eeprom = Some(w.eeprom);
    out.show(&report, ParamReport::human)
}

pub(crate) fn faults(bus: &Bus, out: &Output, drive: u8) -> Result<(), Failure> {
    let faults = bus.faults(drive).map_err(|source| Failure::Param {
        drive,
        param: "r0947".to_owned(),
        source,
    })?;
    out.show(
        &FaultsReport {
            bus: bus.name().to_owned(),
            drive,
            faults,
        },
        FaultsReport::human,
    )
}
