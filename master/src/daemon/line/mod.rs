//! The lines a bus runs over, one kind per file: a serial device ([`serial`]), a serial device
//! server's port over TCP ([`tcp`]). A kind says how it is opened (and opened again after it
//! failed), what receive latency the bus's timing allows for it, and how a failed one is given
//! up ([`LineKind`]); the runtime starts every kind alike ([`super::runtime`]). A line that is
//! not there yet (an adapter not plugged in, a server not up) starts the bus line down, and its
//! line thread opens it when it appears.

use core::time::Duration;
use uss_engine::{Clock, Rx, Transport, TransportError};

pub mod serial;
pub mod tcp;

pub use serial::SerialLine;
pub use tcp::TcpLine;

/// A line opened: its transport, what was obtained (one log line).
#[derive(Debug)]
pub struct Opened<T> {
    pub transport: T,
    pub report: String,
}

/// Why a line did not open.
#[derive(Debug)]
pub enum NotOpened {
    /// Not there yet (a device not plugged in, a server that does not answer): the bus starts
    /// line down and its line thread opens it when it appears; the text says what was found.
    NotThere(String),
    /// It is there and cannot be used as configured: ussd does not start.
    Refused(Box<dyn std::error::Error + Send + Sync>),
}

impl core::fmt::Display for NotOpened {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NotThere(why) => f.write_str(why),
            Self::Refused(e) => write!(f, "{e}"),
        }
    }
}

/// One kind of line, as ussd opens it. Opening and releasing run off the real-time thread (in
/// ussd's start and the bus's line thread): they may allocate and block.
pub trait LineKind: Send + 'static {
    type Transport: Transport + Send + 'static;

    /// The line as the configuration names it (for the log).
    fn name(&self) -> String;

    /// Opens the line.
    fn open(&mut self) -> Result<Opened<Self::Transport>, NotOpened>;

    /// How late the line delivers received bytes, after the latest [`LineKind::open`]: what
    /// the bus's timing allows for (logged, with a warning where it is too slow).
    fn rx_latency(&mut self, bus: &str) -> Duration;

    /// Gives up a failed line, returning what holds it (to be closed off the real-time
    /// thread): [`Line::take`], after dropping unsent output where the kind queues it.
    fn release(line: &mut Line<Self::Transport>) -> Option<Line<Self::Transport>> {
        line.take()
    }
}

/// A line that is open, or not (yet, or any more).
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

    /// Gives up what holds the device, returning it (to be closed off the real-time thread:
    /// closing a tty may wait for its output to drain). A device held open keeps its exclusive
    /// lock, so the reopen would be refused as busy, and keeps its minor number, so a replugged
    /// USB adapter would get another name. Afterwards every use fails as a missing device does.
    pub fn take(&mut self) -> Option<Self> {
        match core::mem::replace(self, Self::Absent) {
            open @ Self::Open(_) => Some(open),
            Self::Absent => None,
        }
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
}
