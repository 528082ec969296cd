//! `soak`: ussd for a long time on a faulty simulated bus, with a controller running a drive
//! and a client writing and reading back parameters; prints what happened. Not part of
//! `cargo test` (it runs for minutes); run it as guide "Soak" says:
//!
//! ```sh
//! cargo build --release -p uss-master --bin ussd && cargo run --release -p uss-benches --bin soak -- --minutes 10
//! ```
//!
//! ussd runs as its own process (the release `ussd` next to this binary) on a bus of its own
//! (`soak<pid>`): 8 simulated drives at 115200 baud whose replies are spoilt with 5 %
//! probability (dropped, bad BCC, a changed byte, cut short, noise), drive 1 with its telegram
//! monitoring on. One thread controls drive 1 (runs it at 10 Hz, refreshes every 20 ms); one
//! writes P1120 on drives 2..=8 in turn and reads it back; one reads r0947 fault buffers.
//! Exits 1 when a parameter result was lost or a read-back did not match.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};
use uss_benches::{addr, param};
use uss_client::{Bus, ClientError, ControlOptions, DriveState, ParamError, Value, state_of};

const DRIVES: u8 = 8;
/// 5 % of replies spoilt, spread over the kinds of fault.
const FAULTS: &str = "drop=0.015,bcc=0.01,byte=0.01,truncate=0.01,noise=0.005";
/// The same as a `[bus.drive.sim]` table's keys.
const FAULT_KEYS: &str = "drop = 0.015, bcc = 0.01, byte = 0.01, truncate = 0.01, noise = 0.005";

fn main() -> ExitCode {
    let duration = match duration_from_args() {
        Ok(d) => d,
        Err(e) => {
            eprintln!("soak: {e}\nusage: soak [--minutes M | --seconds S]");
            return ExitCode::from(2);
        }
    };
    match soak(duration) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => {
            eprintln!("soak: {e}");
            ExitCode::from(2)
        }
    }
}

fn duration_from_args() -> Result<Duration, String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut duration = Duration::from_secs(600);
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        let n: f64 = value
            .parse()
            .ok()
            .filter(|n: &f64| n.is_finite() && *n > 0.0)
            .ok_or_else(|| format!("{flag} {value}: give a positive number"))?;
        duration = match flag.as_str() {
            "--minutes" => Duration::from_secs_f64(n * 60.0),
            "--seconds" => Duration::from_secs_f64(n),
            other => return Err(format!("unknown option {other}")),
        };
    }
    Ok(duration)
}

/// ussd, stopped with SIGTERM when dropped.
struct Daemon {
    child: Child,
    config: PathBuf,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Ok(pid) = i32::try_from(self.child.id()) {
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(pid),
                nix::sys::signal::Signal::SIGTERM,
            );
        }
        let _ = self.child.wait();
        let _ = std::fs::remove_file(&self.config);
    }
}

fn start_ussd(bus: &str) -> Result<Daemon, String> {
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let ussd = exe.with_file_name("ussd");
    if !ussd.exists() {
        return Err(format!(
            "{} is missing: build it first with `cargo build --release -p uss-master --bin ussd`",
            ussd.display()
        ));
    }
    let mut toml = format!(
        "[[bus]]\nname = \"{bus}\"\ndevice = \"sim\"\nbaud = 115200\nretries = 2\n\
         offline_after = 3\nseed = {}\n",
        std::process::id()
    );
    for a in 1..=DRIVES {
        let monitoring = if a == 1 { ", p2014 = 200" } else { "" };
        let _ = write!(
            toml,
            "\n[[bus.drive]]\naddress = {a}\nsim = {{ {FAULT_KEYS}{monitoring} }}\n"
        );
    }
    let config = std::env::temp_dir().join(format!("ussd-soak-{bus}.toml"));
    std::fs::write(&config, toml).map_err(|e| e.to_string())?;
    let child = Command::new(&ussd)
        .arg("--config")
        .arg(&config)
        .args(["--summary-every", "3600"])
        .stdout(Stdio::null())
        .spawn()
        .map_err(|e| format!("cannot start {}: {e}", ussd.display()))?;
    Ok(Daemon { child, config })
}

fn open_when_running(bus: &str) -> Result<Bus, String> {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        match Bus::open(bus) {
            Ok(b) => return Ok(b),
            Err(ClientError::NotRunning { .. }) if Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => return Err(e.to_string()),
        }
    }
}

