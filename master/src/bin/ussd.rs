//! `ussd`: the USS bus master daemon. With no arguments it runs an embedded default (one
//! simulated bus, four drives at 115200 baud), so it works on any machine without hardware.

use clap::Parser;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use uss_master::config::{Config, ConfigError};

/// Log lines held for stdout while it does not take them; beyond, lines are dropped (counted).
const LOG_LINES_BUFFERED: usize = 16_384;
use uss_master::daemon::runtime::{self, RunOptions, RunningBus};
use uss_master::daemon::supervise::{Change, Notifier, Progress};

#[derive(Debug, Parser)]
#[command(
    name = "ussd",
    version,
    about = "Real-time USS bus master: polls USS drives on one or more RS485 buses"
)]
struct Cli {
    /// Configuration file (TOML). Without it ussd runs its embedded default: one simulated bus.
    #[arg(long, value_name = "FILE", conflicts_with = "check_config")]
    config: Option<PathBuf>,
    /// Validate a configuration file, print the effective configuration and exit.
    #[arg(long, value_name = "FILE")]
    check_config: Option<PathBuf>,
    /// The embedded default's bus name (without --config): e.g. to run it beside another ussd.
    #[arg(long, value_name = "NAME", conflicts_with_all = ["config", "check_config"], default_value = "bus0")]
    bus: String,
    /// Exit with an error unless every bus thread gets its CPU, real-time priority and memory lock.
    #[arg(long)]
    require_rt: bool,
    /// Seconds between live summaries.
    #[arg(long, value_name = "SECONDS", default_value_t = 5.0)]
    summary_every: f64,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
    /// Measure whether this machine holds the bus timing, then exit: wake-ups every 1 ms as each
    /// bus thread would run them (its CPU, real-time priority, memory lock), the latency held
    /// against USS's start pause, residual time and a 31-drive cycle at each baud rate, and what
    /// usually breaks a deployment, with how to fix it. Exits 1 when a bus's timing does not hold.
    #[arg(long, conflicts_with = "check_config")]
    qualify: bool,
    /// With --qualify: seconds to measure.
    #[arg(long, value_name = "SECONDS", default_value_t = 30.0)]
    seconds: f64,
    /// With --qualify: an SVG picture of the latency histogram and each bus's start pause.
    #[arg(long, value_name = "FILE.svg", requires = "qualify")]
    plot: Option<PathBuf>,
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

/// SIGINT and SIGTERM set the returned flag: ussd then stops cleanly.
fn stop_on_signals() -> std::io::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))?;
    }
    Ok(stop)
}

fn seconds(name: &str, value: f64) -> Result<Duration, String> {
    Duration::try_from_secs_f64(value)
        .ok()
        .filter(|d| !d.is_zero())
        .ok_or_else(|| format!("--{name} {value}: give a positive number of seconds"))
}

