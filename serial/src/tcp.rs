//! USS through a serial device server: the RS485 port of a ser2net host, a Moxa `NPort` or a
//! Lantronix server in TCP-server ("raw") mode, reached as one TCP connection that carries the
//! line's bytes both ways and nothing else. The server sets 8E1 and the rate on its own port
//! (ser2net: `19200e81`); here the bytes are timed as on a UART: a request leaves the server's
//! port its wire time after it was written, and bytes read together are dated back by their
//! character times from their read, as a USB adapter's are. What the network and the server add
//! before a received byte is read (ser2net's `chardelay`, a Moxa's packing time) is the line's
//! receive latency, which the bus's timing allows for (`rx_latency_ms`, as for USB adapters).
//!
//! As on a serial device, nothing allocates after [`TcpTransport::connect`]: `send` and `recv`
//! run in the real-time thread. A connection the server closes (the server restarted, its port
//! taken by another client, the network gone) is the line failing: [`TransportError::Closed`],
//! and ussd's line thread connects again.

use core::fmt;
use core::time::Duration;
use std::io::{ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::os::fd::AsFd;
use std::time::Instant;
use thiserror::Error;
use uss_engine::{Clock, Rx, Transport, TransportError};
use uss_protocol::{Baud, Timing};

/// Bytes one read takes: several telegrams' worth (a server may deliver a reply with the rest of
/// an earlier one).
const READ_CHUNK: usize = 1024;

/// How long a connection attempt waits for the server.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);

/// How to reach the line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TcpOptions {
    /// The rate the server's port runs at (set there): the bytes' wire time.
    pub baud: Baud,
    /// How long the server may wait before it hands the network a received byte; reported
    /// with the connection.
    pub rx_latency: Duration,
}

/// A connection that could not be made.
#[derive(Debug, Error)]
pub enum TcpError {
    #[error("cannot reach {address}: not a host:port ({source})")]
    Resolve {
        address: String,
        source: std::io::Error,
    },
    #[error(
        "cannot connect to the serial device server at {address}: {source} (is the server up, its TCP port in raw mode, and no other client connected?)"
    )]
    Connect {
        address: String,
        source: std::io::Error,
    },
    #[error("cannot set up the connection to {address}: {step} failed ({source})")]
    Setup {
        address: String,
        step: &'static str,
        source: std::io::Error,
    },
}

/// What [`TcpTransport::connect`] obtained, for one log line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConnectReport {
    pub peer: SocketAddr,
    /// How long the connection took to be made: a round trip of the network, about.
    pub round_trip: Duration,
    pub rx_latency: Duration,
}

impl fmt::Display for ConnectReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "connected to the serial device server at {} (raw TCP, connected in {:.1} ms; 8E1 and \
             the rate are the server's port's; receive latency allowed {:.1} ms)",
            self.peer,
            self.round_trip.as_secs_f64() * 1e3,
            self.rx_latency.as_secs_f64() * 1e3
        )
    }
}

/// One TCP connection to a serial device server's port. See the module documentation.
pub struct TcpTransport {
    stream: TcpStream,
    timing: Timing,
    /// How long a write may wait for room before the line counts as stuck.
    write_stall: Duration,
    raw: [u8; READ_CHUNK],
    len: usize,
    pos: usize,
    /// When the bytes in `raw` were read.
    at: Duration,
}

impl fmt::Debug for TcpTransport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TcpTransport")
            .field("peer", &self.stream.peer_addr().ok())
            .field("baud", &self.timing.baud())
            .field("buffered", &(self.len - self.pos))
            .finish_non_exhaustive()
    }
}

