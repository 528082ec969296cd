//! The iceoryx2 0.10 patterns ussd and its clients use, proven on real services:
//!
//! - a. `out`: exactly one controller per drive. Publish-subscribe with one publisher refuses a
//!   second with `ExceedsMaxSupportedPublishers` and is taken over after a controller is killed.
//!   A blackboard refuses a second writer too, but a killed writer locks its entry
//!   (eclipse-iceoryx/iceoryx2#2008), so `out` is publish-subscribe.
//! - b. `in`, `diag`, `status`: blackboards ussd writes and anyone reads, without allocating.
//! - c. `cycle`: events with ids, non-blocking and blocking waits, no allocation; ussd's death is
//!   announced through the service's `notifier_dead_event`.
//! - d. `params`: request-response answered by a polling server loop; what it allocates.
//! - e. A killed process: `Node::list` shows its node dead; cleanup frees its ports.
//! - f. Nodes with signal handling disabled install no SIGINT/SIGTERM handler.
//!
//! The tests run in iceoryx2 instances apart from other iceoryx2 users on the machine (config
//! prefix `ussshmtest`), with unique bus names per test; a test that kills a process gets an
//! instance of its own, so no other test sees, counts or cleans up its dead node. Dead nodes
//! are cleaned only when a test asks or a service is opened. Child processes are this test
//! binary run again with `USS_SHM_TEST_ROLE` set (see [`child_process`]). A per-thread counting
//! allocator measures what allocates.

#![allow(clippy::unwrap_used)] // test helpers: a failed set-up is a failed test

use core::cell::Cell;
use core::time::Duration;
use std::alloc::{GlobalAlloc, Layout, System};
use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, OnceLock, mpsc};
use std::time::Instant;

use iceoryx2::config::Config;
use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::NodeView;
use iceoryx2::port::client::Client;
use iceoryx2::port::publisher::PublisherCreateError;
use iceoryx2::port::reader::{EntryHandleError, ReaderCreateError};
use iceoryx2::port::writer::{EntryHandleMutError, WriterCreateError};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::blackboard::{BlackboardCreateError, BlackboardOpenError};
use iceoryx2::service::port_factory::blackboard::PortFactory as Blackboard;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSub;
use uss_protocol::Pnu;
use uss_shm_types::names::{self, LAYOUT_VERSION_ATTRIBUTE};
use uss_shm_types::service::{Ipc, IpcThreadsafe};
use uss_shm_types::{
    Address, BlackboardKey, BusName, DriveCounters, DriveDiag, Generation, Heartbeat, Instance,
    LAYOUT_VERSION, Outcome, ParamItem, ParamRequest, ParamResponse, ParamResult, PzdInput,
    PzdOutput, RequestError, Storage, TaskCode,
};

// ---------------------------------------------------------------------------------------------
// Allocation counting (per thread, so parallel tests do not disturb each other).

struct CountingAlloc;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count_allocation() {
    // `try_with`: allocations during thread teardown are not counted, never a panic.
    let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count_allocation();
        // SAFETY: same contract as ours.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count_allocation();
        // SAFETY: same contract as ours.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count_allocation();
        // SAFETY: same contract as ours.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as ours.
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// Runs `f` and returns its result with the number of allocations it made on this thread.
fn allocations_in<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALLOCATIONS.with(Cell::get);
    let r = f();
    (r, ALLOCATIONS.with(Cell::get) - before)
}

// ---------------------------------------------------------------------------------------------
// Test instance, nodes, services.

const ROLE_ENV: &str = "USS_SHM_TEST_ROLE";
const PREFIX_ENV: &str = "USS_SHM_TEST_PREFIX";
const BUS_ENV: &str = "USS_SHM_TEST_BUS";

/// The root directory of these tests' iceoryx2 files (the variant of uss-rt keeps every file
/// below one root: `uss_shm_types::service`), apart from a running ussd's.
const TEST_ROOT: &str = "/dev/shm/uss-shm-test";

/// An iceoryx2 instance of its own: files below [`TEST_ROOT`] named with `prefix`; node
/// creation and destruction clean up no dead nodes (opening a service still does:
/// `service.cleanup_dead_nodes_on_open`).
fn instance(prefix: &str) -> Config {
    // iceoryx2 logs warnings with full Debug dumps of its state; tests assert instead.
    set_log_level(LogLevel::Error);
    let mut c = Config::default();
    c.global
        .set_root_path(&iceoryx2_bb_system_types::path::Path::new(TEST_ROOT.as_bytes()).unwrap());
    c.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
    c.global.node.cleanup_dead_nodes_on_creation = false;
    c.global.node.cleanup_dead_nodes_on_destruction = false;
    c
}

/// The instance shared by the tests that kill nothing, across runs (a child gets its parent's).
/// Their service names carry the process id.
fn config() -> &'static Config {
    static CONFIG: OnceLock<Config> = OnceLock::new();
    CONFIG.get_or_init(|| {
        instance(&std::env::var(PREFIX_ENV).unwrap_or_else(|_| "ussshmtest_".to_owned()))
    })
}

/// An instance for one test that kills processes, so that no other test sees, counts or
/// cleans up its dead nodes. Declare it first in the test: when it drops, every node is gone
/// and it removes what iceoryx2 keeps per instance (a 16-byte `global_mgmt` segment).
struct Isolated(Config);

fn isolated() -> Isolated {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    Isolated(instance(&format!("ussshmtest{}i{n}_", std::process::id())))
}

impl core::ops::Deref for Isolated {
    type Target = Config;

    fn deref(&self) -> &Config {
        &self.0
    }
}

impl Drop for Isolated {
    fn drop(&mut self) {
        /// Every file below `dir` whose name starts with `prefix`.
        fn remove(dir: &std::path::Path, prefix: &str) {
            for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
                let path = entry.path();
                if path.is_dir() {
                    remove(&path, prefix);
                } else if entry.file_name().to_string_lossy().starts_with(prefix) {
                    let _ = std::fs::remove_file(path);
                }
            }
        }
        remove(
            std::path::Path::new(TEST_ROOT),
            self.0.global.prefix.as_str(),
        );
    }
}

