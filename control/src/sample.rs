//! What a controller publishes for its drive, and what ussd takes of it, in the rules' terms. The
//! contract carries it as a `PzdOutput` (`uss-shm-types` converts both ways); ussd's [`Gate`]
//! and the client's [`Session`] speak these.
//!
//! [`Gate`]: crate::gate::Gate
//! [`Session`]: crate::session::Session

use crate::latch::Rejection;
use uss_protocol::Stw1;
pub use uss_protocol::telegram::MAX_PZD_WORDS;

/// The words a controller sends: STW1 first, `count` of them in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Words {
    pub words: [u16; MAX_PZD_WORDS],
    pub count: usize,
}

impl Words {
    /// `stw1` and every other of `count` words 0.
    pub const fn stop(count: usize, stw1: u16) -> Self {
        let mut words = [0; MAX_PZD_WORDS];
        words[0] = stw1;
        Self {
            words,
            count: if count < MAX_PZD_WORDS {
                count
            } else {
                MAX_PZD_WORDS
            },
        }
    }

    /// The words in use.
    pub fn as_slice(&self) -> &[u16] {
        &self.words[..self.count.min(MAX_PZD_WORDS)]
    }

    /// STW1.
    pub const fn stw1(&self) -> u16 {
        self.words[0]
    }

    /// Whether ussd sends these words to a drive with `pzd` PZD words: exactly that many, and
    /// (with PZD) STW1 bit 10 set, without which the drive ignores them, a stop included (USS.md
    /// section 7).
    pub const fn check(&self, pzd: usize) -> Result<(), Rejection> {
        if self.count != pzd || self.count > MAX_PZD_WORDS {
            return Err(Rejection::WordCount);
        }
        if pzd > 0 && !Stw1::from_bits_retain(self.words[0]).contains(Stw1::CONTROL_BY_PLC) {
            return Err(Rejection::NoPlcControl);
        }
        Ok(())
    }
}

/// What a sample asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Body {
    /// Send these words.
    Words(Words),
    /// The controller hands the drive back (a clean exit, not a crash).
    Release,
}

impl Body {
    /// What ussd takes of this body for a drive with `pzd` PZD words ([`Words::check`]; a
    /// release needs no words).
    pub const fn check(self, pzd: usize) -> Result<Self, Rejection> {
        match self {
            Self::Words(words) => match words.check(pzd) {
                Ok(()) => Ok(self),
                Err(e) => Err(e),
            },
            Self::Release => Ok(self),
        }
    }
}

/// One sample of a controller, as it makes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Sample {
    /// A new number for every sample (ussd takes a sample only when it changes; never 0).
    pub sequence: u64,
    /// When it was written, `CLOCK_MONOTONIC` ns (0: not said).
    pub timestamp_ns: u64,
    /// The controlling process.
    pub pid: u32,
    /// The latch this controller acknowledges (0: none). A stop re-arms a latched drive only
    /// when it names the drive's current latch.
    pub latch_id: u64,
    pub body: Body,
}

impl Sample {
    /// STW1 of the words, 0 for a release.
    pub const fn stw1(&self) -> u16 {
        match self.body {
            Body::Words(w) => w.stw1(),
            Body::Release => 0,
        }
    }

    /// The words, `None` for a release.
    pub const fn words(&self) -> Option<Words> {
        match self.body {
            Body::Words(w) => Some(w),
            Body::Release => None,
        }
    }

    /// Whether it hands the drive back.
    pub const fn is_release(&self) -> bool {
        matches!(self.body, Body::Release)
    }
}

/// A sample as ussd received it: what the contract could read of it ([`Received::body`] is the
/// refusal when it could not: another layout version, undefined flags, more than 16 words).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Received {
    pub sequence: u64,
    pub timestamp_ns: u64,
    pub pid: u32,
    pub latch_id: u64,
    pub body: Result<Body, Rejection>,
}

impl Received {
    /// What ussd takes of it for a drive with `pzd` PZD words.
    pub const fn check(&self, pzd: usize) -> Result<Body, Rejection> {
        match self.body {
            Ok(body) => body.check(pzd),
            Err(e) => Err(e),
        }
    }
}

impl From<Sample> for Received {
    /// A sample handed over whole (in one process, or read from a contract that carried it).
    fn from(s: Sample) -> Self {
        Self {
            sequence: s.sequence,
            timestamp_ns: s.timestamp_ns,
            pid: s.pid,
            latch_id: s.latch_id,
            body: Ok(s.body),
        }
    }
}
