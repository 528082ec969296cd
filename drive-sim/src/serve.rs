//! Serving a simulated bus on a serial device or a pseudo-terminal.
//!
//! The loop reads what arrives, frames it with the real clock (start pause and residual time as
//! in USS.md section 4), lets the bus answer, waits the response delay and writes the reply. On a
//! real UART bytes take wire time; a pseudo-terminal moves them instantly and carries no parity
//! (USS.md section 9), so the start pause after a reply counts from the write there.

use crate::bus::SimBus;
use crate::fault::Reply;
use core::time::Duration;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{self, ControlFlags, SetArg};
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use uss_protocol::{Framer, FramerConfig, Timing};

/// How long one wait for input lasts; drive models advance at least this often.
const TICK: Duration = Duration::from_millis(2);

/// A byte stream the simulator serves.
pub trait Port {
    /// Reads what has arrived, waiting at most `timeout`; `Ok(0)` when nothing came.
    fn read_some(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;
    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Whether written bytes take their wire time (a UART) or arrive at once (a pty).
    fn paces_bytes(&self) -> bool;
}

/// A real serial device, opened exclusively at 8E1.
pub struct SerialDevice {
    port: serialport::TTYPort,
}

impl core::fmt::Debug for SerialDevice {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SerialDevice").finish_non_exhaustive()
    }
}

impl SerialDevice {
    pub fn open(path: &Path, baud: u32) -> Result<Self, serialport::Error> {
        let mut port = serialport::new(path.to_string_lossy(), baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(serialport::Parity::Even)
            .stop_bits(serialport::StopBits::One)
            .flow_control(serialport::FlowControl::None)
            .timeout(TICK)
            .open_native()?;
        port.set_exclusive(true)?;
        Ok(Self { port })
    }
}

impl Port for SerialDevice {
    fn read_some(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        serialport::SerialPort::set_timeout(&mut self.port, timeout)?;
        match self.port.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::TimedOut => Ok(0),
            other => other,
        }
    }

    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        Write::write_all(&mut self.port, bytes)
    }

    fn paces_bytes(&self) -> bool {
        true
    }
}

/// A pseudo-terminal pair: the simulator serves the master side, a USS master opens
/// [`Pty::path`]. The simulator keeps the slave side open too, so the pair survives the master
/// closing and reopening it.
#[derive(Debug)]
pub struct Pty {
    master: File,
    _slave: OwnedFd,
    path: PathBuf,
}

impl Pty {
    /// Creates the pair with the slave side in raw 8E1 mode (parity where the kernel keeps it).
    pub fn open() -> nix::Result<Self> {
        let pair = nix::pty::openpty(None, None)?;
        let path = nix::unistd::ttyname(&pair.slave)?;
        let mut t = termios::tcgetattr(&pair.slave)?;
        termios::cfmakeraw(&mut t);
        t.control_flags |= ControlFlags::CS8 | ControlFlags::CREAD | ControlFlags::CLOCAL;
        t.control_flags &= !(ControlFlags::PARODD | ControlFlags::CSTOPB);
        let mut with_parity = t.clone();
        with_parity.control_flags |= ControlFlags::PARENB;
        // Some kernels refuse PARENB on a pty (EINVAL); bytes flow the same without it.
        if termios::tcsetattr(&pair.slave, SetArg::TCSANOW, &with_parity).is_err() {
            termios::tcsetattr(&pair.slave, SetArg::TCSANOW, &t)?;
        }
        Ok(Self {
            master: File::from(pair.master),
            _slave: pair.slave,
            path,
        })
    }

    /// The device a master opens.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Port for Pty {
    fn read_some(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let ms = u16::try_from(timeout.as_millis()).unwrap_or(u16::MAX);
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(0) | Err(nix::Error::EINTR) => return Ok(0),
            Ok(_) => {}
            Err(e) => return Err(e.into()),
        }
        match self.master.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::Interrupted => Ok(0),
            other => other,
        }
    }

    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        Write::write_all(&mut self.master, bytes)
    }

    fn paces_bytes(&self) -> bool {
        false
    }
}

/// Serves `bus` on `port` until `stop` is set. Time starts at `start`, the same origin the
/// bus's fault plans (unplug windows) use.
pub fn serve(
    port: &mut impl Port,
    bus: &mut SimBus,
    timing: Timing,
    start: Instant,
    stop: &AtomicBool,
) -> io::Result<()> {
    let mut framer = Framer::new(FramerConfig::strict(timing));
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        if bus.hangs(start.elapsed()) {
            // The injected hang: read nothing, answer nothing, until stopped.
            std::thread::sleep(TICK);
            continue;
        }
        let n = port.read_some(&mut buf, TICK)?;
        let now = start.elapsed();
        bus.advance(now);
        for &b in &buf[..n] {
            let reply = match framer.push(b, now) {
                Some(Ok(telegram)) => bus.on_telegram(&telegram, now),
                Some(Err(e)) => {
                    bus.on_error(&e, now);
                    None
                }
                None => None,
            };
            if let Some(reply) = reply {
                let end = send(port, &reply, timing, start, now)?;
                framer.line_busy_until(end);
            }
        }
        if let Some(e) = framer.poll(start.elapsed()) {
            bus.on_error(&e, now);
        }
    }
    Ok(())
}

/// Waits out the response delay after `request_end`, writes the reply, and returns when the line
/// is free again.
fn send(
    port: &mut impl Port,
    reply: &Reply,
    timing: Timing,
    start: Instant,
    request_end: Duration,
) -> io::Result<Duration> {
    // A slave keeps the start pause before its reply too (USS.md section 4).
    let due = request_end + reply.delay.max(timing.earliest_reply());
    std::thread::sleep(due.saturating_sub(start.elapsed()));
    // On a pty the master can read the reply the moment `write` starts copying it, so the line
    // is free from then on; stamping after `write` returns would move the start pause later by
    // however long this process was descheduled, and refuse a master that waited correctly.
    let before = start.elapsed();
    port.write_all(reply.bytes())?;
    Ok(if port.paces_bytes() {
        start.elapsed() + timing.telegram(reply.bytes().len().saturating_sub(4))
    } else {
        before
    })
}
