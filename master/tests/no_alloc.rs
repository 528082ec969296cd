//! The real-time loop allocates nothing after start-up: thousands of exchanges with parameter
//! jobs, busy replies, retries, injected faults, offline drives, watchdog trips, re-arms,
//! rejected samples, releases, operator overrides and statistics publishing, under a counting
//! global allocator (ARCHITECTURE.md, "Data flow").
#![cfg(feature = "sim")]
#![allow(clippy::unwrap_used)]

mod common;

use common::allocations;

use crossbeam_channel::Receiver;
use std::sync::Arc;
use std::time::Duration;
use uss_drive_sim::{DriveConfig, Fault, SimBus, SimTransport, VirtualWire};
use uss_engine::control::ControllerId;
use uss_engine::image::DriveImages;
use uss_engine::jobs::Requester;
use uss_engine::stats::DriveStatus;
use uss_engine::{
    Bridge, DriveSetup, Engine, EngineConfig, EngineHandle, Event, Job, LocalBridge, VirtualClock,
};
use uss_master::daemon::ipc::requesters::{Requesters, pidfd_of};
use uss_protocol::telegram::{Layout, PkwMode, PzdCount};
use uss_protocol::{Address, Baud, ParamTask, Pnu, Storage, Timing, Value};
use uss_shm_types::{PzdOutput, StopCommand};

type TestEngine = Engine<SimTransport, VirtualClock, Watching>;

/// The in-process bridge, asking the daemon's table of watched processes whether a job's
/// requester has ended, as ussd's bus thread does.
#[derive(Debug, Default)]
struct Watching(Arc<Requesters>);

impl Bridge for Watching {
    fn take_sample(
        &mut self,
        slot: usize,
        images: &DriveImages,
    ) -> Option<(PzdOutput, ControllerId)> {
        LocalBridge.take_sample(slot, images)
    }
    fn after_poll(&mut self, slot: usize, images: &DriveImages, status: &DriveStatus) {
        LocalBridge.after_poll(slot, images, status);
    }
    fn cycle_completed(&mut self) {}
    fn job_done(&mut self) {}
    fn requester_ended(&self, requester: Requester) -> bool {
        self.0.has_ended(requester)
    }
}

/// Four drives with every PKW mode, echo, faults on every reply, and drive 4 unplugged for a while.
fn faulty_bus() -> (TestEngine, EngineHandle, Receiver<Event>, Arc<Requesters>) {
    let timing = Timing::new(Baud::new(115_200).unwrap());
    let mut bus = SimBus::new(3);
    let mut setups = Vec::new();
    for (a, pkw) in [
        (1u8, PkwMode::Four),
        (2, PkwMode::Variable),
        (3, PkwMode::Three),
        (4, PkwMode::Four),
    ] {
        let layout = Layout::new(pkw, PzdCount::new(4).unwrap());
        let mut dc = DriveConfig::new(Address::new(a).unwrap(), layout);
        dc.eeprom_busy_telegrams = 2;
        dc.response_jitter = Duration::from_micros(200);
        bus.add(dc).unwrap();
        let plan = bus.faults_mut(Address::new(a).unwrap()).unwrap();
        for f in Fault::ALL {
            plan.set_probability(f, 0.02);
        }
        setups.push(DriveSetup {
            weight: if a == 1 { 2 } else { 1 },
            watchdog: Duration::from_millis(50),
            ..DriveSetup::new(Address::new(a).unwrap(), layout)
        });
    }
    // Drive 4 drops out for a while: offline, probes, back online.
    bus.faults_mut(Address::new(4).unwrap())
        .unwrap()
        .unplug(Duration::from_secs(2), Some(Duration::from_secs(3)));
    let config = EngineConfig {
        echo: true,
        // The extra polls for parameter jobs allocate nothing either.
        param_priority: true,
        safety_first: true,
        rx_latency: Duration::ZERO,
        ..common::engine_config(timing, setups)
    };
    let wire = VirtualWire::new(bus, timing).with_echo(true);
    let table = Arc::new(Requesters::default());
    let bridge = Watching(Arc::clone(&table));
    let (engine, handle, events) =
        Engine::with_bridge(config, SimTransport::new(wire), VirtualClock::new(), bridge);
    (engine, handle, events, table)
}

