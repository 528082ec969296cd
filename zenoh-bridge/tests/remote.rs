//! uss-zenoh across a real network boundary: ussd and the bridge in this network namespace, the
//! remote client (`uss-zenoh-client`) in a namespace of the test's own, joined by a veth pair.
//! Inputs arrive, a parameter read returns P1082 = 50.00 Hz of a simulated drive, a write is
//! refused by default and works with `--allow-writes`, killing ussd withdraws the bus's
//! liveliness token and marks the inputs stale, killing the bridge withdraws its own.
//!
//! Remote control across the same boundary: refused by default; with `--allow-control` a remote
//! `uss-zenoh-client run` re-arms and runs a drive, and taking the veth link down trips it
//! (safe command, latched) within the watchdog time; the link back up does not restart it, only a
//! new run does; an operator's stop from either side and a killed bridge latch it too.
//! A bridge paused at the hand-over still takes the run's release when it resumes.
//!
//! A bridge that moves motors or writes runs on mutual TLS (certificates made by the test with
//! openssl as the guide shows): on plain TCP it refuses to start, and a client without a
//! certificate, or with one of another CA, does not get in (and the drive does not move).
//!
//! Creating namespaces needs root; without it the test says it is skipped. CI runs as root and
//! sets `USS_REQUIRE_NETNS`, so there it cannot be skipped.

#![allow(clippy::unwrap_used, clippy::float_cmp)]

mod netns;

use netns::{LEASE_MS, Netns, Pki, bridge, bridge_tls, bridge_users};
use serde_json::Value;
use std::process::Command;
use std::time::{Duration, Instant};
use uss_client::{ControlState, DriveWatch, LatchReason, PzdInput};
use uss_integration_tests::addr;
use uss_integration_tests::{BusSpec, ChildProc, Ussd, assert_report};

/// `zenoh-bridge/examples/read_param.py` in the namespace reads `key`: P1082 = 50.0 Hz (over
/// mutual TLS with `tls`). Without the `eclipse-zenoh` package it says it is skipped, unless
/// `USS_REQUIRE_PY_ZENOH` is set (CI).
/// The controller watchdog of the drives here: a remote run's samples cross a namespace link,
/// a bridge and two Zenoh sessions, on a machine that runs the other tests at once; at the
/// default 100 ms a loaded 2-core CI machine tripped runs "controller stale" that were meant to
/// end otherwise (an operator's stop, a hand-over). The trips these tests are about come from
/// the watchdog all the same, at this time.
const WATCHDOG: &str = "watchdog_ms = 500";
/// A drive with two settings beyond uss-rt's catalogue (uss-sim's extras), for a backup that
/// asks the drive for them.
const WITH_EXTRAS: &str = "watchdog_ms = 500\nsim = { extra = \"701-702\" }";

fn python_reads_p1082(ns: &Netns, key: &str, tls: Option<&netns::ClientTls>) {
    if !python_has_zenoh("the Python client") {
        return;
    }
    let script = example("read_param.py");
    let scheme = if tls.is_some() { "tls" } else { "tcp" };
    let mut command = Command::new("ip");
    command
        .args(["netns", "exec", &ns.name, "python3"])
        .arg(script)
        .args([&format!("{scheme}/{}:7447", ns.here()), key]);
    if let Some(tls) = tls {
        tls.add_to(&mut command);
    }
    let out = command.output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(text.trim(), "50.0 Hz (P1082 Max. frequency)");
}

/// Whether `python3` has the `eclipse-zenoh` package; without it `what` is skipped (said on
/// stderr), unless `USS_REQUIRE_PY_ZENOH` is set (CI).
fn python_has_zenoh(what: &str) -> bool {
    let has = Command::new("python3")
        .args(["-c", "import zenoh"])
        .status()
        .is_ok_and(|s| s.success());
    if !has {
        assert!(
            std::env::var_os("USS_REQUIRE_PY_ZENOH").is_none(),
            "python3 cannot import zenoh but USS_REQUIRE_PY_ZENOH is set"
        );
        eprintln!("SKIPPED {what}: pip install eclipse-zenoh==1.10.2");
    }
    has
}

fn example(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples")
        .join(name)
}

/// A remote watcher of the liveliness token `key` (with the client options `options`), once it
/// has seen the token.
fn watch_alive(ns: &Netns, key: &str, options: &[&str]) -> ChildProc {
    let mut args = options.to_vec();
    args.extend(["alive", key, "--count", "2", "--timeout", "30"]);
    let mut alive = ns.client(&args);
    alive.says(&format!("+ {key}"));
    alive
}

/// uss-zenoh for `bus` over mutual TLS with `--allow-control`, under a policy that grants
/// `control` to the certificate `controller` (what `--allow-control` needs).
fn controlling_bridge(
    ns: &Netns,
    bus: &str,
    prefix: &str,
    pki: &Pki,
) -> (ChildProc, std::path::PathBuf) {
    let policy = pki.control_policy(&["controller"]);
    bridge_tls(
        ns,
        bus,
        prefix,
        &["--allow-control", "--policy", &policy],
        pki,
    )
}

/// Puts `payload` on the drive's `out` key from the other side, under the key of peer `name`
/// (`<prefix>/<bus>/as/<name>/drive/...`, as a named controller sends: the bridge judges it by
/// that name's rights; a listed certificate's put under another key Zenoh's access control
/// drops), and returns the rest of the bridge's control report that says `expect`.
fn put_sample(ns: &Netns, drive: &str, name: &str, payload: &str, expect: &str) -> String {
    let mut reports = ns.client(&[
        "sub",
        &format!("{drive}/control"),
        "--count",
        "100",
        "--timeout",
        "10",
    ]);
    // Put until the report comes: the subscriber may not be there for the first one (every
    // refusal changes the report, so each put brings one).
    let done = std::sync::atomic::AtomicBool::new(false);
    let key = format!(
        "{}/out",
        drive.replace("/drive/", &format!("/as/{name}/drive/"))
    );
    let report = std::thread::scope(|scope| {
        scope.spawn(|| {
            for _ in 0..20 {
                if done.load(std::sync::atomic::Ordering::Relaxed) {
                    break;
                }
                let (ok, _, err) = ns.call(&["put", &key, payload]);
                assert!(ok, "{err}");
                std::thread::sleep(Duration::from_millis(300));
            }
        });
        // Each report as its shipped schema describes it.
        let report = loop {
            let line = format!("{{\"v\":1{}", reports.says("{\"v\":1"));
            assert_report("zenoh/control", &line);
            if let Some((_, rest)) = line.split_once(expect) {
                break rest.to_owned();
            }
        };
        done.store(true, std::sync::atomic::Ordering::Relaxed);
        report
    });
    reports.kill();
    report
}

/// Waits until the bridge answers a parameter read of `drive` over TLS: its first TLS session
/// takes a moment on a loaded machine, and a run or a check that starts before it would fail
/// for that alone.
fn answers_over_tls(ns: &Netns, drive: &str) {
    answers(ns, &[], drive);
}

