//! `uss-zenoh-client`: a small remote client of uss-zenoh for another host (an HMI, a laptop):
//! follow a drive's inputs, read or write a parameter, watch a bus's liveliness, stop a drive,
//! and run one through a bridge that allows remote control. It is also how the tests look at
//! the bridge from the other side of a network boundary.

mod run;
#[path = "../../text.rs"]
mod text;

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
    /// This client's certificate (PEM) for a bridge that asks for one (mutual TLS, tls/
    /// endpoints); its common name is the identity the bridge's access policy names.
    #[arg(long, value_name = "FILE", requires_all = ["key", "ca"])]
    cert: Option<std::path::PathBuf>,
    /// The private key (PEM) of --cert.
    #[arg(long, value_name = "FILE", requires = "cert")]
    key: Option<std::path::PathBuf>,
    /// The certificate authority (PEM) the bridge's certificate must be signed by.
    #[arg(long, value_name = "FILE", requires = "cert")]
    ca: Option<std::path::PathBuf>,
    /// Send stops, parameter queries and samples under this name (`<prefix>/<bus>/as/NAME/
    /// drive/...`), the name a bridge's access policy grants rights to; it lets only the
    /// certificate of that common name (or that user) send there. Default: the common name of
    /// --cert, else the user of --zenoh-config's user/password authentication (none without
    /// either: the keys themselves, with the rights every peer has).
    #[arg(long = "as", value_name = "NAME", global = true)]
    as_name: Option<String>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Print the manual page (roff, for man).
    Man,
    /// Print each sample on KEY (e.g. uss/site/bus0/drive/1/in) as one line of JSON.
    Sub {
        key: String,
        /// Stop after this many samples.
        #[arg(long, default_value_t = 1)]
        count: u64,
        /// Give up after this many seconds.
        #[arg(long, default_value_t = 10.0)]
        timeout: f64,
        /// Print what arrives for this many seconds (at most --count samples) and end without
        /// an error, whatever arrived.
        #[arg(long = "for", value_name = "SECONDS", conflicts_with = "timeout")]
        for_s: Option<f64>,
        /// Start each line with the time it arrived, ns since the Unix epoch (for latency
        /// measurements on one host or hosts with synchronised clocks).
        #[arg(long)]
        stamp: bool,
    },
    /// Query KEY (e.g. uss/site/bus0/drive/1/param/P1082); with --value, write that value (through
    /// the parameter's write key, .../set/P1082); with --file, send a file (a backup for
    /// .../drive/<addr>/diff and .../restore).
    Get {
        key: String,
        /// The value to write (the query's payload), e.g. 45.0.
        #[arg(long)]
        value: Option<String>,
        /// Send this file's text as the query's payload (a backup file).
        #[arg(long, value_name = "FILE", conflicts_with = "value")]
        file: Option<std::path::PathBuf>,
        /// Seconds to wait for the answer.
        #[arg(long, default_value_t = 10.0)]
        timeout: f64,
        /// Ask this many times, one query after the other.
        #[arg(long, default_value_t = 1)]
        repeat: u32,
        /// Start each reply's line with the query's round trip in ns.
        #[arg(long)]
        timed: bool,
    },
    /// Run a drive through a bridge started with --allow-control: OFF1 until the drive is
    /// re-armed, then ON towards HZ, every --period ms; OFF1 and release at the end. Gives up
    /// (sending nothing more) when the drive latches or its images stop coming for a second:
    /// only a new `run` re-arms it.
    Run {
        /// The drive's key, e.g. uss/site/bus0/drive/1.
        drive: String,
        #[arg(long, allow_hyphen_values = true)]
        hz: f32,
        /// Stop after this many seconds (default: at Ctrl-C).
        #[arg(long = "for", value_name = "SECONDS")]
        for_s: Option<f64>,
        /// Milliseconds between samples, at most (a quarter of the drive's watchdog time when
        /// that is shorter).
        #[arg(long, default_value_t = 20)]
        period: u64,
    },
    /// Put VALUE on KEY once, e.g. a sample of your own on uss/site/bus0/drive/1/out (under
    /// your name, as --as says, unless KEY names a peer).
    Put { key: String, value: String },
    /// An operator's stop of the drive KEY (e.g. uss/site/bus0/drive/1), or of every drive of a
    /// bus (uss/site/bus0): OFF1 unless --coast (OFF2) or --quick (OFF3).
    Stop {
        key: String,
        #[arg(long, conflicts_with = "quick")]
        coast: bool,
        #[arg(long)]
        quick: bool,
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

/// Why a command failed. Zenoh's errors are boxed trait objects (not `Error` sources
/// themselves): they are shown, not chained.
#[derive(Debug, thiserror::Error)]
pub enum Failure {
    #[error("{}: {error}", .path.display())]
    ZenohConfig {
        path: std::path::PathBuf,
        error: zenoh::Error,
    },
    #[error("--connect {endpoints:?}: {error}")]
    Connect {
        endpoints: Vec<String>,
        error: zenoh::Error,
    },
    #[error(
        "cannot open the Zenoh session: {}{}",
        text::plain(.0),
        text::session_hint(&.0.to_string())
    )]
    Session(zenoh::Error),
    #[error("--cert/--key/--ca: {0}")]
    Tls(zenoh::Error),
    #[error("--cert {path}: {why} (name this client with --as)")]
    CommonName { path: String, why: String },
    #[error("{0}: give a number of seconds")]
    Seconds(f64),
    /// A subscriber, publisher, query or put on `key` that Zenoh refused.
    #[error("{key}: {error}")]
    Zenoh { key: String, error: zenoh::Error },
    /// An error reply: the bridge's own words.
    #[error("{0}")]
    Replied(String),
    /// `--file` cannot be read.
    #[error("--file {}: {error}", .path.display())]
    File {
        path: std::path::PathBuf,
        error: std::io::Error,
    },
    #[error(
        "{0}: no uss-zenoh answers this key: no bridge serves it (check the prefix and the bus \
         with `uss-zenoh-client ... alive <prefix>/<bus>/alive`), or the bridge's access policy does \
         not let this client ask it (the bridge counts the refusal in its status's `refused`)"
    )]
    NoAnswer(String),
    #[error("{key}: nothing within {seconds} s")]
    Nothing { key: String, seconds: f64 },
    #[error("{key}: no change within {seconds} s")]
    NoChange { key: String, seconds: f64 },
    #[error("stdout: {0}")]
    Stdout(std::io::Error),
    /// The reader of stdout went away (`| head`): the client ends quietly.
    #[error("the output was closed")]
    Closed,
    // Why a remote run ended before its time; with each, the client sends nothing more.
    #[error("cannot handle signal {signal}: {source}")]
    Signal { signal: i32, source: std::io::Error },
    #[error(
        "no image of {drive} within {:?}: is uss-zenoh running for its bus?",
        run::ARM_TIMEOUT
    )]
    NoImage { drive: String },
    #[error("the bridge refused the OFF1: {0}")]
    ArmRefused(String),
    #[error(
        "{drive} was stopped after this run was started ({reason}): a re-arm clears only a \
         latch that began before it was asked for, so nothing was re-armed; run it again if \
         the stop is over"
    )]
    StoppedWhileStarting { drive: String, reason: String },
    #[error("cannot tell when this client started (/proc/self/stat): {0}; nothing was sent")]
    StartTime(std::io::Error),
    #[error(
        "{drive} is in fault (ZSW1 {zsw1:#06X}): it does not run until the fault is \
         acknowledged; read why with `uss-zenoh-client get {drive}/param/r0947[0]` (the fault \
         number; F0072: its telegrams stopped), then acknowledge it where the drive is (`ussctl \
         ack {address}`) and run it again; this client sends nothing more"
    )]
    Faulted {
        drive: String,
        address: String,
        zsw1: u16,
    },
    #[error(
        "{drive} was not re-armed within {:?} (control {control:?}, latch {latch:?}); is the \
         bridge running with --allow-control?",
        run::ARM_TIMEOUT
    )]
    NotArmed {
        drive: String,
        control: String,
        latch: String,
    },
    #[error(
        "{drive} latched after {seconds:.2} s ({reason}): it gets its safe command until a new \
         run re-arms it"
    )]
    Latched {
        drive: String,
        seconds: f64,
        reason: String,
    },
    #[error("the bridge refused a sample: {0}")]
    SampleRefused(String),
    #[error(
        "{drive}: this client's own loop made no call for {seconds:.3} s, longer than the \
         drive's watchdog: that is a trip; it sends nothing more (a new run re-arms the drive)"
    )]
    Stalled { drive: String, seconds: f64 },
    #[error(
        "no fresh image of {drive} for {seconds:.2} s: giving up, sending nothing more (the \
         drive's watchdog stops it)"
    )]
    Blind { drive: String, seconds: f64 },
}

