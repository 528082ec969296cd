//! `uss-zenoh`: the buses a ussd runs, on the network through Zenoh. A separate process (its
//! crash never touches ussd or a bus thread) that reads ussd's services like any local client
//! and maps them to Zenoh key expressions (guide, "Beyond one host"): status, input images,
//! diagnostics and descriptions as JSON, liveliness tokens for the bridge and for each bus ussd
//! serves, a queryable for parameters, read-only unless `--allow-writes`, operator stops from
//! anywhere, and remote control only with `--allow-control`.

mod commission;
mod control;
mod gate;
mod keys;
mod params;
mod payload;
mod policy;
mod publish;
mod refusal;
mod security;
mod text;

use clap::Parser;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use zenoh::{Config, Wait};

#[derive(Debug, Parser)]
#[command(
    name = "uss-zenoh",
    version,
    about = "Bridge the buses a ussd runs to Zenoh: status, inputs, diagnostics, liveliness and parameters (read-only unless --allow-writes)"
)]
// A command line's switches are independent flags.
#[allow(clippy::struct_excessive_bools)]
struct Cli {
    /// A bus to bridge, as named in ussd's configuration; repeat for more.
    #[arg(long = "bus", value_name = "NAME", default_value = "bus0")]
    buses: Vec<String>,
    /// A Zenoh configuration file (JSON5 or YAML): mode, endpoints, scouting, lease, ...
    #[arg(long, value_name = "FILE")]
    zenoh_config: Option<std::path::PathBuf>,
    /// Listen on this Zenoh endpoint too, e.g. tcp/0.0.0.0:7447; repeat for more.
    #[arg(long = "listen", value_name = "ENDPOINT")]
    listen: Vec<String>,
    /// Connect to this Zenoh endpoint (a router, or a peer), e.g. tcp/10.0.0.5:7447; repeat for
    /// more.
    #[arg(long = "connect", value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// Where the keys start: <prefix>/<bus>/... (default uss/<host name>).
    #[arg(long, value_name = "KEY")]
    prefix: Option<String>,
    /// Publish at most this many input images per second and drive (default: every one).
    #[arg(long, value_name = "HZ")]
    max_rate: Option<f64>,
    /// Accept parameter writes (a query with the new value as its payload), under the same
    /// rules as a local write. Without it a write query gets an error reply.
    #[arg(long)]
    allow_writes: bool,
    /// Let remote controllers run the drives: a sample on .../drive/<addr>/out is passed on
    /// through the drive's local controller, which the bridge holds while samples arrive. The
    /// drive's watchdog sees the remote controller itself: no fresh sample within its watchdog
    /// time, and the drive gets its safe command, latched until the remote re-arms it. Needs
    /// --policy granting `control` by name: remote control rests on verified identities only.
    #[arg(long)]
    allow_control: bool,
    /// Allow --allow-writes on links that do not authenticate who reaches the bridge (plain
    /// TCP, multicast scouting): anyone who can reach its port may then change the drives'
    /// parameters. For a lab network only; said at start. Remote control never runs so: it
    /// needs a policy, which needs authenticated links.
    #[arg(long)]
    insecure_network: bool,
    /// Who may do what: a TOML file granting rights (read, stop, write, control) per
    /// certificate common name, bus and drive (guide, "Who may do what"). Zenoh's access
    /// control binds each listed name to its certificate and subscriptions to `read`; the
    /// bridge checks every put and query and answers a refusal with the missing right. Needs
    /// mutual TLS or user/password authentication (then the names are users).
    #[arg(long, value_name = "FILE")]
    policy: Option<PathBuf>,
    /// Print the man page (roff) and exit.
    #[arg(long)]
    man: bool,
}

