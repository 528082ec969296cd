//! `uss-sim`: simulated USS drives on a serial device or a pseudo-terminal, or a demo of a small
//! built-in master against them on the in-process virtual wire.

mod demo;

use clap::{ArgGroup, Parser};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use uss_drive_sim::serve::{Delivered, Delivery, Port, Pty, SerialDevice, serve};
use uss_drive_sim::spec::DriveSpec;
use uss_drive_sim::{Drive, SimBus};
use uss_protocol::{Baud, Timing};

#[derive(Debug, Parser)]
#[command(
    name = "uss-sim",
    version,
    about = "Simulated USS drives (MICROMASTER 4 / SINAMICS G120-like) on a serial device or a pseudo-terminal",
    group(ArgGroup::new("mode").required(true).args(["device", "pty", "demo", "completions", "man"]))
)]
// Command-line switches (pty, demo, man, echo), each its own yes or no.
#[allow(clippy::struct_excessive_bools)]
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
    /// jitter, eeprom-busy, busy, p2014, p2000, dword-error, drop, bcc, byte, truncate, late,
    /// wrong-addr, noise, late-by, unplug, hang, broadcast, family (micromaster4, g110, g120,
    /// simoreg, generic), fragile (see the guide, "Running `uss-sim`").
    #[arg(long = "drive", value_name = "ADDR[:key=value,...]")]
    drives: Vec<DriveSpec>,
    /// With --pty: also reach the pseudo-terminal by PATH, a symbolic link made to it (as socat's
    /// `link=`; a link a killed uss-sim left is replaced, any other file refused) and removed
    /// when uss-sim stops.
    #[arg(long, value_name = "PATH", requires = "pty")]
    link: Option<PathBuf>,
    /// With --pty: imitate a USB adapter's latency timer or a UART's FIFO trigger: bytes toward
    /// the master take their wire time and are handed over together every MS milliseconds.
    #[arg(long, value_name = "MS", requires = "pty", value_parser = parse_ms)]
    rx_tick: Option<Duration>,
    /// With --pty: hand each reply over in two halves MS milliseconds apart.
    #[arg(long, value_name = "MS", requires = "pty", value_parser = parse_ms)]
    split_reply: Option<Duration>,
    /// With --pty: hold each reply until MS milliseconds after it left the wire, then hand it
    /// over in one burst.
    #[arg(long, value_name = "MS", requires = "pty", value_parser = parse_ms)]
    late_reply: Option<Duration>,
    /// With --pty: send the master's request back to it before the reply, as a 2-wire
    /// adapter's echo does (ussd's `echo = true`).
    #[arg(long, requires = "pty")]
    echo: bool,
    /// Seed of the fault injector and response jitter (runs are repeatable).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM; the demo runs 8 s).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
    /// SIGUSR1 power-cycles every drive: off (silent) for this many milliseconds, then back
    /// with its EEPROM's values, in S1, its counters cleared.
    #[arg(long, value_name = "MS", default_value_t = 2000)]
    power_off_ms: u64,
    /// Print a completion script for SHELL (bash, zsh, fish, elvish, powershell) and exit.
    #[arg(long, value_name = "SHELL", exclusive = true)]
    completions: Option<clap_complete::Shell>,
    /// Print the manual page (roff, for man) and exit.
    #[arg(long, exclusive = true)]
    man: bool,
}

/// `--completions SHELL` / `--man`: generated from this command line's own definition.
fn print_docs(shell: Option<clap_complete::Shell>, man: bool) -> std::io::Result<bool> {
    let mut command = <Cli as clap::CommandFactory>::command();
    let mut out = std::io::stdout().lock();
    if let Some(shell) = shell {
        let name = command.get_name().to_owned();
        clap_complete::generate(shell, &mut command, name, &mut out);
        return Ok(true);
    }
    if man {
        clap_mangen::Man::new(command).render(&mut out)?;
        return Ok(true);
    }
    Ok(false)
}

fn parse_ms(s: &str) -> Result<Duration, String> {
    match s.parse::<f64>() {
        Ok(ms) if ms.is_finite() && (0.0..=10_000.0).contains(&ms) => {
            Ok(Duration::from_secs_f64(ms / 1000.0))
        }
        _ => Err(format!("'{s}' is not a time of 0..=10000 ms")),
    }
}

fn parse_baud(s: &str) -> Result<u32, String> {
    let baud: u32 = s.parse().map_err(|_| format!("'{s}' is not a baud rate"))?;
    Baud::new(baud).map(Baud::get).map_err(|e| e.to_string())
}

/// SIGINT and SIGTERM set the returned flag: uss-sim then stops and prints its summary.
fn stop_on_signals() -> std::io::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))?;
    }
    Ok(stop)
}

