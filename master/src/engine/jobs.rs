//! Parameter jobs: what a client asks, the one result each accepted job ends in, and the per-drive
//! mailbox that puts one PKW task at a time on the wire (USS.md section 6, handshake).

use core::time::Duration;
use std::collections::VecDeque;
use uss_protocol::telegram::MAX_PKW_WORDS;
use uss_protocol::{Address, ParamReply, ParamTask, PkwError, PkwMode};
use uss_shm_types::{Answer, ItemOutcome, PathError};

/// A parameter request for one drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Job {
    /// Chosen by the submitter; returned in the result.
    pub id: u64,
    pub address: Address,
    pub task: ParamTask,
}

/// Who asked for a job, as the bus thread can check it: a slot of the engine's table of
/// requesters' liveness ([`crate::EngineHandle::watch_requester`]), or none (ussd's own jobs,
/// in-process clients, a requester that could not be watched).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Requester(pub(crate) u16);

impl Requester {
    /// Nobody the bus thread can check.
    pub const NONE: Self = Self(0);

    /// The slot in the engine's table, if any.
    pub(crate) fn slot(self) -> Option<usize> {
        usize::from(self.0).checked_sub(1)
    }
}

/// A task's PKW words for its drive's PKW mode, encoded once when the job is accepted: every
/// telegram that repeats the task copies them (USS.md section 6, handshake).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Encoded {
    words: [u16; MAX_PKW_WORDS],
    len: u8,
}

impl Encoded {
    /// Encodes `task` for a drive in PKW mode `mode`: the check that the task fits the drive's
    /// parameter channel.
    pub fn new(task: &ParamTask, mode: PkwMode) -> Result<Self, PkwError> {
        let mut words = [0; MAX_PKW_WORDS];
        let len = task.encode(mode, &mut words)?;
        Ok(Self {
            words,
            len: len as u8,
        })
    }

    pub fn words(&self) -> &[u16] {
        &self.words[..usize::from(self.len)]
    }
}

/// A finished job.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JobResult {
    pub job: Job,
    /// The one outcome vocabulary from the engine to the client API (`uss_shm_types::outcome`).
    pub outcome: ItemOutcome,
    /// Telegrams that carried the task (1 when answered at once; more with busy replies or retries).
    pub telegrams: u32,
    /// From the first telegram carrying the task to the result (zero if it never reached the wire).
    pub on_wire: Duration,
}

/// A job in progress.
#[derive(Debug, Clone, Copy)]
struct Active {
    job: Job,
    pkw: Encoded,
    requester: Requester,
    first_sent: Option<Duration>,
    telegrams: u32,
}

/// One drive's FIFO of jobs: one task on the wire at a time, repeated in every telegram until
/// its matching reply arrives (USS.md section 6). Fixed capacity, allocated once.
#[derive(Debug)]
pub struct Mailbox {
    queue: VecDeque<Active>,
    capacity: usize,
}

impl Mailbox {
    pub fn new(capacity: usize) -> Self {
        Self {
            queue: VecDeque::with_capacity(capacity),
            capacity,
        }
    }

    /// Queues a job with its encoded PKW words; gives it back when the mailbox is full.
    pub fn push(&mut self, job: Job, pkw: Encoded) -> Result<(), Job> {
        self.push_for(job, pkw, Requester::NONE)
    }

    /// [`Mailbox::push`] for a job whose requester the bus thread checks before the job goes
    /// out ([`Mailbox::drop_unsent_if`]).
    pub fn push_for(&mut self, job: Job, pkw: Encoded, requester: Requester) -> Result<(), Job> {
        if self.queue.len() >= self.capacity {
            return Err(job);
        }
        self.queue.push_back(Active {
            job,
            pkw,
            requester,
            first_sent: None,
            telegrams: 0,
        });
        Ok(())
    }

    /// Ends the current job with [`PathError::Cancelled`] when it has not gone out yet and
    /// `gone(its requester)` says its requester died: its work dies with it. Call until `None`
    /// before a telegram; a job on the wire runs to its reply.
    pub fn drop_unsent_if(&mut self, gone: impl Fn(Requester) -> bool) -> Option<JobResult> {
        let front = self.queue.front()?;
        if front.first_sent.is_some()
            || front.requester == Requester::NONE
            || !gone(front.requester)
        {
            return None;
        }
        let a = self.queue.pop_front()?;
        Some(JobResult {
            job: a.job,
            outcome: Err(PathError::Cancelled),
            telegrams: 0,
            on_wire: Duration::ZERO,
        })
    }

