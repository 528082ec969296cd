//! `stop`, `coast`, `quick-stop`: an operator's command through ussd.

use crate::cli::Target;
use crate::report::StopReport;
use crate::{Failure, Output};
use uss_client::{Bus, StopCommand};

/// `stop`, `coast`, `quick-stop`: the operator's command through ussd, whoever controls the
/// drive; waits until each drive's image shows it went out, as long as ussd says the drive's
/// next poll may take (an offline drive's next probe).
pub(crate) fn stop(
    bus: &Bus,
    out: &Output,
    target: Target,
    command: StopCommand,
) -> Result<(), Failure> {
    let drives = match target.drive {
        Some(drive) => {
            bus.stop_drive(drive, command)?;
            vec![drive]
        }
        None => bus.stop_all(command)?,
    };
    let mut report = StopReport::new(bus.name(), command);
    for drive in drives {
        let last =
            bus.wait_stopped(drive, command, None)
                .map_err(|source| Failure::StopUnconfirmed {
                    drive,
                    command,
                    source,
                })?;
        report.push(drive, &last);
    }
    out.show(&report, StopReport::human)
}