/// Why the bridge did not start. Zenoh's errors are boxed trait objects (not `Error` sources
/// themselves): they are shown, not chained.
#[derive(Debug, thiserror::Error)]
enum StartError {
    #[error("{}: {error}", .path.display())]
    ZenohConfig { path: PathBuf, error: zenoh::Error },
    #[error("{flag} {endpoints:?}: {error}")]
    Endpoints {
        flag: &'static str,
        endpoints: Vec<String>,
        error: zenoh::Error,
    },
    #[error("--max-rate {0}: give a positive number of images per second")]
    MaxRate(f64),
    #[error("cannot handle signal {signal}: {source}")]
    Signal { signal: i32, source: std::io::Error },
    #[error(
        "cannot open the Zenoh session: {}{}",
        text::plain(.0),
        text::session_hint(&.0.to_string())
    )]
    Session(zenoh::Error),
    #[error("liveliness token {key}: {error}")]
    Token { key: String, error: zenoh::Error },
    /// The operator-stop queryable: without it the bridge does not run.
    #[error("cannot declare the queryable {key}: {error}")]
    Stops { key: String, error: zenoh::Error },
    #[error("cannot start a thread: {0}")]
    Thread(std::io::Error),
    /// Control or writes asked for on links anyone can use.
    #[error(
        "{what} needs links that authenticate who reaches the bridge, and these do not ({why}): {how}",
        why = .why.join("; "),
        how = security::HOW
    )]
    Unauthenticated { what: String, why: Vec<String> },
    #[error(transparent)]
    Policy(#[from] policy::PolicyError),
    #[error(
        "--policy names peers by their certificates' common names or their users: it needs mutual TLS or user/password authentication, and these links are {0}"
    )]
    PolicyNeedsAuth(&'static str),
    #[error("--policy: Zenoh refused the access control made of it: {0}")]
    PolicyConfig(zenoh::Error),
    /// Remote control rests on verified identities only.
    #[error(
        "--allow-control {0}: remote control rests on verified identities only; give --policy a [[grant]] with rights = [\"control\"] and the certificates' common names (or users) in `who` (guide, \"Who may do what\")"
    )]
    ControlNotByName(&'static str),
}

/// Whether `policy` lets remote control rest on verified identities: it grants `control` by
/// name, and not to every authenticated peer.
fn control_by_name(policy: Option<&policy::Policy>) -> Result<(), StartError> {
    let Some(p) = policy else {
        return Err(StartError::ControlNotByName(
            "needs --policy naming who may control",
        ));
    };
    if p.default.contains(&policy::Right::Control) {
        return Err(StartError::ControlNotByName(
            "with a policy that grants `control` by `default` (to every authenticated peer, named by nothing)",
        ));
    }
    if !p
        .grant
        .iter()
        .any(|g| g.rights.contains(&policy::Right::Control) && !g.who.is_empty())
    {
        return Err(StartError::ControlNotByName(
            "with a policy that grants `control` to nobody",
        ));
    }
    Ok(())
}

/// What the bridge lets remote peers do: run drives, change parameters.
fn remote_rights(cli: &Cli) -> Option<String> {
    match (cli.allow_control, cli.allow_writes) {
        (true, true) => Some("--allow-control with --allow-writes".to_owned()),
        (true, false) => Some("--allow-control".to_owned()),
        (false, true) => Some("--allow-writes".to_owned()),
        (false, false) => None,
    }
}

/// The Zenoh configuration: the file's, with `--listen` and `--connect` added.
fn zenoh_config(cli: &Cli) -> Result<Config, StartError> {
    let mut config = match &cli.zenoh_config {
        Some(path) => Config::from_file(path).map_err(|error| StartError::ZenohConfig {
            path: path.clone(),
            error,
        })?,
        None => Config::default(),
    };
    for (flag, key, endpoints) in [
        ("--listen", "listen/endpoints", &cli.listen),
        ("--connect", "connect/endpoints", &cli.connect),
    ] {
        if endpoints.is_empty() {
            continue;
        }
        let list = serde_json::to_string(endpoints).unwrap_or_default();
        config
            .insert_json5(key, &list)
            .map_err(|error| StartError::Endpoints {
                flag,
                endpoints: endpoints.clone(),
                error,
            })?;
    }
    Ok(config)
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_owned())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".to_owned())
}