    pub fn len(&self) -> usize {
        self.queue.len()
    }

    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// The task to put into the next telegram, if any.
    pub fn current(&self) -> Option<&ParamTask> {
        self.queue.front().map(|a| &a.job.task)
    }

    /// The PKW words of the task to put into the next telegram, if any.
    pub fn current_words(&self) -> Option<&[u16]> {
        self.queue.front().map(|a| a.pkw.words())
    }

    /// Records that the current task went out at `now`.
    pub fn sent(&mut self, now: Duration) {
        if let Some(a) = self.queue.front_mut() {
            a.first_sent.get_or_insert(now);
            a.telegrams += 1;
        }
    }

    /// Checks a reply against the current task. Returns the finished job when the reply
    /// matches; a busy reply (AK 0) or another task's reply leaves the job in place.
    pub fn on_reply(&mut self, reply: &ParamReply, now: Duration) -> Option<JobResult> {
        let active = self.queue.front()?;
        if !reply.answers(&active.job.task) {
            return None;
        }
        self.finish(Ok(Answer::of_reply(reply)), now)
    }

    /// Ends the current job with a timeout when it has been on the wire longer than `limit`.
    pub fn expire(&mut self, limit: Duration, now: Duration) -> Option<JobResult> {
        let first = self.queue.front()?.first_sent?;
        if now.saturating_sub(first) > limit {
            self.finish(Err(PathError::Timeout), now)
        } else {
            None
        }
    }

    /// Takes out one job with an id in `ids` that has not gone out yet (a job on the wire stays:
    /// its reply is on the way), ending it with [`PathError::Cancelled`]. Call until `None`.
    pub fn cancel(&mut self, ids: core::ops::Range<u64>) -> Option<JobResult> {
        let at = self
            .queue
            .iter()
            .position(|a| ids.contains(&a.job.id) && a.first_sent.is_none())?;
        // `position` found it, so `remove` returns it; no allocation.
        let a = self.queue.remove(at)?;
        Some(JobResult {
            job: a.job,
            outcome: Err(PathError::Cancelled),
            telegrams: 0,
            on_wire: Duration::ZERO,
        })
    }