/// A failed write to stdout: [`Failure::Closed`] when its reader went away.
fn stdout_failed(e: std::io::Error) -> Failure {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        Failure::Closed
    } else {
        Failure::Stdout(e)
    }
}

/// Writes `line` to stdout at once.
fn say(line: &str) -> Result<(), Failure> {
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")
        .and_then(|()| out.flush())
        .map_err(stdout_failed)
}

fn seconds(s: f64) -> Result<Duration, Failure> {
    Duration::try_from_secs_f64(s).map_err(|_| Failure::Seconds(s))
}

/// What Zenoh refused on `key`.
fn on<K: Into<String>>(key: K) -> impl FnOnce(zenoh::Error) -> Failure {
    move |error| Failure::Zenoh {
        key: key.into(),
        error,
    }
}

fn config(cli: &Cli) -> Result<Config, Failure> {
    let mut config = match &cli.zenoh_config {
        Some(path) => Config::from_file(path).map_err(|error| Failure::ZenohConfig {
            path: path.clone(),
            error,
        })?,
        None => Config::default(),
    };
    if !cli.connect.is_empty() {
        let list = serde_json::to_string(&cli.connect).unwrap_or_default();
        config
            .insert_json5("connect/endpoints", &list)
            .and_then(|()| config.insert_json5("mode", r#""client""#))
            .and_then(|()| config.insert_json5("scouting/multicast/enabled", "false"))
            .map_err(|error| Failure::Connect {
                endpoints: cli.connect.clone(),
                error,
            })?;
    }
    if let (Some(cert), Some(key), Some(ca)) = (&cli.cert, &cli.key, &cli.ca) {
        let path = |p: &std::path::Path| serde_json::to_string(&p.display().to_string());
        for (setting, file) in [
            ("connect_certificate", cert),
            ("connect_private_key", key),
            ("root_ca_certificate", ca),
        ] {
            config
                .insert_json5(
                    &format!("transport/link/tls/{setting}"),
                    &path(file).unwrap_or_default(),
                )
                .map_err(Failure::Tls)?;
        }
        config
            .insert_json5("transport/link/tls/enable_mtls", "true")
            .map_err(Failure::Tls)?;
    }
    Ok(config)
}

/// Prints each reply of a query as a line (after the round trip in ns since `asked`, if given);
/// the first error reply, or no reply, is the error.
fn print_replies(
    key: &str,
    replies: &zenoh::handlers::FifoChannelHandler<zenoh::query::Reply>,
    asked: Option<Instant>,
) -> Result<(), Failure> {
    let mut answered = false;
    while let Ok(reply) = replies.recv() {
        answered = true;
        let round_trip = asked.map(|t| format!("{} ", t.elapsed().as_nanos()));
        match reply.result() {
            Ok(s) => say(&format!(
                "{}{}",
                round_trip.unwrap_or_default(),
                s.payload().try_to_string().unwrap_or_default()
            ))?,
            Err(e) => {
                let said = e.payload().try_to_string().unwrap_or_default();
                return Err(Failure::Replied(refusal_text(&said)));
            }
        }
    }
    if answered {
        Ok(())
    } else {
        Err(Failure::NoAnswer(key.to_owned()))
    }
}

/// Prints each sample on `key` as a line (after its arrival time if `stamp`), at most `count`,
/// for at most `seconds`: running out of time is an error unless `open_ended`.
fn subscribe(
    session: &zenoh::Session,
    key: &str,
    count: u64,
    seconds_: f64,
    open_ended: bool,
    stamp: bool,
) -> Result<(), Failure> {
    use std::io::Write as _;
    let deadline = Instant::now() + seconds(seconds_)?;
    let sub = session.declare_subscriber(key).wait().map_err(on(key))?;
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    for _ in 0..count {
        let left = deadline.saturating_duration_since(Instant::now());
        match sub.recv_timeout(left) {
            Ok(Some(s)) => {
                if stamp {
                    write!(out, "{} ", unix_ns()).map_err(stdout_failed)?;
                }
                let payload = s.payload().try_to_string().unwrap_or_default();
                writeln!(out, "{payload}").map_err(stdout_failed)?;
                // Each sample as it comes, --for or not: a reader of a pipe must see a stale
                // or gone ussd when the bridge says so, not when a buffer fills.
                out.flush().map_err(stdout_failed)?;
            }
            _ if open_ended => break,
            _ => {
                return Err(Failure::Nothing {
                    key: key.to_owned(),
                    seconds: seconds_,
                });
            }
        }
    }
    out.flush().map_err(stdout_failed)
}

fn unix_ns() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos())
}

