//! The engine's side for everyone else ([`EngineHandle`]): process images, parameter jobs,
//! operator stops, statistics, stop; lock-free or bounded, never waiting on the bus thread.

use super::{
    Address, DriveSetup, Duration, Encoded, EngineHandle, INTERNAL_JOB, Job, JobResult, Ordering,
    PzdOutput, Requester, Stats, StopCommand, stop_index,
};
use thiserror::Error;
use uss_protocol::PkwError;
use uss_shm_types::MAX_PARAM_ITEMS;

impl EngineHandle {
    /// Publishes the PZD words the drive should get (STW1, setpoint, ...) as an in-process
    /// controller (an engine built with [`Engine::new`]). Every call refreshes the watchdog: a
    /// controller must publish at least once per watchdog time. Like every sample, it reaches
    /// the drive only while the drive is live (see [`crate::control`]); it names the
    /// latch the drive shows now, so a stop given here re-arms it (the caller sends it knowing
    /// the drive's state: this is no refresher).
    pub fn set_output(&self, address: Address, words: &[u16]) -> Result<(), SubmitError> {
        let slot = self.shared.slot(address)?;
        let allowed = self.shared.setups[slot].layout.pzd.get();
        if words.len() != allowed {
            return Err(SubmitError::PzdWords {
                address,
                given: words.len(),
                allowed,
            });
        }
        let number = self.next_number(slot);
        let shown = self.shared.drives[slot]
            .images
            .latch_id
            .load(Ordering::Acquire);
        let sample = PzdOutput::from_words(words, number, 0, std::process::id())
            .map_err(|_| SubmitError::PzdWords {
                address,
                given: words.len(),
                allowed,
            })?
            .naming(shown);
        self.shared.drives[slot].images.output.put(sample);
        Ok(())
    }

    /// Publishes a sample exactly as given (any version, count or flags), as a foreign
    /// controller could: the engine's checks decide what reaches the drive.
    pub fn publish_sample(&self, address: Address, sample: PzdOutput) -> Result<(), SubmitError> {
        let slot = self.shared.slot(address)?;
        self.shared.drives[slot].images.output.put(sample);
        Ok(())
    }

    /// Hands the drive back, as a controller that ends cleanly does: it gets its safe command,
    /// latched, with the reason "released" (not a watchdog trip).
    pub fn release(&self, address: Address) -> Result<(), SubmitError> {
        let slot = self.shared.slot(address)?;
        let number = self.next_number(slot);
        let sample = PzdOutput::release(number, 0, std::process::id());
        self.shared.drives[slot].images.output.put(sample);
        Ok(())
    }

    fn next_number(&self, slot: usize) -> u64 {
        self.shared.drives[slot]
            .output_number
            .fetch_add(1, Ordering::Relaxed)
            + 1
    }

    /// An operator's stop command (OFF1, OFF2, OFF3) for drive `address`, or every drive with
    /// `None`, from process `pid`: it overrides the drive's controller from its next poll on
    /// and latches. Returns the drives it reached (bit = address).
    pub fn stop_drive(
        &self,
        address: Option<Address>,
        command: StopCommand,
        pid: u32,
    ) -> Result<u32, SubmitError> {
        let which = stop_index(command);
        let slots = match address {
            Some(a) => {
                let slot = self.shared.slot(a)?;
                slot..slot + 1
            }
            None => 0..self.shared.setups.len(),
        };
        let every = address.is_none();
        let mut reached = 0u32;
        for slot in slots {
            let o = &self.shared.drives[slot].overrides;
            o.pid.store(pid, Ordering::Relaxed);
            o.counts[which].fetch_add(1, Ordering::Release);
            reached |= 1 << self.shared.setups[slot].address.get();
        }
        if every {
            // After each drive's own: the bus thread that sees this sees those too.
            self.shared.stop_all.pid.store(pid, Ordering::Relaxed);
            self.shared.stop_all.counts[which].fetch_add(1, Ordering::Release);
        }
        Ok(reached)
    }

    /// The drive's last reply PZD (number = count of good replies) and whether it is online.
    pub fn input(
        &self,
        address: Address,
    ) -> Result<(Option<crate::image::Words>, bool), SubmitError> {
        let slot = self.shared.slot(address)?;
        let image = &self.shared.drives[slot].images;
        let words = image
            .input
            .is_written()
            .then(|| image.input.read())
            .flatten();
        Ok((words, image.online.load(Ordering::Acquire)))
    }

    /// Queues a parameter job. Once accepted it ends in exactly one [`JobResult`].
    pub fn submit(&self, job: Job) -> Result<(), SubmitError> {
        self.submit_for(job, Requester::NONE)
    }

