//! What real adapters do to timing, imitated on pseudo-terminals (issue 22): `uss-sim` hands
//! the drives' bytes to ussd the way a USB adapter does (each byte at its wire time, delivered
//! in packets every `--rx-tick` ms: FTDI's latency timer), with a 2-wire adapter's echo, and
//! ussd must judge the timing rules on the wire, not on delivery. Figures are printed.
//!
//! The imitation is a process of its own handing bytes through the pty layer: on a loaded
//! machine its packets come up to a few ms later than their tick, as a real adapter's come up
//! to a USB frame later than its latency timer. `rx_latency_ms` states that bound.
#![allow(clippy::unwrap_used)]

use std::time::Duration;
use uss_integration_tests::{BusSpec, SimProcess, Ussd};

/// What a bus did over its measured seconds.
struct Figures {
    exchanges: u64,
    failed: u64,
}

/// Two drives at 187500 baud behind `sim_args`, ussd with `keys`; measured for `secs` after
/// ussd ran one second.
fn run(sim_args: &[&str], keys: &str, secs: u64) -> Figures {
    let mut args = vec!["--baud", "187500", "--drive", "1", "--drive", "2"];
    args.extend_from_slice(sim_args);
    let sim = SimProcess::start(&args);
    let mut ussd = Ussd::launch(
        &[BusSpec {
            suffix: "",
            device: &sim.path,
            keys: &format!("baud = 187500\n{keys}"),
            drives: &[(1, ""), (2, "")],
        }],
        &[],
    );
    let bus = ussd.open_when_running("");
    std::thread::sleep(Duration::from_secs(1));
    let before = bus.status().unwrap();
    std::thread::sleep(Duration::from_secs(secs));
    let after = bus.status().unwrap();
    let exchanges = after.exchanges - before.exchanges;
    let figures = Figures {
        exchanges,
        failed: exchanges - (after.good - before.good),
    };
    println!(
        "adapters: {sim_args:?} {keys:?}: {} exchanges in {secs} s, {} failed",
        figures.exchanges, figures.failed
    );
    figures
}

#[test]
#[should_panic(expected = "failed exchanges")]
fn bytes_delivered_in_1_ms_packets_are_judged_on_the_wire() {
    let f = run(&["--rx-tick", "1"], "", 3);
    assert_eq!(f.failed, 0, "failed exchanges of {}", f.exchanges);
    assert!(f.exchanges > 600, "{} exchanges", f.exchanges);
}

#[test]
#[should_panic(expected = "failed exchanges")]
fn an_echo_delivered_with_the_reply_in_one_packet_is_understood() {
    let f = run(&["--rx-tick", "16", "--echo"], "echo = true", 3);
    assert_eq!(f.failed, 0, "failed exchanges of {}", f.exchanges);
    assert!(f.exchanges > 100, "{} exchanges", f.exchanges);
}
