//! The compact live summary `ussd` logs every few seconds: per bus the cycle time, exchanges per
//! second, efficiency against the wire-time floor (USS.md section 4) and errors; per drive its
//! state, online flag, last ZSW1 and actual value, and telegram counters.

use crate::config::BusConfig;
use core::fmt::Write;
use core::time::Duration;
use uss_engine::control::Control;
use uss_engine::stats::{DriveCounters, DriveStatus, Stats};
use uss_protocol::{DriveState, Setpoint, Zsw1};

fn errors(c: &DriveCounters) -> u64 {
    c.rejected
}

/// Renders the summary for `stats`, with rates over the interval since `previous`.
pub fn render(bus: &BusConfig, rt_mode: &str, stats: &Stats, previous: Option<&Stats>) -> String {
    let mut out = String::new();
    let h = &stats.histograms;
    let interval = previous.map_or(stats.at, |p| stats.at.saturating_sub(p.at));
    let secs = interval.as_secs_f64().max(1e-9);
    let exchanges = stats.bus.exchanges - previous.map_or(0, |p| p.bus.exchanges);
    let mean_exchange = Duration::from_nanos(h.exchange.mean() as u64);
    // Said only where the wire timed the exchanges: a pty carries replies faster than its baud
    // rate, where a figure would be no measurement.
    let efficiency = stats.bus.efficiency().map_or_else(String::new, |e| {
        format!(", efficiency {e:.3} of wire floor")
    });
    let total_errors: u64 = stats.drives.iter().map(|d| errors(&d.counters)).sum();
    let online = stats.drives.iter().filter(|d| d.online).count();
    let _ = writeln!(
        out,
        "bus {}: {} baud, {rt_mode}; cycle {:.2} ms, {:.0} exchanges/s{efficiency} \
         (mean exchange {:.3} ms, response delay {:.3} ms), {online}/{} drives online, {total_errors} errors, {} jobs done",
        bus.name,
        bus.baud,
        h.cycle.mean() / 1e6,
        exchanges as f64 / secs,
        mean_exchange.as_secs_f64() * 1e3,
        h.response_delay.mean() / 1e6,
        stats.drives.len(),
        stats.bus.jobs_finished,
    );
    for (d, entry) in stats.drives.iter().zip(&bus.drives) {
        let c = &d.counters;
        let z = Zsw1::from_bits_retain(d.last_zsw1);
        // While the reference is being read again no Hz are known: NaN, printed as such.
        let hz = d
            .reference
            .scale(entry.reference_hz.get())
            .map_or(f32::NAN, |r| Setpoint::from_word(d.last_hiw).hz(r));
        let prev = previous
            .and_then(|p| p.drive(d.address))
            .map(|p| p.counters);
        let per_min =
            |now: u64, before: Option<u64>| (now - before.unwrap_or(0)) as f64 * 60.0 / secs;
        let _ = writeln!(
            out,
            "  drive {:2}: {:7} {:9} ZSW1 0x{:04X} {:7.2} Hz | sent {} good {} ({:.0}/min) rejected {} ({:.0}/min): \
             timeouts {} retries {} bcc {} length {} stx {} residual {} wrong-addr {} parity {} | last error {}{}",
            d.address,
            if d.online {
                "online".to_owned()
            } else {
                format!("OFFLINE since {:.1} s", d.since.as_secs_f64())
            },
            DriveState::from_zsw1(z).short_name(),
            d.last_zsw1,
            hz,
            c.requests,
            c.good,
            per_min(c.good, prev.map(|p| p.good)),
            c.rejected,
            per_min(c.rejected, prev.map(|p| p.rejected)),
            c.timeouts,
            c.retries,
            c.bcc,
            c.length + c.bad_lge,
            c.missing_stx + c.start_pause,
            c.residual,
            c.wrong_address,
            c.parity,
            match d.last_failure {
                uss_engine::stats::LastFailure::None => "-",
                f => f.name(),
            },
            control_note(d),
        );
    }
    out
}

/// ` | live`, or what a latched drive gets and why; and a telegram monitoring that is not on.
fn control_note(d: &DriveStatus) -> String {
    let mut note = match d.control {
        Control::Live => " | live".to_owned(),
        Control::Latched(l) => format!(" | LATCHED ({}): {}", l.reason, l.command),
    };
    if !matches!(
        d.monitoring,
        uss_shm_types::Monitoring::On | uss_shm_types::Monitoring::Unknown
    ) {
        let _ = write!(note, " | telegram monitoring {}", d.monitoring);
    }
    note
}
