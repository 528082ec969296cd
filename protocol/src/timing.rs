//! Timing math of USS.md section 4: character time, start pause, residual run time, the worst-case
//! transaction and the wire-time floor of one exchange.
//!
//! All durations are computed in integer nanoseconds from `11 bits x chars / baud`, rounded to the
//! nearest nanosecond, so results are exact to well below a microsecond at every baud rate.

use core::time::Duration;
use thiserror::Error;

/// Bits per character: start, 8 data, even parity, stop (8E1, USS.md section 2).
pub const BITS_PER_CHAR: u64 = 11;

/// The longest a slave may take from the end of the master's BCC to its own STX (USS.md section 4).
pub const MAX_RESPONSE_DELAY: Duration = Duration::from_millis(20);

/// A baud rate. Any rate from 300 to 12 Mbaud is accepted (drives and adapters support rates the
/// specification does not name); [`Baud::is_standard`] tells whether USS.md section 2 names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Baud(u32);

/// A baud rate outside 300..=12 000 000.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
#[error("baud rate {0} is out of range: use 300..=12000000 (USS names 300 to 187500)")]
pub struct BaudError(pub u32);

impl Baud {
    /// The rates named by the USS specification (USS.md section 2).
    pub const STANDARD: [u32; 13] = [
        300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 76800, 93750, 115_200, 187_500,
    ];
    const MIN: u32 = 300;
    const MAX: u32 = 12_000_000;

    /// Validates a baud rate.
    pub const fn new(baud: u32) -> Result<Self, BaudError> {
        if baud >= Self::MIN && baud <= Self::MAX {
            Ok(Self(baud))
        } else {
            Err(BaudError(baud))
        }
    }

    /// Bits per second.
    pub const fn get(self) -> u32 {
        self.0
    }

    /// Whether USS.md section 2 names this rate.
    pub fn is_standard(self) -> bool {
        Self::STANDARD.contains(&self.0)
    }

    /// The drive setting P2010 (MM4/G110) for this rate, where one is defined (USS.md section 2).
    pub const fn p2010(self) -> Option<u16> {
        match self.0 {
            1200 => Some(3),
            2400 => Some(4),
            4800 => Some(5),
            9600 => Some(6),
            19200 => Some(7),
            38400 => Some(8),
            57600 => Some(9),
            _ => None,
        }
    }

    /// The drive setting p2020 (SINAMICS G120's fieldbus baud rate) for this rate, where one
    /// is defined: 6 = 9600 ... 12 = 115200 (CU230P-2 OI 01/2011, p2020, p.120; V20 OI 07/2012
    /// p.111).
    pub const fn p2020(self) -> Option<u16> {
        match self.0 {
            9600 => Some(6),
            19200 => Some(7),
            38400 => Some(8),
            57600 => Some(9),
            76800 => Some(10),
            93750 => Some(11),
            115_200 => Some(12),
            _ => None,
        }
    }
}

impl core::fmt::Display for Baud {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.0.fmt(f)
    }
}

/// The timing rules of one bus at one baud rate (USS.md section 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    baud: Baud,
}

impl Timing {
    pub const fn new(baud: Baud) -> Self {
        Self { baud }
    }

    pub const fn baud(self) -> Baud {
        self.baud
    }

    /// The time `chars` characters take on the wire: `chars x 11 / baud`.
    pub const fn chars(self, chars: u64) -> Duration {
        self.chars_scaled(chars, 1, 1)
    }

    /// `chars x num / den` character times, rounded to the nearest nanosecond.
    const fn chars_scaled(self, chars: u64, num: u64, den: u64) -> Duration {
        let baud = self.baud.0 as u128;
        let numer = chars as u128 * num as u128 * BITS_PER_CHAR as u128 * 1_000_000_000;
        let denom = baud * den as u128;
        let nanos = (numer + denom / 2) / denom;
        Duration::from_nanos(nanos as u64)
    }

    /// The earliest a slave may start its reply after the request's last character: the
    /// start pause (USS.md section 4: the response delay is at least the start pause), with
    /// one character time of margin for the scheduling of a real line.
    pub const fn earliest_reply(self) -> Duration {
        self.start_pause().saturating_add(self.char_time())
    }

    /// Character time `tz = 11 / baud`.
    pub const fn char_time(self) -> Duration {
        self.chars(1)
    }

    /// Start pause: at least 2 tz of silence before an STX.
    pub const fn start_pause(self) -> Duration {
        self.chars(2)
    }

    /// A telegram of `net` net bytes sent with no gaps: `(net + 4) tz`.
    pub const fn telegram(self, net: usize) -> Duration {
        self.chars(net as u64 + 4)
    }

