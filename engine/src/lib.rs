//! The bus engine: the circulating list on one line (USS.md sections 4 to 6), with no I/O of its
//! own. Its seams are two traits it owns: [`Transport`] (the bytes: `uss-serial`'s serial line,
//! the simulator's virtual wire in `uss-drive-sim`) and [`Clock`] (monotonic, or virtual for
//! tests and benchmarks), and the [`Bridge`] to other processes (their samples, their images,
//! whether the process behind a parameter job still lives). The daemon (`uss-master`) runs
//! engines in real-time threads (`uss-realtime`) and serves their clients.
//!
//! One [`Engine`] owns one [`Transport`] and runs in one thread. Each step polls the next drive of
//! the circulating list: it waits out the start pause, flushes stale input, sends the drive's
//! current PZD (and its pending PKW task, if any), and receives the reply under the response and
//! residual-time rules. A failed attempt is retried up to the configured count; a drive whose
//! polls keep failing goes offline, is probed at a lower rate, and comes back with its first good
//! reply. After start-up nothing here allocates, blocks on a client or logs: clients reach the
//! engine through lock-free process images and bounded channels ([`EngineHandle`]), and events go
//! to a housekeeping thread over a bounded channel, dropped and counted when it lags.
//!
//! The parts: PKW mailboxes ([`jobs`]), diagnostics ([`stats`]), the decision of which PZD words
//! go to a drive ([`control`]), the check of the drive's own telegram monitoring
//! ([`monitoring`]) and reference frequency ([`reference`]), lock-free process images
//! ([`image`]).

pub mod clock;
pub mod control;
pub mod image;
pub mod jobs;
pub mod monitoring;
pub mod period;
pub mod picture;
pub mod reference;
pub mod stats;
pub mod transport;

mod bridge;
pub use bridge::{Bridge, LocalBridge};
mod build;
mod capture;
mod drive;
pub use capture::CAPTURE_QUEUE;
use drive::Drive;
mod event;
pub use event::Event;
mod exchange;
use exchange::Attempt;
mod handle;
pub use handle::SubmitError;
mod line;
mod overrides;
use overrides::{Overrides, stop_index};
pub mod schedule;
mod setup;
use schedule::{Continuity, Turns};
pub use setup::{DriveSetup, EngineConfig};
mod turns;
pub use turns::LOOK_STEP;

pub use clock::{Clock, MonotonicClock, VirtualClock};
pub use jobs::{Job, JobResult};
pub use monitoring::{MonitoringSetup, WatchedParam};
pub use reference::Reference;
pub use stats::{DriveCounters, DriveStatus, LastFailure, Stats};
pub use transport::{Rx, Transport, TransportError};

use crate::control::{Gate, GateSetup, Operator, Poll, Transition, latch_id_of};
use crate::image::DriveImages;
use crate::jobs::{Encoded, Outgoing, Requester};
use crate::period::{PeriodSetup, Periods};
use crate::stats::{BusTiming, LineFailure, LineStatus, Published};
use core::time::Duration;
use crossbeam_channel::{Receiver, Sender, TrySendError, bounded};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use uss_protocol::exchange::{Exchange, Heard, Silence};
use uss_protocol::telegram::{MAX_NET_BYTES, MAX_PKW_WORDS, MAX_PZD_WORDS, MAX_TELEGRAM_BYTES};
use uss_protocol::{Address, Adr, FramerConfig, ParamReply, ReplyKind, Words, encode};
use uss_shm_types::{
    BusStatus, ItemOutcome, LatchReason, Monitoring, PathError, PzdOutput, StopCommand,
};

/// Job ids with this bit are ussd's own (telegram monitoring, reference frequency); clients use
/// the rest.
pub const INTERNAL_JOB: u64 = 1 << 63;
/// ussd's own reads a drive's mailbox may hold besides its clients' jobs: the telegram
/// monitoring and the reference (`monitoring::check_own_reads`).
pub const OWN_READS: usize = 2;

/// How many cancellations can wait for the bus thread.
const CANCEL_QUEUE: usize = 64;

