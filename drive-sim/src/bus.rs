//! A simulated bus: any set of drives at addresses 0..=31, each with its own fault plan. The bus
//! decides who answers a telegram (USS.md sections 1 and 3): only the addressed drive, never for
//! a broadcast, never a telegram received with errors; a mirror telegram comes back unchanged.

use crate::drive::{Drive, DriveConfig};
use crate::fault::{FaultPlan, Reply};
use core::time::Duration;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use thiserror::Error;
use uss_protocol::telegram::MAX_TELEGRAM_BYTES;
use uss_protocol::{Address, FrameError, Telegram};

/// A drive on the bus and what happens to its replies.
#[derive(Debug, Clone)]
pub struct Slot {
    pub drive: Drive,
    pub faults: FaultPlan,
    /// Switched off until then by a power cycle ([`SimBus::power_cycle`]): it hears and answers
    /// nothing, and comes back from its EEPROM.
    pub off_until: Option<Duration>,
}

impl Slot {
    /// Whether it hears the line at `now`: plugged in and powered.
    fn hears(&self, now: Duration) -> bool {
        !self.faults.is_unplugged(now) && self.off_until.is_none()
    }
}

/// A bus that cannot be built as asked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum BusError {
    #[error("two drives have address {0}: every drive on a bus needs its own")]
    DuplicateAddress(Address),
}

/// The simulated bus. Deterministic for a given seed.
#[derive(Debug)]
pub struct SimBus {
    slots: [Option<Box<Slot>>; 32],
    rng: SmallRng,
    /// Telegrams addressed to no drive on the bus.
    pub unanswered: u64,
    /// Set from outside (uss-sim's SIGUSR1): every drive is power-cycled at the next
    /// [`SimBus::advance`], off for `power_off`.
    power_switch: Option<(Arc<AtomicBool>, Duration)>,
}

impl SimBus {
    pub fn new(seed: u64) -> Self {
        Self {
            slots: Default::default(),
            rng: SmallRng::seed_from_u64(seed),
            unanswered: 0,
            power_switch: None,
        }
    }

    /// Adds a drive; addresses must be unique.
    pub fn add(&mut self, config: DriveConfig) -> Result<(), BusError> {
        let slot = &mut self.slots[config.address.get() as usize];
        if slot.is_some() {
            return Err(BusError::DuplicateAddress(config.address));
        }
        *slot = Some(Box::new(Slot {
            drive: Drive::new(config),
            faults: FaultPlan::new(),
            off_until: None,
        }));
        Ok(())
    }

    pub fn slot(&self, address: Address) -> Option<&Slot> {
        self.slots[address.get() as usize].as_deref()
    }

    pub fn slot_mut(&mut self, address: Address) -> Option<&mut Slot> {
        self.slots[address.get() as usize].as_deref_mut()
    }

    pub fn drive(&self, address: Address) -> Option<&Drive> {
        self.slot(address).map(|s| &s.drive)
    }

    pub fn drive_mut(&mut self, address: Address) -> Option<&mut Drive> {
        self.slot_mut(address).map(|s| &mut s.drive)
    }

    pub fn faults_mut(&mut self, address: Address) -> Option<&mut FaultPlan> {
        self.slot_mut(address).map(|s| &mut s.faults)
    }

    /// Whether a drive's fault plan hangs the line at `now` ([`FaultPlan::hang`]).
    pub fn hangs(&self, now: Duration) -> bool {
        self.slots.iter().flatten().any(|s| s.faults.hangs(now))
    }

    /// Every drive set up for a line at `baud` ([`Drive::commission_line`]).
    pub fn commission_line(&mut self, baud: uss_protocol::Baud) {
        for s in self.slots.iter_mut().flatten() {
            s.drive.commission_line(baud);
        }
    }

    /// Every drive on the bus, by ascending address.
    pub fn drives(&self) -> impl Iterator<Item = &Drive> {
        self.slots.iter().flatten().map(|s| &s.drive)
    }

    /// A power cycle of every drive (the cabinet's supply switched off and on): each is off
    /// for `off` from `now`, answering nothing, then starts again with its RAM from EEPROM, in
    /// S1, its counters cleared ([`Drive::power_cycle`]).
    pub fn power_cycle(&mut self, now: Duration, off: Duration) {
        for slot in self.slots.iter_mut().flatten() {
            slot.off_until = Some(now + off);
        }
    }

    /// `flag` set (by a signal handler) power-cycles every drive at the next
    /// [`SimBus::advance`], off for `off`; the flag is cleared then.
    pub fn power_switch(&mut self, flag: Arc<AtomicBool>, off: Duration) {
        self.power_switch = Some((flag, off));
    }

    /// Moves every drive's model to `now`; a drive switched off comes back when its time is up.
    pub fn advance(&mut self, now: Duration) {
        if let Some((flag, off)) = &self.power_switch
            && flag.swap(false, Ordering::Relaxed)
        {
            let off = *off;
            self.power_cycle(now, off);
        }
        for slot in self.slots.iter_mut().flatten() {
            if slot.off_until.is_some_and(|until| now >= until) {
                slot.off_until = None;
                slot.drive.power_cycle();
            }
            slot.drive.advance(now);
        }
    }

    /// A receive error on the line: every plugged-in drive hears it and counts it.
    pub fn on_error(&mut self, error: &FrameError, now: Duration) {
        for slot in self.slots.iter_mut().flatten() {
            if slot.hears(now) {
                slot.drive.count_error(error);
            }
        }
    }

    /// A valid telegram whose BCC arrived at `now`. Returns the reply to send, if any.
    pub fn on_telegram(&mut self, telegram: &Telegram<'_>, now: Duration) -> Option<Reply> {
        let adr = telegram.adr();
        if adr.broadcast {
            for slot in self.slots.iter_mut().flatten() {
                if slot.hears(now) {
                    slot.drive.receive_broadcast(telegram, now);
                }
            }
            return None;
        }
        let Some(slot) = self.slots[adr.address.get() as usize].as_deref_mut() else {
            self.unanswered += 1;
            return None;
        };
        if !slot.hears(now) {
            return None;
        }
        let config = slot.drive.config();
        let jitter = config.response_jitter.as_nanos() as u64;
        let delay = config.response_delay
            + Duration::from_nanos(if jitter > 0 {
                self.rng.random_range(0..=jitter)
            } else {
                0
            });
        if adr.special {
            // These drives define no special telegrams: rejected, no reply.
            slot.drive.count_rejected();
            return None;
        }
        let reply = if adr.is_mirror() {
            Reply::new(telegram.as_bytes(), delay)
        } else {
            let mut buf = [0u8; MAX_TELEGRAM_BYTES];
            let len = slot.drive.receive(telegram, now, &mut buf)?;
            Reply::new(&buf[..len], delay)
        };
        slot.faults.apply(reply, &mut self.rng)
    }
}
