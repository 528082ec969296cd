//! Diagnostics: one [`DriveDiag`] per drive on `uss/<bus>/<gen>/diag` (keyed by address) and
//! one [`BusStatus`] on `uss/<bus>/<gen>/status`, republished by ussd's housekeeping thread.

use crate::LAYOUT_VERSION;
use crate::codes::{UnknownCode, code_table};
use crate::control::{ControlState, LatchReason, Monitoring, Rejection, StopCommand};
#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;
pub use uss_control::DriveFamily;
use uss_protocol::{FrameError, LineError};

/// `last_good_ns` of a drive that never replied.
pub const NEVER: u64 = u64::MAX;

code_table! {
    /// Why the drive's last failed attempt failed (USS.md section 4, "Receive errors to detect
    /// and count"); the `last_failure` byte of [`DriveDiag`].
    pub enum LastFailure {
        /// No attempt has failed yet.
        None = 0 => "none",
        /// No STX within the response delay: "slave x does not respond".
        NoResponse = 1 => "no response",
        /// Garbage before the start of the reply.
        MissingStx = 2 => "missing STX",
        /// An STX without the start pause of 2 character times.
        StartPause = 3 => "start pause not observed",
        BadLge = 4 => "bad LGE",
        Bcc = 5 => "BCC error",
        /// The reply took longer than 1.5 x (n+3) character times.
        Residual = 6 => "residual time exceeded",
        /// The reply's length does not fit the drive's PKW/PZD layout.
        Length = 7 => "wrong length",
        /// Another slave answered.
        WrongAddress = 8 => "wrong slave answered",
        Parity = 9 => "parity error",
        Framing = 10 => "framing error",
        Overrun = 11 => "overrun",
        /// A 2-wire adapter's echo of the request did not match what was sent.
        Echo = 12 => "echo mismatch",
    }
}

code_table! {
    /// Whether the bus line carries telegrams; the `line_state` byte of [`BusStatus`].
    pub enum LineState {
        Up = 0 => "up",
        /// The device failed; ussd reopens it with backoff (0.1 s, doubling to 5 s).
        Down = 1 => "down",
    }
}

code_table! {
    /// Why the bus line went down; the `line_fault` byte of [`BusStatus`].
    pub enum LineFault {
        None = 0 => "none",
        /// The line was closed: a device unplugged (EOF, EIO, ENXIO, ENODEV) or a server's
        /// connection ended.
        Closed = 1 => "the line was closed: a serial device unplugged, or its server's connection ended",
        /// Another I/O error; `line_errno` says which.
        Io = 2 => "the line's I/O failed",
        /// The line took no bytes for longer than its write-stall allowance (an adapter whose
        /// writes stopped being taken, flow stopped).
        Stalled = 3 => "the line's output stalled: no byte could be written for its write-stall allowance",
    }
}

code_table! {
    /// The scheduling ussd's bus thread obtained; the `rt_mode` byte of [`BusStatus`].
    pub enum RtMode {
        /// `SCHED_FIFO` or memory locking failed (or was not asked for): the bus runs best effort.
        BestEffort = 0 => "best effort",
        /// `SCHED_FIFO` obtained.
        Realtime = 1 => "realtime",
    }
}

