//! Diagnostics per drive and per bus, mirroring what the drives keep themselves (r2024..r2031,
//! USS.md section 7), plus timing histograms. Everything is allocated when the engine starts;
//! counting and recording never allocate.

use crate::control::{Control, ControlCounters};
use crate::reference::Reference;
use crate::transport::TransportError;
use core::time::Duration;
use hdrhistogram::Histogram;
use uss_protocol::Address;
use uss_shm_types::{BusStatus, Monitoring, Rejection};
pub use uss_shm_types::{DriveCounters, LastFailure};

/// Why a bus line stopped carrying telegrams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineFailure {
    /// The device was closed or unplugged (EOF, EIO, ENXIO, ENODEV; a pty whose far side is gone).
    Closed,
    /// Another I/O error, with its errno (0 if none was given).
    Io(i32),
    /// No byte could be written for the write-stall allowance.
    Stalled,
}

impl LineFailure {
    pub fn of(e: &TransportError) -> Self {
        match e {
            TransportError::Closed => Self::Closed,
            TransportError::Io(io) => Self::Io(io.raw_os_error().unwrap_or(0)),
            TransportError::Stalled => Self::Stalled,
        }
    }
}

impl core::fmt::Display for LineFailure {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Closed => f.write_str(
                "the line was closed: a serial device unplugged, or its server's connection ended",
            ),
            Self::Io(errno) => write!(
                f,
                "the line's I/O failed: {}",
                std::io::Error::from_raw_os_error(*errno)
            ),
            Self::Stalled => f.write_str(
                "the line's output stalled: no byte could be written for its write-stall allowance",
            ),
        }
    }
}

/// The bus line: up, or down since when and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LineStatus {
    /// `Some` while the line is down: since (bus clock) and why.
    pub down: Option<(Duration, LineFailure)>,
    /// Times the line went down since the engine started.
    pub downs: u64,
}

/// Copies the control counters of a drive's gate into its counters.
pub fn set_control(counters: &mut DriveCounters, c: &ControlCounters) {
    counters.watchdog_trips = c.watchdog_trips;
    counters.latches = c.latches;
    counters.rejected_outputs = c.rejected_outputs;
    counters.releases = c.releases;
    counters.overrides = c.overrides;
    counters.replacements = c.replacements;
}

/// The state of one drive as the master sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveStatus {
    pub address: Address,
    /// The drive answers; false while unknown (see `known`) too.
    pub online: bool,
    /// The first poll (with its retries) decided `online`: until then the drive is unknown.
    pub known: bool,
    /// When `online` last changed (bus clock).
    pub since: Duration,
    /// "Slave x does not respond": set when a poll fails all retries, cleared by the next good
    /// reply (USS.md section 4).
    pub no_reply: bool,
    /// Why the last failed attempt failed ([`LastFailure::None`] before the first).
    pub last_failure: LastFailure,
    pub consecutive_failed_polls: u32,
    pub last_zsw1: u16,
    pub last_hiw: u16,
    pub last_good: Option<Duration>,
    /// Live (the controller's words go out) or latched, and why (`crate::control`).
    pub control: Control,
    /// The last refused sample's rejection.
    pub rejection: Rejection,
    /// The process id in the controller's latest sample (0 before the first).
    pub controller_pid: u32,
    /// STW1 and setpoint of the last telegram sent to the drive.
    pub sent: [u16; 2],
    /// `sequence` of the controller's latest sample the engine took.
    pub taken_sequence: u64,
    /// The drive's own telegram monitoring as read from it, and its time in ms.
    pub monitoring: Monitoring,
    pub monitoring_ms: u32,
    /// The drive's reference frequency as read from it.
    pub reference: Reference,
    /// The count of changes of what ussd knows of the drive (`crate::drive`'s `picture`).
    pub picture: u8,
    /// How often the drive is polled now, and after how long its image is stale
    /// (`crate::period`); set before each [`crate::Bridge::after_poll`].
    pub period: Duration,
    pub stale_after: Duration,
    /// The shortest telegram-off time that does not trip the drive between two of its polls
    /// (`crate::period::Periods::shortest_monitoring`).
    pub monitoring_min: Duration,
    pub counters: DriveCounters,
}

impl DriveStatus {
    pub fn new(address: Address, control: Control) -> Self {
        Self {
            address,
            // Unknown until the first poll decides.
            online: false,
            known: false,
            since: Duration::ZERO,
            no_reply: false,
            last_failure: LastFailure::None,
            consecutive_failed_polls: 0,
            last_zsw1: 0,
            last_hiw: 0,
            last_good: None,
            control,
            rejection: Rejection::None,
            controller_pid: 0,
            sent: [0; 2],
            taken_sequence: 0,
            monitoring: Monitoring::Unknown,
            monitoring_ms: 0,
            reference: Reference::Unknown,
            picture: 0,
            period: Duration::ZERO,
            stale_after: Duration::ZERO,
            monitoring_min: Duration::ZERO,
            counters: DriveCounters::default(),
        }
    }
}

