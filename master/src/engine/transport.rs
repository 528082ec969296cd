//! The line under the engine. [`Transport`] is the seam between the bus engine and the bytes:
//! [`SimTransport`] attaches to the simulator's in-process virtual wire, and
//! [`crate::transports::serial::SerialTransport`] to a serial device or pseudo-terminal.

use crate::engine::clock::Clock;
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
    #[error("serial I/O failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("the serial device was closed or unplugged")]
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

    /// Lets a simulated far side catch up to `now` (drive ramps and telegram monitoring); real
    /// lines need nothing.
    fn idle(&mut self, now: Duration) {
        let _ = now;
    }

    /// Drops output not yet sent, for a line that failed: nothing queued for it is still
    /// wanted, and a tty closed with output queued waits for it to drain (30 s by default).
    fn discard_output(&mut self) {}

    /// The line failed: gives up the device so that it can be opened again, returning what
    /// holds it (to be closed off the real-time thread: closing a tty may wait for its output
    /// to drain). A device held open keeps its exclusive lock, so the reopen would be refused as
    /// busy, and keeps its minor number, so a replugged USB adapter would get another name.
    /// Afterwards every use fails as a missing device does. A line that cannot be reopened
    /// (the simulator's) gives up nothing.
    fn release(&mut self) -> Option<Self>
    where
        Self: Sized,
    {
        None
    }
}

/// A serial line that may not be there yet: a bus whose device is absent when ussd starts
/// (an adapter not plugged in, its udev name not made yet) starts line down, and its line
/// thread opens the device when it appears.
#[derive(Debug)]
pub enum Line<T> {
    Open(T),
    /// Not opened; every use fails as the missing device does (`ENOENT`).
    Absent,
}

impl<T> Line<T> {
    fn absent() -> TransportError {
        TransportError::Io(std::io::Error::from_raw_os_error(nix::libc::ENOENT))
    }
}

impl<T: Transport> Transport for Line<T> {
    fn flush_input(&mut self, now: Duration) -> Result<(), TransportError> {
        match self {
            Self::Open(t) => t.flush_input(now),
            Self::Absent => Err(Self::absent()),
        }
    }

    fn send(&mut self, bytes: &[u8], now: Duration) -> Result<Duration, TransportError> {
        match self {
            Self::Open(t) => t.send(bytes, now),
            Self::Absent => Err(Self::absent()),
        }
    }

    fn recv(
        &mut self,
        deadline: Duration,
        clock: &mut impl Clock,
    ) -> Result<Option<Rx>, TransportError> {
        match self {
            Self::Open(t) => t.recv(deadline, clock),
            Self::Absent => Err(Self::absent()),
        }
    }

    fn idle(&mut self, now: Duration) {
        if let Self::Open(t) = self {
            t.idle(now);
        }
    }

    fn discard_output(&mut self) {
        if let Self::Open(t) = self {
            t.discard_output();
        }
    }

    fn release(&mut self) -> Option<Self> {
        self.discard_output();
        match core::mem::replace(self, Self::Absent) {
            open @ Self::Open(_) => Some(open),
            Self::Absent => None,
        }
    }
}
