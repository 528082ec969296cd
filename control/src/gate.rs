//! Which PZD words go to a drive now: the one place that decides (ARCHITECTURE.md, "Failure
//! model"). Every poll of a drive asks its [`Gate`]; nothing else in ussd chooses words.
//!
//! A drive is **live** (its controller's words go out) or **latched** (it gets a stop command:
//! its configured safe command, or an operator's OFF1/OFF2/OFF3, whichever is stronger). It
//! starts latched when ussd starts, and latches again when
//! - its live controller stops publishing within the watchdog time (frozen, hung or dead), or
//!   its newest sample was written longer ago than that (its own `timestamp_ns`),
//! - ussd itself could not look for longer than the watchdog time (paused by SIGSTOP, a
//!   suspended machine, a starved CPU): a gap in time is a trip, not a fresh start,
//! - a sample arrives that the drive would misread (wrong layout version or flags, a word
//!   count other than the drive's PZD length, STW1 bit 10 clear: [`Received::check`]),
//! - another controller's sample arrives while the drive is live under its controller, with no
//!   release in between (a controller killed and replaced within the watchdog time, a restart
//!   loop): [`LatchReason::Replaced`], counted; the new controller must re-arm,
//! - the controller releases the drive cleanly,
//! - an operator stops it from any process,
//! - an ON arrives while the drive's own telegram monitoring is required but not verified.
//!
//! The latch holds until the controller re-arms the drive the PROFIdrive way: a valid sample
//! with STW1 bit 0 = 0 and the jog bits 8 and 9 clear (OFF1, or OFF2/OFF3; a jog runs the
//! motor) that names the latch ([`Received::latch_id`] = the latch's [`Latch::id`], which the
//! drive's input image publishes): so it was made after the image showed the latch, never by a
//! controller that could not know of it (a stop republished by a refresher, one delivered late,
//! one that crossed an operator's stop). That sample goes out and the drive is live again, so the
//! controller's next ON reaches the drive. A frozen controller that resumes with ON, or a
//! process that reconnects, never restarts a motor by itself. The latch lives here, in ussd; a
//! client cannot clear it any other way.
//!
//! [`Gate::observe`] is a pure function of the gate's state and one look's inputs (the newest
//! sample, an operator command, whether ON is allowed, the time, the engine's own gap): no I/O,
//! no allocation, so the bus thread calls it before every telegram, for every drive, and the
//! tests drive it as a table. [`Gate::words`] are what the drive gets now; [`Gate::decide`]
//! does both for a poll.

use crate::latch::{LatchReason, Rejection};
use crate::sample::{Body, MAX_PZD_WORDS, Received, Words};
use crate::stop::{StopCommand, is_stop, stop_strength};
use core::time::Duration;

/// Which controller published a sample: the unique id iceoryx2 gives its publisher port (a new
/// port, so a new controller process, has a new one whatever its sample says of itself).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct ControllerId(pub u128);

impl ControllerId {
    /// Every sample handed over inside ussd's process (the engine's `publish_sample`: tests,
    /// benchmarks) comes from this one controller.
    pub const IN_PROCESS: Self = Self(0);
}

/// An operator's stop command as the bus thread takes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Operator {
    pub command: StopCommand,
    /// The requesting process (0 if unknown).
    pub pid: u32,
}

/// Why, since when and with what a drive is latched.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Latch {
    pub reason: LatchReason,
    /// What the drive gets.
    pub command: StopCommand,
    /// Bus clock time the latch began (or last changed its reason).
    pub since: Duration,
    /// The operator behind an override, or the controller whose sample caused the latch.
    pub by_pid: u32,
    /// Which latch: `CLOCK_MONOTONIC` ns when it began, strictly greater than the drive's
    /// earlier latch ids (never 0). A stop re-arms the drive only when it names this id.
    pub id: u64,
}

/// The drive's control as published.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Control {
    Live,
    Latched(Latch),
}

/// A change at one poll, for the housekeeping thread's log.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Transition {
    /// The drive latched, or a latched drive got a new cause (or a stronger command).
    Latched { latch: Latch, rejection: Rejection },
    /// OFF1 seen after the latch: the controller's words go out again.
    Rearmed { pid: u32 },
}

/// Counters of one drive's control, mirrored into its diagnostics.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub struct ControlCounters {
    /// Latches since start (the start-up latch counts 1).
    pub latches: u64,
    /// A live controller went stale (not a release).
    pub watchdog_trips: u64,
    /// Another controller's sample arrived while the drive was live under its controller.
    pub replacements: u64,
    /// Samples refused before the wire.
    pub rejected_outputs: u64,
    pub releases: u64,
    pub overrides: u64,
}

/// What a gate needs to know of its drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct GateSetup {
    /// PZD words the drive exchanges (P2012).
    pub pzd: usize,
    /// The configured safe command.
    pub safe: StopCommand,
    /// A live controller that publishes nothing new for longer than this is stale.
    pub watchdog: Duration,
    /// `CLOCK_MONOTONIC` at the bus clock's zero (zero on a virtual clock): latch ids are
    /// `CLOCK_MONOTONIC` ns, so a restarted ussd never repeats an earlier one's.
    pub clock_origin: Duration,
}

