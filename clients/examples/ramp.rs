//! A control loop in step with the bus: wakes on each exchange with its drive (the `cycle`
//! event ussd signals after every poll), ramps the setpoint up to a peak and back down, and
//! publishes once per exchange, which also keeps ussd's watchdog refreshed.
//!
//! ```text
//! ussd &                                   # the embedded simulated bus0 with drives 1..4
//! cargo run -p uss-client --example ramp -- bus0 1 40 3
//! ```
//! Arguments: bus (bus0), drive (1), peak in Hz (40), ramps up and down (1). Hz are scaled by
//! the reference frequency ussd publishes: the drive's own P2000 once ussd has read it (ussd
//! logs a difference from its configuration's `reference_hz`).

use std::process::ExitCode;
use std::time::{Duration, Instant};
use uss_client::{Address, Bus, ControlOptions, CycleEvent, DriveState};

/// Seconds for one ramp from 0 to the peak.
const RAMP_SECONDS: f32 = 2.0;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("ramp: {e}");
            ExitCode::FAILURE
        }
    }
}

fn arg<T: std::str::FromStr>(n: usize, default: T) -> Result<T, String> {
    match std::env::args().nth(n) {
        None => Ok(default),
        Some(a) => a.parse().map_err(|_| {
            format!("argument {n} ({a:?}): usage: ramp [BUS] [DRIVE] [PEAK_HZ] [RAMPS]")
        }),
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    // iceoryx2 warns at start-up that it found no config file and uses its defaults, as
    // ussd does; keep its log to errors unless IOX2_LOG_LEVEL says otherwise.
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let bus_name: String = arg(1, "bus0".to_owned())?;
    let drive = Address::new(arg(2, 1)?)?;
    let peak_hz: f32 = arg(3, 40.0)?;
    let ramps: u32 = arg(4, 1)?;

    let bus = Bus::open_as(&bus_name, "ramp-example")?;
    let events = bus.cycle_listener()?;
    let c = bus.control(drive, ControlOptions::default())?;
    // Hz are scaled by the drive's P2000 as ussd publishes it, once it has read it.
    let reference_hz = c.inputs().wait_for_reference(c.inputs().reference_wait())?;

    // S1 -> S2 -> S4 (USS.md section 7). `wait_for_state` refreshes while it waits. Opening
    // re-arms nothing: the explicit re-arm (OFF1 naming ussd's start-up latch) is this
    // program's deliberate act, asked for when it started: a stop while it starts up stays.
    c.rearm(uss_client::process_start_ns()?)?;
    c.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(2))?;
    c.run_hz(0.0)?;
    c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(2))?;
    println!(
        "drive {drive} on {bus_name}: S4, reference {reference_hz} Hz, ramping to {peak_hz} Hz"
    );

    let start = Instant::now();
    let period = 2.0 * RAMP_SECONDS;
    let mut last_print = start;
    while start.elapsed().as_secs_f32() < period * ramps as f32 {
        // Wait for this drive's next exchange; ussd's death ends the loop with an error.
        let mut ours = false;
        let mut gone = false;
        events.wait(Duration::from_millis(200), |e| match e {
            CycleEvent::Exchange(a) if a == drive.get() => ours = true,
            CycleEvent::UssdGone => gone = true,
            _ => {}
        })?;
        if gone {
            return Err("ussd stopped".into());
        }
        // A triangle: 0 -> peak -> 0 every `period` seconds.
        let phase = (start.elapsed().as_secs_f32() % period) / RAMP_SECONDS;
        let setpoint = peak_hz * if phase <= 1.0 { phase } else { 2.0 - phase };
        // Published on each exchange, or at least every 200 ms without events: the watchdog
        // never sees a stale controller.
        c.run_hz(setpoint)?;
        if ours && last_print.elapsed() >= Duration::from_millis(250) {
            println!(
                "{:5.2} s  setpoint {setpoint:6.2} Hz  actual {:6.2} Hz  {}",
                start.elapsed().as_secs_f32(),
                c.inputs().actual_hz(),
                c.inputs().state().short_name()
            );
            last_print = Instant::now();
        }
    }
    c.stop()?;
    c.inputs().wait_exchanges(2, Duration::from_secs(1))?;
    println!("stopped (OFF1): the drive ramps down by itself");
    Ok(())
}
