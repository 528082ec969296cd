//! Serving a simulated bus on a serial device or a pseudo-terminal.
//!
//! The loop reads what arrives, frames it with the real clock (start pause and residual time as
//! in USS.md section 4), lets the bus answer, waits the response delay and writes the reply. On a
//! real UART bytes take wire time; a pseudo-terminal moves them instantly and carries no parity
//! (USS.md section 9), so the start pause after a reply counts from the write there.

use crate::bus::SimBus;
use crate::fault::Reply;
use core::time::Duration;
use nix::poll::{PollFd, PollFlags, ppoll};
use nix::sys::termios::{self, ControlFlags, SetArg};
use nix::sys::time::TimeSpec;
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
    /// Waits until `at` (what is due meanwhile goes out, where delivery is imitated).
    fn wait_until(&mut self, at: Instant) -> io::Result<()> {
        std::thread::sleep(at.saturating_duration_since(Instant::now()));
        Ok(())
    }
    /// When a telegram of `chars` characters whose last one was read at `read_at` ended on
    /// the wire: then, where bytes arrive at their wire pace (a UART); an imitated adapter on a
    /// pty gets the master's bytes at once, so theirs ends its characters' wire time later.
    fn request_end(&self, read_at: Duration, chars: usize) -> Duration {
        let _ = chars;
        read_at
    }
    /// The master's request, heard back on its own line (a 2-wire adapter's echo; only
    /// [`Delivered`] imitates one).
    fn echo(&mut self, request: &[u8]) -> io::Result<()> {
        let _ = request;
        Ok(())
    }
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
        // To the nanosecond (poll's milliseconds would blur an imitated adapter's delivery).
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
        match ppoll(&mut fds, Some(TimeSpec::from(timeout)), None) {
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
    // The drives' baud rate settings name the line's rate.
    bus.commission_line(timing.baud());
    while !stop.load(Ordering::Relaxed) {
        if bus.hangs(start.elapsed()) {
            // The injected hang: read nothing, answer nothing, until stopped.
            std::thread::sleep(TICK);
            continue;
        }
        let n = port.read_some(&mut buf, TICK)?;
        let now = start.elapsed();
        bus.advance(now);
        if n > 0 {
            port.echo(&buf[..n])?;
        }
        for &b in &buf[..n] {
            let reply = match framer.push(b, now) {
                Some(Ok(telegram)) => {
                    let chars = telegram.as_bytes().len();
                    bus.on_telegram(&telegram, now).map(|r| (r, chars))
                }
                Some(Err(e)) => {
                    bus.on_error(&e, now);
                    None
                }
                None => None,
            };
            if let Some((reply, chars)) = reply {
                let request_end = port.request_end(now, chars);
                let end = send(port, &reply, timing, start, request_end)?;
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
    port.wait_until(start + due)?;
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

/// How the bytes toward the master reach it, imitating what adapters do on a pseudo-terminal
/// (which otherwise hands over every write at once).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Delivery {
    /// Bytes take their wire time (the master's too: a reply waits for the request's) and are
    /// handed over together at every multiple of this since the start: a USB adapter's latency
    /// timer (FTDI: 16 ms by default, 1 ms at best), a UART's FIFO trigger. Zero: each byte
    /// at its own wire time (a UART without FIFO).
    pub tick: Option<Duration>,
    /// Each reply handed over in two halves this far apart (a packet boundary mid-reply).
    pub split: Option<Duration>,
    /// Each reply held until this long after its last byte left the wire, then handed over in
    /// one burst (a late packet).
    pub late: Option<Duration>,
    /// The master's own request comes back before the reply, at its wire time (a 2-wire
    /// adapter's echo).
    pub echo: bool,
}

impl Delivery {
    /// Whether anything differs from a pseudo-terminal's at-once delivery.
    pub fn is_imitated(&self) -> bool {
        *self != Self::default()
    }
}

/// A port whose outgoing bytes are handed over as [`Delivery`] says: each byte is given its
/// wire time, then delivered (written, one `write` per hand-over, so the master reads them
/// together) when due.
#[derive(Debug)]
pub struct Delivered<P> {
    inner: P,
    delivery: Delivery,
    timing: Timing,
    start: Instant,
    /// When the simulated wire is free again (bytes queue behind each other).
    wire_free: Duration,
    /// Bytes and when each is handed over, in order.
    queue: std::collections::VecDeque<(Duration, u8)>,
}

impl<P: Port> Delivered<P> {
    pub fn new(inner: P, delivery: Delivery, timing: Timing, start: Instant) -> Self {
        Self {
            inner,
            delivery,
            timing,
            start,
            wire_free: Duration::ZERO,
            queue: std::collections::VecDeque::new(),
        }
    }

    pub fn inner(&self) -> &P {
        &self.inner
    }

    /// Queues `bytes` whose first character starts on the wire at `first` (or when the wire is
    /// free, if later); a reply gets the split and late faults.
    fn queue(&mut self, bytes: &[u8], first: Duration, reply: bool) {
        let char_time = self.timing.chars(1);
        let begin = first.max(self.wire_free);
        let half = bytes.len().div_ceil(2);
        let last_at = begin + char_time * bytes.len() as u32;
        for (i, &b) in bytes.iter().enumerate() {
            let on_wire = begin + char_time * (i as u32 + 1);
            let mut at = match self.delivery.tick {
                Some(tick) if !tick.is_zero() => {
                    let n = on_wire.as_nanos().div_ceil(tick.as_nanos());
                    Duration::from_nanos(u64::try_from(n * tick.as_nanos()).unwrap_or(u64::MAX))
                }
                _ => on_wire,
            };
            if reply {
                if let Some(late) = self.delivery.late {
                    at = at.max(last_at + late);
                }
                if let (Some(split), true) = (self.delivery.split, i >= half) {
                    at = at.max(begin + char_time * half as u32 + split);
                }
            }
            self.queue.push_back((at, b));
        }
        self.wire_free = last_at;
    }

    /// Hands over every byte due by now, in one write.
    fn deliver_due(&mut self) -> io::Result<()> {
        let now = self.start.elapsed();
        let mut out = [0u8; 512];
        let mut n = 0;
        while let Some(&(at, b)) = self.queue.front() {
            if at > now || n == out.len() {
                break;
            }
            out[n] = b;
            n += 1;
            self.queue.pop_front();
        }
        if n > 0 {
            self.inner.write_all(&out[..n])?;
        }
        Ok(())
    }

    fn next_due(&self) -> Option<Duration> {
        self.queue.front().map(|&(at, _)| at)
    }
}

impl<P: Port> Port for Delivered<P> {
    fn read_some(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        self.deliver_due()?;
        let now = self.start.elapsed();
        let wait = self
            .next_due()
            .map_or(timeout, |at| timeout.min(at.saturating_sub(now)));
        let n = self.inner.read_some(buf, wait)?;
        self.deliver_due()?;
        Ok(n)
    }

    fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        let now = self.start.elapsed();
        self.queue(bytes, now, true);
        self.deliver_due()
    }

    fn paces_bytes(&self) -> bool {
        true
    }

    fn wait_until(&mut self, at: Instant) -> io::Result<()> {
        loop {
            self.deliver_due()?;
            let now = Instant::now();
            if now >= at {
                return Ok(());
            }
            let next = self.next_due().map_or(at, |due| (self.start + due).min(at));
            std::thread::sleep(next.saturating_duration_since(now));
        }
    }

    fn request_end(&self, read_at: Duration, chars: usize) -> Duration {
        read_at + self.timing.chars(chars as u64)
    }

    fn echo(&mut self, request: &[u8]) -> io::Result<()> {
        if !self.delivery.echo {
            return Ok(());
        }
        // The request's characters go onto the wire from now, as the master wrote them.
        let now = self.start.elapsed();
        self.queue(request, now, false);
        self.deliver_due()
    }
}

#[cfg(test)]
mod delivery_tests {
    use super::*;
    use uss_protocol::Baud;

    /// A port that records each write with its time.
    #[derive(Default)]
    struct Recorder {
        writes: Vec<(Duration, Vec<u8>)>,
        start: Option<Instant>,
    }

    impl Port for Recorder {
        fn read_some(&mut self, _buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
            std::thread::sleep(timeout);
            Ok(0)
        }
        fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
            let at = self.start.unwrap().elapsed();
            self.writes.push((at, bytes.to_vec()));
            Ok(())
        }
        fn paces_bytes(&self) -> bool {
            false
        }
    }

    fn delivered(delivery: Delivery) -> Delivered<Recorder> {
        let start = Instant::now();
        let recorder = Recorder {
            start: Some(start),
            ..Recorder::default()
        };
        Delivered::new(
            recorder,
            delivery,
            Timing::new(Baud::new(9600).unwrap()),
            start,
        )
    }

    fn run_until(d: &mut Delivered<Recorder>, ms: u64) {
        d.wait_until(d.start + Duration::from_millis(ms)).unwrap();
    }

    #[test]
    fn a_latency_tick_hands_bytes_over_in_packets_at_their_wire_time_or_later() {
        // 9600 baud: 1.146 ms a character; 16 ms ticks.
        let mut d = delivered(Delivery {
            tick: Some(Duration::from_millis(16)),
            ..Delivery::default()
        });
        d.write_all(&[1; 20]).unwrap();
        run_until(&mut d, 40);
        let writes = &d.inner().writes;
        // 20 characters take 22.9 ms: 13 are on the wire by the 16 ms tick, the rest by 32 ms.
        assert_eq!(writes.len(), 2, "{writes:?}");
        assert_eq!((writes[0].1.len(), writes[1].1.len()), (13, 7));
        assert!(
            writes[0].0 >= Duration::from_millis(16) && writes[1].0 >= Duration::from_millis(32)
        );
    }

    #[test]
    fn a_split_reply_comes_in_two_halves_and_a_late_one_in_one_burst() {
        let mut d = delivered(Delivery {
            split: Some(Duration::from_millis(10)),
            ..Delivery::default()
        });
        d.write_all(&[2; 6]).unwrap();
        run_until(&mut d, 30);
        // Without a tick each character is handed over at its own wire time: the first half by
        // then (characters due while the thread slept, on a loaded machine, come together), the
        // second in one burst 10 ms after the first half ended.
        let (last, first) = d.inner().writes.split_last().unwrap();
        assert_eq!(
            first.iter().map(|w| w.1.len()).sum::<usize>(),
            3,
            "{first:?}"
        );
        assert!(
            first.iter().all(|w| w.0 < Duration::from_millis(13)),
            "{first:?}"
        );
        assert_eq!(last.1.len(), 3);
        assert!(last.0 >= Duration::from_millis(13));

        let mut d = delivered(Delivery {
            late: Some(Duration::from_millis(25)),
            ..Delivery::default()
        });
        d.write_all(&[3; 6]).unwrap();
        run_until(&mut d, 45);
        assert_eq!(d.inner().writes.len(), 1);
        assert!(d.inner().writes[0].0 >= Duration::from_millis(31));
    }

    #[test]
    fn an_echo_and_the_reply_come_in_one_packet_at_a_long_tick() {
        let mut d = delivered(Delivery {
            tick: Some(Duration::from_millis(16)),
            echo: true,
            ..Delivery::default()
        });
        d.echo(&[4; 3]).unwrap();
        d.write_all(&[5; 3]).unwrap();
        run_until(&mut d, 20);
        assert_eq!(d.inner().writes.len(), 1);
        assert_eq!(d.inner().writes[0].1, [4, 4, 4, 5, 5, 5]);
    }
}