/// The common name of the certificate in the PEM file `path`.
fn common_name(path: &std::path::Path) -> Result<String, Failure> {
    let failed = |why: String| Failure::CommonName {
        path: path.display().to_string(),
        why,
    };
    let pem = std::fs::read(path).map_err(|e| failed(e.to_string()))?;
    let (_, pem) = x509_parser::pem::parse_x509_pem(&pem).map_err(|e| failed(e.to_string()))?;
    let cert = pem.parse_x509().map_err(|e| failed(e.to_string()))?;
    let name = cert
        .subject()
        .iter_common_name()
        .next()
        .and_then(|cn| cn.as_str().ok())
        .ok_or_else(|| failed("it has no common name".to_owned()))?;
    Ok(name.to_owned())
}

/// The name this client sends under: `--as`, else its certificate's common name, else the user
/// it logs in as (`transport.auth.usrpwd.user` of its Zenoh configuration).
fn own_name(cli: &Cli, config: &Config) -> Result<Option<String>, Failure> {
    match (&cli.as_name, &cli.cert) {
        (Some(n), _) => Ok(Some(n.clone())),
        (None, Some(cert)) => common_name(cert).map(Some),
        (None, None) => Ok(config
            .get_json("transport/auth/usrpwd/user")
            .ok()
            .and_then(|j| serde_json::from_str::<Option<String>>(&j).ok().flatten())
            .filter(|u| !u.is_empty())),
    }
}

