//! The C ABI (`libussrt`, crate `uss-rt-c`) from real C and C++ programs against a real ussd:
//! the C example and the C++ example (RAII wrapper) of `capi/examples` run a drive as the
//! guide shows, and `capi/tests/c/abi_check.c` goes through every kind of call: statuses and
//! messages, the latch as an error code with its reason, the drive's error number, a stall of
//! the program, a release.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::{Mutex, MutexGuard, PoisonError};
use uss_integration_tests::Ussd;
use uss_integration_tests::addr;

/// One ussd at a time: each runs a paced bus thread, and the machine has two cores.
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(PoisonError::into_inner)
}

fn compile(compiler: &str, source: &str, extra: &[&str]) -> PathBuf {
    uss_integration_tests::c_program(compiler, source, extra)
}

fn run(exe: &Path, args: &[&str]) -> Output {
    Command::new(exe).args(args).output().unwrap()
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn every_kind_of_call_of_the_c_abi_against_a_real_ussd() {
    let exe = compile("cc", "capi/tests/c/abi_check.c", &["-std=c11"]);
    let _serial = serial();
    // Drive 2 has a setting beyond uss-rt's catalogue (uss-sim's extra) for the backup that
    // asks the drive for it.
    let ussd = Ussd::start("", &[(1, ""), (2, "sim = { extra = \"701\" }")]);
    let out = run(&exe, &[&ussd.bus]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stdout}{stderr}\n{}", ussd.log());
    assert!(stdout.starts_with("abi_check: all "), "{stdout}");
    println!("{stdout}");
}

/// `ussrt_scan` from C against `uss-sim` over a pty (issue 46, item 5): the library's scan,
/// the one `ussctl scan` and `uss_rt.scan` give.
#[test]
fn a_c_program_scans_a_line_ussd_does_not_serve() {
    let exe = compile("cc", "capi/tests/c/scan_check.c", &["-std=c11"]);
    let sim = uss_integration_tests::SimProcess::start(&[
        "--baud",
        "19200",
        "--drive",
        "3:pkw=4,pzd=2",
        "--drive",
        "5:pkw=127,pzd=6,family=g120",
    ]);
    let out = run(&exe, &[&sim.path]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{stdout}{stderr}");
    assert!(stdout.starts_with("scan_check: all "), "{stdout}");
}

/// Rule 3 from C: while ussd is paused (SIGSTOP) longer than a drive's limit, the drive's
/// diagnostics read through `ussrt_drive_diag` never say online (`online = 0`, or
/// `USSD_GONE` once ussd's heartbeat is late), and online again once it runs.
#[test]
fn c_diagnostics_of_a_paused_ussd_say_the_drive_is_not_online() {
    use nix::sys::signal::{Signal, kill};
    use std::io::{BufRead as _, BufReader, Write as _};
    use std::process::Stdio;
    let exe = compile("cc", "capi/tests/c/diag_online.c", &["-std=c11"]);
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    ussd.bus()
        .watch(addr(1))
        .unwrap()
        .wait_for(std::time::Duration::from_secs(5), "online", |i| {
            i.online == 1
        })
        .unwrap();
    let mut program = Command::new(&exe)
        .arg(&ussd.bus)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = program.stdin.take().unwrap();
    let mut stdout = BufReader::new(program.stdout.take().unwrap()).lines();
    let mut ask = || {
        writeln!(stdin, "diag").unwrap();
        stdin.flush().unwrap();
        stdout.next().unwrap().unwrap()
    };
    // The diagnostics are published every 100 ms: give the first one time to come.
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(ask(), "online 1");
    let pid = nix::unistd::Pid::from_raw(i32::try_from(ussd.child.id()).unwrap());
    kill(pid, Signal::SIGSTOP).unwrap();
    // Beyond the drive's freshness limit (100 ms here), within ussd's heartbeat limit (500 ms).
    std::thread::sleep(std::time::Duration::from_millis(250));
    let stale = ask();
    // Beyond both.
    std::thread::sleep(std::time::Duration::from_millis(450));
    let paused = ask();
    kill(pid, Signal::SIGCONT).unwrap();
    assert_eq!(stale, "online 0", "{}", ussd.log());
    // Either answer is true: ussd's late heartbeat says it is gone, or the diagnostics say
    // the drive is not online; "online 1" would be a healthy picture that is not true.
    assert!(
        ["online 0", "err ussd_gone"].contains(&paused.as_str()),
        "{paused}: {}",
        ussd.log()
    );
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(ask(), "online 1");
    drop(stdin);
    assert!(program.wait().unwrap().success());
}

#[test]
fn the_c_and_cpp_examples_run_a_drive_as_the_readme_shows() {
    let c = compile("cc", "capi/examples/run_drive.c", &["-std=c11"]);
    let cpp = compile("c++", "capi/examples/run_drive.cpp", &["-std=c++17"]);
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    // Quick ramps: 50 Hz in 1 s up and down.
    for p in ["P1120", "P1121"] {
        let p = p.parse().unwrap();
        bus.write_param(addr(1), p, "1", uss_client::WriteOptions::default())
            .unwrap();
    }
    let out = run(&c, &[&ussd.bus, "1", "10", "1"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        text(&out.stdout),
        format!(
            "{} drive 1: S2, latched, 0.00 Hz of 50.00 Hz\nP1082 = 50.00 Hz\n\
             drive 1: re-armed; running towards 10.0 Hz\ndrive 1: S4 at 10.00 Hz\n\
             drive 1: stopped (OFF1, S2) and released\n",
            ussd.bus
        )
    );
    // The C program's release is ussd's latch from when ussd took it: the C++ program starts
    // after it (its re-arm, asked at its start, clears only a latch older than that), and
    // after the next clock tick, since the kernel's start time of a process is rounded down to
    // its tick (10 ms, `process_start_ns`).
    bus.watch(addr(1))
        .unwrap()
        .wait_for(std::time::Duration::from_secs(5), "released", |i| {
            i.latch_reason == uss_client::LatchReason::Released.code()
        })
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(30));
    let out = run(&cpp, &[&ussd.bus, "1", "10", "1"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        text(&out.stdout),
        "P1082 = 50.00 Hz\ndrive 1: re-armed; running towards 10.0 Hz\n\
         drive 1: S4 at 10.00 Hz\ndrive 1: stopped (OFF1, S2) and released\n"
    );
    // A bus nobody serves: the library's message, exit 1.
    let out = run(&cpp, &["nobody-here", "1", "10", "1"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("ussd is not running on nobody-here"),
        "{}",
        text(&out.stderr)
    );
}
