//! The fault injector: per drive, by probability or as a scripted sequence, it spoils replies the
//! way a real bus does (USS.md sections 4 and 9), or unplugs the drive for a while.

use core::time::Duration;
use rand::Rng;
use std::collections::VecDeque;
use uss_protocol::MAX_RESPONSE_DELAY;
use uss_protocol::telegram::bcc;

/// One way to spoil a reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Fault {
    /// No reply at all (the master sees a response timeout).
    DropReply,
    /// Two bits of the BCC flipped: parity still holds, the BCC check fails.
    CorruptBcc,
    /// One bit of one byte flipped: that character has a parity error (and the BCC fails).
    CorruptByte,
    /// The reply stops part way (residual time exceeded at the master).
    Truncate,
    /// The reply comes after the 20 ms response limit.
    Late,
    /// The reply carries the next address up (the wrong slave answered).
    WrongAddress,
    /// Line noise right before the STX, with no start pause.
    Noise,
}

impl Fault {
    pub const ALL: [Fault; 7] = [
        Fault::DropReply,
        Fault::CorruptBcc,
        Fault::CorruptByte,
        Fault::Truncate,
        Fault::Late,
        Fault::WrongAddress,
        Fault::Noise,
    ];

    /// The name used on the `uss-sim` command line.
    pub const fn name(self) -> &'static str {
        match self {
            Fault::DropReply => "drop",
            Fault::CorruptBcc => "bcc",
            Fault::CorruptByte => "byte",
            Fault::Truncate => "truncate",
            Fault::Late => "late",
            Fault::WrongAddress => "wrong-addr",
            Fault::Noise => "noise",
        }
    }

    pub fn from_name(name: &str) -> Option<Fault> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }

    const fn index(self) -> usize {
        self as usize
    }
}

/// Longest noise burst, in bytes.
pub const MAX_NOISE: usize = 8;

/// A reply on its way to the master, possibly spoilt.
#[derive(Debug, Clone, Copy)]
pub struct Reply {
    buf: [u8; uss_protocol::telegram::MAX_TELEGRAM_BYTES + MAX_NOISE],
    len: usize,
    /// Time from the end of the request to the first byte (noise or STX).
    pub delay: Duration,
    /// Index of a character received with a parity error, if any.
    pub parity_error_at: Option<usize>,
    /// The fault applied, if any.
    pub fault: Option<Fault>,
}

impl Reply {
    /// A clean reply of `len` bytes taken from `bytes`.
    pub fn new(bytes: &[u8], delay: Duration) -> Self {
        let mut buf = [0; uss_protocol::telegram::MAX_TELEGRAM_BYTES + MAX_NOISE];
        let len = bytes.len().min(uss_protocol::telegram::MAX_TELEGRAM_BYTES);
        buf[..len].copy_from_slice(&bytes[..len]);
        Self {
            buf,
            len,
            delay,
            parity_error_at: None,
            fault: None,
        }
    }

    /// The bytes to put on the wire.
    pub fn bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

/// What to do to one drive's replies.
#[derive(Debug, Clone, Default)]
pub struct FaultPlan {
    probability: [f64; Fault::ALL.len()],
    script: VecDeque<Option<Fault>>,
    unplugged: Option<(Duration, Option<Duration>)>,
    /// From when on the line hangs (see [`FaultPlan::hang`]).
    hang_from: Option<Duration>,
    /// How far past the 20 ms limit a late reply comes.
    pub late_by: Duration,
    injected: [u64; Fault::ALL.len()],
}

impl FaultPlan {
    pub fn new() -> Self {
        Self {
            late_by: Duration::from_millis(5),
            ..Self::default()
        }
    }

    /// Each reply suffers `fault` with this probability (0..=1); faults are tried in
    /// [`Fault::ALL`] order and at most one applies.
    pub fn set_probability(&mut self, fault: Fault, probability: f64) {
        self.probability[fault.index()] = probability.clamp(0.0, 1.0);
    }

    pub fn probability(&self, fault: Fault) -> f64 {
        self.probability[fault.index()]
    }

    /// Queues a sequence: the next replies get these faults in order (`None` = clean), before
    /// any probabilities apply again.
    pub fn script(&mut self, faults: impl IntoIterator<Item = Option<Fault>>) {
        self.script.extend(faults);
    }

    /// Unplugs the drive from `from` on, for `duration` or until [`FaultPlan::plug`]. An unplugged
    /// drive neither hears nor answers.
    pub fn unplug(&mut self, from: Duration, duration: Option<Duration>) {
        self.unplugged = Some((from, duration.map(|d| from.saturating_add(d))));
    }

    pub fn plug(&mut self) {
        self.unplugged = None;
    }

    /// Hangs the whole line from `from` on, for good: on the in-process virtual wire the
    /// master's next send never returns (as with a wedged USB-serial driver); `uss-sim` stops
    /// reading and answering. For testing how a master supervises its bus threads.
    pub fn hang(&mut self, from: Duration) {
        self.hang_from = Some(from);
    }

    /// Whether the line hangs at `now`.
    pub fn hangs(&self, now: Duration) -> bool {
        self.hang_from.is_some_and(|from| now >= from)
    }

    /// Whether the drive is off the bus at `now`.
    pub fn is_unplugged(&self, now: Duration) -> bool {
        self.unplugged
            .is_some_and(|(from, until)| now >= from && until.is_none_or(|u| now < u))
    }

    /// How many replies suffered `fault` so far.
    pub fn injected(&self, fault: Fault) -> u64 {
        self.injected[fault.index()]
    }

    fn choose(&mut self, rng: &mut impl Rng) -> Option<Fault> {
        if let Some(scripted) = self.script.pop_front() {
            return scripted;
        }
        Fault::ALL.into_iter().find(|f| {
            self.probability[f.index()] > 0.0 && rng.random_bool(self.probability[f.index()])
        })
    }

    /// Applies the next fault, if any, to `reply`. Returns `None` when the reply is dropped.
    pub fn apply(&mut self, mut reply: Reply, rng: &mut impl Rng) -> Option<Reply> {
        let Some(fault) = self.choose(rng) else {
            return Some(reply);
        };
        self.injected[fault.index()] += 1;
        reply.fault = Some(fault);
        let len = reply.len;
        match fault {
            Fault::DropReply => return None,
            Fault::CorruptBcc => reply.buf[len - 1] ^= 0x81,
            Fault::CorruptByte => {
                let at = rng.random_range(1..len);
                reply.buf[at] ^= 1 << rng.random_range(0..8);
                reply.parity_error_at = Some(at);
            }
            Fault::Truncate => reply.len = rng.random_range(1..len),
            Fault::Late => {
                reply.delay = MAX_RESPONSE_DELAY + self.late_by;
            }
            Fault::WrongAddress => {
                let adr = reply.buf[2];
                reply.buf[2] = (adr & !0x1F) | ((adr + 1) & 0x1F);
                reply.buf[len - 1] = bcc(&reply.buf[..len - 1]);
            }
            Fault::Noise => {
                let n = rng.random_range(1..=MAX_NOISE);
                reply.buf.copy_within(..len, n);
                rng.fill(&mut reply.buf[..n]);
                reply.len = len + n;
            }
        }
        Some(reply)
    }
}
