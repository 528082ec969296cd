//! What the subcommands share: taking control, confirming a stop, reading diagnostics, the
//! bus's health.

use crate::Failure;
use core::time::Duration;
use uss_client::{Bus, ControlOptions, Controller, PzdInput};

/// How long a state change of the drive may take before ussctl gives up.
pub(crate) const STATE_TIMEOUT: Duration = Duration::from_secs(3);

pub(crate) fn diags(bus: &Bus) -> Result<Vec<uss_client::DriveDiag>, String> {
    bus.drives()
        .into_iter()
        .map(|a| bus.diag(a).map_err(|e| e.to_string()))
        .collect()
}

/// Fails with what ussd's heartbeat says when it does not poll the bus.
pub(crate) fn healthy(bus: &Bus) -> Result<(), Failure> {
    match bus.health().error(bus.name()) {
        Some(e) => Err(e.to_string().into()),
        None => Ok(()),
    }
}

/// Takes control of `drive`, explaining a refusal.
pub(crate) fn control(bus: &Bus, drive: u8) -> Result<Controller, String> {
    bus.control(drive, ControlOptions::default())
        .map_err(|e| e.to_string())
}

pub(crate) fn faulted(drive: u8, i: &PzdInput) -> String {
    format!(
        "drive {drive} is in fault (ZSW1 {:#06X}): see `ussctl faults {drive}`, then acknowledge with `ussctl ack {drive}`",
        i.zsw1
    )
}

/// Sends OFF1 and waits until the drive has answered two more exchanges, so it has received it.
pub(crate) fn stop_confirmed(c: &Controller) -> Result<PzdInput, Failure> {
    c.stop().map_err(|e| e.to_string())?;
    Ok(c.wait_for(Duration::from_secs(1), "OFF1 sent", {
        let start = c.inputs().latest().sequence;
        move |i| i.sequence >= start + 2
    })
    .map_err(|e| e.to_string())?)
}
