//! `run`: takes a drive, runs it towards a frequency, and stops it whatever happens.

use super::common::{control, faulted, state_timeout, stop_confirmed};
use crate::report::DriveReport;
use crate::{Failure, Output, catch_signals, stopped};
use core::time::Duration;
use std::time::Instant;
use uss_client::Address;
use uss_client::{Bus, ClientError, Controller, DriveState};

/// How long `run` waits for a drive that stopped answering before it gives up (longer than
/// an offline probe interval, 0.5 s by default, with room to spare).
const OFFLINE_GRACE: Duration = Duration::from_secs(3);

/// Re-arms the drive (OFF1 naming its latch: S1 -> S2, or it stays in S2..S4) and runs it
/// (S2 -> S3 -> S4).
fn start_running(bus: &Bus, c: &Controller, speed: Speed) -> Result<(), Failure> {
    let drive = c.address();
    let first = c.inputs().latest();
    if first.online == 0 {
        return Err(Failure::Offline {
            drive,
            bus: bus.name().to_owned(),
        });
    }
    if uss_client::state_of(&first) == DriveState::Fault {
        return Err(faulted(drive, &first));
    }
    // `ussctl run` is the operator's deliberate command: it re-arms whatever latch the drive
    // showed when it was asked for (ussd's start, an operator's stop, a trip), the one act
    // that may (docs/SAFETY.md); a stop that came while it was starting wins.
    c.rearm(crate::asked_ns()?)
        .map_err(super::common::rearm_failed("run", bus, drive))?;
    c.wait_for(state_timeout(c), "S2 (ready to switch on)", |i| {
        i.online != 0
            && matches!(
                uss_client::state_of(i),
                DriveState::ReadyToSwitchOn
                    | DriveState::ReadyForOperation
                    | DriveState::OperationEnabled
            )
    })?;
    if !matches!(speed, Speed::Percent(_)) {
        // A drive that just came online, was reset or commissioned has its reference read
        // again: ussd scales nothing with the old one, so wait for it (a poll or two).
        let inputs = c.inputs();
        inputs.wait_for_reference(inputs.reference_wait())?;
    }
    match speed {
        Speed::Hz(hz) => c.run_hz(hz)?,
        Speed::Rpm(rpm) => c.run_rpm(rpm)?,
        Speed::Percent(p) => c.run_percent(p)?,
    }
    c.wait_for_state(DriveState::OperationEnabled, state_timeout(c))?;
    Ok(())
}

/// A running drive that stops answering: reported, and given [`OFFLINE_GRACE`] to come back
/// (an offline probe interval or two); the controller keeps publishing meanwhile, and the
/// drive gets its words again when it answers.
#[derive(Default)]
struct Absence {
    since: Option<Instant>,
}

impl Absence {
    /// Takes whether the drive answers now; the failure when it stayed away too long.
    fn note(&mut self, out: &Output, drive: Address, online: bool) -> Option<Failure> {
        match (online, self.since) {
            (false, None) => {
                out.note(&format!(
                    "  drive {drive} does not answer; waiting up to {} s for it",
                    OFFLINE_GRACE.as_secs()
                ));
                self.since = Some(Instant::now());
            }
            (false, Some(t)) if t.elapsed() > OFFLINE_GRACE => {
                return Some(Failure::WentOffline {
                    drive,
                    grace: OFFLINE_GRACE,
                });
            }
            (true, Some(t)) => {
                out.note(&format!(
                    "  drive {drive} answers again after {:.2} s",
                    t.elapsed().as_secs_f64()
                ));
                self.since = None;
            }
            _ => {}
        }
        None
    }
}

/// `run`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Run {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = crate::cli::address)]
    pub(crate) drive: Address,
    /// Frequency in Hz; negative runs the other way.
    #[arg(
        long,
        allow_negative_numbers = true,
        value_name = "HZ",
        required_unless_present_any = ["percent", "rpm"],
        conflicts_with_all = ["percent", "rpm"]
    )]
    pub(crate) hz: Option<f32>,
    /// Speed in rpm of the drive's reference speed (a G120's p2000, which ussd reads with
    /// `pole_pairs` in the drive's configuration); negative runs the other way.
    #[arg(
        long,
        allow_negative_numbers = true,
        value_name = "RPM",
        conflicts_with = "percent"
    )]
    pub(crate) rpm: Option<f32>,
    /// The setpoint in % of the drive's reference (P2000, p2000: 100 % is its reference
    /// frequency or speed; a G120's is in rpm); negative runs the other way.
    #[arg(long, allow_negative_numbers = true, value_name = "PERCENT")]
    pub(crate) percent: Option<f32>,
    /// Run this many seconds, then stop (default: until Ctrl-C).
    #[arg(long = "for", value_name = "SECONDS")]
    pub(crate) duration: Option<f64>,
}

