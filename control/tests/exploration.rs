//! The client's rules ([`Session`]) and ussd's ([`Gate`]) explored together over
//! every sequence of events, breadth first, repeated states merged (docs/SAFETY.md,
//! "Exploration"). A plain breadth-first search rather than a model-checking crate
//! (`stateright`): the model is two real types and ten events, the search is forty lines, and
//! its depth and state count are printed by the test itself.
//!
//! Events: a controller opens (a new one replaces the one before without a release, as a
//! killed process's successor does), keepalive, run, the deliberate act that asks for a re-arm
//! (its time travels with the re-arm), re-arm, stop, release, a refresher's turn,
//! an operator's coast, a gap in time longer than the watchdog, and a poll of the bus thread
//! (which takes the newest sample and operator command and publishes the image the clients
//! read). After every step:
//! - no telegram without STW1 bit 10;
//! - no ON (a word that runs the motor) on the wire unless the live period it belongs to began
//!   by re-arming a latch that an explicit re-arm call acknowledged while the image showed it,
//!   asked for after that latch was made: so opening, reconnecting, a keepalive, a refresher, a
//!   stop never re-arm, an operator's stop is never undone by any of them, and a stop that lands
//!   between the ask and the re-arm call wins.
#![allow(clippy::unwrap_used)]

use std::collections::HashSet;
use std::time::Duration;
use uss_control::{
    Control, ControllerId, DriveImage, Gate, GateSetup, LatchView, MAX_PZD_WORDS, Operator, Poll,
    Received, Sample, Session, SessionSetup, Step, StopCommand, Words, is_stop,
};

const WATCHDOG_MS: u64 = 100;
const RUN: u16 = 0x047F;
const OFF1: u16 = 0x047E;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Event {
    Open,
    Keepalive,
    Run,
    /// The deliberate act that asks for a re-arm (a program's start, a pin's edge): its time
    /// travels with the re-arm call that follows.
    Ask,
    Rearm,
    Stop,
    Release,
    Refresh,
    Coast,
    Gap,
    Poll,
}

const EVENTS: [Event; 11] = [
    Event::Open,
    Event::Keepalive,
    Event::Run,
    Event::Ask,
    Event::Rearm,
    Event::Stop,
    Event::Release,
    Event::Refresh,
    Event::Coast,
    Event::Gap,
    Event::Poll,
];

/// One ussd drive and the controller of the moment, with what is on the way between them.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
struct World {
    gate: Gate,
    /// The controller and who it is to ussd (its publisher).
    session: Option<(Session, u128)>,
    controllers: u128,
    now_ms: u64,
    /// The newest sample not yet taken by the bus thread (the service keeps the latest only).
    pending: Option<(Sample, u128)>,
    operator: Option<StopCommand>,
    /// What the clients read: the image of the last poll.
    image: LatchView,
    /// When the last deliberate act asked for a re-arm, and the newest latch made by then.
    asked: Option<(u64, u64)>,
    /// The newest latch id ussd made so far (0: none).
    newest_latch: u64,
    /// Latch ids an explicit re-arm call acknowledged while the image showed them, asked for
    /// after they began.
    rearmed: Vec<u64>,
    /// The latch the drive's current live period began by re-arming.
    live_from: Option<u64>,
    /// Whether an ON reached the wire on the way here (the search must reach one).
    ran: bool,
}

/// The input image as the clients read it.
fn image_of(gate: &Gate) -> LatchView {
    match gate.control() {
        Control::Live => LatchView::LIVE,
        Control::Latched(l) => LatchView::latched(l.id, l.command),
    }
}

impl World {
    fn new() -> Self {
        let setup = GateSetup {
            pzd: 2,
            safe: StopCommand::Off1,
            watchdog: Duration::from_millis(WATCHDOG_MS),
            clock_origin: Duration::ZERO,
        };
        let gate = Gate::new(setup, Duration::ZERO);
        let image = image_of(&gate);
        Self {
            gate,
            session: None,
            controllers: 0,
            now_ms: 0,
            pending: None,
            operator: None,
            image,
            asked: None,
            newest_latch: image.latch.unwrap_or(0),
            rearmed: Vec::new(),
            live_from: None,
            ran: false,
        }
    }

    fn now_ns(&self) -> u64 {
        self.now_ms * 1_000_000
    }

    /// A call of the controller that changes its words with `change`.
    fn publish(&mut self, change: impl FnOnce(&mut Words)) {
        let (now, image) = (self.now_ns(), self.image);
        if let Some((s, id)) = self.session.as_mut()
            && let Ok(Step::Publish(sample)) = s.publish(now, &image, change)
        {
            self.pending = Some((sample, *id));
        }
    }

