//! The in-process virtual wire as the engine's transport (feature `transport`): ussd's built-in
//! simulated bus (`device = "sim"`) and the engine's tests and benchmarks.

use core::time::Duration;
use uss_engine::{Clock, Rx, Transport, TransportError};

use crate::VirtualWire;

/// The in-process virtual wire to simulated drives: bytes take their real wire time. Every
/// request moves every drive's model (ramps, telegram monitoring) up to its time
/// ([`VirtualWire::transmit`]), the addressed drive before it answers: the engine needs to tell
/// the wire nothing more while it waits.
#[derive(Debug)]
pub struct SimTransport {
    wire: VirtualWire,
}

impl SimTransport {
    pub const fn new(wire: VirtualWire) -> Self {
        Self { wire }
    }

    pub const fn wire(&self) -> &VirtualWire {
        &self.wire
    }

    /// The wire and its drives, for fault injection and inspection in tests.
    pub fn wire_mut(&mut self) -> &mut VirtualWire {
        &mut self.wire
    }
}

impl Transport for SimTransport {
    fn flush_input(&mut self, now: Duration) -> Result<(), TransportError> {
        self.wire.flush_input(now);
        Ok(())
    }

    fn send(&mut self, bytes: &[u8], now: Duration) -> Result<Duration, TransportError> {
        Ok(self.wire.transmit(bytes, now))
    }

    fn recv(
        &mut self,
        deadline: Duration,
        clock: &mut impl Clock,
    ) -> Result<Option<Rx>, TransportError> {
        match self.wire.next_arrival() {
            Some(at) if at <= deadline => {
                clock.sleep_until(at);
                Ok(self.wire.receive(at).map(|b| Rx {
                    byte: b.byte,
                    at: b.at,
                    error: b.error,
                }))
            }
            _ => {
                clock.sleep_until(deadline);
                Ok(None)
            }
        }
    }
}
