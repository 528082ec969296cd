//! A serial device: a USB adapter, an embedded UART, or a pseudo-terminal, opened at 8E1 by
//! [`uss_serial::SerialTransport`]; its receive latency read from sysfs where not configured
//! (an FTDI latency timer, an 8250 FIFO trigger, a USB frame).

use super::{Line, LineKind, NotOpened, Opened};
use crate::config::{BusConfig, Rs485Delay, Rs485Mode, Rs485Rts, RxLatencyMs};
use core::time::Duration;
use std::path::{Path, PathBuf};
use uss_protocol::Timing;
use uss_serial::latency::{self, RxLatency, Source};
use uss_serial::{Rs485Wanted, SerialError, SerialOptions, SerialTransport};

/// A bus's serial device, opened by its configured path (a replugged adapter is opened again
/// by name).
#[derive(Debug, Clone)]
pub struct SerialLine {
    path: PathBuf,
    options: SerialOptions,
    baud: uss_protocol::Baud,
    configured_latency: Option<Duration>,
}

impl SerialLine {
    pub fn new(bus: &BusConfig, path: &Path) -> Self {
        Self {
            path: path.to_owned(),
            options: SerialOptions {
                baud: bus.baud,
                kernel_rs485: bus.rs485 == Rs485Mode::Kernel,
                rs485_settings: Rs485Wanted {
                    rts_high_while_sending: bus.rs485_rts.map(|r| r == Rs485Rts::HighWhileSending),
                    delay_before_ms: bus.rs485_delay_before_ms.map(Rs485Delay::get),
                    delay_after_ms: bus.rs485_delay_after_ms.map(Rs485Delay::get),
                },
                low_latency: true,
                rx_latency: bus.rx_latency_ms.map_or(Duration::ZERO, RxLatencyMs::get),
            },
            baud: bus.baud,
            configured_latency: bus.rx_latency_ms.map(RxLatencyMs::get),
        }
    }
}

impl LineKind for SerialLine {
    type Transport = SerialTransport;

    fn name(&self) -> String {
        self.path.display().to_string()
    }

    fn open(&mut self) -> Result<Opened<SerialTransport>, NotOpened> {
        match SerialTransport::open(&self.path, &self.options) {
            Ok((transport, report)) => Ok(Opened {
                transport,
                report: report.to_string(),
            }),
            // Not plugged in yet, or udev has not named it yet.
            Err(SerialError::NotFound { .. }) => Err(NotOpened::NotThere(format!(
                "{} is not there",
                self.path.display()
            ))),
            Err(e) => Err(NotOpened::Refused(Box::new(e))),
        }
    }

    /// As configured, else as sysfs describes the device; read again at every open (after it:
    /// a granted `ASYNC_LOW_LATENCY` lowers an FTDI latency timer; a replug may bring another
    /// adapter).
    fn rx_latency(&mut self, bus: &str) -> Duration {
        let found = match self.configured_latency {
            Some(latency) => RxLatency {
                latency,
                source: Source::Configured,
            },
            None => latency::detect(Path::new("/sys"), &self.path, Timing::new(self.baud)),
        };
        let device = self.path.display();
        tracing::info!(
            bus,
            device = %device,
            "receive latency {found}: the residual-time and start-pause allowances and the response timeout widen by it"
        );
        if let Some(warning) = found.warning() {
            tracing::warn!(bus, device = %device, "{warning}");
        }
        found.latency
    }

    /// Drops its unsent output first (nothing queued for it is still wanted, and a tty closed
    /// with output queued waits up to 30 s for it to drain), then [`Line::take`].
    fn release(line: &mut Line<SerialTransport>) -> Option<Line<SerialTransport>> {
        if let Line::Open(t) = line {
            t.discard_output();
        }
        line.take()
    }
}