    /// Compressed residual run time after the STX: `(net + 3) tz`.
    pub const fn residual(self, net: usize) -> Duration {
        self.chars(net as u64 + 3)
    }

    /// Maximum residual run time after the STX: `1.5 x (net + 3) x tz`, monitored by both sides.
    pub const fn max_residual(self, net: usize) -> Duration {
        self.chars_scaled(net as u64 + 3, 3, 2)
    }

    /// Worst-case transaction for a request of `request_net` and a reply of `reply_net` net bytes:
    /// `2 tz + (nq+4) tz + 20 ms + tz + 1.5 (nr+3) tz`.
    pub const fn worst_case_transaction(self, request_net: usize, reply_net: usize) -> Duration {
        let wire = self.chars(2 + request_net as u64 + 4 + 1);
        let residual = self.max_residual(reply_net);
        let total = wire.as_nanos() + MAX_RESPONSE_DELAY.as_nanos() + residual.as_nanos();
        Duration::from_nanos(total as u64)
    }

    /// The wire-time floor of one exchange: start pause + request + the slave's actual response
    /// delay + reply. A fast master approaches this, not the worst case.
    pub const fn wire_floor(
        self,
        request_net: usize,
        reply_net: usize,
        response_delay: Duration,
    ) -> Duration {
        let chars = 2 + request_net as u64 + 4 + reply_net as u64 + 4;
        let total = self.chars(chars).as_nanos() + response_delay.as_nanos();
        Duration::from_nanos(total as u64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn timing(baud: u32) -> Timing {
        Timing::new(Baud::new(baud).unwrap())
    }

    fn ms(d: Duration) -> f64 {
        d.as_secs_f64() * 1000.0
    }

    /// USS.md section 4 table: PKW 4 + PZD 2, n = 12 both ways.
    #[test]
    fn worst_case_matches_the_uss_md_table() {
        let table = [
            (9600, 1.146, 2.29, 67.6),
            (19200, 0.573, 1.15, 43.8),
            (38400, 0.286, 0.57, 31.9),
            (115_200, 0.0955, 0.19, 24.0),
            (187_500, 0.0587, 0.12, 22.4),
        ];
        for (baud, tz, pause, worst) in table {
            let t = timing(baud);
            assert!((ms(t.char_time()) - tz).abs() < 0.0006, "tz at {baud}");
            assert!(
                (ms(t.start_pause()) - pause).abs() < 0.006,
                "pause at {baud}"
            );
            let w = ms(t.worst_case_transaction(12, 12));
            assert!((w - worst).abs() < 0.06, "worst case at {baud}: {w}");
        }
    }

    #[test]
    fn char_time_is_exact_in_nanoseconds() {
        assert_eq!(timing(9600).char_time(), Duration::from_nanos(1_145_833));
        assert_eq!(timing(187_500).char_time(), Duration::from_nanos(58_667));
        assert_eq!(timing(115_200).start_pause(), Duration::from_nanos(190_972));
    }

    #[test]
    fn residual_limits() {
        let t = timing(19200);
        // n = 12: compressed 15 tz, maximum 22.5 tz.
        assert_eq!(t.residual(12), t.chars(15));
        assert_eq!(t.max_residual(12).as_nanos(), 12_890_625);
        // Variable length arms the timer for n = 252 first: 1.5 x 255 tz.
        assert_eq!(t.max_residual(252).as_nanos(), 219_140_625);
        assert_eq!(t.telegram(12), t.chars(16));
    }

    #[test]
    fn wire_floor_adds_pause_request_delay_and_reply() {
        let t = timing(19200);
        let floor = t.wire_floor(12, 12, Duration::from_millis(1));
        assert_eq!(floor, t.chars(34) + Duration::from_millis(1));
    }

    #[test]
    fn baud_validation_and_p2010_codes() {
        assert_eq!(Baud::new(0), Err(BaudError(0)));
        assert_eq!(Baud::new(12_000_001), Err(BaudError(12_000_001)));
        assert!(Baud::new(93750).unwrap().is_standard());
        assert!(!Baud::new(250_000).unwrap().is_standard());
        assert_eq!(Baud::new(9600).unwrap().p2010(), Some(6));
        assert_eq!(Baud::new(57600).unwrap().p2010(), Some(9));
        assert_eq!(Baud::new(115_200).unwrap().p2010(), None);
        assert_eq!(Baud::new(19200).unwrap().p2020(), Some(7));
        assert_eq!(Baud::new(115_200).unwrap().p2020(), Some(12));
        assert_eq!(Baud::new(4800).unwrap().p2020(), None);
    }
}
