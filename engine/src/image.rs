//! Process images shared between the real-time thread and everyone else in this process
//! without blocking it: the input image as a sequence lock over atomic words (the writer never
//! waits for a reader, a reader that races a write reads again), and the in-process output
//! sample, which the bus thread takes with `try_lock` and so never waits for either.

use core::sync::atomic::{AtomicBool, AtomicU8, AtomicU16, AtomicU32, AtomicU64, Ordering, fence};
use std::sync::{Mutex, PoisonError, TryLockError};
use uss_protocol::telegram::MAX_PZD_WORDS;
use uss_shm_types::PzdOutput;

/// PZD words with a stamp, readable and writable from any thread.
#[derive(Debug, Default)]
pub struct WordCell {
    seq: AtomicU32,
    len: AtomicU8,
    words: [AtomicU16; MAX_PZD_WORDS],
    /// The writer's sequence number (an exchange count or a controller's counter).
    number: AtomicU64,
    /// The writer's time stamp in nanoseconds on the bus clock.
    stamp_ns: AtomicU64,
}

/// A consistent copy of a [`WordCell`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Words {
    pub len: usize,
    pub words: [u16; MAX_PZD_WORDS],
    pub number: u64,
    pub stamp_ns: u64,
}

impl Words {
    pub fn as_slice(&self) -> &[u16] {
        &self.words[..self.len]
    }
}

impl WordCell {
    /// Writes `words` (at most 16) with a number and time stamp. Concurrent writers are
    /// serialised by the sequence number itself.
    pub fn write(&self, words: &[u16], number: u64, stamp_ns: u64) {
        let mut s = self.seq.load(Ordering::Relaxed);
        loop {
            if s % 2 == 1 {
                core::hint::spin_loop();
                s = self.seq.load(Ordering::Relaxed);
                continue;
            }
            match self
                .seq
                .compare_exchange_weak(s, s + 1, Ordering::Acquire, Ordering::Relaxed)
            {
                Ok(_) => break,
                Err(now) => s = now,
            }
        }
        fence(Ordering::Release);
        let len = words.len().min(MAX_PZD_WORDS);
        for (cell, w) in self.words.iter().zip(&words[..len]) {
            cell.store(*w, Ordering::Relaxed);
        }
        self.len.store(len as u8, Ordering::Relaxed);
        self.number.store(number, Ordering::Relaxed);
        self.stamp_ns.store(stamp_ns, Ordering::Relaxed);
        self.seq.store(s + 2, Ordering::Release);
    }

    /// A consistent copy, or `None` when a writer kept the cell busy for every attempt.
    pub fn read(&self) -> Option<Words> {
        for _ in 0..64 {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 % 2 == 1 {
                core::hint::spin_loop();
                continue;
            }
            let mut out = Words {
                len: self.len.load(Ordering::Relaxed) as usize,
                number: self.number.load(Ordering::Relaxed),
                stamp_ns: self.stamp_ns.load(Ordering::Relaxed),
                ..Words::default()
            };
            for (w, cell) in out.words.iter_mut().zip(&self.words) {
                *w = cell.load(Ordering::Relaxed);
            }
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == s1 {
                return Some(out);
            }
        }
        None
    }

    /// Whether anything was ever written.
    pub fn is_written(&self) -> bool {
        self.seq.load(Ordering::Acquire) != 0
    }
}

/// The images of one drive in this process: what the drive last replied, and the output sample
/// of an in-process controller ([`crate::EngineHandle::set_output`]).
#[derive(Debug, Default)]
pub struct DriveImages {
    /// PZD the drive replied: ZSW1, actual value, further words; number = exchange count.
    pub input: WordCell,
    /// Whether the drive answers (cleared when it goes offline).
    pub online: AtomicBool,
    /// The id of the drive's current latch, 0 while live (the input image's `latch_id`).
    pub latch_id: AtomicU64,
    /// The newest sample of an in-process controller, until the bus thread takes it.
    pub output: SampleCell,
}

/// One pending output sample: the latest written wins; the bus thread takes it at most once.
#[derive(Debug, Default)]
pub struct SampleCell(Mutex<Option<PzdOutput>>);

impl SampleCell {
    /// Leaves `sample` for the bus thread (replacing one it has not taken yet).
    pub fn put(&self, sample: PzdOutput) {
        *self.0.lock().unwrap_or_else(PoisonError::into_inner) = Some(sample);
    }

    /// The sample written since the last take, if any. Never waits: while a writer holds the
    /// cell the sample is taken at the next poll.
    pub fn take(&self) -> Option<PzdOutput> {
        match self.0.try_lock() {
            Ok(mut s) => s.take(),
            Err(TryLockError::Poisoned(p)) => p.into_inner().take(),
            Err(TryLockError::WouldBlock) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn read_returns_what_was_written() {
        let c = WordCell::default();
        assert!(!c.is_written());
        c.write(&[0x047F, 0x2000], 7, 1234);
        let w = c.read().unwrap();
        assert_eq!(w.as_slice(), &[0x047F, 0x2000]);
        assert_eq!((w.number, w.stamp_ns), (7, 1234));
        assert!(c.is_written());
    }

    #[test]
    fn a_sample_is_taken_once_and_the_latest_wins() {
        let cell = SampleCell::default();
        assert_eq!(cell.take(), None);
        let a = PzdOutput::from_words(&[0x047E, 0], 1, 0, 1).unwrap();
        let b = PzdOutput::from_words(&[0x047F, 0x2000], 2, 0, 1).unwrap();
        cell.put(a);
        cell.put(b);
        assert_eq!(cell.take(), Some(b));
        assert_eq!(cell.take(), None);
    }

    #[test]
    fn readers_never_see_a_torn_write() {
        use std::sync::atomic::{AtomicU64, Ordering};
        let c = Arc::new(WordCell::default());
        // Reads made so far: the writer goes on until the reader has read while it wrote (on
        // a busy machine the reader may not run before 20000 writes are done; it failed so
        // once in CI), up to a bound so a reader that never reads still ends the test.
        let reads = Arc::new(AtomicU64::new(0));
        let writer = {
            let (c, reads) = (Arc::clone(&c), Arc::clone(&reads));
            std::thread::spawn(move || {
                let mut i = 0u16;
                for n in 0..10_000_000u32 {
                    if n >= 20_000 && reads.load(Ordering::Relaxed) >= 100 {
                        break;
                    }
                    c.write(&[i; 16], u64::from(i), u64::from(i));
                    i = i.wrapping_add(1);
                }
            })
        };
        let mut seen = 0;
        while !writer.is_finished() {
            if let Some(w) = c.read() {
                assert!(w.words.iter().all(|x| *x == w.words[0]), "torn: {w:?}");
                assert_eq!(u64::from(w.words[0]), w.number);
                seen += 1;
                reads.store(seen, Ordering::Relaxed);
            }
        }
        writer.join().unwrap();
        assert!(seen > 0);
    }
}