/// The master's view of one drive, mirroring what the drive keeps itself (r2024..r2031,
/// USS.md section 7) plus timeouts and retries.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssDriveDiagV9"))]
pub struct DriveDiag {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// Polls in a row that failed all their retries.
    pub consecutive_failed_polls: u32,
    /// ZSW1 of the last good reply.
    pub last_zsw1: u16,
    /// HIW of the last good reply.
    pub last_hiw: u16,
    /// The drive address, 0..=31 (also the blackboard key).
    pub address: u8,
    /// 1 while the drive answers.
    pub online: u8,
    /// 1 after a poll failed all retries ("slave x does not respond"), until the next good
    /// reply (USS.md section 4).
    pub no_reply: u8,
    /// A [`ControlState`] code: 0 live, 1 latched (see [`crate::control`]).
    pub control: u8,
    /// A [`LastFailure`] code.
    pub last_failure: u8,
    /// A [`LatchReason`] code (0 while live).
    pub latch_reason: u8,
    /// The [`StopCommand`] a latched drive gets (0, `NO_STOP_COMMAND`, while live).
    pub latch_command: u8,
    /// The [`Rejection`] of the last refused sample (0 if none).
    pub rejection: u8,
    /// A [`Monitoring`] code: the drive's own telegram monitoring as ussd read it.
    pub monitoring: u8,
    /// 1 once the drive's first poll decided `online`; 0: unknown yet.
    pub known: u8,
    /// The count of changes of what ussd knows of the drive ([`crate::PzdInput::picture`])
    /// `info` describes.
    pub picture: u8,
    pub reserved: [u8; 1],
    /// The telegram-off time read from the drive, ms (0 = off or not read).
    pub monitoring_ms: u32,
    /// The process id in the controller's latest sample; 0 if no controller published yet.
    pub controller_pid: u32,
    /// When `online` last changed, `CLOCK_MONOTONIC` ns.
    pub since_ns: u64,
    /// When the last good reply arrived, `CLOCK_MONOTONIC` ns; [`NEVER`] before the first.
    pub last_good_ns: u64,
    /// When the current (or last) latch began, `CLOCK_MONOTONIC` ns.
    pub latched_since_ns: u64,
    /// What ussd knows of the drive from its configuration.
    pub info: DriveInfo,
    /// What ussd counted for the drive since it started.
    pub counters: DriveCounters,
    /// This drive's exchange time (line free -> its reply complete), ns: p50, p99, p99.9, max;
    /// 0 = none yet.
    pub exchange_ns: [u64; 4],
    /// This drive's response delay (end of our request -> its reply's STX), ns: p50, p99,
    /// p99.9, max.
    pub response_delay_ns: [u64; 4],
    /// How often ussd polls the drive now, ns, and after how long its image is stale
    /// ([`crate::PzdInput::period_ns`], [`crate::PzdInput::stale_after_ns`]); 0: not known yet.
    pub period_ns: u64,
    pub stale_after_ns: u64,
    /// The shortest telegram-off time that does not trip the drive between two of its polls on
    /// this bus, ms: the longest time between them (every exchange at its worst case) and one
    /// poll with its retries.
    pub monitoring_min_ms: u32,
    pub reserved3: u32,
}

/// What ussd knows of one drive from its configuration, published so that no client has to be
/// told it again (a controller scales Hz with `reference_hz`, sends exactly `pzd_words`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssDriveInfoV9"))]
pub struct DriveInfo {
    /// The reference frequency P2000, Hz: a setpoint or HIW of 0x4000 (100 %) is this
    /// frequency (USS.md section 7). The drive's own value once ussd has read it; the
    /// configuration's `reference_hz` where it is not read; [`DriveInfo::REFERENCE_NOT_KNOWN`]
    /// (0) while ussd reads it (again: the drive came online, was reset or commissioned):
    /// then no Hz can be scaled ([`DriveInfo::reference`]).
    pub reference_hz: f32,
    /// The controller watchdog, ms: a controller that does not refresh within it trips the drive.
    pub watchdog_ms: u32,
    /// The [`StopCommand`] a latched drive gets (OFF1, OFF2 or OFF3).
    pub safe_command: u8,
    /// 1: parameter writes are allowed; 0: refused (`params_writable = false`).
    pub params_writable: u8,
    /// The PKW setting P2013: 0, 3 or 4 words, or 127 for variable length (USS.md section 3).
    pub pkw_words: u8,
    /// PZD words (P2012): a controller's samples must carry exactly this many.
    pub pzd_words: u8,
    /// Entries of the drive in the circulating list, 1..=16 (USS.md section 5).
    pub weight: u8,
    /// A [`DriveFamily`] code.
    pub family: u8,
    /// The motor's pole pairs ussd made the drive's reference speed Hz with (a G120's p2000 in
    /// rpm, `pole_pairs` in its configuration): [`DriveInfo::reference_rpm`]; 0 where the
    /// reference is a frequency (MICROMASTER 4's P2000) or no speed is read.
    pub pole_pairs: u8,
    pub reserved: [u8; 1],
}

impl DriveInfo {
    /// `reference_hz` while the drive's reference is not known.
    pub const REFERENCE_NOT_KNOWN: f32 = 0.0;