/// What `run` runs towards.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Speed {
    Hz(f32),
    /// % of the drive's reference: no reference frequency needed.
    Percent(f32),
    /// rpm of the drive's reference speed.
    Rpm(f32),
}

impl Run {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        let speed = match (self.hz, self.percent, self.rpm) {
            (_, Some(p), _) => Speed::Percent(p),
            (_, None, Some(rpm)) => Speed::Rpm(rpm),
            (Some(hz), None, None) => Speed::Hz(hz),
            (None, None, None) => {
                return Err(Failure::Usage("give --hz, --rpm or --percent".to_owned()));
            }
        };
        run_drive(bus, out, self.drive, speed, self.duration)
    }
}

fn run_drive(
    bus: &Bus,
    out: &Output,
    drive: Address,
    speed: Speed,
    duration: Option<f64>,
) -> Result<(), Failure> {
    let duration = duration
        .map(|s| {
            Duration::try_from_secs_f64(s)
                .map_err(|_| Failure::Usage(format!("--for {s}: give a number of seconds >= 0")))
        })
        .transpose()?;
    let c = control(bus, drive)?;
    catch_signals()?;
    start_running(bus, &c, speed)?;
    let reference = c
        .inputs()
        .info()
        .reference()
        .map_or_else(|| "being read again".to_owned(), |r| format!("{r} Hz"));
    let towards = match speed {
        Speed::Hz(hz) => format!("{hz} Hz (reference {reference})"),
        Speed::Percent(p) => format!("{p} % of its reference ({reference})"),
        Speed::Rpm(rpm) => {
            let speed = c
                .inputs()
                .info()
                .reference_rpm()
                .map_or_else(|| "being read again".to_owned(), |r| format!("{r:.0} rpm"));
            format!("{rpm} rpm (reference speed {speed}, {reference})")
        }
    };
    out.note(&format!(
        "drive {drive}: running towards {towards} on {}; {}",
        // The bus by name: it may come from USS_BUS, which a shell keeps out of sight.
        bus.name(),
        match duration {
            Some(d) => format!("stopping after {d:?}"),
            None => "Ctrl-C stops it".to_owned(),
        }
    ));

    let start = Instant::now();
    let mut peak = 0.0f32;
    let mut last_note = Instant::now();
    let mut absence = Absence::default();
    // Well inside the drive's watchdog time, however short it is.
    let period = c.refresh_period().min(Duration::from_millis(10));
    let failure = loop {
        // The loop's own call refreshes the drive: a stalled ussctl trips it, as a dead one.
        let i = match c.keepalive().and_then(|()| c.check()) {
            Ok(i) => i,
            Err(
                e @ (ClientError::UssdGone { .. }
                | ClientError::UssdStopped { .. }
                | ClientError::LineDown { .. }),
            ) => {
                // Nothing to stop through: the drive's own telegram monitoring stops it.
                return Err(Failure::OfDrive { drive, source: e });
            }
            Err(ClientError::Tripped { latch, .. }) => {
                // Latched by ussd: the drive gets its stop command; leave it so.
                return Err(Failure::Tripped {
                    drive,
                    bus: bus.name().to_owned(),
                    after: start.elapsed(),
                    latch,
                });
            }
            Err(e) => break Some(e.into()),
        };
        let actual = c.inputs().actual_hz();
        if actual.abs() > peak.abs() {
            peak = actual;
        }
        if let Some(f) = absence.note(out, drive, i.online != 0) {
            break Some(f);
        }
        if uss_client::state_of(&i) == DriveState::Fault {
            break Some(faulted(drive, &i));
        }
        if stopped() || duration.is_some_and(|d| start.elapsed() >= d) {
            break None;
        }
        if last_note.elapsed() >= Duration::from_millis(500) {
            out.note(&format!(
                "  {:6.1} s  {actual:8.2} Hz",
                start.elapsed().as_secs_f64()
            ));
            last_note = Instant::now();
        }
        std::thread::sleep(period);
    };
    // Stop whatever happened: OFF1, and make sure the drive received it before leaving it
    // to the watchdog (whose safe command is OFF1 by default too).
    let last = stop_confirmed(&c)?;
    if let Some(f) = failure {
        return Err(f);
    }
    let ref_hz = c.inputs().info().reference_hz;
    let report = DriveReport::new(bus.name(), "run", &last, drive, ref_hz).with_peak(peak);
    out.show(&report, DriveReport::human)
}
