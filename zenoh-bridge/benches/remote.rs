//! uss-zenoh across a network boundary (issue "Beyond one host", item 6), printed in one run:
//! ussd (simulated drives) and `uss-zenoh` in this network namespace, `uss-zenoh-client` in a
//! namespace of the benchmark's own joined by a veth pair (as in the remote tests).
//!
//! 1. `latency`: a reply seen by ussd -> its input image seen by a Zenoh subscriber on the other
//!    side (the image's arrival there minus the reply's time, both on this host's clock), next to
//!    a local iceoryx2 client (`DriveWatch` woken by the exchange event) measured in the same
//!    run, over the same images.
//! 2. `params`: a parameter read round trip (P1082), a query from the other side through the
//!    bridge next to `Bus::read_param` in a local client, one after the other.
//! 3. `throughput`: growing loads (drives x exchanges/s, faster simulated lines) until the
//!    remote subscriber misses images: offered and delivered images/s, images lost (gaps in each
//!    drive's sequence as the remote side saw it), and the bridge's CPU time per image.
//!
//! 4. `tls`: the cost of mutual TLS: the input latency (as in 1) and the parameter round trip
//!    (as in 2) through a bridge on plain TCP and through one on mutual TLS (certificates made
//!    with openssl as the guide shows), one after the other in the same run.
//!
//! Needs root for the namespaces (it says SKIPPED otherwise). `cargo bench -p uss-zenoh --bench
//! remote -- latency` runs one part.

#![allow(clippy::unwrap_used, clippy::cast_precision_loss)]

#[path = "../tests/netns/mod.rs"]
mod netns;

use hdrhistogram::Histogram;
use netns::{Netns, Pki, bridge, bridge_tls};
use serde_json::Value;
use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use uss_benches::{Parts, percentiles_us};
use uss_integration_tests::addr;
use uss_integration_tests::{Ussd, monotonic_ns};

/// How long each measurement runs, s (a short run: 1).
fn seconds() -> u64 {
    uss_benches::rounds(10, 1)
}

/// Parameter reads per measurement (a short run: 10).
fn reads() -> usize {
    usize::try_from(uss_benches::rounds(200, 10)).expect("reads")
}

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 60_000_000_000, 3).unwrap()
}

/// Four drives on the simulated bus at 115200 baud, as ussd's embedded default.
fn four_drives() -> Ussd {
    Ussd::start("", &[(1, ""), (2, ""), (3, ""), (4, "")])
}

fn prefix() -> String {
    format!("uss/b{}", std::process::id())
}

/// Each line of `sub --stamp`: the arrival (unix ns) and the image.
fn stamped(out: &str) -> impl Iterator<Item = (u128, Value)> + '_ {
    out.lines().filter_map(|line| {
        let (at, json) = line.split_once(' ')?;
        Some((at.parse().ok()?, serde_json::from_str(json).ok()?))
    })
}

/// Images of the local drives seen through iceoryx2, woken by the exchange event: reply ->
/// image read, until `stop`.
fn local_latency(bus: &str, drives: &[u8], stop: &AtomicBool) -> Histogram<u64> {
    let bus = uss_client::Bus::open(bus).unwrap();
    let listener = bus.cycle_listener().unwrap();
    let watches: Vec<_> = drives
        .iter()
        .map(|&a| bus.watch(addr(a)).unwrap())
        .collect();
    let mut last: Vec<u64> = watches.iter().map(|w| w.latest().sequence).collect();
    let mut h = histogram();
    while !stop.load(Ordering::Relaxed) {
        let _ = listener.wait(Duration::from_millis(50), |_| {});
        let now = monotonic_ns();
        for (w, last) in watches.iter().zip(&mut last) {
            let i = w.latest();
            if i.sequence != *last && i.online != 0 {
                *last = i.sequence;
                let _ = h.record(now.saturating_sub(i.timestamp_ns).max(1));
            }
        }
    }
    h
}

