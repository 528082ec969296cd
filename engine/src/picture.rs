//! What ussd knows of a drive, kept true (issue 46): the values it scales and judges the drive
//! by (its reference frequency, [`super::reference`]; its telegram monitoring,
//! [`super::monitoring`]) are read again whenever they can have changed, and are not used while
//! they are unknown.
//!
//! When they are read again:
//! - the drive came (back) online: it may have been replaced, reset or power-cycled; until the
//!   reads come back both are unknown (a controller's Hz are refused, `require_monitoring`
//!   refuses ON);
//! - a poll of it failed all its retries and a later one got through: it may have restarted;
//! - a write of one of the parameters that may change every setting took effect (the
//!   commissioning parameter, the factory reset, the end of quick commissioning:
//!   [`Rereads`]): both are unknown until read again;
//! - every [`REFRESH_POLLS`] good replies of the drive, in the background: a change made where
//!   ussd cannot see it (the drive's own panel, STARTER on another interface, a power cycle
//!   shorter than a poll) is found within that many exchanges. The reads ride in the PKW words
//!   every telegram carries anyway, so they add no telegram to the bus.
//!
//! A reference that comes back different from the one last read while a controller holds the
//! drive latches it ([`LatchReason::ReferenceChanged`]): the controller's setpoint was scaled
//! with the old value, and the drive would run at a speed nobody commanded.

use super::clock::Clock;
use super::jobs::JobResult;
use super::transport::Transport;
use super::{Bridge, Engine, Event, Monitoring};
use uss_protocol::{ParamTask, Pnu};
use uss_shm_types::LatchReason;

/// How many good replies of a drive go by between two background reads of what ussd knows of
/// it: at 19200 baud one drive alone is polled about every 10 ms, so every 2.6 s; 31 drives
/// each about every 300 ms, so every 80 s. Two PKW jobs (monitoring, reference) per this many
/// exchanges: under 1 % of the drive's PKW channel.
pub const REFRESH_POLLS: u64 = 256;

/// The parameters whose write may change any setting of a drive, the reference and the
/// telegram monitoring included (at most four; from the family's profile, `rereads_after`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Rereads([Option<Pnu>; 4]);

impl Rereads {
    /// None: no write makes ussd read the drive again (but its own parameters').
    pub const NONE: Self = Self([None; 4]);

    /// MICROMASTER 4 / G110 / CU240S, and SINAMICS G120 with the same numbers: the
    /// commissioning parameter P0010, the factory reset P0970, the end of quick commissioning
    /// P3900 (MICROMASTER 440 Parameter List 6SE6400-5BB00-0BP0: P0970 "resets all parameters
    /// to their default values", P3900 "performs the calculations ... and resets all other
    /// parameters not included in the quick commissioning to factory settings").
    pub const MICROMASTER: Self = Self([
        Some(Pnu::from_u16(10)),
        Some(Pnu::from_u16(970)),
        Some(Pnu::from_u16(3900)),
        None,
    ]);

    /// The parameters given, the first four.
    pub fn of(pnus: impl IntoIterator<Item = Pnu>) -> Self {
        let mut out = Self::NONE;
        for (slot, pnu) in out.0.iter_mut().zip(pnus) {
            *slot = Some(pnu);
        }
        out
    }

    /// Whether `task` writes one of them (any index).
    pub fn written_by(&self, task: &ParamTask) -> bool {
        let (ParamTask::Write { pnu, .. } | ParamTask::WriteArray { pnu, .. }) = *task else {
            return false;
        };
        self.0.contains(&Some(pnu))
    }

