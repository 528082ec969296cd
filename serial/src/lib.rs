//! The line under the engine: a UART or USB adapter at 8E1, a pseudo-terminal for end-to-end
//! tests (USS.md sections 2, 4 and 9), or a serial device server's port over TCP ([`tcp`]).
//!
//! [`SerialTransport::open`] lets the `serialport` crate open the device (exclusive, raw, 8E1, no
//! flow control), then tunes the fd itself: parity and framing errors marked in the byte stream
//! (`PARMRK`) so they reach the framer as [`LineError`]s, non-blocking I/O, and the optional
//! kernel RS485 and low-latency modes. Receiving reads everything available into a fixed buffer,
//! timestamps it once and hands it out byte by byte: nothing allocates after `open`, because
//! `send` and `recv` run in the real-time thread.

use crate::rate::ReadBack;
use core::fmt;
use core::ops::RangeInclusive;
use core::time::Duration;
use nix::errno::Errno;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::libc::{c_char, c_int, c_uint, c_ulong, c_ushort};
use nix::poll::{PollFd, PollFlags, ppoll};
use nix::sys::stat::{fstat, major};
use nix::sys::termios::{
    self, ControlFlags, FlushArg, InputFlags, SetArg, SpecialCharacterIndices,
};
use nix::sys::time::TimeSpec;
use serialport::{DataBits, FlowControl, Parity, StopBits, TTYPort};
use std::os::fd::{AsRawFd, BorrowedFd};
use std::path::{Path, PathBuf};
use thiserror::Error;
use uss_engine::{Clock, Rx, Transport, TransportError};
use uss_protocol::{Baud, LineError, Timing};

pub mod latency;
pub mod rate;
pub mod tcp;

pub use tcp::{ConnectReport, TcpError, TcpOptions, TcpTransport};

/// Raw bytes one `read` takes: a whole 256-byte telegram fits even with every byte escaped.
const READ_CHUNK: usize = 1024;

/// The escape byte of the tty's `PARMRK` marking.
const MARK: u8 = 0xFF;

/// Device majors of pseudo-terminal slaves: UNIX98 (`/dev/pts/N`) and legacy BSD (`/dev/ttyp0`).
const UNIX98_PTY_SLAVE_MAJORS: RangeInclusive<u64> = 136..=143;
const BSD_PTY_SLAVE_MAJOR: u64 = 3;

/// Characters the kernel queues for sending; a write that finds no room for as long as these take
/// on the wire (plus a margin) means the line is stuck, not slow.
const TX_QUEUE_CHARS: u64 = 4096;
const STUCK_MARGIN: Duration = Duration::from_millis(100);

/// How long a write may wait for room in the kernel's transmit queue before the line counts as
/// stuck (a line failure, reopened): the queue's wire time and a margin.
pub fn write_stall(timing: Timing) -> Duration {
    timing.chars(TX_QUEUE_CHARS) + STUCK_MARGIN
}

/// The longest single `ppoll`: a far deadline (even `Duration::MAX`) becomes several waits
/// instead of a timeout `ppoll` cannot represent.
const MAX_WAIT: Duration = Duration::from_secs(3600);

/// How to open the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SerialOptions {
    pub baud: Baud,
    /// Let the kernel drive RTS as the RS485 direction line (`TIOCSRS485` with RTS on send), for
    /// embedded UARTs; USB adapters switch by themselves (USS.md section 9).
    pub kernel_rs485: bool,
    /// With `kernel_rs485`: what to change of the port's RS485 set-up (the rest is kept as the
    /// driver or device tree has it).
    pub rs485_settings: Rs485Wanted,
    /// Ask the driver for low latency (`ASYNC_LOW_LATENCY`); an FTDI adapter otherwise holds
    /// received bytes up to 16 ms, most of the 20 ms reply budget (USS.md section 9).
    pub low_latency: bool,
    /// How late the adapter may deliver a received byte. Bytes read together are back-dated
    /// by their character times (the last one arrived when read, each earlier one a character
    /// before) on a UART; a pseudo-terminal with a latency is an adapter imitated on it
    /// (`uss-sim --rx-tick`), timed as a UART (sending takes wire time, reading is back-dated).
    pub rx_latency: Duration,
}

