//! The drive's own telegram monitoring (USS.md section 5): P2014 on MICROMASTER 4 / G110 /
//! CU240S (index 0 = the RS485 COM link), p2040 on G120 / S110. When ussd or its line dies,
//! nothing else stops a running motor: the drive trips (F0070..F0072) only if this time is set.
//! ussd reads it whenever a drive comes online, and again whenever a parameter access through
//! it reads or writes that parameter, and says what it found ([`Monitoring`]). The reads ussd
//! makes of its own ([`WatchedParam`]) are queued here, the reference frequency's too
//! ([`super::reference`]).

use super::clock::Clock;
use super::jobs::{Encoded, Job, JobResult};
use super::transport::Transport;
use super::{Bridge, Drive, DriveSetup, Engine, Event, INTERNAL_JOB};
use core::time::Duration;
use uss_protocol::{ParamRef, ParamTask, PkwMode, Pnu, Subindex, Value};
use uss_shm_types::{Answer, Monitoring, PathError};

/// A drive parameter ussd reads itself when the drive comes online (telegram monitoring,
/// reference frequency); a client's read or write of it through ussd updates what ussd knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WatchedParam {
    pub pnu: Pnu,
    /// The array index, for an indexed parameter.
    pub index: Option<Subindex>,
}

impl From<ParamRef> for WatchedParam {
    fn from(p: ParamRef) -> Self {
        Self {
            pnu: p.pnu,
            index: p.index,
        }
    }
}

impl WatchedParam {
    /// The read task for the parameter.
    pub fn task(self) -> ParamTask {
        let pnu = self.pnu;
        match self.index {
            Some(index) => ParamTask::ReadArray { pnu, index },
            None => ParamTask::Read { pnu },
        }
    }

    /// Whether `task` reads or writes the parameter (so its result says what the drive now
    /// holds).
    pub fn concerns(self, task: &ParamTask) -> bool {
        match (*task, self.index) {
            (ParamTask::Read { pnu } | ParamTask::Write { pnu, .. }, None) => pnu == self.pnu,
            (
                ParamTask::ReadArray { pnu, index: i }
                | ParamTask::WriteArray { pnu, index: i, .. },
                Some(index),
            ) => pnu == self.pnu && i == index,
            _ => false,
        }
    }
}

/// Which parameter holds a drive's telegram-off time, and what ussd expects of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MonitoringSetup {
    /// The parameter; `None`: not checked.
    pub param: Option<WatchedParam>,
    /// Times above this are reported as too long.
    pub max: Duration,
    /// Refuse ON unless the monitoring was read and is on within `max`.
    pub required: bool,
}

impl MonitoringSetup {
    /// MICROMASTER 4 / G110 / CU240S: P2014 index 0 (COM link), at most 1 s, not required.
    pub fn micromaster() -> Self {
        Self {
            // 2014 is a valid PNU and 0 a valid subindex.
            param: Some(WatchedParam {
                pnu: Pnu::from_u16(2014),
                index: Subindex::new(0).ok(),
            }),
            max: Duration::from_secs(1),
            required: false,
        }
    }

    /// The read task for the parameter, if it is checked.
    pub fn task(&self) -> Option<ParamTask> {
        self.param.map(WatchedParam::task)
    }

    /// Whether `task` reads or writes the monitoring parameter.
    pub fn concerns(&self, task: &ParamTask) -> bool {
        self.param.is_some_and(|p| p.concerns(task))
    }

    /// What a value of the parameter means: a word is milliseconds (P2014); a double word is
    /// an IEEE-754 float in milliseconds (p2040). A time shorter than `shortest` (the longest
    /// gap between two polls of the drive on its bus) trips the drive between polls.
    pub fn evaluate(&self, value: Value, shortest: Duration) -> (Monitoring, u32) {
        let ms = match value {
            Value::Word(w) => f64::from(w),
            Value::Dword(d) => f64::from(f32::from_bits(d)),
        };
        if !ms.is_finite() || ms < 0.0 {
            return (Monitoring::Unreadable, 0);
        }
        let ms = ms.round().min(f64::from(u32::MAX)) as u32;
        let state = if ms == 0 {
            Monitoring::Off
        } else if u128::from(ms) < shortest.as_millis() {
            Monitoring::TooShort
        } else if u128::from(ms) > self.max.as_millis() {
            Monitoring::TooLong
        } else {
            Monitoring::On
        };
        (state, ms)
    }

    /// Whether an ON may reach a drive whose monitoring is `state`.
    pub fn allows_on(&self, state: Monitoring) -> bool {
        !self.required || state == Monitoring::On
    }
}

