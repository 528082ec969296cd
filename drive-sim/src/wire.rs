//! The in-process virtual wire: the master's transport in tests and benchmarks attaches here.
//!
//! Bytes take their real wire time (11 bits per character at the bus's baud rate, USS.md
//! section 2); the simulated drives see the request byte by byte through their own framer, with
//! its start-pause and residual-time rules, and their replies arrive after the response delay,
//! again one character time apart. The wire holds no clock: the caller says what time it is, so
//! the same wire runs on a virtual clock in tests and paced in real time in benchmarks.

use crate::bus::SimBus;
use core::time::Duration;
use std::collections::VecDeque;
use uss_protocol::{FrameError, Framer, FramerConfig, LineError, Timing};

/// One character arriving at the master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RxByte {
    pub byte: u8,
    /// When its stop bit ended.
    pub at: Duration,
    /// A UART error flagged on this character.
    pub error: Option<LineError>,
}

/// Bytes the wire can hold for the master before the oldest are lost (an overrun).
const INBOX_CAPACITY: usize = 4096;

/// The virtual wire between one master and a [`SimBus`].
#[derive(Debug)]
pub struct VirtualWire {
    bus: SimBus,
    timing: Timing,
    framer: Framer,
    echo: bool,
    inbox: VecDeque<RxByte>,
    line_busy_until: Duration,
    overruns: u64,
}

impl VirtualWire {
    pub fn new(mut bus: SimBus, timing: Timing) -> Self {
        // The drives' baud rate settings name the line's rate.
        bus.commission_line(timing.baud());
        Self {
            bus,
            timing,
            framer: Framer::new(FramerConfig::strict(timing)),
            echo: false,
            inbox: VecDeque::with_capacity(INBOX_CAPACITY),
            line_busy_until: Duration::ZERO,
            overruns: 0,
        }
    }

    /// Returns the master's own bytes to it, as a 2-wire RS485 adapter does (USS.md section 9).
    #[must_use]
    pub fn with_echo(mut self, echo: bool) -> Self {
        self.echo = echo;
        self
    }

    pub const fn timing(&self) -> Timing {
        self.timing
    }

    pub const fn bus(&self) -> &SimBus {
        &self.bus
    }

    pub fn bus_mut(&mut self) -> &mut SimBus {
        &mut self.bus
    }

    /// Bytes lost because the master did not read them in time.
    pub const fn overruns(&self) -> u64 {
        self.overruns
    }

    /// The master starts sending `bytes` at `at`. The drives hear each character when its stop
    /// bit ends and answer after their response delay. Returns when the last character has left.
    pub fn transmit(&mut self, bytes: &[u8], at: Duration) -> Duration {
        if self.bus.hangs(at) {
            // The injected hang (`hang=` in a drive spec): this call never returns.
            loop {
                std::thread::sleep(Duration::from_secs(3600));
            }
        }
        let tz = self.timing.char_time();
        let mut t = at;
        for &b in bytes {
            t += tz;
            if self.echo {
                self.deliver(RxByte {
                    byte: b,
                    at: t,
                    error: None,
                });
            }
            match self.framer.push(b, t) {
                Some(Ok(telegram)) => {
                    if let Some(reply) = self.bus.on_telegram(&telegram, t) {
                        // A slave keeps the start pause before its reply too (USS.md section 4).
                        let mut r = t + reply.delay.max(self.timing.earliest_reply());
                        for (i, &rb) in reply.bytes().iter().enumerate() {
                            r += tz;
                            let error =
                                (reply.parity_error_at == Some(i)).then_some(LineError::Parity);
                            self.deliver(RxByte {
                                byte: rb,
                                at: r,
                                error,
                            });
                        }
                        self.line_busy_until = self.line_busy_until.max(r);
                    }
                }
                Some(Err(e)) => self.bus.on_error(&e, t),
                None => {}
            }
        }
        // The drives hear the replies on the bus too: the start pause counts from their end.
        self.framer.line_busy_until(self.line_busy_until.max(t));
        // Ramps and telegram monitoring move on once per request (the addressed drive has
        // already caught up when it received it).
        self.bus.advance(t);
        t
    }

    /// Reports a receive error seen by every drive, as if the line had been disturbed.
    pub fn disturb(&mut self, error: &FrameError, at: Duration) {
        self.bus.on_error(error, at);
    }

    /// When the next byte for the master arrives, if one is on its way.
    pub fn next_arrival(&self) -> Option<Duration> {
        self.inbox.front().map(|b| b.at)
    }

    /// The next byte that has arrived by `now`.
    pub fn receive(&mut self, now: Duration) -> Option<RxByte> {
        if self.inbox.front().is_some_and(|b| b.at <= now) {
            self.inbox.pop_front()
        } else {
            None
        }
    }

    /// Discards what has arrived by `now` (the master's input flush); bytes still on their way
    /// are not affected, just as with a real UART.
    pub fn flush_input(&mut self, now: Duration) {
        while self.receive(now).is_some() {}
    }

    /// Moves the drives' models to `now` (ramps, telegram monitoring).
    pub fn advance(&mut self, now: Duration) {
        self.bus.advance(now);
    }

    /// Inserts in arrival order; a late reply may still be arriving when the next request's echo
    /// is. Drops the oldest byte when full, like a UART overrun, without allocating.
    fn deliver(&mut self, byte: RxByte) {
        if self.inbox.len() == INBOX_CAPACITY {
            self.inbox.pop_front();
            self.overruns += 1;
        }
        let pos = self.inbox.partition_point(|b| b.at <= byte.at);
        self.inbox.insert(pos, byte);
    }
}