    /// The reference frequency Hz are scaled by, Hz; none while it is not known.
    pub fn reference(&self) -> Option<f32> {
        Some(self.reference_hz).filter(|hz| hz.is_finite() && *hz > 0.0)
    }

    /// The reference speed a setpoint in rpm is scaled by (0x4000 = 100 %: a G120's p2000),
    /// rpm: `reference_hz x 60 / pole_pairs`; none where the reference is no speed or while it
    /// is not known.
    pub fn reference_rpm(&self) -> Option<f32> {
        let pole_pairs = f32::from(self.pole_pairs);
        (self.pole_pairs > 0)
            .then(|| self.reference())
            .flatten()
            .map(|hz| hz * 60.0 / pole_pairs)
    }

    /// A drive ussd has not described (all zero but the version-independent defaults).
    pub const UNKNOWN: Self = Self {
        reference_hz: 0.0,
        watchdog_ms: 0,
        safe_command: crate::control::NO_STOP_COMMAND,
        params_writable: 0,
        pkw_words: 0,
        pzd_words: 0,
        weight: 0,
        family: DriveFamily::Micromaster4.code(),
        pole_pairs: 0,
        reserved: [0; 1],
    };

    pub fn safe_command(&self) -> Result<StopCommand, UnknownCode> {
        StopCommand::try_from(self.safe_command)
    }
}

/// What ussd counts for one drive: the engine counts into this type and the same value is
/// published (USS.md section 4, "Receive errors to detect and count").
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssDriveCountersV9"))]
pub struct DriveCounters {
    /// Telegrams sent to the drive (retries included).
    pub requests: u64,
    /// Valid replies.
    pub good: u64,
    /// Failed attempts (every reply or silence that failed).
    pub rejected: u64,
    pub timeouts: u64,
    /// Attempts repeated after a failure.
    pub retries: u64,
    /// Polls that failed all their retries.
    pub failed_polls: u64,
    pub missing_stx: u64,
    pub start_pause: u64,
    pub bad_lge: u64,
    pub bcc: u64,
    pub residual: u64,
    pub length: u64,
    pub wrong_address: u64,
    pub parity: u64,
    pub framing: u64,
    pub overrun: u64,
    pub echo: u64,
    /// Replies "not yet" (AK 0) while a parameter task was pending (USS.md section 6).
    pub pkw_busy: u64,
    /// Parameter jobs finished.
    pub jobs_done: u64,
    /// Times the drive got its safe command because its live controller stopped refreshing
    /// (a frozen, hung or dead controller; not a clean release).
    pub watchdog_trips: u64,
    /// Latches since ussd started, whatever their reason (the start-up latch counts 1).
    pub latches: u64,
    /// Controller samples refused before the wire ([`Rejection`]).
    pub rejected_outputs: u64,
    /// Clean hand-backs by a controller.
    pub releases: u64,
    /// Operator stop commands applied to the drive.
    pub overrides: u64,
    /// Times another controller's sample arrived while the drive was live under its
    /// controller, with no release in between (a controller replaced: a trip).
    pub replacements: u64,
}

impl From<&FrameError> for LastFailure {
    /// The receive error of the framer (USS.md section 4) as the contract names it.
    fn from(e: &FrameError) -> Self {
        match e {
            FrameError::MissingStx(_) => Self::MissingStx,
            FrameError::StartPauseNotObserved => Self::StartPause,
            FrameError::BadLge(_) => Self::BadLge,
            FrameError::Bcc { .. } => Self::Bcc,
            FrameError::ResidualTimeExceeded { .. } => Self::Residual,
            FrameError::Line(LineError::Parity) => Self::Parity,
            FrameError::Line(LineError::Framing) => Self::Framing,
            FrameError::Line(LineError::Overrun) => Self::Overrun,
        }
    }
}

impl DriveCounters {
    /// How many counters [`DriveCounters::named`] gives.
    pub const COUNT: usize = 25;