    /// [`EngineHandle::submit`] for a job of `requester`, a number the engine's bridge knows
    /// (ussd's: a watched client process): the bus thread ends it with
    /// [`uss_shm_types::PathError::Cancelled`] instead of sending it when the bridge says the
    /// requester has ended by the time the job would leave the mailbox
    /// ([`crate::Bridge::requester_ended`]; [`crate::LocalBridge`] never says so).
    pub fn submit_for(&self, job: Job, requester: Requester) -> Result<(), SubmitError> {
        self.submit_all_for(job.address, job.id, &[job.task], requester)
            .map_err(|(_, e)| e)
    }

    /// Queues the tasks of one request for drive `address` as jobs `first_id`, `first_id + 1`,
    /// ..., all or none: each is checked first, then room for all of them is taken in the
    /// drive's mailbox at once, so a request is never run in part for want of room (it is
    /// refused whole, [`SubmitError::Busy`]). Once accepted, each ends in exactly one
    /// [`JobResult`]. The error names the task it is about (none: the request as a whole).
    /// No other task of the drive comes between a request's tasks as long as one thread
    /// submits (ussd's parameter server does).
    pub fn submit_all_for(
        &self,
        address: Address,
        first_id: u64,
        tasks: &[uss_protocol::ParamTask],
        requester: Requester,
    ) -> Result<(), (Option<usize>, SubmitError)> {
        let whole = |e| (None, e);
        if self.shared.stop.load(Ordering::Acquire) {
            return Err(whole(SubmitError::Stopped));
        }
        if self.shared.line_down.load(Ordering::Acquire) {
            return Err(whole(SubmitError::LineDown));
        }
        let slot = self.shared.slot(address).map_err(whole)?;
        let setup = &self.shared.setups[slot];
        // A request the drive's queue could never hold whole is no "busy": it is refused as such.
        let depth = self.shared.mailbox_depth;
        let most = MAX_PARAM_ITEMS.min(depth);
        if tasks.is_empty() || tasks.len() > most {
            return Err(whole(SubmitError::TooMany {
                given: tasks.len(),
                most,
            }));
        }
        // Each job made, checked and encoded once, on the stack (a caller may be a real-time
        // thread).
        let mut jobs = [None; MAX_PARAM_ITEMS];
        for (i, (&task, slot)) in tasks.iter().zip(&mut jobs).enumerate() {
            let job = Job {
                id: first_id.wrapping_add(i as u64),
                address,
                task,
            };
            *slot = Some((job, checked(setup, &job).map_err(|e| (Some(i), e))?));
        }
        // Room for every task at once, or for none.
        let queued = &self.shared.drives[slot].queued;
        queued
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n + tasks.len() <= depth).then_some(n + tasks.len())
            })
            .map_err(|_| whole(SubmitError::Busy(depth)))?;
        for (i, (job, pkw)) in jobs.into_iter().flatten().enumerate() {
            // The channel holds every drive's full mailbox: it fails only when the bus thread
            // is gone, and then nothing of the request runs.
            if self.jobs.try_send((job, pkw, requester)).is_err() {
                queued.fetch_sub(tasks.len() - i, Ordering::AcqRel);
                return Err(whole(SubmitError::Stopped));
            }
        }
        Ok(())
    }

    /// Cancels the jobs with ids in `ids` that have not reached the wire yet (their client
    /// died): each ends with [`uss_shm_types::PathError::Cancelled`] at the bus thread's next step. `false` when
    /// the bus thread's queue of cancellations is full (ask again later).
    pub fn cancel(&self, ids: core::ops::Range<u64>) -> bool {
        self.cancels.try_send(ids).is_ok()
    }

    /// Every telegram the bus thread sent and received, when the engine captures
    /// ([`crate::EngineConfig::capture`]); whoever takes them must keep up (the channel holds
    /// [`crate::CAPTURE_QUEUE`] records; more are lost, which their `sequence` shows).
    pub fn captures(&self) -> &crossbeam_channel::Receiver<uss_shm_types::TelegramRecord> {
        &self.captures
    }

    /// The next finished job, waiting at most `timeout`.
    pub fn recv_result(&self, timeout: Duration) -> Option<JobResult> {
        let r = self.results.recv_timeout(timeout).ok()?;
        // Only clients' jobs come here (ussd's own reads end in the bus thread).
        if let Ok(slot) = self.shared.slot(r.job.address) {
            self.shared.drives[slot]
                .queued
                .fetch_sub(1, Ordering::AcqRel);
        }
        Some(r)
    }

    /// A copy of the latest published statistics.
    pub fn stats(&self) -> Stats {
        // A poisoned lock means a panic elsewhere; the data is plain counters and still usable.
        self.shared
            .stats
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .read()
            .clone()
    }

    /// When the statistics [`EngineHandle::stats`] returns were published (bus clock), read
    /// without taking them: a thread that waits for a change polls this, not `stats`.
    pub fn published_at(&self) -> Duration {
        Duration::from_nanos(self.shared.published_ns.load(Ordering::Acquire))
    }

    /// Asks the engine to stop after its current exchange.
    pub fn stop(&self) {
        self.shared.stop.store(true, Ordering::Release);
    }

    pub fn is_stopped(&self) -> bool {
        self.shared.stop.load(Ordering::Acquire)
    }

    /// Whether the bus line is down (the engine waits for a reopened transport).
    pub fn is_line_down(&self) -> bool {
        self.shared.line_down.load(Ordering::Acquire)
    }

    /// How many steps the bus thread has made (see `Shared::progress`); it moves at least every
    /// [`IDLE_STEP`] and every telegram attempt while the thread runs.
    pub fn progress(&self) -> u64 {
        self.shared.progress.load(Ordering::Relaxed)
    }

    /// Counts a step of the bus thread made outside the engine (waiting for its line).
    pub fn note_progress(&self) {
        self.shared.progress.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts one attempt to reopen the line (for the bus status).
    pub fn note_reopen_attempt(&self) {
        self.shared.reopen_attempts.fetch_add(1, Ordering::Relaxed);
    }

    /// Attempts to reopen the line since it last went down.
    pub fn reopen_attempts(&self) -> u32 {
        self.shared.reopen_attempts.load(Ordering::Relaxed)
    }

    pub fn drives(&self) -> &[DriveSetup] {
        &self.shared.setups
    }
}

