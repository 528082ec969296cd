//! Diagnostics per drive and per bus, mirroring what the drives keep themselves (r2024..r2031,
//! USS.md section 7), plus timing histograms. Everything is allocated when the engine starts;
//! counting and recording never allocate.

use crate::engine::control::{Control, ControlCounters};
use crate::engine::transport::TransportError;
use core::time::Duration;
use hdrhistogram::Histogram;
use uss_protocol::Address;
pub use uss_shm_types::{DriveCounters, LastFailure};
use uss_shm_types::{Monitoring, Rejection};

/// Why a bus line stopped carrying telegrams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineFault {
    /// The device was closed or unplugged (EOF, EIO, ENXIO, ENODEV; a pty whose far side is gone).
    Closed,
    /// Another I/O error, with its errno (0 if none was given).
    Io(i32),
}

impl LineFault {
    pub fn of(e: &TransportError) -> Self {
        match e {
            TransportError::Closed => Self::Closed,
            TransportError::Io(io) => Self::Io(io.raw_os_error().unwrap_or(0)),
        }
    }
}

impl core::fmt::Display for LineFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Closed => f.write_str("the serial device was closed or unplugged"),
            Self::Io(errno) => write!(
                f,
                "serial I/O failed: {}",
                std::io::Error::from_raw_os_error(*errno)
            ),
        }
    }
}

/// The bus line: up, or down since when and why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LineStatus {
    /// `Some` while the line is down: since (bus clock) and why.
    pub down: Option<(Duration, LineFault)>,
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
}

/// The state of one drive as the master sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
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
    /// Live (the controller's words go out) or latched, and why (`crate::engine::control`).
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
            counters: DriveCounters::default(),
        }
    }
}

/// Bus-wide counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BusCounters {
    /// Exchanges attempted (retries included).
    pub exchanges: u64,
    pub good: u64,
    /// Completed passes through the circulating list.
    pub cycles: u64,
    /// Cycles that took longer than the configured fixed cycle time.
    pub cycle_overruns: u64,
    /// Events the housekeeping thread could not take in time.
    pub events_dropped: u64,
    /// Job results that found their channel full. The channel holds every job that can be
    /// outstanding, so this stays 0; it is counted rather than assumed.
    pub results_lost: u64,
    pub jobs_accepted: u64,
    pub jobs_finished: u64,
    /// Jobs of clients that died, taken out before they reached the wire.
    pub jobs_cancelled: u64,
    /// Sum over good first attempts of the time from line free to reply complete, in ns.
    pub exchange_ns: u64,
    /// Sum over the same exchanges of their wire-time floor (USS.md section 4): start pause,
    /// request and reply characters, and the drive's actual response delay, in ns.
    pub wire_floor_ns: u64,
}

impl BusCounters {
    /// Wire-time floor over achieved exchange time (1.0 = the master adds nothing), if measured.
    pub fn efficiency(&self) -> Option<f64> {
        (self.exchange_ns > 0).then(|| self.wire_floor_ns as f64 / self.exchange_ns as f64)
    }
}

/// Timing histograms in nanoseconds, to two significant figures (1 %): small enough (about
/// 4000 counters each) that publishing a copy costs the bus thread a few microseconds, which
/// hides inside the next start pause. Exact sums for efficiency live in [`BusCounters`].
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

    /// Copies `other` into `self` without allocating (same bounds).
    fn copy_from(&mut self, other: &Self) {
        for (dst, src) in [
            (&mut self.response_delay, &other.response_delay),
            (&mut self.exchange, &other.exchange),
            (&mut self.turnaround, &other.turnaround),
            (&mut self.work, &other.work),
            (&mut self.cycle, &other.cycle),
        ] {
            dst.reset();
            // Same bounds and precision: adding never resizes.
            let _ = dst.add(src);
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
    pub bus: BusCounters,
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
            bus: BusCounters::default(),
            line: LineStatus::default(),
            drives,
            histograms: BusHistograms::new(),
            update_period,
            drive_histograms,
        }
    }

    /// Copies `other` into `self` without allocating (both made by [`Stats::new`] for the same drives).
    pub fn copy_from(&mut self, other: &Self) {
        self.at = other.at;
        self.bus = other.bus;
        self.line = other.line;
        self.drives.copy_from_slice(&other.drives);
        self.histograms.copy_from(&other.histograms);
        for (dst, src) in self.update_period.iter_mut().zip(&other.update_period) {
            dst.reset();
            let _ = dst.add(src);
        }
        for (dst, src) in self
            .drive_histograms
            .iter_mut()
            .zip(&other.drive_histograms)
        {
            for (d, s) in [
                (&mut dst.exchange, &src.exchange),
                (&mut dst.response_delay, &src.response_delay),
            ] {
                d.reset();
                let _ = d.add(s);
            }
        }
    }

    pub fn drive(&self, address: Address) -> Option<&DriveStatus> {
        self.drives.iter().find(|d| d.address == address)
    }
}
