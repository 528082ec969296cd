//! `ussctl`: look at and operate the drives of a bus that ussd runs. Short, predictable
//! subcommands in the manner of the `ethercat` tool of `EtherCAT` masters, human output by default,
//! `--json` for machines. Errors go to stderr, say what to do, and exit with 1 (2 for usage
//! errors).

mod cli;
mod report;

use clap::Parser;
use cli::{Cli, Command, ParamCommand, Target};
use core::time::Duration;
use report::{
    BusReport, DriveReport, DriveRow, DriveStats, FaultsReport, ParamReport, StatsReport,
    StatusReport, StopReport, WatchLine,
};
use serde::Serialize;
use std::io::Write as _;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, LazyLock};
use std::time::Instant;
use uss_client::uss_protocol::Subindex;
use uss_client::{
    Bus, ClientError, ControlOptions, Controller, DriveState, PzdInput, StopCommand, WriteOptions,
};

/// How long a state change of the drive may take before ussctl gives up.
const STATE_TIMEOUT: Duration = Duration::from_secs(3);
/// How long `run` waits for a drive that stopped answering before it gives up (longer than
/// an offline probe interval, 0.5 s by default, with room to spare).
const OFFLINE_GRACE: Duration = Duration::from_secs(3);

/// Set by SIGINT/SIGTERM once [`catch_signals`] ran.
static STOP: LazyLock<Arc<AtomicBool>> = LazyLock::new(|| Arc::new(AtomicBool::new(false)));

/// `watch` and `run` end cleanly on SIGINT/SIGTERM (`run` stops the drive first).
fn catch_signals() -> Result<(), String> {
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&STOP))
            .map_err(|e| format!("cannot install a handler of signal {signal}: {e}"))?;
    }
    Ok(())
}

fn stopped() -> bool {
    STOP.load(Ordering::Relaxed)
}

/// Why ussctl ends early.
enum Failure {
    /// An error to report on stderr (exit 1).
    Message(String),
    /// Whoever reads our output went away (`ussctl watch | head`): end quietly.
    Closed,
}

