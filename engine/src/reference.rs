//! The drive's reference frequency (USS.md section 7): a setpoint or main actual value of
//! 0x4000 is 100 % of P2000 on MICROMASTER 4 / G110, in Hz; on a G120, of p2000, a speed in
//! rpm, which is `p2000 x pole pairs / 60` Hz at the motor (synchronous speed). Clients scale Hz by the reference
//! ussd publishes; the configuration's `reference_hz` gives it, but the drive scales by its own
//! P2000. ussd reads P2000 whenever a drive comes online (and whenever a parameter access
//! through it reads or writes it) and publishes the drive's value, so `run_hz` and every tool
//! use the frequency the drive uses; the housekeeping thread says when the two differ. It is read
//! again whenever it can have changed ([`super::picture`]), and while it is not known no Hz are
//! scaled with it ([`Reference::scale`]).

use super::clock::Clock;
use super::jobs::JobResult;
use super::monitoring::WatchedParam;
use super::transport::Transport;
use super::{Bridge, DriveSetup, Engine, Event, INTERNAL_JOB};
use uss_protocol::{Pnu, Value};
use uss_shm_types::Answer;

/// P2000, the reference frequency of MICROMASTER 4 / G110 / CU240S.
pub const P2000: WatchedParam = WatchedParam {
    pnu: Pnu::from_u16(2000),
    index: None,
};

/// The highest reference frequency: above 0 and at most 650 Hz, as `reference_hz` allows.
const MAX_HZ: f32 = 650.0;

/// Within this many Hz the drive's reference agrees with the configuration.
pub(super) const AGREES_WITHIN_HZ: f32 = 0.005;

/// The unit of a drive's reference parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceUnit {
    /// A frequency in Hz (P2000 on MICROMASTER 4 / G110).
    Hz,
    /// A speed in rpm (G120's p2000), made Hz with the motor's pole pairs (`pole_pairs` in
    /// the configuration: 2 for a 4-pole motor, 1500 rpm = 50 Hz).
    Rpm { pole_pairs: u8 },
}

impl ReferenceUnit {
    /// A value of the parameter in Hz (rpm x pole pairs / 60, in that order: 1800 rpm at 2
    /// pole pairs is exactly 60 Hz).
    pub fn to_hz(self, value: f32) -> f32 {
        match self {
            Self::Hz => value,
            Self::Rpm { pole_pairs } => value * f32::from(pole_pairs) / 60.0,
        }
    }
}

/// What ussd knows of a drive's reference frequency.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reference {
    /// Not read: no `reference_param`, or a PKW channel that cannot carry a float.
    NotChecked,
    /// Not read yet, or being read again (it can have changed): no Hz are scaled with it.
    Unknown,
    /// The drive's value, Hz.
    Read(f32),
    /// The drive refused the read, it timed out, or the value is not a frequency (G120's
    /// p2000 is in rpm).
    Unreadable,
}

impl Reference {
    /// What it means: a float that makes above 0 and at most 650 Hz in `unit` is a reference
    /// frequency.
    pub fn of(value: Value, unit: ReferenceUnit) -> Self {
        match value {
            Value::Dword(bits) => {
                let hz = unit.to_hz(f32::from_bits(bits));
                if hz.is_finite() && hz > 0.0 && hz <= MAX_HZ {
                    Self::Read(hz)
                } else {
                    Self::Unreadable
                }
            }
            Value::Word(_) => Self::Unreadable,
        }
    }

    /// The reference clients scale Hz by: the drive's, once read; the configured one where it
    /// is not read (`reference_param = ""`) or the drive refused it (warned as unverified);
    /// none while it is [`Reference::Unknown`].
    pub fn scale(self, configured: f32) -> Option<f32> {
        match self {
            Self::Read(hz) => Some(hz),
            Self::NotChecked | Self::Unreadable => Some(configured),
            Self::Unknown => None,
        }
    }

    /// Whether the drive's value was read and differs from the configured one.
    pub fn differs_from(self, configured: f32) -> bool {
        matches!(self, Self::Read(hz) if (hz - configured).abs() > AGREES_WITHIN_HZ)
    }