    /// Every counter by its field name, in field order (for tools that show or export them).
    pub const fn named(&self) -> [(&'static str, u64); Self::COUNT] {
        [
            ("requests", self.requests),
            ("good", self.good),
            ("rejected", self.rejected),
            ("timeouts", self.timeouts),
            ("retries", self.retries),
            ("failed_polls", self.failed_polls),
            ("missing_stx", self.missing_stx),
            ("start_pause", self.start_pause),
            ("bad_lge", self.bad_lge),
            ("bcc", self.bcc),
            ("residual", self.residual),
            ("length", self.length),
            ("wrong_address", self.wrong_address),
            ("parity", self.parity),
            ("framing", self.framing),
            ("overrun", self.overrun),
            ("echo", self.echo),
            ("pkw_busy", self.pkw_busy),
            ("jobs_done", self.jobs_done),
            ("watchdog_trips", self.watchdog_trips),
            ("latches", self.latches),
            ("rejected_outputs", self.rejected_outputs),
            ("releases", self.releases),
            ("overrides", self.overrides),
            ("replacements", self.replacements),
        ]
    }

    /// Counts a failed attempt under its own counter (`rejected`, the count of every failed
    /// attempt, is counted by the caller); [`LastFailure::None`] counts nothing.
    pub fn count(&mut self, f: LastFailure) {
        let c = match f {
            LastFailure::None => return,
            LastFailure::NoResponse => &mut self.timeouts,
            LastFailure::MissingStx => &mut self.missing_stx,
            LastFailure::StartPause => &mut self.start_pause,
            LastFailure::BadLge => &mut self.bad_lge,
            LastFailure::Bcc => &mut self.bcc,
            LastFailure::Residual => &mut self.residual,
            LastFailure::Length => &mut self.length,
            LastFailure::WrongAddress => &mut self.wrong_address,
            LastFailure::Parity => &mut self.parity,
            LastFailure::Framing => &mut self.framing,
            LastFailure::Overrun => &mut self.overrun,
            LastFailure::Echo => &mut self.echo,
        };
        *c += 1;
    }
}

/// The state of the bus as a whole.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssBusStatusV9"))]
pub struct BusStatus {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// The CPU the bus thread is pinned to; -1 = not pinned.
    pub rt_cpu: i32,
    /// An [`RtMode`] code.
    pub rt_mode: u8,
    /// `SCHED_FIFO` priority of the bus thread; 0 = none.
    pub rt_priority: u8,
    /// Drives on the bus.
    pub drive_count: u8,
    /// 1 while the engine runs; 0 once it stopped.
    pub running: u8,
    /// Wire-time floor over achieved exchange time (USS.md section 4) x 1e6; 0 = not measured
    /// ([`BusStatus::efficiency`], from the `timed` sums).
    pub efficiency_ppm: u32,
    /// Exchanges attempted (retries included).
    pub exchanges: u64,
    /// Good exchanges.
    pub good: u64,
    /// Completed passes through the circulating list (USS.md section 5).
    pub cycles: u64,
    /// Cycles that took longer than the configured fixed cycle time.
    pub cycle_overruns: u64,
    /// Events the housekeeping thread could not take in time.
    pub events_dropped: u64,
    /// Parameter results that found their channel full (stays 0; counted, not assumed).
    pub results_lost: u64,
    pub jobs_accepted: u64,
    pub jobs_finished: u64,
    /// Mean time from line free to reply complete over good first attempts, ns; 0 = none yet.
    pub mean_exchange_ns: u64,
    /// The engine's bus clock at this snapshot, ns since the engine started.
    pub bus_clock_ns: u64,
    /// `CLOCK_MONOTONIC` ns at the same instant as `bus_clock_ns`.
    pub timestamp_ns: u64,
    /// A [`LineState`] code.
    pub line_state: u8,
    /// A [`LineFault`] code (0 while the line is up).
    pub line_fault: u8,
    pub reserved: [u8; 2],
    /// With [`LineFault::Io`]: the errno.
    pub line_errno: i32,
    /// When the line went down, `CLOCK_MONOTONIC` ns (0 while up).
    pub line_down_since_ns: u64,
    /// Times the line went down since ussd started.
    pub line_downs: u64,
    /// Attempts to reopen the line since it went down.
    pub reopen_attempts: u32,
    pub reserved2: u32,
    /// Parameter jobs of clients that died, taken out before they reached the wire.
    pub jobs_cancelled: u64,
    /// Exchange time (line free -> reply complete), ns: p50, p99, p99.9, max; 0 = none yet.
    pub exchange_ns: [u64; 4],
    /// Response delay (end of our request -> the reply's STX), ns: p50, p99, p99.9, max.
    pub response_delay_ns: [u64; 4],
    /// Turnaround (reply complete -> next request written), ns: p50, p99, p99.9, max.
    pub turnaround_ns: [u64; 4],
    /// Exchanges timed so far (every good reply).
    pub exchange_count: u64,
    /// Their summed exchange time, ns (from the histogram: to 1 %).
    pub exchange_sum_ns: u64,
    /// Cumulative exchange-time histogram: exchanges that took at most
    /// [`EXCHANGE_BUCKETS_NS`]`[i]` (Prometheus's `le` buckets; `exchange_count` is `+Inf`).
    pub exchange_le: [u64; EXCHANGE_BUCKETS],
    /// Polls out of turn: a drive whose words became a stronger stop than it last got (an
    /// operator's stop, a trip, a release, a controller's own stop), or that a re-arm made
    /// live, polled before the circulating list goes on.
    pub out_of_turn: u64,
    /// Broadcast telegrams sent: a stop of every drive, one per telegram shape of the drives
    /// that take broadcasts.
    pub broadcasts: u64,
    /// Good first attempts timed by the wire (in `timed_exchange_ns` and
    /// `timed_wire_floor_ns`), and those faster than their characters take at the baud rate (a
    /// pty, a buffer's backlog).
    pub timed: u64,
    pub untimed: u64,
    /// Exact sum over the `timed` exchanges of the time from line free to reply complete, ns.
    pub timed_exchange_ns: u64,
    /// Exact sum over the same exchanges of their wire-time floor (USS.md section 4): start
    /// pause, request and reply characters, and the drive's actual response delay, ns.
    pub timed_wire_floor_ns: u64,
}

/// Buckets of [`BusStatus::exchange_le`].
pub const EXCHANGE_BUCKETS: usize = 12;

/// The upper bounds of [`BusStatus::exchange_le`], ns: 0.5 ms to 1 s, spanning a 187500-baud
/// exchange (about 2 ms) to a slow one at 1200 baud and the 20 ms response timeout.
pub const EXCHANGE_BUCKETS_NS: [u64; EXCHANGE_BUCKETS] = [
    500_000,
    1_000_000,
    2_000_000,
    3_000_000,
    5_000_000,
    7_500_000,
    10_000_000,
    20_000_000,
    50_000_000,
    100_000_000,
    250_000_000,
    1_000_000_000,
];

impl DriveDiag {
    /// What ussd says of the drive, for `image`: its description, but with no reference known
    /// when it describes another state of the drive than the image shows (the drive came
    /// back online, was reset or commissioned, or its reference was read anew, after it was
    /// published): the image is published at once, the description moments later, and nothing
    /// is to be scaled with the reference of before.
    pub fn info_for(&self, image: &crate::PzdInput) -> DriveInfo {
        if self.picture == image.picture {
            self.info
        } else {
            DriveInfo {
                reference_hz: DriveInfo::REFERENCE_NOT_KNOWN,
                ..self.info
            }
        }
    }

