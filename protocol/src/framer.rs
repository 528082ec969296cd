//! The incremental receive framer (USS.md sections 3 and 4).
//!
//! Feed it bytes as they arrive, each with its arrival time; it yields complete, checked telegrams
//! or typed errors, and resynchronises by itself after any error: a telegram only starts with an
//! STX that follows at least a start pause of line silence, so after garbage or a broken telegram
//! it waits for the next pause. It never panics and holds at most one telegram (256 bytes).

use crate::telegram::{MAX_NET_BYTES, MAX_TELEGRAM_BYTES, STX, Telegram, bcc};
use crate::timing::Timing;
use core::time::Duration;
use thiserror::Error;

/// A character the UART reported as broken (USS.md section 4, receive errors).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LineError {
    Parity,
    Framing,
    Overrun,
}

/// What went wrong while receiving. Every error leaves the framer waiting for the next start.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum FrameError {
    #[error(
        "byte 0x{0:02X} arrived where an STX after a start pause was expected (garbage before start)"
    )]
    MissingStx(u8),
    #[error("STX arrived without the start pause of 2 character times")]
    StartPauseNotObserved,
    #[error("LGE {0} is out of range 2..=254")]
    BadLge(u8),
    #[error("BCC 0x{actual:02X} received, 0x{expected:02X} computed")]
    Bcc { expected: u8, actual: u8 },
    #[error("telegram took {elapsed:?} after its STX, more than the allowed {allowed:?}")]
    ResidualTimeExceeded {
        allowed: Duration,
        elapsed: Duration,
    },
    #[error("{0:?} error reported by the line")]
    Line(LineError),
}

/// How strictly the framer applies the timing rules.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FramerConfig {
    pub timing: Timing,
    /// Only accept an STX after a start pause (the specification). Turn off only for links that
    /// carry no timing at all.
    pub require_start_pause: bool,
    /// Added to the residual-time limit, for adapters that deliver bytes in late bursts (USB).
    pub residual_slack: Duration,
    /// Taken off the start pause an STX must follow, for the same adapters: bytes read
    /// together seem closer than they were on the wire.
    pub start_pause_slack: Duration,
}

impl FramerConfig {
    /// The rules of USS.md section 4, with no slack.
    pub const fn strict(timing: Timing) -> Self {
        Self {
            timing,
            require_start_pause: true,
            residual_slack: Duration::ZERO,
            start_pause_slack: Duration::ZERO,
        }
    }

