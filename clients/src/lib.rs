//! The Rust client API of uss-rt: talk to the drives of a bus that `ussd` runs, from any local
//! process, over iceoryx2 shared memory (the contract is `uss-shm-types`).
//!
//! ```no_run
//! use std::time::Duration;
//! use uss_client::{Address, Bus, ControlOptions, DriveState, ParamRef, Value};
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let bus = Bus::open("bus0")?; // "ussd is not running on bus0: start it with ..." otherwise
//! for address in bus.drives() {
//!     let d = bus.diag(address)?;
//!     println!("drive {address}: online {} good {}", d.online, d.counters.good);
//! }
//!
//! // Addresses and parameters are checked where they enter (text, a number): typed after.
//! let (one, two) = (Address::new(1)?, Address::new(2)?);
//! let max_hz = bus.read_f32(one, ParamRef::p(1082))?; // P1082 = 50.0
//! bus.write(one, "P1120".parse()?, Value::from_f32(2.0), false)?; // ramp-up 2 s, RAM only
//!
//! // Exclusive control: a second controller of drive 1 is refused.
//! // Every call refreshes the drive's watchdog; a loop calls at least once per watchdog time
//! // (drive.keepalive() between changes).
//! let drive = bus.control(one, ControlOptions::default())?;
//! // Opening re-arms nothing: ussd latched the drive at its start, and only the program's
//! // explicit re-arm (OFF1 naming the latch) lets an ON through. S1 -> S2. A re-arm carries
//! // when it was asked for (here: this program's start), and re-arms no stop that came after.
//! drive.rearm(uss_client::process_start_ns()?)?;
//! drive.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(1))?;
//! drive.run_hz(0.5 * max_hz)?; // S2 -> S4
//! drive.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(1))?;
//! println!("{:.1} Hz", drive.inputs().actual_hz());
//! match drive.set_setpoint(uss_client::Setpoint::from_percent(20.0)) {
//!     // Frozen too long, an operator's stop, ...: the drive is latched until re-armed.
//!     Err(uss_client::ClientError::Tripped { latch, .. }) => {
//!         eprintln!("tripped: {latch}");
//!         // OFF1, acknowledged; an ON may follow. Asked for now, by this program's decision.
//!         drive.rearm(uss_client::monotonic_ns())?;
//!     }
//!     other => other?,
//! }
//! drive.stop()?; // OFF1
//! drive.release()?; // hand it back: "released", not a watchdog trip
//!
//! // Anyone may stop a drive, whoever controls it (OFF1, OFF2 coast, OFF3 quick stop).
//! bus.stop_drive(two, uss_client::StopCommand::Off2)?;
//! # Ok(())
//! # }
//! ```
//!
//! - [`Bus`]: open a bus; [`Bus::status`], [`Bus::drives`], [`Bus::diag`].
//! - [`DriveWatch`] ([`Bus::watch`]): a drive's latest input image (ZSW1, actual value), read
//!   without blocking; [`CycleListener`] ([`Bus::cycle_listener`]) wakes on each exchange
//!   and each completed cycle, to run in step with the bus.
//! - [`Controller`] ([`Bus::control`]): the one writer of a drive's output image, with helpers
//!   that follow the PROFIdrive state machine (USS.md section 7). ussd latches the drive (safe
//!   command until the controller re-arms with OFF1, then ON) when its controller stops
//!   refreshing, sends a bad sample, or an operator stops it: see [`Controller`].
//! - Operator stops ([`Bus::stop_drive`], [`Bus::stop_all`]): OFF1/OFF2/OFF3 from any process,
//!   overriding the controller.
//! - Parameters ([`Bus::read`], [`Bus::write`], [`Bus::batch`], [`Bus::faults`]): typed
//!   [`Value`]s and [`ParamError`]s (USS.md section 6).
//! - Commissioning ([`commissioning`]): the copy of RAM to ROM ([`Bus::save_to_rom`]), the
//!   factory reset ([`Bus::factory_reset`]), quick commissioning ([`Bus::quick_commission`]);
//!   with the `backup` feature the upload, diff and download (`backup`, `restore`); with the
//!   `scan` feature the scan of a line ussd does not serve (`scan`).
//!
//! Errors say what happened and what to do ([`ClientError`], [`ParamError`]).
//!
//! iceoryx2 logs through `tracing` (this workspace builds it with its `tracing` feature): an
//! application with a tracing subscriber sees its messages, one without sees nothing.
//! Applications that explain errors themselves call [`quiet_iceoryx2_logs`] first, as `ussctl`
//! does, to keep iceoryx2's warnings out of their log.

#[cfg(feature = "backup")]
pub mod backup;
mod bus;
pub mod cancel;
mod capture;
mod command;
pub mod commissioning;
mod control;
mod error;
pub mod kinds;
mod link;
mod open;
pub mod params;
mod request;
#[cfg(feature = "backup")]
pub mod restore;
#[cfg(feature = "scan")]
pub mod scan;
mod typed;
#[cfg(feature = "view")]
pub mod view;
mod watch;