    /// A drive nothing is known about yet.
    pub const fn new(address: u8) -> Self {
        Self {
            version: LAYOUT_VERSION,
            consecutive_failed_polls: 0,
            last_zsw1: 0,
            last_hiw: 0,
            address,
            online: 0,
            no_reply: 0,
            control: ControlState::Latched.code(),
            last_failure: LastFailure::None.code(),
            latch_reason: LatchReason::Startup.code(),
            latch_command: crate::control::NO_STOP_COMMAND,
            rejection: Rejection::None.code(),
            monitoring: Monitoring::Unknown.code(),
            known: 0,
            picture: 0,
            reserved: [0; 1],
            monitoring_ms: 0,
            controller_pid: 0,
            since_ns: 0,
            last_good_ns: NEVER,
            latched_since_ns: 0,
            info: DriveInfo::UNKNOWN,
            counters: DriveCounters {
                requests: 0,
                good: 0,
                rejected: 0,
                timeouts: 0,
                retries: 0,
                failed_polls: 0,
                missing_stx: 0,
                start_pause: 0,
                bad_lge: 0,
                bcc: 0,
                residual: 0,
                length: 0,
                wrong_address: 0,
                parity: 0,
                framing: 0,
                overrun: 0,
                echo: 0,
                pkw_busy: 0,
                jobs_done: 0,
                watchdog_trips: 0,
                latches: 0,
                rejected_outputs: 0,
                releases: 0,
                overrides: 0,
                replacements: 0,
            },
            exchange_ns: [0; 4],
            response_delay_ns: [0; 4],
            period_ns: 0,
            stale_after_ns: 0,
            monitoring_min_ms: 0,
            reserved3: 0,
        }
    }