/// Why uss-sim did not run or stopped early.
#[derive(Debug, thiserror::Error)]
pub enum Failure {
    #[error("give at least one --drive ADDR[:key=value,...], e.g. --drive 1:pkw=4,pzd=2")]
    NoDrives,
    #[error(transparent)]
    Baud(#[from] uss_protocol::BaudError),
    #[error(transparent)]
    Bus(#[from] uss_drive_sim::BusError),
    #[error("cannot install signal handlers: {0}")]
    Signals(std::io::Error),
    #[error("cannot open {}: {source}", .path.display())]
    Open {
        path: PathBuf,
        source: serialport::Error,
    },
    #[error("cannot create a pseudo-terminal: {0}")]
    Pty(nix::Error),
    #[error("--link {}: {why}", .path.display())]
    Link { path: PathBuf, why: String },
    #[error("serving stopped: {0}")]
    Serve(std::io::Error),
    /// The demo's own master could not build a telegram.
    #[error("demo: {0}")]
    Demo(String),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // A reader that went away (`uss-sim --man | head`) is no error either.
    if print_docs(cli.completions, cli.man).unwrap_or(true) {
        return ExitCode::SUCCESS;
    }
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            eprintln!("uss-sim: {failure}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<(), Failure> {
    let timing = Timing::new(Baud::new(cli.baud)?);
    let mut specs = cli.drives;
    if specs.is_empty() {
        if !cli.demo {
            return Err(Failure::NoDrives);
        }
        specs = demo::default_drives();
    }
    let mut bus = SimBus::new(cli.seed);
    for spec in &specs {
        bus.add(spec.config)?;
        if let Some(plan) = bus.faults_mut(spec.config.address) {
            *plan = spec.faults.clone();
        }
    }
    let stop = stop_on_signals().map_err(Failure::Signals)?;
    let power = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, Arc::clone(&power))
        .map_err(Failure::Signals)?;
    bus.power_switch(power, Duration::from_millis(cli.power_off_ms));
    let duration = cli.duration.map(Duration::from_secs_f64);
    if cli.demo {
        return demo::run(
            bus,
            timing,
            duration.unwrap_or(Duration::from_secs(8)),
            &stop,
        );
    }
    if let Some(limit) = duration {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            std::thread::sleep(limit);
            stop.store(true, Ordering::Relaxed);
        });
    }
    let start = Instant::now();
    let result = if let Some(path) = &cli.device {
        let mut port = SerialDevice::open(path, cli.baud).map_err(|source| Failure::Open {
            path: path.clone(),
            source,
        })?;
        announce(&format!("DEVICE {}", path.display()), &bus, timing);
        serve_until_stopped(&mut port, &mut bus, timing, start, &stop)
    } else {
        let mut pty = Pty::open().map_err(Failure::Pty)?;
        let link = cli
            .link
            .as_deref()
            .map(|path| Link::make(path, pty.path()))
            .transpose()?;
        announce(&format!("PTY {}", pty.path().display()), &bus, timing);
        if let Some(link) = &link {
            println!("link {} -> {}", link.path.display(), pty.path().display());
        }
        let delivery = Delivery {
            tick: cli.rx_tick,
            split: cli.split_reply,
            late: cli.late_reply,
            echo: cli.echo,
        };
        if delivery.is_imitated() {
            imitate_in_real_time();
            let mut port = Delivered::new(pty, delivery, timing, start);
            serve_until_stopped(&mut port, &mut bus, timing, start, &stop)
        } else {
            serve_until_stopped(&mut pty, &mut bus, timing, start, &stop)
        }
    };
    print_summary(&bus);
    result
}

/// `--link`: a symbolic link to the pseudo-terminal, removed when uss-sim stops (dropped).
struct Link {
    path: PathBuf,
    to: PathBuf,
}

impl Link {
    fn make(path: &std::path::Path, to: &std::path::Path) -> Result<Self, Failure> {
        let refused = |why: String| Failure::Link {
            path: path.to_owned(),
            why,
        };
        match std::fs::symlink_metadata(path) {
            // A link left by a uss-sim that was killed: this user's, to a pty that is gone.
            // Any other link (another user's, a device's udev link, a live pty's) is not
            // uss-sim's to replace.
            Ok(m) if m.file_type().is_symlink() => {
                use std::os::unix::fs::MetadataExt as _;
                let to = std::fs::read_link(path).map_err(|e| refused(e.to_string()))?;
                // SAFETY: geteuid has no preconditions and cannot fail.
                let mine = m.uid() == unsafe { nix::libc::geteuid() };
                if !mine || !to.starts_with("/dev/pts/") || to.exists() {
                    return Err(refused(format!(
                        "is a link to {} that is not a pseudo-terminal gone with a uss-sim of \
                         this user: uss-sim replaces only such a link",
                        to.display()
                    )));
                }
                std::fs::remove_file(path).map_err(|e| refused(e.to_string()))?;
            }
            Ok(_) => {
                return Err(refused(
                    "exists and is no symbolic link: uss-sim replaces only a link".to_owned(),
                ));
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(refused(e.to_string())),
        }
        std::os::unix::fs::symlink(to, path).map_err(|e| refused(e.to_string()))?;
        Ok(Self {
            path: path.to_owned(),
            to: to.to_owned(),
        })
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        // Only while it is still this uss-sim's (another may have replaced it since).
        if std::fs::read_link(&self.path).is_ok_and(|to| to == self.to) {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// An imitated adapter hands bytes over on time only if nothing else runs first: ask for
/// `SCHED_FIFO` (below ussd's bus threads), and go on without it where it is refused.
fn imitate_in_real_time() {
    let param = nix::libc::sched_param { sched_priority: 10 };
    // SAFETY: sets this process's policy from a valid sched_param; no memory is handed over.
    let set = unsafe { nix::libc::sched_setscheduler(0, nix::libc::SCHED_FIFO, &raw const param) };
    if set != 0 {
        eprintln!(
            "uss-sim: no SCHED_FIFO ({}): the imitated delivery may be late under load",
            std::io::Error::last_os_error()
        );
    }
}

fn serve_until_stopped(
    port: &mut impl Port,
    bus: &mut SimBus,
    timing: Timing,
    start: Instant,
    stop: &AtomicBool,
) -> Result<(), Failure> {
    serve(port, bus, timing, start, stop).map_err(Failure::Serve)
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
        "drive {:2}: PKW {} PZD {}, {} {:6.2} Hz ZSW1 0x{:04X}; telegrams good {} rejected {} (BCC {} length {} start {})",
        c.address,
        c.layout.pkw.p2013(),
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