/// What the controllers and operators do at poll `i`: every path of the control gate.
fn control(handle: &EngineHandle, i: usize) {
    let a = |n| Address::new(n).unwrap();
    let (off1, run) = ([0x047E, 0, 0, 0], [0x047F, 0x2000, 0, 0]);
    if i.is_multiple_of(3) {
        // Drive 1: OFF1 (re-arms after an override), then ON.
        let words = if i % 1000 < 9 { off1 } else { run };
        handle.set_output(a(1), &words).unwrap();
        // Drive 2: refreshes for 300 polls, then goes quiet for 100 (a watchdog trip).
        if i % 400 < 300 {
            let words = if i % 400 < 9 { off1 } else { run };
            handle.set_output(a(2), &words).unwrap();
        }
        // Drive 3: a valid controller, except for a sample with STW1 bit 10 clear now and then.
        if i.is_multiple_of(50) {
            let bad =
                PzdOutput::from_words(&[0x007F, 0, 0, 0], 1_000_000 + i as u64, 0, 1).unwrap();
            handle.publish_sample(a(3), bad).unwrap();
        } else {
            handle.set_output(a(3), &off1).unwrap();
        }
    }
    // Operators coast drive 4 and quick-stop drive 1; drive 4's controller releases it.
    if i.is_multiple_of(700) {
        handle.stop_drive(Some(a(4)), StopCommand::Off2, 1).unwrap();
    }
    if i % 1000 == 500 {
        handle.stop_drive(Some(a(1)), StopCommand::Off3, 1).unwrap();
    }
    if i % 900 == 100 {
        handle.set_output(a(4), &off1).unwrap();
    }
    if i % 900 == 200 {
        handle.release(a(4)).unwrap();
    }
}

#[test]
fn bus_loop_allocates_nothing_per_exchange() {
    let (mut engine, handle, events, requesters) = faulty_bus();
    let tasks = [
        ParamTask::Read {
            pnu: Pnu::from_u16(700),
        },
        ParamTask::Write {
            pnu: Pnu::from_u16(1120),
            value: Value::Word(3),
            storage: Storage::RamAndEeprom,
        },
        ParamTask::Read {
            pnu: Pnu::from_u16(2000),
        },
        ParamTask::ReadArrayLen {
            pnu: Pnu::from_u16(947),
        },
    ];
    let mut results = 0u64;
    let mut id = 0u64;
    // Every telegram is captured (as in ussd) and taken here, as ussd's housekeeping does.
    let captured = std::cell::Cell::new(0u64);
    // Every other job names a watched requester (this process, alive): the bus thread checks
    // it before the job leaves the mailbox.
    let me = pidfd_of(std::process::id()).unwrap();
    let requester = requesters.watch(std::os::fd::AsFd::as_fd(&me)).unwrap();
    let mut step = |count: usize, results: &mut u64, id: &mut u64| {
        for i in 0..count {
            control(&handle, i);
            if i % 5 == 0 {
                let a = Address::new(1 + (i / 5 % 4) as u8).unwrap();
                let mut task = tasks[i / 20 % tasks.len()];
                if a.get() == 3 {
                    task = ParamTask::Read {
                        pnu: Pnu::from_u16(700),
                    };
                }
                let job = Job {
                    id: *id,
                    address: a,
                    task,
                };
                let submitted = if (*id).is_multiple_of(2) {
                    handle.submit_for(job, requester)
                } else {
                    handle.submit(job)
                };
                if submitted.is_ok() {
                    *id += 1;
                }
            }
            engine.poll_next().unwrap();
            while handle.recv_result(Duration::ZERO).is_some() {
                *results += 1;
            }
            while events.try_recv().is_ok() {}
            while handle.captures().try_recv().is_ok() {
                captured.set(captured.get() + 1);
            }
        }
    };
    step(500, &mut results, &mut id);
    let before = allocations();
    step(5000, &mut results, &mut id);
    let allocations = allocations() - before;
    let stats = engine.stats();
    assert_eq!(allocations, 0, "allocations during 5000 polls");
    // The run really covered the paths it claims to.
    let total = |f: fn(&uss_engine::DriveCounters) -> u64| {
        stats.drives.iter().map(|d| f(&d.counters)).sum::<u64>()
    };
    assert!(stats.bus.exchanges > 5000);
    assert!(total(|c| c.retries) > 50, "retries");
    assert!(total(|c| c.pkw_busy) > 10, "busy replies");
    assert!(total(|c| c.failed_polls) > 0, "offline");
    assert!(total(|c| c.watchdog_trips) > 0, "watchdog");
    assert!(total(|c| c.rejected_outputs) > 0, "rejected samples");
    assert!(total(|c| c.overrides) > 0, "operator overrides");
    assert!(total(|c| c.releases) > 0, "releases");
    assert!(total(|c| c.latches) > 10, "latches and re-arms");
    assert!(results > 500, "{results} job results");
    assert!(
        captured.get() >= 2 * stats.bus.exchanges,
        "every request and every reply captured ({} for {} exchanges)",
        captured.get(),
        stats.bus.exchanges
    );
}
