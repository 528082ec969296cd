//! `ack`: acknowledges a drive's fault.

use super::common::control;
use crate::report::DriveReport;
use crate::{Failure, Output};
use core::time::Duration;
use uss_client::{Bus, ClientError, DriveState};

pub(crate) fn ack(bus: &Bus, out: &Output, drive: u8) -> Result<(), Failure> {
    let c = control(bus, drive)?;
    if c.inputs().state() != DriveState::Fault {
        out.note(&format!(
            "drive {drive} shows no fault; acknowledging anyway"
        ));
    }
    c.acknowledge_fault(Duration::from_secs(1))?;
    let last = match c.wait_for(Duration::from_secs(1), "fault cleared", |i| {
        uss_client::state_of(i) != DriveState::Fault
    }) {
        Ok(i) => i,
        Err(ClientError::WaitTimeout { .. }) => return Err(Failure::FaultPersists { drive }),
        Err(e) => return Err(e.into()),
    };
    out.show(
        &DriveReport::new(
            bus.name(),
            "ack",
            &last,
            drive,
            c.inputs().info().reference_hz,
        ),
        DriveReport::human,
    )
}