impl TcpTransport {
    /// Connects to `address` (`host:port`) within [`CONNECT_TIMEOUT`], without Nagle's delay
    /// (a request goes out whole at once) and non-blocking, with keepalives so a silent network
    /// loss ends the connection; what the server sent before is dropped.
    pub fn connect(address: &str, options: &TcpOptions) -> Result<(Self, ConnectReport), TcpError> {
        let peers: Vec<SocketAddr> = address
            .to_socket_addrs()
            .map_err(|source| TcpError::Resolve {
                address: address.to_owned(),
                source,
            })?
            .collect();
        let started = Instant::now();
        let mut last = std::io::Error::new(ErrorKind::NotFound, "the name has no address");
        let mut connected = None;
        for peer in peers {
            match TcpStream::connect_timeout(&peer, CONNECT_TIMEOUT) {
                Ok(stream) => {
                    connected = Some((stream, peer));
                    break;
                }
                Err(e) => last = e,
            }
        }
        let (stream, peer) = connected.ok_or_else(|| TcpError::Connect {
            address: address.to_owned(),
            source: last,
        })?;
        let round_trip = started.elapsed();
        let setup = |step: &'static str| {
            move |source| TcpError::Setup {
                address: address.to_owned(),
                step,
                source,
            }
        };
        stream.set_nodelay(true).map_err(setup("TCP_NODELAY"))?;
        nix::sys::socket::setsockopt(&stream, nix::sys::socket::sockopt::KeepAlive, &true)
            .map_err(|e| setup("SO_KEEPALIVE")(e.into()))?;
        stream.set_nonblocking(true).map_err(setup("O_NONBLOCK"))?;
        let timing = Timing::new(options.baud);
        let mut transport = Self {
            stream,
            timing,
            write_stall: crate::write_stall(timing),
            raw: [0; READ_CHUNK],
            len: 0,
            pos: 0,
            at: Duration::ZERO,
        };
        transport
            .flush_input(Duration::ZERO)
            .map_err(|e| setup("the first read")(std::io::Error::other(e.to_string())))?;
        Ok((
            transport,
            ConnectReport {
                peer,
                round_trip,
                rx_latency: options.rx_latency,
            },
        ))
    }

    /// Reads what has arrived into the buffer, timestamped now; false when nothing had.
    fn fill(&mut self, clock: &impl Clock) -> Result<bool, TransportError> {
        loop {
            match self.stream.read(&mut self.raw) {
                // The server closed the connection.
                Ok(0) => return Err(TransportError::Closed),
                Ok(n) => {
                    self.len = n;
                    self.pos = 0;
                    self.at = clock.now();
                    return Ok(true);
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(false),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(connection_failure(e)),
            }
        }
    }
}

/// A connection that failed: reset or aborted by the server's side is the line closed.
fn connection_failure(e: std::io::Error) -> TransportError {
    match e.kind() {
        ErrorKind::ConnectionReset
        | ErrorKind::ConnectionAborted
        | ErrorKind::BrokenPipe
        | ErrorKind::NotConnected => TransportError::Closed,
        _ => TransportError::Io(e),
    }
}

impl Transport for TcpTransport {
    /// Drops what has arrived and what was read but not yet returned. Bytes still on the
    /// network arrive later: the framer's start pause and ADR check keep them out.
    fn flush_input(&mut self, _now: Duration) -> Result<(), TransportError> {
        self.len = 0;
        self.pos = 0;
        let mut scratch = [0u8; READ_CHUNK];
        loop {
            match self.stream.read(&mut scratch) {
                Ok(0) => return Err(TransportError::Closed),
                Ok(_) => {}
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(connection_failure(e)),
            }
        }
    }

    /// Writes every byte and returns when the last character leaves the server's port: `now`
    /// plus their wire time (USS.md section 4).
    fn send(&mut self, bytes: &[u8], now: Duration) -> Result<Duration, TransportError> {
        let stream = &self.stream;
        crate::write_all(
            stream.as_fd(),
            bytes,
            self.write_stall,
            |rest| (&*stream).write(rest),
            connection_failure,
        )?;
        Ok(now + self.timing.chars(bytes.len() as u64))
    }

