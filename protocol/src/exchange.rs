//! One master exchange without I/O (USS.md section 4): when the next telegram may go (a start
//! pause after the line's last character), by when its reply must start (the response time the
//! master allows) and complete (the residual time, as the [`Framer`] judges it), and what each
//! character received means. The bus engine, `ussctl scan` (the client library's scan) and the
//! simulator's demo run their exchanges on it; each does its own I/O and its own bookkeeping.
//!
//! ```
//! # use core::time::Duration;
//! # use uss_protocol::{Adr, Address, Baud, Timing};
//! # use uss_protocol::exchange::{Exchange, Heard, Silence};
//! # use uss_protocol::framer::FramerConfig;
//! # use uss_protocol::telegram::encode;
//! let timing = Timing::new(Baud::new(19_200).unwrap());
//! let mut ex = Exchange::new(FramerConfig::strict(timing), Duration::ZERO);
//! let send_at = ex.send_at(); // a start pause after the line was last busy
//! let request_end = send_at + timing.telegram(14);
//! ex.sent(request_end, Duration::from_millis(20));
//! // The drive's reply, one character every character time, a start pause after the request.
//! let mut reply = [0u8; 32];
//! let n = encode(&mut reply, Adr::to(Address::new(3).unwrap()), &[], &[0x0B31, 0]).unwrap();
//! let mut at = request_end + timing.start_pause();
//! let mut got = None;
//! for &byte in &reply[..n] {
//!     assert!(at <= ex.deadline());
//!     if let Heard::Telegram { telegram, .. } = ex.heard(byte, None, at) {
//!         got = Some(telegram.adr().address.get());
//!     }
//!     at += timing.char_time();
//! }
//! assert_eq!(got, Some(3));
//! // Silence after a request: no reply.
//! ex.sent(ex.send_at() + timing.telegram(14), Duration::from_millis(20));
//! assert_eq!(ex.silence(), Silence::NoReply(None));
//! ```

use crate::framer::{FrameError, Framer, FramerConfig, LineError};
use crate::telegram::Telegram;
use crate::timing::Timing;
use core::time::Duration;

/// The master's side of one line: the receive framer, when the line last carried anything, and
/// the reply being waited for.
#[derive(Debug, Clone)]
pub struct Exchange {
    framer: Framer,
    /// When the line last carried anything (our request, a character received).
    free_at: Duration,
    /// By when the reply must start.
    reply_by: Duration,
    /// When the reply's STX came, once it did.
    stx_at: Option<Duration>,
    /// The first garbage before the reply (a reply may still follow it after a pause).
    garbage: Option<FrameError>,
}

/// What a character received meant.
#[derive(Debug, PartialEq, Eq)]
pub enum Heard<'a> {
    /// Part of a telegram, or garbage a reply may still follow: receive on, until
    /// [`Exchange::deadline`].
    More,
    /// A complete, checked telegram: from its STX at `stx_at` to its last character at `done`,
    /// and the first garbage that came before it, if any.
    Telegram {
        telegram: Telegram<'a>,
        stx_at: Duration,
        done: Duration,
        after_garbage: Option<FrameError>,
    },
    /// A reply broken beyond repair (a bad BCC or length, a character the UART flagged, one too
    /// late): let the line go quiet before the next request, so its rest is not taken for the
    /// next reply.
    Broken(FrameError),
}

/// Why the deadline passed without a telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Silence {
    /// A telegram began and did not complete within its residual time.
    Incomplete,
    /// None began; only garbage came, if this says so.
    NoReply(Option<FrameError>),
}

impl Exchange {
    /// An idle line, free since `free_at`, received by a framer of `config`.
    pub const fn new(config: FramerConfig, free_at: Duration) -> Self {
        Self {
            framer: Framer::new(config),
            free_at,
            reply_by: free_at,
            stx_at: None,
            garbage: None,
        }
    }

    /// The line's timing.
    pub const fn timing(&self) -> Timing {
        self.framer.config().timing
    }

    /// The framer's rules.
    pub const fn config(&self) -> &FramerConfig {
        self.framer.config()
    }

    /// Receives with `config` from now on (a line reopened with another latency), the line free
    /// since `free_at`.
    pub fn restart(&mut self, config: FramerConfig, free_at: Duration) {
        *self = Self::new(config, free_at);
    }

