//! The simulator on the virtual wire allocates nothing per exchange, so the master's real-time
//! tests can run it inside their allocation-counting real-time loop.
#![allow(clippy::unwrap_used)]

use std::alloc::{GlobalAlloc, Layout as AllocLayout, System};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use uss_drive_sim::{DriveConfig, Fault, SimBus, VirtualWire};
use uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, encode};
use uss_protocol::{Address, Adr, Baud, Framer, FramerConfig, Timing};

struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: AllocLayout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: AllocLayout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: AllocLayout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn exchanges_with_pkw_tasks_and_faults_allocate_nothing() {
    let timing = Timing::new(Baud::new(115_200).unwrap());
    let mut bus = SimBus::new(9);
    for (a, pkw) in [
        (1, PkwMode::Four),
        (2, PkwMode::Variable),
        (3, PkwMode::Three),
    ] {
        let mut config = DriveConfig::new(
            Address::new(a).unwrap(),
            Layout::new(pkw, PzdCount::new(4).unwrap()),
        );
        config.telegram_off_time_ms = 500;
        config.response_jitter = Duration::from_micros(300);
        bus.add(config).unwrap();
        let plan = bus.faults_mut(Address::new(a).unwrap()).unwrap();
        for fault in Fault::ALL {
            plan.set_probability(fault, 0.01);
        }
    }
    let mut wire = VirtualWire::new(bus, timing).with_echo(true);
    let mut framer = Framer::new(FramerConfig::strict(timing));
    let mut buf = [0u8; MAX_TELEGRAM_BYTES];
    let tasks: [[u16; 4]; 4] = [
        [0x1000 | 1082, 0, 0, 0],
        [0xD000 | 1120, 0, 0x4040, 0],
        [0x6000 | 947, 2, 0, 0],
        [0x2000 | 3, 0, 0, 2],
    ];
    let mut now = Duration::ZERO;
    let mut replies = 0u64;
    let mut run = |count: usize, now: &mut Duration, replies: &mut u64| {
        for i in 0..count {
            let address = 1 + (i % 3) as u8;
            let pkw_words = if address == 3 { 3 } else { 4 };
            let task = &tasks[(i / 7) % tasks.len()];
            let stw = if i % 200 < 100 { 0x047E } else { 0x047F };
            let n = encode(
                &mut buf,
                Adr::to(Address::new(address).unwrap()),
                &task[..pkw_words],
                &[stw, 0x2000, 0, 0],
            )
            .unwrap();
            *now += timing.start_pause();
            wire.flush_input(*now);
            framer.reset();
            let end = wire.transmit(&buf[..n], *now);
            framer.line_busy_until(end);
            *now = end + Duration::from_millis(30);
            while let Some(rx) = wire.receive(*now) {
                // The echo of our own request frames too; count only the drives' replies.
                if let Some(Ok(t)) = framer.push(rx.byte, rx.at)
                    && t.as_bytes() != &buf[..n]
                {
                    *replies += 1;
                }
            }
            wire.advance(*now);
        }
    };
    run(100, &mut now, &mut replies);
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    run(5000, &mut now, &mut replies);
    let allocations = ALLOCATIONS.load(Ordering::Relaxed) - before;
    assert_eq!(allocations, 0, "allocations during 5000 exchanges");
    assert!(
        replies > 4000,
        "{replies} replies: the exchanges really ran"
    );
}