    /// Whether the drive's last good reply is older at `now_ns` than ussd's limit for it while
    /// it counts as online: these diagnostics are not the drive as it is (a stalled bus thread).
    /// The limit is the drive's (`stale_after_ns`, 0: not known yet, never overdue) and the age
    /// diagnostics have by the way they are made ([`crate::names::DIAG_AGE_NS`]), so a drive
    /// that answers every poll is never shown stale.
    pub const fn is_overdue(&self, now_ns: u64) -> bool {
        self.stale_after_ns != 0
            && crate::pzd::overdue(
                self.online,
                self.last_good_ns,
                self.stale_after_ns
                    .saturating_add(crate::names::DIAG_AGE_NS),
                now_ns,
            )
    }

    /// Whether the drive answers as these diagnostics say at `now_ns`: online, and not overdue
    /// (stale diagnostics are not the drive as it is, so they never show it online).
    pub const fn is_online_at(&self, now_ns: u64) -> bool {
        self.online != 0 && !self.is_overdue(now_ns)
    }

    pub fn last_failure(&self) -> Result<LastFailure, UnknownCode> {
        LastFailure::try_from(self.last_failure)
    }

    /// Whether the drive gets its controller's words (not latched).
    pub fn is_live(&self) -> bool {
        self.control == ControlState::Live.code()
    }

    pub fn latch_reason(&self) -> Result<LatchReason, UnknownCode> {
        LatchReason::try_from(self.latch_reason)
    }

    pub fn latch_command(&self) -> Result<StopCommand, UnknownCode> {
        StopCommand::try_from(self.latch_command)
    }

    pub fn rejection(&self) -> Result<Rejection, UnknownCode> {
        Rejection::try_from(self.rejection)
    }

    pub fn monitoring(&self) -> Result<Monitoring, UnknownCode> {
        Monitoring::try_from(self.monitoring)
    }
}

impl BusStatus {
    /// A bus that has not started.
    pub const EMPTY: Self = Self {
        version: LAYOUT_VERSION,
        rt_cpu: -1,
        rt_mode: RtMode::BestEffort.code(),
        rt_priority: 0,
        drive_count: 0,
        running: 0,
        efficiency_ppm: 0,
        exchanges: 0,
        good: 0,
        cycles: 0,
        cycle_overruns: 0,
        events_dropped: 0,
        results_lost: 0,
        jobs_accepted: 0,
        jobs_finished: 0,
        mean_exchange_ns: 0,
        bus_clock_ns: 0,
        timestamp_ns: 0,
        line_state: LineState::Up.code(),
        line_fault: LineFault::None.code(),
        reserved: [0; 2],
        line_errno: 0,
        line_down_since_ns: 0,
        line_downs: 0,
        reopen_attempts: 0,
        reserved2: 0,
        jobs_cancelled: 0,
        exchange_ns: [0; 4],
        response_delay_ns: [0; 4],
        turnaround_ns: [0; 4],
        exchange_count: 0,
        exchange_sum_ns: 0,
        exchange_le: [0; EXCHANGE_BUCKETS],
        out_of_turn: 0,
        broadcasts: 0,
        timed: 0,
        untimed: 0,
        timed_exchange_ns: 0,
        timed_wire_floor_ns: 0,
    };

    pub fn rt_mode(&self) -> Result<RtMode, UnknownCode> {
        RtMode::try_from(self.rt_mode)
    }

    /// Wire-time floor over achieved exchange time (1.0 = the master adds nothing), at most 1:
    /// over the exchanges timed by the wire, and only while at most 1 in 100 were not (a line
    /// that carries replies faster than its baud rate, a pty, is not measured by it: none).
    /// `efficiency_ppm` carries the same figure for readers without floating point.
    pub fn efficiency(&self) -> Option<f64> {
        let wire_timed = self.untimed.saturating_mul(100) <= self.timed + self.untimed;
        (self.timed_exchange_ns > 0 && wire_timed)
            .then(|| self.timed_wire_floor_ns as f64 / self.timed_exchange_ns as f64)
    }

