//! `ack`: acknowledges a drive's fault.

use super::common::{control, rearm_failed};
use crate::cli::address;
use crate::report::DriveReport;
use crate::{Failure, Output};
use uss_client::Address;
use uss_client::{Bus, ClientError, DriveState, StopCommand};

/// `ack`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Ack {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
}

impl Ack {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        ack(bus, out, self.drive)
    }
}

fn ack(bus: &Bus, out: &Output, drive: Address) -> Result<(), Failure> {
    let c = control(bus, drive)?;
    if c.inputs().state() != DriveState::Fault {
        out.note(&format!(
            "drive {drive} shows no fault; acknowledging anyway"
        ));
    }
    // The edge reaches only a live drive: the operator's `ack` re-arms it first with the stop
    // it is latched with (naming its latch: a stop, never an ON), and hands it back latched
    // ("released") when it ends. A coast or quick stop stays on the wire throughout: in the
    // re-arm, through the edge and in the latch of the release (or of a trip, should ussctl
    // die halfway).
    let before = c.inputs().latest();
    let held = (!before.is_live())
        .then(|| StopCommand::of_code(before.latch_command))
        .flatten()
        .filter(|s| s.strength() > StopCommand::Off1.strength());
    c.rearm_keeping_stop(crate::asked_ns()?)
        .map_err(rearm_failed("ack", bus, drive))?;
    // The edge takes two exchanges, the drive's answer a third: the drive's handshake time
    // each (31 drives at 9600 baud poll each drive only every 1.3 s).
    c.acknowledge_fault(c.inputs().handshake())?;
    let last = match c.wait_polled("fault cleared", |i| {
        uss_client::state_of(i) != DriveState::Fault
    }) {
        Ok(i) => i,
        Err(ClientError::WaitTimeout { .. }) => return Err(Failure::FaultPersists { drive }),
        Err(e) => return Err(e.into()),
    };
    let shown = out.show(
        &DriveReport::new(
            bus.name(),
            "ack",
            &last,
            drive,
            c.inputs().info().reference_hz,
        ),
        DriveReport::human,
    );
    if let Some(stop) = held {
        out.note(&format!(
            "drive {drive}: its {} stays: it is handed back latched with it, not with the OFF1 a release sends",
            stop.name()
        ));
    }
    shown
}