/// The longest single sleep of an idle bus thread (every drive offline, or a fixed cycle time
/// reached early): it wakes at least this often to count progress and to see a stop.
pub const IDLE_STEP: Duration = Duration::from_millis(50);

/// What other threads reach of one drive: its process images, the number of the last output
/// sample handed in, its operator stops. The bus thread's own record of it is [`Drive`].
#[derive(Debug, Default)]
struct DriveCells {
    /// Clients' jobs of the drive submitted whose results were not taken yet: at most the
    /// mailbox depth, so a client's job always finds room in the mailbox.
    queued: AtomicUsize,
    images: DriveImages,
    output_number: AtomicU64,
    overrides: Overrides,
}

/// State shared by the engine and its handles.
#[derive(Debug)]
struct Shared {
    setups: Vec<DriveSetup>,
    slot_of: [Option<u8>; 32],
    /// What other threads reach of each drive, by slot.
    drives: Vec<DriveCells>,
    /// Stops of every drive at once (OFF1, OFF2, OFF3 counts): each goes out as a broadcast
    /// (`engine::turns`) besides each drive's own override.
    stop_all: Overrides,
    stats: Mutex<Published>,
    /// When the statistics were last published (bus clock, ns): read without their lock, so a
    /// reader waiting for a change does not hold back the publication it waits for.
    published_ns: AtomicU64,
    stop: AtomicBool,
    /// Set by the bus thread while its line is down.
    line_down: AtomicBool,
    /// Attempts to reopen the line since it went down (by whoever reopens it).
    reopen_attempts: AtomicU32,
    /// Counts the bus thread's steps: every telegram attempt, every poll, every
    /// [`IDLE_STEP`] of an idle wait, every wait for a reopened line. A counter that stops
    /// means the bus thread hangs (see the daemon's supervisor, `uss-master`'s `daemon::supervise`).
    progress: AtomicU64,
    /// Clients' jobs each drive's mailbox takes ([`EngineConfig::mailbox_depth`]); it holds
    /// [`OWN_READS`] more for ussd's own reads.
    mailbox_depth: usize,
}

impl Shared {
    fn slot(&self, address: Address) -> Result<usize, SubmitError> {
        self.slot_of[address.get() as usize]
            .map(usize::from)
            .ok_or(SubmitError::UnknownDrive(address))
    }
}

/// The engine's side for everyone else: process images, parameter jobs, statistics, stop.
#[derive(Debug, Clone)]
pub struct EngineHandle {
    shared: Arc<Shared>,
    jobs: Sender<(Job, Encoded, Requester)>,
    cancels: Sender<core::ops::Range<u64>>,
    results: Receiver<JobResult>,
    captures: Receiver<uss_shm_types::TelegramRecord>,
}

