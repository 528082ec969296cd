//! What an adapter's receive latency costs (issue 22), on pseudo-terminals with the
//! simulator's packet delivery (`uss-sim --rx-tick MS`: each byte at its wire time, handed over
//! every MS, as an FTDI latency timer does): two drives (PKW 4, PZD 2) at 9600, 19200 and
//! 187500 baud: each byte handed over at its wire time ("wire", a UART without FIFO, the
//! reference), and in 1 ms and 16 ms packets, "before" (timed as a UART, the timing rules
//! judged on delivery with no latency allowed, as before issue 22: `rx_latency_ms = 0.001`,
//! which makes a pty count as an adapter) and "after" (`rx_latency_ms` = the tick and a USB frame,
//! what ussd reads from sysfs for an FTDI adapter); 16 ms packets with a 2-wire echo. Prints,
//! per case, good exchanges per second, failed exchanges, the line's efficiency (the share of
//! time it carries telegrams) and the throughput as a ratio to the reference's at the same
//! rate, all in one run.
//!
//! `cargo bench -p uss-benches --bench adapters`

use std::time::Duration;
use uss_benches::{open_bus, start_sim, start_ussd};
use uss_protocol::{Baud, Timing};

/// Characters on the wire per exchange: request and reply of PKW 4, PZD 2 (16 each).
const CHARS_PER_EXCHANGE: u64 = 32;
/// How long each case is measured (a short run: a tenth of it).
fn measured() -> Duration {
    Duration::from_millis(uss_benches::rounds(4000, 400))
}

struct Case {
    per_s: f64,
    failed: u64,
    exchanges: u64,
    efficiency: f64,
}

/// `tick_ms`: `uss-sim --rx-tick` (0: each byte at its wire time, no packets).
fn measure(baud: u32, tick_ms: u32, rx_latency_ms: f64, echo: bool) -> Case {
    let baud_text = baud.to_string();
    let tick = tick_ms.to_string();
    let mut args = vec!["--baud", &baud_text, "--drive", "1", "--drive", "2"];
    args.extend(["--rx-tick", &tick]);
    if echo {
        args.push("--echo");
    }
    let (_sim, pty) = start_sim(&args);
    let name = format!(
        "adapters{}b{baud}t{tick_ms}l{}e{}",
        std::process::id(),
        (rx_latency_ms * 10.0) as u32,
        u8::from(echo)
    );
    let _ussd = start_ussd(
        &name,
        &format!(
            "[[bus]]\nname = \"{name}\"\ndevice = \"{pty}\"\nbaud = {baud}\necho = {echo}\n\
             rx_latency_ms = {rx_latency_ms}\n\n[[bus.drive]]\naddress = 1\n\n\
             [[bus.drive]]\naddress = 2\n"
        ),
    );
    let bus = open_bus(&name);
    std::thread::sleep(Duration::from_millis(uss_benches::rounds(1000, 300)));
    let before = bus.status().expect("status");
    std::thread::sleep(measured());
    let after = bus.status().expect("status");
    let exchanges = after.exchanges - before.exchanges;
    let good = after.good - before.good;
    let timing = Timing::new(Baud::new(baud).expect("baud"));
    let busy = timing.chars(CHARS_PER_EXCHANGE).as_secs_f64() * good as f64;
    Case {
        per_s: good as f64 / measured().as_secs_f64(),
        failed: exchanges - good,
        exchanges,
        efficiency: busy / measured().as_secs_f64(),
    }
}

fn main() {
    println!(
        "== adapters: 2 drives on a pty, {:.1} s each; efficiency = share of the line's time carrying telegrams",
        measured().as_secs_f64()
    );
    println!(
        "{:>7} {:>9} {:>8} | {:>10} {:>14} {:>6} {:>9}",
        "baud", "delivery", "ussd", "good/s", "failed", "eff.", "vs wire"
    );
    for baud in [9600, 19_200, 187_500] {
        // The reference: every byte at its wire time, as a UART without FIFO; 0.1 ms for the
        // imitation's own wake-ups.
        let pty = measure(baud, 0, 0.1, false);
        let show = |delivery: &str, ussd: &str, c: &Case| {
            println!(
                "{baud:>7} {delivery:>9} {ussd:>8} | {:>10.1} {:>6} of {:>5} {:>5.1}% {:>8.2}x",
                c.per_s,
                c.failed,
                c.exchanges,
                c.efficiency * 100.0,
                c.per_s / pty.per_s
            );
        };
        show("wire", "-", &pty);
        for tick in [1, 16] {
            // Timed as a UART (sending takes wire time) with no latency allowed: as before.
            let before = measure(baud, tick, 0.001, false);
            show(&format!("{tick} ms"), "before", &before);
            let after = measure(baud, tick, f64::from(tick + 1), false);
            show(&format!("{tick} ms"), "after", &after);
        }
        // No "before": the echo rule is not a setting (before it, every exchange failed).
        let echo_after = measure(baud, 16, 17.0, true);
        show("16+echo", "after", &echo_after);
    }
}
