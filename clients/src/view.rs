//! One serializable view of what ussd publishes (feature `view`): the bus status as every
//! front-end that speaks JSON or a dynamic language shows it (`ussctl status --json`, Python's
//! `Bus.status()`), with codes turned into words and nanoseconds into microseconds, built in one
//! place from the contract's `#[repr(C)]` [`BusStatus`].

use serde::Serialize;
use uss_shm_types::BusStatus;
use uss_shm_types::diag::RtMode;

/// The bus as a whole.
#[derive(Debug, Clone, PartialEq, Serialize, schemars::JsonSchema)]
pub struct BusView {
    pub bus: String,
    pub running: bool,
    /// `realtime` or `best effort` (`unknown`: a code this client does not know).
    pub rt_mode: &'static str,
    /// -1: not pinned.
    pub rt_cpu: i32,
    pub rt_priority: u8,
    pub drive_count: u8,
    pub cycles: u64,
    pub exchanges: u64,
    pub good: u64,
    pub cycle_overruns: u64,
    pub events_dropped: u64,
    pub results_lost: u64,
    pub jobs_accepted: u64,
    pub jobs_finished: u64,
    /// Parameter jobs of clients that died, taken out before they reached the wire.
    pub jobs_cancelled: u64,
    pub mean_exchange_us: f64,
    /// Wire-time floor over achieved exchange time; null until measured.
    pub efficiency: Option<f64>,
    /// "up" or "down".
    pub line: &'static str,
    /// Why the line is down; null while up.
    pub line_error: Option<String>,
    /// Attempts to reopen a line that is down.
    pub reopen_attempts: u32,
    /// Times the line went down since ussd started.
    pub line_downs: u64,
    /// Polls out of turn: a stop, a trip or a re-arm sent before the circulating list went on.
    pub out_of_turn: u64,
    /// Broadcast telegrams: stops of every drive.
    pub broadcasts: u64,
}

impl BusView {
    /// The view of bus `bus`'s status `s`.
    pub fn new(bus: &str, s: &BusStatus) -> Self {
        Self {
            bus: bus.to_owned(),
            running: s.running != 0,
            rt_mode: RtMode::try_from(s.rt_mode).map_or("unknown", RtMode::name),
            rt_cpu: s.rt_cpu,
            rt_priority: s.rt_priority,
            drive_count: s.drive_count,
            cycles: s.cycles,
            exchanges: s.exchanges,
            good: s.good,
            cycle_overruns: s.cycle_overruns,
            events_dropped: s.events_dropped,
            results_lost: s.results_lost,
            jobs_accepted: s.jobs_accepted,
            jobs_finished: s.jobs_finished,
            jobs_cancelled: s.jobs_cancelled,
            mean_exchange_us: s.mean_exchange_ns as f64 / 1e3,
            efficiency: s.efficiency(),
            line: if s.is_line_down() { "down" } else { "up" },
            line_error: s.line_fault_text(),
            reopen_attempts: s.reopen_attempts,
            line_downs: s.line_downs,
            out_of_turn: s.out_of_turn,
            broadcasts: s.broadcasts,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_shm_types::diag::{LineFault, LineState};

    #[test]
    fn codes_become_words_and_a_down_line_says_why() {
        let mut s = BusStatus {
            running: 1,
            rt_mode: RtMode::Realtime.code(),
            mean_exchange_ns: 2_500,
            ..BusStatus::EMPTY
        };
        let v = BusView::new("b0", &s);
        assert_eq!((v.running, v.rt_mode, v.line), (true, "realtime", "up"));
        assert_eq!((v.mean_exchange_us, v.line_error), (2.5, None));
        (s.line_state, s.line_fault) = (LineState::Down.code(), LineFault::Stalled.code());
        s.rt_mode = 9;
        let v = BusView::new("b0", &s);
        assert_eq!((v.line, v.rt_mode), ("down", "unknown"));
        assert!(v.line_error.unwrap().contains("stalled"));
    }
}