    /// The parameters, in order.
    pub fn iter(&self) -> impl Iterator<Item = Pnu> + '_ {
        self.0.iter().flatten().copied()
    }
}

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// The drive in `slot` may have changed every setting (it came back online, or a reset or
    /// commissioning write took effect): what ussd knows of it is unknown until read again.
    /// `say`: tell the housekeeping thread (a write's effect; a drive coming online says so
    /// itself).
    pub(super) fn forget_picture(&mut self, slot: usize, say: bool) {
        let d = &mut self.drives[slot];
        d.monitoring_due = true;
        d.reference_due = true;
        if d.setup.monitoring.param.is_some() && d.monitoring != Monitoring::Unreadable {
            d.monitoring = Monitoring::Unknown;
        }
        let was = d.reference;
        if d.setup.reference_read().is_some() {
            d.reference = super::Reference::Unknown;
        }
        // Whatever it was, a description published before now is not the drive: the input
        // image carries the new count at this very poll, and the diagnostics follow at once.
        d.picture = d.picture.wrapping_add(1);
        self.control_changed = true;
        if say && was != d.reference {
            let (address, configured_hz) = (d.setup.address, d.setup.reference_hz);
            let at = self.clock.now();
            self.emit(Event::Reference {
                address,
                at,
                reference: super::Reference::Unknown,
                configured_hz,
            });
        }
    }

    /// Before a poll of the drive in `slot`: its background reads, when they are due.
    pub(super) fn refresh_picture(&mut self, slot: usize) {
        let d = &mut self.drives[slot];
        let good = d.counters.good;
        if good.saturating_sub(d.refreshed_at) >= REFRESH_POLLS {
            d.refreshed_at = good;
            d.monitoring_due = true;
            d.reference_due = true;
        }
    }

    /// A finished job of the drive in `slot` that wrote a parameter which may change every
    /// setting: what ussd knows of the drive is read again, now and once more
    /// [`AFTER_RESET_POLLS`] polls later (a drive may answer the write before its reset or
    /// calculation has finished). Only a refusal leaves it: a write whose answer was lost may
    /// have been taken.
    pub(super) fn on_reread_write(&mut self, slot: usize, result: &JobResult) {
        if result.job.task.is_write()
            && !matches!(result.outcome, Ok(Err(_)))
            && self.drives[slot]
                .setup
                .rereads_after
                .written_by(&result.job.task)
        {
            self.forget_picture(slot, true);
            let d = &mut self.drives[slot];
            d.refreshed_at = d
                .counters
                .good
                .saturating_sub(REFRESH_POLLS - AFTER_RESET_POLLS);
        }
    }

    /// The drive's reference came back as `now` (`Some(hz)`, or `None`: no longer readable as a
    /// frequency), `before` the one last read: a controller scaled its setpoint with the old
    /// one, or will re-arm on a picture of it, so the drive latches (again, with a new latch a
    /// re-arm asked before the change cannot name), whether a controller holds it or not.
    pub(super) fn on_reference_changed(&mut self, slot: usize, before: f32, now: Option<f32>) {
        if now.is_some_and(|hz| (hz - before).abs() <= super::reference::AGREES_WITHIN_HZ) {
            return;
        }
        let now = self.clock.now();
        self.latch_now(slot, LatchReason::ReferenceChanged, now);
    }
}

/// Polls after a reset or commissioning write until what ussd knows of the drive is read a
/// second time.
pub const AFTER_RESET_POLLS: u64 = 16;

#[cfg(test)]
mod tests {
    use super::*;
    use uss_protocol::{Storage, Subindex, Value};

    #[test]
    fn a_write_of_a_reset_parameter_is_recognised_at_any_index() {
        let r = Rereads::MICROMASTER;
        let write = |pnu: u16| ParamTask::Write {
            pnu: Pnu::from_u16(pnu),
            value: Value::Word(1),
            storage: Storage::Ram,
        };
        assert!(r.written_by(&write(970)));
        assert!(r.written_by(&write(10)));
        assert!(r.written_by(&write(3900)));
        assert!(!r.written_by(&write(2000)), "its own reads see that");
        assert!(r.written_by(&ParamTask::WriteArray {
            pnu: Pnu::from_u16(3900),
            index: Subindex::new(1).unwrap(),
            value: Value::Word(1),
            storage: Storage::RamAndEeprom,
        }));
        assert!(!r.written_by(&ParamTask::Read {
            pnu: Pnu::from_u16(970)
        }));
        assert!(!Rereads::NONE.written_by(&write(970)));
        assert_eq!(
            Rereads::of([Pnu::from_u16(51)]).iter().collect::<Vec<_>>(),
            [Pnu::from_u16(51)]
        );
    }
}