    /// The rules of USS.md section 4 judged on bytes an adapter delivers up to `latency` late
    /// and in packets: the residual-time limit widened and the start pause shortened by
    /// exactly that much.
    pub const fn with_latency(timing: Timing, latency: Duration) -> Self {
        Self {
            timing,
            require_start_pause: true,
            residual_slack: latency,
            start_pause_slack: latency,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Between telegrams: the next byte should be an STX after a pause.
    Idle,
    /// Inside a run of bytes that is not a telegram; silently consumed until a pause.
    Garbage,
    /// Receiving a telegram whose STX arrived at `stx_at`.
    Receiving { stx_at: Duration, allowed: Duration },
}

/// The incremental receive framer. See the module documentation.
#[derive(Debug, Clone)]
pub struct Framer {
    config: FramerConfig,
    buf: [u8; MAX_TELEGRAM_BYTES],
    len: usize,
    state: State,
    last_activity: Option<Duration>,
}

impl Framer {
    pub const fn new(config: FramerConfig) -> Self {
        Self {
            config,
            buf: [0; MAX_TELEGRAM_BYTES],
            len: 0,
            state: State::Idle,
            last_activity: None,
        }
    }

    pub const fn config(&self) -> &FramerConfig {
        &self.config
    }

    /// Drops any partial telegram (the master flushes input before each request). The line
    /// activity time is kept, so the start pause is still enforced.
    pub fn reset(&mut self) {
        self.len = 0;
        self.state = State::Idle;
    }

    /// Records that the line carried traffic (for example our own transmission) until `at`, so the
    /// start pause counts from then.
    pub fn line_busy_until(&mut self, at: Duration) {
        self.last_activity = Some(self.last_activity.map_or(at, |t| t.max(at)));
    }

    /// Whether a telegram is partly received.
    pub const fn is_receiving(&self) -> bool {
        matches!(self.state, State::Receiving { .. })
    }

    /// The time by which the telegram being received must be complete, if one is.
    pub const fn deadline(&self) -> Option<Duration> {
        match self.state {
            State::Receiving { stx_at, allowed } => Some(stx_at.saturating_add(allowed)),
            _ => None,
        }
    }

    /// Checks the residual-time limit with no byte arriving: call when a deadline passes.
    pub fn poll(&mut self, now: Duration) -> Option<FrameError> {
        if let State::Receiving { stx_at, allowed } = self.state {
            let elapsed = now.saturating_sub(stx_at);
            if elapsed > allowed {
                self.abort();
                return Some(FrameError::ResidualTimeExceeded { allowed, elapsed });
            }
        }
        None
    }

    /// Reports a character the UART flagged as broken; a telegram in progress is lost.
    pub fn push_line_error(&mut self, error: LineError, at: Duration) -> FrameError {
        self.line_busy_until(at);
        self.abort();
        FrameError::Line(error)
    }

    /// Feeds one byte that arrived at `at`. Returns a telegram when this byte completes one, an
    /// error when this byte reveals one, and `None` otherwise.
    pub fn push(&mut self, byte: u8, at: Duration) -> Option<Result<Telegram<'_>, FrameError>> {
        let pause = self
            .config
            .timing
            .start_pause()
            .saturating_sub(self.config.start_pause_slack);
        let paused = self
            .last_activity
            .is_none_or(|t| at.saturating_sub(t) >= pause);
        self.line_busy_until(at);
        match self.state {
            State::Receiving { stx_at, allowed } => {
                let elapsed = at.saturating_sub(stx_at);
                if elapsed > allowed {
                    let err = FrameError::ResidualTimeExceeded { allowed, elapsed };
                    self.abort();
                    // The late byte may itself start the next telegram.
                    if byte == STX && paused {
                        self.start(at);
                    }
                    return Some(Err(err));
                }
                self.receive(byte, stx_at)
            }
            State::Idle | State::Garbage => {
                let may_start = paused || !self.config.require_start_pause;
                if byte == STX && may_start {
                    self.start(at);
                    None
                } else if self.state == State::Garbage && !paused {
                    None
                } else {
                    self.state = State::Garbage;
                    Some(Err(if byte == STX {
                        FrameError::StartPauseNotObserved
                    } else {
                        FrameError::MissingStx(byte)
                    }))
                }
            }
        }
    }

    /// The telegram the last [`Framer::push`] completed (it stays in the buffer until the next
    /// character): for a caller that must look at the framer again before it takes the
    /// telegram. Only after a push that returned `Some(Ok(_))`.
    pub(crate) fn completed(&self) -> Telegram<'_> {
        let total = (usize::from(self.buf[1]) + 2).min(MAX_TELEGRAM_BYTES);
        Telegram::checked_by_framer(&self.buf[..total])
    }

    fn start(&mut self, at: Duration) {
        self.buf[0] = STX;
        self.len = 1;
        // Until LGE arrives the timer is armed for the longest telegram (USS.md section 4).
        self.state = State::Receiving {
            stx_at: at,
            allowed: self.allowed(MAX_NET_BYTES),
        };
    }

    fn allowed(&self, net: usize) -> Duration {
        self.config
            .timing
            .max_residual(net)
            .saturating_add(self.config.residual_slack)
    }

    fn abort(&mut self) {
        self.len = 0;
        self.state = State::Garbage;
    }

    fn receive(&mut self, byte: u8, stx_at: Duration) -> Option<Result<Telegram<'_>, FrameError>> {
        self.buf[self.len] = byte;
        self.len += 1;
        if self.len == 2 {
            if !(2..=254).contains(&byte) {
                self.abort();
                return Some(Err(FrameError::BadLge(byte)));
            }
            self.state = State::Receiving {
                stx_at,
                allowed: self.allowed(byte as usize - 2),
            };
            return None;
        }
        let total = self.buf[1] as usize + 2;
        if self.len < total {
            return None;
        }
        self.len = 0;
        self.state = State::Idle;
        let expected = bcc(&self.buf[..total - 1]);
        let actual = self.buf[total - 1];
        if expected != actual {
            self.state = State::Garbage;
            return Some(Err(FrameError::Bcc { expected, actual }));
        }
        // STX (`start`), LGE (above), the length and the BCC are checked: the telegram as is.
        Some(Ok(Telegram::checked_by_framer(&self.buf[..total])))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adr::{Address, Adr};
    use crate::telegram::encode;
    use crate::timing::Baud;

