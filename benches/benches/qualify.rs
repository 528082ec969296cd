//! `ussd --qualify` beside rt-tests' `cyclictest` in one run: the same priority, the same CPU,
//! the same seconds, the same 1 ms interval, both locking memory, started together; once on an
//! idle machine and once under `stress-ng` load (CPU, I/O and memory workers). It prints both
//! tools' p99 and maximum and their ratio: the qualification measures what cyclictest measures,
//! so its verdict can be trusted (issue 35: within 10 % at p99).
//!
//! Needs `cyclictest` (Debian `rt-tests`) and `stress-ng`, and root for `SCHED_FIFO`; a missing
//! tool fails the run, it prints no figure it did not measure.
//!
//! `cargo bench -p uss-benches --bench qualify` (`USS_BENCH_SHORT=1`: 2 s each, CI does that)

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

/// cyclictest's and the bus thread's priority (ussd's default `priority`).
const PRIORITY: u8 = 80;

/// p99 and maximum, µs.
#[derive(Debug, Clone, Copy)]
struct Figures {
    p99: f64,
    max: f64,
}

fn need(tool: &str, package: &str) {
    let found = Command::new("sh")
        .args(["-c", &format!("command -v {tool}")])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    assert!(found, "{tool} is not installed: apt-get install {package}");
}

fn finished(what: &str, child: Child) -> String {
    let Output {
        status,
        stdout,
        stderr,
    } = child.wait_with_output().expect(what);
    let out = String::from_utf8_lossy(&stdout).into_owned();
    // ussd --qualify exits 1 when the timing does not hold: a verdict, not a failure.
    assert!(
        status.success() || (what == "ussd --qualify" && status.code() == Some(1)),
        "{what}: {status}\n{out}{}",
        String::from_utf8_lossy(&stderr)
    );
    out
}

/// `wake-up latency: p50 .. us, p99 X us, p99.9 .. us, max Y us` of `ussd --qualify`.
fn ussd_figures(out: &str) -> Figures {
    let line = out
        .lines()
        .find(|l| l.contains("wake-up latency:"))
        .unwrap_or_else(|| panic!("ussd --qualify: not measured:\n{out}"));
    let words: Vec<&str> = line.split_whitespace().collect();
    let value = |key: &str| -> f64 {
        words
            .windows(2)
            .find(|w| w[0] == key)
            .and_then(|w| w[1].parse().ok())
            .unwrap_or_else(|| panic!("no {key} in {line:?}"))
    };
    Figures {
        p99: value("p99"),
        max: value("max"),
    }
}

/// p99 from cyclictest's 1 µs histogram, and its reported maximum.
fn cyclictest_figures(out: &str) -> Figures {
    let mut bins = Vec::new();
    let mut max = None;
    for line in out.lines() {
        if let Some(m) = line.strip_prefix("# Max Latencies:") {
            max = m.trim().parse::<f64>().ok();
        } else if let Some((us, n)) = line.split_once(' ')
            && let (Ok(us), Ok(n)) = (us.parse::<u64>(), n.trim().parse::<u64>())
        {
            bins.push((us, n));
        }
    }
    let total: u64 = bins.iter().map(|b| b.1).sum();
    assert!(total > 0, "cyclictest: not measured:\n{out}");
    let mut seen = 0;
    let p99 = bins
        .iter()
        .find(|&&(_, n)| {
            seen += n;
            seen * 100 >= total * 99
        })
        .map_or(0.0, |&(us, _)| us as f64);
    Figures {
        p99,
        max: max.unwrap_or_else(|| panic!("cyclictest: no maximum:\n{out}")),
    }
}

/// Both tools at once for `seconds` on `cpu`.
fn one_run(ussd: &Path, config: &Path, cpu: usize, seconds: u64) -> (Figures, Figures) {
    let secs = seconds.to_string();
    let ussd = Command::new(ussd)
        .args(["--qualify", "--seconds", &secs, "--config"])
        .arg(config)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("ussd --qualify");
    let cyclictest = Command::new("cyclictest")
        .args(["-m", "-q", "-i", "1000", "-h", "20000"])
        .args(["-p", &PRIORITY.to_string(), "-a", &cpu.to_string()])
        .args(["-D", &secs])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("cyclictest");
    let ours = ussd_figures(&finished("ussd --qualify", ussd));
    let theirs = cyclictest_figures(&finished("cyclictest", cyclictest));
    (ours, theirs)
}

fn main() {
    need("cyclictest", "rt-tests");
    need("stress-ng", "stress-ng");
    let short = uss_benches::short();
    let seconds: u64 = if short { 2 } else { 60 };
    let ussd = uss_benches::release_binary("uss-master", "ussd");
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    let cpu = cpus - 1;
    let config = std::env::temp_dir().join(format!("qualify-{}.toml", std::process::id()));
    std::fs::write(
        &config,
        format!(
            "[[bus]]\nname = \"qualify{}\"\ndevice = \"sim\"\nbaud = 187500\ncpu = {cpu}\n\
             priority = {PRIORITY}\n\n[[bus.drive]]\naddress = 1\n",
            std::process::id()
        ),
    )
    .expect("the configuration");
    println!(
        "qualify: ussd --qualify beside cyclictest -m -i 1000 -p {PRIORITY} -a {cpu}, {seconds} s \
         each, started together (this machine: {cpus} CPUs)"
    );
    println!(
        "  {:<7} {:>12} {:>15} {:>8} {:>12} {:>15} {:>8}",
        "load", "ussd p99", "cyclictest p99", "ratio", "ussd max", "cyclictest max", "ratio"
    );
    for load in ["idle", "stress"] {
        let stress = (load == "stress").then(|| {
            Command::new("stress-ng")
                .args(["--cpu", &cpus.to_string(), "--io", "1", "--vm", "1"])
                .args([
                    "--vm-bytes",
                    "256M",
                    "--timeout",
                    &format!("{}s", seconds + 5),
                ])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("stress-ng")
        });
        if stress.is_some() {
            std::thread::sleep(Duration::from_secs(1));
        }
        let (ours, theirs) = one_run(&ussd, &config, cpu, seconds);
        if let Some(mut s) = stress {
            let _ = s.kill();
            let _ = s.wait();
        }
        println!(
            "  {load:<7} {:>9.1} us {:>12.1} us {:>7.2}x {:>9.1} us {:>12.1} us {:>7.2}x",
            ours.p99,
            theirs.p99,
            ours.p99 / theirs.p99.max(1.0),
            ours.max,
            theirs.max,
            ours.max / theirs.max.max(1.0)
        );
    }
    let _ = std::fs::remove_file(&config);
}