/// `key` (a drive's `.../drive/<addr>/...`, or a bus's key) under the sender's name: `as/<name>`
/// goes before the last `/drive/`, or at the end of a bus's key; a key that names a peer
/// already (`.../as/<name>/...`) stays as written.
fn named_key(key: &str, name: Option<&str>) -> String {
    let key = key.trim_end_matches('/');
    match (name, key.rfind("/drive/")) {
        (None, _) => key.to_owned(),
        _ if key.contains("/as/") => key.to_owned(),
        (Some(n), Some(at)) => format!("{}/as/{n}{}", &key[..at], &key[at..]),
        (Some(n), None) => format!("{key}/as/{n}"),
    }
}

fn put(session: &zenoh::Session, key: &str, value: &str) -> Result<(), Failure> {
    session.put(key, value.to_owned()).wait().map_err(on(key))
}

fn run(cli: &Cli) -> Result<(), Failure> {
    let config = config(cli)?;
    let name = own_name(cli, &config)?;
    let session = zenoh::open(config).wait().map_err(Failure::Session)?;
    let done = command(&session, cli, name.as_deref());
    if done.is_ok() {
        let _ = session.close().wait();
    } else {
        // The link may be down: a close would wait for the peer (10 s) before the program
        // could say why it failed. The process ends now and the system closes its sockets.
        std::mem::forget(session);
    }
    done
}

/// A query's payload: `--file`'s text (sent to the key as given), or `--value` (sent to a
/// parameter's write key: the bool says so).
fn payload_of(
    value: Option<&str>,
    file: Option<&std::path::Path>,
) -> Result<(Option<String>, bool), Failure> {
    match file {
        Some(path) => std::fs::read_to_string(path)
            .map(|t| (Some(t), false))
            .map_err(|error| Failure::File {
                path: path.to_owned(),
                error,
            }),
        None => Ok((value.map(str::to_owned), true)),
    }
}

/// `get KEY [--value V]`: a read, or a write through the parameter's write key
/// (`.../set/P1082`: the key an access policy's `write` right covers), `repeat` times.
#[allow(
    clippy::too_many_arguments,
    reason = "the command's own arguments, one each"
)]
fn get(
    session: &zenoh::Session,
    key: &str,
    name: Option<&str>,
    value: Option<&str>,
    to_write_key: bool,
    timeout: f64,
    repeat: u32,
    timed: bool,
) -> Result<(), Failure> {
    // The last `/param/` is the parameter's (a prefix may hold the word too).
    let key = &named_key(key, name);
    let key = match (value, key.rfind("/param/")) {
        (Some(_), Some(at)) if to_write_key => {
            format!("{}/set/{}", &key[..at], &key[at + "/param/".len()..])
        }
        _ => key.to_owned(),
    };
    let key = &key;
    for _ in 0..repeat {
        let asked = Instant::now();
        let mut get = session.get(key).timeout(seconds(timeout)?);
        if let Some(v) = value {
            get = get.payload(v.to_owned());
        }
        let replies = get.wait().map_err(on(key))?;
        print_replies(key, &replies, timed.then_some(asked))?;
    }
    Ok(())
}

