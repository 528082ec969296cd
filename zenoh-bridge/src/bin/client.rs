//! `uss-zenoh-client`: a small remote client of uss-zenoh for another host (an HMI, a laptop):
//! follow a drive's inputs, read or write a parameter, watch a bus's liveliness. It is also how
//! the tests look at the bridge from the other side of a network boundary.

use clap::{Parser, Subcommand};
use core::time::Duration;
use std::process::ExitCode;
use std::time::Instant;
use zenoh::sample::SampleKind;
use zenoh::{Config, Wait};

#[derive(Debug, Parser)]
#[command(
    name = "uss-zenoh-client",
    version,
    about = "Read what uss-zenoh publishes, from any host"
)]
struct Cli {
    /// Connect to this Zenoh endpoint (uss-zenoh's --listen, or a router), e.g. tcp/10.0.0.2:7447.
    #[arg(long, value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// A Zenoh configuration file instead (JSON5 or YAML).
    #[arg(long, value_name = "FILE")]
    zenoh_config: Option<std::path::PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Print each sample on KEY (e.g. uss/site/bus0/drive/1/in) as one line of JSON.
    Sub {
        key: String,
        /// Stop after this many samples.
        #[arg(long, default_value_t = 1)]
        count: u64,
        /// Give up after this many seconds.
        #[arg(long, default_value_t = 10.0)]
        timeout: f64,
    },
    /// Query KEY (e.g. uss/site/bus0/drive/1/param/P1082); with --value, write that value.
    Get {
        key: String,
        /// The value to write (the query's payload), e.g. 45.0.
        #[arg(long)]
        value: Option<String>,
        /// Seconds to wait for the answer.
        #[arg(long, default_value_t = 10.0)]
        timeout: f64,
    },
    /// Print `+ KEY` when a liveliness token appears, `- KEY` when it goes, with the time in ms
    /// since the client started.
    Alive {
        key: String,
        /// Stop after this many changes.
        #[arg(long, default_value_t = 1)]
        count: u64,
        /// Give up after this many seconds.
        #[arg(long, default_value_t = 30.0)]
        timeout: f64,
    },
}

fn seconds(s: f64) -> Result<Duration, String> {
    Duration::try_from_secs_f64(s).map_err(|_| format!("{s}: give a number of seconds"))
}

fn config(cli: &Cli) -> Result<Config, String> {
    let mut config = match &cli.zenoh_config {
        Some(path) => Config::from_file(path).map_err(|e| format!("{}: {e}", path.display()))?,
        None => Config::default(),
    };
    if !cli.connect.is_empty() {
        let list = serde_json::to_string(&cli.connect).unwrap_or_default();
        config
            .insert_json5("connect/endpoints", &list)
            .and_then(|()| config.insert_json5("mode", r#""client""#))
            .and_then(|()| config.insert_json5("scouting/multicast/enabled", "false"))
            .map_err(|e| format!("--connect {:?}: {e}", cli.connect))?;
    }
    Ok(config)
}

fn run(cli: &Cli) -> Result<(), String> {
    let session = zenoh::open(config(cli)?)
        .wait()
        .map_err(|e| format!("cannot open the Zenoh session: {e}"))?;
    let start = Instant::now();
    match &cli.command {
        Command::Sub {
            key,
            count,
            timeout,
        } => {
            let deadline = start + seconds(*timeout)?;
            let sub = session
                .declare_subscriber(key)
                .wait()
                .map_err(|e| format!("{key}: {e}"))?;
            for _ in 0..*count {
                let left = deadline.saturating_duration_since(Instant::now());
                match sub.recv_timeout(left) {
                    Ok(Some(s)) => println!("{}", s.payload().try_to_string().unwrap_or_default()),
                    _ => return Err(format!("{key}: nothing within {timeout} s")),
                }
            }
        }
        Command::Get {
            key,
            value,
            timeout,
        } => {
            let mut get = session.get(key).timeout(seconds(*timeout)?);
            if let Some(v) = value {
                get = get.payload(v.clone());
            }
            let replies = get.wait().map_err(|e| format!("{key}: {e}"))?;
            let mut answered = false;
            while let Ok(reply) = replies.recv() {
                answered = true;
                match reply.result() {
                    Ok(s) => println!("{}", s.payload().try_to_string().unwrap_or_default()),
                    Err(e) => {
                        return Err(e.payload().try_to_string().unwrap_or_default().into_owned());
                    }
                }
            }
            if !answered {
                return Err(format!("{key}: no uss-zenoh answers this key"));
            }
        }
        Command::Alive {
            key,
            count,
            timeout,
        } => {
            let deadline = start + seconds(*timeout)?;
            let sub = session
                .liveliness()
                .declare_subscriber(key)
                .history(true)
                .wait()
                .map_err(|e| format!("{key}: {e}"))?;
            for _ in 0..*count {
                let left = deadline.saturating_duration_since(Instant::now());
                match sub.recv_timeout(left) {
                    Ok(Some(s)) => {
                        let sign = if s.kind() == SampleKind::Put {
                            '+'
                        } else {
                            '-'
                        };
                        println!("{sign} {} {}", s.key_expr(), start.elapsed().as_millis());
                    }
                    _ => return Err(format!("{key}: no change within {timeout} s")),
                }
            }
        }
    }
    let _ = session.close().wait();
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("uss-zenoh-client: {e}");
            ExitCode::FAILURE
        }
    }
}