/// ussd's own reads of the drive's telegram monitoring, and what the results say.
impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// A result that says what the drive's telegram monitoring is (ussd's own read, or a
    /// client's read or write of that parameter).
    pub(super) fn on_monitoring_result(&mut self, slot: usize, result: &JobResult) {
        let setup = self.drives[slot].setup.monitoring;
        let (state, ms) = match result.outcome {
            Ok(Ok(Answer::Value(v))) => setup.evaluate(v, self.drives[slot].shortest_monitoring),
            // A refused write leaves the parameter as it was.
            _ if result.job.task.is_write() => return,
            Ok(Err(_)) | Err(PathError::Timeout) => (Monitoring::Unreadable, 0),
            Ok(Ok(Answer::ElementCount(_) | Answer::Description(_))) => return,
            // The drive is gone or ussd stops: read again when it is back.
            Err(
                PathError::DriveOffline
                | PathError::MailboxFull
                | PathError::Shutdown
                | PathError::LineDown
                | PathError::Cancelled
                | PathError::Refused(_),
            ) => {
                if result.job.id & INTERNAL_JOB != 0 {
                    self.drives[slot].monitoring_due = true;
                }
                return;
            }
        };
        let d = &mut self.drives[slot];
        let changed = (d.monitoring, d.monitoring_ms) != (state, ms);
        d.monitoring = state;
        d.monitoring_ms = ms;
        if changed {
            // Published at once, as a latch is: `require_monitoring` judges by it.
            self.control_changed = true;
            let address = d.setup.address;
            let at = self.clock.now();
            let shortest_ms = u32::try_from(d.shortest_monitoring.as_millis()).unwrap_or(u32::MAX);
            self.emit(Event::Monitoring {
                address,
                at,
                state,
                ms,
                shortest_ms,
            });
        }
    }

    /// Queues ussd's own reads of the drive's telegram monitoring and reference frequency
    /// when they are due and the mailbox has room (otherwise at a later poll).
    pub(super) fn check_own_reads(&mut self, slot: usize) {
        let d = &mut self.drives[slot];
        let setup = d.setup;
        if d.monitoring_due {
            d.monitoring_due = queue_own_read(d, setup.monitoring.param, MONITORING_READ);
        }
        if d.reference_due {
            d.reference_due = queue_own_read(d, setup.reference_read(), REFERENCE_READ);
        }
    }
}

/// The job-id tag of ussd's own read of the telegram monitoring (with [`INTERNAL_JOB`] and the
/// drive's address).
const MONITORING_READ: u64 = 0;
/// The tag of ussd's own read of the reference frequency.
const REFERENCE_READ: u64 = 1 << 8;

/// Puts ussd's own read of `param` into the drive's mailbox; whether it is still due (the
/// mailbox was full). A parameter the channel cannot carry is not read.
fn queue_own_read(d: &mut Drive, param: Option<WatchedParam>, tag: u64) -> bool {
    let Some(task) = param
        .map(WatchedParam::task)
        .filter(|_| d.setup.layout.pkw != PkwMode::None)
    else {
        return false;
    };
    let address = d.setup.address;
    let job = Job {
        id: INTERNAL_JOB | tag | u64::from(address.get()),
        address,
        task,
    };
    let Ok(pkw) = Encoded::new(&task, d.setup.layout.pkw) else {
        return false;
    };
    // Queued already (due again before it ran: the drive went and came back): once is enough,
    // and the mailbox keeps room for one of each (`OWN_READS`).
    if d.mailbox.holds(job.id) {
        return false;
    }
    d.mailbox.push(job, pkw).is_err()
}