/// What to set of a port's kernel RS485 mode; `None` keeps what the port has (a device tree's
/// polarity and delays, on a board wired for them).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Rs485Wanted {
    /// RTS high while sending (`true`) or low while sending.
    pub rts_high_while_sending: Option<bool>,
    pub delay_before_ms: Option<u32>,
    pub delay_after_ms: Option<u32>,
}

/// The kernel RS485 set-up a port runs with, as the driver wrote it back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rs485Kept {
    pub rts_high_while_sending: bool,
    pub delay_before_ms: u32,
    pub delay_after_ms: u32,
}

impl fmt::Display for Rs485Kept {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "RTS {} while sending, delays {}/{} ms",
            if self.rts_high_while_sending {
                "high"
            } else {
                "low"
            },
            self.delay_before_ms,
            self.delay_after_ms
        )
    }
}

/// Whether even parity is really on the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParityState {
    /// 8E1 set and read back from the driver.
    Even,
    /// A pseudo-terminal carries bytes only and keeps no parity (USS.md section 9): normal
    /// there, and not checked by reading termios back.
    NotOnPseudoTerminal,
}

/// The outcome of an optional driver setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Setting {
    NotRequested,
    Set,
    /// The driver does not offer it; the errno says how it refused.
    Unsupported(Errno),
}

/// What [`SerialTransport::open`] obtained, for one structured log line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OpenReport {
    pub pseudo_terminal: bool,
    pub parity: ParityState,
    /// Kernel RS485 mode. `Unsupported` only on a pseudo-terminal: a real port that refuses it
    /// fails to open.
    pub rs485: Setting,
    /// With kernel RS485 set: what the driver runs with.
    pub rs485_kept: Option<Rs485Kept>,
    pub low_latency: Setting,
}

impl fmt::Display for ParityState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Even => "even",
            Self::NotOnPseudoTerminal => "none-on-pty",
        })
    }
}

impl fmt::Display for Setting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NotRequested => f.write_str("not-requested"),
            Self::Set => f.write_str("set"),
            Self::Unsupported(errno) => write!(f, "unsupported({errno:?})"),
        }
    }
}

impl fmt::Display for OpenReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "pty={} parity={} rs485={} low_latency={}",
            self.pseudo_terminal, self.parity, self.rs485, self.low_latency
        )?;
        if let Some(kept) = self.rs485_kept {
            write!(f, " ({kept})")?;
        }
        Ok(())
    }
}

/// Why the line could not be opened as USS needs it.
#[derive(Debug, Error)]
pub enum SerialError {
    #[error("cannot open {}: No such file or directory", .path.display())]
    NotFound { path: PathBuf },
    #[error(
        "cannot open {}: permission denied (run as a member of the group owning the device, usually dialout)",
        .path.display()
    )]
    PermissionDenied { path: PathBuf },
    #[error("cannot open {}: device is busy (opened exclusively by another process)", .path.display())]
    Busy { path: PathBuf },
    #[error("cannot open {}: {source}", .path.display())]
    Open {
        path: PathBuf,
        source: serialport::Error,
    },
    #[error("cannot set up {}: {step} failed ({errno})", .path.display())]
    Setup {
        path: PathBuf,
        step: &'static str,
        errno: Errno,
    },
    #[error(
        "cannot open {}: the driver did not keep 8E1 (8 data bits, even parity, 1 stop bit); drives answer nothing else (USS.md section 2)",
        .path.display()
    )]
    ParityRefused { path: PathBuf },
    #[error("cannot use {}: {off}", .path.display())]
    RateOff {
        path: PathBuf,
        off: crate::rate::RateOff,
    },
    #[error(
        "cannot open {}: kernel RS485 mode requested but the driver refused TIOCSRS485 ({errno:?}): use rs485 = \"auto\" for adapters that switch direction themselves",
        .path.display()
    )]
    Rs485Refused { path: PathBuf, errno: Errno },
    #[error(
        "cannot open {}: kernel RS485 mode requested but the driver left it off after TIOCSRS485: use rs485 = \"auto\" for adapters that switch direction themselves",
        .path.display()
    )]
    Rs485LeftOff { path: PathBuf },
}

impl SerialError {
    fn from_open(path: &Path, source: serialport::Error) -> Self {
        let path = path.to_owned();
        match source.kind() {
            serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => Self::NotFound { path },
            serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => {
                Self::PermissionDenied { path }
            }
            // serialport reports EBUSY (TIOCEXCL held by another) and a held flock this way.
            serialport::ErrorKind::NoDevice => Self::Busy { path },
            _ => Self::Open { path, source },
        }
    }
}

