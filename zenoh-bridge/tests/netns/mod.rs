//! A network namespace of the test's (or the benchmark's) own, joined to this one by a veth pair,
//! with `uss-zenoh` listening on this side and `uss-zenoh-client` run on the other. Shared by
//! the remote tests and the remote benchmark (`#[path]`), so not every item is used by both.

#![allow(dead_code, clippy::unwrap_used)]

use std::process::Command;
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

    /// `uss-zenoh-client` in the namespace, connected to the bridge.
    pub fn client(&self, args: &[&str]) -> ChildProc {
        self.client_of(&format!("tcp/{}:7447", self.here()), args)
    }

    /// `uss-zenoh-client` in the namespace, connected to `endpoint` (a router).
    pub fn client_of(&self, endpoint: &str, args: &[&str]) -> ChildProc {
        let command = self.command_of(endpoint, args);
        ChildProc::spawn(format!("uss-zenoh-client {}", args.join(" ")), command)
    }

    /// The command line of `uss-zenoh-client` in the namespace, connected to `endpoint`.
    pub fn command_of(&self, endpoint: &str, args: &[&str]) -> Command {
        let mut command = Command::new("ip");
        command
            .args(["netns", "exec", &self.name])
            .arg(CLIENT)
            .args(["--connect", endpoint])
            .args(args);
        command
    }

    /// Takes the link between the namespaces down or up.
    pub fn link(&self, up: bool) {
        ip(&["link", "set", &self.host_if, if up { "up" } else { "down" }]).unwrap();
    }

    /// Runs the client to its end: (success, stdout, stderr).
    pub fn call(&self, args: &[&str]) -> (bool, String, String) {
        let (status, out, err) = self.client(args).finish();
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

/// uss-zenoh for `bus`, listening on the namespace's near address (scouting off).
pub fn bridge(
    ns: &Netns,
    bus: &str,
    prefix: &str,
    extra: &[&str],
) -> (ChildProc, std::path::PathBuf) {
    let config = std::env::temp_dir().join(format!(
        "uss-zenoh-{}-{}.json5",
        std::process::id(),
        ns.name
    ));
    std::fs::write(
        &config,
        format!(
            "{{ mode: \"peer\", listen: {{ endpoints: [\"tcp/{}:7447\"] }}, scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }}, transport: {{ link: {{ tx: {{ lease: {LEASE_MS} }} }} }} }}",
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
