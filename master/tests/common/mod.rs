//! The counting global allocator of the allocation tests. It counts per thread, so a test can
//! run other threads (a simulator, a controller, a reader) beside the one it checks:
//! `let before = allocations(); ...; allocations() - before` on the checked thread.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    // Const-initialised and without a destructor: touching it never allocates.
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count() {
    // `try_with`: an allocation during thread teardown is not counted, never a panic.
    let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
}

/// Allocations made by the calling thread so far.
pub fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

// SAFETY: forwards to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// The engine settings of the allocation tests on a simulated bus: 20 ms response timeout, two
/// retries, offline after one failed poll, 200 ms probes, 500 ms parameter timeout, mailboxes
/// of 8, status every 20 ms, every telegram captured; no echo, no parameter priority.
#[allow(
    dead_code,
    reason = "not every allocation test runs an engine on a simulated bus"
)]
pub fn engine_config(
    timing: uss_protocol::Timing,
    drives: Vec<uss_engine::DriveSetup>,
) -> uss_engine::EngineConfig {
    use std::time::Duration;
    uss_engine::EngineConfig {
        timing,
        response_timeout: Duration::from_millis(20),
        retries: 2,
        offline_after: 1,
        offline_probe: Duration::from_millis(200),
        cycle_time: None,
        param_timeout: Duration::from_millis(500),
        echo: false,
        mailbox_depth: 8,
        publish_every: Duration::from_millis(20),
        param_priority: false,
        safety_first: true,
        rx_latency: Duration::ZERO,
        capture: true,
        drives,
    }
}