/// What is known of a drive's telegram monitoring before it was read.
pub(super) fn initial_monitoring(setup: &DriveSetup) -> Monitoring {
    if setup.monitoring.param.is_none() {
        Monitoring::NotChecked
    } else if setup.layout.pkw == PkwMode::None {
        Monitoring::Unreadable
    } else {
        Monitoring::Unknown
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_protocol::Storage;

    /// ussd's own read of a parameter is queued once. A drive that went offline with its own
    /// reads queued has them due again (they ended "offline"), a probe while it is away queues
    /// them, and its coming back marks them due once more: each was queued a second time while
    /// the first still waited, so the mailbox held more than the `OWN_READS` it keeps for
    /// them, and a client's full queue met "mailbox full" (found by a review).
    #[test]
    fn an_own_read_already_queued_is_not_queued_again() {
        let setup = DriveSetup::new(
            uss_protocol::Address::new(1).unwrap(),
            uss_protocol::Layout::new(PkwMode::Four, uss_protocol::PzdCount::new(2).unwrap()),
        );
        let gate = crate::control::Gate::new(
            crate::control::GateSetup {
                pzd: 2,
                safe: setup.safe,
                watchdog: setup.watchdog,
                clock_origin: Duration::ZERO,
            },
            Duration::ZERO,
        );
        let mut d = Drive::new(setup, gate, crate::OWN_READS, Duration::from_millis(10));
        let monitoring = setup.monitoring.param;
        assert!(
            !queue_own_read(&mut d, monitoring, MONITORING_READ),
            "queued"
        );
        // Due again while it waits: it is queued already, so it is not due any more.
        assert!(!queue_own_read(&mut d, monitoring, MONITORING_READ));
        assert_eq!(d.mailbox.len(), 1);
        assert!(!queue_own_read(
            &mut d,
            setup.reference_read(),
            REFERENCE_READ
        ));
        assert_eq!(d.mailbox.len(), 2, "each own read once: OWN_READS");
    }

    fn mm() -> MonitoringSetup {
        MonitoringSetup::micromaster()
    }

    /// A bus whose polls never trip a drive.
    const NONE: Duration = Duration::ZERO;

    #[test]
    fn a_telegram_off_time_shorter_than_the_gap_between_polls_is_too_short() {
        let gap = Duration::from_millis(2300);
        assert_eq!(
            mm().evaluate(Value::Word(100), gap),
            (Monitoring::TooShort, 100)
        );
        assert_eq!(mm().evaluate(Value::Word(2300), gap).0, Monitoring::TooLong);
        let long_limit = MonitoringSetup {
            max: Duration::from_secs(5),
            ..mm()
        };
        assert_eq!(
            long_limit.evaluate(Value::Word(2300), gap).0,
            Monitoring::On
        );
        assert_eq!(long_limit.evaluate(Value::Word(0), gap).0, Monitoring::Off);
    }

    #[test]
    fn p2014_words_are_milliseconds_against_the_limit() {
        assert_eq!(mm().evaluate(Value::Word(0), NONE), (Monitoring::Off, 0));
        assert_eq!(mm().evaluate(Value::Word(100), NONE), (Monitoring::On, 100));
        assert_eq!(
            mm().evaluate(Value::Word(1000), NONE),
            (Monitoring::On, 1000)
        );
        assert_eq!(
            mm().evaluate(Value::Word(1001), NONE),
            (Monitoring::TooLong, 1001)
        );
    }

    #[test]
    fn p2040_floats_are_milliseconds_too() {
        let f = |x: f32| Value::Dword(x.to_bits());
        assert_eq!(mm().evaluate(f(100.0), NONE), (Monitoring::On, 100));
        assert_eq!(mm().evaluate(f(0.0), NONE), (Monitoring::Off, 0));
        assert_eq!(
            mm().evaluate(f(f32::NAN), NONE),
            (Monitoring::Unreadable, 0)
        );
        assert_eq!(mm().evaluate(f(-5.0), NONE), (Monitoring::Unreadable, 0));
    }

    #[test]
    fn the_check_reads_index_0_of_p2014_and_recognises_writes_to_it() {
        let setup = mm();
        let pnu = Pnu::from_u16(2014);
        // Index 0 is the COM link (MM420 Parameter List 04/02 p.84), index 1 the BOP link.
        let com = Subindex::new(0).unwrap();
        assert_eq!(setup.task(), Some(ParamTask::ReadArray { pnu, index: com }));
        let write = ParamTask::WriteArray {
            pnu,
            index: com,
            value: Value::Word(0),
            storage: Storage::Ram,
        };
        assert!(setup.concerns(&write));
        let other_index = ParamTask::ReadArray {
            pnu,
            index: Subindex::new(1).unwrap(),
        };
        assert!(!setup.concerns(&other_index));
        assert!(!setup.concerns(&ParamTask::Read { pnu }));
        let g120 = MonitoringSetup {
            param: Some(WatchedParam {
                pnu: Pnu::from_u16(2040),
                index: None,
            }),
            ..setup
        };
        assert!(g120.concerns(&ParamTask::Read {
            pnu: Pnu::from_u16(2040)
        }));
        assert_eq!(
            MonitoringSetup {
                param: None,
                ..setup
            }
            .task(),
            None
        );
    }

    #[test]
    fn only_verified_monitoring_allows_on_when_required() {
        let required = MonitoringSetup {
            required: true,
            ..mm()
        };
        assert!(required.allows_on(Monitoring::On));
        for s in [
            Monitoring::Unknown,
            Monitoring::Off,
            Monitoring::TooLong,
            Monitoring::Unreadable,
            Monitoring::NotChecked,
            Monitoring::TooShort,
        ] {
            assert!(!required.allows_on(s), "{s}");
            assert!(mm().allows_on(s), "{s}: not required");
        }
    }
}
