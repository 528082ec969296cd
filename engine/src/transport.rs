//! The line under the engine. [`Transport`] is the seam between the bus engine and the bytes:
//! `uss_drive_sim::SimTransport` attaches to the simulator's in-process virtual wire, and
//! `uss_serial::SerialTransport` to a serial device or pseudo-terminal.

use crate::clock::Clock;
use core::time::Duration;
use thiserror::Error;
use uss_protocol::LineError;

/// One character received from the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rx {
    pub byte: u8,
    /// When it arrived, on the engine's clock.
    pub at: Duration,
    /// A UART error flagged on this character (parity or framing), where the transport reports them.
    pub error: Option<LineError>,
}

/// A transport that can no longer carry telegrams.
#[derive(Debug, Error)]
pub enum TransportError {
    #[error("the line's I/O failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("the line was closed: a serial device unplugged, or its server's connection ended")]
    Closed,
    /// A write found no room for its whole allowance: the line's output stalled.
    #[error("the line's output stalled: no byte could be written for its write-stall allowance")]
    Stalled,
}

/// A half-duplex line to the drives.
pub trait Transport {
    /// Drops input that has already arrived, so nothing from an earlier exchange is matched to
    /// the next request (USS.md section 4).
    fn flush_input(&mut self, now: Duration) -> Result<(), TransportError>;

    /// Starts sending `bytes` at `now` and returns when the last character will have left the
    /// line (the response delay counts from then).
    fn send(&mut self, bytes: &[u8], now: Duration) -> Result<Duration, TransportError>;

    /// The next character, waiting on `clock` at most until `deadline`; `None` when the deadline
    /// passes first.
    fn recv(
        &mut self,
        deadline: Duration,
        clock: &mut impl Clock,
    ) -> Result<Option<Rx>, TransportError>;
}