/// Why ussd did not run, or did not stop cleanly.
#[derive(Debug, thiserror::Error)]
enum Failure {
    /// A command-line value that cannot be used.
    #[error("{0}")]
    Usage(String),
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("cannot install signal handlers: {0}")]
    Signals(std::io::Error),
    /// The shared memory's root directory cannot be made what the configuration asks.
    #[error("{0}")]
    Access(#[from] uss_master::daemon::access::AccessError),
    #[error(transparent)]
    Start(#[from] runtime::StartError),
    /// Buses that did not stop cleanly (a failed line, a hung bus thread).
    #[error("{}", .0.join("; "))]
    Stop(Vec<String>),
}

impl Failure {
    /// 2 for what the user gave (command line, configuration), 1 for what happened.
    fn exit_code(&self) -> u8 {
        match self {
            Self::Usage(_) | Self::Config(_) => 2,
            Self::Signals(_) | Self::Access(_) | Self::Start(_) | Self::Stop(_) => 1,
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // A reader that went away (`ussd --man | head`) is no error either.
    if print_docs(cli.completions, cli.man).unwrap_or(true) {
        return ExitCode::SUCCESS;
    }
    if let Some(path) = &cli.check_config {
        return match Config::load(path) {
            Ok(config) => {
                for warning in config.warnings() {
                    eprintln!("ussd: warning: {}: {warning}", path.display());
                }
                // A reader that went away early (`ussd --check-config F | head`) is no error.
                let _ = std::io::stdout().write_all(config.to_toml().as_bytes());
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("ussd: {e}");
                ExitCode::from(2)
            }
        };
    }
    if cli.qualify {
        return qualify(&cli);
    }
    // The log never blocks a thread that logs: a worker writes stdout, and lines that do not
    // fit its buffer while stdout is stuck (a full pipe, a stalled journald) are dropped and
    // counted, so the heartbeat and the stops go on (issue 21).
    let (writer, flush_at_exit) = tracing_appender::non_blocking::NonBlockingBuilder::default()
        .lossy(true)
        .buffered_lines_limit(LOG_LINES_BUFFERED)
        .thread_name("ussd-log")
        .finish(std::io::stdout());
    let dropped = writer.error_counter();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(writer)
        .with_ansi(false)
        .init();
    let code = match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            // Once where the log and the errors go to one place (a terminal, the journal):
            // the log has it for a log file of its own, stderr for the one who ran it.
            if !stdout_is_stderr() {
                tracing::error!("{failure}");
            }
            eprintln!("ussd: {failure}");
            ExitCode::from(failure.exit_code())
        }
    };
    if dropped.dropped_lines() > 0 {
        eprintln!(
            "ussd: {} log lines were dropped while stdout could not take them",
            dropped.dropped_lines()
        );
    }
    drop(flush_at_exit);
    code
}

/// No `--config`: the embedded default (one simulated bus), on bus `bus`.
#[cfg(feature = "sim")]
fn embedded_default(bus: &str) -> Result<Config, Failure> {
    tracing::info!("no --config given: running the embedded default (one simulated bus)");
    let mut config = Config::embedded_default();
    config.buses[0].name = uss_shm_types::BusName::new(bus)
        .map(|_| bus.to_owned())
        .map_err(|e| Failure::Usage(format!("--bus {bus}: {e}")))?;
    Ok(config)
}

/// A build without the simulator has no embedded default.
#[cfg(not(feature = "sim"))]
fn embedded_default(_bus: &str) -> Result<Config, Failure> {
    Err(Failure::Usage(
        "this ussd was built without the simulated bus (the `sim` feature), so it has no \
         embedded default: give --config FILE"
            .to_owned(),
    ))
}

/// `--qualify`: measure, report each bus, plot; exit 1 when a bus's timing does not hold.
fn qualify(cli: &Cli) -> ExitCode {
    use uss_master::daemon::qualify;
    let config = match &cli.config {
        Some(path) => Config::load(path).map_err(Failure::from),
        None => embedded_default(&cli.bus),
    };
    let config = match config {
        Ok(c) => c,
        Err(failure) => {
            eprintln!("ussd: {failure}");
            return ExitCode::from(failure.exit_code());
        }
    };
    let duration = match seconds("seconds", cli.seconds) {
        Ok(d) => d,
        Err(e) => {
            eprintln!("ussd: {e}");
            return ExitCode::from(2);
        }
    };
    println!(
        "ussd --qualify: measuring for {:.0} s (what cyclictest -m -i 1000 measures, at each bus's \
         priority and CPU)...",
        duration.as_secs_f64()
    );
    let measured = measuring(&config, duration);
    let mut holds = measured.len() == config.buses.len();
    if !holds {
        eprintln!(
            "ussd: a measuring thread could not run: only {} of {} buses measured",
            measured.len(),
            config.buses.len()
        );
    }
    for m in &measured {
        let Some(bus) = config.buses.iter().find(|b| b.name == m.bus) else {
            continue;
        };
        let checks = qualify::checks(bus);
        print!("{}", qualify::report(m, &checks, duration.as_secs_f64()));
        holds &= m.at_own_rate().is_some_and(|at| at.holds());
    }
    if let Some(path) = &cli.plot {
        match qualify::plot(path, &measured) {
            Ok(()) => println!("plot: {}", path.display()),
            Err(e) => {
                eprintln!("ussd: the plot: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    if holds {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

/// [`qualify::measure`], with a progress bar on standard error while it runs when that is a
/// terminal (a minute of silence looks hung); nothing in a pipe or a log.
fn measuring(config: &Config, duration: Duration) -> Vec<uss_master::daemon::qualify::Measured> {
    use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
    use std::io::IsTerminal as _;
    if !std::io::stderr().is_terminal() {
        return uss_master::daemon::qualify::measure(config, duration);
    }
    let bar = ProgressBar::with_draw_target(
        Some(u64::try_from(duration.as_millis()).unwrap_or(u64::MAX)),
        ProgressDrawTarget::stderr(),
    );
    bar.set_style(
        ProgressStyle::with_template("measuring {bar:40} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let started = Instant::now();
    std::thread::scope(|scope| {
        let measuring = scope.spawn(|| uss_master::daemon::qualify::measure(config, duration));
        while !measuring.is_finished() {
            let done = started.elapsed().min(duration);
            bar.set_position(u64::try_from(done.as_millis()).unwrap_or(u64::MAX));
            bar.set_message(format!(
                "{:.0} of {:.0} s",
                done.as_secs_f64(),
                duration.as_secs_f64()
            ));
            std::thread::sleep(Duration::from_millis(200));
        }
        bar.finish_and_clear();
        measuring.join().unwrap_or_default()
    })
}

/// Whether standard output and standard error are the same file (a terminal, one pipe).
fn stdout_is_stderr() -> bool {
    use std::os::fd::AsFd as _;
    let id = |fd: std::os::fd::BorrowedFd<'_>| {
        nix::sys::stat::fstat(fd)
            .ok()
            .map(|s| (s.st_dev, s.st_ino, s.st_rdev))
    };
    let (out, err) = (id(std::io::stdout().as_fd()), id(std::io::stderr().as_fd()));
    out.is_some() && out == err
}

fn run(cli: &Cli) -> Result<(), Failure> {
    let config = if let Some(path) = &cli.config {
        Config::load(path)?
    } else {
        embedded_default(&cli.bus)?
    };
    let options = RunOptions {
        require_rt: cli.require_rt,
        summary_every: seconds("summary-every", cli.summary_every).map_err(Failure::Usage)?,
    };
    let duration = cli
        .duration
        .map(|d| seconds("duration", d))
        .transpose()
        .map_err(Failure::Usage)?;
    let stop = stop_on_signals().map_err(Failure::Signals)?;
    // A bus another ussd serves is refused before anything is made or said; a root other
    // ussd processes use keeps who may use it.
    // Held until this ussd's nodes exist: a ussd starting beside it waits, then sees them.
    let start_lock = uss_master::daemon::access::StartLock::take()?;
    let running = uss_master::daemon::access::running();
    if let Some(r) = running
        .iter()
        .find(|r| config.buses.iter().any(|b| b.name.as_str() == r.bus))
    {
        return Err(Failure::Start(runtime::StartError::Ipc(
            uss_master::daemon::ipc::IpcError::Served {
                bus: r.bus.clone(),
                pid: Some(r.pid),
            },
        )));
    }
    // Who may use the services, before any exists.
    let access = uss_master::daemon::access::prepare(config.access_group.as_deref(), &running)?;
    tracing::info!("{access}");
    let buses = runtime::start(&config.buses, options)?;
    drop(start_lock);
    for b in &buses {
        tracing::info!(bus = %b.name, drives = b.handle.drives().len(), "polling");
    }
    let started = Instant::now();
    let mut notifier = Notifier::from_env(started);
    notifier.ready(&status_line(&buses));
    if let Some(period) = notifier.watchdog() {
        let bounds: Vec<String> = buses
            .iter()
            .map(|b| format!("{} {:.1} s", b.name, b.stall_bound.as_secs_f64()))
            .collect();
        tracing::info!(
            "systemd watchdog every {:.1} s: keep-alives only while every bus thread makes progress (hung after {})",
            period.as_secs_f64(),
            bounds.join(", ")
        );
    }
    let bounds: Vec<Duration> = buses.iter().map(|b| b.stall_bound).collect();
    let limits: Vec<Option<Duration>> = buses.iter().map(|b| b.line_down_limit).collect();
    let mut progress = Progress::new(&bounds, &limits, &counts(&buses), started);
    let mut line_failed = false;
    let mut next_cleanup = Duration::from_secs(1);
    let mut left_behind = LeftBehind::default();
    let mut next_status = Duration::from_secs(5);
    while !stop.load(Ordering::Relaxed) && duration.is_none_or(|d| started.elapsed() < d) {
        if let Some(b) = buses.iter().find(|b| b.has_failed()) {
            // A bus that cannot go on (a simulated wire failed): stop, and let the supervisor
            // (systemd Restart=on-failure) bring ussd back.
            tracing::error!(bus = %b.name, "the bus thread ended: its line failed");
            line_failed = true;
            break;
        }
        let now = Instant::now();
        let down: Vec<bool> = buses.iter().map(|b| b.handle.is_line_down()).collect();
        for change in progress.check(&counts(&buses), &down, now) {
            report(&buses, change, notifier.watchdog().is_some());
        }
        notifier.keep_alive(now, progress.healthy());
        if started.elapsed() >= next_cleanup {
            next_cleanup += Duration::from_secs(1);
            // One root for every bus of this process: the first bus looks for them all.
            if let Some(cleanup) = buses.first().and_then(RunningBus::cleanup_dead_nodes) {
                left_behind.report(&cleanup);
            }
        }
        if started.elapsed() >= next_status {
            next_status += Duration::from_secs(5);
            notifier.status(&status_line(&buses));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    tracing::info!(
        "stopping: pending parameter jobs end with 'shutdown', each drive gets its safe command (or the stronger stop it has) once"
    );
    notifier
        .stopping("stopping: each drive gets its safe command (or the stronger stop it has) once");
    let mut failed = Vec::new();
    for b in buses {
        let name = b.name.clone();
        if let Err(e) = b.stop() {
            failed.push(format!("bus {name}: {e}"));
        }
    }
    if line_failed && failed.is_empty() {
        failed.push("a bus line failed".to_owned());
    }
    if failed.is_empty() {
        Ok(())
    } else {
        Err(Failure::Stop(failed))
    }
}

/// Every bus thread's progress counter, in the order of `buses`.
fn counts(buses: &[RunningBus]) -> Vec<u64> {
    buses.iter().map(RunningBus::progress).collect()
}

/// Logs a bus thread that hangs or moves again, or a line down past its limit.
fn report(buses: &[RunningBus], change: Change, watchdog: bool) {
    let consequence = if watchdog {
        "ussd withholds systemd's watchdog keep-alive, so systemd restarts it"
    } else {
        "no systemd watchdog is set to restart ussd; restart it by hand"
    };
    match change {
        Change::Hung { bus, for_ } => {
            tracing::error!(
                bus = %buses[bus].name,
                "bus thread hangs: no progress for {:.1} s (a wedged serial driver, or a bug); its drives are not polled and their telegram monitoring (P2014) stops them; {consequence}",
                for_.as_secs_f64()
            );
        }
        Change::Moving { bus, for_ } => {
            tracing::warn!(
                bus = %buses[bus].name,
                "bus thread moves again after hanging for {:.1} s",
                for_.as_secs_f64()
            );
        }
        Change::LineDownTooLong { bus, for_ } => {
            tracing::error!(
                bus = %buses[bus].name,
                "line down for {:.1} s (line_down_limit_ms), still reopened by its configured path; {consequence}",
                for_.as_secs_f64()
            );
        }
    }
}

/// One line for `systemctl status`: each bus, its drives online and whether its line is up.
fn status_line(buses: &[RunningBus]) -> String {
    let parts: Vec<String> = buses
        .iter()
        .map(|b| {
            let stats = b.handle.stats();
            let online = stats.drives.iter().filter(|d| d.online).count();
            let line = if b.handle.is_line_down() {
                ", line down"
            } else {
                ""
            };
            format!(
                "bus {}: {online}/{} drives online{line}",
                b.name,
                stats.drives.len()
            )
        })
        .collect();
    parts.join("; ")
}

/// The dead client nodes a cleanup left, from one look to the next.
#[derive(Default)]
struct LeftBehind {
    /// Left by the last look.
    last: std::collections::HashSet<u128>,
    /// Named in the log already (those still left).
    named: std::collections::HashSet<u128>,
}

impl LeftBehind {
    /// Logs what a look for dead client nodes removed, and names once each node left on two
    /// looks in a row (on one, another process may have been cleaning it just then).
    fn report(&mut self, cleanup: &uss_master::daemon::runtime::Cleanup) {
        if cleanup.removed > 0 {
            tracing::info!(
                nodes = cleanup.removed,
                "cleaned up after dead client processes"
            );
        }
        let now: std::collections::HashSet<u128> = cleanup.left.iter().map(|&(id, _)| id).collect();
        for &(id, pid) in &cleanup.left {
            if !self.last.contains(&id) || !self.named.insert(id) {
                continue;
            }
            match pid {
                // iceoryx2 makes a node's monitor first and removes it last.
                None => tracing::warn!(
                    node = id,
                    "could not remove the node a dead client process left half made or half dropped (no details, no ports): remove {}/nodes/*{id}* while no uss-rt process runs",
                    uss_shm_types::service::root().display()
                ),
                Some(pid) => tracing::warn!(
                    node = id,
                    pid,
                    "could not remove the node of dead process {pid}: its ports stay in the bus's services (a process of another user, whose files ussd may not remove?)"
                ),
            }
        }
        self.named.retain(|id| now.contains(id));
        self.last = now;
    }
}