/// Timing histograms in nanoseconds, to two significant figures (1 %, about 4000 counters
/// each). The bus thread never copies them to publish them: it records into a [`FreshTiming`] as
/// well and hands that over whole ([`Published`]). Exact sums for efficiency live in
/// [`Stats::bus`].
#[derive(Debug, Clone)]
pub struct BusHistograms {
    /// End of our request to the start of the reply's STX (the slave's response delay).
    pub response_delay: Histogram<u64>,
    /// Line free after the previous exchange to this reply complete: comparable to the wire floor.
    pub exchange: Histogram<u64>,
    /// Reply complete (its last byte's arrival) to the next request written: the start pause
    /// plus whatever the master adds (its wake-up latency and its work).
    pub turnaround: Histogram<u64>,
    /// The master's own work: from seeing a reply complete to being ready to send the next
    /// request (before the start-pause wait). Below the start pause it costs no wire time.
    pub work: Histogram<u64>,
    /// One pass through the circulating list.
    pub cycle: Histogram<u64>,
}

/// Highest value recorded: 60 s; larger values saturate.
const MAX_NS: u64 = 60_000_000_000;

fn histogram(sigfig: u8) -> Histogram<u64> {
    // Bounds and precision are constants within hdrhistogram's limits.
    Histogram::new_with_bounds(1, MAX_NS, sigfig).expect("valid histogram bounds")
}

/// Records a duration, saturating at the histogram's bounds; never allocates.
pub fn record(h: &mut Histogram<u64>, d: Duration) {
    h.saturating_record(u64::try_from(d.as_nanos()).unwrap_or(MAX_NS).max(1));
}

/// One timing histogram as the engine keeps it: all of it (for `Engine::stats`) and what was
/// recorded since the last hand-over to the published copy ([`Published`]). One
/// [`Recorded::record`] writes both.
#[derive(Debug, Clone)]
pub struct Recorded {
    pub total: Histogram<u64>,
    pub fresh: Histogram<u64>,
}

impl Recorded {
    fn new(sigfig: u8) -> Self {
        Self {
            total: histogram(sigfig),
            fresh: histogram(sigfig),
        }
    }

    /// Two significant figures, as the bus's histograms and the update periods.
    pub fn bus() -> Self {
        Self::new(2)
    }

    /// One significant figure plus, as a drive's exchange times and response delays.
    pub fn drive() -> Self {
        Self::new(1)
    }

    /// Records a duration, saturating at the histograms' bounds; never allocates.
    pub fn record(&mut self, d: Duration) {
        record(&mut self.total, d);
        record(&mut self.fresh, d);
    }

    /// Hands what was recorded since the last hand-over to `pending` (empty, same bounds) and
    /// keeps the empty one: an exchange of two histograms, no copy of counts.
    pub fn hand_over(&mut self, pending: &mut Histogram<u64>) {
        core::mem::swap(&mut self.fresh, pending);
    }
}

/// The bus's timing as the engine keeps it (see [`BusHistograms`] for what each is).
#[derive(Debug, Clone)]
pub struct BusTiming {
    pub response_delay: Recorded,
    pub exchange: Recorded,
    pub turnaround: Recorded,
    pub work: Recorded,
    pub cycle: Recorded,
}

impl BusTiming {
    pub fn new() -> Self {
        Self {
            response_delay: Recorded::bus(),
            exchange: Recorded::bus(),
            turnaround: Recorded::bus(),
            work: Recorded::bus(),
            cycle: Recorded::bus(),
        }
    }

    /// Everything recorded, as published.
    pub fn totals(&self) -> BusHistograms {
        BusHistograms {
            response_delay: self.response_delay.total.clone(),
            exchange: self.exchange.total.clone(),
            turnaround: self.turnaround.total.clone(),
            work: self.work.total.clone(),
            cycle: self.cycle.total.clone(),
        }
    }

    /// Hands what was recorded since the last hand-over to `pending`.
    pub fn hand_over(&mut self, pending: &mut BusHistograms) {
        self.response_delay.hand_over(&mut pending.response_delay);
        self.exchange.hand_over(&mut pending.exchange);
        self.turnaround.hand_over(&mut pending.turnaround);
        self.work.hand_over(&mut pending.work);
        self.cycle.hand_over(&mut pending.cycle);
    }
}