/// One look's inputs (before every telegram, and at the drive's poll).
#[derive(Debug, Clone, Copy)]
pub struct Poll<'a> {
    pub now: Duration,
    /// How much longer than its work explains the engine did not look (0 normally): paused by
    /// SIGSTOP, a suspended machine, a starved CPU. Longer than the watchdog time latches a
    /// live drive ([`LatchReason::Paused`]).
    pub gap: Duration,
    /// The controller's newest sample since the previous poll, if any.
    pub sample: Option<&'a Received>,
    /// Who published `sample`.
    pub from: ControllerId,
    /// An operator's stop command that arrived since the previous poll.
    pub operator: Option<Operator>,
    /// Whether an ON may reach the drive (false: its telegram monitoring is required and not
    /// verified).
    pub on_allowed: bool,
}

/// The control of one drive. See the module documentation.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Gate {
    setup: GateSetup,
    control: Control,
    /// The id of the latest latch (0 before the first).
    last_id: u64,
    /// The live controller's latest valid words.
    words: [u16; MAX_PZD_WORDS],
    /// Sequence of the last sample taken: a repeat is not a refresh.
    last_sequence: Option<u64>,
    /// When a sample with a new sequence last arrived.
    refreshed_at: Duration,
    controller_pid: u32,
    /// The controller whose re-arm made the drive live: while live, only its samples are taken.
    owner: Option<ControllerId>,
    rejection: Rejection,
    counters: ControlCounters,
}

impl Gate {
    /// A gate latched by ussd's start: the drive gets its safe command until a controller arms it.
    pub fn new(setup: GateSetup, now: Duration) -> Self {
        let id = latch_id(&setup, now, 0);
        Self {
            setup,
            control: Control::Latched(Latch {
                reason: LatchReason::Startup,
                command: setup.safe,
                since: now,
                by_pid: 0,
                id,
            }),
            last_id: id,
            words: [0; MAX_PZD_WORDS],
            last_sequence: None,
            refreshed_at: now,
            controller_pid: 0,
            owner: None,
            rejection: Rejection::None,
            counters: ControlCounters {
                latches: 1,
                ..ControlCounters::default()
            },
        }
    }

    pub fn control(&self) -> Control {
        self.control
    }

    pub fn counters(&self) -> ControlCounters {
        self.counters
    }

    /// The rejection of the last refused sample.
    pub fn rejection(&self) -> Rejection {
        self.rejection
    }

    /// The process id in the latest sample (0 before the first).
    pub fn controller_pid(&self) -> u32 {
        self.controller_pid
    }

    /// `sequence` of the latest sample taken (0 before the first).
    pub fn taken_sequence(&self) -> u64 {
        self.last_sequence.unwrap_or(0)
    }

    /// Latches the drive from outside a poll (the bus line came back): the same rules as a
    /// latch at a poll.
    pub fn latch(&mut self, reason: LatchReason, now: Duration) -> Transition {
        self.latch_with(reason, self.setup.safe, now, 0, Rejection::None)
    }

    /// Decides the words for this poll into `out` (the first `pzd` words are sent) and returns
    /// what changed, if anything: [`Gate::observe`], then [`Gate::words`].
    pub fn decide(&mut self, poll: Poll<'_>, out: &mut [u16; MAX_PZD_WORDS]) -> Option<Transition> {
        let changed = self.observe(poll);
        self.words(out);
        changed
    }

    /// Takes one look's inputs and returns what changed, if anything.
    pub fn observe(&mut self, poll: Poll<'_>) -> Option<Transition> {
        let mut changed = None;
        // An operator's command comes first: its latch has a new id, which a sample that arrived
        // with it cannot name, so that sample cannot re-arm the drive.
        if let Some(op) = poll.operator {
            self.counters.overrides += 1;
            changed = Some(self.latch_with(
                LatchReason::Override,
                op.command,
                poll.now,
                op.pid,
                Rejection::None,
            ));
        }
        let sample = poll
            .sample
            .filter(|s| self.last_sequence != Some(s.sequence));
        if self.control == Control::Live && poll.gap > self.setup.watchdog {
            // ussd could not look for longer than the watchdog time: whatever waits now was
            // not seen in time, and the drive went that long without a fresh command.
            self.counters.watchdog_trips += 1;
            changed = Some(self.latch_with(
                LatchReason::Paused,
                self.setup.safe,
                poll.now,
                self.controller_pid,
                Rejection::None,
            ));
        }
        if let Some(sample) = sample {
            self.last_sequence = Some(sample.sequence);
            self.refreshed_at = self.written_at(sample, poll.now);
            self.controller_pid = sample.pid;
            if let Some(t) = self.take(sample, poll) {
                changed = Some(t);
            }
        }
        if self.control == Control::Live
            && poll.now.saturating_sub(self.refreshed_at) > self.setup.watchdog
        {
            self.counters.watchdog_trips += 1;
            changed = Some(self.latch_with(
                LatchReason::Stale,
                self.setup.safe,
                poll.now,
                self.controller_pid,
                Rejection::None,
            ));
        }
        changed
    }

