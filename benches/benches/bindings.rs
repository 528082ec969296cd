//! The cost of a call through the C ABI (`libussrt`) and through Python (`uss_rt`) against the
//! same call of the Rust client, measured in one run against one ussd (issue 20's closing
//! figures). Two calls:
//!
//! - reading a drive's input image: Rust `DriveWatch::snapshot` (the image and whether it can
//!   be trusted), C `ussrt_drive_read` (the same, into a struct), Python `uss_rt.read_input`
//!   (the same, as a dict with enums): the median of 300 batch means of 1000 calls;
//! - reading P1082: Rust `Bus::read`, C `ussrt_param_read_raw`, Python `uss_rt.read_param`:
//!   the median of 200 round trips, which the drive's place in the circulating list dominates.
//!
//! It builds the release `ussd` and libussrt (profile `lib`), compiles `benches/c/bindings.c`
//! against the library as built (its soname `libussrt.so.0` linked beside it, as install.sh
//! does) and runs ussd on a bus of its own (one simulated drive at 187500 baud). Python needs
//! `uss_rt` installed (`python3 -m pip install ./python`): a part that cannot be measured fails
//! the run, it prints no figure it did not measure.
//!
//! `cargo bench -p uss-benches --bench bindings` (`USS_BENCH_SHORT=1`: a few calls each, to
//! show the benchmark still runs; CI does that)

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use uss_benches::{addr, param};
use uss_client::Bus;

/// Batches of 1000 image reads, and parameter round trips; a short run takes a few of each.
fn counts() -> (usize, usize) {
    if uss_benches::short() {
        (5, 5)
    } else {
        (300, 200)
    }
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn target() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root().join("target"), PathBuf::from)
}

fn run(what: &str, command: &mut Command) {
    let status = command.status().unwrap_or_else(|e| panic!("{what}: {e}"));
    assert!(status.success(), "{what} failed");
}

fn median(mut v: Vec<u64>) -> u64 {
    v.sort_unstable();
    v[v.len() / 2]
}

/// ussd on a bus of its own (one simulated drive at 187500 baud); killed when dropped.
fn start_ussd(bus: &str) -> uss_benches::Child {
    uss_benches::start_ussd(
        bus,
        &format!(
            "[[bus]]\nname = \"{bus}\"\ndevice = \"sim\"\nbaud = 187500\n\n[[bus.drive]]\naddress = 1\n"
        ),
    )
}

fn rust_calls(bus: &Bus) -> (u64, u64) {
    let (batches, reads) = counts();
    let watch = bus.watch(addr(1)).expect("drive 1's image");
    let mut means = Vec::with_capacity(batches);
    for _ in 0..batches {
        let t0 = Instant::now();
        for _ in 0..1000 {
            std::hint::black_box(watch.snapshot());
        }
        means.push(t0.elapsed().as_nanos() as u64 / 1000);
    }
    let trips = (0..reads)
        .map(|_| {
            let t0 = Instant::now();
            bus.read(addr(1), param(1082)).expect("P1082");
            t0.elapsed().as_nanos() as u64
        })
        .collect();
    (median(means), median(trips))
}

/// `(drive_read, param_read)` in ns as a program printed them.
fn parse(out: &str) -> Option<(u64, u64)> {
    let value = |key: &str| {
        out.lines()
            .find_map(|l| l.strip_prefix(key))
            .and_then(|v| v.trim().parse().ok())
    };
    Some((value("drive_read ")?, value("param_read ")?))
}

fn c_calls(bus: &str) -> (u64, u64) {
    let (batches, reads) = counts();
    let lib = target().join("lib");
    let exe = lib.join("bench-bindings");
    // The program loads the library by its soname, which only an install links (install.sh).
    let soname = lib.join("libussrt.so.0");
    let _ = std::fs::remove_file(&soname);
    std::os::unix::fs::symlink("libussrt.so", &soname).expect("libussrt.so.0 -> libussrt.so");
    run(
        "cc",
        Command::new("cc")
            .args(["-std=c11", "-O2", "-I"])
            .arg(root().join("capi/include"))
            .arg("-I")
            .arg(root().join("shm-types/include"))
            .arg(root().join("benches/c/bindings.c"))
            .arg("-o")
            .arg(&exe)
            .arg(lib.join("libussrt.so")),
    );
    let out = Command::new(&exe)
        .args([bus, "1", &batches.to_string(), &reads.to_string()])
        .env("LD_LIBRARY_PATH", &lib)
        .output()
        .expect("the C program");
    parse(&String::from_utf8_lossy(&out.stdout)).unwrap_or_else(|| {
        panic!("C: not measured: {}", String::from_utf8_lossy(&out.stderr));
    })
}

const PYTHON: &str = r#"
import statistics, sys, time
import uss_rt
bus = uss_rt.open_bus(sys.argv[1])
batches, reads = int(sys.argv[2]), int(sys.argv[3])
means = []
for _ in range(batches):
    t0 = time.perf_counter_ns()
    for _ in range(1000):
        uss_rt.read_input(bus, 1)
    means.append((time.perf_counter_ns() - t0) // 1000)
trips = []
for _ in range(reads):
    t0 = time.perf_counter_ns()
    uss_rt.read_param(bus, 1, 1082)
    trips.append(time.perf_counter_ns() - t0)
print("drive_read", int(statistics.median(means)))
print("param_read", int(statistics.median(trips)))
"#;

fn python_calls(bus: &str) -> (u64, u64) {
    let (batches, reads) = counts();
    let out = Command::new("python3")
        .args(["-c", PYTHON, bus, &batches.to_string(), &reads.to_string()])
        .current_dir(std::env::temp_dir())
        .output()
        .expect("python3");
    parse(&String::from_utf8_lossy(&out.stdout)).unwrap_or_else(|| {
        panic!(
            "Python: not measured ({}); install uss_rt with `python3 -m pip install ./python`",
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .last()
                .unwrap_or("?")
        )
    })
}

fn main() {
    run(
        "cargo build libussrt",
        Command::new(env!("CARGO")).current_dir(root()).args([
            "build",
            "--quiet",
            "--profile",
            "lib",
            "-p",
            "uss-rt-c",
            "--lib",
        ]),
    );
    let name = format!("bindings{}", std::process::id());
    let _ussd = start_ussd(&name);
    let deadline = Instant::now() + Duration::from_secs(20);
    let bus = loop {
        if let Ok(bus) = Bus::open(&name)
            && bus.read(addr(1), param(1082)).is_ok()
        {
            break bus;
        }
        assert!(Instant::now() < deadline, "ussd did not come up");
        std::thread::sleep(Duration::from_millis(50));
    };
    let rust = rust_calls(&bus);
    let c = c_calls(&name);
    let python = python_calls(&name);
    println!("bindings: one call, the same ussd, one run (median; read_input: batches of 1000)");
    println!(
        "  {:<8} {:>16} {:>10} {:>18} {:>10}",
        "", "read_input", "/ Rust", "read P1082", "/ Rust"
    );
    let row = |who: &str, (image, param): (u64, u64)| {
        println!(
            "  {who:<8} {:>13} ns {:>9.2}x {:>15.1} us {:>9.2}x",
            image,
            image as f64 / rust.0 as f64,
            param as f64 / 1e3,
            param as f64 / rust.1 as f64
        );
    };
    row("Rust", rust);
    row("C ABI", c);
    row("Python", python);
}
