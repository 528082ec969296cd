//! Telegram capture: every telegram ussd's bus thread sends and every reply it receives (or
//! the bytes that came instead, or nothing), one [`TelegramRecord`] each, on
//! `uss/<bus>/<gen>/capture` (publish-subscribe, no history; see [`crate::names::capture`]).
//!
//! The bus thread copies each telegram into a preallocated ring; ussd's housekeeping thread
//! publishes the records, so capturing costs the bus thread a copy and nothing else, and a slow
//! subscriber loses records (its buffer overflows; `sequence` shows the gap) but never slows
//! the bus.

use crate::codes::{UnknownCode, code_table};
use crate::diag::LastFailure;
use crate::{LAYOUT_VERSION, check_version};
#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;

code_table! {
    /// Which way a captured telegram went; the `direction` byte of [`TelegramRecord`].
    pub enum Direction {
        /// Master to drive: the request.
        Request = 0 => "request",
        /// Drive to master: the reply, what came instead of it, or nothing.
        Reply = 1 => "reply",
    }
}

/// Bytes a record holds: the longest telegram (STX, LGE 254, its 254 bytes) and 8 more of
/// whatever came with it.
pub const CAPTURE_BYTES: usize = 264;

/// `flags` bit: more bytes came than [`CAPTURE_BYTES`]; the rest are not in the record.
pub const CAPTURE_TRUNCATED: u8 = 1 << 0;
/// `flags` bit: the request carries a parameter task (its PKW words are not "no task").
pub const CAPTURE_TASK: u8 = 1 << 1;

/// One captured telegram.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "ipc",
    derive(ZeroCopySend),
    type_name("UssTelegramRecordV9")
)]
pub struct TelegramRecord {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// Bytes used in `bytes`.
    pub len: u16,
    /// A [`Direction`] code.
    pub direction: u8,
    /// A reply's [`LastFailure`] code: 0 (`None`) for a good reply of the polled drive, e.g.
    /// `NoResponse` with no bytes, `Bcc` with the broken bytes. 0 for a request.
    pub outcome: u8,
    /// The polled drive's address (a reply from another drive is `WrongAddress`).
    pub address: u8,
    /// The drive's PKW mode as P2013 says it: 0, 3, 4 or 127 (variable length).
    pub pkw: u8,
    /// The drive's PZD words.
    pub pzd: u8,
    /// [`CAPTURE_TRUNCATED`], [`CAPTURE_TASK`].
    pub flags: u8,
    pub reserved: [u8; 4],
    /// Counts the records of this ussd instance's bus, from 1; a gap is records lost.
    pub sequence: u64,
    /// The first byte on the wire, `CLOCK_MONOTONIC` ns (a reply without bytes: when the wait
    /// for it ended).
    pub start_ns: u64,
    /// The last byte on the wire, `CLOCK_MONOTONIC` ns.
    pub end_ns: u64,
    pub bytes: [u8; CAPTURE_BYTES],
}

impl TelegramRecord {
    /// An empty record of the current layout version.
    pub const EMPTY: Self = Self {
        version: LAYOUT_VERSION,
        len: 0,
        direction: Direction::Request.code(),
        outcome: LastFailure::None.code(),
        address: 0,
        pkw: 0,
        pzd: 0,
        flags: 0,
        reserved: [0; 4],
        sequence: 0,
        start_ns: 0,
        end_ns: 0,
        bytes: [0; CAPTURE_BYTES],
    };

    /// The captured bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len).min(CAPTURE_BYTES)]
    }

    pub fn direction(&self) -> Result<Direction, UnknownCode> {
        Direction::try_from(self.direction)
    }

    pub fn outcome(&self) -> Result<LastFailure, UnknownCode> {
        LastFailure::try_from(self.outcome)
    }

    /// Whether it is our request (not a reply).
    pub fn is_request(&self) -> bool {
        self.direction() == Ok(Direction::Request)
    }

    /// How it ended, in words: "sent" (a request), "good" (a good reply), or what failed
    /// ("no response", "BCC error", ...).
    pub fn outcome_name(&self) -> &'static str {
        match self.outcome() {
            _ if self.is_request() => "sent",
            Ok(LastFailure::None) => "good",
            Ok(f) => f.name(),
            Err(_) => "unknown outcome",
        }
    }

    /// Checks the record's version.
    pub const fn check(&self) -> Result<(), crate::ContractError> {
        check_version(self.version)
    }
}

/// Bytes as hex pairs separated by spaces: `02 0E 01`.
#[derive(Debug, Clone, Copy)]
pub struct Hex<'a>(pub &'a [u8]);

impl core::fmt::Display for Hex<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        for (i, b) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

impl Default for TelegramRecord {
    fn default() -> Self {
        Self::EMPTY
    }
}