    /// The world after `event`; `Err` names a broken invariant.
    fn after(&self, event: Event) -> Result<Self, String> {
        let mut w = self.clone();
        let (now, image) = (w.now_ns(), w.image);
        match event {
            Event::Open => {
                w.controllers += 1;
                let setup = SessionSetup {
                    pzd: 2,
                    pid: 7,
                    watchdog_ns: WATCHDOG_MS * 1_000_000,
                    first_sequence: u64::try_from(w.controllers).unwrap() * 1000,
                };
                w.session = Some((Session::new(setup), w.controllers));
            }
            Event::Keepalive => w.publish(|_| {}),
            Event::Run => w.publish(|words| {
                words.words[0] = RUN;
                words.words[1] = 0x2000;
            }),
            Event::Stop => w.publish(|words| words.words[0] = OFF1),
            Event::Ask => {
                // Time goes on around the act: every latch so far began before it, every latch
                // after it begins later.
                w.now_ms += 1;
                w.asked = Some((w.now_ns(), w.newest_latch));
                w.now_ms += 1;
            }
            Event::Rearm => {
                if let Some((s, id)) = w.session.as_mut()
                    && let Some((asked_ns, newest_then)) = w.asked
                    && let Ok(sample) = s.rearm(now, &image, asked_ns)
                {
                    w.pending = Some((sample, *id));
                    // The oracle is the order of events, not the clock: only a latch made by
                    // the time of the ask may be re-armed by it.
                    if let Some(latch) = image.latch().filter(|&l| l <= newest_then) {
                        w.rearmed.push(latch);
                        w.rearmed.sort_unstable();
                        w.rearmed.dedup();
                    }
                }
            }
            Event::Release => {
                if let Some((mut s, id)) = w.session.take() {
                    w.pending = Some((s.release(now), id));
                }
            }
            Event::Refresh => {
                if let Some((s, id)) = w.session.as_mut()
                    && let Some(sample) = s.refresh(now, &image)
                {
                    w.pending = Some((sample, *id));
                }
            }
            Event::Coast => w.operator = Some(StopCommand::Off2),
            Event::Gap => w.now_ms += WATCHDOG_MS + 1,
            Event::Poll => w.poll()?,
        }
        Ok(w)
    }

    /// The bus thread's look and telegram, and the invariants on what went out.
    fn poll(&mut self) -> Result<(), String> {
        let before = self.gate.control();
        let (sample, from) = self.pending.take().unzip();
        let sample = sample.map(Received::from);
        let mut out = [0u16; MAX_PZD_WORDS];
        self.gate.decide(
            Poll {
                now: Duration::from_millis(self.now_ms),
                gap: Duration::ZERO,
                sample: sample.as_ref(),
                from: ControllerId(from.unwrap_or_default()),
                operator: self
                    .operator
                    .take()
                    .map(|command| Operator { command, pid: 9 }),
                on_allowed: true,
            },
            &mut out,
        );
        match (before, self.gate.control()) {
            (Control::Latched(l), Control::Live) => self.live_from = Some(l.id),
            (_, Control::Latched(_)) => self.live_from = None,
            _ => {}
        }
        self.image = image_of(&self.gate);
        self.newest_latch = self.newest_latch.max(self.image.latch.unwrap_or(0));
        if out[0] & 0x0400 == 0 {
            return Err(format!("a telegram without STW1 bit 10: {:#06x}", out[0]));
        }
        if !is_stop(out[0]) {
            self.ran = true;
        }
        if !is_stop(out[0]) && !self.live_from.is_some_and(|l| self.rearmed.contains(&l)) {
            return Err(format!(
                "ON {:#06x} on the wire in a live period that began with latch {:?}, which no explicit re-arm acknowledged ({:?})",
                out[0], self.live_from, self.rearmed
            ));
        }
        Ok(())
    }
}

#[test]
fn no_on_reaches_the_wire_after_a_latch_without_an_explicit_re_arm_after_it() {
    const DEPTH: usize = 10;
    let mut seen: HashSet<World> = HashSet::new();
    let mut level = vec![(World::new(), Vec::<Event>::new())];
    seen.insert(level[0].0.clone());
    let mut on_seen = false;
    for depth in 1..=DEPTH {
        let mut next = Vec::new();
        for (world, path) in &level {
            for event in EVENTS {
                let mut steps = path.clone();
                steps.push(event);
                let w = world
                    .after(event)
                    .unwrap_or_else(|broken| panic!("{broken}\nafter {steps:?}"));
                on_seen |= w.ran;
                if seen.insert(w.clone()) {
                    next.push((w, steps));
                }
            }
        }
        println!(
            "exploration: depth {depth}: {} new states, {} in all",
            next.len(),
            seen.len()
        );
        level = next;
    }
    // The search reaches what it must: an ON on the wire after its controller's re-arm.
    assert!(on_seen, "no sequence ran the drive: the model is broken");
    println!(
        "exploration: every sequence of {} events to depth {DEPTH}: {} distinct states, no invariant broken",
        EVENTS.len(),
        seen.len()
    );
}
