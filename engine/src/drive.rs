//! One drive as the engine keeps it: everything the bus thread knows of a slot in one record
//! ([`Drive`]). Its setup, the gate that decides its words, its parameter mailbox, its link
//! state, what it last said, its counters and its timing. The published statistics are a
//! snapshot built from these records ([`Drive::status`]), never a second copy kept beside them.
//!
//! What other threads reach (the process images, operator stops) stays in the engine's shared
//! state, indexed by the same slot.

use super::control::Gate;
use super::jobs::Mailbox;
use super::reference::Reference;
use super::stats::{DriveHistograms, DriveStatus, LastFailure, Recorded, set_control};
use super::{DriveSetup, Event, monitoring};
use core::time::Duration;
use hdrhistogram::Histogram;
use uss_protocol::{Address, DriveState, Zsw1};
use uss_shm_types::{DriveCounters, Monitoring};

/// One drive as the engine keeps it. See the module documentation.
#[derive(Debug)]
pub(super) struct Drive {
    pub setup: DriveSetup,
    /// Decides the words that go out (`crate::control`).
    pub gate: Gate,
    pub mailbox: Mailbox,
    pub link: Link,
    /// ZSW1 and HIW of its last good reply.
    pub last_zsw1: u16,
    pub last_hiw: u16,
    /// STW1 and setpoint of the last telegram sent to it.
    pub sent: [u16; 2],
    /// Its counters, but the gate's (added to the snapshot from the gate itself).
    pub counters: DriveCounters,
    /// Its own telegram monitoring as read from it, and its time in ms.
    pub monitoring: Monitoring,
    pub monitoring_ms: u32,
    /// Its reference frequency as read from it.
    pub reference: Reference,
    /// Counts (mod 256) every change of what ussd knows of it that clients scale by: its
    /// reference forgotten (it came online, was reset or commissioned) or read anew. Published
    /// with the input image at once and with the diagnostics' description later
    /// (`uss_shm_types::DriveDiag::info_for`): a description of another count is not it.
    pub picture: u8,
    /// The last reference frequency read from it, Hz, kept while it is read again: a value
    /// that comes back different latches a drive under a controller (`crate::picture`).
    pub last_reference: Option<f32>,
    /// The telegram-monitoring parameter should be read (`crate::picture` says when).
    pub monitoring_due: bool,
    /// The reference-frequency parameter should be read.
    pub reference_due: bool,
    /// Its good replies when its background reads were last due (`crate::picture`).
    pub refreshed_at: u64,
    /// The shortest telegram-off time that does not trip the drive between two of its polls
    /// (`Periods::shortest_monitoring`).
    pub shortest_monitoring: Duration,
    /// How often it is polled, and after how long its image is stale, as of its last poll
    /// (`crate::period`).
    pub period: Duration,
    pub stale_after: Duration,
    /// Operator commands already taken: OFF1, OFF2, OFF3.
    pub overrides_seen: [u32; 3],
    pub timing: DriveTiming,
    /// The request sent to it before the one in flight.
    pub sent_before: SentBefore,
}

/// The request last sent to a drive before the one in flight, byte for byte. A line that hands
/// a request back one exchange late (a device server's buffer, an echo held over) gives the
/// master this one, which parses as the drive's reply from the right address (found by issue
/// 48's sweep: with a controller's setpoint changing every poll, an absent drive looked online,
/// its own STW1 as ZSW1, and parameter reads answered 0). Kept in place: no allocation.
#[derive(Debug, Clone)]
pub(super) struct SentBefore {
    bytes: [u8; uss_protocol::telegram::MAX_TELEGRAM_BYTES],
    len: usize,
}

impl SentBefore {
    pub const fn new() -> Self {
        Self {
            bytes: [0; uss_protocol::telegram::MAX_TELEGRAM_BYTES],
            len: 0,
        }
    }