/// The Zenoh configuration the bridge opens with, how its links authenticate, and its access
/// policy with what it names peers by.
type Secured = (
    Config,
    security::Links,
    Option<(policy::Policy, policy::Names)>,
);

/// One of a bus's threads: publisher, stops, control, parameters.
type Job = Box<dyn FnOnce(&zenoh::Session, &publish::Options, &Arc<AtomicBool>) + Send>;

/// The threads of one bus: its publisher, its stops (on the queryable declared before), remote
/// control, parameters and commissioning, with the bridge's flags (`--allow-writes`,
/// `--allow-control`).
fn bus_jobs(
    stops: zenoh::query::Queryable<zenoh::handlers::FifoChannelHandler<zenoh::query::Query>>,
    w: bool,
    c: bool,
) -> [(&'static str, Job); 5] {
    // The drives the bridge holds for remote controllers: no parameter writes to them.
    let held = Arc::new(control::Held::default());
    let (held_params, held_commission) = (Arc::clone(&held), Arc::clone(&held));
    [
        ("publish", Box::new(publish::run)),
        (
            "stops",
            Box::new(move |_, o, st| {
                control::serve_stops(&stops, &o.bus, &o.keys, &o.gate, st);
            }),
        ),
        (
            "control",
            Box::new(move |s, o, st| {
                control::serve_control(s, &o.bus, &o.keys, c, &o.gate, &held, st);
            }),
        ),
        ("params", queries(w, held_params, params::serve)),
        ("commission", queries(w, held_commission, commission::serve)),
    ]
}

/// A thread that answers queries with `serve` (parameters, commissioning) under the bridge's
/// `--allow-writes` (`w`) and the drives it holds for remote controllers.
fn queries(
    w: bool,
    held: Arc<control::Held>,
    serve: fn(&zenoh::Session, &str, &keys::Keys, params::Rules<'_>, &Arc<AtomicBool>),
) -> Job {
    Box::new(move |s, o, st| {
        let rules = params::Rules {
            allow_writes: w,
            held: &held,
            gate: &o.gate,
        };
        serve(s, &o.bus, &o.keys, rules, st);
    })
}

const fn allowed(yes: bool) -> &'static str {
    if yes { "allowed" } else { "refused" }
}

/// The Zenoh configuration with the checks of who may reach the bridge: control or writes only
/// on authenticated links (or, said on stderr, with `--insecure-network`), and the access
/// policy made into Zenoh's access control (with what the links name peers by).
fn secured_config(cli: &Cli, prefix: &str) -> Result<Secured, StartError> {
    let mut config = zenoh_config(cli)?;
    let links = security::links(&config);
    let policy = match &cli.policy {
        Some(path) => {
            let p = policy::Policy::load(path, &cli.buses)?;
            let by = match links {
                security::Links::MutualTls => policy::Names::Certificates,
                security::Links::UserPassword => policy::Names::Users,
                security::Links::Open(_) => return Err(StartError::PolicyNeedsAuth(links.name())),
            };
            config
                .insert_json5(
                    "access_control",
                    &p.access_control(prefix, &cli.buses, by).to_string(),
                )
                .map_err(StartError::PolicyConfig)?;
            Some((p, by))
        }
        None => None,
    };
    let open = match (remote_rights(cli), &links) {
        (Some(what), security::Links::Open(why)) => Some((what, why.clone())),
        _ => None,
    };
    if let Some((what, why)) = open.as_ref().filter(|_| !cli.insecure_network) {
        return Err(StartError::Unauthenticated {
            what: what.clone(),
            why: why.clone(),
        });
    }
    if cli.allow_control {
        control_by_name(policy.as_ref().map(|(p, _)| p))?;
    }
    if let Some((what, why)) = open {
        eprintln!(
            "uss-zenoh: --insecure-network: {what} on links that do not authenticate ({}): \
             anyone who reaches this bridge may change the drives' parameters",
            why.join("; "),
        );
    }
    Ok((config, links, policy))
}

fn run(cli: &Cli) -> Result<(), StartError> {
    let prefix = cli
        .prefix
        .clone()
        .unwrap_or_else(|| format!("uss/{}", host_name()));
    if let Some(r) = cli.max_rate.filter(|r| !(r.is_finite() && *r > 0.0)) {
        return Err(StartError::MaxRate(r));
    }
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .map_err(|source| StartError::Signal { signal, source })?;
    }
    let (config, links, policy) = secured_config(cli, &prefix)?;
    let session = zenoh::open(config).wait().map_err(StartError::Session)?;
    let bridge_key = format!("{prefix}/bridge");
    let bridge = session
        .liveliness()
        .declare_token(&bridge_key)
        .wait()
        .map_err(|error| StartError::Token {
            key: bridge_key.clone(),
            error,
        })?;
    let mut threads = Vec::new();
    for bus in &cli.buses {
        let options = publish::Options {
            bus: bus.clone(),
            keys: keys::Keys::new(&prefix, bus),
            max_rate: cli.max_rate,
            gate: Arc::new(gate::Gate::new(bus, policy.clone())),
        };
        // Declared before anything else runs: without it the bridge does not run.
        let stops = session
            .declare_queryable(options.keys.stops())
            .wait()
            .map_err(|error| StartError::Stops {
                key: options.keys.stops(),
                error,
            })?;
        let jobs = bus_jobs(stops, cli.allow_writes, cli.allow_control);
        for (what, job) in jobs {
            let (s, st, o) = (session.clone(), Arc::clone(&stop), options.clone());
            let thread = std::thread::Builder::new()
                .name(format!("{what}-{bus}"))
                .spawn(move || job(&s, &o, &st))
                .map_err(StartError::Thread)?;
            threads.push(thread);
        }
    }
    // A reader of stdout that went away is no reason not to bridge.
    let _ = writeln!(
        std::io::stdout(),
        "uss-zenoh: bridging {} under {prefix}/ (parameter writes {}, remote control {}, links {}{}), Zenoh id {}",
        cli.buses.join(", "),
        allowed(cli.allow_writes),
        allowed(cli.allow_control),
        links.name(),
        policy
            .as_ref()
            .map_or_else(String::new, |(p, _)| format!(", policy: {}", p.summary())),
        session.zid()
    );
    for t in threads {
        let _ = t.join();
    }
    let _ = bridge.undeclare().wait();
    let _ = session.close().wait();
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if cli.man {
        return print_man::<Cli>("uss-zenoh");
    }
    uss_client::quiet_iceoryx2_logs();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("uss-zenoh: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Prints the man page of command line `C` (roff, for man).
fn print_man<C: clap::CommandFactory>(program: &str) -> ExitCode {
    let mut page = Vec::new();
    let printed = clap_mangen::Man::new(C::command())
        .render(&mut page)
        .and_then(|()| std::io::Write::write_all(&mut std::io::stdout(), &page));
    printed.map_or_else(
        |e| {
            eprintln!("{program}: {e}");
            ExitCode::FAILURE
        },
        |()| ExitCode::SUCCESS,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy(text: &str) -> policy::Policy {
        policy::Policy::parse(text, &["line1".to_owned()]).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Issue 32, item 6: remote control rests on verified identities only.
    #[test]
    fn remote_control_needs_a_policy_that_grants_it_by_name() {
        let refused = |p: Option<&policy::Policy>| match control_by_name(p) {
            Err(e) => e.to_string(),
            Ok(()) => String::new(),
        };
        assert!(refused(None).contains("needs --policy naming who may control"));
        let by_default = policy("default = [\"read\", \"stop\", \"control\"]\n");
        assert!(refused(Some(&by_default)).contains("by `default`"));
        let nobody = policy("[[grant]]\nwho = [\"eng\"]\nrights = [\"write\"]\n");
        assert!(refused(Some(&nobody)).contains("to nobody"));
        let named = policy("[[grant]]\nwho = [\"hmi-1\"]\nrights = [\"control\"]\n");
        assert_eq!(refused(Some(&named)), "");
    }
}