/// Waits until the bridge answers a parameter read of `drive` from a client started with
/// `options` (a login of its own).
fn answers(ns: &Netns, options: &[&str], drive: &str) {
    let deadline = Instant::now() + Duration::from_secs(15);
    let key = format!("{drive}/param/P1121");
    let args: Vec<&str> = options
        .iter()
        .copied()
        .chain(["get", key.as_str()])
        .collect();
    while !ns.call(&args).0 {
        assert!(
            Instant::now() < deadline,
            "the bridge never answered over TLS"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Whether a remote run's failure says an operator stopped its drive: from the image it saw
/// (`(operator stop)`), or from the bridge's refusal of a sample it sent before that image
/// reached it (`latched (an operator sent OFF1 ...)`): which comes first is the network's.
fn stopped_by_an_operator(err: &str) -> bool {
    err.contains("(operator stop)") || err.contains("latched (an operator sent OFF")
}

fn json(line: &str) -> Value {
    serde_json::from_str(line.trim()).unwrap_or_else(|e| panic!("{e}: {line:?}"))
}

#[test]
fn a_remote_client_reads_inputs_and_parameters_and_sees_ussd_go() {
    let Some(ns) = Netns::create() else { return };
    let mut ussd = Ussd::start("", &[(1, WATCHDOG), (2, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/t{}", std::process::id());
    let key = |rest: &str| format!("{prefix}/{bus}/{rest}");
    let (mut bridge_proc, config) = bridge(&ns, &bus, &prefix, &[]);

    inputs_arrive(&ns, &key);

    parameters_read_and_writes_refused(&ns, &key);

    diagnostics_of_a_paused_ussd_say_stale(&ns, &ussd, &key("drive/1/diag"));

    sub_for_writes_each_sample_as_it_comes(&ns, &key("drive/2/info"));

    // ussd killed: the bus's token goes, the last image comes once more, marked stale.
    let mut alive = watch_alive(&ns, &key("alive"), &[]);
    let mut inputs = ns.client(&[
        "sub",
        &key("drive/1/in"),
        "--count",
        "100000",
        "--timeout",
        "30",
    ]);
    let mut diags = ns.client(&[
        "sub",
        &key("drive/1/diag"),
        "--count",
        "100000",
        "--timeout",
        "30",
    ]);
    inputs.says("\"stale\":false");
    diags.says("\"stale\":false");
    let killed = Instant::now();
    ussd.kill();
    alive.says(&format!("- {}", key("alive")));
    let withdrawn = killed.elapsed();
    let stale = inputs.says("\"stale\":true");
    assert!(stale.contains("\"online\":false"), "{stale}");
    // The diagnostics too (rule 3): their last put must not stand as a live drive.
    let stale = diags.says("\"stale\":true");
    assert!(stale.contains("\"online\":false"), "{stale}");
    diags.kill();
    println!(
        "liveliness of the bus withdrawn {:.0} ms after ussd was killed",
        withdrawn.as_secs_f64() * 1e3
    );
    assert!(withdrawn < Duration::from_secs(3), "{withdrawn:?}");
    inputs.kill();

    // ussd back with another drive list: the bridge follows it (drive 5 is new).
    ussd.restart_with(&[BusSpec {
        suffix: "",
        device: "sim",
        keys: "",
        drives: &[(1, WATCHDOG), (2, WATCHDOG), (5, WATCHDOG)],
    }]);
    let (ok, out, err) = ns.call(&["sub", &key("drive/5/in")]);
    assert!(ok, "{err}");
    assert_eq!(json(&out)["drive"].as_u64(), Some(5));

    // With --allow-writes (over mutual TLS: writes need authenticated links), a write goes to
    // the drive and reads back.
    bridge_proc.kill();
    let pki = Pki::new("writes", "uss-rt test CA", &ns.here());
    let engineer = pki.client("engineer");
    ns.use_tls(Some(engineer.clone()));
    let (mut bridge_proc, _) = bridge_tls(&ns, &bus, &prefix, &["--allow-writes"], &pki);
    // The guide's Python example over mutual TLS too.
    answers_over_tls(&ns, &key("drive/1"));
    python_reads_p1082(&ns, &key("drive/1/param/P1082"), Some(&engineer));
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
        err.contains("drive 1 P1082: \"fast\" is not a number") && err.contains("[value]"),
        "{err}"
    );

    // The bridge killed: its own token goes.
    let mut alive = watch_alive(&ns, &format!("{prefix}/bridge"), &[]);
    let killed = Instant::now();
    bridge_proc.kill();
    alive.says(&format!("- {prefix}/bridge"));
    println!(
        "liveliness of the bridge withdrawn {:.0} ms after it was killed",
        killed.elapsed().as_secs_f64() * 1e3
    );
    let _ = std::fs::remove_file(config);
}

/// `kill -STOP` / `kill -CONT` (`name`) to process `pid`.
fn signal(name: &str, pid: u32) {
    let ok = Command::new("kill")
        .args([name, &pid.to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill {name} {pid}");
}

/// `sub --for` writes each sample as it comes, not when its output buffer fills or it ends (the
/// fourth adversarial run: a pipe's reader got the bridge's "stale" 3 s late). `key` is a
/// drive's info, a short line every 5 s, which used to come only at the end.
fn sub_for_writes_each_sample_as_it_comes(ns: &Netns, key: &str) {
    let mut held = ns.client(&["sub", key, "--for", "30", "--count", "9"]);
    held.says("reference_hz");
    // A sub that wrote it only on its way out has ended by now.
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        held.child.try_wait().unwrap().is_none(),
        "the line came only when sub ended"
    );
    held.kill();
}

/// ussd paused (a stalled process): a diagnostics put of the drive at `key` published past the
/// drive's freshness limit says it is stale and not online (rule 3), also in the time before
/// ussd's heartbeat stops counting as serving (its limit, `GONE_AFTER_NS`, is longer; after
/// it, the bridge puts the last diagnostics again, marked stale). The pause is timed so that the bridge's next put (one a
/// second) falls in the middle of that window.
fn diagnostics_of_a_paused_ussd_say_stale(ns: &Netns, ussd: &Ussd, key: &str) {
    let limit_ns = ussd.bus().diag(addr(1)).unwrap().stale_after_ns;
    let gone_ns = uss_client::uss_shm_types::names::GONE_AFTER_NS;
    println!(
        "remote: drive 1's diagnostics are stale after {limit_ns} ns, ussd gone after {gone_ns} ns"
    );
    assert!(limit_ns + 200_000_000 < gone_ns, "no window to test in");
    let unix_ns = || {
        let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH);
        u64::try_from(t.unwrap().as_nanos()).unwrap()
    };
    let signal = |name: &str| signal(name, ussd.child.id());
    let mut diags = ns.client(&["sub", key, "--count", "100000", "--timeout", "30"]);
    diags.says("\"online\":true");
    let put = json(&diags.says(""))["published_unix_ns"].as_u64().unwrap();
    // The next put comes a second after this one: pause so that it lands mid-window.
    let pause_at = put + 1_000_000_000 - u64::midpoint(limit_ns, gone_ns);
    std::thread::sleep(Duration::from_nanos(pause_at.saturating_sub(unix_ns())));
    let paused = unix_ns();
    signal("-STOP");
    std::thread::sleep(Duration::from_millis(1500));
    signal("-CONT");
    let resumed = unix_ns();
    let mut in_the_window = 0;
    loop {
        let line = diags.says("");
        let d = json(&line);
        let published = d["published_unix_ns"].as_u64().unwrap();
        if published > resumed {
            break;
        }
        if published > paused + limit_ns + 20_000_000 {
            let view = &d["drive_status"];
            assert_eq!(
                (d["online"].as_bool(), d["stale"].as_bool()),
                (Some(false), Some(true)),
                "a diagnostics put {} ms into a pause of ussd: {line}",
                (published - paused) / 1_000_000
            );
            assert_eq!(
                (view["online"].as_bool(), view["stale"].as_bool()),
                (Some(false), Some(true)),
                "a diagnostics put {} ms into a pause of ussd: {line}",
                (published - paused) / 1_000_000
            );
            in_the_window += 1;
        }
    }
    diags.kill();
    println!("remote: {in_the_window} diagnostics put(s) of a paused ussd past the limit");
    assert!(in_the_window >= 1, "no diagnostics put in the window");
}

/// Every new image of drive 1 as JSON version 1, the status, drive 2's description.
fn inputs_arrive(ns: &Netns, key: &dyn Fn(&str) -> String) {
    // Inputs: every new image of drive 1, as JSON version 1.
    let (ok, out, err) = ns.call(&["sub", &key("drive/1/in"), "--count", "3"]);
    assert!(ok, "{err}");
    let images: Vec<Value> = out.lines().map(json).collect();
    assert_eq!(images.len(), 3);
    // Each payload as its shipped schema (docs/schema/zenoh/) describes it.
    for line in out.lines() {
        assert_report("zenoh/in", line);
    }
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
    reader_goes_away(ns, &["sub", &key("drive/1/in"), "--count", "100000"]);
    let (ok, out, err) = ns.call(&["sub", &key("status")]);
    assert!(ok, "{err}");
    assert_report("zenoh/status", out.trim());
    let status = json(&out);
    assert_eq!(
        (status["ussd"].as_str(), status["stale"].as_bool()),
        (Some("running"), Some(false))
    );
    // The client's one view of the bus, as ussctl and Python show it.
    assert_eq!(
        (
            status["bus_status"]["line"].as_str(),
            status["bus_status"]["drive_count"].as_u64()
        ),
        (Some("up"), status["drives"].as_u64())
    );
    assert!(status["bus_status"]["good"].as_u64() > Some(0), "{status}");
    let (ok, out, err) = ns.call(&["sub", &key("drive/2/info")]);
    assert!(ok, "{err}");
    assert_report("zenoh/info", out.trim());
    assert_eq!(json(&out)["reference_hz"].as_f64(), Some(50.0));
    let (ok, out, err) = ns.call(&["sub", &key("drive/2/diag")]);
    assert!(ok, "{err}");
    assert_report("zenoh/diag", out.trim());
    // The client's one view of the drive, as ussctl status --json shows it.
    let view = &json(&out)["drive_status"];
    assert_eq!(
        (
            view["address"].as_u64(),
            view["online"].as_bool(),
            view["state"].as_str()
        ),
        (Some(2), Some(true), Some("S2")),
        "{out}"
    );
}

/// `uss-zenoh-client ARGS | head -1`: the reader goes away after one line, and the client
/// ends quietly (it used to panic on the closed pipe, or fail with "stdout: Broken pipe").
fn reader_goes_away(ns: &Netns, args: &[&str]) {
    use std::io::BufRead as _;
    let mut child = ns
        .command_of(&format!("tcp/{}:7447", ns.here()), args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    stdout.read_line(&mut first).unwrap();
    assert!(first.starts_with('{'), "{first}");
    drop(stdout);
    let deadline = Instant::now() + Duration::from_secs(10);
    while child.try_wait().unwrap().is_none() {
        assert!(
            Instant::now() < deadline,
            "{args:?} still runs after its reader went away"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.is_empty(),
        "{args:?}: {:?} {err}",
        out.status
    );
}

/// P1082 read from Rust and Python; a write refused by default; a drive that is not there.
fn parameters_read_and_writes_refused(ns: &Netns, key: &dyn Fn(&str) -> String) {
    // A parameter read from the real (simulated) drive, in the parameter's own type.
    let (ok, out, err) = ns.call(&["get", &key("drive/1/param/P1082")]);
    assert!(ok, "{err}");
    reader_goes_away(ns, &["get", &key("drive/1/param/P1082"), "--repeat", "20"]);
    assert_report("zenoh/param", out.trim());
    let p = json(&out);
    assert_eq!(p["value"].as_f64(), Some(50.0), "{p}");
    assert_eq!(
        (p["param"].as_str(), p["unit"].as_str()),
        (Some("P1082"), Some("Hz"))
    );
    assert_eq!(p["shown"].as_str(), Some("50.00 Hz"));
    // The same from Python (eclipse-zenoh, the guide's example), in the other namespace too.
    python_reads_p1082(ns, &key("drive/1/param/P1082"), None);
    // A write is refused by default, with a reply that says why; a bad key says why too.
    let (ok, _, err) = ns.call(&["get", &key("drive/1/param/P1082"), "--value", "45"]);
    assert!(!ok);
    // Each error reply says its kind from the error table (the C status, the Python
    // exception): a refusal, an unknown drive.
    assert!(
        err.contains("writes are refused: this uss-zenoh runs without --allow-writes [refused]"),
        "{err}"
    );
    let (ok, _, err) = ns.call(&["get", &key("drive/7/param/P1082")]);
    assert!(!ok);
    assert!(err.contains("drive 7 P1082:"), "{err}");
    assert!(err.contains("[unknown_drive]"), "{err}");
}

/// Waits until the drive's image satisfies `done`, at most `timeout`; the image and how long it
/// took.
fn wait_image(
    watch: &DriveWatch,
    timeout: Duration,
    what: &str,
    done: impl Fn(&PzdInput) -> bool,
) -> (PzdInput, Duration) {
    let start = Instant::now();
    loop {
        let i = watch.latest();
        if done(&i) {
            return (i, start.elapsed());
        }
        assert!(
            start.elapsed() < timeout,
            "drive {} not {what} within {timeout:?}: control {}, latch {}, zsw1 {:#06x}",
            watch.address(),
            i.control,
            i.latch_reason,
            i.zsw1
        );
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn latched(i: &PzdInput) -> bool {
    i.control == ControlState::Latched.code()
}

fn reason(i: &PzdInput) -> LatchReason {
    LatchReason::try_from(i.latch_reason).unwrap()
}

/// The guide's two hosts through a router: the bridge and the remote client each connect to a
/// Zenoh router (here eclipse-zenoh's, `examples/router.py`, in place of `zenohd`), neither to
/// the other.
#[test]
fn a_remote_client_reaches_the_bridge_through_a_router() {
    let Some(ns) = Netns::create() else { return };
    if !python_has_zenoh("the router test") {
        return;
    }
    let ussd = Ussd::start("", &[(1, WATCHDOG)]);
    // The guide's router, over mutual TLS: the router, the bridge and the client each show a
    // certificate of the plant's CA.
    let pki = Pki::new("router", "uss-rt test CA", &ns.here());
    let (cert, key) = pki.server("router", &ns.here());
    let router_at = format!("tls/{}:7448", ns.here());
    let mut command = Command::new("python3");
    command.arg(example("router.py")).arg(&router_at).args([
        "--cert",
        &cert,
        "--key",
        &key,
        "--ca",
        &pki.path("ca.pem"),
    ]);
    let mut router = ChildProc::spawn("router.py".into(), command);
    router.says("listening on");
    let prefix = format!("uss/r{}", std::process::id());
    let (_bridge, config) = bridge_tls(&ns, &ussd.bus, &prefix, &["--connect", &router_at], &pki);
    let key = format!("{prefix}/{}/drive/1/param/P1082", ussd.bus);
    // A client without a certificate does not get in.
    let (status, _, err) = ns.client_of(&router_at, &["get", &key]).finish();
    assert!(
        !status.success()
            && err.contains("cannot open the Zenoh session")
            && err.contains("(--cert, --key, --ca)")
            && !err.contains(".rs:"),
        "{err}"
    );
    ns.use_tls(Some(pki.client("hmi-1")));
    // The router learns the bridge's queryable when the bridge has connected.
    let deadline = Instant::now() + Duration::from_secs(15);
    let read = loop {
        let (status, out, err) = ns.client_of(&router_at, &["get", &key]).finish();
        if status.success() {
            break json(&out);
        }
        assert!(Instant::now() < deadline, "never answered: {err}");
        std::thread::sleep(Duration::from_millis(200));
    };
    assert_eq!(read["value"].as_f64(), Some(50.0), "{read}");
    let inputs = format!("{prefix}/{}/drive/1/in", ussd.bus);
    let (status, out, err) = ns.client_of(&router_at, &["sub", &inputs]).finish();
    assert!(status.success(), "{err}");
    assert_eq!(json(&out)["online"].as_bool(), Some(true));
    let _ = std::fs::remove_file(config);
}

#[test]
fn remote_control_is_refused_by_default_and_fail_safe_across_the_network() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WATCHDOG), (2, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/c{}", std::process::id());
    let drive = format!("{prefix}/{bus}/drive/1");
    let watch = ussd.bus().watch(addr(1)).unwrap();

    // By default a remote controller is told no, and the drive keeps its safe command.
    let (mut bridge_proc, config) = bridge(&ns, &bus, &prefix, &[]);
    let (ok, _, err) = ns.call(&["run", &drive, "--hz", "10"]);
    assert!(!ok);
    assert!(
        err.contains("remote control is refused: this uss-zenoh runs without --allow-control"),
        "{err}"
    );
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Startup);
    assert_eq!(i.sent_stw1, 0x047E);
    bridge_proc.kill();

    // With --allow-control (over mutual TLS) the remote run re-arms (OFF1, then ON) and runs
    // the drive.
    let pki = Pki::new("control", "uss-rt test CA", &ns.here());
    ns.use_tls(Some(pki.client("controller")));
    let (mut bridge_proc, _) = controlling_bridge(&ns, &bus, &prefix, &pki);
    answers_over_tls(&ns, &drive);
    let mut run = ns.client(&["run", &drive, "--hz", "10"]);
    run.says("re-armed");
    let (i, _) = wait_image(&watch, Duration::from_secs(10), "above 3 Hz", |i| {
        hz(i) > 3.0
    });
    assert!(!latched(&i) && i.sent_stw1 == 0x047F, "{i:?}");

    let lease = link_down_trips_and_latches(&ns, &prefix, &watch, run);
    let _ = std::fs::remove_file(lease);

    // An OFF1 that does not name the latch (sent before it, or by one that never saw it)
    // re-arms nothing.
    let report = put_sample(
        &ns,
        &drive,
        "controller",
        r#"{"v":1,"from":"late","seq":1,"stw1":1150,"hz":0.0}"#,
        "is latched",
    );
    assert!(
        report.contains("re-arm it with a stop naming the latch"),
        "{report}"
    );
    // The kind of the refusal from the error table, as a local program gets it.
    assert!(
        report.contains(r#""error_kind":"tripped","error_code":8"#),
        "{report}"
    );
    std::thread::sleep(Duration::from_millis(300));
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Stale, "{i:?}");

    // Only a new, deliberate run re-arms it.
    let (ok, out, err) = ns.call(&["run", &drive, "--hz", "5", "--for", "1"]);
    assert!(ok, "{out}{err}");
    assert!(
        out.contains("re-armed") && out.contains("and released"),
        "{out}"
    );
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Released, "{i:?}");

    operator_stops_latch(&ns, &ussd, &drive);

    // A sample the bridge cannot read is refused, reported, and not passed on.
    let report = put_sample(&ns, &drive, "controller", "run fast", "not a sample");
    assert!(report.contains("send e.g."), "{report}");
    assert!(
        report.contains(r#""error_kind":"invalid_sample""#),
        "{report}"
    );

    // A bridge that dies is a stale controller: latched within the watchdog time.
    let mut run = ns.client(&["run", &drive, "--hz", "10"]);
    run.says("re-armed");
    wait_image(&watch, Duration::from_secs(5), "live", |i| !latched(i));
    let killed = Instant::now();
    bridge_proc.kill();
    let (i, _) = wait_image(&watch, Duration::from_secs(3), "latched", latched);
    assert_eq!(reason(&i), LatchReason::Stale);
    println!(
        "drive latched {:.0} ms after the bridge was killed",
        killed.elapsed().as_secs_f64() * 1e3
    );
    run.kill();
    let _ = std::fs::remove_file(config);
}

fn hz(i: &PzdInput) -> f32 {
    uss_client::Setpoint::from_word(i.hiw).hz(50.0)
}

/// The link between the namespaces goes down while `run` controls drive 1: the drive trips within
/// its watchdog time, the blind `run` gives up, the remote side learns within the lease that the
/// bridge is unreachable; the link back up restarts nothing. Returns the lease file to remove.
fn link_down_trips_and_latches(
    ns: &Netns,
    prefix: &str,
    watch: &DriveWatch,
    mut run: ChildProc,
) -> std::path::PathBuf {
    // The network goes: no fresh sample within the watchdog time (500 ms) trips the drive.
    // A watcher on the remote side with the same lease (a session expires on its own lease).
    let lease = std::env::temp_dir().join(format!("uss-zenoh-lease-{}.json5", ns.name));
    std::fs::write(
        &lease,
        format!("{{ transport: {{ link: {{ tx: {{ lease: {LEASE_MS} }} }} }} }}"),
    )
    .unwrap();
    let mut alive = watch_alive(
        ns,
        &format!("{prefix}/bridge"),
        &["--zenoh-config", lease.to_str().unwrap()],
    );
    let cut = Instant::now();
    ns.link(false);
    let (tripped, after) = wait_image(watch, Duration::from_secs(3), "latched", latched);
    assert_eq!(reason(&tripped), LatchReason::Stale);
    assert_eq!(tripped.sent_stw1 & 0x0401, 0x0400, "OFF1 with bit 10 set");
    println!(
        "drive latched {:.0} ms after the link went down (watchdog 500 ms)",
        after.as_secs_f64() * 1e3
    );
    assert!(after < Duration::from_millis(1500), "{after:?}");
    // The remote run, blind, gives up and sends nothing more.
    let (status, _, err) = run.finish();
    assert!(!status.success());
    assert!(err.contains("no fresh image"), "{err}");
    println!(
        "the remote run gave up {:.0} ms after the link went down",
        cut.elapsed().as_secs_f64() * 1e3
    );
    // The remote side learns the bridge is unreachable within the bridge's lease.
    alive.says(&format!("- {prefix}/bridge"));
    let unreachable = cut.elapsed();
    println!(
        "the remote side saw the bridge's token withdrawn {:.0} ms after the link went down \
         (lease {LEASE_MS} ms)",
        unreachable.as_secs_f64() * 1e3
    );
    assert!(
        unreachable < Duration::from_millis(LEASE_MS * 2),
        "{unreachable:?}"
    );
    let down = watch.latest();
    assert!(
        hz(&down) < hz(&tripped) - 2.0,
        "{} -> {}",
        hz(&tripped),
        hz(&down)
    );

    // The link back: the drive stays latched and keeps ramping down; nothing restarts it.
    ns.link(true);
    std::thread::sleep(Duration::from_secs(2));
    let after_link = watch.latest();
    assert!(latched(&after_link) && reason(&after_link) == LatchReason::Stale);
    assert!(hz(&after_link) <= hz(&down));
    assert_eq!(after_link.sent_stw1, 0x047E);

    lease
}

/// An operator's stop from either side latches a remotely controlled drive; the remote run is
/// told.
fn operator_stops_latch(ns: &Netns, ussd: &Ussd, drive: &str) {
    // An operator's stop from the remote side latches the drive; the remote run is told.
    let mut run = ns.client(&["run", drive, "--hz", "10"]);
    run.says("re-armed");
    // While it controls the drive, another sender is refused, another process of the same
    // certificate (its own `from`) too (a peer the policy does not grant control:
    // `a_peer_without_rights_is_refused`).
    let report = put_sample(
        ns,
        drive,
        "controller",
        r#"{"v":1,"from":"intruder","seq":9999999999999999999,"stw1":1151,"hz":40.0}"#,
        "controlled remotely by",
    );
    assert!(
        report.contains("nothing of \\\"intruder\\\" was sent"),
        "{report}"
    );
    assert!(report.contains(r#""error_kind":"controlled""#), "{report}");
    let (ok, out, err) = ns.call(&["stop", drive, "--quick"]);
    assert!(ok, "{err}");
    let stop = json(&out);
    assert_eq!(stop["confirmed"].as_bool(), Some(true), "{stop}");
    assert_eq!(
        (stop["command"].as_str(), stop["latch_reason"].as_str()),
        (Some("OFF3"), Some("operator stop"))
    );
    let (status, _, err) = run.finish();
    assert!(!status.success() && stopped_by_an_operator(&err), "{err}");

    // ... and so does one from this side (ussctl).
    let mut run = ns.client(&["run", drive, "--hz", "10"]);
    run.says("re-armed");
    let (status, _, err) = ussd.ussctl(&["stop", "1"]).finish();
    assert!(status.success(), "{err}");
    let (status, _, err) = run.finish();
    assert!(!status.success() && stopped_by_an_operator(&err), "{err}");
}

/// A full line at the factory baud rate (31 drives at 9600 baud, each polled every 1.3 s): a
/// remote run re-arms, runs and releases drive 20, and a remote stop is confirmed. The client
/// waits by the drive's handshake time in its images (`handshake_ms`), not by fixed seconds.
#[test]
fn a_remote_client_controls_a_drive_of_a_full_line_at_9600_baud() {
    let Some(ns) = Netns::create() else { return };
    let drives: Vec<(u8, &str)> = (1..=31).map(|a| (a, WATCHDOG)).collect();
    let ussd = Ussd::start("baud = 9600", &drives);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/f{}", std::process::id());
    let drive = format!("{prefix}/{bus}/drive/20");
    let watch = ussd.bus().watch(addr(20)).unwrap();
    let pki = Pki::new("full", "uss-rt test CA", &ns.here());
    ns.use_tls(Some(pki.client("controller")));
    let (_bridge, config) = controlling_bridge(&ns, &bus, &prefix, &pki);
    answers_over_tls(&ns, &drive);

    let (ok, out, err) = ns.call(&["run", &drive, "--hz", "10", "--for", "3"]);
    assert!(ok, "{out}{err}");
    assert!(
        out.contains("re-armed") && out.contains("and released"),
        "{out}"
    );
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Released, "{i:?}");

    let mut run = ns.client(&["run", &drive, "--hz", "10"]);
    run.says("re-armed");
    let (ok, out, err) = ns.call(&["stop", &drive]);
    assert!(ok, "{err}");
    let stop = json(&out);
    assert_eq!(stop["confirmed"].as_bool(), Some(true), "{stop}");
    let (status, _, err) = run.finish();
    assert!(!status.success() && stopped_by_an_operator(&err), "{err}");
    let _ = std::fs::remove_file(config);
}

#[test]
fn a_bridge_that_moves_motors_or_writes_refuses_plain_tcp_and_control_needs_a_policy() {
    for rights in [
        &["--allow-control"][..],
        &["--allow-writes"],
        &["--allow-control", "--allow-writes"],
    ] {
        let out = Command::new(netns::BRIDGE)
            .args(["--bus", "uss-nobus", "--listen", "tcp/127.0.0.1:0"])
            .args(rights)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{rights:?}: {err}");
        assert!(
            err.contains("needs links that authenticate who reaches the bridge")
                && err.contains("endpoint tcp/127.0.0.1:0 is not TLS")
                && err.contains("--insecure-network"),
            "{err}"
        );
    }
    // Remote control never runs unauthenticated: it needs a policy that names who may control,
    // which needs authenticated links, so --insecure-network does not let it through.
    let out = Command::new(netns::BRIDGE)
        .args(["--bus", "uss-nobus", "--listen", "tcp/127.0.0.1:0"])
        .args(["--allow-control", "--insecure-network"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.code() == Some(1)
            && err.contains("--allow-control needs --policy naming who may control")
            && err.contains("remote control rests on verified identities only"),
        "{err}"
    );
    // In a lab, --insecure-network lets writes through and says what it means.
    let mut command = Command::new(netns::BRIDGE);
    command.args([
        "--bus",
        "uss-nobus",
        "--listen",
        "tcp/127.0.0.1:0",
        "--allow-writes",
        "--insecure-network",
    ]);
    let mut lab = ChildProc::spawn("uss-zenoh --insecure-network".into(), command);
    // A policy names certificates: it needs mutual TLS, lab or not; a bad one names its line.
    let policy = std::env::temp_dir().join(format!("uss-policy-{}.toml", std::process::id()));
    for (text, said) in [
        (
            "[[grant]]\nwho = [\"a\"]\nrights = [\"read\"]\n",
            "it needs mutual TLS",
        ),
        ("[[grant]]\nwho = [\"a\"]\nrights = [\"run\"]\n", "line 3"),
    ] {
        std::fs::write(&policy, text).unwrap();
        let out = Command::new(netns::BRIDGE)
            .args([
                "--bus",
                "uss-nobus",
                "--listen",
                "tcp/127.0.0.1:0",
                "--insecure-network",
            ])
            .arg("--policy")
            .arg(&policy)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.code() == Some(1) && err.contains(said), "{err}");
    }
    let _ = std::fs::remove_file(&policy);
    let said = lab.says("bridging");
    assert!(said.contains("links unauthenticated"), "{said}");
    lab.kill();
    let err = lab.stderr();
    assert!(
        err.contains("--insecure-network: --allow-writes on links that do not authenticate")
            && err.contains("anyone who reaches this bridge may change the drives' parameters"),
        "{err}"
    );
}

#[test]
fn over_mutual_tls_a_client_without_a_certificate_or_of_another_ca_does_not_get_in() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/m{}", std::process::id());
    let drive = format!("{prefix}/{bus}/drive/1");
    let watch = ussd.bus().watch(addr(1)).unwrap();
    let pki = Pki::new("mtls", "uss-rt test CA", &ns.here());
    let (mut bridge_proc, config) = controlling_bridge(&ns, &bus, &prefix, &pki);
    let other = Pki::new("other", "another CA", &ns.here());
    let strangers = [
        ("no certificate (plain TCP)", None),
        (
            "a certificate of another CA",
            Some(other.client("intruder")),
        ),
    ];
    for (who, tls) in strangers {
        ns.use_tls(tls);
        let (ok, _, err) = ns.call(&["run", &drive, "--hz", "10", "--for", "1"]);
        assert!(!ok, "{who}: got in");
        assert!(
            err.contains("cannot open the Zenoh session"),
            "{who}: {err}"
        );
        println!("mtls: {who}: {}", err.lines().next().unwrap_or(""));
    }
    // No trace of them on the drive: still latched since start, OFF1.
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Startup, "{i:?}");
    assert_eq!(i.sent_stw1, 0x047E);
    // The plant's controller gets in and runs it.
    ns.use_tls(Some(pki.client("controller")));
    answers_over_tls(&ns, &drive);
    let (ok, out, err) = ns.call(&["run", &drive, "--hz", "5", "--for", "1"]);
    if !ok {
        bridge_proc.kill();
        panic!("{out}{err}\nbridge: {}", bridge_proc.stderr());
    }
    assert!(
        out.contains("re-armed") && out.contains("and released"),
        "{out}"
    );
    bridge_proc.kill();
    let _ = std::fs::remove_file(config);
}

/// A bridge that stalls while a remote run hands its drive back (a starved CPU, a paused
/// process) still takes the hand-over when it resumes, and the run says so: the release is sent
/// again until the bridge confirms it, for several seconds, not for a single handshake time.
#[test]
fn a_remote_run_hands_its_drive_back_to_a_bridge_that_stalls_at_the_hand_over() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, "watchdog_ms = 500\nsim = { p2014 = 100 }")]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/h{}", std::process::id());
    let drive = format!("{prefix}/{bus}/drive/1");
    let watch = ussd.bus().watch(addr(1)).unwrap();
    let pki = Pki::new("stall", "uss-rt test CA", &ns.here());
    ns.use_tls(Some(pki.client("controller")));
    let (mut bridge_proc, config) = controlling_bridge(&ns, &bus, &prefix, &pki);
    answers_over_tls(&ns, &drive);
    let mut run = ns.client(&["run", &drive, "--hz", "5", "--for", "0.5"]);
    run.says("re-armed");
    // The run ends and hands the drive back while the bridge is paused for 4 s.
    signal("-STOP", bridge_proc.pid());
    std::thread::sleep(Duration::from_secs(4));
    // The run still waits for the hand-over (it did not end before the pause).
    assert!(run.child.try_wait().unwrap().is_none(), "the run ended");
    signal("-CONT", bridge_proc.pid());
    let (status, out, err) = run.finish();
    assert!(status.success(), "{err}");
    assert!(out.contains("and released"), "{out}");
    // Its watchdog stopped the drive meanwhile (the bridge was silent); nothing restarts it.
    let i = watch.latest();
    assert!(latched(&i), "{i:?}");
    assert_eq!(i.sent_stw1 & 0x0401, 0x0400, "OFF1 with bit 10 set");

    // A drive in fault is not run: the client names the fault, says how to clear it and sends
    // nothing (it said "re-armed; running towards 5 Hz" and went on). ussd paused past the
    // drive's telegram-off time (P2014 = 100 ms) trips it with F0072.
    signal("-STOP", ussd.child.id());
    std::thread::sleep(Duration::from_millis(500));
    signal("-CONT", ussd.child.id());
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    while watch.latest().zsw1 & 0x0008 == 0 {
        assert!(std::time::Instant::now() < deadline, "{:?}", watch.latest());
        std::thread::sleep(Duration::from_millis(10));
    }
    let before = watch.latest();
    let (status, out, err) = ns
        .client(&["run", &drive, "--hz", "5", "--for", "0.5"])
        .finish();
    println!("remote: run of a faulted drive: {status}\n{out}{err}");
    assert!(!status.success(), "{out}");
    assert!(!out.contains("re-armed"), "{out}");
    assert!(
        err.contains("is in fault (ZSW1 0x") && err.contains("ussctl ack 1"),
        "{err}"
    );
    let i = watch.latest();
    assert!(latched(&i) && i.latch_id == before.latch_id, "{i:?}");
    bridge_proc.kill();
    let _ = std::fs::remove_file(config);
}

/// The bridge is one process to ussd: while it holds a drive for a remote controller, ussd's
/// "writes to a controlled drive are refused" sees the bridge's own pid in every parameter
/// query. Another remote peer must not change the running drive's parameters through it.
#[test]
fn a_drive_under_remote_control_takes_no_parameter_writes_from_the_network() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/w{}", std::process::id());
    let drive = format!("{prefix}/{bus}/drive/1");
    let watch = ussd.bus().watch(addr(1)).unwrap();
    let pki = Pki::new("held", "uss-rt test CA", &ns.here());
    // The controller runs drive 1; the engineer may write parameters.
    let policy = pki.dir.join("held-policy.toml");
    std::fs::write(
        &policy,
        "[[grant]]\nwho = [\"controller\"]\nrights = [\"control\"]\n\n\
         [[grant]]\nwho = [\"engineer\"]\nrights = [\"write\"]\n",
    )
    .unwrap();
    let (_bridge, config) = bridge_tls(
        &ns,
        &bus,
        &prefix,
        &[
            "--allow-control",
            "--allow-writes",
            "--policy",
            policy.to_str().unwrap(),
        ],
        &pki,
    );
    ns.use_tls(Some(pki.client("controller")));
    // The bridge answers over TLS before the run starts (its first session takes a moment).
    answers_over_tls(&ns, &drive);
    let mut run = ns.client(&["run", &drive, "--hz", "10"]);
    run.says("re-armed");
    wait_image(&watch, Duration::from_secs(10), "live", |i| !latched(i));
    // Another peer sets a 650 s ramp-down time on the running drive.
    ns.use_tls(Some(pki.client("engineer")));
    let (ok, out, err) = ns.call(&["get", &format!("{drive}/param/P1121"), "--value", "650"]);
    assert!(
        !ok,
        "another peer changed a remotely controlled drive: {out}"
    );
    assert!(
        err.contains("drive 1 P1121: the drive runs under remote control by")
            && err.contains("nothing was written"),
        "{err}"
    );
    assert_eq!(
        ussd.bus().read(addr(1), uss_integration_tests::param(1121)),
        Ok(uss_client::Value::from_f32(10.0)),
        "P1121 unchanged"
    );
    // Reads still go through; once the controller releases the drive, writes do again.
    let (ok, _, err) = ns.call(&["get", &format!("{drive}/param/P1121")]);
    assert!(ok, "{err}");
    run.kill();
    let (i, _) = wait_image(&watch, Duration::from_secs(3), "latched", latched);
    assert_eq!(reason(&i), LatchReason::Stale);
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let (ok, _, err) = ns.call(&["get", &format!("{drive}/param/P1121"), "--value", "8"]);
        if ok {
            break;
        }
        assert!(Instant::now() < deadline, "never released: {err}");
        std::thread::sleep(Duration::from_millis(500));
    }
    let _ = std::fs::remove_file(config);
}

/// A Zenoh user finds a bus without knowing the host's prefix: a query with wildcards
/// (`**/<bus>/drive/1/param/P1082`, `**/<bus>/drive/2/stop`) is answered, each reply under its
/// concrete key.
#[test]
fn a_query_with_wildcards_is_answered_under_each_concrete_key() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WATCHDOG), (2, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/k{}", std::process::id());
    let (_bridge, config) = bridge(&ns, &bus, &prefix, &[]);
    let deadline = Instant::now() + Duration::from_secs(10);
    let (ok, out, err) = loop {
        let answer = ns.call(&["get", &format!("**/{bus}/drive/1/param/P1082")]);
        if answer.0 || !answer.2.contains("no reply") || Instant::now() > deadline {
            break answer;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(ok, "a query with wildcards is not answered: {err}");
    assert_eq!(json(&out)["value"].as_f64(), Some(50.0), "{out}");
    // Every drive of the bus, each reply under its own key (the client prints the keys).
    let (ok, out, err) = ns.call(&["get", &format!("uss/*/{bus}/drive/*/param/P1082")]);
    assert!(ok, "{err}");
    let mut drives: Vec<u64> = out
        .lines()
        .filter_map(|l| json(l)["drive"].as_u64())
        .collect();
    // Replies come in the order they arrive.
    drives.sort_unstable();
    assert_eq!(drives, [1, 2], "{out}");
    // A wildcard for the parameter, or a write to many drives, is refused with what to do.
    let (ok, _, err) = ns.call(&["get", &format!("**/{bus}/drive/1/param/*")]);
    assert!(!ok && err.contains("name the parameter"), "{err}");
    // An operator's stop found the same way: drive 2 only, confirmed under its own key.
    let (ok, out, err) = ns.call(&["stop", &format!("**/{bus}/drive/2")]);
    assert!(ok, "{err}");
    assert_report("zenoh/stop", out.trim());
    let stop = json(&out);
    assert_eq!(
        (stop["drive"].as_u64(), stop["confirmed"].as_bool()),
        (Some(2), Some(true)),
        "{stop}"
    );
    let _ = std::fs::remove_file(config);
}

/// An access policy (`--policy`) grants rights per certificate: a peer with a valid certificate
/// but without the `control` right cannot run a drive (it does not move), nor write without
/// `write`, and each refusal is answered with the missing right, counted in the bus's status and
/// logged with the peer's name; a peer that sends under another's name is not let in by Zenoh;
/// every authenticated peer may stop a drive; the controller runs only its drive, and writes to
/// it while it runs it (the bridge holds the drive per identity, not for every peer).
#[test]
fn an_access_policy_grants_control_writes_and_stops_per_certificate() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WATCHDOG), (2, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/p{}", std::process::id());
    let drive = |d: u8| format!("{prefix}/{bus}/drive/{d}");
    let (watch1, watch2) = (
        ussd.bus().watch(addr(1)).unwrap(),
        ussd.bus().watch(addr(2)).unwrap(),
    );
    let pki = Pki::new("policy", "uss-rt test CA", &ns.here());
    let policy = pki.dir.join("policy.toml");
    std::fs::write(
        &policy,
        "default = [\"read\", \"stop\"]\n\n[[grant]]\nwho = [\"controller\"]\nrights = [\"control\", \"write\"]\ndrives = [1]\n\n[[grant]]\nwho = [\"engineer\"]\nrights = [\"write\"]\n\n[[grant]]\nwho = [\"second\"]\nrights = [\"control\"]\ndrives = [1]\n",
    )
    .unwrap();
    let (mut bridge_proc, config) = bridge_tls(
        &ns,
        &bus,
        &prefix,
        &[
            "--allow-control",
            "--allow-writes",
            "--policy",
            policy.to_str().unwrap(),
        ],
        &pki,
    );
    let (viewer, controller, engineer) = (
        pki.client("viewer"),
        pki.client("controller"),
        pki.client("engineer"),
    );

    ns.use_tls(Some(viewer.clone()));
    a_peer_without_rights_is_refused(&ns, &ussd, &drive(1));
    let param = format!("{}/param/P1121", drive(1));

    // The controller runs drive 1, and not drive 2, which it was not granted.
    ns.use_tls(Some(controller.clone()));
    let (ok, _, err) = ns.call(&["run", &drive(2), "--hz", "10", "--for", "1"]);
    assert!(
        !ok && err.contains("\"controller\" (certificate) has not the right `control` on drive 2"),
        "{err}"
    );
    let i = watch2.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Startup, "{i:?}");
    let mut run = ns.client(&["run", &drive(1), "--hz", "10"]);
    run.says("re-armed");
    wait_image(&watch1, Duration::from_secs(10), "live", |i| !latched(i));
    a_forged_from_is_another_sender(&ns, &pki, &drive(1), &watch1);
    ns.use_tls(Some(controller.clone()));
    // While it runs the drive, its own certificate writes to it; the engineer's does not.
    let (ok, out, err) = ns.call(&["get", &param, "--value", "9"]);
    assert!(ok && json(&out)["value"].as_f64() == Some(9.0), "{err}");
    ns.use_tls(Some(engineer.clone()));
    let (ok, _, err) = ns.call(&["get", &param, "--value", "650"]);
    assert!(
        !ok && err.contains("runs under remote control by") && err.contains("nothing was written"),
        "{err}"
    );
    assert_eq!(
        ussd.bus().read(addr(1), uss_integration_tests::param(1121)),
        Ok(uss_client::Value::from_f32(9.0))
    );

    // Every authenticated peer may stop it: the viewer's stop latches it.
    ns.use_tls(Some(viewer));
    let (ok, out, err) = ns.call(&["stop", &drive(1)]);
    assert!(ok, "{err}");
    assert_eq!(json(&out)["confirmed"].as_bool(), Some(true), "{out}");
    let (status, _, err) = run.finish();
    assert!(!status.success() && stopped_by_an_operator(&err), "{err}");
    // The refusals are counted in the bus's status.
    let (ok, out, err) = ns.call(&["sub", &format!("{prefix}/{bus}/status")]);
    assert!(ok, "{err}");
    let refused = &json(&out)["refused"];
    assert!(
        refused["control"].as_u64() >= Some(2) && refused["write"].as_u64() >= Some(1),
        "{out}"
    );

    // The engineer writes, through the write key (drive 2: the bridge still holds drive 1 for
    // its controller until it releases it).
    ns.use_tls(Some(engineer));
    let param = format!("{}/param/P1121", drive(2));
    let (ok, out, err) = ns.call(&["get", &param, "--value", "8"]);
    assert!(ok, "{err}");
    assert_eq!(json(&out)["value"].as_f64(), Some(8.0), "{out}");
    bridge_proc.kill();
    // Each refusal is logged with who asked.
    let said = bridge_proc.stderr();
    assert!(
        said.contains("\"viewer\" (a name nothing vouches for) has not the right `control`")
            && said.contains("\"controller\" (certificate) has not the right `control` on drive 2"),
        "{said}"
    );
    let _ = std::fs::remove_file(config);
}