    /// A byte already read is returned at once, even after the deadline; otherwise waits in
    /// `ppoll` until bytes arrive or the deadline passes on `clock`. Bytes read together are
    /// dated back from their read, the last one then, each before it a character earlier.
    fn recv(
        &mut self,
        deadline: Duration,
        clock: &mut impl Clock,
    ) -> Result<Option<Rx>, TransportError> {
        loop {
            if self.pos < self.len {
                let byte = self.raw[self.pos];
                self.pos += 1;
                let later = (self.len - self.pos) as u64;
                let at = self.at.saturating_sub(self.timing.chars(later));
                return Ok(Some(Rx {
                    byte,
                    at,
                    error: None,
                }));
            }
            if self.fill(clock)? {
                continue;
            }
            if !crate::input_by(self.stream.as_fd(), deadline, clock)? {
                return Ok(None);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use std::net::TcpListener;
    use uss_engine::MonotonicClock;

    fn options() -> TcpOptions {
        TcpOptions {
            baud: Baud::new(19_200).unwrap(),
            rx_latency: Duration::from_millis(2),
        }
    }

    /// A server's port, seen from the other end of the connection.
    fn connected() -> (TcpTransport, TcpStream) {
        let server = TcpListener::bind("127.0.0.1:0").unwrap();
        let address = server.local_addr().unwrap().to_string();
        let (transport, report) = TcpTransport::connect(&address, &options()).unwrap();
        assert_eq!(report.peer.to_string(), address);
        let (port, _) = server.accept().unwrap();
        (transport, port)
    }

    #[test]
    fn a_server_that_takes_nothing_is_a_stalled_write_and_one_that_closed_is_the_line_closed() {
        // The server never reads: once the socket's buffers are full, the shared send loop
        // waits a write stall's time and says so, never blocks on.
        let (mut t, port) = connected();
        let clock = MonotonicClock::new();
        let chunk = [0x55u8; 1024];
        let outcome = (0..1_000_000)
            .map(|_| t.send(&chunk, clock.now()))
            .find(Result::is_err);
        assert!(
            matches!(outcome, Some(Err(TransportError::Stalled))),
            "{outcome:?}"
        );
        // The server is gone: a write fails as the line closed (reset or broken pipe).
        drop(port);
        let (mut t, port) = connected();
        drop(port);
        let outcome = (0..1000)
            .map(|_| {
                std::thread::sleep(Duration::from_millis(1));
                t.send(&chunk, clock.now())
            })
            .find(Result::is_err);
        assert!(
            matches!(outcome, Some(Err(TransportError::Closed))),
            "{outcome:?}"
        );
    }

    #[test]
    fn bytes_go_out_whole_and_come_back_dated_by_their_wire_time() {
        let (mut t, mut port) = connected();
        let mut clock = MonotonicClock::new();
        let now = clock.now();
        let done = t.send(&[0x02, 0x06, 0x03], now).unwrap();
        let timing = Timing::new(options().baud);
        assert_eq!(done, now + timing.chars(3), "three characters' wire time");
        let mut got = [0u8; 3];
        port.read_exact(&mut got).unwrap();
        assert_eq!(got, [0x02, 0x06, 0x03]);
        port.write_all(&[0x02, 0x04, 0x05]).unwrap();
        let deadline = clock.now() + Duration::from_secs(2);
        let first = t.recv(deadline, &mut clock).unwrap().unwrap();
        let mut rest = vec![first];
        while rest.len() < 3 {
            rest.push(t.recv(deadline, &mut clock).unwrap().unwrap());
        }
        assert_eq!(
            rest.iter().map(|r| r.byte).collect::<Vec<_>>(),
            [0x02, 0x04, 0x05]
        );
        if rest[2].at == rest[0].at + timing.chars(2) {
            // Read together: dated back a character apart.
        } else {
            assert!(rest[2].at > rest[0].at, "read apart: in order");
        }
        assert!(rest.iter().all(|r| r.error.is_none()));
    }

    #[test]
    fn nothing_arrives_by_the_deadline_and_a_closed_connection_is_the_line_closed() {
        let (mut t, port) = connected();
        let mut clock = MonotonicClock::new();
        let deadline = clock.now() + Duration::from_millis(20);
        assert!(t.recv(deadline, &mut clock).unwrap().is_none());
        assert!(clock.now() >= deadline);
        drop(port);
        let deadline = clock.now() + Duration::from_secs(2);
        assert!(matches!(
            t.recv(deadline, &mut clock),
            Err(TransportError::Closed)
        ));
    }

    #[test]
    fn no_server_is_a_connect_error_naming_the_address() {
        let server = TcpListener::bind("127.0.0.1:0").unwrap();
        let address = server.local_addr().unwrap().to_string();
        drop(server);
        let e = TcpTransport::connect(&address, &options()).unwrap_err();
        assert!(matches!(e, TcpError::Connect { .. }), "{e}");
        assert!(e.to_string().contains(&address), "{e}");
        let e = TcpTransport::connect("no port here", &options()).unwrap_err();
        assert!(matches!(e, TcpError::Resolve { .. }), "{e}");
    }
}