/// ussd's resident set (kB) and CPU time used so far, from /proc.
fn usage(pid: u32) -> (u64, Duration) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rss = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0);
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command (in parentheses): utime and stime are the 12th and 13th.
    let ticks: u64 = stat.rsplit_once(')').map_or(0, |(_, rest)| {
        rest.split_whitespace()
            .skip(11)
            .take(2)
            .filter_map(|t| t.parse::<u64>().ok())
            .sum()
    });
    // SAFETY: sysconf has no preconditions.
    let hz = u64::try_from(unsafe { nix::libc::sysconf(nix::libc::_SC_CLK_TCK) })
        .unwrap_or(100)
        .max(1);
    (rss, Duration::from_millis(ticks * 1000 / hz))
}

#[derive(Default)]
struct Counts {
    param_requests: AtomicU64,
    param_failures: AtomicU64,
    lost: AtomicU64,
    mismatches: AtomicU64,
    aborts: AtomicU64,
    offline_blips: AtomicU64,
}

/// Runs drive 1 at 10 Hz until `stop`; a trip (anything that latches it) counts as an abort
/// and the drive is re-armed and run again.
fn controller(bus: &Bus, stop: &AtomicBool, counts: &Counts) -> Result<(), String> {
    let c = bus
        .control(addr(1), ControlOptions::default())
        .map_err(|e| e.to_string())?;
    let run = |c: &uss_client::Controller| -> Result<(), String> {
        c.rearm(uss_client::monotonic_ns())
            .map_err(|e| e.to_string())?;
        // Read again after a blip offline: no Hz before it is known.
        let inputs = c.inputs();
        inputs
            .wait_for_reference(inputs.reference_wait())
            .map_err(|e| e.to_string())?;
        c.run_hz(10.0).map_err(|e| e.to_string())?;
        c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(10))
            .map_err(|e| e.to_string())?;
        Ok(())
    };
    run(&c)?;
    let mut offline = false;
    while !stop.load(Ordering::Relaxed) {
        // The loop's own call refreshes the drive (every 10 ms, inside its 100 ms watchdog).
        match c.keepalive().and_then(|()| c.check()) {
            Ok(i) => {
                if i.online == 0 && !offline {
                    counts.offline_blips.fetch_add(1, Ordering::Relaxed);
                }
                offline = i.online == 0;
                if i.online != 0 && state_of(&i) == DriveState::Fault {
                    counts.aborts.fetch_add(1, Ordering::Relaxed);
                    eprintln!("  controller: drive 1 in fault (ZSW1 {:#06X})", i.zsw1);
                    c.acknowledge_fault(Duration::from_secs(2))
                        .map_err(|e| e.to_string())?;
                    run(&c)?;
                }
            }
            Err(ClientError::Tripped { latch, .. }) => {
                counts.aborts.fetch_add(1, Ordering::Relaxed);
                eprintln!("  controller: drive 1 tripped: {latch}; re-arming");
                run(&c)?;
            }
            Err(e) => return Err(format!("controller: {e}")),
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    c.release().map_err(|e| e.to_string())?;
    Ok(())
}

/// Writes P1120 on drives 2..=8 in turn and reads it back until `stop`.
fn writer(bus: &Bus, stop: &AtomicBool, counts: &Counts) {
    let mut held: [Option<Value>; DRIVES as usize + 1] = [None; DRIVES as usize + 1];
    let mut k = 0u32;
    while !stop.load(Ordering::Relaxed) {
        let drive = 2 + (k % u32::from(DRIVES - 1)) as u8;
        let value = Value::from_f32(1.0 + (k % 200) as f32 * 0.5);
        k += 1;
        counts.param_requests.fetch_add(2, Ordering::Relaxed);
        match bus.write(addr(drive), param(1120), value, false) {
            Ok(v) if v == value => held[usize::from(drive)] = Some(value),
            Ok(v) => {
                counts.mismatches.fetch_add(1, Ordering::Relaxed);
                eprintln!("  writer: drive {drive} P1120 := {value:X?} answered {v:X?}");
            }
            Err(e) => {
                // It may or may not have been written: the read-back says.
                held[usize::from(drive)] = None;
                count_failure(counts, &e);
            }
        }
        match (bus.read(addr(drive), param(1120)), held[usize::from(drive)]) {
            (Ok(v), Some(h)) if v != h => {
                counts.mismatches.fetch_add(1, Ordering::Relaxed);
                eprintln!("  writer: drive {drive} P1120 reads {v:X?}, written {h:X?}");
            }
            (Ok(v), _) => held[usize::from(drive)] = Some(v),
            (Err(e), _) => count_failure(counts, &e),
        }
    }
}

/// Reads every drive's fault buffer (8 elements in one request) in turn until `stop`.
fn fault_reader(bus: &Bus, stop: &AtomicBool, counts: &Counts) {
    let mut k = 0u8;
    while !stop.load(Ordering::Relaxed) {
        let drive = 1 + k % DRIVES;
        k = k.wrapping_add(1);
        counts.param_requests.fetch_add(1, Ordering::Relaxed);
        if let Err(e) = bus.faults(addr(drive)) {
            count_failure(counts, &e);
        }
    }
}

/// A failure ussd reported (a job timeout, the drive offline for a moment) is a result; no
/// answer at all is a lost result.
fn count_failure(counts: &Counts, e: &ParamError) {
    match e {
        ParamError::NoAnswer(_) | ParamError::Dropped => {
            counts.lost.fetch_add(1, Ordering::Relaxed);
            eprintln!("  lost: {e}");
        }
        _ => {
            counts.param_failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}

fn soak(duration: Duration) -> Result<bool, String> {
    let name = format!("soak{}", std::process::id());
    let daemon = start_ussd(&name)?;
    let pid = daemon.child.id();
    let bus = open_when_running(&name)?;
    let deadline = Instant::now() + Duration::from_secs(20);
    while bus
        .drives()
        .iter()
        .any(|&a| bus.watch(a).map_or(true, |w| w.latest().online == 0))
    {
        if Instant::now() > deadline {
            return Err("the simulated drives did not come online".into());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    println!(
        "soak: ussd (process {pid}) on bus {name}: {DRIVES} simulated drives at 115200 baud, \
         5 % of replies spoilt ({FAULTS}); running {:.0} s",
        duration.as_secs_f64()
    );
    let stop = Arc::new(AtomicBool::new(false));
    let counts = Arc::new(Counts::default());
    std::thread::sleep(Duration::from_secs(2));
    let (rss_start, cpu_start) = usage(pid);
    let status_start = bus.status().map_err(|e| e.to_string())?;
    let started = Instant::now();

    let result = std::thread::scope(|s| {
        let control = s.spawn(|| controller(&bus, &stop, &counts));
        s.spawn(|| writer(&bus, &stop, &counts));
        s.spawn(|| fault_reader(&bus, &stop, &counts));
        let mut next_report = Duration::from_secs(60);
        while started.elapsed() < duration {
            std::thread::sleep(Duration::from_millis(200));
            if control.is_finished() {
                break;
            }
            if started.elapsed() >= next_report {
                next_report += Duration::from_secs(60);
                if let Ok(st) = bus.status() {
                    println!(
                        "  {:5.0} s: {} exchanges, {} param requests, {} lost, {} mismatches, \
                         {} controller aborts",
                        started.elapsed().as_secs_f64(),
                        st.exchanges - status_start.exchanges,
                        counts.param_requests.load(Ordering::Relaxed),
                        counts.lost.load(Ordering::Relaxed),
                        counts.mismatches.load(Ordering::Relaxed),
                        counts.aborts.load(Ordering::Relaxed)
                    );
                    let _ = std::io::stdout().flush();
                }
            }
        }
        stop.store(true, Ordering::Relaxed);
        control
            .join()
            .unwrap_or_else(|_| Err("the controller panicked".into()))
    });
    let elapsed = started.elapsed();
    let status_end = bus.status().map_err(|e| e.to_string())?;
    let (rss_end, cpu_end) = usage(pid);
    let exchanges = status_end.exchanges - status_start.exchanges;
    let errors: u64 = bus
        .drives()
        .iter()
        .filter_map(|&a| bus.diag(a).ok())
        .map(|d| {
            let c = d.counters;
            c.timeouts + c.bcc + c.length + c.missing_stx + c.bad_lge + c.residual + c.start_pause
        })
        .sum();
    let cpu = cpu_end.saturating_sub(cpu_start);
    let c = &counts;
    let lost = c.lost.load(Ordering::Relaxed);
    let mismatches = c.mismatches.load(Ordering::Relaxed);
    println!(
        "soak: {:.0} s: {exchanges} exchanges ({:.0}/s), {errors} spoilt or missing replies \
         seen (all drives, since start), {} param requests ({} ended in a reported failure), \
         {lost} lost results, {mismatches} read-back mismatches, {} controller aborts, {} offline \
         blips of the controlled drive; ussd RSS {rss_start} kB -> {rss_end} kB, CPU {:.1} s = \
         {:.1} us per exchange; jobs accepted {} finished {} lost {}",
        elapsed.as_secs_f64(),
        exchanges as f64 / elapsed.as_secs_f64(),
        c.param_requests.load(Ordering::Relaxed),
        c.param_failures.load(Ordering::Relaxed),
        c.aborts.load(Ordering::Relaxed),
        c.offline_blips.load(Ordering::Relaxed),
        cpu.as_secs_f64(),
        cpu.as_secs_f64() * 1e6 / exchanges.max(1) as f64,
        status_end.jobs_accepted,
        status_end.jobs_finished,
        status_end.results_lost
    );
    drop(daemon);
    result?;
    Ok(lost == 0 && mismatches == 0 && status_end.results_lost == 0)
}