    const BAUD: u32 = 19200;

    fn timing() -> Timing {
        Timing::new(Baud::new(BAUD).unwrap())
    }

    fn framer() -> Framer {
        Framer::new(FramerConfig::strict(timing()))
    }

    fn telegram(addr: u8, pzd: &[u16]) -> ([u8; 64], usize) {
        let mut buf = [0u8; 64];
        let n = encode(&mut buf, Adr::to(Address::new(addr).unwrap()), &[], pzd).unwrap();
        (buf, n)
    }

    /// Feeds bytes at wire speed from `start`; returns every event and the time after the last byte.
    fn feed(
        f: &mut Framer,
        bytes: &[u8],
        start: Duration,
    ) -> (Vec<Result<Vec<u8>, FrameError>>, Duration) {
        let tz = timing().char_time();
        let mut at = start;
        let mut out = Vec::new();
        for &b in bytes {
            at += tz;
            if let Some(ev) = f.push(b, at) {
                out.push(ev.map(|t| t.as_bytes().to_vec()));
            }
        }
        (out, at)
    }

    #[test]
    fn byte_by_byte_telegram_is_delivered_once() {
        let (buf, n) = telegram(7, &[0x047E, 0x1234]);
        let mut f = framer();
        let (events, _) = feed(&mut f, &buf[..n], Duration::ZERO);
        assert_eq!(events, vec![Ok(buf[..n].to_vec())]);
    }

    #[test]
    fn chunk_arriving_at_once_is_accepted() {
        let (buf, n) = telegram(7, &[0x047E, 0x1234]);
        let mut f = framer();
        let at = Duration::from_millis(5);
        let mut got = None;
        for &b in &buf[..n] {
            if let Some(ev) = f.push(b, at) {
                got = Some(ev.unwrap().as_bytes().to_vec());
            }
        }
        assert_eq!(got.as_deref(), Some(&buf[..n]));
    }

    #[test]
    fn garbage_before_start_is_reported_once_then_resynchronises() {
        let (buf, n) = telegram(1, &[0xFB41, 0]);
        let mut f = framer();
        let mut bytes = vec![0x55, 0x02, 0xFF, 0x00];
        let (events, end) = feed(&mut f, &bytes, Duration::ZERO);
        assert_eq!(events, vec![Err(FrameError::MissingStx(0x55))]);
        // Back to back with the garbage: no pause, so the telegram is lost as garbage too.
        let (events, end) = feed(&mut f, &buf[..n], end);
        assert!(events.is_empty(), "{events:?}");
        // After a start pause the next telegram is received.
        let pause = timing().start_pause();
        bytes.clear();
        bytes.extend_from_slice(&buf[..n]);
        let (events, _) = feed(&mut f, &bytes, end + pause);
        assert_eq!(events, vec![Ok(buf[..n].to_vec())]);
    }

    #[test]
    fn stx_without_start_pause_is_an_error() {
        let (buf, n) = telegram(1, &[1, 2]);
        let mut f = framer();
        let (_, end) = feed(&mut f, &buf[..n], Duration::ZERO);
        let (events, _) = feed(&mut f, &buf[..n], end);
        assert_eq!(events, vec![Err(FrameError::StartPauseNotObserved)]);
    }

    #[test]
    fn our_own_transmission_counts_as_line_activity() {
        let (buf, n) = telegram(1, &[1, 2]);
        let mut f = framer();
        f.line_busy_until(Duration::from_millis(10));
        let (events, _) = feed(&mut f, &buf[..n], Duration::from_millis(10));
        assert_eq!(events[0], Err(FrameError::StartPauseNotObserved));
    }

    #[test]
    fn lenient_framer_accepts_stx_without_pause() {
        let (buf, n) = telegram(1, &[1, 2]);
        let mut f = Framer::new(FramerConfig {
            require_start_pause: false,
            ..FramerConfig::strict(timing())
        });
        let (_, end) = feed(&mut f, &buf[..n], Duration::ZERO);
        let (events, _) = feed(&mut f, &buf[..n], end);
        assert_eq!(events, vec![Ok(buf[..n].to_vec())]);
    }

