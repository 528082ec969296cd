//! `stop`, `coast`, `quick-stop`: an operator's command through ussd.

use crate::cli::address;
use crate::report::StopReport;
use crate::{Failure, Output};
use uss_client::{Address, Bus, ClientError, StopCommand};

/// The drive a stop command is for, or every drive of the bus: the arguments of `stop`,
/// `coast` and `quick-stop`.
#[derive(Debug, Clone, Copy, clap::Args)]
#[group(required = true, multiple = false)]
pub struct Target {
    /// The drive's address.
    #[arg(value_parser = address)]
    pub drive: Option<Address>,
    /// Every drive of the bus.
    #[arg(long)]
    pub all: bool,
}

impl Target {
    /// Sends `command` to the target (see [`stop`]).
    pub(crate) fn run(
        self,
        bus_name: &str,
        out: &Output,
        command: StopCommand,
    ) -> Result<(), Failure> {
        stop(bus_name, out, self, command)
    }
}

/// `stop`, `coast`, `quick-stop`: the operator's command through ussd's stop socket first (no
/// open bus needed: neither the heartbeat nor the services' port limits stand in its way),
/// whoever controls the drive; then waits until each drive's image shows it went out, as long
/// as ussd says the drive's next poll may take. Where this process cannot read the images (the
/// services admit no more readers), the stop stands and the report says it is unconfirmed.
fn stop(bus_name: &str, out: &Output, target: Target, command: StopCommand) -> Result<(), Failure> {
    // The latch that confirms the stop began when it was sent, or later: not an older one of
    // an as strong stop.
    let sent = uss_client::monotonic_ns();
    let drives = uss_client::stop(bus_name, target.drive, command)?;
    let mut report = StopReport::new(bus_name, command);
    let bus = match Bus::open_as(bus_name, "ussctl") {
        Ok(bus) => Some(bus),
        Err(e @ ClientError::Ipc { .. }) => {
            report.unconfirmed(&drives, &e);
            None
        }
        Err(e) => return Err(e.into()),
    };
    if let Some(bus) = bus {
        for drive in drives {
            match bus.wait_stopped_since(drive, command, sent, None) {
                Ok(last) => report.push(drive, &last),
                Err(e @ ClientError::Ipc { .. }) => report.unconfirmed(&[drive], &e),
                Err(source) => {
                    return Err(Failure::StopUnconfirmed {
                        drive,
                        command,
                        source,
                    });
                }
            }
        }
    }
    out.show(&report, StopReport::human)
}