    /// When the next telegram may start: a start pause after the line last carried anything.
    pub fn send_at(&self) -> Duration {
        self.free_at + self.timing().start_pause()
    }

    /// When the line last carried anything.
    pub const fn free_at(&self) -> Duration {
        self.free_at
    }

    /// The line carried something until `at` (a character this side did not push, a reply on
    /// its way through an adapter that the next request must wait out).
    pub fn busy_until(&mut self, at: Duration) {
        self.free_at = self.free_at.max(at);
        self.framer.line_busy_until(at);
    }

    /// A request went out; its last character left at `end` (its echo read back, if the line
    /// has one: the line was busy until the request's computed end, not until the echo was
    /// delivered). Its reply must start by `end + reply_within`.
    pub fn sent(&mut self, end: Duration, reply_within: Duration) {
        self.framer.reset();
        self.framer.line_busy_until(end);
        self.free_at = end;
        self.reply_by = end + reply_within;
        self.stx_at = None;
        self.garbage = None;
    }

    /// Until when to receive: the reply's start, or once it started, its residual time.
    pub fn deadline(&self) -> Duration {
        self.framer.deadline().unwrap_or(self.reply_by)
    }

    /// Whether a telegram is partly received.
    pub const fn is_receiving(&self) -> bool {
        self.framer.is_receiving()
    }