/// The bus engine. See the module documentation.
#[derive(Debug)]
pub struct Engine<T: Transport, C: Clock, B: Bridge = LocalBridge> {
    cfg: EngineConfig,
    transport: T,
    clock: C,
    /// The line's exchange rules without I/O: start pause, reply deadline, framer, when the line
    /// was last busy (`uss_protocol::exchange`).
    exchange: Exchange,
    shared: Arc<Shared>,
    /// Everything the engine keeps of each drive, by slot (`engine::drive`).
    drives: Vec<Drive>,
    poll_list: Vec<u8>,
    /// Each drive's expected poll period and freshness limit, published with its image.
    periods: Periods,
    /// The drives due a poll out of turn (`engine::schedule`, fed by `engine::turns`).
    turns: Turns,
    /// Stops of every drive already sent (OFF1, OFF2, OFF3 counts).
    stop_all_seen: [u32; 3],
    /// The engine's own continuity between two looks at every drive: a gap latches.
    continuity: Continuity,
    position: usize,
    /// With `param_priority`: whether the last poll was an extra one for a parameter job, and
    /// where the search for the next such drive starts (round robin among them).
    extra_was_last: bool,
    extra_cursor: usize,
    tx: [u8; MAX_TELEGRAM_BYTES],
    last_reply_done: Option<Duration>,
    /// When the engine saw the last good reply complete (on its clock, after waking).
    last_reply_seen: Option<Duration>,
    cycle_start: Duration,
    last_publish: Duration,
    /// A drive latched or was re-armed since the last publication: the next one comes at the
    /// end of this step, so what clients read shows it with the poll that carried it.
    control_changed: bool,
    jobs: Receiver<(Job, Encoded, Requester)>,
    cancels: Receiver<core::ops::Range<u64>>,
    results: Sender<JobResult>,
    events: Sender<Event>,
    capture: capture::Capture,
    bus: BusStatus,
    line: LineStatus,
    /// The bus's timing; each drive's is in its record.
    timing: BusTiming,
    /// [`Engine::stats`]' snapshot, built when asked for and dropped by the next step.
    snapshot: std::cell::OnceCell<Stats>,
    bridge: B,
}

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    pub fn clock(&self) -> &C {
        &self.clock
    }

    pub fn clock_mut(&mut self) -> &mut C {
        self.snapshot.take();
        &mut self.clock
    }

    pub fn transport(&self) -> &T {
        &self.transport
    }

    pub fn transport_mut(&mut self) -> &mut T {
        self.snapshot.take();
        &mut self.transport
    }

    /// The bus's counters now (cheap: no snapshot).
    pub fn counters(&self) -> &BusStatus {
        &self.bus
    }

    /// The engine's statistics now: a snapshot built from its drives when first asked for
    /// after a step (the published copy, [`EngineHandle::stats`], lags by up to
    /// `publish_every`). It allocates, and the next step drops it: for tests, benchmarks and
    /// tools that run an engine in their own thread, not for ussd's bus thread.
    pub fn stats(&self) -> &Stats {
        self.snapshot.get_or_init(|| {
            build::snapshot(
                self.clock.now(),
                &self.bus,
                self.line,
                &self.drives,
                &self.timing,
            )
        })
    }

    /// Polls until the handle asks to stop, then shuts down (see [`Engine::shutdown`]). When
    /// the line fails, takes the bus down ([`Engine::line_down`]) and returns the error: the
    /// caller reopens the line and resumes with [`Engine::restore`].
    pub fn run(&mut self) -> Result<(), TransportError> {
        while !self.shared.stop.load(Ordering::Acquire) {
            if let Err(e) = self.poll_next() {
                self.line_down(&e);
                return Err(e);
            }
        }
        self.shutdown()
    }

    /// Polls the next drive in the circulating list (or waits for the next offline probe when
    /// every drive is offline). Returns the address polled.
    pub fn poll_next(&mut self) -> Result<Option<Address>, TransportError> {
        self.snapshot.take();
        self.shared.progress.fetch_add(1, Ordering::Relaxed);
        self.take_jobs();
        self.take_cancels();
        // A drive due out of turn first (`engine::turns`), then the circulating list.
        self.look_and_broadcast()?;
        let polled = if let Some(slot) = self.turns.next(None) {
            self.poll_out_of_turn(slot)?;
            Some(self.drives[slot].setup.address)
        } else {
            match self.next_slot()? {
                Some(slot) => {
                    self.poll_drive(slot, true)?;
                    Some(self.drives[slot].setup.address)
                }
                None => None,
            }
        };
        self.publish_if_due();
        Ok(polled)
    }

    /// Ends every pending job with [`PathError::Shutdown`] and sends each drive its safe command
    /// once (one attempt, no retries).
    pub fn shutdown(&mut self) -> Result<(), TransportError> {
        self.snapshot.take();
        self.shared.stop.store(true, Ordering::Release);
        self.fail_all_jobs(Err(PathError::Shutdown));
        if self.line.down.is_some() {
            // Nothing reaches the drives; their own telegram monitoring stops them.
            self.publish();
            return Ok(());
        }
        for slot in 0..self.drives.len() {
            let setup = self.drives[slot].setup;
            // The safe command, or the stronger stop the drive already gets.
            let command = self.drives[slot].gate.stop_for(setup.safe);
            let mut output = [0u16; MAX_PZD_WORDS];
            output[0] = command.stw1();
            let len = setup.layout.pzd.get();
            let begin = self.exchange.free_at();
            match self.attempt(slot, Some(&output[..len]), false)? {
                Attempt::Reply { words, timing } => self.on_reply(slot, &words, begin, timing),
                Attempt::Failed(f) => self.drives[slot].attempt_failed(f),
            }
        }
        self.publish();
        Ok(())
    }

    fn fail_all_jobs(&mut self, outcome: ItemOutcome) {
        let now = self.clock.now();
        self.take_jobs();
        for slot in 0..self.drives.len() {
            while let Some(r) = self.drives[slot].mailbox.finish(outcome, now) {
                self.deliver(r);
            }
        }
    }

    /// Moves submitted jobs into their drives' mailboxes.
    fn take_jobs(&mut self) {
        while let Ok((job, pkw, requester)) = self.jobs.try_recv() {
            self.bus.jobs_accepted += 1;
            let Some(slot) = self.shared.slot_of[job.address.get() as usize].map(usize::from)
            else {
                continue; // the handle checked the address; a stale job cannot name another
            };
            let outcome = if self.shared.stop.load(Ordering::Acquire) {
                Some(PathError::Shutdown)
            } else if self.drives[slot].link.known() && !self.drives[slot].link.online() {
                Some(PathError::DriveOffline)
            } else {
                // Not expected: the handle took room for every client's job, and ussd's own
                // reads have theirs (`OWN_READS`); kept so a job is still ended, never lost.
                self.drives[slot]
                    .mailbox
                    .push_for(job, pkw, requester)
                    .err()
                    .map(|_| PathError::MailboxFull)
            };
            if let Some(failed) = outcome {
                self.deliver(JobResult {
                    job,
                    outcome: Err(failed),
                    telegrams: 0,
                    on_wire: Duration::ZERO,
                });
            }
        }
    }

    /// Ends the jobs at the front of drive `slot`'s mailbox whose requester died, before one
    /// of them leaves it: a dead client's work dies with it, whenever it died.
    fn drop_jobs_of_the_dead(&mut self, slot: usize) {
        loop {
            let bridge = &self.bridge;
            let Some(r) = self.drives[slot]
                .mailbox
                .drop_unsent_if(|who| bridge.requester_ended(who))
            else {
                break;
            };
            self.bus.jobs_cancelled += 1;
            self.deliver(r);
        }
    }

    /// Takes out the jobs of dead clients that have not reached the wire.
    fn take_cancels(&mut self) {
        while let Ok(ids) = self.cancels.try_recv() {
            for slot in 0..self.drives.len() {
                while let Some(r) = self.drives[slot].mailbox.cancel(ids.clone()) {
                    self.bus.jobs_cancelled += 1;
                    self.deliver(r);
                }
            }
        }
    }

    fn deliver(&mut self, result: JobResult) {
        let slot = self.shared.slot_of[result.job.address.get() as usize].map(usize::from);
        if let Some(slot) = slot
            && self.drives[slot]
                .setup
                .monitoring
                .concerns(&result.job.task)
        {
            self.on_monitoring_result(slot, &result);
        }
        if let Some(slot) = slot
            && let Some(param) = self.drives[slot].setup.reference_param
            && param.concerns(&result.job.task)
        {
            self.on_reference_result(slot, &result);
        }
        if let Some(slot) = slot {
            self.on_reread_write(slot, &result);
        }
        if result.job.id & INTERNAL_JOB != 0 {
            return; // ussd's own read: nobody waits for it
        }
        self.bus.jobs_finished += 1;
        if let Some(slot) = slot {
            self.drives[slot].counters.jobs_done += 1;
        }
        // Cannot be full: clients' jobs are capped per drive (the handle's room in each
        // mailbox), and the channel holds every drive's; disconnected only when the parameter
        // bridge is gone. Either way the result is lost, and counted.
        match self.results.try_send(result) {
            Ok(()) => self.bridge.job_done(),
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.bus.results_lost += 1;
            }
        }
    }

    fn emit(&mut self, event: Event) {
        if self.events.try_send(event).is_err() {
            self.bus.events_dropped += 1;
        }
    }

    /// With `param_priority`, after a regular poll: the next online drive (round robin) with
    /// a parameter job waiting.
    fn extra_slot(&mut self) -> Option<usize> {
        if !self.cfg.param_priority || self.extra_was_last {
            self.extra_was_last = false;
            return None;
        }
        let n = self.drives.len();
        let found = (0..n).map(|k| (self.extra_cursor + k) % n).find(|&slot| {
            self.drives[slot].link.online() && !self.drives[slot].mailbox.is_empty()
        })?;
        self.extra_cursor = (found + 1) % n;
        self.extra_was_last = true;
        Some(found)
    }

    /// The next slot of the circulating list that is due, ending a cycle when the list wraps
    /// (or, with `param_priority`, an extra poll of a drive with a parameter job waiting).
    fn next_slot(&mut self) -> Result<Option<usize>, TransportError> {
        if let Some(slot) = self.extra_slot() {
            return Ok(Some(slot));
        }
        let mut now = self.clock.now();
        for _ in 0..self.poll_list.len() {
            if self.position == self.poll_list.len() {
                self.position = 0;
                self.end_cycle()?;
                now = self.clock.now();
            }
            let slot = usize::from(self.poll_list[self.position]);
            self.position += 1;
            let link = &self.drives[slot].link;
            if link.online() || now >= link.next_probe {
                return Ok(Some(slot));
            }
        }
        // Every drive is offline and none is due: wait for the first probe.
        let next = self
            .drives
            .iter()
            .map(|d| d.link.next_probe)
            .min()
            .unwrap_or(now);
        self.idle_until(next)?;
        Ok(None)
    }

    /// Sleeps until `at` in steps of at most [`LOOK_STEP`], counting progress after each and
    /// polling the drives due out of turn meanwhile (`engine::turns`); returns early when
    /// asked to stop.
    fn idle_until(&mut self, at: Duration) -> Result<(), TransportError> {
        loop {
            let now = self.clock.now();
            if now >= at || self.shared.stop.load(Ordering::Acquire) {
                return Ok(());
            }
            self.clock.sleep_until(at.min(now + LOOK_STEP));
            self.shared.progress.fetch_add(1, Ordering::Relaxed);
            self.serve_out_of_turn(None)?;
        }
    }

    fn end_cycle(&mut self) -> Result<(), TransportError> {
        self.bridge.cycle_completed();
        let now = self.clock.now();
        let took = now.saturating_sub(self.cycle_start);
        self.periods
            .cycle_done(took.saturating_sub(self.continuity.take_stall()));
        self.bus.cycles += 1;
        self.timing.cycle.record(took);
        match self.cfg.cycle_time {
            Some(cycle) if took > cycle => {
                self.bus.cycle_overruns += 1;
                self.emit(Event::CycleOverrun { at: now, took });
                self.cycle_start = now;
            }
            Some(cycle) => {
                self.cycle_start += cycle;
                self.idle_until(self.cycle_start)?;
            }
            None => self.cycle_start = now,
        }
        Ok(())
    }

    /// Drive `slot`'s newest sample and operator command, judged by its gate at `now` (`gap`:
    /// how much longer than its work explains the engine did not look); its status follows, a
    /// change is an event.
    fn observe(&mut self, slot: usize, now: Duration, gap: Duration) -> Option<Transition> {
        let sample = self
            .bridge
            .take_sample(slot, &self.shared.drives[slot].images);
        let operator = self.take_override(slot);
        let d = &mut self.drives[slot];
        let on_allowed = d.setup.monitoring.allows_on(d.monitoring);
        // What the contract could read of the sample, in the rules' terms.
        let received = sample.as_ref().map(|(s, _)| s.received());
        let change = d.gate.observe(Poll {
            now,
            gap,
            sample: received.as_ref(),
            from: sample.map(|(_, from)| from).unwrap_or_default(),
            operator,
            on_allowed,
        });
        if sample.is_none() && change.is_none() {
            return None;
        }
        self.shared.drives[slot]
            .images
            .latch_id
            .store(latch_id_of(d.gate.control()), Ordering::Release);
        let address = d.setup.address;
        self.control_changed |= change.is_some();
        match change {
            Some(Transition::Latched { latch, rejection }) => self.emit(Event::Latched {
                address,
                latch,
                rejection,
            }),
            Some(Transition::Rearmed { pid }) => self.emit(Event::Rearmed {
                address,
                at: now,
                pid,
            }),
            None => {}
        }
        change
    }

    /// Latches drive `slot` from outside a poll (the line came back, its reference changed
    /// under its controller): the same rules as a latch at a poll; its next telegram carries
    /// the stop, out of turn (`Engine::look`).
    fn latch_now(&mut self, slot: usize, reason: LatchReason, now: Duration) {
        let d = &mut self.drives[slot];
        let change = d.gate.latch(reason, now);
        self.control_changed = true;
        let address = d.setup.address;
        self.shared.drives[slot]
            .images
            .latch_id
            .store(latch_id_of(d.gate.control()), Ordering::Release);
        if let Transition::Latched { latch, rejection } = change {
            self.emit(Event::Latched {
                address,
                latch,
                rejection,
            });
        }
    }

    /// The PZD to send now, as the drive's [`Gate`] decides from the controller's newest
    /// sample, operator commands and the telegram-monitoring rule (`crate::control`);
    /// the drive is no longer due out of turn.
    fn output(&mut self, slot: usize, now: Duration, out: &mut [u16; MAX_PZD_WORDS]) {
        self.observe(slot, now, Duration::ZERO);
        let d = &mut self.drives[slot];
        d.gate.words(out);
        d.sent = [out[0], out[1]];
        self.turns.sent(slot);
    }

    /// After every poll of the drive in `slot`, good or failed: its period and freshness limit
    /// as they are now, then its image to the clients.
    fn after_poll(&mut self, slot: usize) {
        let d = &mut self.drives[slot];
        d.period = self.periods.period(slot, d.link.online());
        d.stale_after = self.periods.stale_after(slot, d.link.online());
        self.bridge
            .after_poll(slot, &self.shared.drives[slot].images, &d.status());
    }

    /// The strongest operator command that arrived for the drive since its last poll.
    fn take_override(&mut self, slot: usize) -> Option<Operator> {
        let o = &self.shared.drives[slot].overrides;
        o.take(&mut self.drives[slot].overrides_seen)
            .map(|command| Operator {
                command,
                pid: o.pid.load(Ordering::Relaxed),
            })
    }

    fn publish_if_due(&mut self) {
        let now = self.clock.now();
        if self.control_changed || now.saturating_sub(self.last_publish) >= self.cfg.publish_every {
            self.publish();
        }
    }

    /// Writes a snapshot of the drives into the shared statistics, and hands the timing
    /// recorded since over, unless a reader holds them right now.
    fn publish(&mut self) {
        let now = self.clock.now();
        let Ok(mut shared) = self.shared.stats.try_lock() else {
            // A reader holds them: a change is published at the next step.
            return;
        };
        self.control_changed = false;
        let (stats, pending) = shared.hand_over();
        stats.at = now;
        self.shared.published_ns.store(
            u64::try_from(now.as_nanos()).unwrap_or(u64::MAX),
            Ordering::Release,
        );
        stats.bus = self.bus;
        stats.line = self.line;
        for (status, d) in stats.drives.iter_mut().zip(&self.drives) {
            *status = d.status();
        }
        if let Some(pending) = pending {
            self.timing.hand_over(&mut pending.histograms);
            let per_drive = pending
                .drive_histograms
                .iter_mut()
                .zip(&mut pending.update_period);
            for (d, (histograms, update_period)) in self.drives.iter_mut().zip(per_drive) {
                d.timing.hand_over(histograms, update_period);
            }
        }
        self.last_publish = now;
    }
}
