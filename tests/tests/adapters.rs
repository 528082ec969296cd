//! What real adapters do to timing, imitated on pseudo-terminals (issue 22): `uss-sim` hands
//! the drives' bytes to ussd the way a USB adapter does (each byte at its wire time, delivered
//! in packets every `--rx-tick` ms: FTDI's latency timer), with a 2-wire adapter's echo, and
//! ussd must judge the timing rules on the wire, not on delivery. Figures are printed.
//!
//! The imitation is a process of its own handing bytes through the pty layer: on a loaded
//! machine its packets come up to a few ms later than their tick, as a real adapter's come up
//! to a USB frame later than its latency timer. `rx_latency_ms` states that bound.
#![allow(clippy::unwrap_used)]

use std::fmt::Write;
use std::time::Duration;
use uss_integration_tests::addr;
use uss_integration_tests::{BusSpec, SimProcess, Ussd};

/// What a bus did over its measured seconds.
struct Figures {
    exchanges: u64,
    failed: u64,
}

impl Figures {
    /// Whether the rules held: no exchange failed but for the imitation's own rare late
    /// packets (a scheduling stall of uss-sim or the pty layer longer than the allowance's
    /// margin, a few ms, on a loaded 2-core machine): at most 1 in 200.
    fn held(&self) -> bool {
        self.failed * 200 <= self.exchanges
    }
}

/// Two drives at 187500 baud behind `sim_args`, ussd with `keys`; measured for `secs` after
/// ussd ran one second.
fn run(sim_args: &[&str], keys: &str, secs: u64) -> Figures {
    // One imitation at a time: each is a real-time process whose timing is the test.
    static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _turn = ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
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
    let mut why = String::new();
    for d in [1, 2] {
        let c = bus.diag(addr(d)).unwrap().counters;
        let _ = write!(
            why,
            " drive {d}: timeouts {} start pause {} missing STX {} residual {} echo {};",
            c.timeouts, c.start_pause, c.missing_stx, c.residual, c.echo
        );
    }
    println!(
        "adapters: {sim_args:?} {keys:?}: {} exchanges in {secs} s, {} failed;{why}",
        figures.exchanges, figures.failed
    );
    figures
}

/// [`run`], and once more when the figures miss `expected`: a virtual machine's host can stall
/// uss-sim or ussd for several ms (cyclictest on this project's 2-core VM, idle: wake-ups up to
/// 6 ms late), longer than the allowances these imitations are built on, and then exchanges
/// truly fail in the imitation itself. A ussd that judged timing on delivery fails every run
/// (the strict runs below show how much); a stall seldom hits two runs in a row.
fn run_expecting(
    sim_args: &[&str],
    keys: &str,
    secs: u64,
    expected: impl Fn(&Figures) -> bool,
) -> Figures {
    let first = run(sim_args, keys, secs);
    if expected(&first) {
        return first;
    }
    println!("adapters: measured once more (the first run's figures above)");
    run(sim_args, keys, secs)
}

#[test]
fn bytes_delivered_in_1_ms_packets_are_judged_on_the_wire() {
    let f = run_expecting(&["--rx-tick", "1"], "rx_latency_ms = 4", 3, Figures::held);
    assert!(f.held(), "{} failed exchanges of {}", f.failed, f.exchanges);
    assert!(f.exchanges > 600, "{} exchanges", f.exchanges);
    // The same packets judged on delivery with no latency allowed: most break.
    let strict = run(&["--rx-tick", "1"], "rx_latency_ms = 0.001", 3);
    assert!(
        strict.failed * 10 > strict.exchanges,
        "{} failed exchanges of {}",
        strict.failed,
        strict.exchanges
    );
}

#[test]
fn bytes_delivered_in_16_ms_packets_are_judged_on_the_wire() {
    let f = run_expecting(&["--rx-tick", "16"], "rx_latency_ms = 19", 3, Figures::held);
    assert!(f.held(), "{} failed exchanges of {}", f.failed, f.exchanges);
    assert!(f.exchanges > 100, "{} exchanges", f.exchanges);
}

#[test]
fn an_echo_delivered_with_the_reply_in_one_packet_is_understood() {
    let f = run_expecting(
        &["--rx-tick", "16", "--echo"],
        "echo = true\nrx_latency_ms = 19",
        3,
        Figures::held,
    );
    assert!(f.held(), "{} failed exchanges of {}", f.failed, f.exchanges);
    assert!(f.exchanges > 100, "{} exchanges", f.exchanges);
}

#[test]
fn a_reply_delivered_in_one_late_burst_within_the_latency_is_taken_on_its_first_attempt() {
    let f = run_expecting(
        &["--late-reply", "25"],
        "rx_latency_ms = 27",
        2,
        Figures::held,
    );
    assert!(f.held(), "{} failed exchanges of {}", f.failed, f.exchanges);
    assert!(f.exchanges > 40, "{} exchanges", f.exchanges);
}

#[test]
fn a_reply_later_than_the_latency_is_never_taken_for_the_retry_answer() {
    // Every reply comes 35 ms after it left the wire; ussd allows 10: each attempt times
    // out, and the retry waits the 10 ms out and flushes, so the late reply of one attempt is
    // never read as the answer to the next.
    let f = run_expecting(&["--late-reply", "35"], "rx_latency_ms = 10", 2, |f| {
        f.failed == f.exchanges
    });
    assert_eq!(f.failed, f.exchanges, "late replies taken as answers");
    assert!(f.exchanges > 10, "{} exchanges", f.exchanges);
}

#[test]
fn a_reply_handed_over_in_two_halves_within_the_latency_is_whole() {
    let f = run_expecting(
        &["--split-reply", "2"],
        "rx_latency_ms = 5",
        2,
        Figures::held,
    );
    assert!(f.held(), "{} failed exchanges of {}", f.failed, f.exchanges);
    assert!(f.exchanges > 100, "{} exchanges", f.exchanges);
    // Allowing no latency, the same replies break at the split (residual time). On a loaded
    // machine ussd may now and then read late enough to find both halves already there (one
    // of 21 on a CI run): nearly every one fails, not each.
    let strict = run(&["--split-reply", "2"], "rx_latency_ms = 0.001", 2);
    assert!(strict.exchanges >= 10, "{} exchanges", strict.exchanges);
    assert!(
        strict.failed * 10 >= strict.exchanges * 9,
        "split replies taken whole: {} of {} failed",
        strict.failed,
        strict.exchanges
    );
}

/// Found by issue 48's adversarial sweep: a line that sends back our own request (a 2-wire
/// adapter with `echo = true` missing, a TCP peer that echoes) must not make a drive that is
/// not there look online. Drive 5 is absent; its only "replies" are ussd's own requests.
#[test]
fn an_echo_of_our_own_request_is_no_reply_of_an_absent_drive() {
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1", "--echo"]);
    let drives: &[(u8, &str)] = &[(1, ""), (5, "")];
    let mut ussd = Ussd::launch(
        &[BusSpec {
            suffix: "",
            device: &sim.path,
            keys: "baud = 115200",
            drives,
        }],
        &[],
    );
    let bus = ussd.open_when_running("");
    std::thread::sleep(Duration::from_secs(2));
    let d = bus.diag(addr(5)).unwrap();
    assert_eq!(
        d.online, 0,
        "absent drive 5 shown online from echoes: {:?}",
        d.counters
    );
    // Counted as what it is, so the troubleshooting page's `echo = true` is found.
    assert!(
        d.counters.echo > 0 && d.counters.good == 0,
        "{:?}",
        d.counters
    );
    let _ = ussd.terminate();
}