pub use bus::{Bus, DEFAULT_NODE_NAME};
pub use capture::Capture;
pub use command::stop;
pub use commissioning::{Commissioned, Picture, Reset, Saved};
pub use control::{ControlOptions, Controller, DEFAULT_REFRESH, HANDSHAKE_TIMEOUT, Jog, Refresher};
pub use error::{ClientError, Latch, ParamError};
pub use kinds::ErrorKind;
pub use link::{Health, monotonic_ns, process_start_ns};
pub use params::WriteOptions;
pub use typed::{Description, Fault, FaultReport, FaultTime, ParamValue, Runtime, Warning};
pub use uss_catalogue::{Catalogue, DataType, Quantity, Typed, Values};
pub use uss_protocol::{
    Address, DriveState, ParamRef, ParamTask, Pnu, Setpoint, Stw1, Subindex, Value, Zsw1,
};
pub use uss_shm_types::{
    BusState, BusStatus, ControlState, DriveDiag, DriveError, DriveFamily, DriveInfo, LatchReason,
    LineFault, Monitoring, ParamItem, ParamRequest, ParamResponse, PathError, PzdInput, PzdOutput,
    Rejection, RequestError, StopCommand,
};
pub use watch::{CycleEvent, CycleListener, DriveWatch, Snapshot};
/// The protocol and contract crates this API speaks, so applications use the same versions.
pub use {uss_catalogue, uss_protocol, uss_shm_types};

/// The PROFIdrive state of an input image.
pub fn state_of(input: &PzdInput) -> DriveState {
    DriveState::from_zsw1(Zsw1::from_bits_retain(input.zsw1))
}

/// The short state name of a ZSW1: S1..S4, "fault", "not ready" (USS.md section 7).
pub fn state_name(zsw1: u16) -> &'static str {
    DriveState::from_zsw1(Zsw1::from_bits_retain(zsw1)).short_name()
}

/// What a ZSW1 says beyond the state, as short flags: set bits by name, and the active-low
/// MICROMASTER alarms (bits 11, 12, 13, 15) when they are active (USS.md section 7).
pub fn zsw1_flags(zsw1: u16) -> Vec<&'static str> {
    let z = Zsw1::from_bits_retain(zsw1);
    let set = [
        (Zsw1::FAULT, "fault"),
        (Zsw1::WARNING, "warning"),
        (Zsw1::AT_SETPOINT, "at-setpoint"),
        (Zsw1::CONTROL_REQUESTED, "control-requested"),
        (Zsw1::MAX_FREQUENCY_REACHED, "max-frequency"),
        (Zsw1::RUNNING_RIGHT, "running-right"),
    ];
    let clear = [
        (Zsw1::NO_OFF2, "off2"),
        (Zsw1::NO_OFF3, "off3"),
        (Zsw1::NO_CURRENT_LIMIT, "current-limit"),
        (Zsw1::NO_HOLDING_BRAKE, "holding-brake"),
        (Zsw1::NO_MOTOR_OVERLOAD, "motor-overload"),
        (Zsw1::NO_INVERTER_OVERLOAD, "inverter-overload"),
    ];
    let mut flags: Vec<_> = set
        .iter()
        .filter(|(bit, _)| z.contains(*bit))
        .map(|&(_, name)| name)
        .collect();
    flags.extend(
        clear
            .iter()
            .filter(|(bit, _)| !z.contains(*bit))
            .map(|&(_, name)| name),
    );
    flags
}

/// Limits iceoryx2's own logging to errors (unless `IOX2_LOG_LEVEL` says otherwise), for
/// applications that report errors themselves; without it iceoryx2 logs multi-kilobyte
/// warnings, e.g. when a service still holds a dead process's ports.
pub fn quiet_iceoryx2_logs() {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The MM420 start-up trace of USS.md section 7.
    #[test]
    fn states_and_flags_of_the_mm420_trace() {
        assert_eq!(state_name(0xFB41), "S1");
        assert_eq!(state_name(0xFB31), "S2");
        assert_eq!(state_name(0xFB32), "S3");
        assert_eq!(state_name(0xFB34), "S4");
        assert_eq!(state_name(0xFB3C), "fault");
        assert_eq!(
            zsw1_flags(0xFB34),
            ["at-setpoint", "control-requested", "running-right"]
        );
        assert_eq!(
            zsw1_flags(0x6B37),
            [
                "at-setpoint",
                "control-requested",
                "running-right",
                "holding-brake",
                "inverter-overload"
            ]
        );
        assert_eq!(zsw1_flags(0x0008)[0], "fault");
    }

    #[test]
    fn handles_move_between_threads() {
        fn send_sync<T: Send + Sync>() {}
        send_sync::<Bus>();
        send_sync::<DriveWatch>();
        send_sync::<Controller>();
        send_sync::<CycleListener>();
    }
}
