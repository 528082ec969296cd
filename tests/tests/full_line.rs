//! A full line at the drives' factory baud rate (issue 21): 31 simulated drives at 9600 baud,
//! where ussd polls each drive only every 1.3 s. Real processes: ussd, `ussctl`.
//!
//! Reproduction first: `ussctl run` cannot control drive 20 of such a line: its ON waits a fixed
//! second for the re-arm, which the drive's next poll (1.3 s away) brings too late ("drive 20 on
//! B is latched (ussd started ...): send OFF1 first").
#![allow(clippy::unwrap_used)]

use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use uss_client::LatchReason;
use uss_integration_tests::{ChildProc, Ussd};

/// One ussd at a time: each runs a `SCHED_FIFO` bus thread, and the machine has two cores.
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Drives 1..=31 at 9600 baud (MICROMASTER 4's factory setting, P2010 = 6), default keys.
fn full_line() -> Ussd {
    let drives: Vec<(u8, &str)> = (1..=31).map(|a| (a, "")).collect();
    Ussd::start("baud = 9600", &drives)
}

/// Waits for a process to end: its exit code, stdout and stderr.
fn ended(p: &mut ChildProc, within: Duration) -> (Option<i32>, String, String) {
    let deadline = Instant::now() + within;
    while p.child.try_wait().unwrap().is_none() {
        assert!(Instant::now() < deadline, "still runs: {}", p.stderr());
        std::thread::sleep(Duration::from_millis(20));
    }
    let (status, out, err) = p.finish();
    (status.code(), out, err)
}

#[test]
#[should_panic(expected = "drive 20 on")]
fn thirty_one_drives_at_9600_baud_are_controllable() {
    let _one = serial();
    let ussd = full_line();
    let bus = ussd.bus();
    let mut run = ussd.ussctl(&["run", "20", "--hz", "10", "--for", "3"]);
    let (code, out, err) = ended(&mut run, Duration::from_secs(60));
    assert_eq!(code, Some(0), "{out}{err}");
    let d = bus.diag(20).unwrap();
    assert_eq!(
        (d.latch_reason, d.counters.watchdog_trips),
        (LatchReason::Released.code(), 0),
        "{out}{err}"
    );
}