/// Another certificate granted control too does not take a drive over by sending its holder's
/// `from` (every peer reads it on `.../control`): the holder is its verified name.
fn a_forged_from_is_another_sender(ns: &Netns, pki: &Pki, drive: &str, watch: &DriveWatch) {
    let (ok, out, err) = ns.call(&["sub", &format!("{drive}/control")]);
    assert!(ok, "{err}");
    let holder = json(&out)["holder"].as_str().unwrap_or_default().to_owned();
    assert!(!holder.is_empty(), "{out}");
    ns.use_tls(Some(pki.client("second")));
    let forged = format!(r#"{{"v":1,"from":{holder:?},"seq":999999999,"stw1":1151,"hz":45.0}}"#);
    let report = put_sample(ns, drive, "second", &forged, "controlled remotely by");
    assert!(report.contains("nothing of"), "{report}");
    assert!(
        hz(&watch.latest()) < 20.0,
        "the forged 45 Hz reached the drive"
    );
}

/// A peer with a valid certificate but only the default rights (the policy does not list it):
/// its samples are refused with the right it lacks and the drive does not move; it reads but
/// does not write; under a listed name (another's) nothing of it reaches the bridge.
fn a_peer_without_rights_is_refused(ns: &Netns, ussd: &Ussd, drive: &str) {
    let watch = ussd.bus().watch(addr(1)).unwrap();
    // A valid certificate without the control right: its samples are refused with the right
    // it lacks, and the drive does not move.
    answers_over_tls(ns, drive);
    let (ok, out, err) = ns.call(&["run", drive, "--hz", "10", "--for", "1"]);
    assert!(!ok, "the viewer ran the drive: {out}");
    assert!(
        err.contains("the bridge refused the OFF1")
            && err.contains(
                "\"viewer\" (a name nothing vouches for) has not the right `control` on drive 1"
            ),
        "{err}"
    );
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Startup, "{i:?}");
    assert_eq!(i.sent_stw1, 0x047E);
    // ... it reads, but does not write: the error reply names the right.
    let param = format!("{drive}/param/P1121");
    let (ok, out, err) = ns.call(&["get", &param]);
    assert!(ok && json(&out)["value"].as_f64() == Some(10.0), "{err}");
    let (ok, _, err) = ns.call(&["get", &param, "--value", "650"]);
    assert!(
        !ok && err.contains("has not the right `write` on drive 1"),
        "{err}"
    );
    assert_eq!(
        ussd.bus().read(addr(1), uss_integration_tests::param(1121)),
        Ok(uss_client::Value::from_f32(10.0))
    );
    // Under the controller's name, the viewer's samples and queries never reach the bridge:
    // Zenoh binds a listed name to its certificate.
    let (ok, _, err) = ns.call(&[
        "--as",
        "controller",
        "get",
        &param,
        "--value",
        "650",
        "--timeout",
        "2",
    ]);
    println!("policy: the viewer's write as the controller: {err}");
    assert!(
        !ok && err.contains("no uss-zenoh answers") && err.contains("access policy"),
        "{err}"
    );
    let (ok, _, err) = ns.call(&[
        "--as",
        "controller",
        "run",
        drive,
        "--hz",
        "10",
        "--for",
        "1",
    ]);
    println!("policy: the viewer's run as the controller: {err}");
    assert!(
        !ok && err.contains("was not re-armed"),
        "the viewer ran the drive as the controller: {err}"
    );
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Startup, "{i:?}");
    assert_eq!(
        ussd.bus().read(addr(1), uss_integration_tests::param(1121)),
        Ok(uss_client::Value::from_f32(10.0))
    );
}