/// `struct serial_rs485` of `linux/serial.h` (the libc crate lacks it).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct SerialRs485 {
    flags: u32,
    delay_rts_before_send: u32,
    delay_rts_after_send: u32,
    padding: [u32; 5],
}

const SER_RS485_ENABLED: u32 = 1 << 0;
const SER_RS485_RTS_ON_SEND: u32 = 1 << 1;
const SER_RS485_RTS_AFTER_SEND: u32 = 1 << 2;
/// Receive while sending: a flag of the device tree's that ussd keeps.
#[cfg(test)]
const SER_RS485_RX_DURING_TX: u32 = 1 << 4;

/// `struct serial_struct` of `linux/serial.h` (the libc crate lacks it); its two pointer-sized
/// fields are `usize` and `c_ulong`, the same layout.
#[repr(C)]
#[derive(Debug, Default)]
struct SerialStruct {
    kind: c_int,
    line: c_int,
    port: c_uint,
    irq: c_int,
    flags: c_int,
    xmit_fifo_size: c_int,
    custom_divisor: c_int,
    baud_base: c_int,
    close_delay: c_ushort,
    io_type: c_char,
    reserved_char: c_char,
    hub6: c_int,
    closing_wait: c_ushort,
    closing_wait2: c_ushort,
    iomem_base: usize,
    iomem_reg_shift: c_ushort,
    port_high: c_uint,
    iomap_base: c_ulong,
}

const ASYNC_LOW_LATENCY: c_int = 1 << 13;

#[cfg(target_pointer_width = "64")]
const _: () = assert!(size_of::<SerialStruct>() == 72 && size_of::<SerialRs485>() == 32);

/// The ioctls nix has no wrappers for; the macros turn -1 into the errno.
mod ioctl {
    use super::{SerialRs485, SerialStruct};
    use nix::libc;

    nix::ioctl_read_bad!(tiocgserial, libc::TIOCGSERIAL, SerialStruct);
    nix::ioctl_write_ptr_bad!(tiocsserial, libc::TIOCSSERIAL, SerialStruct);
    // The kernel writes back the configuration it applied.
    nix::ioctl_readwrite_bad!(tiocsrs485, libc::TIOCSRS485, SerialRs485);
    nix::ioctl_read_bad!(tiocgrs485, libc::TIOCGRS485, SerialRs485);
    nix::ioctl_read_bad!(tiocgicount, libc::TIOCGICOUNT, super::SerialIcounter);
    nix::ioctl_none_bad!(tiocnxcl, libc::TIOCNXCL);
    nix::ioctl_read_bad!(tcgets2, libc::TCGETS2, libc::termios2);
}

/// Undoes the tty's `PARMRK` marking (termios(3)): `FF FF` is a literal 0xFF and `FF 00 X` is X
/// received with a parity or framing error, `FF 00 00` being a break. The state lives across
/// reads, because a marking may be split between two. Linux does not mark overruns in the stream
/// (it only counts them), so they never appear here.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum Unmark {
    #[default]
    Plain,
    /// After `FF`.
    Escape,
    /// After `FF 00`: the next byte arrived broken.
    Flagged,
}

impl Unmark {
    /// Feeds one raw byte; returns a received character once one is complete.
    fn push(&mut self, raw: u8) -> Option<(u8, Option<LineError>)> {
        let (next, out) = match (*self, raw) {
            (Self::Plain, MARK) => (Self::Escape, None),
            (Self::Plain, byte) | (Self::Escape, byte @ MARK) => (Self::Plain, Some((byte, None))),
            (Self::Escape, 0) => (Self::Flagged, None),
            // Not a marking the tty makes: the byte is flagged, so the framer drops the telegram
            // rather than trusting it.
            (Self::Escape, byte) => (Self::Plain, Some((byte, Some(LineError::Framing)))),
            // A break arrives as a NUL with an error; the tty tells it from a NUL with bad
            // parity no better, and a break is what a zero character with an error usually is.
            (Self::Flagged, 0) => (Self::Plain, Some((0, Some(LineError::Framing)))),
            (Self::Flagged, byte) => (Self::Plain, Some((byte, Some(LineError::Parity)))),
        };
        *self = next;
        out
    }
}