/// A node like ussd and clients create them: named, signal handling left to the process.
fn node_in(config: &Config, name: &str) -> Node<Ipc> {
    NodeBuilder::new()
        .name(&NodeName::new(name).unwrap())
        .config(config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .unwrap()
}

fn node(name: &str) -> Node<Ipc> {
    node_in(config(), name)
}

/// A bus of its own for one test, served by generation 1 (the tests here play one ussd
/// instance each, except where a test restarts it).
fn unique_bus() -> Instance {
    static NEXT: AtomicU32 = AtomicU32::new(0);
    let n = NEXT.fetch_add(1, Ordering::Relaxed);
    let bus = BusName::new(&format!("t{}-{n}", std::process::id())).unwrap();
    Instance::new(bus, Generation(1))
}

fn drive(a: u8) -> Address {
    Address::new(a).unwrap()
}

fn version_attribute() -> AttributeSpecifier {
    AttributeSpecifier::new()
        .define(
            &LAYOUT_VERSION_ATTRIBUTE.try_into().unwrap(),
            &LAYOUT_VERSION.to_string().as_str().try_into().unwrap(),
        )
        .unwrap()
}

fn version_verifier() -> AttributeVerifier {
    AttributeVerifier::new()
        .require(
            &LAYOUT_VERSION_ATTRIBUTE.try_into().unwrap(),
            &LAYOUT_VERSION.to_string().as_str().try_into().unwrap(),
        )
        .unwrap()
}

/// ussd's side of a drive's `out` service.
fn create_out(ussd: &Node<Ipc>, bus: &Instance, a: Address) -> PubSub<Ipc, PzdOutput, ()> {
    ussd.service_builder(&names::drive_out(bus, a))
        .publish_subscribe::<PzdOutput>()
        .max_publishers(names::OUT_MAX_PUBLISHERS)
        .subscriber_max_buffer_size(names::OUT_LATEST_ONLY)
        .history_size(names::OUT_HISTORY)
        .enable_safe_overflow(true)
        .create_with_attributes(&version_attribute())
        .unwrap()
}

/// A controller's side of a drive's `out` service.
fn open_out(controller: &Node<Ipc>, bus: &Instance, a: Address) -> PubSub<Ipc, PzdOutput, ()> {
    controller
        .service_builder(&names::drive_out(bus, a))
        .publish_subscribe::<PzdOutput>()
        .open()
        .unwrap()
}

/// ussd's side of a drive's `in` service: a blackboard with one entry, `PzdInput::EMPTY`.
fn create_in(
    ussd: &Node<Ipc>,
    bus: &Instance,
    a: Address,
    max_readers: usize,
) -> Result<Blackboard<Ipc, BlackboardKey>, BlackboardCreateError> {
    ussd.service_builder(&names::drive_in(bus, a))
        .blackboard_creator::<BlackboardKey>()
        .max_readers(max_readers)
        .add::<PzdInput>(BlackboardKey::IMAGE, PzdInput::EMPTY)
        .create_with_attributes(&version_attribute())
}

/// A client's side of a blackboard.
fn open_blackboard(client: &Node<Ipc>, name: &ServiceName) -> Blackboard<Ipc, BlackboardKey> {
    client
        .service_builder(name)
        .blackboard_opener::<BlackboardKey>()
        .open()
        .unwrap()
}

/// The error of a call that must fail (entry handles have no `Debug` for `unwrap_err`).
fn refusal<T, E>(r: Result<T, E>) -> E {
    match r {
        Ok(_) => panic!("expected a refusal"),
        Err(e) => e,
    }
}

fn output(stw1: u16, setpoint: u16, sequence: u64) -> PzdOutput {
    PzdOutput::from_words(
        &[stw1, setpoint],
        sequence,
        sequence * 1000,
        std::process::id(),
    )
    .unwrap()
}

fn input(zsw1: u16, sequence: u64) -> PzdInput {
    PzdInput::from_words(&[zsw1, 0x199A], sequence, sequence * 1000, 20_000_000).unwrap()
}

// ---------------------------------------------------------------------------------------------
// a. One controller per drive.

#[test]
fn out_service_refuses_a_second_controller_with_exceeds_max_supported_publishers() {
    let bus = unique_bus();
    let ussd = node("ussd");
    let out = create_out(&ussd, &bus, drive(1));
    let subscriber = out
        .subscriber_builder()
        .buffer_size(names::OUT_LATEST_ONLY)
        .create()
        .unwrap();
    let (c1, c2) = (node("controller-1"), node("controller-2"));
    let (svc1, svc2) = (open_out(&c1, &bus, drive(1)), open_out(&c2, &bus, drive(1)));

    let p1 = svc1.publisher_builder().create().unwrap();
    let refused = svc2.publisher_builder().create().unwrap_err();
    assert_eq!(refused, PublisherCreateError::ExceedsMaxSupportedPublishers);
    assert_eq!(
        refused.to_string(),
        "PublisherCreateError::ExceedsMaxSupportedPublishers"
    );
    assert_eq!(
        svc1.publisher_builder().create().unwrap_err(),
        PublisherCreateError::ExceedsMaxSupportedPublishers,
        "also within the controller's own node"
    );

    // ussd receives the latest sample once, then nothing: it keeps its own copy between
    // samples (it needs one anyway for the controller watchdog).
    for seq in 1..=5 {
        p1.send_copy(output(0x047F, seq as u16, seq)).unwrap();
    }
    assert_eq!(
        subscriber.receive().unwrap().map(|s| *s),
        Some(output(0x047F, 5, 5))
    );
    assert!(subscriber.receive().unwrap().is_none());

    let ((), on_send) = allocations_in(|| {
        for seq in 6..=105 {
            p1.send_copy(output(0x047F, 0, seq)).unwrap();
        }
    });
    let (latest, on_receive) = allocations_in(|| subscriber.receive().unwrap().map(|s| s.sequence));
    assert_eq!(latest, Some(105));
    assert_eq!(on_receive, 0, "ussd's receive allocated");
    // One allocation per sample in the controller's process. (If this changes, update the
    // notes in `names` and ARCHITECTURE.md.)
    assert_eq!(
        on_send, 100,
        "send_copy no longer allocates once per sample"
    );

    // Handing over: when the first controller goes, the second takes over.
    drop(p1);
    let p2 = svc2.publisher_builder().create().unwrap();
    p2.send_copy(output(0x047E, 0, 1)).unwrap();
    assert_eq!(subscriber.receive().unwrap().map(|s| s.stw1), Some(0x047E));
}

/// A sample that ussd has not received yet goes with its publisher. So a controller that ends
/// cleanly publishes its release and keeps the publisher until ussd reports the release taken
/// (`PzdInput::taken_sequence`); otherwise a clean exit would look like a crash.
#[test]
fn a_sample_not_yet_received_is_lost_when_its_publisher_is_dropped() {
    let bus = unique_bus();
    let ussd = node("ussd");
    let out = create_out(&ussd, &bus, drive(2));
    let subscriber = out
        .subscriber_builder()
        .buffer_size(names::OUT_LATEST_ONLY)
        .create()
        .unwrap();
    let controller = node("controller");
    let publisher = open_out(&controller, &bus, drive(2))
        .publisher_builder()
        .create()
        .unwrap();
    publisher
        .send_copy(PzdOutput::release(7, 0, std::process::id()))
        .unwrap();
    drop(publisher);
    assert!(subscriber.receive().unwrap().is_none());
}

#[test]
fn blackboard_refuses_a_second_writer_so_clients_cannot_forge_input_images() {
    let bus = unique_bus();
    let ussd = node("ussd");
    let svc = create_in(&ussd, &bus, drive(2), 8).unwrap();
    let writer = svc.writer_builder().create().unwrap();
    let handle = writer.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();

    let rogue = node("rogue");
    let rsvc = open_blackboard(&rogue, &names::drive_in(&bus, drive(2)));
    let refused = rsvc.writer_builder().create().unwrap_err();
    assert_eq!(refused, WriterCreateError::ExceedsMaxSupportedWriters);
    assert_eq!(
        refused.to_string(),
        "WriterCreateError::ExceedsMaxSupportedWriters"
    );
    assert_eq!(
        svc.writer_builder().create().unwrap_err(),
        WriterCreateError::ExceedsMaxSupportedWriters
    );
    assert_eq!(
        refusal(writer.entry::<PzdInput>(&BlackboardKey::IMAGE)),
        EntryHandleMutError::HandleAlreadyExists,
        "one handle per entry, too"
    );

    let reader = rsvc.reader_builder().create().unwrap();
    let seen = reader.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();
    for seq in 1..=5 {
        handle.update_with_copy(input(0xFB34, seq));
    }
    assert_eq!(*seen.get(), input(0xFB34, 5));
}

// ---------------------------------------------------------------------------------------------
// b. Images and diagnostics ussd writes and anyone reads.

#[test]
fn input_blackboard_reader_reads_the_latest_value_and_neither_side_allocates() {
    let bus = unique_bus();
    let ussd = node("ussd");
    let svc = create_in(&ussd, &bus, drive(3), 8).unwrap();
    let writer = svc.writer_builder().create().unwrap();
    let handle = writer.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();
    let hmi = node("hmi");
    let csvc = open_blackboard(&hmi, &names::drive_in(&bus, drive(3)));
    let reader = csvc.reader_builder().create().unwrap();
    let entry = reader.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();

    let first = entry.get();
    assert_eq!(*first, PzdInput::EMPTY);
    assert!(entry.is_up_to_date(&first));
    handle.update_with_copy(input(0xFB34, 1));
    assert!(!entry.is_up_to_date(&first), "an update must be noticed");

    let (mismatches, allocations) = allocations_in(|| {
        let mut mismatches = 0;
        for seq in 2..=10_000u64 {
            handle.update_with_copy(input(seq as u16, seq));
            let v = entry.get();
            mismatches += usize::from(v.sequence != seq || v.zsw1 != seq as u16);
        }
        mismatches
    });
    assert_eq!(mismatches, 0);
    assert_eq!(allocations, 0, "update_with_copy + get allocated");
}

#[test]
fn input_blackboard_serves_readers_up_to_max_readers() {
    let bus = unique_bus();
    let ussd = node("ussd");
    let name = names::drive_in(&bus, drive(4));
    let svc = create_in(&ussd, &bus, drive(4), 4).unwrap();
    let writer = svc.writer_builder().create().unwrap();
    writer
        .entry::<PzdInput>(&BlackboardKey::IMAGE)
        .unwrap()
        .update_with_copy(input(0xFB34, 42));

    let clients: Vec<_> = (0..4).map(|i| node(&format!("hmi-{i}"))).collect();
    let services: Vec<_> = clients.iter().map(|c| open_blackboard(c, &name)).collect();
    let readers: Vec<_> = services
        .iter()
        .map(|s| s.reader_builder().create().unwrap())
        .collect();
    for r in &readers {
        let v = r.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap().get();
        assert_eq!(*v, input(0xFB34, 42));
    }
    assert_eq!(
        services[0].reader_builder().create().unwrap_err(),
        ReaderCreateError::ExceedsMaxSupportedReaders
    );
}

#[test]
fn diag_blackboard_is_keyed_by_drive_address() {
    let bus = unique_bus();
    let ussd = node("ussd");
    let mut creator = ussd
        .service_builder(&names::diag(&bus))
        .blackboard_creator::<BlackboardKey>();
    for a in [1, 2, 5] {
        creator = creator.add::<DriveDiag>(BlackboardKey::drive(drive(a)), DriveDiag::new(a));
    }
    let svc = creator.create().unwrap();
    let writer = svc.writer_builder().create().unwrap();
    let five = writer
        .entry::<DriveDiag>(&BlackboardKey::drive(drive(5)))
        .unwrap();
    five.update_with_copy(DriveDiag {
        online: 1,
        counters: DriveCounters {
            good: 17,
            ..DriveCounters::default()
        },
        ..DriveDiag::new(5)
    });

    let logger = node("logger");
    let csvc = open_blackboard(&logger, &names::diag(&bus));
    let mut keys = Vec::new();
    csvc.list_keys(|k| {
        keys.push(k.value);
        CallbackProgression::Continue
    });
    keys.sort_unstable();
    assert_eq!(keys, [1, 2, 5]);
    let reader = csvc.reader_builder().create().unwrap();
    let d = reader
        .entry::<DriveDiag>(&BlackboardKey::drive(drive(5)))
        .unwrap()
        .get();
    assert_eq!((d.address, d.online, d.counters.good), (5, 1, 17));
    assert_eq!(
        refusal(reader.entry::<DriveDiag>(&BlackboardKey::drive(drive(3)))),
        EntryHandleError::EntryDoesNotExist
    );
    // The value type is part of the entry: a wrong one is "does not exist", not garbage.
    assert_eq!(
        refusal(reader.entry::<PzdInput>(&BlackboardKey::drive(drive(1)))),
        EntryHandleError::EntryDoesNotExist
    );
}

#[test]
fn clients_of_another_layout_are_refused_when_they_open() {
    /// What a client built against a future layout would declare: same size and alignment.
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("UssPzdInputV99")]
    struct FutureInput([u64; size_of::<PzdInput>() / 8]);

    let bus = unique_bus();
    let ussd = node("ussd");
    let _in = create_in(&ussd, &bus, drive(6), 8).unwrap();
    let client = node("client");
    let opener = || {
        client
            .service_builder(&names::drive_in(&bus, drive(6)))
            .blackboard_opener::<BlackboardKey>()
    };
    let require = |version: &str| {
        AttributeVerifier::new()
            .require(
                &LAYOUT_VERSION_ATTRIBUTE.try_into().unwrap(),
                &version.try_into().unwrap(),
            )
            .unwrap()
    };
    let future = (uss_shm_types::LAYOUT_VERSION + 1).to_string();
    assert_eq!(
        opener()
            .open_with_attributes(&require(&future))
            .unwrap_err(),
        BlackboardOpenError::IncompatibleAttributes
    );
    let current = uss_shm_types::LAYOUT_VERSION.to_string();
    let svc = opener().open_with_attributes(&require(&current)).unwrap();
    let reader = svc.reader_builder().create().unwrap();
    assert_eq!(
        refusal(reader.entry::<FutureInput>(&BlackboardKey::IMAGE)),
        EntryHandleError::EntryDoesNotExist
    );
    assert!(reader.entry::<PzdInput>(&BlackboardKey::IMAGE).is_ok());
    // A publish-subscribe payload of another type name is refused at open.
    let _out = create_out(&ussd, &bus, drive(6));
    assert!(
        client
            .service_builder(&names::drive_out(&bus, drive(6)))
            .publish_subscribe::<FutureInput>()
            .open()
            .is_err()
    );
}