    /// When `sample` was written, on the bus clock: its own `timestamp_ns` (`CLOCK_MONOTONIC`),
    /// never later than `now`; `now` when it carries none (0).
    fn written_at(&self, sample: &Received, now: Duration) -> Duration {
        if sample.timestamp_ns == 0 {
            return now;
        }
        Duration::from_nanos(sample.timestamp_ns)
            .saturating_sub(self.setup.clock_origin)
            .min(now)
    }

    /// The words the drive gets now into `out` (the first `pzd` are sent): the live
    /// controller's, or the latch's stop command.
    pub fn words(&self, out: &mut [u16; MAX_PZD_WORDS]) {
        *out = [0; MAX_PZD_WORDS];
        match self.control {
            Control::Live => out.copy_from_slice(&self.words),
            Control::Latched(latch) => out[0] = latch.command.stw1(),
        }
    }

    /// Takes a new sample.
    fn take(&mut self, sample: &Received, poll: Poll<'_>) -> Option<Transition> {
        let pid = sample.pid;
        if self.control == Control::Live && self.owner != Some(poll.from) {
            // Another controller while the drive runs under one: whatever it sends (an ON, a
            // stop, a release), it takes nothing over without seeing a latch first.
            self.counters.replacements += 1;
            return Some(self.latch_with(
                LatchReason::Replaced,
                self.setup.safe,
                poll.now,
                pid,
                Rejection::None,
            ));
        }
        match sample.check(self.setup.pzd) {
            Err(rejection) => {
                self.counters.rejected_outputs += 1;
                let repeated = self.rejection == rejection
                    && matches!(self.control, Control::Latched(l) if l.reason == LatchReason::Rejected);
                self.rejection = rejection;
                (!repeated).then(|| {
                    self.latch_with(
                        LatchReason::Rejected,
                        self.setup.safe,
                        poll.now,
                        pid,
                        rejection,
                    )
                })
            }
            Ok(Body::Release) => {
                self.counters.releases += 1;
                match self.control {
                    Control::Live => Some(self.latch_with(
                        LatchReason::Released,
                        self.setup.safe,
                        poll.now,
                        pid,
                        Rejection::None,
                    )),
                    // Already latched: the cause of that latch stays the news.
                    Control::Latched(_) => None,
                }
            }
            Ok(Body::Words(Words { words, .. })) => {
                // A word that runs the motor: ON, or a jog (bit 8 or 9 on an OFF1 word; found
                // by issue 46's adversarial sweep: required monitoring refused ON only, and a
                // jog went out to a drive whose monitoring was off).
                let runs = self.setup.pzd > 0 && stop_strength(words[0]) == 0;
                // A stop re-arms (OFF1, OFF2, OFF3); a jog word has bit 0 clear too, but runs.
                // (Without PZD every word is 0: a stop.)
                let stop = self.setup.pzd == 0 || is_stop(words[0]);
                match self.control {
                    Control::Live if runs && !poll.on_allowed => Some(self.latch_with(
                        LatchReason::MonitoringOff,
                        self.setup.safe,
                        poll.now,
                        pid,
                        Rejection::None,
                    )),
                    Control::Live => {
                        self.words = words;
                        None
                    }
                    Control::Latched(latch) if stop && sample.latch_id == latch.id => {
                        self.words = words;
                        self.control = Control::Live;
                        self.owner = Some(poll.from);
                        Some(Transition::Rearmed { pid })
                    }
                    Control::Latched(mut latch) if stop => {
                        // A stop of a controller that does not re-arm still reaches the drive
                        // when it stops harder than the latch's command (a coast over OFF1): a
                        // safe command is sendable from anywhere. The latch stays the same.
                        if let Some(harder) = StopCommand::of_stw1(words[0])
                            .filter(|c| c.strength() > latch.command.strength())
                        {
                            latch.command = harder;
                            self.control = Control::Latched(latch);
                        }
                        None
                    }
                    Control::Latched(_) => None,
                }
            }
        }
    }

    /// The stop a latch made now sends for `command`: the stronger of it and the stop the drive
    /// gets already (its latch's, or a live controller's own OFF2 or OFF3). A latch never
    /// weakens a stop: a controller that coasts and then releases, goes stale or is replaced
    /// leaves its drive coasting.
    pub fn stop_for(&self, command: StopCommand) -> StopCommand {
        let current = match self.control {
            Control::Latched(l) => Some(l.command),
            Control::Live if self.setup.pzd > 0 => StopCommand::of_stw1(self.words[0]),
            Control::Live => None,
        };
        match current {
            Some(c) if c.strength() > command.strength() => c,
            _ => command,
        }
    }

    fn latch_with(
        &mut self,
        reason: LatchReason,
        command: StopCommand,
        now: Duration,
        by_pid: u32,
        rejection: Rejection,
    ) -> Transition {
        let command = self.stop_for(command);
        let id = latch_id(&self.setup, now, self.last_id);
        let latch = Latch {
            reason,
            command,
            since: now,
            by_pid,
            id,
        };
        self.last_id = id;
        self.counters.latches += 1;
        self.control = Control::Latched(latch);
        Transition::Latched { latch, rejection }
    }
}

