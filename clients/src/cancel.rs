//! The caller's way to cut a long call short (a restore, a scan): a [`Cancel`] the call asks
//! between its steps, never in the middle of one.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// The caller's way to cut a long call short. A restore asked once writes no further value
/// and puts back what it raised; asked again, it leaves what it could not put back yet. A scan
/// asks no further address and reports what it found.
pub trait Cancel {
    /// How many times the caller asked to stop (0: not yet).
    fn asked(&self) -> usize;
    /// Why, as the report says it ("Ctrl-C", "SIGTERM", "cancelled").
    fn why(&self) -> &'static str;
}

/// A call nobody cuts short (but the drive, the line or ussd).
#[derive(Debug, Clone, Copy, Default)]
pub struct NeverCancelled;

impl Cancel for NeverCancelled {
    fn asked(&self) -> usize {
        0
    }

    fn why(&self) -> &'static str {
        "cancelled"
    }
}

/// A cancel handle another thread (a GUI's button, a signal handler) asks with.
#[derive(Debug, Clone, Default)]
pub struct CancelHandle(Arc<AtomicUsize>);

impl CancelHandle {
    /// Asks the call to stop (a restore asked again: to leave what it puts back).
    pub fn cancel(&self) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }
}

impl Cancel for CancelHandle {
    fn asked(&self) -> usize {
        self.0.load(Ordering::Relaxed)
    }

    fn why(&self) -> &'static str {
        "cancelled"
    }
}