#[test]
fn threadsafe_ussd_ports_move_to_another_thread_and_serve_plain_ipc_clients() {
    let bus = unique_bus();
    let ussd = NodeBuilder::new()
        .config(config())
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcThreadsafe>()
        .unwrap();
    let name = names::drive_in(&bus, drive(7));
    let svc = ussd
        .service_builder(&name)
        .blackboard_creator::<BlackboardKey>()
        .add::<PzdInput>(BlackboardKey::IMAGE, PzdInput::EMPTY)
        .create()
        .unwrap();
    let writer = svc.writer_builder().create().unwrap();
    let handle = writer.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();
    // Ports made before the RT thread starts, then moved into it.
    std::thread::spawn(move || handle.update_with_copy(input(0xFB34, 9)))
        .join()
        .unwrap();

    let client = node("client");
    let csvc = open_blackboard(&client, &name);
    let reader = csvc.reader_builder().create().unwrap();
    let v = reader
        .entry::<PzdInput>(&BlackboardKey::IMAGE)
        .unwrap()
        .get();
    assert_eq!((v.zsw1, v.sequence), (0xFB34, 9));
}

// ---------------------------------------------------------------------------------------------
// c. Exchange and cycle events.

/// ussd's side of the `cycle` event service.
fn create_cycle(
    ussd: &Node<Ipc>,
    bus: &Instance,
) -> iceoryx2::service::port_factory::event::PortFactory<Ipc> {
    ussd.service_builder(&names::cycle(bus))
        .event()
        .event_id_max_value(names::EVENT_ID_MAX)
        .notifier_dead_event(EventId::new(names::USSD_GONE))
        .create_with_attributes(&version_attribute())
        .unwrap()
}

