//! `ussctl`: look at and operate the drives of a bus that ussd runs. Short, predictable
//! subcommands in the manner of the `ethercat` tool of `EtherCAT` masters, human output by default,
//! `--json` for machines. Errors go to stderr, say what to do, and exit with 1 (2 for usage
//! errors).

mod cli;
mod commands;
mod decode;
mod failure;
mod interface;
mod pcapng;
mod plot;
mod report;

use clap::Parser;
use cli::{Cli, Command, ParamCommand};
use core::time::Duration;
use serde::Serialize;
use std::io::Write as _;
use std::process::ExitCode;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicI32, AtomicUsize, Ordering};
use uss_client::{Bus, StopCommand};

/// SIGINT, SIGTERM and SIGHUP (a closed terminal or ssh session) received once
/// [`catch_signals`] ran, and the last of them.
static SIGNALS: AtomicUsize = AtomicUsize::new(0);
static LAST_SIGNAL: AtomicI32 = AtomicI32::new(0);

/// `watch`, `run`, `restore`, ... end cleanly on SIGINT, SIGTERM or SIGHUP (`run` stops the
/// drive first, `restore` puts back what it raised): a thread counts them.
pub(crate) fn catch_signals() -> Result<(), Failure> {
    static CAUGHT: OnceLock<Result<(), String>> = OnceLock::new();
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let caught = CAUGHT.get_or_init(|| {
        let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])
            .map_err(|e| e.to_string())?;
        std::thread::Builder::new()
            .name("signals".into())
            .spawn(move || {
                for signal in signals.forever() {
                    LAST_SIGNAL.store(signal, Ordering::Relaxed);
                    SIGNALS.fetch_add(1, Ordering::Relaxed);
                }
            })
            .map(drop)
            .map_err(|e| e.to_string())
    });
    caught.clone().map_err(|e| Failure::Signal {
        signal: SIGINT,
        source: std::io::Error::other(e),
    })
}

/// Whether a SIGINT, SIGTERM or SIGHUP came.
pub(crate) fn stopped() -> bool {
    signals() > 0
}

/// How many SIGINT, SIGTERM and SIGHUP came.
pub(crate) fn signals() -> usize {
    SIGNALS.load(Ordering::Relaxed)
}

/// ussctl's signals (SIGINT, SIGTERM, SIGHUP) as the library's cancel of a long call (a
/// restore, a scan).
pub(crate) struct Signals;

impl uss_client::cancel::Cancel for Signals {
    fn asked(&self) -> usize {
        signals()
    }

    fn why(&self) -> &'static str {
        signal_name()
    }
}

/// The last signal that came, as a report names it: "Ctrl-C", "SIGTERM", "SIGHUP".
pub(crate) fn signal_name() -> &'static str {
    match LAST_SIGNAL.load(Ordering::Relaxed) {
        signal_hook::consts::SIGTERM => "SIGTERM",
        signal_hook::consts::SIGHUP => "SIGHUP",
        _ => "Ctrl-C",
    }
}

pub(crate) use failure::Failure;