    /// What is known before the read.
    pub(super) fn initial(setup: &DriveSetup) -> Self {
        if setup.reference_read().is_some() {
            Self::Unknown
        } else {
            Self::NotChecked
        }
    }
}

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// A result that says what the drive's reference frequency is (ussd's own read, or a
    /// client's read or write of that parameter).
    pub(super) fn on_reference_result(&mut self, slot: usize, result: &JobResult) {
        let own = result.job.id & INTERNAL_JOB != 0;
        let reference = match result.outcome {
            Ok(Ok(Answer::Value(v))) => Reference::of(v, self.drives[slot].setup.reference_unit),
            // A refused write leaves the parameter as it was.
            _ if result.job.task.is_write() => return,
            Ok(Err(_)) => Reference::Unreadable,
            Ok(Ok(_)) => return,
            // ussd's own read got no answer, the drive is gone or ussd stops: still unknown,
            // read again (a client's read that timed out says nothing of the drive).
            Err(_) => {
                if own {
                    self.drives[slot].reference_due = true;
                }
                return;
            }
        };
        let d = &mut self.drives[slot];
        let before = d.last_reference;
        // A reference read before and now not a frequency (refused, or out of range): not
        // known, never the configured value in its place.
        let reference = match reference {
            Reference::Unreadable if before.is_some() => Reference::Unknown,
            other => other,
        };
        if let Reference::Read(hz) = reference {
            d.last_reference = Some(hz);
        }
        if d.reference == reference {
            return;
        }
        d.reference = reference;
        d.picture = d.picture.wrapping_add(1);
        let setup = d.setup;
        let at = self.clock.now();
        // Published at once, as a latch is: clients scale by it.
        self.control_changed = true;
        self.emit(Event::Reference {
            address: setup.address,
            at,
            reference,
            configured_hz: setup.reference_hz,
        });
        if let Some(before) = before {
            match reference {
                Reference::Read(hz) => self.on_reference_changed(slot, before, Some(hz)),
                Reference::Unknown => self.on_reference_changed(slot, before, None),
                _ => {}
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // the values asserted are exactly representable
mod tests {
    use super::*;

    fn float(hz: f32) -> Value {
        Value::Dword(hz.to_bits())
    }

    #[test]
    fn a_float_of_1_to_650_is_the_drive_reference() {
        let hz = ReferenceUnit::Hz;
        assert_eq!(Reference::of(float(50.0), hz), Reference::Read(50.0));
        assert_eq!(Reference::of(float(650.0), hz), Reference::Read(650.0));
        for not_hz in [0.0, -50.0, 1500.0, f32::NAN, f32::INFINITY] {
            assert_eq!(
                Reference::of(float(not_hz), hz),
                Reference::Unreadable,
                "{not_hz}"
            );
        }
        assert_eq!(Reference::of(Value::Word(50), hz), Reference::Unreadable);
    }

    #[test]
    fn a_g120_reference_speed_becomes_hz_with_the_pole_pairs() {
        let four_pole = ReferenceUnit::Rpm { pole_pairs: 2 };
        assert_eq!(
            Reference::of(float(1500.0), four_pole),
            Reference::Read(50.0)
        );
        assert_eq!(
            Reference::of(float(1800.0), four_pole),
            Reference::Read(60.0)
        );
        let two_pole = ReferenceUnit::Rpm { pole_pairs: 1 };
        assert_eq!(
            Reference::of(float(3000.0), two_pole),
            Reference::Read(50.0)
        );
        // 210 000 rpm on a 4-pole motor is 7000 Hz: not a reference frequency.
        assert_eq!(
            Reference::of(float(210_000.0), four_pole),
            Reference::Unreadable
        );
    }

    #[test]
    fn clients_scale_by_the_drive_value_once_read_and_never_while_unknown() {
        assert_eq!(Reference::Read(50.0).scale(60.0), Some(50.0));
        for unread in [Reference::NotChecked, Reference::Unreadable] {
            assert_eq!(unread.scale(60.0), Some(60.0));
            assert!(!unread.differs_from(60.0));
        }
        assert_eq!(Reference::Unknown.scale(60.0), None);
        assert!(!Reference::Unknown.differs_from(60.0));
        assert!(Reference::Read(50.0).differs_from(60.0));
        assert!(!Reference::Read(60.001).differs_from(60.0));
    }

    #[test]
    fn p2000_is_read_whole_and_its_writes_are_recognised() {
        use uss_protocol::{ParamTask, Storage, Subindex};
        let pnu = Pnu::from_u16(2000);
        assert_eq!(P2000.task(), ParamTask::Read { pnu });
        let write = ParamTask::Write {
            pnu,
            value: float(60.0),
            storage: Storage::Ram,
        };
        assert!(P2000.concerns(&write));
        let indexed = ParamTask::ReadArray {
            pnu,
            index: Subindex::new(1).unwrap(),
        };
        assert!(!P2000.concerns(&indexed));
    }
}
