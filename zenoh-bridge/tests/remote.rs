//! uss-zenoh across a real network boundary: ussd and the bridge in this network namespace, the
//! remote client (`uss-zenoh-client`) in a namespace of the test's own, joined by a veth pair.
//! Inputs arrive, a parameter read returns P1082 = 50.00 Hz of a simulated drive, a write is
//! refused by default and works with `--allow-writes`, killing ussd withdraws the bus's
//! liveliness token and marks the inputs stale, killing the bridge withdraws its own.
//!
//! Creating namespaces needs root; without it the test says it is skipped. CI runs as root and
//! sets `USS_REQUIRE_NETNS`, so there it cannot be skipped.

#![allow(clippy::unwrap_used, clippy::float_cmp)]

use serde_json::Value;
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};
use uss_integration_tests::{ChildProc, Ussd};

/// This package's binaries, built by cargo for this test with the test's own features (a
/// separate `cargo build -p uss-zenoh` would resolve zenoh's features anew and rebuild it).
const BRIDGE: &str = env!("CARGO_BIN_EXE_uss-zenoh");
const CLIENT: &str = env!("CARGO_BIN_EXE_uss-zenoh-client");

/// A network namespace joined to this one by a veth pair: here 10.231.N.1, there 10.231.N.2.
struct Netns {
    name: String,
    host_if: String,
    subnet: u32,
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
    fn create() -> Option<Netns> {
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

    fn here(&self) -> String {
        format!("10.231.{}.1", self.subnet)
    }

    fn there(&self) -> String {
        format!("10.231.{}.2", self.subnet)
    }

    /// `uss-zenoh-client` in the namespace, connected to the bridge.
    fn client(&self, args: &[&str]) -> ChildProc {
        let mut command = Command::new("ip");
        command
            .args(["netns", "exec", &self.name])
            .arg(CLIENT)
            .args(["--connect", &format!("tcp/{}:7447", self.here())])
            .args(args);
        ChildProc::spawn(format!("uss-zenoh-client {}", args.join(" ")), command)
    }

    /// Runs the client to its end: (success, stdout, stderr).
    fn call(&self, args: &[&str]) -> (bool, String, String) {
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

/// uss-zenoh for `bus`, listening on the namespace's near address (scouting off).
fn bridge(ns: &Netns, bus: &str, prefix: &str, extra: &[&str]) -> (ChildProc, std::path::PathBuf) {
    let config = std::env::temp_dir().join(format!(
        "uss-zenoh-{}-{}.json5",
        std::process::id(),
        ns.name
    ));
    std::fs::write(
        &config,
        format!(
            "{{ mode: \"peer\", listen: {{ endpoints: [\"tcp/{}:7447\"] }}, scouting: {{ multicast: {{ enabled: false }}, gossip: {{ enabled: false }} }} }}",
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

/// `zenoh-bridge/examples/read_param.py` in the namespace reads `key`: P1082 = 50.0 Hz. Without
/// the `eclipse-zenoh` package it says it is skipped, unless `USS_REQUIRE_PY_ZENOH` is set (CI).
fn python_reads_p1082(ns: &Netns, key: &str) {
    let has = Command::new("python3")
        .args(["-c", "import zenoh"])
        .status()
        .is_ok_and(|s| s.success());
    if !has {
        assert!(
            std::env::var_os("USS_REQUIRE_PY_ZENOH").is_none(),
            "python3 cannot import zenoh but USS_REQUIRE_PY_ZENOH is set"
        );
        eprintln!("SKIPPED the Python client: pip install eclipse-zenoh==1.10.2");
        return;
    }
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/read_param.py");
    let out = Command::new("ip")
        .args(["netns", "exec", &ns.name, "python3"])
        .arg(script)
        .args([&format!("tcp/{}:7447", ns.here()), key])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(text.trim(), "50.0 Hz (P1082 Max. frequency)");
}

fn json(line: &str) -> Value {
    serde_json::from_str(line.trim()).unwrap_or_else(|e| panic!("{e}: {line:?}"))
}

#[test]
fn a_remote_client_reads_inputs_and_parameters_and_sees_ussd_go() {
    let Some(ns) = Netns::create() else { return };
    let mut ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/t{}", std::process::id());
    let key = |rest: &str| format!("{prefix}/{bus}/{rest}");
    let (mut bridge_proc, config) = bridge(&ns, &bus, &prefix, &[]);

    inputs_arrive(&ns, &key);

    parameters_read_and_writes_refused(&ns, &key);

    // ussd killed: the bus's token goes, the last image comes once more, marked stale.
    let mut alive = ns.client(&["alive", &key("alive"), "--count", "2", "--timeout", "30"]);
    alive.says(&format!("+ {}", key("alive")));
    let mut inputs = ns.client(&[
        "sub",
        &key("drive/1/in"),
        "--count",
        "100000",
        "--timeout",
        "30",
    ]);
    inputs.says("\"stale\":false");
    let killed = Instant::now();
    ussd.kill();
    alive.says(&format!("- {}", key("alive")));
    let withdrawn = killed.elapsed();
    let stale = inputs.says("\"stale\":true");
    assert!(stale.contains("\"online\":false"), "{stale}");
    println!(
        "liveliness of the bus withdrawn {:.0} ms after ussd was killed",
        withdrawn.as_secs_f64() * 1e3
    );
    assert!(withdrawn < Duration::from_secs(3), "{withdrawn:?}");
    inputs.kill();

    // With --allow-writes (and ussd back), a write goes to the drive and reads back.
    ussd.restart();
    bridge_proc.kill();
    let (mut bridge_proc, _) = bridge(&ns, &bus, &prefix, &["--allow-writes"]);
    let deadline = Instant::now() + Duration::from_secs(15);
    let written = loop {
        let (ok, out, err) = ns.call(&["get", &key("drive/1/param/P1082"), "--value", "45"]);
        if ok {
            break json(&out);
        }
        assert!(
            Instant::now() < deadline,
            "the write never went through: {err}"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(
        (written["value"].as_f64(), written["written"].as_bool()),
        (Some(45.0), Some(false))
    );
    let (ok, out, err) = ns.call(&["get", &key("drive/1/param/P1082")]);
    assert!(ok, "{err}");
    assert_eq!(json(&out)["value"].as_f64(), Some(45.0));
    // A value the parameter cannot take is refused before the bus, with ussctl's words.
    let (ok, _, err) = ns.call(&["get", &key("drive/1/param/P1082"), "--value", "fast"]);
    assert!(!ok);
    assert!(
        err.contains("drive 1 P1082: \"fast\" is not a number"),
        "{err}"
    );

    // The bridge killed: its own token goes.
    let mut alive = ns.client(&[
        "alive",
        &format!("{prefix}/bridge"),
        "--count",
        "2",
        "--timeout",
        "30",
    ]);
    alive.says(&format!("+ {prefix}/bridge"));
    let killed = Instant::now();
    bridge_proc.kill();
    alive.says(&format!("- {prefix}/bridge"));
    println!(
        "liveliness of the bridge withdrawn {:.0} ms after it was killed",
        killed.elapsed().as_secs_f64() * 1e3
    );
    let _ = std::fs::remove_file(config);
}

/// Every new image of drive 1 as JSON version 1, the status, drive 2's description.
fn inputs_arrive(ns: &Netns, key: &dyn Fn(&str) -> String) {
    // Inputs: every new image of drive 1, as JSON version 1.
    let (ok, out, err) = ns.call(&["sub", &key("drive/1/in"), "--count", "3"]);
    assert!(ok, "{err}");
    let images: Vec<Value> = out.lines().map(json).collect();
    assert_eq!(images.len(), 3);
    for i in &images {
        assert_eq!(
            (i["v"].as_u64(), i["drive"].as_u64()),
            (Some(1), Some(1)),
            "{i}"
        );
        assert_eq!(
            (i["online"].as_bool(), i["stale"].as_bool()),
            (Some(true), Some(false))
        );
        assert_eq!(
            (i["state"].as_str(), i["control"].as_str()),
            (Some("S2"), Some("latched"))
        );
        assert!(i["stw1"].as_u64().unwrap() & 0x0400 != 0);
    }
    assert!(images[0]["sequence"].as_u64() < images[2]["sequence"].as_u64());
    let (ok, out, err) = ns.call(&["sub", &key("status")]);
    assert!(ok, "{err}");
    let status = json(&out);
    assert_eq!(
        (status["ussd"].as_str(), status["stale"].as_bool()),
        (Some("running"), Some(false))
    );
    let (ok, out, err) = ns.call(&["sub", &key("drive/2/info")]);
    assert!(ok, "{err}");
    assert_eq!(json(&out)["reference_hz"].as_f64(), Some(50.0));
}

/// P1082 read from Rust and Python; a write refused by default; a drive that is not there.
fn parameters_read_and_writes_refused(ns: &Netns, key: &dyn Fn(&str) -> String) {
    // A parameter read from the real (simulated) drive, in the parameter's own type.
    let (ok, out, err) = ns.call(&["get", &key("drive/1/param/P1082")]);
    assert!(ok, "{err}");
    let p = json(&out);
    assert_eq!(p["value"].as_f64(), Some(50.0), "{p}");
    assert_eq!(
        (p["param"].as_str(), p["unit"].as_str()),
        (Some("P1082"), Some("Hz"))
    );
    assert_eq!(p["shown"].as_str(), Some("50.00 Hz"));
    // The same from Python (eclipse-zenoh, the README's example), in the other namespace too.
    python_reads_p1082(ns, &key("drive/1/param/P1082"));
    // A write is refused by default, with a reply that says why; a bad key says why too.
    let (ok, _, err) = ns.call(&["get", &key("drive/1/param/P1082"), "--value", "45"]);
    assert!(!ok);
    assert!(
        err.contains("writes are refused: this uss-zenoh runs without --allow-writes"),
        "{err}"
    );
    let (ok, _, err) = ns.call(&["get", &key("drive/7/param/P1082")]);
    assert!(!ok);
    assert!(err.contains("drive 7 P1082:"), "{err}");
}