/// User/password authentication names peers too: a policy grants rights per user; a wrong
/// password does not get in; a user without the right is refused with the right it lacks, and
/// under the granted user's name nothing of it reaches the bridge; the granted user runs the
/// drive.
#[test]
fn under_user_password_an_access_policy_grants_rights_per_user() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/u{}", std::process::id());
    let drive = format!("{prefix}/{bus}/drive/1");
    let watch = ussd.bus().watch(addr(1)).unwrap();
    let dir = std::env::temp_dir().join(format!("uss-users-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let dictionary = dir.join("users.txt");
    std::fs::write(&dictionary, "operator:op-secret\nguest:guest-secret\n").unwrap();
    let policy = dir.join("policy.toml");
    std::fs::write(
        &policy,
        "[[grant]]\nwho = [\"operator\"]\nrights = [\"control\"]\n",
    )
    .unwrap();
    let (mut bridge_proc, config) = bridge_users(
        &ns,
        &bus,
        &prefix,
        &["--allow-control", "--policy", policy.to_str().unwrap()],
        &dictionary,
    );
    let login = |user: &str, password: &str| {
        let file = dir.join(format!("{user}-{password}.json5"));
        std::fs::write(
            &file,
            format!(
                "{{ transport: {{ auth: {{ usrpwd: {{ user: \"{user}\", password: \"{password}\" }} }} }} }}"
            ),
        )
        .unwrap();
        file.display().to_string()
    };
    let run = |login: &str, as_name: Option<&str>| {
        let mut args = vec!["--zenoh-config", login];
        if let Some(n) = as_name {
            args.extend(["--as", n]);
        }
        args.extend(["run", drive.as_str(), "--hz", "5", "--for", "1"]);
        ns.call(&args)
    };
    let guest = login("guest", "guest-secret");
    answers(&ns, &["--zenoh-config", &guest], &drive);
    let (ok, _, err) = run(&login("operator", "guess"), None);
    assert!(
        !ok && err.contains("cannot open the Zenoh session"),
        "{err}"
    );
    let (ok, _, err) = run(&guest, None);
    assert!(
        !ok && err.contains("\"guest\" (a name nothing vouches for) has not the right `control`"),
        "{err}"
    );
    let (ok, _, err) = run(&guest, Some("operator"));
    assert!(!ok && err.contains("was not re-armed"), "{err}");
    let i = watch.latest();
    assert!(latched(&i) && reason(&i) == LatchReason::Startup, "{i:?}");
    assert_eq!(i.sent_stw1, 0x047E);
    let (ok, out, err) = run(&login("operator", "op-secret"), None);
    assert!(
        ok && out.contains("re-armed") && out.contains("and released"),
        "{out}{err}"
    );
    bridge_proc.kill();
    let said = bridge_proc.stderr();
    assert!(
        said.contains("\"guest\" (a name nothing vouches for) has not the right `control`"),
        "{said}"
    );
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_file(config);
}

/// REARM across the network (issue 45): an operator's coast that lands while a remote
/// `uss-zenoh-client run` starts (connecting, its first image on the way), swept from 0 to
/// 80 ms after its start, is not re-armed by it: the run refuses ("stopped after this run was
/// started") and the drive is never live again after the coast; through a real bridge over
/// mutual TLS under a policy. A run with no stop meanwhile re-arms and runs. A sample that
/// names the latch without `asked_ns`, or with an `asked_ns` before the latch, re-arms nothing.
#[test]
fn a_stop_while_a_remote_run_starts_is_not_re_armed_by_it() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/r{}", std::process::id());
    let drive = format!("{prefix}/{bus}/drive/1");
    let watch = ussd.bus().watch(addr(1)).unwrap();
    let pki = Pki::new("rearm", "uss-rt test CA", &ns.here());
    ns.use_tls(Some(pki.client("controller")));
    let (mut bridge_proc, config) = controlling_bridge(&ns, &bus, &prefix, &pki);
    answers_over_tls(&ns, &drive);
    let rearmed = coasts_while_runs_start(&ns, &ussd, &drive, &[0, 5, 10, 20, 40, 80]);
    assert!(
        rearmed.is_empty(),
        "a coast while the remote run started was re-armed by it (ms after its start, latch): {rearmed:?}"
    );
    // A named re-arm without its time, or asked for before the latch began, re-arms nothing.
    let latch = watch.latest().latch_id;
    for payload in [
        format!(r#"{{"v":1,"from":"t","seq":1,"stw1":1150,"hz":0.0,"rearm":{latch}}}"#),
        format!(
            r#"{{"v":1,"from":"t","seq":2,"stw1":1150,"hz":0.0,"rearm":{latch},"asked_ns":{}}}"#,
            latch - 1
        ),
    ] {
        let report = put_sample(&ns, &drive, "controller", &payload, "\"state\":\"refused\"");
        assert!(report.contains("nothing was"), "{payload}: {report}");
        std::thread::sleep(Duration::from_millis(200));
        assert!(latched(&watch.latest()), "{payload}");
    }
    // Past a slow link (a bridge that publishes 2 images a second): the first image a run
    // sees may come 500 ms after its start, and shows a coast made meanwhile.
    bridge_proc.kill();
    let _ = std::fs::remove_file(config);
    let policy = pki.control_policy(&["controller"]);
    let (mut bridge_proc, config) = bridge_tls(
        &ns,
        &bus,
        &prefix,
        &["--allow-control", "--policy", &policy, "--max-rate", "2"],
        &pki,
    );
    answers_over_tls(&ns, &drive);
    let rearmed = coasts_while_runs_start(&ns, &ussd, &drive, &[100, 200, 300]);
    assert!(
        rearmed.is_empty(),
        "past a slow link, a coast while the remote run started was re-armed by it: {rearmed:?}"
    );
    // The deliberate act with nothing in between: it re-arms and runs.
    let (ok, out, err) = ns.call(&["run", &drive, "--hz", "5", "--for", "1"]);
    assert!(ok && out.contains("re-armed"), "{out}{err}");
    bridge_proc.kill();
    let _ = std::fs::remove_file(config);
}

/// For each offset: starts `uss-zenoh-client run` on `drive` (drive 1 of `ussd`), coasts the
/// drive that many ms after, and sees whether the drive is live again after the coast within
/// 2.5 s; the run must fail, saying why. The (offset, latch) of each coast that was undone.
fn coasts_while_runs_start(
    ns: &Netns,
    ussd: &Ussd,
    drive: &str,
    offsets: &[u64],
) -> Vec<(u64, u64)> {
    let watch = ussd.bus().watch(addr(1)).unwrap();
    let mut rearmed = Vec::new();
    for &offset_ms in offsets {
        let before = watch.latest().latch_id;
        let mut run = ns.client(&["run", drive, "--hz", "10", "--for", "1"]);
        std::thread::sleep(Duration::from_millis(offset_ms));
        ussd.bus()
            .stop_drive(addr(1), uss_client::StopCommand::Off2)
            .unwrap();
        let (coast, _) = wait_image(&watch, Duration::from_secs(3), "the coast", |i| {
            i.latch_id > before
        });
        let end = Instant::now() + Duration::from_millis(2500);
        while Instant::now() < end {
            let i = watch.latest();
            if !latched(&i) {
                rearmed.push((offset_ms, coast.latch_id));
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let (status, out, err) = run.finish();
        assert!(!status.success(), "coast {offset_ms} ms in: {out}{err}");
        assert!(
            // Refused by the client (the coast came after its start, or during its re-arm) or
            // by the bridge (its re-arm named a latch older than the coast): the operator's stop.
            err.contains("operator"),
            "coast {offset_ms} ms in: {err}"
        );
    }
    rearmed
}

/// Commissioning across the network (issue 46, item 5), as the client library does it: under an
/// access policy over mutual TLS, any authenticated peer describes a parameter, takes a backup
/// and diffs it; only the peer granted `commission` restores it (and copies RAM to ROM); a
/// backup that changes a guarded parameter (the command source) is refused to it as well,
/// since nothing guarded is written from across the network; a drive under remote control
/// takes no restore from another peer.
#[test]
fn commissioning_over_the_network_follows_the_policy_and_never_writes_a_guarded_value() {
    let Some(ns) = Netns::create() else { return };
    let ussd = Ussd::start("", &[(1, WITH_EXTRAS), (2, WATCHDOG)]);
    let bus = ussd.bus.clone();
    let prefix = format!("uss/c{}", std::process::id());
    let drive = |d: u8| format!("{prefix}/{bus}/drive/{d}");
    let pki = Pki::new("commission", "uss-rt test CA", &ns.here());
    let policy = pki.dir.join("policy.toml");
    std::fs::write(
        &policy,
        "default = [\"read\", \"stop\"]\n\n[[grant]]\nwho = [\"engineer\"]\nrights = [\"commission\"]\n",
    )
    .unwrap();
    let (mut bridge_proc, config) = bridge_tls(
        &ns,
        &bus,
        &prefix,
        &["--allow-writes", "--policy", policy.to_str().unwrap()],
        &pki,
    );
    ns.use_tls(Some(pki.client("viewer")));
    let (backup, file) = describe_and_back_up(&ns, &drive(1), &pki.dir);
    let diff = |ns: &Netns| {
        let (ok, out, err) = ns.call(&[
            "get",
            &format!("{}/diff", drive(1)),
            "--file",
            file.to_str().unwrap(),
            "--timeout",
            "60",
        ]);
        assert!(ok, "{err}");
        json(&out)
    };
    let d = diff(&ns);
    assert!(
        d["same"].as_u64() > Some(30) && d["differ"].as_array().is_some_and(Vec::is_empty),
        "{d}"
    );
    // Drive 1's ramp changed here: the diff says so; the viewer may not restore it.
    ussd.bus()
        .write(
            addr(1),
            uss_integration_tests::param(1120),
            uss_client::Value::from_f32(9.0),
            false,
        )
        .unwrap();
    let d = diff(&ns);
    assert_eq!(d["differ"][0]["param"].as_str(), Some("P1120[0]"), "{d}");
    let restore = |ns: &Netns, file: &std::path::Path| {
        ns.call(&[
            "get",
            &format!("{}/restore", drive(1)),
            "--file",
            file.to_str().unwrap(),
            "--timeout",
            "60",
        ])
    };
    let (ok, _, err) = restore(&ns, &file);
    assert!(
        !ok && err.contains("has not the right `commission` on drive 1"),
        "{err}"
    );
    // The engineer restores it: P1120 is the file's again.
    ns.use_tls(Some(pki.client("engineer")));
    let (ok, out, err) = restore(&ns, &file);
    assert!(ok, "{err}");
    let r = json(&out);
    assert_eq!(
        (r["complete"].as_bool(), r["written"].as_u64()),
        (Some(true), Some(1)),
        "{out}"
    );
    assert_ne!(
        ussd.bus()
            .read(addr(1), uss_integration_tests::param(1120))
            .unwrap(),
        uss_client::Value::from_f32(9.0)
    );
    // A backup that changes the command source is refused to it too, nothing written.
    let guarded = pki.dir.join("guarded.toml");
    let changed = change_value(&backup, "P0700", "1");
    std::fs::write(&guarded, changed).unwrap();
    let (ok, _, err) = restore(&ns, &guarded);
    assert!(
        !ok && err.contains("P0700") && err.contains("nothing was written"),
        "{err}"
    );
    // The copy of RAM to ROM.
    let (ok, out, err) = ns.call(&["get", &format!("{}/save", drive(1)), "--timeout", "30"]);
    assert!(ok, "{err}");
    assert_eq!(json(&out)["param"].as_str(), Some("P0971"), "{out}");
    bridge_proc.kill();
    let said = bridge_proc.stderr();
    assert!(
        said.contains("\"viewer\" (a name nothing vouches for) has not the right `commission`"),
        "{said}"
    );
    let _ = std::fs::remove_file(config);
}

/// What the drive says P1120 is (beside the catalogue), and a backup of it, saved in `dir`: its
/// text and file.
fn describe_and_back_up(
    ns: &Netns,
    drive: &str,
    dir: &std::path::Path,
) -> (String, std::path::PathBuf) {
    // What the drive says P1120 is, beside the catalogue.
    let (ok, out, err) = ns.call(&["get", &format!("{drive}/describe/P1120")]);
    assert!(ok, "{err}");
    let d = json(&out);
    assert_eq!(
        (
            d["param"].as_str(),
            d["data_type"].as_str(),
            d["read_only"].as_bool()
        ),
        (Some("P1120"), Some("float"), Some(false)),
        "{out}"
    );
    assert!(d["max"].as_f64() > d["min"].as_f64(), "{out}");
    // A backup, and its diff against the drive: nothing differs.
    let (ok, backup, err) = ns.call(&["get", &format!("{drive}/backup"), "--timeout", "60"]);
    assert!(ok && backup.contains("P1120"), "{err}{backup}");
    assert!(!backup.contains("[described."), "{backup}");
    // Asked to, the backup holds what the drive describes beyond the catalogue; a range that
    // is none is refused as invalid, by the error table's kind.
    let (ok, found, err) = ns.call(&[
        "get",
        &format!("{drive}/backup?discover=700-710"),
        "--timeout",
        "60",
    ]);
    assert!(
        ok && found.contains("[described.P0701]") && found.contains("[described.P0702]"),
        "{err}{found}"
    );
    let (ok, out, err) = ns.call(&["get", &format!("{drive}/backup?discover=710-700")]);
    assert!(
        !ok && format!("{out}{err}").contains("discover=710-700"),
        "{out}{err}"
    );
    let file = dir.join("drive1.toml");
    std::fs::write(&file, &backup).unwrap();
    (backup, file)
}

/// `backup` with the first line of `param` given `value` instead (`P0700 = [2, 2, 2]` ->
/// `P0700 = [1, 2, 2]`, or `P0700 = 2` -> `P0700 = 1`).
fn change_value(backup: &str, param: &str, value: &str) -> String {
    let mut done = false;
    backup
        .lines()
        .map(|l| {
            if !done && l.trim_start().starts_with(&format!("{param} ")) {
                done = true;
                let (head, tail) = l.split_once('=').unwrap();
                let tail = tail.trim();
                let new = if let Some(list) = tail.strip_prefix('[') {
                    let rest = list.split_once(',').map_or("]", |(_, r)| r);
                    format!("[{value},{rest}")
                } else {
                    value.to_owned()
                };
                format!("{head}= {new}")
            } else {
                l.to_owned()
            }
        })
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}
