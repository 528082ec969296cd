//! A network namespace of the test's (or the benchmark's) own, joined to this one by a veth pair,
//! with `uss-zenoh` listening on this side and `uss-zenoh-client` run on the other. Shared by
//! the remote tests and the remote benchmark (`#[path]`), so not every item is used by both.

#![allow(dead_code, clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, Ordering};
use uss_integration_tests::ChildProc;

/// This package's binaries, built by cargo for this test with the test's own features (a
/// separate `cargo build -p uss-zenoh` would resolve zenoh's features anew and rebuild it).
pub const BRIDGE: &str = env!("CARGO_BIN_EXE_uss-zenoh");
pub const CLIENT: &str = env!("CARGO_BIN_EXE_uss-zenoh-client");

/// A network namespace joined to this one by a veth pair: here 10.231.N.1, there 10.231.N.2.
pub struct Netns {
    pub name: String,
    pub host_if: String,
    pub subnet: u32,
    /// The certificate the clients show: `None`, plain TCP to the bridge.
    tls: Mutex<Option<ClientTls>>,
}

/// What a client in the namespace connects with over TLS: its certificate and key, and the CA
/// it checks the bridge's certificate against.
#[derive(Debug, Clone)]
pub struct ClientTls {
    pub cert: PathBuf,
    pub key: PathBuf,
    pub ca: PathBuf,
}

impl ClientTls {
    /// `--cert FILE --key FILE --ca FILE`, as the Rust and the Python client take them.
    pub fn add_to(&self, command: &mut Command) {
        command
            .arg("--cert")
            .arg(&self.cert)
            .arg("--key")
            .arg(&self.key)
            .arg("--ca")
            .arg(&self.ca);
    }
}

/// Certificates made with openssl exactly as the guide shows: a CA, the bridge's certificate
/// (for the namespace's near address), and clients' certificates by common name.
pub struct Pki {
    pub dir: PathBuf,
}

/// A new P-256 key and a self-signed (or, with `-CA`, CA-signed) certificate, valid for the
/// days that follow.
const NEW_KEY: [&str; 8] = [
    "req",
    "-x509",
    "-newkey",
    "ec",
    "-pkeyopt",
    "ec_paramgen_curve:P-256",
    "-nodes",
    "-days",
];