/// A serial device or pseudo-terminal, opened exclusively at 8E1 (USS.md section 2).
pub struct SerialTransport {
    /// Owns the fd; closing it on drop also releases serialport's exclusive flock.
    port: TTYPort,
    timing: Timing,
    /// How long a write may wait for room in the kernel's queue before the line counts as stuck.
    write_stall: Duration,
    raw: [u8; READ_CHUNK],
    len: usize,
    pos: usize,
    /// When the bytes in `raw` were read.
    at: Duration,
    /// Reads the UART's overrun count (`TIOCGICOUNT`), where the driver keeps one: Linux
    /// counts overruns instead of marking them in the stream.
    overruns: Option<OverrunProbe>,
    /// The count at the last read, and whether the next character returned carries the
    /// overrun (characters were lost before it).
    overruns_seen: u64,
    overrun_pending: bool,
    /// Characters in `raw[..len]` (markings undone), and how many of them were handed out.
    chars: u64,
    handed: u64,
    unmark: Unmark,
    /// A UART takes each character's wire time; a pseudo-terminal moves bytes at once, so there
    /// the request has left (and the reply may start) as soon as `write` returns.
    paced: bool,
}

impl fmt::Debug for SerialTransport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SerialTransport")
            .field("fd", &self.port.as_raw_fd())
            .field("baud", &self.timing.baud())
            .field("buffered", &(self.len - self.pos))
            .field("unmark", &self.unmark)
            .finish_non_exhaustive()
    }
}

impl SerialTransport {
    /// Opens the device exclusively (`TIOCEXCL` and flock) at 8E1 through the serialport crate,
    /// raw, no flow control, with input already received flushed. On a real port 8E1 is read
    /// back and a refused kernel RS485 mode is an error; a pseudo-terminal opens without parity,
    /// RS485 or low latency and the report says so (USS.md section 9).
    pub fn open(path: &Path, options: &SerialOptions) -> Result<(Self, OpenReport), SerialError> {
        Self::open_with(path, options, read_back_rate)
    }

    /// Drops output not yet sent (`tcflush(TCOFLUSH)`), for a line that failed: nothing queued
    /// for it is still wanted, and a tty closed with output queued waits for it to drain (30 s
    /// by default). Errors are of no interest on a line that failed.
    pub fn discard_output(&mut self) {
        let _ = termios::tcflush(self.fd(), FlushArg::TCOFLUSH);
    }

    /// [`SerialTransport::open`] with the rate read back by `probe` (an injection point for
    /// tests: the real one asks the driver, and nothing of a pseudo-terminal).
    pub fn open_with(
        path: &Path,
        options: &SerialOptions,
        probe: RateProbe,
    ) -> Result<(Self, OpenReport), SerialError> {
        let mut port = serialport::new(path.to_string_lossy(), options.baud.get())
            .data_bits(DataBits::Eight)
            .parity(Parity::Even)
            .stop_bits(StopBits::One)
            .flow_control(FlowControl::None)
            .open_native()
            .map_err(|e| SerialError::from_open(path, e))?;
        port.set_exclusive(true)
            .map_err(|e| SerialError::from_open(path, e))?;
        let timing = Timing::new(options.baud);
        let mut transport = Self {
            port,
            timing,
            write_stall: write_stall(timing),
            raw: [0; READ_CHUNK],
            len: 0,
            pos: 0,
            at: Duration::ZERO,
            overruns: None,
            overruns_seen: 0,
            overrun_pending: false,
            chars: 0,
            handed: 0,
            unmark: Unmark::Plain,
            paced: true,
        };
        let report = transport.set_up(path, *options)?;
        let rate =
            probe(transport.fd(), report.pseudo_terminal).map_err(|errno| SerialError::Setup {
                path: path.to_owned(),
                step: "TCGETS2 (the rate obtained)",
                errno,
            })?;
        if let Some(read_back) = rate {
            crate::rate::obtained(options.baud.get(), read_back).map_err(|off| {
                SerialError::RateOff {
                    path: path.to_owned(),
                    off,
                }
            })?;
        }
        if !report.pseudo_terminal
            && let Ok(count) = read_overruns(transport.fd())
        {
            transport.overruns = Some(read_overruns);
            transport.overruns_seen = count;
        }
        // A pseudo-terminal with a receive latency is an adapter imitated on it (uss-sim
        // --rx-tick): bytes take their wire time there as on a UART.
        transport.paced = !report.pseudo_terminal || !options.rx_latency.is_zero();
        Ok((transport, report))
    }

