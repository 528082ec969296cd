//! A serial line that may not be there yet, and how a failed one is given up: a bus whose device
//! is absent when ussd starts (an adapter not plugged in, its udev name not made yet) starts
//! line down, and its line thread opens the device when it appears
//! ([`super::runtime`]).

use core::time::Duration;
use uss_engine::{Clock, Rx, Transport, TransportError};
use uss_serial::SerialTransport;

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

impl Line<SerialTransport> {
    /// The line failed: drops its unsent output first (nothing queued for it is still wanted,
    /// and a tty closed with output queued waits up to 30 s for it to drain), then
    /// [`Line::take`].
    pub fn release(&mut self) -> Option<Self> {
        if let Self::Open(t) = self {
            t.discard_output();
        }
        self.take()
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