    /// [`BusStatus::efficiency`] x 1e6, 0 = not measured (`efficiency_ppm`).
    pub fn efficiency_ppm(&self) -> u32 {
        self.efficiency().map_or(0, |e| (e * 1e6) as u32)
    }

    /// Whether the bus line is down.
    pub fn is_line_down(&self) -> bool {
        self.line_state == LineState::Down.code()
    }

    /// Why the line is down, in words (with the errno's text for an I/O error); `None` while up.
    pub fn line_fault_text(&self) -> Option<String> {
        if !self.is_line_down() {
            return None;
        }
        Some(match LineFault::try_from(self.line_fault) {
            Ok(LineFault::Io) => format!(
                "the line's I/O failed: {}",
                std::io::Error::from_raw_os_error(self.line_errno)
            ),
            Ok(f) => f.name().to_owned(),
            Err(e) => e.to_string(),
        })
    }
}

impl Default for BusStatus {
    fn default() -> Self {
        Self::EMPTY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failure_codes_round_trip_and_unknown_codes_are_refused() {
        for f in LastFailure::ALL {
            assert_eq!(LastFailure::try_from(f.code()), Ok(*f));
        }
        assert_eq!(LastFailure::ALL.len(), 13);
        assert_eq!(
            LastFailure::try_from(13),
            Err(UnknownCode {
                table: "LastFailure",
                code: 13
            })
        );
        assert_eq!(LastFailure::NoResponse.to_string(), "no response");
    }

    #[test]
    fn a_new_drive_has_no_failure_and_never_replied() {
        let d = DriveDiag::new(5);
        assert_eq!(d.last_failure(), Ok(LastFailure::None));
        assert_eq!((d.address, d.last_good_ns), (5, NEVER));
    }

    #[test]
    fn diagnostics_of_a_drive_that_answers_every_poll_are_never_stale_and_old_ones_are() {
        // Polled every 20 ms, stale after 100 ms. Its last good reply came just before the
        // engine's snapshot, the snapshot was copied for clients a period later, and read a
        // period after that, by a reader woken late: as old as diagnostics get while the drive
        // answers every poll (CI saw such a drive flicker "stale" in the exporter, 2026-12-03).
        let mut d = DriveDiag::new(1);
        (d.online, d.last_good_ns, d.period_ns, d.stale_after_ns) =
            (1, 1_000_000_000, 20_000_000, 100_000_000);
        let worst = d.last_good_ns
            + d.period_ns
            + 2 * crate::names::HEARTBEAT_PERIOD_NS
            + crate::names::HEARTBEAT_PERIOD_NS / 5;
        assert!(!d.is_overdue(worst) && d.is_online_at(worst));
        // Older than the drive's limit and that age: a stalled bus thread, a paused ussd.
        let old = d.last_good_ns + d.stale_after_ns + crate::names::DIAG_AGE_NS + 1;
        assert!(d.is_overdue(old) && !d.is_online_at(old));
        // Not online, or no limit known yet: nothing to be overdue for.
        d.stale_after_ns = 0;
        assert!(!d.is_overdue(old));
        (d.stale_after_ns, d.online) = (100_000_000, 0);
        assert!(!d.is_overdue(old));
    }

    #[test]
    fn status_reports_efficiency_only_when_measured() {
        let mut s = BusStatus::EMPTY;
        assert_eq!(s.efficiency(), None);
        assert_eq!((s.rt_mode(), s.rt_cpu), (Ok(RtMode::BestEffort), -1));
        (s.timed, s.timed_exchange_ns, s.timed_wire_floor_ns) = (99, 2_000_000, 1_700_000);
        assert_eq!(s.efficiency(), Some(0.85));
        assert_eq!(s.efficiency_ppm(), 850_000);
        // 1 in 100 faster than the wire (a buffer's backlog) still measures; 2 in 100 do not.
        s.untimed = 1;
        assert_eq!(s.efficiency(), Some(0.85));
        s.untimed = 2;
        assert_eq!((s.efficiency(), s.efficiency_ppm()), (None, 0));
        s.rt_mode = 2;
        assert!(s.rt_mode().is_err());
    }
}
