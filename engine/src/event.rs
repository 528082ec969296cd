//! What the bus thread tells the housekeeping thread ([`Event`]): sent over a bounded channel,
//! dropped and counted when it lags.

use crate::control::Latch;
use crate::reference;
use crate::stats::{LastFailure, LineFailure};
use core::time::Duration;
use uss_protocol::Address;
use uss_shm_types::{Monitoring, Rejection};

/// Something the housekeeping thread should know (and log).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    DriveOffline {
        address: Address,
        at: Duration,
        failure: LastFailure,
    },
    DriveOnline {
        address: Address,
        at: Duration,
    },
    /// The drive latched (stale controller, refused sample, release, operator stop, ...), or
    /// a latched drive got a new cause: it gets `latch.command` until its controller re-arms.
    Latched {
        address: Address,
        latch: Latch,
        rejection: Rejection,
    },
    /// The controller sent a stop naming the latch (OFF1, or the latch's own stop): its words
    /// go to the drive again.
    Rearmed {
        address: Address,
        at: Duration,
        pid: u32,
    },
    /// What the drive's reference frequency was found to be.
    Reference {
        address: Address,
        at: Duration,
        reference: reference::Reference,
        /// The configuration's `reference_hz`.
        configured_hz: f32,
    },
    /// What the drive's own telegram monitoring was found to be.
    Monitoring {
        address: Address,
        at: Duration,
        state: Monitoring,
        ms: u32,
        /// The shortest time that does not trip the drive between two of its polls.
        shortest_ms: u32,
    },
    CycleOverrun {
        at: Duration,
        took: Duration,
    },
    /// The bus line failed: every drive is offline, every pending job ended.
    LineDown {
        at: Duration,
        fault: LineFailure,
    },
    /// The line is back: every drive is latched and probed.
    LineUp {
        at: Duration,
        down_for: Duration,
    },
    /// An attempt failed and the poll tries again (`attempt` is the retry's number, from 1).
    Retry {
        address: Address,
        at: Duration,
        attempt: u8,
        failure: LastFailure,
    },
    /// The drive's state from its ZSW1 (S1..S5, fault) changed; `from` is `None` for its first
    /// reply.
    /// The drive's ZSW1 bit 9 ("control requested") changed, or was clear at the first
    /// reply: `taken` false means the drive does not take its commands from this link (its
    /// command source is elsewhere): ussd's control words, stops included, are ignored.
    Commands {
        address: Address,
        at: Duration,
        taken: bool,
    },
    StateChanged {
        address: Address,
        at: Duration,
        from: Option<uss_protocol::DriveState>,
        to: uss_protocol::DriveState,
    },
}
