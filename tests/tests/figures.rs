//! The figures that describe the bus are true (issue 21): an efficiency is the wire-time floor
//! over the time the exchanges took, at most 1 by definition. Real processes: `uss-sim` over a
//! pty, stalled with SIGSTOP and resumed (its backlog of replies then arrives at once, faster than
//! the baud rate could carry it), and `ussd`.
#![allow(clippy::unwrap_used)]
const STALLS: usize = 4;

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use std::time::Duration;
use uss_integration_tests::{SimProcess, Ussd};

#[test]
fn efficiency_stays_at_most_one_when_the_simulator_stalls_and_resumes() {
    let sim = SimProcess::start(&["--baud", "19200", "--drive", "1", "--drive", "2"]);
    let ussd = Ussd::start_on(&sim.path, "baud = 19200", &[(1, ""), (2, "")]);
    let bus = ussd.bus();
    let pid = Pid::from_raw(i32::try_from(sim.child.id()).unwrap());
    for _ in 0..STALLS {
        kill(pid, Signal::SIGSTOP).unwrap();
        std::thread::sleep(Duration::from_millis(300));
        kill(pid, Signal::SIGCONT).unwrap();
        std::thread::sleep(Duration::from_millis(300));
    }
    // Published every 100 ms.
    std::thread::sleep(Duration::from_millis(300));
    let status = bus.status().unwrap();
    let e = status.efficiency();
    println!("efficiency after four stalls of the simulator: {e:?}");
    assert!(e.is_none_or(|e| e <= 1.0), "efficiency {e:?}");
    let mut st = ussd.ussctl(&["status"]);
    let (_, out, _) = st.finish();
    let shown = out
        .split("efficiency ")
        .nth(1)
        .and_then(|t| t.split([',', '\n']).next())
        .map(|t| t.parse::<f64>().unwrap());
    assert!(shown.is_none_or(|e| e <= 1.0), "{out}");
}
