//! With iceoryx2 active the bus thread still allocates nothing per exchange: its bridge takes the
//! controller's samples (subscriber), publishes input images (blackboard) and signals events
//! while a controller in another thread publishes and a reader reads. Only the bus thread's
//! allocations are counted.
#![allow(clippy::unwrap_used)]

mod common;

use common::allocations;

use iceoryx2::prelude::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use uss_drive_sim::{DriveConfig, Fault, SimBus, VirtualWire};
use uss_master::ipc as ussd_ipc;
use uss_master::{DriveSetup, Engine, EngineConfig, SimTransport, VirtualClock};
use uss_protocol::telegram::{Layout, PkwMode, PzdCount};
use uss_protocol::{Address, Baud, Stw1, Timing};
use uss_shm_types::names;
use uss_shm_types::{BlackboardKey, BusName, DriveAddress, PzdInput, PzdOutput};

#[test]
fn bus_thread_with_iceoryx2_allocates_nothing_per_exchange() {
    let bus_name = format!("na{}", std::process::id());
    let timing = Timing::new(Baud::new(115_200).unwrap());
    let layout = Layout::new(PkwMode::Four, PzdCount::new(2).unwrap());
    let mut sim = SimBus::new(5);
    let mut setups = Vec::new();
    for a in [1u8, 2] {
        let address = Address::new(a).unwrap();
        sim.add(DriveConfig::new(address, layout)).unwrap();
        for f in Fault::ALL {
            sim.faults_mut(address).unwrap().set_probability(f, 0.02);
        }
        setups.push(DriveSetup {
            address,
            layout,
            weight: 1,
            safe_stw1: Stw1::READY,
            watchdog: Duration::from_millis(50),
            params_writable: true,
        });
    }
    let addresses: Vec<Address> = setups.iter().map(|d| d.address).collect();
    let bus_ipc = ussd_ipc::create(&bus_name, &addresses, Duration::ZERO).unwrap();
    let config = EngineConfig {
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
        drives: setups,
    };
    let (mut engine, _handle, _events) = Engine::with_bridge(
        config,
        SimTransport::new(VirtualWire::new(sim, timing)),
        VirtualClock::new(),
        bus_ipc.rt,
    );

    // A controller for drive 1 and a reader of its inputs, in this thread.
    let client = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .unwrap();
    let bus = BusName::new(&bus_name).unwrap();
    let one = DriveAddress::new(1).unwrap();
    let publisher = client
        .service_builder(&names::drive_out(&bus, one))
        .publish_subscribe::<PzdOutput>()
        .open()
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let reader = client
        .service_builder(&names::drive_in(&bus, one))
        .blackboard_opener::<BlackboardKey>()
        .open()
        .unwrap()
        .reader_builder()
        .create()
        .unwrap();
    let input = reader.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();

    let running = Arc::new(AtomicBool::new(true));
    let bus_thread = {
        let running = Arc::clone(&running);
        std::thread::spawn(move || {
            for _ in 0..300 {
                engine.poll_next().unwrap();
            }
            let before = allocations();
            for _ in 0..3000 {
                engine.poll_next().unwrap();
            }
            let during = allocations() - before;
            running.store(false, Ordering::Release);
            (during, engine.stats().clone())
        })
    };
    let mut sequence = 0;
    let mut seen = 0;
    while running.load(Ordering::Acquire) {
        sequence += 1;
        let out =
            PzdOutput::from_words(&[0x047F, 0x2000], sequence, 0, std::process::id()).unwrap();
        publisher.send_copy(out).unwrap();
        seen = seen.max(input.get().sequence);
        std::thread::sleep(Duration::from_micros(200));
    }
    let (allocations, stats) = bus_thread.join().unwrap();
    assert_eq!(allocations, 0, "the bus thread allocated during 3000 polls");
    assert!(
        seen > 100,
        "the reader saw the bus thread's input images ({seen})"
    );
    let retries: u64 = stats.drives.iter().map(|d| d.counters.retries).sum();
    assert!(retries > 0, "faults and retries were part of the run");
    drop(bus_ipc.status);
    drop(bus_ipc.params);
}