#[test]
fn cycle_event_delivers_exchange_and_cycle_ids_without_allocating() {
    let bus = unique_bus();
    let ussd = node("ussd");
    let notifier = create_cycle(&ussd, &bus)
        .notifier_builder()
        .create()
        .unwrap();
    let hmi = node("hmi");
    let listener = hmi
        .service_builder(&names::cycle(&bus))
        .event()
        .open()
        .unwrap()
        .listener_builder()
        .create()
        .unwrap();

    let mut none = 0;
    let woken = listener
        .timed_wait(|_| none += 1, Duration::from_millis(20))
        .unwrap();
    assert_eq!((woken, none), (0, 0), "nothing was notified yet");

    let three = names::exchange_completed(drive(3));
    notifier
        .notify_with_custom_event_id(EventId::new(three))
        .unwrap();
    notifier
        .notify_with_custom_event_id(EventId::new(three))
        .unwrap();
    let reached = notifier
        .notify_with_custom_event_id(EventId::new(names::CYCLE_COMPLETED))
        .unwrap();
    assert_eq!(reached, 1, "one listener notified");
    let mut seen = Vec::new();
    listener
        .try_wait(|a| seen.push((a.id.as_value(), a.count)))
        .unwrap();
    seen.sort_unstable();
    assert_eq!(seen, [(three, 2), (names::CYCLE_COMPLETED, 1)]);

    let (sum, allocations) = allocations_in(|| {
        let mut sum = 0;
        for _ in 0..1000 {
            notifier
                .notify_with_custom_event_id(EventId::new(names::CYCLE_COMPLETED))
                .unwrap();
            listener.try_wait(|a| sum += a.id.as_value()).unwrap();
        }
        sum
    });
    assert_eq!(sum, 1000 * names::CYCLE_COMPLETED);
    assert_eq!(allocations, 0, "notify + try_wait allocated");
}