fn latency(ns: &Netns) {
    println!(
        "1. input latency, reply -> image seen (4 drives, 115200 baud, {} s)",
        seconds()
    );
    let ussd = four_drives();
    let prefix = prefix();
    let (_bridge, config) = bridge(ns, &ussd.bus, &prefix, &[]);
    let stop = Arc::new(AtomicBool::new(false));
    let local = {
        let (bus, stop) = (ussd.bus.clone(), Arc::clone(&stop));
        std::thread::spawn(move || local_latency(&bus, &[1, 2, 3, 4], &stop))
    };
    let key = format!("{prefix}/{}/drive/*/in", ussd.bus);
    let remote = remote_latency(ns, &key, seconds());
    stop.store(true, Ordering::Relaxed);
    let local = local.join().unwrap();
    println!("   local iceoryx2  {}", percentiles_us(&local));
    println!("   remote Zenoh    {}", percentiles_us(&remote));
    let ratio = |q: f64| remote.value_at_quantile(q) as f64 / local.value_at_quantile(q) as f64;
    println!(
        "   remote / local: p50 {:.1}x  p99 {:.1}x  max {:.1}x",
        ratio(0.5),
        ratio(0.99),
        remote.max() as f64 / local.max() as f64
    );
    let _ = std::fs::remove_file(config);
}

fn params(ns: &Netns) {
    const WARM_UP: usize = 5;
    println!(
        "2. parameter read round trip, P1082 ({} reads each, the first {WARM_UP} not counted)",
        reads()
    );
    let ussd = four_drives();
    let prefix = prefix();
    let (_bridge, config) = bridge(ns, &ussd.bus, &prefix, &[]);
    let bus = uss_client::Bus::open(&ussd.bus).unwrap();
    let param = "P1082".parse().unwrap();
    let mut local = histogram();
    for n in 0..reads() {
        let t = Instant::now();
        bus.read_param(addr(1), param).unwrap();
        if n >= WARM_UP {
            let _ = local.record(t.elapsed().as_nanos() as u64);
        }
    }
    let key = format!("{prefix}/{}/drive/1/param/P1082", ussd.bus);
    let remote = remote_reads(ns, &key, reads(), WARM_UP);
    println!("   local Bus::read_param  {}", percentiles_us(&local));
    println!("   remote Zenoh query     {}", percentiles_us(&remote));
    println!(
        "   remote / local: p50 {:.2}x  p99 {:.2}x",
        remote.value_at_quantile(0.5) as f64 / local.value_at_quantile(0.5) as f64,
        remote.value_at_quantile(0.99) as f64 / local.value_at_quantile(0.99) as f64
    );
    let _ = std::fs::remove_file(config);
}

/// Remote input latency for `seconds` through the bridge the namespace's clients reach now.
fn remote_latency(ns: &Netns, key: &str, seconds: u64) -> Histogram<u64> {
    let (_, out, err) = ns
        .client(&[
            "sub",
            key,
            "--for",
            &seconds.to_string(),
            "--count",
            "100000000",
            "--stamp",
        ])
        .finish();
    let mut remote = histogram();
    for (at, image) in stamped(&out) {
        if image["stale"] != false {
            continue;
        }
        let published = image["published_unix_ns"].as_f64().unwrap_or_default();
        let reply = published - image["reply_ms_ago"].as_f64().unwrap_or_default() * 1e6;
        let _ = remote.record(((at as f64 - reply).max(1.0)) as u64);
    }
    assert!(remote.len() > 100, "too few remote images: {err}");
    remote
}

/// `reads` parameter round trips from the namespace (the first `warm_up` not counted).
fn remote_reads(ns: &Netns, key: &str, reads: usize, warm_up: usize) -> Histogram<u64> {
    let (ok, out, err) = ns
        .client(&["get", key, "--repeat", &reads.to_string(), "--timed"])
        .finish();
    assert!(ok.success(), "{err}");
    let mut h = histogram();
    for line in out.lines().skip(warm_up) {
        let ns: u64 = line.split(' ').next().unwrap().parse().unwrap();
        let _ = h.record(ns);
    }
    h
}