    /// Whether `telegram` is that request.
    pub fn is(&self, telegram: &[u8]) -> bool {
        self.len > 0 && self.bytes[..self.len] == *telegram
    }

    /// Keeps `sent`, the request of the exchange that just ended.
    pub fn keep(&mut self, sent: &[u8]) {
        let len = sent.len().min(self.bytes.len());
        self.bytes[..len].copy_from_slice(&sent[..len]);
        self.len = len;
    }
}

/// Whether a drive answers, as one state: what its polls decided so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum LinkState {
    /// No poll has decided yet (`tried`: one failed, or the line went down, before any did).
    Unknown { tried: bool },
    /// It answers; `failing`: its latest polls failed, fewer than take it offline.
    Online { failing: bool },
    /// Its polls failed all their retries (USS.md section 4: "slave x does not respond"), or
    /// the line went down under it.
    Offline,
}

/// Whether a drive answers, since when, and when to try it again (USS.md section 4: "slave x
/// does not respond" after a poll fails all its retries). Published as the [`DriveStatus`]
/// fields `online`, `known`, `no_reply`, `since`, ..., which say what each means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Link {
    pub state: LinkState,
    pub since: Duration,
    pub last_failure: LastFailure,
    pub consecutive_failed_polls: u32,
    pub last_good: Option<Duration>,
    /// When an offline drive is probed next.
    pub next_probe: Duration,
}

impl Link {
    /// Unknown until the first poll decides.
    fn new() -> Self {
        Self {
            state: LinkState::Unknown { tried: false },
            since: Duration::ZERO,
            last_failure: LastFailure::None,
            consecutive_failed_polls: 0,
            last_good: None,
            next_probe: Duration::ZERO,
        }
    }

    /// Whether it answers.
    pub const fn online(&self) -> bool {
        matches!(self.state, LinkState::Online { .. })
    }

    /// Whether a poll has decided `online` yet.
    pub const fn known(&self) -> bool {
        !matches!(self.state, LinkState::Unknown { .. })
    }

    /// Whether its latest poll failed (or the line went down).
    pub const fn no_reply(&self) -> bool {
        match self.state {
            LinkState::Unknown { tried } => tried,
            LinkState::Online { failing } => failing,
            LinkState::Offline => true,
        }
    }

    /// A good reply completed `at`; returns the time since the previous one, and whether the
    /// drive came (back) online with it.
    pub fn good(&mut self, at: Duration) -> (Option<Duration>, bool) {
        let since_last = self.last_good.map(|previous| at.saturating_sub(previous));
        self.last_good = Some(at);
        self.consecutive_failed_polls = 0;
        let came_back = !self.online();
        if came_back {
            self.since = at;
        }
        self.state = LinkState::Online { failing: false };
        (since_last, came_back)
    }

    /// A poll failed all its retries at `now`; returns whether that takes the drive offline: a
    /// drive of unknown state with its first failed poll, an online one after `offline_after`
    /// in a row. It is probed again after `probe`.
    pub fn failed(&mut self, now: Duration, offline_after: u32, probe: Duration) -> bool {
        self.consecutive_failed_polls += 1;
        self.next_probe = now + probe;
        let decides = match self.state {
            LinkState::Unknown { .. } => true,
            LinkState::Online { .. } => self.consecutive_failed_polls >= offline_after,
            LinkState::Offline => false,
        };
        self.state = match self.state {
            _ if decides => {
                self.since = now;
                LinkState::Offline
            }
            LinkState::Online { .. } => LinkState::Online { failing: true },
            other => other,
        };
        decides
    }

    /// The line went down at `now`: nothing answers.
    pub fn line_down(&mut self, now: Duration) {
        self.state = match self.state {
            LinkState::Online { .. } => {
                self.since = now;
                LinkState::Offline
            }
            LinkState::Unknown { .. } => LinkState::Unknown { tried: true },
            LinkState::Offline => LinkState::Offline,
        };
    }
}