impl From<String> for Failure {
    fn from(message: String) -> Self {
        Self::Message(message)
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // iceoryx2 reports every refused open at warning level with a debug dump; ussctl explains
    // errors itself. IOX2_LOG_LEVEL still overrides.
    uss_client::quiet_iceoryx2_logs();
    match run(&cli) {
        Ok(()) | Err(Failure::Closed) => ExitCode::SUCCESS,
        Err(Failure::Message(e)) => {
            eprintln!("ussctl: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: &Cli) -> Result<(), Failure> {
    let mut bus = Bus::open_as(&cli.bus, "ussctl").map_err(|e| e.to_string())?;
    if let Some(t) = cli.timeout {
        let t = Duration::try_from_secs_f64(t)
            .ok()
            .filter(|d| !d.is_zero())
            .ok_or_else(|| format!("--timeout {t}: give a positive number of seconds"))?;
        bus.set_answer_timeout(Some(t));
    }
    let out = Output { json: cli.json };
    match &cli.command {
        Command::Status { ref_hz } => status(&bus, &out, *ref_hz),
        Command::Watch {
            drives,
            interval,
            count,
            ref_hz,
        } => watch(&bus, &out, drives, *interval, *count, *ref_hz),
        Command::Param(ParamCommand::Read { drive, param, kind }) => {
            let v = bus
                .read(*drive, param.pnu.get(), param.index.map(Subindex::get))
                .map_err(|e| format!("drive {drive} {param}: {e}"))?;
            out.show(
                &ParamReport::new(bus.name(), *drive, *param, v, *kind),
                ParamReport::human,
            )
        }
        Command::Param(ParamCommand::Write {
            drive,
            param,
            value,
            eeprom,
            kind,
            force,
        }) => {
            let (value, kind) = cli::parse_value(value, *kind)?;
            let options = WriteOptions {
                eeprom: *eeprom,
                force: *force,
            };
            let index = param.index.map(Subindex::get);
            let now = bus
                .write_with(*drive, param.pnu.get(), index, value, options)
                .map_err(|e| format!("drive {drive} {param}: {e}"))?;
            // The value the drive now holds, read as the type it was written as.
            let mut report = ParamReport::new(bus.name(), *drive, *param, now, Some(kind));
            report.eeprom = Some(*eeprom);
            out.show(&report, ParamReport::human)
        }
        Command::Run {
            drive,
            hz,
            ref_hz,
            duration,
        } => run_drive(&bus, &out, *drive, *hz, *ref_hz, *duration),
        Command::Stop(target) => stop(&bus, &out, *target, StopCommand::Off1),
        Command::Coast(target) => stop(&bus, &out, *target, StopCommand::Off2),
        Command::QuickStop(target) => stop(&bus, &out, *target, StopCommand::Off3),
        Command::Ack { drive } => ack(&bus, &out, *drive),
        Command::Faults { drive } => {
            let faults = bus
                .faults(*drive)
                .map_err(|e| format!("drive {drive} r0947: {e}"))?;
            out.show(
                &FaultsReport {
                    bus: bus.name().to_owned(),
                    drive: *drive,
                    faults,
                },
                FaultsReport::human,
            )
        }
        Command::Stats => stats(&bus, &out),
    }
}

/// Human or JSON output.
struct Output {
    json: bool,
}

impl Output {
    fn show<T: Serialize>(&self, report: &T, human: impl Fn(&T) -> String) -> Result<(), Failure> {
        let mut text = if self.json {
            serde_json::to_string(report).map_err(|e| format!("cannot write JSON: {e}"))?
        } else {
            human(report)
        };
        if !text.ends_with('\n') {
            text.push('\n');
        }
        let mut stdout = std::io::stdout().lock();
        match stdout
            .write_all(text.as_bytes())
            .and_then(|()| stdout.flush())
        {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(Failure::Closed),
            Err(e) => Err(format!("cannot write the output: {e}").into()),
        }
    }

    /// Progress for people (nothing with `--json`); a closed output does not stop the work.
    fn note(&self, text: &str) {
        if !self.json {
            let _ = writeln!(std::io::stdout().lock(), "{text}");
        }
    }
}

fn diags(bus: &Bus) -> Result<Vec<uss_client::DriveDiag>, String> {
    bus.drives()
        .into_iter()
        .map(|a| bus.diag(a).map_err(|e| e.to_string()))
        .collect()
}

/// `status`: the table; with the line down, the table and then the failure (exit 1).
fn status(bus: &Bus, out: &Output, ref_hz: f32) -> Result<(), Failure> {
    let report = StatusReport {
        bus: BusReport::new(bus.name(), &bus.status().map_err(|e| e.to_string())?),
        drives: diags(bus)?
            .iter()
            .map(|d| DriveRow::new(d, ref_hz))
            .collect(),
    };
    out.show(&report, StatusReport::human)?;
    healthy(bus)
}

fn stats(bus: &Bus, out: &Output) -> Result<(), Failure> {
    let status = bus.status().map_err(|e| e.to_string())?;
    let report = StatsReport {
        bus: BusReport::new(bus.name(), &status),
        drives: diags(bus)?
            .iter()
            .map(|d| DriveStats::new(d, status.timestamp_ns))
            .collect(),
    };
    out.show(&report, StatsReport::human)?;
    healthy(bus)
}

/// Fails with what ussd's heartbeat says when it does not poll the bus.
fn healthy(bus: &Bus) -> Result<(), Failure> {
    match bus.health().error(bus.name()) {
        Some(e) => Err(e.to_string().into()),
        None => Ok(()),
    }
}

fn watch(
    bus: &Bus,
    out: &Output,
    only: &[u8],
    interval_ms: u64,
    count: Option<u64>,
    ref_hz: f32,
) -> Result<(), Failure> {
    let addresses = if only.is_empty() {
        bus.drives()
    } else {
        only.to_vec()
    };
    let watches = addresses
        .iter()
        .map(|&a| bus.watch(a))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    catch_signals()?;
    let start = Instant::now();
    let interval = Duration::from_millis(interval_ms.max(1));
    let mut round = 0;
    while !stopped() && count.is_none_or(|n| round < n) {
        if round > 0 {
            sleep_unless_stopped(interval);
            if stopped() {
                break;
            }
        }
        let t = start.elapsed().as_secs_f64();
        for w in &watches {
            // A stale picture is never shown: ussd gone, stopped or its line down ends it.
            let image = w.read().map_err(|e| e.to_string())?;
            out.show(
                &WatchLine::new(t, w.address(), &image, ref_hz),
                WatchLine::human,
            )?;
        }
        round += 1;
    }
    Ok(())
}

/// Sleeps `d` in small steps so Ctrl-C is noticed quickly.
fn sleep_unless_stopped(d: Duration) {
    let end = Instant::now() + d;
    while !stopped() {
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return;
        }
        std::thread::sleep(left.min(Duration::from_millis(20)));
    }
}

/// Takes control of `drive`, explaining a refusal.
fn control(bus: &Bus, drive: u8) -> Result<Controller, String> {
    bus.control(drive, ControlOptions::default())
        .map_err(|e| e.to_string())
}

fn faulted(drive: u8, i: &PzdInput) -> String {
    format!(
        "drive {drive} is in fault (ZSW1 {:#06X}): see `ussctl faults {drive}`, then acknowledge with `ussctl ack {drive}`",
        i.zsw1
    )
}

/// Arms the drive (OFF1: S1 -> S2, or it stays in S2..S4) and runs it (S2 -> S3 -> S4).
fn start_running(bus: &Bus, c: &Controller, hz: f32, ref_hz: f32) -> Result<(), Failure> {
    let drive = c.address();
    let first = c.inputs().latest();
    if first.online == 0 {
        return Err(format!(
            "drive {drive} on {} is offline: check `ussctl status`, its wiring, address and baud rate",
            bus.name()
        )
        .into());
    }
    if uss_client::state_of(&first) == DriveState::Fault {
        return Err(faulted(drive, &first).into());
    }
    c.enable().map_err(|e| e.to_string())?;
    c.wait_for(STATE_TIMEOUT, "S2 (ready to switch on)", |i| {
        i.online != 0
            && matches!(
                uss_client::state_of(i),
                DriveState::ReadyToSwitchOn
                    | DriveState::ReadyForOperation
                    | DriveState::OperationEnabled
            )
    })
    .map_err(|e| e.to_string())?;
    c.run_hz(hz, ref_hz).map_err(|e| e.to_string())?;
    c.wait_for_state(DriveState::OperationEnabled, STATE_TIMEOUT)
        .map_err(|e| e.to_string())?;
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
    fn note(&mut self, out: &Output, drive: u8, online: bool) -> Option<String> {
        match (online, self.since) {
            (false, None) => {
                out.note(&format!(
                    "  drive {drive} does not answer; waiting up to {} s for it",
                    OFFLINE_GRACE.as_secs()
                ));
                self.since = Some(Instant::now());
            }
            (false, Some(t)) if t.elapsed() > OFFLINE_GRACE => {
                return Some(format!(
                    "drive {drive} went offline while running and did not come back within {} s: check `ussctl status`, its wiring and power",
                    OFFLINE_GRACE.as_secs()
                ));
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

fn run_drive(
    bus: &Bus,
    out: &Output,
    drive: u8,
    hz: f32,
    ref_hz: f32,
    duration: Option<f64>,
) -> Result<(), Failure> {
    let duration = duration
        .map(|s| {
            Duration::try_from_secs_f64(s)
                .map_err(|_| format!("--for {s}: give a number of seconds >= 0"))
        })
        .transpose()?;
    let c = control(bus, drive)?;
    catch_signals()?;
    start_running(bus, &c, hz, ref_hz)?;
    out.note(&format!(
        "drive {drive}: running towards {hz} Hz (reference {ref_hz} Hz); {}",
        match duration {
            Some(d) => format!("stopping after {d:?}"),
            None => "Ctrl-C stops it".to_owned(),
        }
    ));

    let refresher = c.spawn_refresher(uss_client::DEFAULT_REFRESH);
    let start = Instant::now();
    let mut peak = 0.0f32;
    let mut last_note = Instant::now();
    let mut absence = Absence::default();
    let failure = loop {
        let i = match c.check() {
            Ok(i) => i,
            Err(
                e @ (ClientError::UssdGone { .. }
                | ClientError::UssdStopped { .. }
                | ClientError::LineDown { .. }),
            ) => {
                // Nothing to stop through: the drive's own telegram monitoring stops it.
                drop(refresher);
                return Err(format!("drive {drive}: {e}").into());
            }
            Err(ClientError::Tripped { latch, .. }) => {
                // Latched by ussd: the drive gets its stop command; leave it so.
                drop(refresher);
                return Err(format!(
                    "drive {drive} on {} tripped after {:.2} s: {latch} ({:.2} s ago); it gets {}, latched: run `ussctl run {drive}` again to re-arm it (OFF1, then ON)",
                    bus.name(),
                    start.elapsed().as_secs_f64(),
                    latch.ago.as_secs_f64(),
                    latch.command
                )
                .into());
            }
            Err(e) => break Some(e.to_string()),
        };
        let actual = c.inputs().actual_hz(ref_hz);
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
        std::thread::sleep(Duration::from_millis(10));
    };
    let refresh_result = refresher.stop();
    // Stop whatever happened: OFF1, and make sure the drive received it before leaving it
    // to the watchdog (whose safe command is OFF1 by default too).
    let last = stop_confirmed(&c)?;
    refresh_result.map_err(|e| e.to_string())?;
    if let Some(f) = failure {
        return Err(f.into());
    }
    let mut report = DriveReport::new(bus.name(), "run", &last, drive, ref_hz);
    report.peak_hz = Some(peak);
    out.show(&report, DriveReport::human)
}

/// Sends OFF1 and waits until the drive has answered two more exchanges, so it has received it.
fn stop_confirmed(c: &Controller) -> Result<PzdInput, Failure> {
    c.stop().map_err(|e| e.to_string())?;
    Ok(c.wait_for(Duration::from_secs(1), "OFF1 sent", {
        let start = c.inputs().latest().sequence;
        move |i| i.sequence >= start + 2
    })
    .map_err(|e| e.to_string())?)
}

/// How long an operator command may take to show in the drive's image: an offline drive is
/// probed only every `offline_probe_ms`.
const STOP_TIMEOUT: Duration = Duration::from_secs(3);

/// `stop`, `coast`, `quick-stop`: the operator's command through ussd, whoever controls the
/// drive; waits until each drive's image shows it went out.
fn stop(bus: &Bus, out: &Output, target: Target, command: StopCommand) -> Result<(), Failure> {
    let drives = match target.drive {
        Some(drive) => {
            bus.stop_drive(drive, command).map_err(|e| e.to_string())?;
            vec![drive]
        }
        None => bus.stop_all(command).map_err(|e| e.to_string())?,
    };
    let mut report = StopReport::new(bus.name(), command);
    for drive in drives {
        let last = bus
            .wait_stopped(drive, command, STOP_TIMEOUT)
            .map_err(|e| format!("drive {drive}: {command} sent, not yet confirmed: {e}"))?;
        report.push(drive, &last);
    }
    out.show(&report, StopReport::human)
}

fn ack(bus: &Bus, out: &Output, drive: u8) -> Result<(), Failure> {
    let c = control(bus, drive)?;
    if c.inputs().state() != DriveState::Fault {
        out.note(&format!(
            "drive {drive} shows no fault; acknowledging anyway"
        ));
    }
    c.acknowledge_fault(Duration::from_secs(1))
        .map_err(|e| e.to_string())?;
    let last = match c.wait_for(Duration::from_secs(1), "fault cleared", |i| {
        uss_client::state_of(i) != DriveState::Fault
    }) {
        Ok(i) => i,
        Err(ClientError::WaitTimeout { .. }) => {
            return Err(format!(
                "drive {drive}: the fault is still active after the acknowledge, so its cause persists: see `ussctl faults {drive}`"
            )
            .into());
        }
        Err(e) => return Err(e.to_string().into()),
    };
    out.show(
        &DriveReport::new(bus.name(), "ack", &last, drive, 50.0),
        DriveReport::human,
    )
}