#[test]
fn cycle_event_wakes_a_blocked_listener() {
    let bus = unique_bus();
    let (ready_tx, ready_rx) = mpsc::channel();
    let ussd_thread = {
        let bus = bus.clone();
        std::thread::spawn(move || {
            let ussd = node("ussd");
            let notifier = create_cycle(&ussd, &bus)
                .notifier_builder()
                .create()
                .unwrap();
            ready_tx.send(()).unwrap();
            std::thread::sleep(Duration::from_millis(50));
            notifier
                .notify_with_custom_event_id(EventId::new(names::CYCLE_COMPLETED))
                .unwrap();
            // Keep the service alive until the listener had its chance.
            std::thread::sleep(Duration::from_millis(200));
        })
    };
    ready_rx.recv().unwrap();
    let hmi = node("hmi");
    let listener = hmi
        .service_builder(&names::cycle(&bus))
        .event()
        .open()
        .unwrap()
        .listener_builder()
        .create()
        .unwrap();
    let start = Instant::now();
    let mut ids = Vec::new();
    listener
        .timed_wait(|a| ids.push(a.id.as_value()), Duration::from_secs(2))
        .unwrap();
    assert_eq!(ids, [names::CYCLE_COMPLETED]);
    assert!(start.elapsed() < Duration::from_secs(1), "woke by timeout");
    ussd_thread.join().unwrap();
}

// ---------------------------------------------------------------------------------------------
// d. Parameter requests: request-response, answered by a server loop.

/// What the test's ussd answers: each item's value is `pnu * 10 + index`.
fn answer(req: &ParamRequest) -> ParamResponse {
    match req.validate() {
        Err(refusal) => ParamResponse::refused(req.address, refusal),
        Ok((address, items)) => {
            let mut r = ParamResponse::new(address.get());
            r.count = items.len() as u8;
            for (slot, item) in r.results.iter_mut().zip(items) {
                *slot = ParamResult {
                    outcome: Outcome::Value.code(),
                    value: u32::from(item.pnu().map_or(0, Pnu::get)) * 10
                        + u32::from(item.subindex()),
                    telegrams: 1,
                    ..ParamResult::NOT_RUN
                };
            }
            r
        }
    }
}

/// ussd's IPC bridge loop until `stop`: polls the server (a server has no file descriptor to
/// wait on), answers each request once. Returns what every answered request allocated:
/// (in `receive`, in `send_copy`).
fn serve(bus: &Instance, ready: &mpsc::Sender<()>, stop: &AtomicBool) -> Vec<(u64, u64)> {
    let ussd = node("ussd-bridge");
    let svc = ussd
        .service_builder(&names::params(bus))
        .request_response::<ParamRequest, ParamResponse>()
        .create_with_attributes(&version_attribute())
        .unwrap();
    let server = svc.server_builder().create().unwrap();
    ready.send(()).unwrap();
    let mut allocations = Vec::with_capacity(64);
    while !stop.load(Ordering::Acquire) {
        let (active, on_receive) = allocations_in(|| server.receive().unwrap());
        match active {
            Some(active) => {
                let ((), on_send) =
                    allocations_in(|| active.send_copy(answer(active.payload())).unwrap());
                allocations.push((on_receive, on_send));
            }
            None => std::thread::sleep(Duration::from_micros(100)),
        }
    }
    allocations
}

type ParamClient = Client<Ipc, ParamRequest, (), ParamResponse, ()>;

/// Sends `req`, waits for its response and checks no second one follows.
fn round_trip(client: &ParamClient, req: &ParamRequest) -> ParamResponse {
    let pending = client.send_copy(*req).unwrap();
    let deadline = Instant::now() + Duration::from_secs(2);
    let response = loop {
        if let Some(r) = pending.receive().unwrap() {
            break *r;
        }
        assert!(Instant::now() < deadline, "no response within 2 s");
        std::thread::sleep(Duration::from_micros(50));
    };
    std::thread::sleep(Duration::from_millis(5));
    assert!(pending.receive().unwrap().is_none(), "a second response");
    response
}

