//! Building an engine: the circulating list (USS.md section 5), each drive's gate latched by
//! ussd's start, the statistics before the first poll, and everything the engine and its
//! handle share.

use super::{
    Arc, AtomicBool, AtomicU32, AtomicU64, Bridge, BusStatus, BusTiming, CANCEL_QUEUE, Clock,
    Continuity, Drive, DriveCells, DriveSetup, Duration, Engine, EngineConfig, EngineHandle, Event,
    Exchange, FramerConfig, Gate, GateSetup, LOOK_STEP, LineStatus, LocalBridge,
    MAX_TELEGRAM_BYTES, Mutex, OWN_READS, Overrides, PeriodSetup, Periods, Published, Receiver,
    Shared, Stats, Transport, Turns, bounded, capture,
};

/// Builds the circulating list: each drive `weight` times, spread over the cycle (USS.md
/// section 5). Occurrence k of drive i of n sits at (k + i/n) / weight, so a drive polled twice per
/// cycle is polled every half cycle and drives of equal weight keep their configured order.
fn circulating_list(drives: &[DriveSetup]) -> Vec<u8> {
    let n = drives.len().max(1) as f64;
    let mut entries: Vec<(f64, usize)> = drives
        .iter()
        .enumerate()
        .flat_map(|(i, d)| {
            let w = f64::from(d.weight.max(1));
            (0..d.weight.max(1)).map(move |k| ((f64::from(k) + i as f64 / n) / w, i))
        })
        .collect();
    entries.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    entries.into_iter().map(|(_, i)| i as u8).collect()
}

/// Each drive's gate, latched by ussd's start at `now`.
fn gates(drives: &[DriveSetup], clock_origin: Duration, now: Duration) -> Vec<Gate> {
    drives
        .iter()
        .map(|d| {
            let setup = GateSetup {
                pzd: d.layout.pzd.get(),
                safe: d.safe,
                watchdog: d.watchdog,
                clock_origin,
            };
            Gate::new(setup, now)
        })
        .collect()
}

/// The statistics as published: a snapshot of the bus and of each drive's record, at `at`,
/// with everything recorded (allocates: the bus thread publishes with [`Published::hand_over`]).
pub(super) fn snapshot(
    at: Duration,
    bus: &BusStatus,
    line: LineStatus,
    drives: &[Drive],
    timing: &BusTiming,
) -> Stats {
    let (drive_histograms, update_period) = drives.iter().map(|d| d.timing.totals()).unzip();
    Stats {
        at,
        bus: *bus,
        line,
        drives: drives.iter().map(Drive::status).collect(),
        histograms: timing.totals(),
        drive_histograms,
        update_period,
    }
}

/// What the poll periods of `cfg`'s bus depend on. One attempt at worst: the request, the
/// drive's response timeout and the longest reply at its maximum residual time (USS.md
/// section 4), for the bus's largest telegrams.
pub(super) fn period_setup(cfg: &EngineConfig) -> PeriodSetup {
    let request = cfg
        .drives
        .iter()
        .map(|d| d.layout.request_net_bytes())
        .max()
        .unwrap_or(0);
    let reply = cfg
        .drives
        .iter()
        .map(|d| d.layout.max_reply_net_bytes())
        .max()
        .unwrap_or(0);
    let worst = cfg.timing.worst_case_transaction(request, reply);
    PeriodSetup {
        attempt: worst.saturating_sub(uss_protocol::MAX_RESPONSE_DELAY)
            + cfg.response_timeout
            + cfg.rx_latency,
        retries: cfg.retries,
        probe: cfg.offline_probe,
        param_priority: cfg.param_priority,
        fixed_cycle: cfg.cycle_time,
    }
}

