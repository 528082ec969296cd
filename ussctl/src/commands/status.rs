//! `status` and `stats`: the bus and its drives, once.

use super::common::{diags, healthy};
use crate::report::{BusView, DriveStats, StatsReport, StatusLines, StatusReport, TimingReport};
use crate::{Failure, Output};
use uss_client::Bus;

/// `status`: the table; with the line down, the table and then the failure (exit 1).
pub(crate) fn status(bus: &Bus, out: &Output) -> Result<(), Failure> {
    let report = StatusReport::of(bus)?;
    out.show(&report, StatusLines::human)?;
    healthy(bus)
}

pub(crate) fn stats(bus: &Bus, out: &Output) -> Result<(), Failure> {
    let status = bus.status()?;
    let report = StatsReport {
        bus: BusView::new(bus.name(), &status),
        timing: TimingReport::of(&status),
        drives: diags(bus)?
            .iter()
            .map(|d| DriveStats::new(d, uss_client::monotonic_ns()))
            .collect(),
    };
    out.show(&report, StatsReport::human)?;
    healthy(bus)
}
