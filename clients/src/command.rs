//! Operator stop commands (OFF1, OFF2, OFF3) for one drive or a whole bus, from any process,
//! through ussd's `command` service. They override the drive's controller and latch: the drive
//! gets the command until its controller re-arms it (OFF1, then ON), and the controller's next
//! call fails with [`ClientError::Tripped`].

use crate::request::{NoAnswer, client, round_trip};
use crate::{Bus, ClientError};
use core::time::Duration;
use uss_shm_types::names;
use uss_shm_types::{
    ALL_DRIVES, CommandError, DriveAddress, LatchReason, OperatorRequest, PzdInput, StopCommand,
};

/// How long ussd may take to answer an operator command.
const COMMAND_TIMEOUT: Duration = Duration::from_secs(2);

impl Bus {
    /// Stops drive `address` with `command` (OFF1 ramp, OFF2 coast, OFF3 quick stop), whoever
    /// controls it. Returns once ussd has handed the command to the bus thread, which applies
    /// it at the drive's next poll; [`Bus::wait_stopped`] waits for that.
    pub fn stop_drive(&self, address: u8, command: StopCommand) -> Result<(), ClientError> {
        DriveAddress::new(address)?;
        self.known(address)?;
        self.operator(address, command).map(|_| ())
    }

    /// Stops every drive of the bus with `command`; returns their addresses.
    pub fn stop_all(&self, command: StopCommand) -> Result<Vec<u8>, ClientError> {
        self.operator(ALL_DRIVES, command)
    }

    /// Waits until drive `address` got a stop command at least as strong as `command` from an
    /// operator (its input image shows the override and the control word that went out) and
    /// returns that image. `timeout` `None` waits the drive's own time for it
    /// ([`crate::DriveWatch::handshake`]: its turn in the circulating list, or its next probe
    /// while offline, and the poll).
    pub fn wait_stopped(
        &self,
        address: u8,
        command: StopCommand,
        timeout: Option<Duration>,
    ) -> Result<PzdInput, ClientError> {
        let watch = self.watch(address)?;
        let wanted = format!("{command} applied");
        let shown = |i: &PzdInput| {
            let got = StopCommand::try_from(i.latch_command).unwrap_or(StopCommand::None);
            i.latch_reason == LatchReason::Override.code()
                && got.strength() >= command.strength()
                && got.stw1() == Some(i.sent_stw1)
        };
        match timeout {
            Some(timeout) => watch.wait_for(timeout, &wanted, shown),
            None => watch.wait_polled(&wanted, shown),
        }
    }

    fn operator(&self, address: u8, command: StopCommand) -> Result<Vec<u8>, ClientError> {
        let services = self.link().check()?;
        let name = names::command(&services.instance);
        let client = client(self.link(), &services, &services.commands, &name)?;
        let answer = round_trip(
            client,
            OperatorRequest::new(address, command),
            COMMAND_TIMEOUT,
        )?;
        let response = match answer {
            Ok(r) => r,
            Err(NoAnswer::NotRunning | NoAnswer::Dropped) => {
                return Err(ClientError::NotRunning {
                    bus: self.name().to_owned(),
                });
            }
            Err(NoAnswer::Timeout) => {
                return Err(ClientError::ipc(
                    "waiting for ussd's answer to a stop command",
                    format!("no answer within {COMMAND_TIMEOUT:?}"),
                ));
            }
        };
        uss_shm_types::check_version(response.version)?;
        match response.error() {
            Ok(CommandError::Ok) => Ok(response.addresses().collect()),
            Ok(error) => Err(ClientError::CommandRefused {
                bus: self.name().to_owned(),
                error,
            }),
            Err(e) => Err(uss_shm_types::ContractError::from(e).into()),
        }
    }
}
