//! Benchmarks of uss-rt live in `benches/benches/`; each prints ratios measured in one run
//! (see `docs/ARCHITECTURE.md`, "Measuring"). Run them with `cargo bench -p uss-benches`.
//! This library holds what they share.

use hdrhistogram::Histogram;

/// `p50 / p99 / p99.9 / max` of a nanosecond histogram, in microseconds.
pub fn percentiles_us(h: &Histogram<u64>) -> String {
    let us = |v: u64| v as f64 / 1000.0;
    format!(
        "p50 {:8.1} us  p99 {:8.1} us  p99.9 {:8.1} us  max {:8.1} us  (n = {})",
        us(h.value_at_quantile(0.5)),
        us(h.value_at_quantile(0.99)),
        us(h.value_at_quantile(0.999)),
        us(h.max()),
        h.len()
    )
}

/// The parts of a benchmark to run: `cargo bench` passes harness flags such as `--bench`; any
/// other argument names a part, and no name means every part (`cargo bench -p uss-benches -- scale`).
#[derive(Debug)]
pub struct Parts(Vec<String>);

impl Parts {
    pub fn from_args() -> Self {
        Self(
            std::env::args()
                .skip(1)
                .filter(|a| !a.starts_with("--"))
                .collect(),
        )
    }

    pub fn wanted(&self, name: &str) -> bool {
        self.0.is_empty() || self.0.iter().any(|o| o == name)
    }
}

/// Whether to run short (`USS_BENCH_SHORT=1`): a few rounds of each part, to show the
/// benchmark still runs from a fresh clone (CI does that); its figures mean nothing.
pub fn short() -> bool {
    std::env::var_os("USS_BENCH_SHORT").is_some_and(|v| v == "1")
}

/// How many rounds (exchanges, samples, repetitions) a benchmark part takes: `full`, or in
/// [`short`] mode a twentieth of them and at least `least` (enough to run every line of the
/// part; the figures then mean nothing).
pub fn rounds(full: u64, least: u64) -> u64 {
    if short() {
        (full / 20).max(least)
    } else {
        full
    }
}

/// The workspace's target directory.
pub fn target_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(
        || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"),
        std::path::PathBuf::from,
    )
}

/// Builds `bin` of `package` in release (or in the profile `USS_BENCH_PROFILE` names: CI's
/// short runs take the `dev` profile its tests built) and returns its path.
pub fn release_binary(package: &str, bin: &str) -> std::path::PathBuf {
    let profile = std::env::var("USS_BENCH_PROFILE").unwrap_or_else(|_| "release".to_owned());
    let status = std::process::Command::new(env!("CARGO"))
        .args([
            "build",
            "--quiet",
            "--profile",
            &profile,
            "-p",
            package,
            "--bin",
            bin,
        ])
        .status()
        .unwrap_or_else(|e| panic!("cargo build {bin}: {e}"));
    assert!(status.success(), "building {bin}");
    // Cargo keeps the dev profile's output in `debug`.
    let dir = if profile == "dev" {
        "debug"
    } else {
        profile.as_str()
    };
    target_dir().join(dir).join(bin)
}

/// A child process killed (and its configuration file removed) when dropped.
#[derive(Debug)]
pub struct Child {
    pub child: std::process::Child,
    pub file: Option<std::path::PathBuf>,
}

impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if let Some(f) = &self.file {
            let _ = std::fs::remove_file(f);
        }
    }
}

/// A release `ussd` running `config` (TOML text), quiet; killed when dropped.
pub fn start_ussd(name: &str, config: &str) -> Child {
    let ussd = release_binary("uss-master", "ussd");
    let file = std::env::temp_dir().join(format!("{name}-{}.toml", std::process::id()));
    std::fs::write(&file, config).expect("the benchmark's configuration file");
    let child = std::process::Command::new(ussd)
        .arg("--config")
        .arg(&file)
        .args(["--summary-every", "3600"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("the release ussd");
    Child {
        child,
        file: Some(file),
    }
}

/// A release `uss-sim --pty` with `args`; returns it and the pty's path.
pub fn start_sim(args: &[&str]) -> (Child, String) {
    use std::io::BufRead;
    let sim = release_binary("uss-drive-sim", "uss-sim");
    let mut child = std::process::Command::new(sim)
        .arg("--pty")
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("the release uss-sim");
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().expect("piped"))
        .read_line(&mut line)
        .expect("uss-sim's first line");
    let path = line
        .trim()
        .strip_prefix("PTY ")
        .unwrap_or_else(|| panic!("uss-sim printed {line:?}"))
        .to_owned();
    (Child { child, file: None }, path)
}

/// Opens bus `name` once its ussd serves it (at most 30 s).
pub fn open_bus(name: &str) -> uss_client::Bus {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    loop {
        match uss_client::Bus::open(name) {
            Ok(b) => return b,
            Err(e) => assert!(std::time::Instant::now() < deadline, "bus {name}: {e}"),
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// Drive `a` of a benchmark's bus (1..=31).
pub fn addr(a: u8) -> uss_client::Address {
    uss_client::Address::new(a).expect("a benchmark drive's address is 0..=31")
}

/// Parameter `pnu` (P + the number).
pub fn param(pnu: u16) -> uss_client::ParamRef {
    uss_client::ParamRef::p(pnu)
}

/// The benchmarks' bus: ussd's defaults but a 500 ms probe and one failed poll to go offline.
pub fn engine_config(
    timing: uss_protocol::Timing,
    drives: Vec<uss_engine::DriveSetup>,
    capture: bool,
) -> uss_engine::EngineConfig {
    uss_engine::EngineConfig {
        timing,
        response_timeout: core::time::Duration::from_millis(20),
        retries: 2,
        offline_after: 1,
        offline_probe: core::time::Duration::from_millis(500),
        cycle_time: None,
        param_timeout: core::time::Duration::from_secs(2),
        echo: false,
        mailbox_depth: 16,
        publish_every: core::time::Duration::from_millis(100),
        param_priority: false,
        safety_first: true,
        rx_latency: core::time::Duration::ZERO,
        capture,
        drives,
    }
}