fn tls(ns: &Netns) {
    const WARM_UP: usize = 5;
    println!(
        "4. mutual TLS vs plain TCP: input latency (4 drives, 115200 baud, {} s each) and \
         P1082 round trip ({} reads each)",
        seconds(),
        reads()
    );
    let ussd = four_drives();
    let prefix = prefix();
    let pki = Pki::new("bench", "uss-rt bench CA", &ns.here());
    let inputs = format!("{prefix}/{}/drive/*/in", ussd.bus);
    let param = format!("{prefix}/{}/drive/1/param/P1082", ussd.bus);
    let mut measured = Vec::new();
    for secure in [false, true] {
        let (mut bridge_proc, config) = if secure {
            ns.use_tls(Some(pki.client("bench")));
            bridge_tls(ns, &ussd.bus, &prefix, &[], &pki)
        } else {
            ns.use_tls(None);
            bridge(ns, &ussd.bus, &prefix, &[])
        };
        let latency = remote_latency(ns, &inputs, seconds());
        let reads = remote_reads(ns, &param, reads(), WARM_UP);
        bridge_proc.kill();
        let _ = std::fs::remove_file(config);
        measured.push((
            if secure { "mutual TLS" } else { "plain TCP " },
            latency,
            reads,
        ));
    }
    ns.use_tls(None);
    for (name, latency, reads) in &measured {
        println!("   {name} input  {}", percentiles_us(latency));
        println!("   {name} P1082  {}", percentiles_us(reads));
    }
    let (tcp, tls) = (&measured[0], &measured[1]);
    let ratio = |a: &Histogram<u64>, b: &Histogram<u64>, q: f64| {
        b.value_at_quantile(q) as f64 / a.value_at_quantile(q) as f64
    };
    println!(
        "   TLS / TCP: input p50 {:.2}x  p99 {:.2}x; P1082 p50 {:.2}x  p99 {:.2}x",
        ratio(&tcp.1, &tls.1, 0.5),
        ratio(&tcp.1, &tls.1, 0.99),
        ratio(&tcp.2, &tls.2, 0.5),
        ratio(&tcp.2, &tls.2, 0.99)
    );
}

/// CPU time (user + system) of process `pid` so far.
fn cpu_time(pid: u32) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // After the command's closing parenthesis: state is field 3, utime 14, stime 15.
    let rest = stat.rsplit_once(") ").map_or("", |(_, r)| r);
    let fields: Vec<u64> = rest.split(' ').map(|f| f.parse().unwrap_or(0)).collect();
    let ticks = fields.get(11).copied().unwrap_or(0) + fields.get(12).copied().unwrap_or(0);
    Duration::from_nanos(ticks * 1_000_000_000 / clock_ticks())
}

fn clock_ticks() -> u64 {
    std::process::Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8_lossy(&o.stdout).trim().parse().ok())
        .unwrap_or(100)
}

/// One load: drives on one simulated bus at `baud`, each answering after `delay_ms`.
struct Load {
    drives: u8,
    baud: u32,
    delay_ms: &'static str,
}

/// What the remote side saw of one load.
struct Carried {
    offered: f64,
    delivered: f64,
    lost: u64,
    cpu_per_image: Duration,
    cpu_share: f64,
}