/// The id of `control`'s latch, 0 while live: the input image's `latch_id`.
pub const fn latch_id_of(control: Control) -> u64 {
    match control {
        Control::Live => 0,
        Control::Latched(l) => l.id,
    }
}

/// The id of a latch made at bus time `now`, after one with id `last`.
fn latch_id(setup: &GateSetup, now: Duration, last: u64) -> u64 {
    let at = setup.clock_origin.saturating_add(now).as_nanos();
    u64::try_from(at)
        .unwrap_or(u64::MAX)
        .max(last.saturating_add(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    const READY: u16 = 0x047E;
    const RUN: u16 = 0x047F;
    const COAST: u16 = 0x047C;
    const QUICK: u16 = 0x047A;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn setup() -> GateSetup {
        GateSetup {
            pzd: 2,
            safe: StopCommand::Off1,
            watchdog: ms(100),
            clock_origin: ms(5000),
        }
    }

    fn sample(seq: u64, words: &[u16]) -> Received {
        stamped(seq, words, 0)
    }

    /// A sample of the controller of pid 42 written at `timestamp_ns`, naming no latch.
    fn stamped(seq: u64, words: &[u16], timestamp_ns: u64) -> Received {
        let mut w = Words::stop(words.len(), 0);
        w.words[..words.len()].copy_from_slice(words);
        Received {
            sequence: seq,
            timestamp_ns,
            pid: 42,
            latch_id: 0,
            body: Ok(Body::Words(w)),
        }
    }

    fn naming(s: Received, latch_id: u64) -> Received {
        Received { latch_id, ..s }
    }

    fn release_sample(seq: u64) -> Received {
        Received {
            body: Ok(Body::Release),
            ..sample(seq, &[])
        }
    }

    /// What goes out and what changed, for one poll.
    struct Step {
        words: [u16; 2],
        change: Option<Transition>,
    }

    /// Plays polls on a gate: `(time ms, sample, operator, on_allowed)`.
    struct Play {
        gate: Gate,
        seq: u64,
        /// Who publishes the samples: the controller of pid 42 unless a test changes it.
        from: ControllerId,
    }

    impl Play {
        /// A gate after ussd's start and its first poll.
        fn new() -> Self {
            let mut p = Self {
                gate: Gate::new(setup(), ms(0)),
                seq: 0,
                from: ControllerId(42),
            };
            p.poll(0, None, None);
            p
        }

        /// A gate that is live and running: armed with OFF1, then ON with a setpoint.
        fn running() -> Self {
            let mut p = Self::new();
            p.send(1, &[READY, 0]);
            p.send(2, &[RUN, 0x2000]);
            assert_eq!(p.gate.control(), Control::Live);
            p
        }

        fn poll(&mut self, t: u64, sample: Option<Received>, op: Option<StopCommand>) -> Step {
            self.poll_with(t, sample, op, true)
        }

        fn poll_with(
            &mut self,
            t: u64,
            sample: Option<Received>,
            op: Option<StopCommand>,
            on_allowed: bool,
        ) -> Step {
            let mut out = [0u16; MAX_PZD_WORDS];
            let change = self.gate.decide(
                Poll {
                    now: ms(t),
                    gap: Duration::ZERO,
                    sample: sample.as_ref(),
                    from: self.from,
                    operator: op.map(|command| Operator { command, pid: 7 }),
                    on_allowed,
                },
                &mut out,
            );
            Step {
                words: [out[0], out[1]],
                change,
            }
        }

        /// A fresh sample with the next sequence number from a controller that saw the image
        /// as it is: it names the current latch.
        fn send(&mut self, t: u64, words: &[u16]) -> Step {
            let seen = self.latch_id();
            self.send_naming(t, words, seen)
        }

        /// A fresh sample naming latch `id` (an earlier one, or 0: none).
        fn send_naming(&mut self, t: u64, words: &[u16], id: u64) -> Step {
            self.seq += 1;
            let s = naming(sample(self.seq, words), id);
            self.poll(t, Some(s), None)
        }

        /// A fresh sample of another controller (`from`), which saw the image as it is.
        fn send_from(&mut self, from: u128, t: u64, words: &[u16]) -> Step {
            self.from = ControllerId(from);
            self.send(t, words)
        }

        /// The current latch's id (0 while live).
        fn latch_id(&self) -> u64 {
            match self.gate.control() {
                Control::Live => 0,
                Control::Latched(l) => l.id,
            }
        }

        fn reason(&self) -> Option<LatchReason> {
            match self.gate.control() {
                Control::Live => None,
                Control::Latched(l) => Some(l.reason),
            }
        }
    }

    fn latched(change: Option<Transition>) -> (LatchReason, StopCommand, Rejection) {
        match change {
            Some(Transition::Latched { latch, rejection }) => {
                (latch.reason, latch.command, rejection)
            }
            other => panic!("expected a latch, got {other:?}"),
        }
    }

    /// After a stale trip at 200 ms and the poll after it.
    fn tripped() -> Play {
        let mut p = Play::running();
        p.poll(200, None, None);
        p.poll(210, None, None);
        p
    }

    /// Overridden with OFF2 at 10 ms.
    fn coasted() -> Play {
        let mut p = Play::running();
        p.poll(10, None, Some(StopCommand::Off2));
        p
    }

    /// Live, its controller's own coast (OFF2) at 3 ms; `QUICK` for its quick stop (OFF3).
    fn own_stop(stw1: u16) -> Play {
        let mut p = Play::running();
        p.send(3, &[stw1, 0]);
        assert_eq!(p.gate.control(), Control::Live);
        p
    }

    /// Latched at start, then coasted by an operator at 10 ms: the start-up latch's id is an
    /// earlier one.
    fn coasted_at_start() -> (Play, u64) {
        let mut p = Play::new();
        let startup = p.latch_id();
        p.poll(10, None, Some(StopCommand::Off2));
        (p, startup)
    }

    /// `sample` published with the next sequence number and taken at `t`.
    fn with(
        p: &mut Play,
        t: u64,
        words: &[u16],
        op: Option<StopCommand>,
        on_allowed: bool,
    ) -> Step {
        p.seq += 1;
        let s = sample(p.seq, words);
        p.poll_with(t, Some(s), op, on_allowed)
    }

    fn release(p: &mut Play) -> Step {
        p.seq += 1;
        let s = release_sample(p.seq);
        p.poll(10, Some(s), None)
    }

    /// A sample the contract could not read (its refusal: another layout version, unknown
    /// flags), with the next sequence number.
    fn foreign(p: &mut Play, t: u64, refusal: Rejection) -> Step {
        p.seq += 1;
        let s = Received {
            body: Err(refusal),
            ..sample(p.seq, &[RUN, 0x2000])
        };
        p.poll(t, Some(s), None)
    }

    /// The decision table: state x event -> words on the wire, and the latch that follows.
    #[rustfmt::skip]
    #[test]
    fn decision_table() {
        use LatchReason::{Override, Rejected, Released, Replaced, Stale, Startup};
        type Case = (&'static str, fn() -> Play, fn(&mut Play) -> Step, [u16; 2], Option<LatchReason>);
        let cases: &[Case] = &[
            // Latched at start-up.
            ("start, no controller: safe command", Play::new, |p| p.poll(1, None, None), [READY, 0], Some(Startup)),
            ("start, ON without OFF1 first: refused", Play::new, |p| p.send(1, &[RUN, 0x2000]), [READY, 0], Some(Startup)),
            ("start, OFF1 arms: its words go out", Play::new, |p| p.send(1, &[READY, 0x1000]), [READY, 0x1000], None),
            ("start, OFF2 from the controller also arms", Play::new, |p| p.send(1, &[COAST, 0]), [COAST, 0], None),
            ("start, bit 10 clear: rejected", Play::new, |p| p.send(1, &[0x007E, 0]), [READY, 0], Some(Rejected)),
            ("start, operator coast: OFF2", Play::new, |p| p.poll(1, None, Some(StopCommand::Off2)), [COAST, 0], Some(Override)),
            // Live and running.
            ("live, fresh ON: its words", Play::running, |p| p.send(50, &[RUN, 0x3000]), [RUN, 0x3000], None),
            ("live, nothing new within the watchdog: last words", Play::running, |p| p.poll(102, None, None), [RUN, 0x2000], None),
            ("live, nothing new beyond the watchdog: stale", Play::running, |p| p.poll(103, None, None), [READY, 0], Some(Stale)),
            ("live, a repeated sequence is no refresh", Play::running, |p| { let s = sample(p.seq, &[RUN, 0x2000]); p.poll(103, Some(s), None) }, [READY, 0], Some(Stale)),
            ("live, all-zero struct: rejected", Play::running, |p| foreign(p, 10, Rejection::Version), [READY, 0], Some(Rejected)),
            ("live, STW1 0x0000: rejected", Play::running, |p| p.send(10, &[0x0000, 0]), [READY, 0], Some(Rejected)),
            ("live, STW1 0x007F: rejected", Play::running, |p| p.send(10, &[0x007F, 0x2000]), [READY, 0], Some(Rejected)),
            ("live, one word for two: rejected", Play::running, |p| p.send(10, &[RUN]), [READY, 0], Some(Rejected)),
            ("live, unknown flags: rejected", Play::running, |p| foreign(p, 10, Rejection::Flags), [READY, 0], Some(Rejected)),
            ("live, release: safe command", Play::running, release, [READY, 0], Some(Released)),
            ("live, operator OFF1", Play::running, |p| p.poll(10, None, Some(StopCommand::Off1)), [READY, 0], Some(Override)),
            ("live, operator OFF3", Play::running, |p| p.poll(10, None, Some(StopCommand::Off3)), [QUICK, 0], Some(Override)),
            ("live, operator OFF3 beats a fresh ON", Play::running, |p| with(p, 10, &[RUN, 0x3000], Some(StopCommand::Off3), true), [QUICK, 0], Some(Override)),
            ("live, ON with required monitoring off", Play::running, |p| with(p, 10, &[RUN, 0x2000], None, false), [READY, 0], Some(LatchReason::MonitoringOff)),
            ("live, OFF1 with monitoring off still goes out", Play::running, |p| with(p, 10, &[READY, 0], None, false), [READY, 0], None),
            ("live, jog with required monitoring off", Play::running, |p| with(p, 10, &[0x057E, 0], None, false), [READY, 0], Some(LatchReason::MonitoringOff)),
            ("live, coast with a jog bit and monitoring off still goes out", Play::running, |p| with(p, 10, &[0x057C, 0], None, false), [0x057C, 0], None),
            // A latch never weakens the stop a live controller sends itself (found by the
            // adversarial run: `ussctl ack` and every release handed an OFF2 back as OFF1).
            ("live, own coast, release: OFF2 stays", || own_stop(COAST), release, [COAST, 0], Some(Released)),
            ("live, own coast, nothing new beyond the watchdog: OFF2 stays", || own_stop(COAST), |p| p.poll(104, None, None), [COAST, 0], Some(Stale)),
            ("live, own quick stop, rejected sample: OFF3 stays", || own_stop(QUICK), |p| p.send(10, &[0x0000, 0]), [QUICK, 0], Some(Rejected)),
            ("live, own coast, another controller: OFF2 stays", || own_stop(COAST), |p| p.send_from(43, 10, &[RUN, 0x3000]), [COAST, 0], Some(Replaced)),
            ("live, own coast, operator OFF1: OFF2 stays", || own_stop(COAST), |p| p.poll(10, None, Some(StopCommand::Off1)), [COAST, 0], Some(Override)),
            ("live, own quick stop, operator OFF2: OFF2", || own_stop(QUICK), |p| p.poll(10, None, Some(StopCommand::Off2)), [COAST, 0], Some(Override)),
            // Latched after a trip or an override.
            ("stale, the frozen controller resumes with ON: latched", tripped, |p| p.send(300, &[RUN, 0x2000]), [READY, 0], Some(Stale)),
            ("stale, OFF1 re-arms", tripped, |p| p.send(300, &[READY, 0]), [READY, 0], None),
            ("stale, jog right does not re-arm", tripped, |p| p.send(300, &[0x057E, 0]), [READY, 0], Some(Stale)),
            ("stale, jog left does not re-arm", tripped, |p| p.send(300, &[0x067E, 0]), [READY, 0], Some(Stale)),
            ("stale, garbage does not re-arm", tripped, |p| foreign(p, 210, Rejection::Version), [READY, 0], Some(Rejected)),
            ("stale, a release keeps the trip's reason", tripped, release, [READY, 0], Some(Stale)),
            ("coasted, operator OFF1: OFF2 stays", coasted, |p| p.poll(20, None, Some(StopCommand::Off1)), [COAST, 0], Some(Override)),
            ("coasted, ON: latched", coasted, |p| p.send(20, &[RUN, 0x2000]), [COAST, 0], Some(Override)),
            ("coasted, OFF1 naming it re-arms", coasted, |p| p.send(20, &[READY, 0]), [READY, 0], None),
            ("coasted, OFF1 naming it at the very next poll re-arms", coasted, |p| p.send(11, &[READY, 0]), [READY, 0], None),
            ("coasted, OFF1 naming no latch (made while live, republished): no re-arm", coasted, |p| p.send_naming(20, &[READY, 0], 0), [COAST, 0], Some(Override)),
            ("coasted at start, OFF1 naming the start-up latch: no re-arm", || coasted_at_start().0, |p| { let (_, startup) = coasted_at_start(); p.send_naming(20, &[READY, 0], startup) }, [COAST, 0], Some(Override)),
            ("coasted, OFF1 naming a later id: no re-arm", coasted, |p| { let id = p.latch_id() + 1; p.send_naming(20, &[READY, 0], id) }, [COAST, 0], Some(Override)),
            ("start, OFF1 naming no latch: no re-arm", Play::new, |p| p.send_naming(1, &[READY, 0], 0), [READY, 0], Some(Startup)),
            ("stale, OFF1 naming no latch (the refresher's, before the trip): no re-arm", tripped, |p| p.send_naming(300, &[READY, 0], 0), [READY, 0], Some(Stale)),
            ("running, OFF1 with an override at the same poll: no re-arm", Play::running, |p| with(p, 10, &[READY, 0], Some(StopCommand::Off2), true), [COAST, 0], Some(Override)),
            // Another controller while live: a trip, whatever it sends.
            ("running, ON of another controller: replaced", Play::running, |p| p.send_from(43, 10, &[RUN, 0x3000]), [READY, 0], Some(Replaced)),
            ("running, OFF1 of another controller: replaced", Play::running, |p| p.send_from(43, 10, &[READY, 0]), [READY, 0], Some(Replaced)),
            ("running, a release of another controller: replaced", Play::running, |p| { p.from = ControllerId(43); release(p) }, [READY, 0], Some(Replaced)),
            ("running, the same controller's ON: its words", Play::running, |p| p.send_from(42, 10, &[RUN, 0x3000]), [RUN, 0x3000], None),
            ("stale, another controller's OFF1 naming the trip re-arms (it saw the latch)", tripped, |p| p.send_from(43, 300, &[READY, 0]), [READY, 0], None),
            ("released, another controller's OFF1 naming it re-arms", || { let mut p = Play::running(); release(&mut p); p }, |p| p.send_from(43, 20, &[READY, 0]), [READY, 0], None),
            // A controller's harder stop reaches a latched drive without re-arming it.
            ("start, a coast naming no latch: OFF2 goes out, still latched", Play::new, |p| p.send_naming(1, &[COAST, 0], 0), [COAST, 0], Some(Startup)),
            ("stale, a quick stop naming no latch: OFF3 goes out, still latched", tripped, |p| p.send_naming(300, &[QUICK, 0], 0), [QUICK, 0], Some(Stale)),
            ("coasted, OFF1 naming no latch does not weaken the coast", coasted, |p| p.send_naming(20, &[READY, 0], 0), [COAST, 0], Some(Override)),
        ];
        for (name, start, event, words, reason) in cases {
            let mut p = start();
            let step = event(&mut p);
            assert_eq!(step.words, *words, "{name}: words on the wire");
            assert_eq!(p.reason(), *reason, "{name}: latch reason");
        }
    }

    #[test]
    fn a_frozen_controller_trips_once_and_runs_again_only_after_off1_then_on() {
        let mut p = Play::running();
        let (reason, command, _) = latched(p.poll(103, None, None).change);
        assert_eq!((reason, command), (LatchReason::Stale, StopCommand::Off1));
        assert_eq!(
            p.poll(150, None, None).change,
            None,
            "one trip, not one per poll"
        );
        assert_eq!(p.gate.counters().watchdog_trips, 1);
        // SIGCONT: the refresher publishes ON again, for seconds.
        for t in (200..2000).step_by(20) {
            assert_eq!(p.send(t, &[RUN, 0x2000]).words, [READY, 0], "t = {t} ms");
        }
        // OFF1 naming no latch (the refresher's words from before the freeze): still latched.
        assert_eq!(p.send_naming(1990, &[READY, 0], 0).change, None);
        assert!(p.reason().is_some());
        // The deliberate re-arm: OFF1 naming the trip, then ON.
        let step = p.send(2000, &[READY, 0]);
        assert_eq!(step.change, Some(Transition::Rearmed { pid: 42 }));
        assert_eq!(p.send(2020, &[RUN, 0x2000]).words, [RUN, 0x2000]);
        let c = p.gate.counters();
        assert_eq!((c.latches, c.watchdog_trips, c.releases), (2, 1, 0));
    }

    #[test]
    fn a_controller_replaced_while_live_latches_once_and_the_new_one_must_re_arm() {
        let mut p = Play::running();
        // The old controller was killed; the new one publishes ON at once, within the
        // watchdog time.
        let step = p.send_from(43, 10, &[RUN, 0x2000]);
        assert_eq!(step.words, [READY, 0]);
        let (reason, command, _) = latched(step.change);
        assert_eq!(
            (reason, command),
            (LatchReason::Replaced, StopCommand::Off1)
        );
        assert_eq!(p.gate.counters().replacements, 1);
        // Its ONs run nothing, and are no new latch.
        assert_eq!(p.send_naming(20, &[RUN, 0x2000], 0).change, None);
        assert_eq!(p.reason(), Some(LatchReason::Replaced));
        // Its re-arm (naming the latch it saw) makes it the drive's controller.
        assert_eq!(
            p.send(30, &[READY, 0]).change,
            Some(Transition::Rearmed { pid: 42 })
        );
        assert_eq!(p.send(40, &[RUN, 0x2000]).words, [RUN, 0x2000]);
        // Now the old one's samples are another controller's.
        let step = p.send_from(42, 50, &[RUN, 0x2000]);
        assert_eq!(latched(step.change).0, LatchReason::Replaced);
        let c = p.gate.counters();
        assert_eq!((c.replacements, c.watchdog_trips, c.latches), (2, 0, 3));
    }

    #[test]
    fn release_is_counted_as_a_release_not_a_trip() {
        let mut p = Play::running();
        p.seq += 1;
        let step = p.poll(10, Some(release_sample(p.seq)), None);
        assert_eq!(latched(step.change).0, LatchReason::Released);
        // Nothing more arrives: a released drive does not go "stale".
        assert_eq!(p.poll(500, None, None).change, None);
        let c = p.gate.counters();
        assert_eq!((c.releases, c.watchdog_trips, c.latches), (1, 0, 2));
    }

    #[test]
    fn each_kind_of_rejection_is_counted_and_named() {
        let mut p = Play::running();
        let (reason, _, rejection) = latched(p.send(10, &[0x007F, 0x2000]).change);
        assert_eq!(
            (reason, rejection),
            (LatchReason::Rejected, Rejection::NoPlcControl)
        );
        // The same garbage again is counted, not a new latch.
        assert_eq!(p.send(20, &[0x007F, 0x2000]).change, None);
        let (_, _, rejection) = latched(p.send(30, &[RUN]).change);
        assert_eq!(rejection, Rejection::WordCount);
        assert_eq!(p.gate.counters().rejected_outputs, 3);
        assert_eq!(p.gate.rejection(), Rejection::WordCount);
    }

    #[test]
    fn operator_commands_only_grow_stronger_until_re_armed() {
        let mut p = Play::running();
        let (_, command, _) = latched(p.poll(10, None, Some(StopCommand::Off3)).change);
        assert_eq!(command, StopCommand::Off3);
        let (_, command, _) = latched(p.poll(20, None, Some(StopCommand::Off1)).change);
        assert_eq!(command, StopCommand::Off3, "OFF1 does not weaken OFF3");
        let (_, command, _) = latched(p.poll(30, None, Some(StopCommand::Off2)).change);
        assert_eq!(command, StopCommand::Off2);
        assert_eq!(p.gate.counters().overrides, 3);
        // Re-armed (by an OFF1 naming the latch), the next latch starts from the safe command
        // again.
        p.send(40, &[READY, 0]);
        let (_, command, _) = latched(p.poll(200, None, None).change);
        assert_eq!(command, StopCommand::Off1);
    }

    #[test]
    fn a_configured_coast_is_the_latched_command() {
        let mut gate = Gate::new(
            GateSetup {
                safe: StopCommand::Off2,
                ..setup()
            },
            ms(0),
        );
        let mut out = [0; MAX_PZD_WORDS];
        gate.decide(
            Poll {
                now: ms(1),
                gap: Duration::ZERO,
                sample: None,
                from: ControllerId(42),
                operator: None,
                on_allowed: true,
            },
            &mut out,
        );
        assert_eq!(out[..2], [COAST, 0]);
    }

    #[test]
    fn a_gap_of_the_engine_longer_than_the_watchdog_latches_a_live_drive_as_paused() {
        fn look(gap: u64, sample: Option<&Received>) -> Poll<'_> {
            Poll {
                now: ms(10),
                gap: ms(gap),
                sample,
                from: ControllerId(42),
                operator: None,
                on_allowed: true,
            }
        }
        let mut p = Play::running();
        // A gap within the watchdog time changes nothing.
        assert_eq!(p.gate.observe(look(100, None)), None);
        // Beyond it, even with a fresh sample waiting: latched, counted as a trip.
        let fresh = sample(99, &[RUN, 0x2000]);
        let change = p.gate.observe(look(101, Some(&fresh)));
        assert!(matches!(
            change,
            Some(Transition::Latched { latch, .. }) if latch.reason == LatchReason::Paused
        ));
        assert_eq!(p.gate.counters().watchdog_trips, 1);
        let mut out = [0; MAX_PZD_WORDS];
        p.gate.words(&mut out);
        assert_eq!(out[0], READY);
    }

    #[test]
    fn a_sample_is_as_fresh_as_its_own_time_stamp() {
        fn look(s: &Received) -> Poll<'_> {
            Poll {
                now: ms(1000),
                gap: Duration::ZERO,
                sample: Some(s),
                from: ControllerId(42),
                operator: None,
                on_allowed: true,
            }
        }
        let mut p = Play::running();
        // Bus time 1000 ms is CLOCK_MONOTONIC 6000 ms (the clock's origin is 5000 ms).
        let stamped = |seq: u64, at_ms: u64| stamped(seq, &[RUN, 0x2000], at_ms * 1_000_000);
        // Written 50 ms ago: fresh.
        assert_eq!(p.gate.observe(look(&stamped(90, 5950))), None);
        // Written 150 ms ago (a paused controller's last sample, delivered now): stale.
        let change = p.gate.observe(look(&stamped(91, 5850)));
        assert!(matches!(
            change,
            Some(Transition::Latched { latch, .. }) if latch.reason == LatchReason::Stale
        ));
    }

    #[test]
    fn every_latch_has_a_new_id_above_the_last_in_monotonic_ns() {
        let mut p = Play::new();
        let startup = p.latch_id();
        assert_eq!(startup, 5_000_000_000, "the clock origin plus 0 ms");
        // Two latches at the same bus time still get two ids.
        let (_, first) = (p.poll(10, None, Some(StopCommand::Off1)), p.latch_id());
        let _ = p.gate.latch(LatchReason::LineRestored, ms(10));
        let second = p.latch_id();
        assert_eq!(first, 5_010_000_000);
        assert_eq!(second, first + 1);
        let Some(Transition::Latched { latch, .. }) =
            p.poll(20, None, Some(StopCommand::Off2)).change
        else {
            panic!("a stronger command is a new latch");
        };
        assert_eq!(latch.id, 5_020_000_000);
        // A gate on a virtual clock at 0 still never uses id 0 ("no latch").
        let gate = Gate::new(
            GateSetup {
                clock_origin: Duration::ZERO,
                ..setup()
            },
            ms(0),
        );
        assert!(matches!(gate.control(), Control::Latched(l) if l.id == 1));
    }

    #[test]
    fn a_restored_line_latches_a_live_drive() {
        let mut p = Play::running();
        let t = p.gate.latch(LatchReason::LineRestored, ms(50));
        assert_eq!(latched(Some(t)).0, LatchReason::LineRestored);
        assert_eq!(p.send(60, &[RUN, 0x2000]).words, [READY, 0]);
    }
}
