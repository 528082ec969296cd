//! A serial device server's RS485 port over raw TCP (`device = "tcp://host:port"`): ser2net, a
//! Moxa `NPort` or a Lantronix server in TCP-server mode, reached by [`uss_serial::TcpTransport`].
//! The server sets 8E1 and the rate on its own port. A server that does not answer is a line
//! not there: the bus starts line down and connects when it answers, as for an adapter not
//! plugged in.
//!
//! Its receive latency, where not configured, is what a server may hold a received byte back
//! before it sends it on, plus the connection's round trip: ser2net waits 2 characters (at least
//! 1 ms) after each one and at most 20 ms (`chardelay`, `chardelay-min`, `chardelay-max`,
//! ser2net.yaml(5) of ser2net 4.3), so 20 ms unless `rx_latency_ms` says less (a server whose
//! hold-back is off, ser2net's `chardelay: false`).

use super::{LineKind, NotOpened, Opened};
use crate::config::{BusConfig, RxLatencyMs};
use core::time::Duration;
use uss_serial::{TcpOptions, TcpTransport};

/// ser2net's longest hold-back of received bytes by default (`chardelay-max`, 20000 us).
pub const SERVER_HOLD_BACK: Duration = Duration::from_millis(20);

/// A bus's serial device server port.
#[derive(Debug, Clone)]
pub struct TcpLine {
    address: String,
    baud: uss_protocol::Baud,
    configured_latency: Option<Duration>,
    /// The latest connection's round trip.
    round_trip: Duration,
}

impl TcpLine {
    pub fn new(bus: &BusConfig, address: &str) -> Self {
        Self {
            address: address.to_owned(),
            baud: bus.baud,
            configured_latency: bus.rx_latency_ms.map(RxLatencyMs::get),
            round_trip: Duration::ZERO,
        }
    }

    fn latency(&self) -> Duration {
        self.configured_latency
            .unwrap_or(SERVER_HOLD_BACK + self.round_trip)
    }
}

impl LineKind for TcpLine {
    type Transport = TcpTransport;

    fn name(&self) -> String {
        format!("tcp://{}", self.address)
    }

    fn open(&mut self) -> Result<Opened<TcpTransport>, NotOpened> {
        let options = TcpOptions {
            baud: self.baud,
            rx_latency: self.latency(),
        };
        let (transport, report) = TcpTransport::connect(&self.address, &options)
            .map_err(|e| NotOpened::NotThere(e.to_string()))?;
        // The latency allowed follows this connection's round trip.
        self.round_trip = report.round_trip;
        let report = uss_serial::ConnectReport {
            rx_latency: self.latency(),
            ..report
        };
        Ok(Opened {
            transport,
            report: report.to_string(),
        })
    }

    fn rx_latency(&mut self, bus: &str) -> Duration {
        let latency = self.latency();
        let source = match self.configured_latency {
            Some(_) => "configured (rx_latency_ms)".to_owned(),
            None => format!(
                "the server's hold-back allowance ({} ms, ser2net's chardelay-max) and the \
                 connection's round trip ({:.1} ms)",
                SERVER_HOLD_BACK.as_millis(),
                self.round_trip.as_secs_f64() * 1e3
            ),
        };
        tracing::info!(
            bus,
            device = %self.name(),
            "receive latency {:.1} ms, {source}: the residual-time and start-pause allowances and the response timeout widen by it",
            latency.as_secs_f64() * 1e3
        );
        latency
    }
}
