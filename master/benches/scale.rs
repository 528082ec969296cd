//! Scale (issue "the real-time bus engine"), printed as measured in one run on this machine: 8
//! simulated buses x 31 drives in one ussd runtime (every bus in its real-time thread with its
//! iceoryx2 services, as `ussd` runs them), the process's CPU use and peak memory. The bus
//! threads run `SCHED_FIFO` where the machine allows (root here); the mode is printed.
//!
//! `cargo bench -p uss-master --bench scale`

use std::fmt::Write;
use std::time::{Duration, Instant};
use uss_engine::Stats;
use uss_master::config::Config;
use uss_master::daemon::runtime::{self, RunOptions};

/// (user, system) CPU seconds of this process so far.
fn cpu_seconds() -> (f64, f64) {
    let usage = nix::sys::resource::getrusage(nix::sys::resource::UsageWho::RUSAGE_SELF)
        .expect("getrusage");
    let t = |tv: nix::sys::time::TimeVal| tv.tv_sec() as f64 + tv.tv_usec() as f64 / 1e6;
    (t(usage.user_time()), t(usage.system_time()))
}
fn peak_rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(0)
}

fn scale() {
    let mut toml = String::new();
    for b in 0..8 {
        let _ = write!(
            toml,
            "[[bus]]\nname = \"scale{}b{b}\"\ndevice = \"sim\"\nbaud = 115200\n\n",
            std::process::id()
        );
        for a in 1..=31 {
            let _ = write!(toml, "[[bus.drive]]\naddress = {a}\n\n");
        }
    }
    let config = Config::parse(&toml, "scale.toml").expect("scale configuration");
    let rss_before = peak_rss_kib();
    let cpu_before = cpu_seconds();
    let started = Instant::now();
    let buses = runtime::start(
        &config.buses,
        RunOptions {
            require_rt: false,
            summary_every: Duration::from_secs(3600),
        },
    )
    .expect("start 8 buses");
    // A short run (USS_BENCH_SHORT=1, CI: it still runs from a fresh clone) takes a second.
    let short = std::env::var_os("USS_BENCH_SHORT").is_some_and(|v| v == "1");
    std::thread::sleep(Duration::from_secs(if short { 1 } else { 10 }));
    let stats: Vec<Stats> = buses.iter().map(|b| b.handle.stats()).collect();
    let report = &buses[0].rt_report;
    let mode = format!(
        "{}: SCHED_FIFO {}, memory {}",
        report.mode(),
        report
            .priority
            .map_or("not obtained".to_owned(), |p| format!("priority {p}")),
        if report.memory_locked {
            "locked"
        } else {
            "not locked"
        }
    );
    let wall = started.elapsed().as_secs_f64();
    let (user, system) = cpu_seconds();
    let (user, system) = (user - cpu_before.0, system - cpu_before.1);
    let cpu = user + system;
    for b in buses {
        b.stop().expect("clean stop");
    }
    let exchanges: u64 = stats.iter().map(|s| s.bus.exchanges).sum();
    let errors: u64 = stats
        .iter()
        .flat_map(|s| s.drives.iter())
        .map(|d| d.counters.rejected)
        .sum();
    let online = stats
        .iter()
        .flat_map(|s| s.drives.iter())
        .filter(|d| d.online)
        .count();
    let eff: Vec<String> = stats
        .iter()
        .map(|s| format!("{:.3}", s.bus.efficiency().unwrap_or(0.0)))
        .collect();
    println!(
        "== scale: 8 simulated buses x 31 drives at 115200 baud in one process, {wall:.1} s [{mode}]"
    );
    println!(
        "   {exchanges} exchanges ({:.0}/s), {online}/248 drives online, {errors} errors; efficiency per bus {}",
        exchanges as f64 / wall,
        eff.join(" ")
    );
    println!(
        "   CPU {cpu:.2} s (user {user:.2} s, system {system:.2} s) in {wall:.1} s = {:.1} % of one core ({:.1} % per bus, {:.1} us per exchange); peak RSS {:.1} MiB (was {:.1} MiB before the buses)",
        cpu / wall * 100.0,
        cpu / wall * 100.0 / 8.0,
        cpu / exchanges.max(1) as f64 * 1e6,
        peak_rss_kib() as f64 / 1024.0,
        rss_before as f64 / 1024.0
    );
}

fn main() {
    scale();
}