    #[test]
    fn bad_bcc_and_bad_lge_are_reported() {
        let (mut buf, n) = telegram(2, &[3, 4]);
        buf[n - 1] ^= 0x10;
        let mut f = framer();
        let (events, end) = feed(&mut f, &buf[..n], Duration::ZERO);
        assert!(matches!(events[..], [Err(FrameError::Bcc { .. })]));
        let (events, _) = feed(&mut f, &[0x02, 0xFF, 0x00], end + timing().start_pause());
        assert_eq!(events, vec![Err(FrameError::BadLge(0xFF))]);
    }

    #[test]
    fn residual_time_is_monitored_per_lge() {
        let (buf, _) = telegram(2, &[3, 4]);
        let t = timing();
        let mut f = framer();
        // STX, LGE, ADR on time, then the rest 1.5 x (n+3) tz after the STX plus a bit.
        let (events, _) = feed(&mut f, &buf[..3], Duration::ZERO);
        assert!(events.is_empty());
        let stx_at = t.char_time();
        assert_eq!(f.deadline(), Some(stx_at + t.max_residual(4)));
        let late = stx_at + t.max_residual(4) + Duration::from_micros(1);
        let ev = f.push(buf[3], late).map(|r| r.map(|t| t.as_bytes().len()));
        assert_eq!(
            ev,
            Some(Err(FrameError::ResidualTimeExceeded {
                allowed: t.max_residual(4),
                elapsed: t.max_residual(4) + Duration::from_micros(1),
            }))
        );
    }

    #[test]
    fn poll_reports_a_stalled_telegram() {
        let (buf, _) = telegram(2, &[3, 4]);
        let mut f = framer();
        feed(&mut f, &buf[..2], Duration::ZERO);
        let deadline = f.deadline().unwrap();
        assert_eq!(f.poll(deadline), None);
        assert!(matches!(
            f.poll(deadline + Duration::from_nanos(1)),
            Some(FrameError::ResidualTimeExceeded { .. })
        ));
        assert!(!f.is_receiving());
    }

    #[test]
    fn residual_slack_widens_the_limit() {
        let (buf, n) = telegram(2, &[3, 4]);
        let t = timing();
        let mut f = Framer::new(FramerConfig {
            residual_slack: Duration::from_millis(16),
            ..FramerConfig::strict(t)
        });
        f.push(buf[0], Duration::ZERO);
        let late = t.max_residual(4) + Duration::from_millis(10);
        let mut last = None;
        for &b in &buf[1..n] {
            last = f.push(b, late).map(|r| r.is_ok());
        }
        assert_eq!(last, Some(true));
    }

    #[test]
    fn latency_shortens_the_start_pause_by_exactly_that_much() {
        let (buf, n) = telegram(2, &[3, 4]);
        let t = timing();
        let latency = t.char_time() / 2;
        // `feed` puts the STX one character time after its start.
        let short = t.start_pause().saturating_sub(latency + t.char_time());
        let mut f = Framer::new(FramerConfig::with_latency(t, latency));
        f.line_busy_until(Duration::from_millis(10));
        let (events, _) = feed(&mut f, &buf[..n], Duration::from_millis(10) + short);
        assert_eq!(events, vec![Ok(buf[..n].to_vec())]);
        let mut f = Framer::new(FramerConfig::with_latency(t, latency));
        f.line_busy_until(Duration::from_millis(10));
        let (events, _) = feed(
            &mut f,
            &buf[..n],
            (Duration::from_millis(10) + short).saturating_sub(Duration::from_nanos(1)),
        );
        assert_eq!(events[0], Err(FrameError::StartPauseNotObserved));
    }

    #[test]
    fn line_error_drops_the_telegram_in_progress() {
        let (buf, n) = telegram(2, &[3, 4]);
        let mut f = framer();
        let (_, end) = feed(&mut f, &buf[..4], Duration::ZERO);
        assert_eq!(
            f.push_line_error(LineError::Parity, end),
            FrameError::Line(LineError::Parity)
        );
        let (events, end) = feed(&mut f, &buf[4..n], end);
        assert!(events.is_empty());
        let (events, _) = feed(&mut f, &buf[..n], end + timing().start_pause());
        assert_eq!(events, vec![Ok(buf[..n].to_vec())]);
    }
}