impl Default for BusTiming {
    fn default() -> Self {
        Self::new()
    }
}

impl BusHistograms {
    pub fn new() -> Self {
        Self {
            response_delay: histogram(2),
            exchange: histogram(2),
            turnaround: histogram(2),
            work: histogram(2),
            cycle: histogram(2),
        }
    }
}

impl Default for BusHistograms {
    fn default() -> Self {
        Self::new()
    }
}

/// Everything the engine knows about its bus, as published to other threads.
#[derive(Debug, Clone)]
pub struct Stats {
    /// Bus clock time of this snapshot.
    pub at: Duration,
    /// The bus's counters, in the contract's own type: the engine counts into the fields it
    /// owns (exchanges, jobs, cycles, timing sums, ...), the publisher adds the rest (its time,
    /// the line, the quantiles, the bus thread's real-time mode) and publishes it as it is.
    pub bus: BusStatus,
    pub line: LineStatus,
    pub drives: Vec<DriveStatus>,
    pub histograms: BusHistograms,
    /// Per drive (same order as `drives`): time between two good replies.
    pub update_period: Vec<Histogram<u64>>,
    /// Per drive: its exchange times and response delays (the bus's are in `histograms`), to
    /// one significant figure plus (6 %: about 500 counters each, cheap to publish).
    pub drive_histograms: Vec<DriveHistograms>,
}

/// One drive's timing.
#[derive(Debug, Clone)]
pub struct DriveHistograms {
    pub exchange: Histogram<u64>,
    pub response_delay: Histogram<u64>,
}

impl DriveHistograms {
    fn new() -> Self {
        Self {
            exchange: histogram(1),
            response_delay: histogram(1),
        }
    }
}

impl Stats {
    /// Statistics of drives that start with `control` (each with its address).
    pub fn new(drives: impl IntoIterator<Item = (Address, Control)>) -> Self {
        let drives: Vec<DriveStatus> = drives
            .into_iter()
            .map(|(a, c)| DriveStatus::new(a, c))
            .collect();
        let update_period = drives.iter().map(|_| histogram(2)).collect();
        let drive_histograms = drives.iter().map(|_| DriveHistograms::new()).collect();
        Self {
            at: Duration::ZERO,
            bus: BusStatus::EMPTY,
            line: LineStatus::default(),
            drives,
            histograms: BusHistograms::new(),
            update_period,
            drive_histograms,
        }
    }

    /// Copies everything of `other` but its timing histograms into `self` (both made by
    /// [`Stats::new`] for the same drives): plain data, no allocation, a few hundred bytes per
    /// drive.
    pub fn copy_counters_from(&mut self, other: &Self) {
        self.at = other.at;
        self.bus = other.bus;
        self.line = other.line;
        self.drives.copy_from_slice(&other.drives);
    }

    /// Adds the timing recorded in `t` to this snapshot's histograms (same bounds: adding never
    /// resizes).
    fn merge(&mut self, t: &FreshTiming) {
        let h = &mut self.histograms;
        for (dst, src) in [
            (&mut h.response_delay, &t.histograms.response_delay),
            (&mut h.exchange, &t.histograms.exchange),
            (&mut h.turnaround, &t.histograms.turnaround),
            (&mut h.work, &t.histograms.work),
            (&mut h.cycle, &t.histograms.cycle),
        ] {
            let _ = dst.add(src);
        }
        for (dst, src) in self.update_period.iter_mut().zip(&t.update_period) {
            let _ = dst.add(src);
        }
        for (dst, src) in self.drive_histograms.iter_mut().zip(&t.drive_histograms) {
            let _ = dst.exchange.add(&src.exchange);
            let _ = dst.response_delay.add(&src.response_delay);
        }
    }

    pub fn drive(&self, address: Address) -> Option<&DriveStatus> {
        self.drives.iter().find(|d| d.address == address)
    }
}

/// The timing the bus thread recorded since it last handed it over: the same histograms as
/// [`Stats`] has, each counting only what came since.
#[derive(Debug, Clone)]
pub struct FreshTiming {
    pub histograms: BusHistograms,
    pub update_period: Vec<Histogram<u64>>,
    pub drive_histograms: Vec<DriveHistograms>,
}

impl FreshTiming {
    /// Empty histograms for `drives` drives.
    pub fn new(drives: usize) -> Self {
        Self {
            histograms: BusHistograms::new(),
            update_period: (0..drives).map(|_| histogram(2)).collect(),
            drive_histograms: (0..drives).map(|_| DriveHistograms::new()).collect(),
        }
    }