/// What a drive's good reply said that is news: events, as values, for the engine to emit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct Said {
    /// ZSW1 bit 9 ("control requested") changed, or was clear at the first reply: whether the
    /// drive takes its commands from this link.
    pub commands: Option<bool>,
    /// Its state changed (from `None` at the first reply).
    pub state: Option<(Option<DriveState>, DriveState)>,
}

impl Said {
    /// The events, in the order the engine emits them.
    pub fn events(self, address: Address, at: Duration) -> impl Iterator<Item = Event> {
        let commands = self
            .commands
            .map(|taken| Event::Commands { address, at, taken });
        let state = self.state.map(|(from, to)| Event::StateChanged {
            address,
            at,
            from,
            to,
        });
        commands.into_iter().chain(state)
    }
}

/// A drive's timing: its exchanges, its response delays, the time between two good replies.
#[derive(Debug, Clone)]
pub(super) struct DriveTiming {
    pub exchange: Recorded,
    pub response_delay: Recorded,
    pub update_period: Recorded,
}

impl DriveTiming {
    fn new() -> Self {
        Self {
            exchange: Recorded::drive(),
            response_delay: Recorded::drive(),
            update_period: Recorded::bus(),
        }
    }

    /// Everything recorded, as published: the drive's histograms and its update period.
    pub fn totals(&self) -> (DriveHistograms, Histogram<u64>) {
        let histograms = DriveHistograms {
            exchange: self.exchange.total.clone(),
            response_delay: self.response_delay.total.clone(),
        };
        (histograms, self.update_period.total.clone())
    }

    /// Hands what was recorded since the last hand-over to the published copy's empty
    /// histograms of this drive ([`Recorded::hand_over`]).
    pub fn hand_over(
        &mut self,
        histograms: &mut DriveHistograms,
        update_period: &mut Histogram<u64>,
    ) {
        self.exchange.hand_over(&mut histograms.exchange);
        self.response_delay
            .hand_over(&mut histograms.response_delay);
        self.update_period.hand_over(update_period);
    }
}

impl Drive {
    /// A drive with its gate as it starts, unknown, before its first poll.
    pub fn new(setup: DriveSetup, gate: Gate, mailbox_depth: usize, shortest: Duration) -> Self {
        Self {
            setup,
            gate,
            mailbox: Mailbox::new(mailbox_depth),
            link: Link::new(),
            last_zsw1: 0,
            last_hiw: 0,
            sent: [0; 2],
            counters: DriveCounters::default(),
            monitoring: monitoring::initial_monitoring(&setup),
            monitoring_ms: 0,
            reference: Reference::initial(&setup),
            picture: 0,
            last_reference: None,
            monitoring_due: false,
            reference_due: false,
            refreshed_at: 0,
            shortest_monitoring: shortest,
            period: Duration::ZERO,
            stale_after: Duration::ZERO,
            overrides_seen: [0; 3],
            sent_before: SentBefore::new(),
            timing: DriveTiming::new(),
        }
    }

    /// A good reply's process data: what it says that is news; remembers ZSW1 and HIW.
    /// `first`: the drive's first good reply.
    pub fn heard(&mut self, pzd: &[u16], first: bool) -> Said {
        let Some(&zsw1) = pzd.first() else {
            self.last_zsw1 = 0;
            self.last_hiw = 0;
            return Said::default();
        };
        let state = |z| DriveState::from_zsw1(Zsw1::from_bits_retain(z));
        let taken = |z: u16| Zsw1::from_bits_retain(z).contains(Zsw1::CONTROL_REQUESTED);
        let from = (!first).then(|| state(self.last_zsw1));
        let took = (!first).then(|| taken(self.last_zsw1));
        // Said when it changes, and at the first reply only when the drive does not take them.
        let commands =
            (took != Some(taken(zsw1)) && (took.is_some() || !taken(zsw1))).then_some(taken(zsw1));
        let to = state(zsw1);
        self.last_zsw1 = zsw1;
        self.last_hiw = pzd.get(1).copied().unwrap_or(0);
        Said {
            commands,
            state: (from != Some(to)).then_some((from, to)),
        }
    }

