//! What the subcommands share: taking control, confirming a stop, reading diagnostics, the
//! bus's health.

use crate::Failure;
use core::time::Duration;
use uss_client::Address;
use uss_client::{Bus, ControlOptions, Controller, PzdInput};

/// How long a state change may take in the drive before ussctl gives up; the bus adds the
/// drive's handshake time ([`state_timeout`]).
const STATE_TIMEOUT: Duration = Duration::from_secs(3);

/// How long a state change of drive `c` may take: the drive's own time and the bus's time to
/// carry the command and the answer (31 drives at 9600 baud poll each only every 1.3 s).
pub(crate) fn state_timeout(c: &Controller) -> Duration {
    STATE_TIMEOUT + c.inputs().handshake()
}

pub(crate) fn diags(bus: &Bus) -> Result<Vec<uss_client::DriveDiag>, Failure> {
    Ok(bus
        .drives()
        .into_iter()
        .map(|a| bus.diag(a))
        .collect::<Result<_, _>>()?)
}

/// Fails with what ussd's heartbeat says when it does not poll the bus.
pub(crate) fn healthy(bus: &Bus) -> Result<(), Failure> {
    match bus.health().error(bus.name()) {
        Some(e) => Err(e.into()),
        None => Ok(()),
    }
}

/// Takes control of `drive`, explaining a refusal.
/// The failure of a re-arm by `ussctl command` (`run`, `ack`), which carries the command's start:
/// a latch that began after it (or within its 10 ms) is said as a stop while it started.
pub(crate) fn rearm_failed(
    command: &'static str,
    bus: &Bus,
    drive: Address,
) -> impl FnOnce(uss_client::ClientError) -> Failure {
    move |e| match e {
        uss_client::ClientError::Tripped { latch, .. } => Failure::StoppedWhileStarting {
            command,
            drive,
            bus: bus.name().to_owned(),
            latch,
        },
        e => e.into(),
    }
}

pub(crate) fn control(bus: &Bus, drive: Address) -> Result<Controller, Failure> {
    Ok(bus.control(drive, ControlOptions::default())?)
}

pub(crate) const fn faulted(drive: Address, i: &PzdInput) -> Failure {
    Failure::Faulted {
        drive,
        zsw1: i.zsw1,
    }
}

/// Sends OFF1 and waits until the drive has answered two more exchanges, so it has received it.
pub(crate) fn stop_confirmed(c: &Controller) -> Result<PzdInput, Failure> {
    c.stop()?;
    Ok(c.wait_polled("OFF1 sent", {
        let start = c.inputs().latest().sequence;
        move |i| i.sequence >= start + 2
    })?)
}
