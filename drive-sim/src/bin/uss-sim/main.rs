//! `uss-sim`: simulated USS drives on a serial device or a pseudo-terminal, or a demo of a small
//! built-in master against them on the in-process virtual wire.

mod demo;

use clap::{ArgGroup, Parser};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use uss_drive_sim::serve::{Port, Pty, SerialDevice, serve};
use uss_drive_sim::spec::DriveSpec;
use uss_drive_sim::{Drive, SimBus};
use uss_protocol::{Baud, Timing};

#[derive(Debug, Parser)]
#[command(
    name = "uss-sim",
    version,
    about = "Simulated USS drives (MICROMASTER 4 / SINAMICS G120-like) on a serial device or a pseudo-terminal",
    group(ArgGroup::new("mode").required(true).args(["device", "pty", "demo"]))
)]
struct Cli {
    /// Serve this serial device (8E1, opened exclusively), e.g. /dev/ttyUSB0.
    #[arg(long, value_name = "PATH")]
    device: Option<PathBuf>,
    /// Create a pseudo-terminal pair, print `PTY <path>` for the master to open, and serve it.
    #[arg(long)]
    pty: bool,
    /// Run a small built-in master against the drives on the in-process virtual wire and print
    /// what it sees (no hardware, no second process).
    #[arg(long)]
    demo: bool,
    /// Baud rate of the bus.
    #[arg(long, default_value_t = 19200, value_parser = parse_baud)]
    baud: u32,
    /// A drive on the bus, repeatable: ADDR or ADDR:key=value,... with keys pkw, pzd, delay,
    /// jitter, eeprom-busy, busy, p2014, dword-error, drop, bcc, byte, truncate, late, wrong-addr,
    /// noise, late-by, unplug (see the README).
    #[arg(long = "drive", value_name = "ADDR[:key=value,...]")]
    drives: Vec<DriveSpec>,
    /// Seed of the fault injector and response jitter (runs are repeatable).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM; the demo runs 8 s).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
}

fn parse_baud(s: &str) -> Result<u32, String> {
    let baud: u32 = s.parse().map_err(|_| format!("'{s}' is not a baud rate"))?;
    Baud::new(baud).map(Baud::get).map_err(|e| e.to_string())
}

static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: nix::libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

fn install_signal_handlers() -> nix::Result<()> {
    use nix::sys::signal::{SaFlags, SigAction, SigHandler, SigSet, Signal, sigaction};
    let action = SigAction::new(
        SigHandler::Handler(on_signal),
        SaFlags::empty(),
        SigSet::empty(),
    );
    for signal in [Signal::SIGINT, Signal::SIGTERM] {
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        unsafe { sigaction(signal, &action) }?;
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("uss-sim: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<(), String> {
    let timing = Timing::new(Baud::new(cli.baud).map_err(|e| e.to_string())?);
    let mut specs = cli.drives;
    if specs.is_empty() {
        if !cli.demo {
            return Err(
                "give at least one --drive ADDR[:key=value,...], e.g. --drive 1:pkw=4,pzd=2".into(),
            );
        }
        specs = demo::default_drives();
    }
    let mut bus = SimBus::new(cli.seed);
    for spec in &specs {
        bus.add(spec.config).map_err(|e| e.to_string())?;
        if let Some(plan) = bus.faults_mut(spec.config.address) {
            *plan = spec.faults.clone();
        }
    }
    install_signal_handlers().map_err(|e| format!("cannot install signal handlers: {e}"))?;
    let duration = cli.duration.map(Duration::from_secs_f64);
    if cli.demo {
        return demo::run(
            bus,
            timing,
            duration.unwrap_or(Duration::from_secs(8)),
            &STOP,
        );
    }
    if let Some(limit) = duration {
        std::thread::spawn(move || {
            std::thread::sleep(limit);
            STOP.store(true, Ordering::Relaxed);
        });
    }
    let start = Instant::now();
    let result = if let Some(path) = &cli.device {
        let mut port = SerialDevice::open(path, cli.baud)
            .map_err(|e| format!("cannot open {}: {e}", path.display()))?;
        announce(&format!("DEVICE {}", path.display()), &bus, timing);
        serve_until_stopped(&mut port, &mut bus, timing, start)
    } else {
        let mut pty = Pty::open().map_err(|e| format!("cannot create a pseudo-terminal: {e}"))?;
        announce(&format!("PTY {}", pty.path().display()), &bus, timing);
        serve_until_stopped(&mut pty, &mut bus, timing, start)
    };
    print_summary(&bus);
    result
}

fn serve_until_stopped(
    port: &mut impl Port,
    bus: &mut SimBus,
    timing: Timing,
    start: Instant,
) -> Result<(), String> {
    serve(port, bus, timing, start, &STOP).map_err(|e| format!("serving stopped: {e}"))
}

/// The first line is machine-readable (`PTY /dev/pts/N`); tests and scripts wait for it.
fn announce(first_line: &str, bus: &SimBus, timing: Timing) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{first_line}");
    let _ = writeln!(
        out,
        "serving {} drive(s) at {} baud (8E1); start pause {:?}; stop with Ctrl-C",
        bus.drives().count(),
        timing.baud(),
        timing.start_pause()
    );
    for d in bus.drives() {
        let _ = writeln!(out, "  {}", describe(d));
    }
    let _ = out.flush();
}

fn describe(d: &Drive) -> String {
    let c = d.config();
    let n = d.counters();
    format!(
        "drive {:2}: PKW {:?} PZD {}, {:?} {:6.2} Hz ZSW1 0x{:04X}; telegrams good {} rejected {} (BCC {} length {} start {})",
        c.address,
        c.layout.pkw,
        c.layout.pzd.get(),
        d.state(),
        d.frequency_hz(),
        d.zsw1().bits(),
        n.good,
        n.rejected,
        n.bcc,
        n.length,
        n.start
    )
}

fn print_summary(bus: &SimBus) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "stopped; final state:");
    for d in bus.drives() {
        let _ = writeln!(out, "  {}", describe(d));
    }
    let _ = out.flush();
}