fn carry(ns: &Netns, load: &Load, seconds: u64) -> Carried {
    let drive_keys = format!("sim = {{ delay = {} }}", load.delay_ms);
    let drives: Vec<(u8, &str)> = (1..=load.drives)
        .map(|a| (a, drive_keys.as_str()))
        .collect();
    let ussd = Ussd::start(
        &format!("baud = {}\nnonstandard_baud = true", load.baud),
        &drives,
    );
    let prefix = prefix();
    let (bridge_proc, config) = bridge(ns, &ussd.bus, &prefix, &[]);
    let key = format!("{prefix}/{}/drive/*/in", ussd.bus);
    let cpu_before = cpu_time(bridge_proc.pid());
    let started = Instant::now();
    let (_, out, _) = ns
        .client(&[
            "sub",
            &key,
            "--for",
            &seconds.to_string(),
            "--count",
            "1000000000",
            "--stamp",
        ])
        .finish();
    let cpu = cpu_time(bridge_proc.pid()).saturating_sub(cpu_before);
    let wall = started.elapsed();
    let mut seen: HashMap<u64, BTreeSet<u64>> = HashMap::new();
    let (mut first, mut last) = (u128::MAX, 0);
    for (at, image) in stamped(&out) {
        if image["stale"] != false {
            continue;
        }
        let (Some(drive), Some(seq)) = (image["drive"].as_u64(), image["sequence"].as_u64()) else {
            continue;
        };
        seen.entry(drive).or_default().insert(seq);
        first = first.min(at);
        last = last.max(at);
    }
    let window = (last.saturating_sub(first)) as f64 / 1e9;
    let delivered: u64 = seen.values().map(|s| s.len() as u64).sum();
    let offered: u64 = seen
        .values()
        .map(|s| s.last().unwrap() - s.first().unwrap() + 1)
        .sum();
    let _ = std::fs::remove_file(config);
    Carried {
        offered: offered as f64 / window,
        delivered: delivered as f64 / window,
        lost: offered - delivered,
        cpu_per_image: cpu / u32::try_from(delivered.max(1)).unwrap_or(u32::MAX),
        cpu_share: cpu.as_secs_f64() / wall.as_secs_f64(),
    }
}

fn throughput(ns: &Netns) {
    const LOADS: [Load; 5] = [
        Load {
            drives: 4,
            baud: 115_200,
            delay_ms: "1",
        },
        Load {
            drives: 31,
            baud: 187_500,
            delay_ms: "1",
        },
        Load {
            drives: 31,
            baud: 1_000_000,
            delay_ms: "0.2",
        },
        Load {
            drives: 31,
            baud: 4_000_000,
            delay_ms: "0.05",
        },
        Load {
            drives: 31,
            baud: 12_000_000,
            delay_ms: "0.02",
        },
    ];
    let seconds = (seconds() / 2).max(1);
    println!(
        "3. throughput: images per second one bridge carries to a remote subscriber ({seconds} s each)"
    );
    println!("   drives  baud      sim delay  offered/s  delivered/s  lost  bridge CPU  CPU/image");
    let mut carried_without_loss = None;
    for load in &LOADS {
        let c = carry(ns, load, seconds);
        println!(
            "   {:6}  {:8}  {:>6} ms  {:9.0}  {:11.0}  {:4}  {:8.1} %  {:6.1} us",
            load.drives,
            load.baud,
            load.delay_ms,
            c.offered,
            c.delivered,
            c.lost,
            c.cpu_share * 100.0,
            c.cpu_per_image.as_secs_f64() * 1e6
        );
        if c.lost == 0 {
            carried_without_loss = Some((load.drives, c.delivered));
        }
    }
    match carried_without_loss {
        Some((drives, rate)) => println!(
            "   carried without a loss: up to {drives} drives x {:.0} images/s each ({rate:.0} images/s)",
            rate / f64::from(drives)
        ),
        None => println!("   every load lost images"),
    }
}

fn main() {
    let parts = Parts::from_args();
    let Some(ns) = Netns::create() else {
        // Where a network namespace is required (CI), not measuring is a failure.
        assert!(
            std::env::var_os("USS_REQUIRE_NETNS").is_none(),
            "USS_REQUIRE_NETNS is set and no network namespace could be made"
        );
        println!("SKIPPED: the remote benchmark needs root for its network namespace");
        return;
    };
    if parts.wanted("latency") {
        latency(&ns);
    }
    if parts.wanted("params") {
        params(&ns);
    }
    if parts.wanted("throughput") {
        throughput(&ns);
    }
    if parts.wanted("tls") {
        tls(&ns);
    }
}
