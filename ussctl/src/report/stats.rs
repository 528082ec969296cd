//! `status --stats` and `status --timing`: counters, timing and what ussd knows of each
//! drive.

use super::status::{BusLine, BusView, ControlView, last_failure};
use serde::Serialize;
use std::fmt::Write as _;
use uss_client::view::InfoView;
use uss_client::{BusStatus, DriveDiag};
use uss_shm_types::diag::NEVER;
use uss_shm_types::{DriveCounters, DriveInfo};

/// `stats`: the bus and every counter of every drive.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct StatsReport {
    pub bus: BusView,
    /// The bus's timing, µs: p50, p99, p99.9, max.
    pub timing: TimingReport,
    pub drives: Vec<DriveStats>,
}

/// Timing percentiles of a bus in µs: `[p50, p99, p99.9, max]`, zeros while none measured.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct TimingReport {
    /// Line free -> reply complete.
    pub exchange: [f64; 4],
    /// End of the request -> the reply's STX.
    pub response_delay: [f64; 4],
    /// Reply complete -> next request written.
    pub turnaround: [f64; 4],
}

/// Timing percentiles of a drive in µs: `[p50, p99, p99.9, max]`, zeros while none measured.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DriveTiming {
    pub exchange: [f64; 4],
    pub response_delay: [f64; 4],
}

impl TimingReport {
    pub fn of(s: &BusStatus) -> Self {
        let us = |ns: [u64; 4]| ns.map(|n| n as f64 / 1e3);
        Self {
            exchange: us(s.exchange_ns),
            response_delay: us(s.response_delay_ns),
            turnaround: us(s.turnaround_ns),
        }
    }

    pub fn human(&self) -> String {
        [
            timing_row("exchange", self.exchange),
            timing_row("response delay", self.response_delay),
            timing_row("turnaround", self.turnaround),
        ]
        .concat()
    }
}

/// One line of percentiles in µs: `  exchange        p50 ... us  p99 ... max ... us`.
pub(super) fn timing_row(name: &str, q: [f64; 4]) -> String {
    format!(
        "  {name:<15} p50 {:9.1} us  p99 {:9.1} us  p99.9 {:9.1} us  max {:9.1} us\n",
        q[0], q[1], q[2], q[3]
    )
}

#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DriveStats {
    pub address: u8,
    /// Answering, as ussd's fresh diagnostics say (false while they are stale).
    pub online: bool,
    /// The diagnostics are older than ussd's limit for them (a paused ussd, a stalled bus
    /// thread): the rest is the drive as it was, not as it is.
    pub stale: bool,
    pub no_reply: bool,
    pub control: ControlView,
    pub last_error: &'static str,
    pub consecutive_failed_polls: u32,
    /// ms since the last good reply when ussctl read it; null: never.
    pub last_good_ms_ago: Option<f64>,
    /// What ussd knows of the drive from its configuration.
    pub info: InfoReport,
    /// Every counter by name.
    pub counters: serde_json::Map<String, serde_json::Value>,
    /// This drive's exchange time and response delay, µs: p50, p99, p99.9, max.
    pub timing: DriveTiming,
    /// The same, in the contract's order, for people.
    #[serde(skip)]
    ordered: [(&'static str, u64); ORDERED],
}

/// The counters and the four values after them.
const ORDERED: usize = DriveCounters::COUNT + 4;

/// Every counter of a drive, in the order of the contract (USS.md section 7's list plus
/// timeouts, retries and parameter jobs).
pub(super) fn counters(d: &DriveDiag) -> [(&'static str, u64); ORDERED] {
    let mut all = [("", 0); ORDERED];
    all[..DriveCounters::COUNT].copy_from_slice(&d.counters.named());
    all[DriveCounters::COUNT..].copy_from_slice(&[
        ("since_ns", d.since_ns),
        ("last_good_ns", d.last_good_ns),
        ("last_zsw1", u64::from(d.last_zsw1)),
        ("last_hiw", u64::from(d.last_hiw)),
    ]);
    all
}

/// What ussd knows of a drive from its configuration and the drive itself: the one view
/// ([`InfoView`]), and `pkw`, the name v1 of the interface gave `pkw_words` (the same number).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct InfoReport {
    #[serde(flatten)]
    pub view: InfoView,
    /// P2013: 0, 3, 4, or 127 (variable); `pkw_words` under its name of v1.
    pub pkw: u8,
}

impl InfoReport {
    pub fn of(i: &DriveInfo) -> Self {
        let view = InfoView::of(i);
        Self {
            pkw: view.pkw_words,
            view,
        }
    }

    pub fn human(&self) -> String {
        self.view.human()
    }
}

impl DriveStats {
    /// The figures of `d` as read at `now_ns` (`CLOCK_MONOTONIC`).
    pub fn new(d: &DriveDiag, now_ns: u64) -> Self {
        Self {
            address: d.address,
            online: d.is_online_at(now_ns),
            stale: d.is_overdue(now_ns),
            no_reply: d.no_reply != 0,
            control: ControlView::of_diag(d),
            last_error: last_failure(d),
            consecutive_failed_polls: d.consecutive_failed_polls,
            last_good_ms_ago: (d.last_good_ns != NEVER)
                .then(|| now_ns.saturating_sub(d.last_good_ns) as f64 / 1e6),
            info: InfoReport::of(&d.info),
            counters: counters(d)
                .iter()
                .map(|&(k, v)| (k.to_owned(), v.into()))
                .collect(),
            timing: DriveTiming {
                exchange: d.exchange_ns.map(|n| n as f64 / 1e3),
                response_delay: d.response_delay_ns.map(|n| n as f64 / 1e3),
            },
            ordered: counters(d),
        }
    }
}

impl StatsReport {
    pub fn human(&self) -> String {
        let b = &self.bus;
        let mut out = b.human();
        let _ = writeln!(
            out,
            "\n  cycle overruns {}, parameter jobs accepted {} finished {}, events dropped {}, results lost {}",
            b.cycle_overruns, b.jobs_accepted, b.jobs_finished, b.events_dropped, b.results_lost
        );
        out.push_str(&self.timing.human());
        for d in &self.drives {
            let _ = write!(
                out,
                "drive {}: {}, last error {}",
                d.address,
                match (d.stale, d.online) {
                    (true, _) => "STALE (diagnostics older than their limit)",
                    (false, true) => "online",
                    (false, false) => "offline",
                },
                d.last_error
            );
            if let Some(ms) = d.last_good_ms_ago {
                let _ = write!(out, ", last good reply {ms:.1} ms ago");
            }
            let _ = write!(out, ", {}", d.control.human());
            out.push('\n');
            let _ = writeln!(out, "  {}", d.info.human());
            out.push_str(&timing_row("exchange", d.timing.exchange));
            out.push_str(&timing_row("response delay", d.timing.response_delay));
            let line: Vec<String> = d
                .ordered
                .iter()
                .filter(|(k, _)| !k.ends_with("_ns") && !k.starts_with("last_"))
                .map(|(k, v)| format!("{k} {v}"))
                .collect();
            for chunk in line.chunks(8) {
                let _ = writeln!(out, "  {}", chunk.join("  "));
            }
        }
        out
    }
}