    /// A character arrived at `at` (or one the UART flagged with `error`).
    pub fn heard(&mut self, byte: u8, error: Option<LineError>, at: Duration) -> Heard<'_> {
        self.free_at = self.free_at.max(at);
        let was_receiving = self.framer.is_receiving();
        if let Some(e) = error {
            return Heard::Broken(self.framer.push_line_error(e, at));
        }
        // What the character completed is taken from the framer once its state was looked at.
        let event = self.framer.push(byte, at).map(|r| r.map(|_| ()));
        if !was_receiving && self.framer.is_receiving() {
            self.stx_at = Some(at);
        }
        match event {
            None => Heard::More,
            Some(Ok(())) => Heard::Telegram {
                telegram: self.framer.completed(),
                stx_at: self.stx_at.unwrap_or(at),
                done: at,
                after_garbage: self.garbage,
            },
            Some(Err(e @ (FrameError::MissingStx(_) | FrameError::StartPauseNotObserved))) => {
                // Garbage before the reply: the reply may still follow after a pause.
                self.garbage.get_or_insert(e);
                Heard::More
            }
            Some(Err(e)) => Heard::Broken(e),
        }
    }

    /// The deadline passed with no telegram: why. A telegram begun is dropped.
    pub fn silence(&mut self) -> Silence {
        if self.framer.is_receiving() {
            self.framer.reset();
            Silence::Incomplete
        } else {
            Silence::NoReply(self.garbage)
        }
    }

    /// The line went quiet after a broken reply: whatever the framer held is dropped.
    pub fn quiet(&mut self) {
        self.framer.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::telegram::encode;
    use crate::{Address, Adr, Baud};

    fn timing() -> Timing {
        Timing::new(Baud::new(9600).unwrap())
    }

    fn reply(address: u8) -> ([u8; 32], usize) {
        let mut buf = [0u8; 32];
        let n = encode(
            &mut buf,
            Adr::to(Address::new(address).unwrap()),
            &[],
            &[0x0B31, 0x1000],
        )
        .unwrap();
        (buf, n)
    }

    /// Feeds `bytes` from `from`, a character time apart: what the last one meant (owned).
    fn feed(ex: &mut Exchange, bytes: &[u8], from: Duration) -> (String, Duration) {
        let c = ex.timing().char_time();
        let mut at = from;
        let mut said = String::from("more");
        for &b in bytes {
            said = match ex.heard(b, None, at) {
                Heard::More => "more".into(),
                Heard::Telegram {
                    telegram,
                    stx_at,
                    after_garbage,
                    ..
                } => format!(
                    "telegram from {} (stx at {:?}, garbage {:?})",
                    telegram.adr().address.get(),
                    stx_at.saturating_sub(from),
                    after_garbage.is_some()
                ),
                Heard::Broken(e) => format!("broken: {e}"),
            };
            at += c;
        }
        (said, at)
    }

    #[test]
    fn a_reply_in_time_is_a_telegram_and_moves_the_line_on() {
        let t = timing();
        let mut ex = Exchange::new(FramerConfig::strict(t), Duration::ZERO);
        assert_eq!(ex.send_at(), t.start_pause());
        let end = ex.send_at() + t.telegram(8);
        ex.sent(end, Duration::from_millis(20));
        assert_eq!(ex.deadline(), end + Duration::from_millis(20));
        let (bytes, n) = reply(3);
        let from = end + t.start_pause() + Duration::from_millis(2);
        let (said, _) = feed(&mut ex, &bytes[..n], from);
        assert_eq!(said, "telegram from 3 (stx at 0ns, garbage false)");
        // The next request waits a start pause after the reply's last character.
        let last = from + t.char_time() * u32::try_from(n - 1).unwrap();
        assert_eq!((ex.free_at(), ex.send_at()), (last, last + t.start_pause()));
    }

    #[test]
    fn once_a_reply_began_its_residual_time_is_the_deadline() {
        let t = timing();
        let mut ex = Exchange::new(FramerConfig::strict(t), Duration::ZERO);
        let end = ex.send_at() + t.telegram(8);
        ex.sent(end, Duration::from_millis(20));
        let (bytes, n) = reply(3);
        let from = end + t.start_pause() + Duration::from_millis(2);
        let _ = feed(&mut ex, &bytes[..3], from);
        assert!(ex.is_receiving());
        assert_eq!(ex.deadline(), from + t.max_residual(n - 4));
        // Nothing more came: the reply is incomplete, and the framer holds nothing of it.
        assert_eq!(ex.silence(), Silence::Incomplete);
        assert!(!ex.is_receiving());
    }

    #[test]
    fn garbage_before_a_reply_is_remembered_and_the_reply_still_taken() {
        let t = timing();
        let mut ex = Exchange::new(FramerConfig::strict(t), Duration::ZERO);
        let end = ex.send_at() + t.telegram(8);
        ex.sent(end, Duration::from_millis(50));
        let (said, at) = feed(&mut ex, &[0x55, 0xAA], end + t.start_pause());
        assert_eq!(said, "more");
        let (bytes, n) = reply(5);
        let (said, _) = feed(&mut ex, &bytes[..n], at + t.start_pause());
        assert_eq!(said, "telegram from 5 (stx at 0ns, garbage true)");
        // Garbage alone is a reply that did not come, with what came instead.
        ex.sent(ex.send_at() + t.telegram(8), Duration::from_millis(50));
        let from = ex.free_at() + t.start_pause();
        let _ = feed(&mut ex, &[0x55], from);
        assert_eq!(
            ex.silence(),
            Silence::NoReply(Some(FrameError::MissingStx(0x55)))
        );
        // A new request forgets it.
        ex.sent(ex.send_at() + t.telegram(8), Duration::from_millis(50));
        assert_eq!(ex.silence(), Silence::NoReply(None));
    }

    #[test]
    fn a_bad_bcc_or_a_flagged_character_breaks_the_reply() {
        let t = timing();
        let mut ex = Exchange::new(FramerConfig::strict(t), Duration::ZERO);
        let end = ex.send_at() + t.telegram(8);
        ex.sent(end, Duration::from_millis(20));
        let (mut bytes, n) = reply(3);
        bytes[n - 1] ^= 0xFF;
        let (said, _) = feed(&mut ex, &bytes[..n], end + t.start_pause());
        assert!(said.starts_with("broken: BCC"), "{said}");
        ex.quiet();
        ex.sent(ex.send_at() + t.telegram(8), Duration::from_millis(20));
        let at = ex.free_at() + t.start_pause();
        assert_eq!(
            ex.heard(0x02, Some(LineError::Parity), at),
            Heard::Broken(FrameError::Line(LineError::Parity))
        );
        assert_eq!(ex.free_at(), at);
    }

    #[test]
    fn a_reply_on_its_way_is_waited_out_and_a_restart_forgets_the_line() {
        let t = timing();
        let mut ex = Exchange::new(FramerConfig::strict(t), Duration::ZERO);
        ex.busy_until(Duration::from_millis(30));
        ex.busy_until(Duration::from_millis(10));
        assert_eq!(ex.send_at(), Duration::from_millis(30) + t.start_pause());
        let latency = Duration::from_millis(2);
        ex.restart(
            FramerConfig::with_latency(t, latency),
            Duration::from_secs(1),
        );
        assert_eq!(
            (ex.free_at(), ex.config().residual_slack),
            (Duration::from_secs(1), latency)
        );
    }

    /// What comes down the line in a property test: garbage, or an intact reply.
    #[derive(Debug, Clone)]
    enum Chunk {
        Garbage(std::vec::Vec<u8>),
        Reply(u8, std::vec::Vec<u16>),
    }

    fn chunk() -> impl proptest::strategy::Strategy<Value = Chunk> {
        use proptest::prelude::*;
        prop_oneof![
            proptest::collection::vec(any::<u8>(), 1..8).prop_map(Chunk::Garbage),
            (0u8..32, proptest::collection::vec(any::<u16>(), 0..5))
                .prop_map(|(a, w)| Chunk::Reply(a, w)),
        ]
    }

    proptest::proptest! {
        /// Garbage and intact replies in any order, after any pause: an intact reply after a
        /// start pause of silence (and no telegram of the garbage's still being received) is
        /// taken whole, as the very bytes sent, on its last character and not before.
        #[test]
        fn an_intact_reply_after_a_start_pause_is_taken_whatever_came_before(
            chunks in proptest::collection::vec((chunk(), 0u64..6_000), 1..12),
        ) {
            let t = timing();
            let c = t.char_time();
            let mut ex = Exchange::new(FramerConfig::strict(t), Duration::ZERO);
            let end = ex.send_at() + t.telegram(8);
            ex.sent(end, Duration::from_millis(20));
            let mut at = end;
            for (chunk, gap_us) in chunks {
                at += Duration::from_micros(gap_us);
                let paused = at.saturating_sub(ex.free_at()) >= t.start_pause();
                let expect = !ex.is_receiving() && paused;
                match chunk {
                    Chunk::Garbage(bytes) => {
                        for b in bytes {
                            let _ = ex.heard(b, None, at);
                            at += c;
                        }
                    }
                    Chunk::Reply(address, words) => {
                        let mut buf = [0u8; 32];
                        let n = encode(&mut buf, Adr::to(Address::new(address).unwrap()), &[], &words).unwrap();
                        for (k, &b) in buf[..n].iter().enumerate() {
                            let heard = ex.heard(b, None, at);
                            if !expect {
                                at += c;
                                continue;
                            }
                            if k + 1 < n {
                                proptest::prop_assert_eq!(&heard, &Heard::More, "byte {} of {:?}", k, &buf[..n]);
                            } else if let Heard::Telegram { telegram, done, .. } = heard {
                                proptest::prop_assert_eq!(telegram.as_bytes(), &buf[..n]);
                                proptest::prop_assert_eq!(done, at);
                            } else {
                                proptest::prop_assert!(false, "{:?} not taken: {:?}", &buf[..n], heard);
                            }
                            at += c;
                        }
                    }
                }
            }
        }
    }

    proptest::proptest! {
        /// Whatever comes down the line, in whatever rhythm: no panic, the line's last activity
        /// never goes back, the deadline is the reply's start limit while no telegram is being
        /// received, and a telegram given is one the codec parses as the same bytes.
        #[test]
        fn any_line_gives_an_exchange_that_keeps_its_rules(
            chars in proptest::collection::vec((proptest::prelude::any::<u8>(), 0u64..3_000, 0u8..40), 0..120),
        ) {
            let t = timing();
            let mut ex = Exchange::new(FramerConfig::strict(t), Duration::ZERO);
            let end = ex.send_at() + t.telegram(8);
            let within = Duration::from_millis(20);
            ex.sent(end, within);
            let mut at = end;
            for (byte, gap_us, kind) in chars {
                at += Duration::from_micros(gap_us);
                let before = ex.free_at();
                if !ex.is_receiving() {
                    proptest::prop_assert_eq!(ex.deadline(), end + within);
                }
                let error = match kind {
                    0 => Some(LineError::Parity),
                    1 => Some(LineError::Framing),
                    _ => None,
                };
                if let Heard::Telegram { telegram, stx_at, done, .. } = ex.heard(byte, error, at) {
                    let bytes = telegram.as_bytes();
                    let again = Telegram::parse(bytes);
                    proptest::prop_assert!(again.is_ok_and(|g| g.as_bytes() == bytes));
                    proptest::prop_assert!(stx_at <= done && done == at);
                }
                proptest::prop_assert!(ex.free_at() >= before && ex.free_at() >= at);
            }
            let _ = ex.silence();
            proptest::prop_assert!(!ex.is_receiving());
        }
    }
}