fn openssl(dir: &Path, args: &[&str]) {
    let out = Command::new("openssl")
        .current_dir(dir)
        .args(args)
        .output()
        .expect("openssl (apt-get install openssl)");
    assert!(
        out.status.success(),
        "openssl {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
}

impl Pki {
    /// A CA called `ca_name` and the bridge's certificate for `bridge_ip`.
    pub fn new(tag: &str, ca_name: &str, bridge_ip: &str) -> Pki {
        let dir = std::env::temp_dir().join(format!("uss-pki-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        // 1. The CA.
        let subject = format!("/CN={ca_name}");
        let mut args = NEW_KEY.to_vec();
        args.extend([
            "3650", "-subj", &subject, "-keyout", "ca.key", "-out", "ca.pem",
        ]);
        openssl(&dir, &args);
        let pki = Pki { dir };
        // 2. The bridge's certificate, for the address clients connect to.
        pki.issue(
            "bridge",
            "uss-bridge",
            Some(&format!("IP:{bridge_ip},DNS:uss-bridge")),
        );
        pki
    }

    /// A server's certificate (a router's) for `ip`, signed by the CA: `<file>.pem`,
    /// `<file>.key`.
    pub fn server(&self, file: &str, ip: &str) -> (String, String) {
        self.issue(file, &format!("uss-{file}"), Some(&format!("IP:{ip}")));
        (
            self.path(&format!("{file}.pem")),
            self.path(&format!("{file}.key")),
        )
    }

    /// 3. A certificate with common name `cn`, signed by the CA: `<file>.pem`, `<file>.key`.
    fn issue(&self, file: &str, cn: &str, san: Option<&str>) {
        let (key, pem) = (format!("{file}.key"), format!("{file}.pem"));
        let subject = format!("/CN={cn}");
        let mut args = NEW_KEY.to_vec();
        args.extend([
            "825",
            "-subj",
            &subject,
            "-addext",
            "basicConstraints=critical,CA:FALSE",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-keyout",
            &key,
            "-out",
            &pem,
        ]);
        let san = san.map(|s| format!("subjectAltName={s}"));
        if let Some(san) = &san {
            args.extend(["-addext", san]);
        }
        openssl(&self.dir, &args);
    }

    /// A client's certificate with common name `cn`, and this CA to check the bridge with.
    pub fn client(&self, cn: &str) -> ClientTls {
        self.issue(cn, cn, None);
        ClientTls {
            cert: self.dir.join(format!("{cn}.pem")),
            key: self.dir.join(format!("{cn}.key")),
            ca: self.dir.join("ca.pem"),
        }
    }

    pub fn path(&self, file: &str) -> String {
        self.dir.join(file).display().to_string()
    }

    /// An access policy granting `control` to the certificates `who` (and `read`, `stop` to
    /// every peer of the CA): what `--allow-control` needs. Its path.
    pub fn control_policy(&self, who: &[&str]) -> String {
        let path = self.dir.join("control-policy.toml");
        let names: Vec<String> = who.iter().map(|w| format!("{w:?}")).collect();
        std::fs::write(
            &path,
            format!(
                "default = [\"read\", \"stop\"]\n\n[[grant]]\nwho = [{}]\nrights = [\"control\"]\n",
                names.join(", ")
            ),
        )
        .unwrap();
        path.display().to_string()
    }
}

impl Drop for Pki {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

impl Netns {
    pub fn create() -> Option<Netns> {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        let id = (std::process::id() % 1000) * 4 + n;
        let ns = Netns {
            name: format!("uss-zt-{id}"),
            host_if: format!("uzh{id}"),
            subnet: 1 + id % 250,
            tls: Mutex::new(None),
        };
        let peer_if = format!("uzp{id}");
        let (here, there) = (ns.here(), format!("{}/30", ns.there()));
        let made = ip(&["netns", "add", &ns.name])
            .and_then(|()| {
                ip(&[
                    "link",
                    "add",
                    &ns.host_if,
                    "type",
                    "veth",
                    "peer",
                    "name",
                    &peer_if,
                ])
            })
            .and_then(|()| ip(&["link", "set", &peer_if, "netns", &ns.name]))
            .and_then(|()| ip(&["addr", "add", &format!("{here}/30"), "dev", &ns.host_if]))
            .and_then(|()| ip(&["link", "set", &ns.host_if, "up"]))
            .and_then(|()| ip(&["-n", &ns.name, "addr", "add", &there, "dev", &peer_if]))
            .and_then(|()| ip(&["-n", &ns.name, "link", "set", &peer_if, "up"]))
            .and_then(|()| ip(&["-n", &ns.name, "link", "set", "lo", "up"]));
        match made {
            Ok(()) => Some(ns),
            Err(e) if std::env::var_os("USS_REQUIRE_NETNS").is_none() => {
                eprintln!("SKIPPED: cannot make a network namespace ({e}); run as root");
                None
            }
            Err(e) => panic!("cannot make a network namespace ({e}) but USS_REQUIRE_NETNS is set"),
        }
    }

    pub fn here(&self) -> String {
        format!("10.231.{}.1", self.subnet)
    }

    pub fn there(&self) -> String {
        format!("10.231.{}.2", self.subnet)
    }

    /// From now on the clients connect over TLS with `tls` (`None`: plain TCP again).
    pub fn use_tls(&self, tls: Option<ClientTls>) {
        *self.tls.lock().unwrap() = tls;
    }

    /// `uss-zenoh-client` in the namespace, connected to the bridge (over TLS after
    /// [`Netns::use_tls`]).
    pub fn client(&self, args: &[&str]) -> ChildProc {
        let scheme = if self.tls.lock().unwrap().is_some() {
            "tls"
        } else {
            "tcp"
        };
        self.client_of(&format!("{scheme}/{}:7447", self.here()), args)
    }

    /// `uss-zenoh-client` in the namespace, connected to `endpoint` (a router).
    pub fn client_of(&self, endpoint: &str, args: &[&str]) -> ChildProc {
        let command = self.command_of(endpoint, args);
        ChildProc::spawn(format!("uss-zenoh-client {}", args.join(" ")), command)
    }

    /// The command line of `uss-zenoh-client` in the namespace, connected to `endpoint`.
    ///
    /// A `run` is made two clock ticks after whatever came before it: its re-arm is asked at
    /// its process's start, which the kernel keeps rounded down to its tick (10 ms,
    /// `process_start_ns`), so a run started within a tick of a latch (the release of the run
    /// before it, an operator's stop) cannot show that it came after it, and is refused as the
    /// rules want (a re-arm clears no latch that may have begun after it was asked for).
    pub fn command_of(&self, endpoint: &str, args: &[&str]) -> Command {
        if args.first() == Some(&"run") {
            std::thread::sleep(std::time::Duration::from_millis(30));
        }
        let mut command = Command::new("ip");
        command
            .args(["netns", "exec", &self.name])
            .arg(CLIENT)
            .args(["--connect", endpoint]);
        if let Some(tls) = &*self.tls.lock().unwrap() {
            tls.add_to(&mut command);
        }
        command.args(args);
        command
    }

    /// Takes the link between the namespaces down or up.
    pub fn link(&self, up: bool) {
        ip(&["link", "set", &self.host_if, if up { "up" } else { "down" }]).unwrap();
    }

    /// Runs the client to its end: (success, stdout, stderr). A failure that said nothing
    /// (a signal) is named by its exit status.
    pub fn call(&self, args: &[&str]) -> (bool, String, String) {
        let (status, out, mut err) = self.client(args).finish();
        if !status.success() && err.trim().is_empty() {
            err = format!("the client ended with {status} and said nothing");
        }
        (status.success(), out, err)
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = ip(&["link", "del", &self.host_if]);
        let _ = ip(&["netns", "del", &self.name]);
    }
}

/// The Zenoh lease of the bridge and of the remote watcher: a session that hears nothing from
/// its peer for its own lease closes and withdraws the peer's liveliness tokens (Zenoh's
/// default is 10 s).
pub const LEASE_MS: u64 = 2000;

/// uss-zenoh for `bus`, listening on the namespace's near address (scouting off), over plain
/// TCP: a read-only bridge (or one with --insecure-network).
pub fn bridge(
    ns: &Netns,
    bus: &str,
    prefix: &str,
    extra: &[&str],
) -> (ChildProc, std::path::PathBuf) {
    bridge_with(ns, bus, prefix, extra, Auth::None)
}

/// uss-zenoh for `bus` as [`bridge`], over mutual TLS with `pki`'s CA and bridge certificate.
pub fn bridge_tls(
    ns: &Netns,
    bus: &str,
    prefix: &str,
    extra: &[&str],
    pki: &Pki,
) -> (ChildProc, std::path::PathBuf) {
    bridge_with(ns, bus, prefix, extra, Auth::MutualTls(pki))
}

/// uss-zenoh for `bus` as [`bridge`], over plain TCP with user/password authentication: every
/// peer logs in as a user of `dictionary` (`user:password` lines).
pub fn bridge_users(
    ns: &Netns,
    bus: &str,
    prefix: &str,
    extra: &[&str],
    dictionary: &std::path::Path,
) -> (ChildProc, std::path::PathBuf) {
    bridge_with(ns, bus, prefix, extra, Auth::Users(dictionary))
}

/// How the bridge's links authenticate peers.
#[derive(Clone, Copy)]
enum Auth<'a> {
    None,
    MutualTls(&'a Pki),
    Users(&'a std::path::Path),
}

fn bridge_with(
    ns: &Netns,
    bus: &str,
    prefix: &str,
    extra: &[&str],
    auth: Auth<'_>,
) -> (ChildProc, std::path::PathBuf) {
    let config = std::env::temp_dir().join(format!(
        "uss-zenoh-{}-{}.json5",
        std::process::id(),
        ns.name
    ));
    let (scheme, tls) = match auth {
        Auth::MutualTls(pki) => (
            "tls",
            format!(
                ", tls: {{ root_ca_certificate: \"{}\", listen_certificate: \"{bridge}\", listen_private_key: \"{key}\", connect_certificate: \"{bridge}\", connect_private_key: \"{key}\", enable_mtls: true }}",
                pki.path("ca.pem"),
                bridge = pki.path("bridge.pem"),
                key = pki.path("bridge.key")
            ),
        ),
        Auth::Users(dictionary) => (
            "tcp",
            format!(
                " }}, auth: {{ usrpwd: {{ dictionary_file: \"{}\" }}",
                dictionary.display()
            ),
        ),
        Auth::None => ("tcp", String::new()),
    };
    std::fs::write(
        &config,
        format!(
            "{{ mode: \"peer\", listen: {{ endpoints: [\"{scheme}/{}:7447\"] }}, scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }}, transport: {{ link: {{ tx: {{ lease: {LEASE_MS} }}{tls} }} }} }}",
            ns.here()
        ),
    )
    .unwrap();
    let mut command = Command::new(BRIDGE);
    command
        .args(["--bus", bus, "--prefix", prefix, "--zenoh-config"])
        .arg(&config)
        .args(extra);
    let mut child = ChildProc::spawn("uss-zenoh".into(), command);
    child.says("bridging");
    (child, config)
}