    /// An attempt failed with `failure`: counted as the drive counts a telegram it refuses.
    pub fn attempt_failed(&mut self, failure: LastFailure) {
        self.counters.rejected += 1;
        self.counters.count(failure);
    }

    /// The drive as published: a snapshot of this record, the gate's state and counters
    /// included.
    pub fn status(&self) -> DriveStatus {
        let mut counters = self.counters;
        set_control(&mut counters, &self.gate.counters());
        DriveStatus {
            address: self.setup.address,
            online: self.link.online(),
            known: self.link.known(),
            since: self.link.since,
            no_reply: self.link.no_reply(),
            last_failure: self.link.last_failure,
            consecutive_failed_polls: self.link.consecutive_failed_polls,
            last_zsw1: self.last_zsw1,
            last_hiw: self.last_hiw,
            last_good: self.link.last_good,
            control: self.gate.control(),
            rejection: self.gate.rejection(),
            controller_pid: self.gate.controller_pid(),
            sent: self.sent,
            taken_sequence: self.gate.taken_sequence(),
            monitoring: self.monitoring,
            monitoring_ms: self.monitoring_ms,
            reference: self.reference,
            picture: self.picture,
            period: self.period,
            stale_after: self.stale_after,
            monitoring_min: self.shortest_monitoring,
            counters,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn an_unknown_drive_is_offline_with_its_first_failed_poll_an_online_one_after_several() {
        let mut link = Link::new();
        assert!(link.failed(ms(10), 3, ms(500)), "unknown: decided at once");
        assert_eq!(
            (link.online(), link.known(), link.next_probe),
            (false, true, ms(510))
        );
        assert_eq!(
            link.good(ms(20)),
            (None, true),
            "back with its first good reply"
        );
        assert_eq!(link.good(ms(30)), (Some(ms(10)), false));
        assert!(!link.failed(ms(40), 3, ms(500)));
        assert!(!link.failed(ms(50), 3, ms(500)));
        assert!(link.no_reply() && link.online());
        assert_eq!(link.state, LinkState::Online { failing: true });
        assert!(link.failed(ms(60), 3, ms(500)), "the third in a row");
        assert_eq!((link.state, link.since), (LinkState::Offline, ms(60)));
        link.line_down(ms(70));
        assert_eq!(
            link.since,
            ms(60),
            "offline since its last poll, not the line's fall"
        );
    }

    #[test]
    fn a_reply_says_a_state_change_and_a_drive_that_does_not_take_its_commands() {
        use uss_protocol::Layout;
        let setup = DriveSetup::new(
            Address::new(1).unwrap(),
            Layout::new(
                uss_protocol::PkwMode::Four,
                uss_protocol::PzdCount::new(2).unwrap(),
            ),
        );
        let gate = Gate::new(
            super::super::control::GateSetup {
                pzd: 2,
                safe: setup.safe,
                watchdog: setup.watchdog,
                clock_origin: Duration::ZERO,
            },
            Duration::ZERO,
        );
        let mut d = Drive::new(setup, gate, 1, ms(10));
        let ready = Zsw1::READY_TO_SWITCH_ON | Zsw1::CONTROL_REQUESTED;
        let first = d.heard(&[ready.bits(), 0], true);
        assert_eq!(first.commands, None, "takes them: nothing to say");
        assert!(matches!(first.state, Some((None, _))));
        assert_eq!(d.heard(&[ready.bits(), 7], false), Said::default());
        assert_eq!(d.last_hiw, 7);
        let local = d.heard(&[Zsw1::READY_TO_SWITCH_ON.bits(), 0], false);
        assert_eq!(local.commands, Some(false), "its command source moved");
        assert_eq!(
            local.events(setup.address, ms(1)).count(),
            1,
            "same state, commands only"
        );
    }
}