#[test]
fn param_requests_get_exactly_one_response_from_a_server_loop() {
    let bus = unique_bus();
    let stop = Arc::new(AtomicBool::new(false));
    let (ready_tx, ready_rx) = mpsc::channel();
    let server = {
        let (bus, stop) = (bus.clone(), Arc::clone(&stop));
        std::thread::spawn(move || serve(&bus, &ready_tx, &stop))
    };
    ready_rx.recv().unwrap();

    let tool = node("ussctl");
    let client = tool
        .service_builder(&names::params(&bus))
        .request_response::<ParamRequest, ParamResponse>()
        .open()
        .unwrap()
        .client_builder()
        .create()
        .unwrap();

    let items = [
        ParamItem::read(1082),
        ParamItem::new(TaskCode::ReadArray, 2010, 3, 0, Storage::Ram),
        ParamItem::new(TaskCode::WriteWord, 1120, 0, 100, Storage::RamAndEeprom),
    ];
    let req = ParamRequest::new(drive(3), &items).unwrap();
    let r = round_trip(&client, &req);
    assert_eq!(
        (r.error(), r.address, r.count),
        (Ok(RequestError::Ok), 3, 3)
    );
    let values: Vec<_> = r.results().iter().map(|x| (x.outcome(), x.value)).collect();
    assert_eq!(
        values,
        [
            (Ok(Outcome::Value), 10_820),
            (Ok(Outcome::Value), 20_103),
            (Ok(Outcome::Value), 11_200)
        ]
    );

    let mut bad = req;
    bad.items[1].index = 300;
    let r = round_trip(&client, &bad);
    assert_eq!(
        (r.error(), r.error_item, r.count),
        (Ok(RequestError::BadSubindex), 1, 0)
    );

    let ((), client_allocations) = allocations_in(|| {
        for _ in 0..10 {
            round_trip(&client, &req);
        }
    });
    stop.store(true, Ordering::Release);
    let server_allocations = server.join().unwrap();
    assert_eq!(server_allocations.len(), 12, "one answer per request");
    eprintln!(
        "request-response: server allocations per request (receive, send_copy) \
         {server_allocations:?}; client {client_allocations} over 10 round trips"
    );
    // The first request sets up the connection. After that every request costs the same: the
    // bridge thread allocates per request but does not grow. (If iceoryx2 stops allocating
    // here, the reason ARCHITECTURE.md gives for the bridge thread changed: update it.)
    let steady = server_allocations[1];
    assert!(
        steady.0 + steady.1 > 0,
        "request-response stopped allocating"
    );
    assert!(
        server_allocations[1..].iter().all(|n| *n == steady),
        "server allocations vary: {server_allocations:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// e. A process that dies: detected, its ports freed.

/// A child process that is killed when the test ends, whatever happens (a child left running
/// would keep the test's output pipe open).
struct ChildGuard(Child);

impl Drop for ChildGuard {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Runs this test binary's [`child_process`] in `role`, in the instance `config`.
fn spawn_child(
    role: &str,
    bus: &Instance,
    config: &Config,
) -> (ChildGuard, BufReader<ChildStdout>) {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args([
            "child_process",
            "--exact",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(ROLE_ENV, role)
        .env(PREFIX_ENV, config.global.prefix.as_str())
        .env(BUS_ENV, bus.bus.as_str())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let out = BufReader::new(child.stdout.take().unwrap());
    (ChildGuard(child), out)
}

/// What the child printed after `tag` (the test harness may print before it on the same line).
fn child_says(out: &mut BufReader<ChildStdout>, tag: &str) -> String {
    let mut line = String::new();
    loop {
        line.clear();
        assert_ne!(
            out.read_line(&mut line).unwrap(),
            0,
            "child ended before {tag}"
        );
        if let Some((_, rest)) = line.split_once(tag) {
            return rest.trim().to_owned();
        }
    }
}

/// Starts a child in `role`, waits until it is READY, kills it with SIGKILL (no destructor
/// runs) and returns its process id.
fn kill_child(role: &str, bus: &Instance, config: &Config) -> i32 {
    let (mut child, mut out) = spawn_child(role, bus, config);
    let pid = i32::try_from(child.0.id()).unwrap();
    assert_eq!(child_says(&mut out, "READY"), "");
    child.0.kill().unwrap();
    child.0.wait().unwrap();
    pid
}

/// The dead nodes `Node::list` reports: (id, process id, name).
fn dead_nodes(config: &Config) -> Vec<(UniqueNodeId, i32, String)> {
    let mut dead = Vec::new();
    Node::<Ipc>::list(config, |state| {
        if let NodeState::Dead(view) = state {
            let details = view.details().as_ref().expect("details of a dead node");
            dead.push((
                *view.id(),
                details.process_id().value(),
                details.name().as_str().to_owned(),
            ));
        }
        CallbackProgression::Continue
    })
    .unwrap();
    dead
}

/// Cleans up dead nodes of this test instance even when an assertion fails.
struct CleanupDeadNodes<'a>(&'a Node<Ipc>);

impl Drop for CleanupDeadNodes<'_> {
    fn drop(&mut self) {
        self.0.try_cleanup_dead_nodes();
    }
}

#[test]
fn killed_controller_is_listed_dead_and_cleanup_removes_its_publisher() {
    let (bus, config) = (unique_bus(), isolated());
    let ussd = node_in(&config, "ussd");
    let _cleanup = CleanupDeadNodes(&ussd);
    let out = create_out(&ussd, &bus, drive(1));
    let subscriber = out.subscriber_builder().create().unwrap();

    let pid = kill_child("controller", &bus, &config);

    // The sample sent before the kill is still delivered; the dead publisher keeps its slot.
    assert_eq!(subscriber.receive().unwrap().map(|s| s.stw1), Some(0x047F));
    let mut publisher_nodes = Vec::new();
    out.dynamic_config().list_publishers(|p| {
        publisher_nodes.push(p.node_id);
        CallbackProgression::Continue
    });
    assert_eq!(publisher_nodes.len(), 1);

    // Node::list shows the publisher's node dead, with its process id and name; so does the
    // service's own node list.
    assert_eq!(
        dead_nodes(&config),
        [(publisher_nodes[0], pid, "controller-child".to_owned())]
    );
    let mut dead_on_service = Vec::new();
    out.nodes(|state| {
        if let NodeState::Dead(view) = state {
            dead_on_service.push(*view.id());
        }
        CallbackProgression::Continue
    })
    .unwrap();
    assert_eq!(dead_on_service, publisher_nodes);

    let cleaned = ussd.try_cleanup_dead_nodes();
    assert_eq!((cleaned.cleanups, cleaned.failed_cleanups), (1, 0));
    assert_eq!(out.dynamic_config().number_of_publishers(), 0);
    assert!(dead_nodes(&config).is_empty());
}

#[test]
fn next_controller_takes_over_from_a_killed_one_by_opening_the_service() {
    let (bus, config) = (unique_bus(), isolated());
    let ussd = node_in(&config, "ussd");
    let _cleanup = CleanupDeadNodes(&ussd);
    let out = create_out(&ussd, &bus, drive(1));
    let subscriber = out.subscriber_builder().create().unwrap();
    kill_child("controller", &bus, &config);
    assert_eq!(out.dynamic_config().number_of_publishers(), 1);

    // `service.cleanup_dead_nodes_on_open` (default true): opening removes the dead node from
    // the service, so the next controller gets the publisher without anyone calling cleanup.
    assert!(config.global.service.cleanup_dead_nodes_on_open);
    let replacement = node_in(&config, "controller-new");
    let svc = open_out(&replacement, &bus, drive(1));
    assert_eq!(out.dynamic_config().number_of_publishers(), 0);
    let publisher = svc.publisher_builder().create().unwrap();
    publisher.send_copy(output(0x047E, 0, 1)).unwrap();
    let mut last = None;
    while let Some(s) = subscriber.receive().unwrap() {
        last = Some(s.stw1);
    }
    assert_eq!(last, Some(0x047E));
}

#[test]
fn listeners_hear_ussd_gone_when_the_killed_ussd_is_cleaned_up() {
    let (bus, config) = (unique_bus(), isolated());
    let hmi = node_in(&config, "hmi");
    let _cleanup = CleanupDeadNodes(&hmi);
    let (mut child, mut out) = spawn_child("ussd", &bus, &config);
    assert_eq!(child_says(&mut out, "READY"), "");
    let listener = hmi
        .service_builder(&names::cycle(&bus))
        .event()
        .open()
        .unwrap()
        .listener_builder()
        .create()
        .unwrap();
    child.0.kill().unwrap();
    child.0.wait().unwrap();

    let mut ids = Vec::new();
    listener.try_wait(|a| ids.push(a.id.as_value())).unwrap();
    assert!(
        ids.is_empty(),
        "announced before anyone cleaned up: {ids:?}"
    );
    assert_eq!(hmi.try_cleanup_dead_nodes().cleanups, 1);
    listener
        .timed_wait(|a| ids.push(a.id.as_value()), Duration::from_secs(1))
        .unwrap();
    assert_eq!(ids, [names::USSD_GONE]);
}

/// ussd's side of the heartbeat service: opened if clients of an earlier ussd hold it,
/// created otherwise.
fn open_heartbeat(ussd: &Node<Ipc>, bus: &Instance) -> PubSub<Ipc, Heartbeat, ()> {
    ussd.service_builder(&names::heartbeat(&bus.bus))
        .publish_subscribe::<Heartbeat>()
        .max_publishers(1)
        .subscriber_max_buffer_size(1)
        .history_size(1)
        .enable_safe_overflow(true)
        .open_or_create_with_attributes(&version_verifier())
        .unwrap()
}

/// What a restarted ussd relies on: a client subscribed to the heartbeat of a killed ussd stays
/// subscribed, the restarted one cleans up the dead node, takes the one publisher slot and is
/// heard by that subscriber; a client that subscribes later gets its newest heartbeat at once.
#[test]
fn a_restarted_ussd_takes_over_the_heartbeat_while_clients_stay_subscribed() {
    let (bus, config) = (unique_bus(), isolated());
    let hmi = node_in(&config, "hmi");
    let _cleanup = CleanupDeadNodes(&hmi);
    let (mut child, mut out) = spawn_child("heartbeat", &bus, &config);
    assert_eq!(child_says(&mut out, "READY"), "");
    let subscriber = open_heartbeat(&hmi, &bus)
        .subscriber_builder()
        .buffer_size(1)
        .create()
        .unwrap();
    // A subscriber is connected when the publisher sends next: within one period.
    assert_eq!(next_heartbeat(&subscriber).generation, 1);
    child.0.kill().unwrap();
    child.0.wait().unwrap();

    let restarted = node_in(&config, "ussd-restarted");
    assert_eq!(restarted.try_cleanup_dead_nodes().cleanups, 1);
    let service = open_heartbeat(&restarted, &bus);
    let publisher = service.publisher_builder().create().unwrap();
    publisher
        .send_copy(Heartbeat::new(std::process::id(), Generation(2)))
        .unwrap();
    assert_eq!(
        next_heartbeat(&subscriber).generation,
        2,
        "the old subscriber hears the new ussd"
    );
    let late = open_heartbeat(&node_in(&config, "late"), &bus)
        .subscriber_builder()
        .buffer_size(1)
        .create()
        .unwrap();
    publisher
        .send_copy(Heartbeat::new(std::process::id(), Generation(2)))
        .unwrap();
    assert_eq!(
        next_heartbeat(&late).generation,
        2,
        "history at the next send"
    );
}

/// The next heartbeat, waiting up to 1 s.
fn next_heartbeat(
    subscriber: &iceoryx2::port::subscriber::Subscriber<Ipc, Heartbeat, ()>,
) -> Heartbeat {
    let deadline = Instant::now() + Duration::from_secs(1);
    loop {
        if let Some(h) = subscriber.receive().unwrap() {
            return *h;
        }
        assert!(Instant::now() < deadline, "no heartbeat");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// iceoryx2 0.10 (eclipse-iceoryx/iceoryx2#2008, open): cleanup frees a killed writer's port
/// but not the entry it held (`has_producer` stays set in shared memory), so no later writer
/// can update that entry while the service lives. A restarted ussd therefore writes its
/// blackboards only after every client dropped them. When this test fails, the fix arrived.
#[test]
fn restarted_ussd_writes_its_blackboards_only_after_clients_reopened() {
    let (bus, config) = (unique_bus(), isolated());
    let hmi = node_in(&config, "hmi");
    let _cleanup = CleanupDeadNodes(&hmi);
    let name = names::drive_in(&bus, drive(1));
    let (mut child, mut out) = spawn_child("ussd", &bus, &config);
    assert_eq!(child_says(&mut out, "READY"), "");
    let svc = open_blackboard(&hmi, &name);
    let reader = svc.reader_builder().create().unwrap();
    let entry = reader.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();
    child.0.kill().unwrap();
    child.0.wait().unwrap();
    assert_eq!(entry.get().zsw1, 0xFB34, "the last value stays readable");

    let restarted = node_in(&config, "ussd-restarted");
    assert_eq!(
        create_in(&restarted, &bus, drive(1), 8).unwrap_err(),
        BlackboardCreateError::AlreadyExists,
        "the client keeps the service alive"
    );
    {
        let opened = open_blackboard(&restarted, &name);
        let writer = opened.writer_builder().create().unwrap();
        assert_eq!(
            refusal(writer.entry::<PzdInput>(&BlackboardKey::IMAGE)),
            EntryHandleMutError::HandleAlreadyExists,
            "the dead writer's entry stays locked"
        );
    }

    // The client drops the service (on USSD_GONE); ussd creates it afresh; the client reopens.
    drop((entry, reader, svc));
    let svc = create_in(&restarted, &bus, drive(1), 8).unwrap();
    let writer = svc.writer_builder().create().unwrap();
    writer
        .entry::<PzdInput>(&BlackboardKey::IMAGE)
        .unwrap()
        .update_with_copy(input(0xFB31, 1));
    let reopened = open_blackboard(&hmi, &name);
    let reader = reopened.reader_builder().create().unwrap();
    let v = reader
        .entry::<PzdInput>(&BlackboardKey::IMAGE)
        .unwrap()
        .get();
    assert_eq!((v.zsw1, v.sequence), (0xFB31, 1));
}

// ---------------------------------------------------------------------------------------------
// f. Signal handling stays with the process.

/// SIGINT and SIGTERM bits of a child's caught-signal mask (`SigCgt` in /proc/self/status).
fn caught_int_term(role: &str) -> (bool, bool) {
    let (mut child, mut out) = spawn_child(role, &unique_bus(), config());
    let mask = u64::from_str_radix(&child_says(&mut out, "SIGCGT"), 16).unwrap();
    assert!(child.0.wait().unwrap().success());
    (mask & (1 << (2 - 1)) != 0, mask & (1 << (15 - 1)) != 0)
}

#[test]
fn node_with_signal_handling_disabled_installs_no_sigint_or_sigterm_handler() {
    assert_eq!(caught_int_term("signals-disabled"), (false, false));
}

#[test]
fn node_with_default_signal_handling_catches_sigint_and_sigterm_once_it_waits() {
    assert_eq!(caught_int_term("signals-default"), (true, true));
}

// ---------------------------------------------------------------------------------------------
// Child processes.

/// Prints `READY`, then waits for the parent's SIGKILL (never outliving a parent that failed
/// to send it).
fn ready_until_killed() {
    println!("READY");
    std::io::stdout().flush().unwrap();
    std::thread::sleep(Duration::from_secs(30));
}

/// Not a test of its own: the entry point of the child processes the tests above spawn. Does
/// nothing unless `USS_SHM_TEST_ROLE` is set.
#[test]
fn child_process() {
    let Ok(role) = std::env::var(ROLE_ENV) else {
        return;
    };
    let bus = Instance::new(
        BusName::new(&std::env::var(BUS_ENV).unwrap()).unwrap(),
        Generation(1),
    );
    match role.as_str() {
        "controller" => {
            let node = node("controller-child");
            let publisher = open_out(&node, &bus, drive(1))
                .publisher_builder()
                .create()
                .unwrap();
            publisher.send_copy(output(0x047F, 0x2000, 7)).unwrap();
            ready_until_killed();
        }
        "ussd" => {
            let node = node("ussd-child");
            let svc = create_in(&node, &bus, drive(1), 8).unwrap();
            let writer = svc.writer_builder().create().unwrap();
            let entry = writer.entry::<PzdInput>(&BlackboardKey::IMAGE).unwrap();
            entry.update_with_copy(input(0xFB34, 9));
            let _notifier = create_cycle(&node, &bus)
                .notifier_builder()
                .create()
                .unwrap();
            ready_until_killed();
        }
        "heartbeat" => {
            let node = node("ussd-child");
            let publisher = open_heartbeat(&node, &bus)
                .publisher_builder()
                .create()
                .unwrap();
            let mut h = Heartbeat::new(std::process::id(), Generation(1));
            println!("READY");
            std::io::stdout().flush().unwrap();
            // As ussd does: a heartbeat every period (here 10 ms), until killed.
            for sequence in 1..3000 {
                h.sequence = sequence;
                publisher.send_copy(h).unwrap();
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        "signals-disabled" | "signals-default" => {
            let mode = if role == "signals-disabled" {
                SignalHandlingMode::Disabled
            } else {
                SignalHandlingMode::HandleTerminationRequests
            };
            let node = NodeBuilder::new()
                .config(config())
                .signal_handling_mode(mode)
                .create::<Ipc>()
                .unwrap();
            assert_eq!(node.signal_handling_mode(), mode);
            node.wait(Duration::from_millis(1)).unwrap();
            let status = std::fs::read_to_string("/proc/self/status").unwrap();
            let mask = status
                .lines()
                .find_map(|l| l.strip_prefix("SigCgt:"))
                .unwrap();
            println!("SIGCGT {}", mask.trim());
        }
        other => panic!("unknown child role {other}"),
    }
}