impl<T: Transport, C: Clock> Engine<T, C> {
    /// Builds the engine with process images in this process only; returns it with its handle
    /// and the event receiver for the housekeeping thread.
    pub fn new(cfg: EngineConfig, transport: T, clock: C) -> (Self, EngineHandle, Receiver<Event>) {
        Engine::with_bridge(cfg, transport, clock, LocalBridge)
    }
}

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// Builds the engine and everything it will use, with `bridge` carrying the process images
    /// to other processes; returns it with its handle and the event receiver for the
    /// housekeeping thread.
    pub fn with_bridge(
        cfg: EngineConfig,
        transport: T,
        clock: C,
        bridge: B,
    ) -> (Self, EngineHandle, Receiver<Event>) {
        let mut slot_of = [None; 32];
        for (i, d) in cfg.drives.iter().enumerate() {
            slot_of[d.address.get() as usize] = Some(i as u8);
        }
        let capacity = (cfg.mailbox_depth * cfg.drives.len()).max(1);
        let now = clock.now();
        let gates = gates(&cfg.drives, clock.monotonic_origin(), now);
        let poll_list = circulating_list(&cfg.drives);
        let period_setup = period_setup(&cfg);
        let periods = Periods::new(&poll_list, cfg.drives.len(), period_setup);
        let drives: Vec<Drive> = cfg
            .drives
            .iter()
            .zip(gates)
            .enumerate()
            .map(|(slot, (&setup, gate))| {
                let shortest = periods.shortest_monitoring(slot);
                Drive::new(setup, gate, cfg.mailbox_depth + OWN_READS, shortest)
            })
            .collect();
        let timing = BusTiming::new();
        let stats = snapshot(
            now,
            &BusStatus::EMPTY,
            LineStatus::default(),
            &drives,
            &timing,
        );
        let shared = Arc::new(Shared {
            setups: cfg.drives.clone(),
            slot_of,
            drives: cfg.drives.iter().map(|_| DriveCells::default()).collect(),
            stop_all: Overrides::default(),
            stats: Mutex::new(Published::new(&stats)),
            published_ns: AtomicU64::new(0),
            stop: AtomicBool::new(false),
            line_down: AtomicBool::new(false),
            reopen_attempts: AtomicU32::new(0),
            progress: AtomicU64::new(0),
            mailbox_depth: cfg.mailbox_depth,
        });
        // Clients' jobs never exceed `capacity` (each drive's mailbox depth), so neither
        // channel can be full when the engine sends: no result is ever lost.
        let (jobs_tx, jobs_rx) = bounded(capacity);
        let (cancels_tx, cancels_rx) = bounded(CANCEL_QUEUE);
        let (results_tx, results_rx) = bounded(capacity);
        let (events_tx, events_rx) = bounded(1024);
        let (capture, captures) = capture::Capture::new(cfg.capture);
        let engine = Self {
            exchange: Exchange::new(FramerConfig::with_latency(cfg.timing, cfg.rx_latency), now),
            transport,
            clock,
            shared: Arc::clone(&shared),
            drives,
            poll_list,
            periods,
            turns: Turns::NONE,
            stop_all_seen: [0; 3],
            continuity: Continuity::new(now, period_setup.attempt + LOOK_STEP * 2),
            position: 0,
            extra_was_last: false,
            extra_cursor: 0,
            tx: [0; MAX_TELEGRAM_BYTES],
            last_reply_done: None,
            last_reply_seen: None,
            cycle_start: now,
            last_publish: now,
            control_changed: false,
            jobs: jobs_rx,
            cancels: cancels_rx,
            results: results_tx,
            events: events_tx,
            capture,
            bus: BusStatus::EMPTY,
            line: LineStatus::default(),
            timing,
            snapshot: std::cell::OnceCell::new(),
            cfg,
            bridge,
        };
        let handle = EngineHandle {
            shared,
            jobs: jobs_tx,
            cancels: cancels_tx,
            results: results_rx,
            captures,
        };
        (engine, handle, events_rx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_protocol::{Address, Layout, PkwMode, PzdCount};

    fn setup(address: u8, weight: u8) -> DriveSetup {
        DriveSetup {
            weight,
            ..DriveSetup::new(
                Address::new(address).unwrap(),
                Layout::new(PkwMode::Four, PzdCount::new(2).unwrap()),
            )
        }
    }

    #[test]
    fn circulating_list_spreads_weighted_drives() {
        assert_eq!(
            circulating_list(&[setup(1, 1), setup(2, 1), setup(3, 1)]),
            vec![0, 1, 2]
        );
        assert_eq!(
            circulating_list(&[setup(1, 2), setup(2, 1), setup(3, 1)]),
            vec![0, 1, 0, 2]
        );
        assert_eq!(
            circulating_list(&[setup(1, 1), setup(2, 3)]),
            vec![0, 1, 1, 1]
        );
        let list = circulating_list(&[setup(1, 4), setup(2, 4), setup(3, 1)]);
        assert_eq!(list.len(), 9);
        assert_eq!(list.iter().filter(|&&i| usize::from(i) == 2).count(), 1);
    }
}
