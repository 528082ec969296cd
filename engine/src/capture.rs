//! Telegram capture in the bus thread: each request as sent and each reply as received (the
//! bytes of a broken one and what was drained after it, or none), copied into a
//! [`TelegramRecord`] and handed to a preallocated bounded channel that another thread drains
//! (ussd's housekeeping thread publishes the records on `uss/<bus>/<gen>/capture`). A copy and a
//! `try_send`: no allocation, no blocking; a full channel loses the record, and the records'
//! `sequence` shows the gap.
//!
//! Times are the engine clock's (ns since its origin): the thread that publishes a record adds
//! the origin ([`TelegramRecord`] carries `CLOCK_MONOTONIC` ns).

use super::{DriveSetup, Duration, LastFailure};
use crossbeam_channel::{Receiver, Sender, bounded};
use uss_shm_types::{CAPTURE_BYTES, CAPTURE_TASK, CAPTURE_TRUNCATED, Direction, TelegramRecord};

/// Records the channel holds: several seconds of a busy bus for a thread that drains it every
/// 50 ms.
pub const CAPTURE_QUEUE: usize = 2048;

/// The bus thread's capture state.
#[derive(Debug)]
pub(super) struct Capture {
    out: Sender<TelegramRecord>,
    /// Capture is on (off, the channel stays connected and empty).
    on: bool,
    sequence: u64,
    /// The reply being received.
    reply: TelegramRecord,
}

impl Capture {
    /// A capture (off unless `on`) and the receiving end of its channel.
    pub(super) fn new(on: bool) -> (Self, Receiver<TelegramRecord>) {
        let (tx, rx) = bounded(if on { CAPTURE_QUEUE } else { 1 });
        let capture = Self {
            out: tx,
            on,
            sequence: 0,
            reply: TelegramRecord::EMPTY,
        };
        (capture, rx)
    }

    fn stamp(&mut self, record: &mut TelegramRecord, setup: &DriveSetup) {
        self.sequence += 1;
        record.sequence = self.sequence;
        record.address = setup.address.get();
        record.pkw = setup.layout.pkw.p2013() as u8;
        record.pzd = setup.layout.pzd.get() as u8;
    }

    fn send(&self, record: &TelegramRecord) {
        let _ = self.out.try_send(*record);
    }

    /// Our request to the drive of `setup`, on the wire from `start` to `end`.
    pub(super) fn request(
        &mut self,
        setup: &DriveSetup,
        bytes: &[u8],
        task: bool,
        (start, end): (Duration, Duration),
    ) {
        if !self.on {
            return;
        }
        let mut record = TelegramRecord::EMPTY;
        self.stamp(&mut record, setup);
        let n = bytes.len().min(CAPTURE_BYTES);
        record.bytes[..n].copy_from_slice(&bytes[..n]);
        record.len = n as u16;
        record.flags = if task { CAPTURE_TASK } else { 0 };
        record.start_ns = nanos(start);
        record.end_ns = nanos(end);
        self.send(&record);
        self.reply_begin();
    }

    /// Forget what was received so far: a reply starts (or the echo was ours).
    pub(super) fn reply_begin(&mut self) {
        self.reply.len = 0;
        self.reply.flags = 0;
        self.reply.start_ns = 0;
        self.reply.end_ns = 0;
    }

    /// A byte on the line at `at`.
    pub(super) fn byte(&mut self, byte: u8, at: Duration) {
        if !self.on {
            return;
        }
        let r = &mut self.reply;
        let n = usize::from(r.len);
        if n < CAPTURE_BYTES {
            r.bytes[n] = byte;
            r.len += 1;
        } else {
            r.flags |= CAPTURE_TRUNCATED;
        }
        if n == 0 {
            r.start_ns = nanos(at);
        }
        r.end_ns = nanos(at);
    }

    /// The reply to the drive of `setup` ended: good (`LastFailure::None`) or failed; `now` is
    /// when the wait ended, the time of a reply without bytes.
    pub(super) fn reply_end(&mut self, setup: &DriveSetup, outcome: LastFailure, now: Duration) {
        if !self.on {
            return;
        }
        let mut record = self.reply;
        self.stamp(&mut record, setup);
        record.direction = Direction::Reply.code();
        record.outcome = outcome.code();
        if record.len == 0 {
            record.start_ns = nanos(now);
            record.end_ns = nanos(now);
        }
        self.send(&record);
        self.reply_begin();
    }
}

/// The engine clock's time in ns.
fn nanos(at: Duration) -> u64 {
    u64::try_from(at.as_nanos()).unwrap_or(u64::MAX)
}