    fn set_up(&self, path: &Path, options: SerialOptions) -> Result<OpenReport, SerialError> {
        let fd = self.fd();
        let failed = |step: &'static str| {
            move |errno| SerialError::Setup {
                path: path.to_owned(),
                step,
                errno,
            }
        };
        let pseudo_terminal = is_pseudo_terminal(fd).map_err(failed("fstat"))?;
        mark_line_errors(fd).map_err(failed("tcsetattr (INPCK, PARMRK)"))?;
        let parity = if pseudo_terminal {
            ParityState::NotOnPseudoTerminal
        } else {
            let applied = termios::tcgetattr(fd).map_err(failed("tcgetattr"))?;
            if !is_8e1(applied.control_flags) {
                return Err(SerialError::ParityRefused {
                    path: path.to_owned(),
                });
            }
            ParityState::Even
        };
        let flags = fcntl(fd, FcntlArg::F_GETFL).map_err(failed("fcntl(F_GETFL)"))?;
        fcntl(
            fd,
            FcntlArg::F_SETFL(OFlag::from_bits_retain(flags) | OFlag::O_NONBLOCK),
        )
        .map_err(failed("fcntl(F_SETFL, O_NONBLOCK)"))?;
        let mut rs485_kept = None;
        let rs485 = if options.kernel_rs485 {
            match enable_rs485(fd, options.rs485_settings) {
                Ok(Some(kept)) => {
                    rs485_kept = Some(kept);
                    Setting::Set
                }
                Err(errno) if pseudo_terminal => Setting::Unsupported(errno),
                Err(errno) => {
                    return Err(SerialError::Rs485Refused {
                        path: path.to_owned(),
                        errno,
                    });
                }
                Ok(None) => {
                    return Err(SerialError::Rs485LeftOff {
                        path: path.to_owned(),
                    });
                }
            }
        } else {
            Setting::NotRequested
        };
        let low_latency = if options.low_latency {
            set_low_latency(fd).map_or_else(Setting::Unsupported, |()| Setting::Set)
        } else {
            Setting::NotRequested
        };
        termios::tcflush(fd, FlushArg::TCIFLUSH).map_err(failed("tcflush"))?;
        Ok(OpenReport {
            pseudo_terminal,
            parity,
            rs485,
            rs485_kept,
            low_latency,
        })
    }

    fn fd(&self) -> BorrowedFd<'_> {
        port_fd(&self.port)
    }

    /// The next character already read, if any.
    fn next_buffered(&mut self) -> Option<Rx> {
        while self.pos < self.len {
            let raw = self.raw[self.pos];
            self.pos += 1;
            if let Some((byte, error)) = self.unmark.push(raw) {
                self.handed += 1;
                let error = if self.overrun_pending {
                    self.overrun_pending = false;
                    error.or(Some(LineError::Overrun))
                } else {
                    error
                };
                let at = if self.paced {
                    // On the wire the last character of the read came last; each one before
                    // it a character time earlier.
                    self.at
                        .saturating_sub(self.timing.chars(self.chars.saturating_sub(self.handed)))
                } else {
                    self.at
                };
                return Some(Rx { byte, at, error });
            }
        }
        None
    }

    /// Reads what the kernel holds into the buffer, timestamped now; false when it held nothing.
    fn fill(&mut self, clock: &impl Clock) -> Result<bool, TransportError> {
        loop {
            match nix::unistd::read(port_fd(&self.port), &mut self.raw) {
                // A hung-up tty reads as end of file.
                Ok(0) => return Err(TransportError::Closed),
                Ok(n) => {
                    self.len = n;
                    self.pos = 0;
                    self.at = clock.now();
                    self.handed = 0;
                    // Only a paced line dates bytes back, and only then needs their count.
                    if self.paced {
                        let mut unmark = self.unmark;
                        self.chars = self.raw[..n]
                            .iter()
                            .filter(|&&raw| unmark.push(raw).is_some())
                            .count() as u64;
                    }
                    self.note_overruns();
                    return Ok(true);
                }
                Err(Errno::EAGAIN) => return Ok(false),
                Err(Errno::EINTR) => {}
                Err(errno) => return Err(line_failure(errno)),
            }
        }
    }

    /// Marks the next character when the UART counted overruns since the last read.
    fn note_overruns(&mut self) {
        if let Some(probe) = self.overruns
            && let Ok(count) = probe(self.fd())
        {
            if count > self.overruns_seen {
                self.overrun_pending = true;
            }
            self.overruns_seen = count;
        }
    }
}