/// Checks `job` for drive `setup` and encodes its words: the one check that the task fits
/// the drive's channel, and its words for every telegram that will carry it.
fn checked(setup: &DriveSetup, job: &Job) -> Result<Encoded, SubmitError> {
    if job.id & INTERNAL_JOB != 0 {
        return Err(SubmitError::ReservedJobId(job.id));
    }
    if job.task.is_write() && !setup.params_writable {
        return Err(SubmitError::WritesDisabled(job.address));
    }
    Encoded::new(&job.task, setup.layout.pkw).map_err(|error| SubmitError::Pkw {
        address: job.address,
        error,
    })
}

/// A request the handle refuses before it reaches the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum SubmitError {
    #[error("no drive {0} on this bus")]
    UnknownDrive(Address),
    #[error("parameter writes are disabled for drive {0} (params_writable = false)")]
    WritesDisabled(Address),
    #[error("drive {address}: {error}")]
    Pkw { address: Address, error: PkwError },
    #[error("drive {address} exchanges {allowed} PZD words, {given} given")]
    PzdWords {
        address: Address,
        given: usize,
        allowed: usize,
    },
    #[error(
        "the drive's parameter queue has no room for every task of the request (it holds {0}): nothing of it was queued; retry once earlier requests finished"
    )]
    Busy(usize),
    #[error("the bus engine has stopped")]
    Stopped,
    #[error("job id {0:#x} is reserved for ussd's own jobs")]
    ReservedJobId(u64),
    #[error("the bus line is down: ussd reopens it; retry once it is back")]
    LineDown,
    #[error("a request of {given} tasks: the drive's queue takes 1 to {most} at once")]
    TooMany { given: usize, most: usize },
}

impl From<&SubmitError> for uss_shm_types::RequestError {
    /// What a client is told of a job the engine would not take (the contract's codes; the
    /// engine's error keeps the detail for ussd's log).
    fn from(e: &SubmitError) -> Self {
        use uss_shm_types::RequestError as Told;
        match e {
            SubmitError::UnknownDrive(_) => Told::UnknownDrive,
            SubmitError::WritesDisabled(_) => Told::WritesDisabled,
            SubmitError::Pkw { error, .. } => match error {
                PkwError::NoChannel => Told::NoParameterChannel,
                PkwError::DwordOverThreeWords => Told::DwordOverThreeWords,
                PkwError::Subindex(_) => Told::BadSubindex,
                _ => Told::ValueType,
            },
            SubmitError::PzdWords { .. } => Told::ValueType,
            SubmitError::Busy(_) => Told::Busy,
            SubmitError::Stopped => Told::Shutdown,
            SubmitError::ReservedJobId(_) => Told::BadTask,
            SubmitError::LineDown => Told::LineDown,
            SubmitError::TooMany { .. } => Told::BadCount,
        }
    }
}