    fn reset(&mut self) {
        let h = &mut self.histograms;
        for x in [
            &mut h.response_delay,
            &mut h.exchange,
            &mut h.turnaround,
            &mut h.work,
            &mut h.cycle,
        ] {
            x.reset();
        }
        self.update_period.iter_mut().for_each(Histogram::reset);
        for d in &mut self.drive_histograms {
            d.exchange.reset();
            d.response_delay.reset();
        }
    }
}

/// What the bus thread publishes, under a lock it only ever tries: the latest counters, and the
/// timing it handed over that no reader has taken into the histograms yet.
///
/// Publishing costs the bus thread a copy of the counters and an exchange of two [`FreshTiming`]s
/// (pointers, 0.1 us for 4 drives, 0.5 us for 31): never a copy of the histograms, which took it
/// 16 us for 4 drives and 73 us for 31, more on a busy machine (medians of
/// `cargo bench -p uss-benches --bench bus -- publish`). Merging is the reader's work.
#[derive(Debug)]
pub struct Published {
    /// The counters as last published; the histograms as of the last [`Published::read`].
    stats: Stats,
    /// Handed over, not merged yet (empty when `full` is false).
    pending: FreshTiming,
    full: bool,
}

impl Published {
    /// A snapshot of `stats` (its histograms included), with nothing handed over yet.
    pub fn new(stats: &Stats) -> Self {
        Self {
            stats: stats.clone(),
            pending: FreshTiming::new(stats.drives.len()),
            full: false,
        }
    }

    /// The bus thread's side: the snapshot to write the latest counters into (plain data),
    /// and, unless the last hand-over was not merged yet, the empty [`FreshTiming`] to exchange
    /// what was recorded since for (otherwise the engine keeps recording and hands it over next
    /// time). Never allocates.
    pub fn hand_over(&mut self) -> (&mut Stats, Option<&mut FreshTiming>) {
        let timing = (!self.full).then_some(&mut self.pending);
        self.full = true;
        (&mut self.stats, timing)
    }

    /// The reader's side: merges what was handed over and returns the snapshot.
    pub fn read(&mut self) -> &Stats {
        if self.full {
            self.stats.merge(&self.pending);
            self.pending.reset();
            self.full = false;
        }
        &self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(drives: u8) -> Stats {
        Stats::new((1..=drives).map(|a| (Address::new(a).expect("address"), Control::Live)))
    }

    /// Records `n` exchanges of drive slot 1 into the engine's own stats and the fresh timing.
    fn exchanges(own: &mut Stats, fresh: &mut FreshTiming, n: u64) {
        for k in 0..n {
            let d = Duration::from_micros(2000 + k);
            for h in [
                &mut own.histograms.exchange,
                &mut fresh.histograms.exchange,
                &mut own.drive_histograms[1].exchange,
                &mut fresh.drive_histograms[1].exchange,
                &mut own.update_period[1],
                &mut fresh.update_period[1],
            ] {
                record(h, d);
            }
            own.bus.exchanges += 1;
        }
    }

    /// The engine's hand-over: its counters, and its fresh timing exchanged for the empty one.
    fn hand_over(published: &mut Published, own: &Stats, fresh: &mut FreshTiming) {
        let (stats, pending) = published.hand_over();
        stats.copy_counters_from(own);
        if let Some(pending) = pending {
            core::mem::swap(pending, fresh);
        }
    }

    #[test]
    fn a_reader_sees_every_recorded_value_once_however_publications_and_reads_interleave() {
        let mut own = stats(3);
        let mut fresh = FreshTiming::new(3);
        let mut published = Published::new(&own);
        exchanges(&mut own, &mut fresh, 5);
        hand_over(&mut published, &own, &mut fresh);
        // Not read yet: the next publication copies the counters but keeps recording.
        exchanges(&mut own, &mut fresh, 7);
        hand_over(&mut published, &own, &mut fresh);
        assert_eq!(
            fresh.histograms.exchange.len(),
            7,
            "kept for the next hand-over"
        );
        let read = published.read().clone();
        assert_eq!(read.bus.exchanges, 12);
        assert_eq!(read.histograms.exchange.len(), 5);
        hand_over(&mut published, &own, &mut fresh);
        assert_eq!(
            fresh.histograms.exchange.len(),
            0,
            "handed over, an empty one back"
        );
        let read = published.read().clone();
        for h in [
            &read.histograms.exchange,
            &read.drive_histograms[1].exchange,
            &read.update_period[1],
        ] {
            assert_eq!(h.len(), 12);
        }
        assert_eq!(read.histograms.exchange, own.histograms.exchange);
        assert_eq!(
            read.drive_histograms[1].exchange,
            own.drive_histograms[1].exchange
        );
        // Reading again changes nothing.
        assert_eq!(published.read().histograms.exchange.len(), 12);
    }
}
