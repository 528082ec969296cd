//! A program of your own on `uss-client`: opens ussd's bus, reads drive 1's maximum frequency
//! P1082 in the manual's notation, then controls the drive: the deliberate re-arm (naming the
//! time this program started, so an operator's stop since then stays), 10 Hz for a second,
//! and a stop, confirmed by the drive.
//!
//! ```text
//! ussd &                                            # the embedded simulated bus0
//! cargo run -p uss-example-controller -- bus0 1     # prints what it does, line by line
//! ```

use std::process::ExitCode;
use std::time::Duration;
use uss_client::{Address, Bus, ControlOptions, DriveState};

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("uss-example-controller: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let bus_name = args.next().unwrap_or_else(|| "bus0".to_owned());
    let drive = Address::new(args.next().map_or(Ok(1), |a| a.parse())?)?;

    let bus = Bus::open_as(&bus_name, "example-controller")?;
    let p1082 = bus.read_param(drive, "P1082".parse()?)?;
    println!("drive {drive}: {p1082}");

    let c = bus.control(drive, ControlOptions::default())?;
    c.inputs().wait_for_reference(c.inputs().reference_wait())?;
    // Opening re-arms nothing: this is the program's deliberate act, as of its start.
    c.rearm(uss_client::process_start_ns()?)?;
    c.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(2))?;
    c.run_hz(10.0)?;
    c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(2))?;
    println!("drive {drive}: running at 10 Hz");
    // The program's own calls feed the drive's watchdog.
    let end = std::time::Instant::now() + Duration::from_secs(1);
    while std::time::Instant::now() < end {
        c.run_hz(10.0)?;
        std::thread::sleep(Duration::from_millis(20));
    }
    c.stop()?;
    c.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(5))?;
    println!("drive {drive}: stopped (OFF1)");
    Ok(())
}