#[allow(
    clippy::too_many_lines,
    reason = "the dispatch of the subcommands: one arm each, each a call"
)]
fn command(session: &zenoh::Session, cli: &Cli, name: Option<&str>) -> Result<(), Failure> {
    let start = Instant::now();
    match &cli.command {
        Command::Sub {
            key,
            count,
            timeout,
            for_s,
            stamp,
        } => subscribe(
            session,
            key,
            *count,
            for_s.unwrap_or(*timeout),
            for_s.is_some(),
            *stamp,
        )?,
        Command::Get {
            key,
            value,
            file,
            timeout,
            repeat,
            timed,
        } => {
            let (payload, rewrite) = payload_of(value.as_deref(), file.as_deref())?;
            get(
                session,
                key,
                name,
                payload.as_deref(),
                rewrite,
                *timeout,
                *repeat,
                *timed,
            )?;
        }
        Command::Run {
            drive,
            hz,
            for_s,
            period,
        } => run::run(
            session,
            drive,
            &format!("{}/out", named_key(drive, name)),
            *hz,
            for_s.map(seconds).transpose()?,
            *period,
        )?,
        // A sample of one's own goes under one's name, as `run`'s and `stop`'s do.
        Command::Put { key, value } => put(session, &named_key(key, name), value)?,
        Command::Stop { key, coast, quick } => {
            let command = match (coast, quick) {
                (true, _) => "off2",
                (_, true) => "off3",
                _ => "off1",
            };
            let key = format!("{}/stop", named_key(key, name));
            let replies = session
                .get(&key)
                .payload(command)
                .timeout(Duration::from_secs(10))
                .wait()
                .map_err(on(&key))?;
            print_replies(&key, &replies, None)?;
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
                .map_err(on(key))?;
            for _ in 0..*count {
                let left = deadline.saturating_duration_since(Instant::now());
                match sub.recv_timeout(left) {
                    Ok(Some(s)) => {
                        let sign = if s.kind() == SampleKind::Put {
                            '+'
                        } else {
                            '-'
                        };
                        say(&format!(
                            "{sign} {} {}",
                            s.key_expr(),
                            start.elapsed().as_millis()
                        ))?;
                    }
                    _ => {
                        return Err(Failure::NoChange {
                            key: key.clone(),
                            seconds: *timeout,
                        });
                    }
                }
            }
        }
        // Printed by main before a session opens.
        Command::Man => {}
    }
    Ok(())
}

/// An error reply in words: the bridge's text and its kind from the error table
/// (`{"error": ..., "kind": ..., "code": ...}`: `drive 7 P1082: ... [unknown_drive]`); a reply
/// of another form (an older bridge's plain text) as it is.
fn refusal_text(said: &str) -> String {
    match serde_json::from_str::<serde_json::Value>(said) {
        Ok(v) if v["error"].is_string() => format!(
            "{} [{}]",
            v["error"].as_str().unwrap_or_default(),
            v["kind"].as_str().unwrap_or("unknown")
        ),
        _ => said.to_owned(),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if matches!(cli.command, Command::Man) {
        let mut page = Vec::new();
        let printed = clap_mangen::Man::new(<Cli as clap::CommandFactory>::command())
            .render(&mut page)
            .and_then(|()| std::io::Write::write_all(&mut std::io::stdout(), &page));
        return match printed {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("uss-zenoh-client: {e}");
                ExitCode::FAILURE
            }
        };
    }
    match run(&cli) {
        Ok(()) | Err(Failure::Closed) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("uss-zenoh-client: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::named_key;

    #[test]
    fn a_named_key_puts_the_name_before_the_drive_or_after_the_bus() {
        let n = Some("hmi-1");
        assert_eq!(
            named_key("uss/p/line1/drive/1/param/P1082", n),
            "uss/p/line1/as/hmi-1/drive/1/param/P1082"
        );
        assert_eq!(
            named_key("uss/p/line1/drive/1/", n),
            "uss/p/line1/as/hmi-1/drive/1"
        );
        assert_eq!(named_key("uss/p/line1", n), "uss/p/line1/as/hmi-1");
        assert_eq!(
            named_key("**/line1/drive/2", n),
            "**/line1/as/hmi-1/drive/2"
        );
        assert_eq!(
            named_key("uss/p/line1/drive/1", None),
            "uss/p/line1/drive/1"
        );
        // Written out already (another peer's name, to be refused by the bridge): as written.
        assert_eq!(
            named_key("uss/p/line1/as/other/drive/1/out", n),
            "uss/p/line1/as/other/drive/1/out"
        );
    }
}