    /// Ends the current job with `outcome`.
    pub fn finish(&mut self, outcome: ItemOutcome, now: Duration) -> Option<JobResult> {
        let a = self.queue.pop_front()?;
        Some(JobResult {
            job: a.job,
            outcome,
            telegrams: a.telegrams,
            on_wire: a
                .first_sent
                .map_or(Duration::ZERO, |t| now.saturating_sub(t)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_protocol::{ErrorNumber, Pnu, Storage, Value};
    use uss_shm_types::DriveError;

    fn words(job: &Job) -> Encoded {
        Encoded::new(&job.task, PkwMode::Four).unwrap()
    }

    fn job(id: u64, pnu: u16) -> Job {
        Job {
            id,
            address: Address::new(1).unwrap(),
            task: ParamTask::Read {
                pnu: Pnu::from_u16(pnu),
            },
        }
    }

    fn reply(id: u8, pnu: u16, value: u16) -> ParamReply {
        let mut words = [0u16; 4];
        words[0] = (u16::from(id) << 12) | pnu;
        words[3] = value;
        ParamReply::decode(&words).unwrap()
    }

    #[test]
    fn one_task_at_a_time_in_fifo_order() {
        let mut m = Mailbox::new(4);
        m.push(job(1, 700), words(&job(1, 700))).unwrap();
        m.push(job(2, 1000), words(&job(2, 1000))).unwrap();
        assert_eq!(m.current(), Some(&job(1, 700).task));
        m.sent(Duration::from_millis(1));
        assert!(
            m.on_reply(&reply(1, 1000, 5), Duration::from_millis(2))
                .is_none(),
            "not its reply"
        );
        assert!(
            m.on_reply(&reply(0, 700, 0), Duration::from_millis(3))
                .is_none(),
            "busy"
        );
        m.sent(Duration::from_millis(3));
        let r = m
            .on_reply(&reply(1, 700, 5), Duration::from_millis(4))
            .unwrap();
        assert_eq!(r.job.id, 1);
        assert_eq!(r.outcome, Ok(Ok(Answer::Value(Value::Word(5)))));
        assert_eq!(r.telegrams, 2);
        assert_eq!(r.on_wire, Duration::from_millis(3));
        assert_eq!(m.current(), Some(&job(2, 1000).task));
        assert_eq!(m.current_words(), Some(words(&job(2, 1000)).words()));
    }

    #[test]
    fn cancel_takes_out_what_has_not_gone_out_and_keeps_the_job_on_the_wire() {
        let mut m = Mailbox::new(8);
        for id in 1..=5 {
            m.push(job(id, 700), words(&job(id, 700))).unwrap();
        }
        m.push(job(50, 700), words(&job(50, 700))).unwrap();
        m.sent(Duration::from_millis(1)); // job 1 is on the wire
        let cancelled: Vec<u64> = std::iter::from_fn(|| m.cancel(1..6))
            .map(|r| r.job.id)
            .collect();
        assert_eq!(cancelled, [2, 3, 4, 5]);
        assert_eq!(
            m.current(),
            Some(&job(1, 700).task),
            "the job on the wire stays"
        );
        assert_eq!(m.len(), 2, "job 50 is someone else's");
        let r = m
            .on_reply(&reply(1, 700, 5), Duration::from_millis(2))
            .unwrap();
        assert_eq!(
            (r.job.id, r.outcome),
            (1, Ok(Ok(Answer::Value(Value::Word(5)))))
        );
    }

    #[test]
    fn a_dead_requesters_jobs_are_dropped_before_the_wire_and_the_one_on_it_stays() {
        let mut m = Mailbox::new(8);
        let dead = Requester(3);
        m.push_for(job(1, 700), words(&job(1, 700)), dead).unwrap();
        m.push_for(job(2, 700), words(&job(2, 700)), dead).unwrap();
        m.push_for(job(3, 700), words(&job(3, 700)), Requester(4))
            .unwrap();
        m.push(job(4, 700), words(&job(4, 700))).unwrap();
        m.sent(Duration::from_millis(1)); // job 1 is on the wire
        let gone = |r: Requester| r == dead;
        assert!(
            m.drop_unsent_if(gone).is_none(),
            "the job on the wire stays"
        );
        m.on_reply(&reply(1, 700, 5), Duration::from_millis(2))
            .unwrap();
        let r = m.drop_unsent_if(gone).unwrap();
        assert_eq!((r.job.id, r.outcome), (2, Err(PathError::Cancelled)));
        assert!(m.drop_unsent_if(gone).is_none(), "job 3's requester lives");
        assert_eq!(m.current(), Some(&job(3, 700).task));
        m.finish(Ok(Ok(Answer::Value(Value::Word(0)))), Duration::ZERO);
        assert!(
            m.drop_unsent_if(|_| true).is_none(),
            "ussd's own job has no requester to die"
        );
    }

    #[test]
    fn full_mailbox_gives_the_job_back() {
        let mut m = Mailbox::new(1);
        m.push(job(1, 700), words(&job(1, 700))).unwrap();
        assert_eq!(m.push(job(2, 700), words(&job(2, 700))), Err(job(2, 700)));
    }

    #[test]
    fn job_expires_only_after_reaching_the_wire() {
        let mut m = Mailbox::new(2);
        m.push(job(1, 700), words(&job(1, 700))).unwrap();
        assert!(
            m.expire(Duration::from_millis(10), Duration::from_secs(5))
                .is_none()
        );
        m.sent(Duration::from_secs(5));
        assert!(
            m.expire(Duration::from_millis(10), Duration::from_millis(5010))
                .is_none()
        );
        let r = m
            .expire(Duration::from_millis(10), Duration::from_millis(5011))
            .unwrap();
        assert_eq!(r.outcome, Err(PathError::Timeout));
    }

    #[test]
    fn drive_errors_and_rights_become_outcomes() {
        let write = Job {
            id: 9,
            address: Address::new(1).unwrap(),
            task: ParamTask::Write {
                pnu: Pnu::from_u16(1082),
                value: Value::Word(1),
                storage: Storage::Ram,
            },
        };
        let mut m = Mailbox::new(2);
        m.push(write, words(&write)).unwrap();
        let r = m.on_reply(&reply(7, 1082, 5), Duration::ZERO).unwrap();
        assert_eq!(
            r.outcome,
            Ok(Err(DriveError::Refused(ErrorNumber::WrongDataType)))
        );
        m.push(write, words(&write)).unwrap();
        let r = m.on_reply(&reply(8, 1082, 0), Duration::ZERO).unwrap();
        assert_eq!(r.outcome, Ok(Err(DriveError::NoChangeRights)));
    }
}