impl Drop for SerialTransport {
    fn drop(&mut self) {
        // TIOCEXCL outlives our fd while another holds the tty open (a simulator keeps its pty
        // slave open), so the next opener would get EBUSY; the flock goes with the fd. Nothing
        // to do if this fails: the fd closes next.
        // SAFETY: the fd is open (owned by `port`); TIOCNXCL takes no argument.
        let _ = unsafe { ioctl::tiocnxcl(self.port.as_raw_fd()) };
    }
}

impl Transport for SerialTransport {
    /// `tcflush(TCIFLUSH)` plus what was read but not yet returned, and a half-read marking.
    fn flush_input(&mut self, _now: Duration) -> Result<(), TransportError> {
        termios::tcflush(self.fd(), FlushArg::TCIFLUSH).map_err(line_failure)?;
        self.len = 0;
        self.pos = 0;
        self.chars = 0;
        self.handed = 0;
        self.unmark = Unmark::Plain;
        Ok(())
    }

    /// Writes every byte and returns when the last character leaves the UART: `now` plus their
    /// wire time (USS.md section 4). No `tcdrain`: it is slow on USB adapters.
    fn send(&mut self, bytes: &[u8], now: Duration) -> Result<Duration, TransportError> {
        let fd = self.fd();
        write_all(
            fd,
            bytes,
            self.write_stall,
            |rest| nix::unistd::write(fd, rest).map_err(std::io::Error::from),
            |e| line_failure(Errno::from_raw(e.raw_os_error().unwrap_or(0))),
        )?;
        Ok(if self.paced {
            now + self.timing.chars(bytes.len() as u64)
        } else {
            now
        })
    }

    /// A byte already read is returned at once, even after the deadline; otherwise waits in
    /// `ppoll` until input arrives or the deadline passes on `clock`. Bytes read together carry
    /// the time of that read.
    fn recv(
        &mut self,
        deadline: Duration,
        clock: &mut impl Clock,
    ) -> Result<Option<Rx>, TransportError> {
        loop {
            if let Some(rx) = self.next_buffered() {
                return Ok(Some(rx));
            }
            if self.fill(clock)? {
                continue;
            }
            if !input_by(self.fd(), deadline, clock)? {
                return Ok(None);
            }
        }
    }
}