/// When this ussctl was asked to act: the moment its process started (`CLOCK_MONOTONIC`, the
/// kernel's start time, not `main()`'s: loading and start-up take milliseconds, tens of them on
/// a loaded machine). `run` and `ack` re-arm only the latches older than that, never an
/// operator's stop that came while it was starting (docs/SAFETY.md, REARM).
pub(crate) fn asked_ns() -> Result<u64, Failure> {
    uss_client::process_start_ns().map_err(Failure::StartTime)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // iceoryx2 reports every refused open at warning level with a debug dump; ussctl explains
    // errors itself. IOX2_LOG_LEVEL still overrides.
    uss_client::quiet_iceoryx2_logs();
    match run(&cli) {
        Ok(()) | Err(Failure::Closed) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("ussctl: {e}");
            // `param diff`, like diff(1): 1 for differences, 2 for trouble.
            let diff = matches!(&cli.command, Command::Param(ParamCommand::Diff(_)));
            if diff && !matches!(e, Failure::Differ { .. }) {
                ExitCode::from(2)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

/// The commands that need no bus: completions and the man page (generated from this command
/// line's own definition), `scan` (a line ussd does not serve) and `top` (which waits for a
/// ussd that is not there yet, and follows one that goes).
fn run_without_bus(cli: &Cli) -> Option<Result<(), Failure>> {
    let out = Output { json: cli.json };
    match &cli.command {
        Command::Scan(scan) => Some(scan.run(&out)),
        Command::Top(top) => Some(top.run(&cli.bus)),
        Command::Completions { shell } => {
            let mut command = <Cli as clap::CommandFactory>::command();
            let mut out = Vec::new();
            clap_complete::generate(*shell, &mut command, "ussctl", &mut out);
            Some(write_out(&String::from_utf8_lossy(&out)))
        }
        Command::Schema { report } => Some(interface::print_schema(report.as_deref())),
        Command::Man => {
            let mut out = Vec::new();
            Some(
                clap_mangen::Man::new(<Cli as clap::CommandFactory>::command())
                    .render(&mut out)
                    .map_err(Failure::Output)
                    .and_then(|()| write_out(&String::from_utf8_lossy(&out))),
            )
        }
        _ => None,
    }
}

fn run(cli: &Cli) -> Result<(), Failure> {
    if let Some(done) = run_without_bus(cli) {
        return done;
    }
    let out = Output { json: cli.json };
    // A stop goes out before anything else, on its own path: it needs no open bus.
    match &cli.command {
        Command::Stop(target) => return target.run(&cli.bus, &out, StopCommand::Off1),
        Command::Coast(target) => return target.run(&cli.bus, &out, StopCommand::Off2),
        Command::QuickStop(target) => return target.run(&cli.bus, &out, StopCommand::Off3),
        _ => {}
    }
    let mut bus = Bus::open_as(&cli.bus, "ussctl")?;
    if let Some(t) = cli.timeout {
        let t = Duration::try_from_secs_f64(t)
            .ok()
            .filter(|d| !d.is_zero())
            .ok_or_else(|| {
                Failure::Usage(format!("--timeout {t}: give a positive number of seconds"))
            })?;
        bus.set_answer_timeout(Some(t));
    }
    match &cli.command {
        Command::Status => commands::status::status(&bus, &out),
        Command::Stats => commands::status::stats(&bus, &out),
        Command::Watch(c) => c.run(&bus, &out),
        Command::Capture(c) => c.run(&bus, &out),
        Command::Trace(c) => c.run(&bus, &out),
        Command::Param(c) => c.run(&bus, &out),
        Command::Run(c) => c.run(&bus, &out),
        Command::Ack(c) => c.run(&bus, &out),
        Command::Faults(c) => c.run(&bus, &out),
        Command::Scan(_)
        | Command::Completions { .. }
        | Command::Man
        | Command::Schema { .. }
        | Command::Top(_)
        | Command::Stop(_)
        | Command::Coast(_)
        | Command::QuickStop(_) => {
            unreachable!("handled before the bus is opened")
        }
    }
}

/// Writes `text` to stdout as it is; a reader that went away (`| head`) ends ussctl quietly.
pub(crate) fn write_out(text: &str) -> Result<(), Failure> {
    let mut stdout = std::io::stdout().lock();
    match stdout
        .write_all(text.as_bytes())
        .and_then(|()| stdout.flush())
    {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(Failure::Closed),
        Err(e) => Err(Failure::Output(e)),
    }
}

/// Human or JSON output.
pub(crate) struct Output {
    json: bool,
}

impl Output {
    pub(crate) fn show<T: Serialize>(
        &self,
        report: &T,
        human: impl Fn(&T) -> String,
    ) -> Result<(), Failure> {
        let mut text = if self.json {
            serde_json::to_string(&interface::Versioned {
                v: interface::VERSION,
                report,
            })?
        } else {
            human(report)
        };
        if !text.ends_with('\n') {
            text.push('\n');
        }
        write_out(&text)
    }

    /// Progress for people (nothing with `--json`); a closed output does not stop the work.
    pub(crate) fn note(&self, text: &str) {
        if !self.json {
            let _ = writeln!(std::io::stdout().lock(), "{text}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    /// Every subcommand and argument of `cmd` (but clap's own --help and --version) without
    /// help text, by path.
    fn undocumented(cmd: &clap::Command, path: &str, out: &mut Vec<String>) {
        if cmd.get_about().is_none() {
            out.push(path.to_owned());
        }
        for a in cmd.get_arguments() {
            let own = !matches!(a.get_id().as_str(), "help" | "version");
            if own && a.get_help().is_none() && !a.is_hide_set() {
                out.push(format!("{path} {}", a.get_id()));
            }
        }
        for sub in cmd.get_subcommands() {
            undocumented(sub, &format!("{path} {}", sub.get_name()), out);
        }
    }

    #[test]
    fn every_subcommand_and_argument_has_help_text() {
        let cmd = Cli::command();
        cmd.clone().debug_assert();
        let mut missing = Vec::new();
        undocumented(&cmd, "ussctl", &mut missing);
        assert!(missing.is_empty(), "without help text: {missing:?}");
    }
}