/// Writes every byte of `bytes` to the non-blocking `fd` with `write`, waiting in `ppoll` while
/// the device takes nothing, at most `write_stall` each time ([`TransportError::Stalled`]): the
/// one send loop of every line kind. `failure` says what an error of `write` means for its kind
/// (a line gone, or an I/O error).
pub(crate) fn write_all(
    fd: BorrowedFd<'_>,
    bytes: &[u8],
    write_stall: Duration,
    mut write: impl FnMut(&[u8]) -> std::io::Result<usize>,
    failure: impl Fn(std::io::Error) -> TransportError,
) -> Result<(), TransportError> {
    let mut rest = bytes;
    while !rest.is_empty() {
        match write(rest) {
            Ok(n) if n > 0 => rest = &rest[n..],
            Ok(_) => {
                if !ready(fd, PollFlags::POLLOUT, write_stall)? {
                    return Err(TransportError::Stalled);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if !ready(fd, PollFlags::POLLOUT, write_stall)? {
                    return Err(TransportError::Stalled);
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(failure(e)),
        }
    }
    Ok(())
}

/// Waits in `ppoll` until `fd` has input (or hung up) or `deadline` passes on `clock`: false
/// once it passed. A signal counts as input: the caller reads (nothing) and asks again.
pub(crate) fn input_by(
    fd: BorrowedFd<'_>,
    deadline: Duration,
    clock: &mut impl Clock,
) -> Result<bool, TransportError> {
    let remaining = deadline.saturating_sub(clock.now());
    if remaining.is_zero() {
        return Ok(false);
    }
    let wait = remaining.min(MAX_WAIT);
    if !ready(fd, PollFlags::POLLIN, wait)? && wait == remaining {
        // ppoll waited the whole timeout; a clock other than the wall clock (a virtual one) is
        // moved to the deadline here.
        clock.sleep_until(deadline);
        return Ok(false);
    }
    Ok(true)
}

/// Waits until `fd` is ready for `events` (or hung up) or `timeout` passes; false on timeout.
/// A signal counts as ready: the caller retries and computes a fresh timeout.
pub(crate) fn ready(
    fd: BorrowedFd<'_>,
    events: PollFlags,
    timeout: Duration,
) -> Result<bool, TransportError> {
    let mut fds = [PollFd::new(fd, events)];
    match ppoll(&mut fds, Some(TimeSpec::from(timeout)), None) {
        Ok(0) => Ok(false),
        Ok(_) | Err(Errno::EINTR) => Ok(true),
        Err(errno) => Err(line_failure(errno)),
    }
}

/// Reads a UART's count of characters lost to overruns.
type OverrunProbe = fn(BorrowedFd<'_>) -> Result<u64, Errno>;

/// `struct serial_icounter_struct` of `linux/serial.h`.
#[repr(C)]
#[derive(Debug, Default)]
struct SerialIcounter {
    cts: c_int,
    dsr: c_int,
    rng: c_int,
    dcd: c_int,
    rx: c_int,
    tx: c_int,
    frame: c_int,
    overrun: c_int,
    parity: c_int,
    brk: c_int,
    buf_overrun: c_int,
    reserved: [c_int; 9],
}

/// Hardware (FIFO) and buffer overruns (`TIOCGICOUNT`).
fn read_overruns(fd: BorrowedFd<'_>) -> Result<u64, Errno> {
    let mut count = SerialIcounter::default();
    // SAFETY: the fd is open and `count` is a valid `struct serial_icounter_struct` to fill.
    unsafe { ioctl::tiocgicount(fd.as_raw_fd(), &raw mut count) }?;
    Ok(u64::from(count.overrun.unsigned_abs()) + u64::from(count.buf_overrun.unsigned_abs()))
}

/// Reads back the rate a port obtained (`None`: nothing to read, a pseudo-terminal).
pub type RateProbe = fn(BorrowedFd<'_>, bool) -> Result<Option<ReadBack>, Errno>;

/// The driver's word on the rate: termios's output speed (`TCGETS2`) and, for an 8250-family
/// UART, its divisor base (`TIOCGSERIAL`). A pseudo-terminal has no rate.
pub fn read_back_rate(
    fd: BorrowedFd<'_>,
    pseudo_terminal: bool,
) -> Result<Option<ReadBack>, Errno> {
    if pseudo_terminal {
        return Ok(None);
    }
    let mut t2 = core::mem::MaybeUninit::<nix::libc::termios2>::zeroed();
    // SAFETY: the fd is open and `t2` is a `struct termios2` for the kernel to fill.
    unsafe { ioctl::tcgets2(fd.as_raw_fd(), t2.as_mut_ptr()) }?;
    // SAFETY: zeroed, then filled by the kernel: every field is an integer.
    let t2 = unsafe { t2.assume_init() };
    let mut serial = SerialStruct::default();
    // SAFETY: as in `set_low_latency`. A driver without it (most USB adapters) refuses.
    let baud_base = match unsafe { ioctl::tiocgserial(fd.as_raw_fd(), &raw mut serial) } {
        // An 8250-family port: a known UART type and a divisor base.
        Ok(_) if serial.kind != 0 && serial.baud_base > 0 && serial.line >= 0 => {
            u32::try_from(serial.baud_base).ok()
        }
        _ => None,
    };
    Ok(Some(ReadBack {
        termios: t2.c_ospeed,
        baud_base,
    }))
}

fn port_fd(port: &TTYPort) -> BorrowedFd<'_> {
    // SAFETY: `port` owns this fd and keeps it open for as long as it lives, which the returned
    // borrow cannot outlive.
    unsafe { BorrowedFd::borrow_raw(port.as_raw_fd()) }
}

/// An errno from reading or writing the line: the ones an unplugged device or a closed pty gives
/// mean the line is gone.
fn line_failure(errno: Errno) -> TransportError {
    match errno {
        Errno::EIO | Errno::ENXIO | Errno::ENODEV => TransportError::Closed,
        other => TransportError::Io(other.into()),
    }
}

fn is_pseudo_terminal(fd: BorrowedFd<'_>) -> nix::Result<bool> {
    let major = major(fstat(fd)?.st_rdev);
    Ok(UNIX98_PTY_SLAVE_MAJORS.contains(&major) || major == BSD_PTY_SLAVE_MAJOR)
}

/// Makes the tty mark parity and framing errors in the stream instead of dropping or passing the
/// broken byte silently (USS.md section 4 counts them); a break becomes a marked NUL instead of
/// a signal. `VMIN` 1 and `VTIME` 0 make an empty non-blocking read EAGAIN, never 0.
fn mark_line_errors(fd: BorrowedFd<'_>) -> nix::Result<()> {
    let mut t = termios::tcgetattr(fd)?;
    t.input_flags |= InputFlags::INPCK | InputFlags::PARMRK;
    t.input_flags &=
        !(InputFlags::IGNPAR | InputFlags::ISTRIP | InputFlags::IGNBRK | InputFlags::BRKINT);
    t.control_chars[SpecialCharacterIndices::VMIN as usize] = 1;
    t.control_chars[SpecialCharacterIndices::VTIME as usize] = 0;
    termios::tcsetattr(fd, SetArg::TCSANOW, &t)
}

/// 8 data bits, even parity, one stop bit (USS.md section 2).
fn is_8e1(flags: ControlFlags) -> bool {
    flags & ControlFlags::CSIZE == ControlFlags::CS8
        && flags.contains(ControlFlags::PARENB)
        && !flags.intersects(ControlFlags::PARODD | ControlFlags::CMSPAR | ControlFlags::CSTOPB)
}

/// Turns the port's kernel RS485 mode on with what `wanted` changes and the rest as the port
/// has it (read first: `TIOCGRS485`); what the driver runs with, `None` if it left RS485 off.
fn enable_rs485(fd: BorrowedFd<'_>, wanted: Rs485Wanted) -> Result<Option<Rs485Kept>, Errno> {
    let mut current = SerialRs485::default();
    // SAFETY: the fd is open and `current` is a valid `struct serial_rs485` to fill.
    unsafe { ioctl::tiocgrs485(fd.as_raw_fd(), &raw mut current) }?;
    let mut rs485 = rs485_settings(current, wanted);
    // SAFETY: the fd is open and `rs485` is a valid `struct serial_rs485` the kernel reads and
    // writes back.
    unsafe { ioctl::tiocsrs485(fd.as_raw_fd(), &raw mut rs485) }?;
    Ok((rs485.flags & SER_RS485_ENABLED != 0).then_some(Rs485Kept {
        rts_high_while_sending: rs485.flags & SER_RS485_RTS_ON_SEND != 0,
        delay_before_ms: rs485.delay_rts_before_send,
        delay_after_ms: rs485.delay_rts_after_send,
    }))
}

/// The RS485 set-up to write: `current` (the driver's, perhaps from the device tree) enabled,
/// with what `wanted` says; a port that has no polarity yet gets RTS high while sending.
fn rs485_settings(current: SerialRs485, wanted: Rs485Wanted) -> SerialRs485 {
    let mut s = current;
    s.flags |= SER_RS485_ENABLED;
    let polarity = SER_RS485_RTS_ON_SEND | SER_RS485_RTS_AFTER_SEND;
    match wanted.rts_high_while_sending {
        Some(true) => s.flags = (s.flags & !polarity) | SER_RS485_RTS_ON_SEND,
        Some(false) => s.flags = (s.flags & !polarity) | SER_RS485_RTS_AFTER_SEND,
        None if s.flags & polarity == 0 => s.flags |= SER_RS485_RTS_ON_SEND,
        None => {}
    }
    if let Some(ms) = wanted.delay_before_ms {
        s.delay_rts_before_send = ms;
    }
    if let Some(ms) = wanted.delay_after_ms {
        s.delay_rts_after_send = ms;
    }
    s
}

fn set_low_latency(fd: BorrowedFd<'_>) -> Result<(), Errno> {
    let mut serial = SerialStruct::default();
    // SAFETY: the fd is open and `serial` is a valid `struct serial_struct` for the kernel to
    // fill.
    unsafe { ioctl::tiocgserial(fd.as_raw_fd(), &raw mut serial) }?;
    if serial.flags & ASYNC_LOW_LATENCY == 0 {
        serial.flags |= ASYNC_LOW_LATENCY;
        // SAFETY: as above; the kernel only reads `serial`.
        unsafe { ioctl::tiocsserial(fd.as_raw_fd(), &raw const serial) }?;
    }
    Ok(())
}

#[cfg(test)]
mod tests;
