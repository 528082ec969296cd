//! Fail-safe control, end to end (issue 7): real `ussd` processes, real clients (`ussctl`, this
//! process through the Rust API, a raw iceoryx2 publisher as a foreign controller would be),
//! real signals. No drive ever runs without a live, deliberate command:
//!
//! - a frozen controller trips the drive once; when it resumes the drive stays stopped until a
//!   controller re-arms it (OFF1, then ON), and `ussctl run` reports the trip and fails;
//! - a sample the drive would misread is refused at the poll that takes it, latched, named;
//! - a clean release is "released", a SIGKILL is a watchdog trip: counted apart;
//! - a call that waits for a drive with a short watchdog (18 ms) refreshes within it;
//! - `ussctl stop/coast/quick-stop` (one drive or `--all`) override a running controller;
//! - after an operator's stop a jogging controller re-arms nothing; only its stop does, and only
//!   one that names the latch (a stop republished from before it, as a refresher would, or one
//!   that crossed the operator's stop, never does);
//! - parameter writes to a controlled drive need `--force` (or the controlling process);
//! - a drive whose own telegram monitoring is off is reported, and refused ON when required;
//! - the same freeze over a real pty with `uss-sim`.
//!
//! Each test starts its own ussd on a bus named after this process; the tests take turns.
//! Measured latencies are printed (run with `--nocapture`).
#![allow(clippy::unwrap_used, clippy::float_cmp)]

use iceoryx2::prelude::*;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use uss_client::{
    Bus, ClientError, ControlOptions, DriveState, LatchReason, Monitoring, ParamError, PzdInput,
    Rejection, Setpoint, StopCommand, Value, WriteOptions, state_of,
};
use uss_integration_tests::{ChildProc, SimProcess, Ussd, monotonic_ns};
use uss_integration_tests::{addr, param};
use uss_shm_types::names;
use uss_shm_types::service::Ipc;
use uss_shm_types::{Address, BusName, Heartbeat, Instance, LAYOUT_VERSION, PzdOutput};

/// One ussd at a time: each runs a `SCHED_FIFO` bus thread, and the machine has two cores.
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(PoisonError::into_inner)
}

const OFF1: u16 = 0x047E;
const OFF2: u16 = 0x047C;
const OFF3: u16 = 0x047A;
const RUN: u16 = 0x047F;

fn hz(i: &PzdInput) -> f32 {
    Setpoint::from_word(i.hiw).hz(50.0)
}

fn signal(child: &ChildProc, s: Signal) -> u64 {
    let at = monotonic_ns();
    kill(Pid::from_raw(i32::try_from(child.pid()).unwrap()), s).unwrap();
    at
}

/// Whether ussd logged a line with `text` (waiting up to 2 s for it).
fn logged(ussd: &Ussd, text: &str) -> bool {
    ussd.log_line(text, Duration::from_secs(2)).is_some()
}

/// Quick ramps for drive `a`: 50 Hz in 1 s up, in 0.5 s down.
fn quick_ramps(bus: &Bus, a: u8) {
    bus.write(addr(a), param(1120), Value::from_f32(1.0), false)
        .unwrap();
    bus.write(addr(a), param(1121), Value::from_f32(0.5), false)
        .unwrap();
}

/// `ussctl run DRIVE --hz HZ` until it says the drive runs.
fn run(ussd: &Ussd, drive: u8, hz: &str) -> ChildProc {
    // `ussctl run` re-arms only a latch older than its start, which the kernel knows to 10 ms:
    // a latch made just now (a release, a stop of the test's own) is let age past that first.
    let latch = ussd.bus().watch(addr(drive)).unwrap().latest().latch_id;
    while monotonic_ns().saturating_sub(latch) < 20_000_000 {
        std::thread::sleep(Duration::from_millis(2));
    }
    let mut run = ussd.ussctl(&["run", &drive.to_string(), "--hz", hz]);
    let said = run.says(&format!("drive {drive}:"));
    assert!(said.starts_with(" running towards"), "{said}");
    run
}

/// Waits for `ussctl run` to end: its exit code and stderr.
fn ended(run: &mut ChildProc, within: Duration) -> (Option<i32>, String) {
    let deadline = Instant::now() + within;
    while run.child.try_wait().unwrap().is_none() {
        assert!(Instant::now() < deadline, "ussctl run still runs");
        std::thread::sleep(Duration::from_millis(10));
    }
    let (status, _, err) = run.finish();
    (status.code(), err)
}

/// The first image at or after now that `done` accepts, looking every 100 us.
fn first_image(bus: &Bus, a: u8, timeout: Duration, done: impl Fn(&PzdInput) -> bool) -> PzdInput {
    let watch = bus.watch(addr(a)).unwrap();
    let deadline = Instant::now() + timeout;
    loop {
        let i = watch.latest();
        if done(&i) {
            return i;
        }
        assert!(Instant::now() < deadline, "drive {a}: still {i:?}");
        std::thread::sleep(Duration::from_micros(100));
    }
}

/// `processes` processes each holding 8 connections to the stop socket at `path` that never say
/// anything (made again as soon as ussd closes one).
fn idle_connections(path: &std::path::Path, processes: usize) -> Vec<ChildProc> {
    stop_socket_users(
        "uss-idle-connections",
        &[path.as_os_str(), "8".as_ref()],
        "holding 8",
        processes,
    )
}

/// `processes` processes connecting to the stop socket at `path` and closing at once, in a
/// tight loop.
fn flooders(path: &std::path::Path, processes: usize) -> Vec<ChildProc> {
    stop_socket_users("uss-stop-flood", &[path.as_os_str()], "flooding", processes)
}

/// `processes` runs of this crate's `binary` with `args`, each once it said `ready`.
fn stop_socket_users(
    binary: &str,
    args: &[&std::ffi::OsStr],
    ready: &str,
    processes: usize,
) -> Vec<ChildProc> {
    (0..processes)
        .map(|_| {
            let mut command = std::process::Command::new(uss_integration_tests::binary(
                "uss-integration-tests",
                binary,
            ));
            command.args(args);
            let mut child = ChildProc::spawn(binary.into(), command);
            child.says(ready);
            child
        })
        .collect()
}

/// The drive's diagnostics once `done` accepts them (republished every 100 ms).
fn diag_when(
    bus: &Bus,
    a: u8,
    done: impl Fn(&uss_client::DriveDiag) -> bool,
) -> uss_client::DriveDiag {
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let d = bus.diag(addr(a)).unwrap();
        if done(&d) {
            return d;
        }
        assert!(
            Instant::now() < deadline,
            "drive {a}: diagnostics still {d:?}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Asserts for `during` that drive `a` stays latched by `reason` with OFF1 going out and never
/// runs faster than it did at the start.
fn stays_stopped(bus: &Bus, a: u8, reason: LatchReason, during: Duration) {
    let watch = bus.watch(addr(a)).unwrap();
    let start = watch.latest();
    let end = Instant::now() + during;
    while Instant::now() < end {
        let i = watch.latest();
        assert_eq!(i.latch_reason, reason.code(), "{i:?}");
        assert_eq!(i.sent_stw1, OFF1, "{i:?}");
        assert!(hz(&i) <= hz(&start) + 0.01, "the motor speeds up: {i:?}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn frozen_controller_trips_once_and_the_drive_stays_stopped_when_it_resumes() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "watchdog_ms = 100.0"), (2, "")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);
    let mut controller = run(&ussd, 1, "20");
    first_image(&bus, 1, Duration::from_secs(5), |i| hz(i) >= 19.9);

    let frozen_at = signal(&controller, Signal::SIGSTOP);
    let trip = first_image(&bus, 1, Duration::from_secs(2), |i| !i.is_live());
    let latency = trip.timestamp_ns.saturating_sub(frozen_at) as f64 / 1e6;
    println!("failsafe: frozen controller latched {latency:.1} ms after SIGSTOP (watchdog 100 ms)");
    assert_eq!(trip.latch_reason, LatchReason::Stale.code());
    assert_eq!(trip.sent_stw1, OFF1, "the trip's own telegram carried OFF1");
    // The last refresh (every 20 ms) may have come up to 20 ms before the freeze: the watchdog
    // runs from it, not from the freeze.
    assert!(latency > 75.0, "tripped before its watchdog: {latency} ms");
    // It ramps down to S2, then the controller resumes.
    first_image(&bus, 1, Duration::from_secs(3), |i| {
        state_of(i) == DriveState::ReadyToSwitchOn && i.hiw == 0
    });
    signal(&controller, Signal::SIGCONT);
    stays_stopped(&bus, 1, LatchReason::Stale, Duration::from_secs(1));
    let (code, err) = ended(&mut controller, Duration::from_secs(3));
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("drive 1 on")
            && err.contains("tripped after")
            && err.contains("its controller stopped publishing within the watchdog time")
            && err.contains("run `ussctl run 1` again to re-arm it"),
        "{err}"
    );
    let d = diag_when(&bus, 1, |d| d.counters.watchdog_trips == 1);
    assert_eq!(d.latch_reason, LatchReason::Stale.code());
    assert!(logged(&ussd, "drive 1: controller stale"), "{}", ussd.log());

    // Only a deliberate re-arm runs it again: opening is none (the ON is the trip's news).
    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    assert!(matches!(c.run_hz(10.0), Err(ClientError::Tripped { .. })));
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.run_hz(10.0).unwrap();
    let again = c
        .wait_for(Duration::from_secs(5), "10 Hz", |i| hz(i) >= 9.9)
        .unwrap();
    assert!(again.is_live());
}

/// A foreign controller: a raw iceoryx2 publisher of the contract's `out` service.
struct RawController {
    publisher: iceoryx2::port::publisher::Publisher<Ipc, PzdOutput, ()>,
    /// The drive's image, for the latch a sample names.
    watch: uss_client::DriveWatch,
    sequence: u64,
    _node: Node<Ipc>,
}

impl RawController {
    fn open(bus_name: &str, a: u8) -> Self {
        let node = NodeBuilder::new()
            .config(&uss_shm_types::service::config().unwrap())
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .unwrap();
        // As any client: the newest heartbeat names the generation that serves the bus.
        let bus = BusName::new(bus_name).unwrap();
        let heartbeat = node
            .service_builder(&names::heartbeat(&bus))
            .publish_subscribe::<Heartbeat>()
            .open()
            .unwrap()
            .subscriber_builder()
            .create()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(2);
        let beat = loop {
            if let Some(beat) = heartbeat.receive().unwrap() {
                break *beat;
            }
            assert!(Instant::now() < deadline, "no heartbeat");
            std::thread::sleep(Duration::from_millis(1));
        };
        let instance = Instance::new(bus, beat.generation());
        let name = names::drive_out(&instance, Address::new(a).unwrap());
        let publisher = node
            .service_builder(&name)
            .publish_subscribe::<PzdOutput>()
            .open()
            .unwrap()
            .publisher_builder()
            .create()
            .unwrap();
        Self {
            publisher,
            watch: Bus::open(bus_name).unwrap().watch(addr(a)).unwrap(),
            sequence: 0,
            _node: node,
        }
    }

    /// Publishes `words` naming the latch the drive's image shows now, as a controller that
    /// looked at it; returns the sample's sequence number.
    fn words(&mut self, words: &[u16]) -> u64 {
        let seen = self.watch.latest().latch_id;
        self.words_naming(words, seen)
    }

    /// Publishes `words` naming latch `latch_id` (0: none).
    fn words_naming(&mut self, words: &[u16], latch_id: u64) -> u64 {
        let sample = PzdOutput::from_words(words, 0, monotonic_ns(), std::process::id()).unwrap();
        self.send(sample.naming(latch_id))
    }

    /// Publishes `sample` with the next sequence number; returns that number.
    fn send(&mut self, mut sample: PzdOutput) -> u64 {
        self.sequence += 1;
        sample.sequence = self.sequence;
        self.publisher.send_copy(sample).unwrap();
        self.sequence
    }

    /// Publishes `words` every 10 ms until drive `a` satisfies `done`.
    fn until(&mut self, bus: &Bus, a: u8, words: &[u16], done: impl Fn(&PzdInput) -> bool) {
        let watch = bus.watch(addr(a)).unwrap();
        let deadline = Instant::now() + Duration::from_secs(5);
        while !done(&watch.latest()) {
            assert!(Instant::now() < deadline, "{:?}", watch.latest());
            self.words(words);
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

#[test]
fn every_kind_of_bad_sample_from_a_raw_publisher_latches_the_drive_at_the_poll_that_takes_it() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let bus = ussd.bus();
    let mut raw = RawController::open(&ussd.bus, 1);
    let valid = PzdOutput::from_words(&[RUN, 0x2000], 0, 0, std::process::id()).unwrap();
    let kinds = [
        (
            "an all-zero C struct",
            PzdOutput {
                version: 0,
                word_count: 0,
                stw1: 0,
                setpoint: 0,
                ..valid
            },
            Rejection::Version,
        ),
        (
            "STW1 0x0000",
            PzdOutput {
                stw1: 0x0000,
                ..valid
            },
            Rejection::NoPlcControl,
        ),
        (
            "STW1 0x007F (bit 10 clear)",
            PzdOutput {
                stw1: 0x007F,
                ..valid
            },
            Rejection::NoPlcControl,
        ),
        (
            "1 word for a drive with 2",
            PzdOutput {
                word_count: 1,
                ..valid
            },
            Rejection::WordCount,
        ),
        (
            "word count 0",
            PzdOutput {
                word_count: 0,
                ..valid
            },
            Rejection::WordCount,
        ),
        (
            "layout version 3",
            PzdOutput {
                version: LAYOUT_VERSION + 1,
                ..valid
            },
            Rejection::Version,
        ),
    ];
    for (n, (name, bad, rejection)) in kinds.into_iter().enumerate() {
        // Armed with OFF1, running with ON.
        raw.until(&bus, 1, &[OFF1, 0], PzdInput::is_live);
        raw.until(&bus, 1, &[RUN, 0x1000], |i| {
            state_of(i) == DriveState::OperationEnabled
        });
        let seq = raw.send(bad);
        let taken = first_image(&bus, 1, Duration::from_secs(1), |i| i.taken_sequence >= seq);
        assert_eq!(taken.taken_sequence, seq, "{name}");
        assert_eq!(
            taken.sent_stw1, OFF1,
            "{name}: the safe command at the poll that took it"
        );
        assert_eq!(taken.latch_reason, LatchReason::Rejected.code(), "{name}");
        assert_eq!(taken.rejection, rejection.code(), "{name}");
        assert_eq!(taken.latched_by_pid, std::process::id(), "{name}");
        // The good samples after it do not bring the drive back.
        for _ in 0..20 {
            raw.words(&[RUN, 0x1000]);
            std::thread::sleep(Duration::from_millis(10));
        }
        let after = bus.watch(addr(1)).unwrap().latest();
        assert_eq!(
            (after.sent_stw1, after.latch_reason),
            (OFF1, LatchReason::Rejected.code()),
            "{name}"
        );
        let d = diag_when(&bus, 1, |d| d.counters.rejected_outputs == n as u64 + 1);
        assert_eq!(d.rejection, rejection.code(), "{name}");
    }
    assert_eq!(
        bus.diag(addr(1)).unwrap().counters.watchdog_trips,
        0,
        "refusals are not watchdog trips"
    );
    let log = ussd.log_line(
        "(STW1 bit 10 (control by PLC) is clear)",
        Duration::from_secs(2),
    );
    assert!(
        log.is_some_and(|l| l.contains("drive 1: refused a sample of process")),
        "{}",
        ussd.log()
    );
}

/// Identity from iceoryx2, not from the sample (issue 45): a sample that claims another
/// process (`controller_pid`, which a program may fill with any number) latches its drive as
/// the publisher's process, in the image (`latched_by_pid`) and in ussd's log.
#[test]
fn a_sample_that_claims_another_process_is_named_as_its_publishers() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut raw = RawController::open(&ussd.bus, 1);
    raw.until(&bus, 1, &[OFF1, 0], PzdInput::is_live);
    let forged = std::process::id() + 4242;
    let bad = PzdOutput::from_words(&[0x007F, 0], 0, 0, forged).unwrap();
    let seq = raw.send(bad);
    let taken = first_image(&bus, 1, Duration::from_secs(1), |i| i.taken_sequence >= seq);
    assert_eq!(taken.latch_reason, LatchReason::Rejected.code());
    assert_eq!(taken.latched_by_pid, std::process::id());
    let mine = format!(
        "drive 1: refused a sample of process {}",
        std::process::id()
    );
    assert!(
        ussd.log_line(&mine, Duration::from_secs(2)).is_some(),
        "{}",
        ussd.log()
    );
    assert!(!ussd.log().contains(&forged.to_string()), "{}", ussd.log());
}

/// The watchdog watches the program, not a thread (issue 20): a control loop that stops
/// calling (blocked, deadlocked) while its refresher thread lives trips the drive within the
/// watchdog time, and the program's next call is the trip, not a fresh start.
#[test]
fn a_refresher_does_not_keep_a_drive_live_for_a_program_that_stopped_calling() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);
    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    let refresher = c.spawn_refresher(Duration::from_millis(20));
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.run_hz(10.0).unwrap();
    c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(5))
        .unwrap();
    // The loop blocks: its last call was the wait above.
    let blocked = monotonic_ns();
    let tripped = first_image(&bus, 1, Duration::from_secs(2), |i| !i.is_live());
    let after = tripped.timestamp_ns.saturating_sub(blocked) as f64 / 1e6;
    println!("failsafe: a stalled program's drive latched {after:.0} ms after its last call");
    assert_eq!(
        tripped.latch_reason,
        LatchReason::Stale.code(),
        "{tripped:?}"
    );
    assert_eq!(tripped.sent_stw1, OFF1);
    stays_stopped(&bus, 1, LatchReason::Stale, Duration::from_millis(500));
    // Resumed, the program's next call is the trip; only the deliberate re-arm runs it again.
    assert!(matches!(c.run_hz(10.0), Err(ClientError::Tripped { .. })));
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.run_hz(10.0).unwrap();
    c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(5))
        .unwrap();
    refresher.stop().unwrap();
}

/// A drive with a short watchdog (18 ms; ussd's default is 100 ms): a call that waits for the
/// drive refreshes within that time (every quarter of the drive's watchdog time, at most every
/// 20 ms), so the wait itself never trips it. A process the machine does not run for longer
/// than the watchdog is stalled all the same (a loaded CI machine once held this one 21.6 ms):
/// such a trip is taken for what it is and the wait is tried again, up to three times; a wait
/// that refreshes too seldom (every 20 ms, as before the fix) trips in every one.
#[test]
fn a_waiting_call_keeps_a_drive_with_a_short_watchdog_live() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "watchdog_ms = 18")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);
    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    let mut stalls = Vec::new();
    for _ in 0..3 {
        let trips = bus.diag(addr(1)).unwrap().counters.watchdog_trips;
        c.rearm(uss_client::monotonic_ns()).unwrap();
        c.run_hz(10.0).unwrap();
        c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(5))
            .unwrap();
        // The program waits inside its own call for half a second: a timeout, not a trip.
        match c.wait_for(Duration::from_millis(500), "nothing", |_| false) {
            Err(ClientError::WaitTimeout { .. }) => {
                assert!(c.check().unwrap().is_live());
                let d = bus.diag(addr(1)).unwrap();
                assert_eq!(d.counters.watchdog_trips, trips, "{:?}", d.counters);
                println!("failsafe: a 500 ms wait on an 18 ms watchdog, stalls before: {stalls:?}");
                return;
            }
            Err(ClientError::Stalled { gap, .. }) => stalls.push(gap),
            other => panic!("{other:?}"),
        }
    }
    panic!("every wait stalled its drive (gaps {stalls:?}): it refreshes too seldom");
}

#[test]
fn a_clean_release_is_not_a_trip_and_a_sigkill_is() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);

    // `ussctl run --for` ends cleanly: released.
    let mut clean = ussd.ussctl(&["run", "1", "--hz", "10", "--for", "0.5"]);
    let (status, out, err) = clean.finish();
    assert!(status.success(), "{out}{err}");
    let d = diag_when(&bus, 1, |d| d.counters.releases == 1);
    assert_eq!(
        (d.latch_reason, d.counters.watchdog_trips),
        (LatchReason::Released.code(), 0)
    );
    assert!(
        logged(&ussd, "drive 1: released by its controller"),
        "{}",
        ussd.log()
    );
    assert!(
        ussd.log_line("drive 1: controller stale", Duration::from_millis(100))
            .is_none()
    );

    // A controller of this process that is dropped: released too, the drive confirmed it.
    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.wait_for(Duration::from_secs(2), "live", PzdInput::is_live)
        .unwrap();
    let released = c.release().unwrap();
    assert_eq!(released.latch_reason, LatchReason::Released.code());
    let d = diag_when(&bus, 1, |d| d.counters.releases == 2);
    assert_eq!(d.counters.watchdog_trips, 0);

    // SIGKILL: no release; the watchdog trips, counted.
    let mut killed = run(&ussd, 1, "10");
    killed.kill();
    let d = diag_when(&bus, 1, |d| d.counters.watchdog_trips == 1);
    assert_eq!(
        (d.latch_reason, d.counters.releases),
        (LatchReason::Stale.code(), 2)
    );
}

/// STOP-NOWAIT against a flood from many processes (found by the adversarial review): 34
/// processes of 8 idle connections (272, more than the 256 ussd serves at once; the bound per
/// process does not stop a flood that forks) made ussd close the oldest connection for each new
/// one, and a stop whose bytes came a few ms after its connect was lost (49 of 50 with 5 ms).
/// Now the process holding the most gives up one; a client's stop is answered.
#[test]
fn a_flood_of_idle_connections_from_many_processes_loses_no_stop() {
    use std::io::{Read as _, Write as _};
    use std::os::unix::net::UnixStream;
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let path = names::stop_socket(&BusName::new(&ussd.bus).unwrap());
    let holders = idle_connections(&path, 34);
    for i in 0..20 {
        let mut stream = UnixStream::connect(&path).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(2)))
            .unwrap();
        // A client that takes a moment between its connect and its bytes (a loaded machine).
        std::thread::sleep(Duration::from_millis(5));
        let request = uss_shm_types::OperatorRequest::new(2, StopCommand::Off1);
        stream
            .write_all(&request.to_bytes())
            .unwrap_or_else(|e| panic!("stop {i}: {e}"));
        let mut answer = [0u8; uss_shm_types::OPERATOR_RESPONSE_BYTES];
        stream
            .read_exact(&mut answer)
            .unwrap_or_else(|e| panic!("stop {i}: no answer: {e}"));
        let response = uss_shm_types::OperatorResponse::from_bytes(&answer).unwrap();
        assert_eq!(
            response.error(),
            Ok(uss_shm_types::CommandError::Ok),
            "stop {i}"
        );
    }
    let mut coast = ussd.ussctl(&["coast", "1"]);
    let (status, out, err) = coast.finish();
    assert!(status.success(), "{out}{err}");
    drop(holders);
}

/// REPLACED with `ussctl` (issue 32): `ussctl run`, SIGKILL, and at once another `ussctl run`
/// of the same drive, well within its watchdog time. The drive never stopped and no trip was
/// counted; a crash-restart loop went unseen. Now the second run's re-arm meets the trip its own
/// first sample caused ("controller replaced", counted): it stops the drive and says so, and
/// only a run after that (which re-arms the trip it saw) runs the drive again.
#[test]
fn a_killed_ussctl_run_replaced_at_once_is_a_trip() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "watchdog_ms = 2000")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);
    let mut first = run(&ussd, 1, "20");
    first_image(&bus, 1, Duration::from_secs(5), |i| hz(i) >= 19.9);
    first.kill();
    let mut second = ussd.ussctl(&["run", "1", "--hz", "40"]);
    let (status, out, err) = second.finish();
    assert_eq!(status.code(), Some(1), "{out}{err}");
    assert!(
        err.contains("its controller was replaced: process"),
        "{err}"
    );
    let i = bus.watch(addr(1)).unwrap().latest();
    assert_eq!(
        (i.latch_reason, i.sent_stw1),
        (LatchReason::Replaced.code(), OFF1),
        "{i:?}"
    );
    let d = diag_when(&bus, 1, |d| d.counters.replacements == 1);
    assert_eq!(
        d.counters.watchdog_trips, 0,
        "no stale trip: replaced first"
    );
    // The operator runs it again: that run re-arms the trip it saw.
    let mut third = run(&ussd, 1, "10");
    first_image(&bus, 1, Duration::from_secs(5), |i| {
        i.is_live() && i.sent_stw1 == 0x047F
    });
    third.kill();
}

/// Runs drives with `ussctl run`, gives the operator's `command` with `ussctl ARGS`, and checks
/// the STW1 that went out, the latch, and that each controller failed with the override.
fn operator_overrides(ussd: &Ussd, drives: &[u8], args: &[&str], stw1: u16, name: &str) {
    let bus = ussd.bus();
    let mut runs: Vec<ChildProc> = drives.iter().map(|&a| run(ussd, a, "20")).collect();
    let mut stop = ussd.ussctl(args);
    let (status, out, err) = stop.finish();
    assert!(status.success(), "{args:?}: {out}{err}");
    for &a in drives {
        assert!(
            out.contains(&format!("drive {a}: {name} sent (STW1 {stw1:#06X})")),
            "{args:?}: {out}"
        );
        let i = bus.watch(addr(a)).unwrap().latest();
        assert_eq!(
            (i.sent_stw1, i.latch_reason),
            (stw1, LatchReason::Override.code()),
            "{args:?}"
        );
    }
    for run in &mut runs {
        let (code, err) = ended(run, Duration::from_secs(3));
        assert_eq!(code, Some(1), "{err}");
        assert!(
            err.contains(&format!("an operator sent {name} from process")),
            "{err}"
        );
    }
    // Latched: still the operator's command after the controllers' last "run".
    std::thread::sleep(Duration::from_millis(300));
    for &a in drives {
        assert_eq!(
            bus.watch(addr(a)).unwrap().latest().sent_stw1,
            stw1,
            "{args:?}"
        );
    }
}

#[test]
fn ussctl_stop_coast_and_quick_stop_override_a_running_controller_and_latch() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, ""), (2, ""), (3, "")]);
    let bus = ussd.bus();
    for a in [1, 2, 3] {
        quick_ramps(&bus, a);
    }
    operator_overrides(&ussd, &[1], &["coast", "1"], OFF2, "OFF2");
    // OFF2 leaves the drive in S1 (switching-on inhibited) at once.
    first_image(&bus, 1, Duration::from_secs(1), |i| {
        state_of(i) == DriveState::SwitchingOnInhibited
    });
    operator_overrides(&ussd, &[2], &["stop", "2"], OFF1, "OFF1");
    operator_overrides(&ussd, &[3], &["quick-stop", "3"], OFF3, "OFF3");
    operator_overrides(&ussd, &[1, 2], &["quick-stop", "--all"], OFF3, "OFF3");
    assert_eq!(bus.diag(addr(2)).unwrap().counters.overrides, 2);

    // The latency of the override: the API call -> the first reply to a telegram carrying it.
    let c = bus.control(addr(3), ControlOptions::default()).unwrap();
    let _refresh = c.spawn_refresher(Duration::from_millis(20));
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.run_hz(20.0).unwrap();
    c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(5))
        .unwrap();
    // This process's command client is opened by its first use, not measured.
    bus.stop_drive(addr(2), StopCommand::Off1).unwrap();
    let asked = monotonic_ns();
    bus.stop_drive(addr(3), StopCommand::Off2).unwrap();
    let out = first_image(&bus, 3, Duration::from_secs(1), |i| i.sent_stw1 == OFF2);
    let latency = out.timestamp_ns.saturating_sub(asked) as f64 / 1e6;
    println!("failsafe: operator OFF2 on the wire, reply in, {latency:.1} ms after the API call");
    assert_eq!(out.latch_reason, LatchReason::Override.code());
    assert_eq!(out.latched_by_pid, std::process::id());
    assert!(matches!(
        c.set_setpoint(Setpoint::from_percent(10.0)),
        Err(ClientError::Tripped { .. })
    ));
}

/// STOP-ANYWHERE through the stop socket (issue 32): 64 connections that say nothing (8
/// processes of 8, each made again the moment ussd closes it) and a process that opens more than
/// its share hold nobody back: an operator's coast from another process is sent and confirmed
/// while they wait. (With the stop socket served one connection at a time, each waited for up to
/// 200 ms, `ussctl coast` failed after 2 s and the drive ran on.)
#[test]
fn idle_stop_connections_do_not_delay_an_operators_coast() {
    use std::io::Read as _;
    use std::os::unix::net::UnixStream;
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, ""), (2, ""), (3, "")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);
    let mut running = run(&ussd, 1, "20");
    let path = names::stop_socket(&BusName::new(&ussd.bus).unwrap());
    let holders = idle_connections(&path, 8);
    // This process takes its share of idle connections too.
    let mine: Vec<UnixStream> = (0..8)
        .map(|_| UnixStream::connect(&path).unwrap())
        .collect();

    let asked = Instant::now();
    let mut coast = ussd.ussctl(&["coast", "1"]);
    let (status, out, err) = coast.finish();
    let took = asked.elapsed();
    assert!(status.success(), "{out}{err}");
    assert!(out.contains("drive 1: OFF2 sent (STW1 0x047C)"), "{out}");
    let i = bus.watch(addr(1)).unwrap().latest();
    assert_eq!(
        (i.sent_stw1, i.latch_reason),
        (OFF2, LatchReason::Override.code())
    );
    println!(
        "failsafe: ussctl coast with 64 idle stop connections (and 8 of this process): sent and \
         confirmed in {:.1} ms",
        took.as_secs_f64() * 1e3
    );
    let (code, err) = ended(&mut running, Duration::from_secs(3));
    assert_eq!(code, Some(1), "{err}");
    // One more than its share: refused at once, named.
    let mut ninth = UnixStream::connect(&path).unwrap();
    let mut answer = [0u8; uss_shm_types::OPERATOR_RESPONSE_BYTES];
    ninth.read_exact(&mut answer).unwrap();
    let refused = uss_shm_types::OperatorResponse::from_bytes(&answer).unwrap();
    assert_eq!(
        refused.error(),
        Ok(uss_shm_types::CommandError::TooManyConnections)
    );
    drop((holders, mine));
}

/// The gate's re-arm rule with a real ussd and a foreign controller: after an operator's stop,
/// a controller that keeps jogging (JOG1/JOG2 have STW1 bit 0 clear, like a stop) re-arms
/// nothing and no jog word goes out; only its stop (OFF1) re-arms, and only its ON after that
/// runs the drive.
#[test]
fn a_jog_does_not_re_arm_an_operator_stop_only_a_stop_does() {
    const JOG1: u16 = OFF1 | 0x0100;
    const JOG2: u16 = OFF1 | 0x0200;
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut raw = RawController::open(&ussd.bus, 1);
    raw.until(&bus, 1, &[OFF1, 0], PzdInput::is_live);
    raw.until(&bus, 1, &[RUN, 0x1000], |i| {
        state_of(i) == DriveState::OperationEnabled
    });
    bus.stop_drive(addr(1), StopCommand::Off1).unwrap();
    first_image(&bus, 1, Duration::from_secs(1), |i| {
        i.latch_reason == LatchReason::Override.code()
    });
    let watch = bus.watch(addr(1)).unwrap();
    for n in 0..60 {
        let jog = if n % 2 == 0 { JOG1 } else { JOG2 };
        let seq = raw.words(&[jog, 0x1000]);
        let i = first_image(&bus, 1, Duration::from_secs(1), |i| i.taken_sequence >= seq);
        assert_eq!(
            (i.sent_stw1, i.latch_reason),
            (OFF1, LatchReason::Override.code()),
            "jog {jog:#06X} (sample {seq}) was taken as a re-arm: {i:?}"
        );
        assert!(!i.is_live(), "{i:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(watch.latest().latch_reason, LatchReason::Override.code());
    // The deliberate re-arm: a stop, then ON runs the drive again.
    raw.until(&bus, 1, &[OFF1, 0], PzdInput::is_live);
    raw.until(&bus, 1, &[RUN, 0x1000], |i| {
        state_of(i) == DriveState::OperationEnabled
    });
    raw.words(&[OFF1, 0]);
}

/// The other re-arm rule with a real ussd: a stop re-arms only when it names the latch, so a
/// controller that republishes its OFF1 all the time (every 0.2 ms, many samples per poll, as
/// a refresher would) never re-arms an operator's stop that comes in meanwhile, however its
/// samples and the stop cross: the drive stays latched poll after poll. Only a stop naming the
/// new latch, published after the image showed it, re-arms it.
#[test]
fn a_republished_stop_never_re_arms_an_operator_stop() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut raw = RawController::open(&ussd.bus, 1);
    let watch = bus.watch(addr(1)).unwrap();
    for round in 0..3 {
        raw.until(&bus, 1, &[OFF1, 0], PzdInput::is_live);
        // Live: the controller's OFF1 names no latch (there is none), and keeps coming.
        let mut stop = ussd.ussctl(&["stop", "1"]);
        let deadline = Instant::now() + Duration::from_secs(5);
        // Then twenty more polls of republished OFF1s: the drive stays latched by the operator.
        let mut latched: Option<PzdInput> = None;
        loop {
            assert!(
                Instant::now() < deadline,
                "round {round}: {:?}",
                watch.latest()
            );
            raw.words_naming(&[OFF1, 0], 0);
            let i = watch.latest();
            match latched {
                None if i.latch_reason == LatchReason::Override.code() => latched = Some(i),
                None => {}
                Some(l) if i.sequence >= l.sequence + 20 => break,
                Some(l) => assert_eq!(
                    (i.latch_reason, i.latch_id, i.sent_stw1),
                    (LatchReason::Override.code(), l.latch_id, OFF1),
                    "round {round}: a republished OFF1 re-armed the operator's stop: {i:?}"
                ),
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        let latched = latched.unwrap();
        let (status, _) = ended(&mut stop, Duration::from_secs(5));
        assert_eq!(
            status,
            Some(0),
            "round {round}: ussctl stop confirmed its stop"
        );
        // A stop naming the latch, made after the image showed it, re-arms.
        let seq = raw.words_naming(&[OFF1, 0], latched.latch_id);
        let i = first_image(&bus, 1, Duration::from_secs(1), |i| i.taken_sequence >= seq);
        assert!(i.is_live(), "round {round}: {i:?}");
    }
}

/// A stop's confirmation is of that stop, not of an older one (seen on CI: the guide's `ussctl
/// quick-stop --all`, then `ussctl ack 1`, refused "latched 0.06 s ago"): a drive already latched
/// by an operator's coast shows a stop as strong as a quick stop before ussd has taken the new
/// one, and ussd latches it anew at the drive's next poll. `wait_stopped` after this handle's
/// stop returns an image whose latch began when the stop was sent or later: the new stop's, so a
/// re-arm asked after it returned finds the latch older than itself.
#[test]
fn a_stops_confirmation_shows_that_stop_not_an_older_one() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let bus = ussd.bus();
    for round in 0..5 {
        bus.stop_drive(addr(1), StopCommand::Off2).unwrap();
        bus.wait_stopped(addr(1), StopCommand::Off2, None).unwrap();
        let asked = monotonic_ns();
        let weaker = if round % 2 == 0 {
            StopCommand::Off3
        } else {
            StopCommand::Off1
        };
        if round < 3 {
            bus.stop_drive(addr(1), weaker).unwrap();
        } else {
            bus.stop_all(weaker).unwrap();
        }
        let shown = bus.wait_stopped(addr(1), weaker, None).unwrap();
        assert!(
            shown.latch_id >= asked,
            "round {round}: {weaker} confirmed by the latch before it ({} ns earlier): {shown:?}",
            asked - shown.latch_id
        );
        assert_eq!(shown.sent_stw1, OFF2, "round {round}: the coast stays");
    }
    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    c.rearm_keeping_stop(monotonic_ns()).unwrap();
    assert_eq!(c.inputs().latest().sent_stw1, OFF2);
}

#[test]
fn parameter_writes_to_a_controlled_drive_need_force_or_the_controlling_process() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, ""), (2, ""), (3, "params_writable = false")]);
    let bus = ussd.bus();
    let controller = run(&ussd, 1, "5");
    let pid = controller.pid();

    // Another process (this one, and a ussctl) may read but not write.
    assert_eq!(bus.read_f32(addr(1), param(1082)), Ok(50.0));
    let stretch = Value::from_f32(650.0);
    assert_eq!(
        bus.write(addr(1), param(1121), stretch, false),
        Err(ParamError::Controlled { address: 1, pid })
    );
    let mut refused = ussd.ussctl(&["param", "write", "1", "P1121", "650.0"]);
    let (status, _, err) = refused.finish();
    assert_eq!(status.code(), Some(1));
    assert!(
        err.contains(&format!("drive 1 is controlled by process {pid}")),
        "{err}"
    );
    assert!(err.contains("--force"), "{err}");
    assert_ne!(
        bus.read_f32(addr(1), param(1121)),
        Ok(650.0),
        "nothing was written"
    );

    // Deliberately, with force.
    let mut forced = ussd.ussctl(&["param", "write", "1", "P1121", "2.5", "--force"]);
    let (status, out, err) = forced.finish();
    assert!(status.success(), "{out}{err}");
    assert_eq!(bus.read_f32(addr(1), param(1121)), Ok(2.5));
    let options = WriteOptions {
        force: true,
        ..WriteOptions::default()
    };
    assert_eq!(
        bus.write_with(addr(1), param(1120), Value::from_f32(1.5), options),
        Ok(Value::from_f32(1.5))
    );

    // The controlling process writes through its own handles.
    let own = bus.control(addr(2), ControlOptions::default()).unwrap();
    own.rearm(uss_client::monotonic_ns()).unwrap();
    assert_eq!(bus.write(addr(2), param(1121), stretch, false), Ok(stretch));
    drop(own);

    // params_writable = false refuses everything, forced or not.
    assert!(matches!(
        bus.write_with(addr(3), param(1121), stretch, options),
        Err(ParamError::Refused {
            error: uss_client::RequestError::WritesDisabled,
            ..
        })
    ));
}

/// A configuration whose `reference_hz` differs from the drive's P2000 would scale every Hz
/// wrong: with 60 configured and 50 in the drive, `run_hz(50)` would run the motor at 41.7 Hz
/// and a reading of 50 Hz would show 60. ussd reads P2000 when the drive comes online,
/// publishes the drive's value (so every client scales by what the drive scales by) and says
/// so in its log.
#[test]
fn hz_are_scaled_by_the_reference_frequency_the_drive_uses() {
    let _serial = serial();
    let ussd = Ussd::start(
        "",
        &[
            (1, "reference_hz = 60.0"),
            (2, "reference_hz = 60.0\nsim.p2000 = 60"),
            (3, "reference_hz = 60.0\nreference_param = \"\""),
        ],
    );
    let bus = ussd.bus();
    // A reference not read yet is no reference (0): wait for the drive's.
    let read = diag_when(&bus, 1, |d| d.info.reference().is_some_and(|r| r != 60.0));
    assert_eq!(read.info.reference_hz, 50.0, "the drive's P2000");
    assert!(
        logged(
            &ussd,
            "drive 1: reference frequency P2000 = 50 Hz, but reference_hz = 60 in the \
             configuration: Hz are scaled by the drive's 50 Hz"
        ),
        "{}",
        ussd.log()
    );
    // Drive 2 agrees with the configuration; drive 3's is not read.
    std::thread::sleep(Duration::from_millis(500));
    let two = diag_when(&bus, 2, |d| d.info.reference().is_some());
    assert_eq!(two.info.reference_hz, 60.0);
    assert_eq!(bus.diag(addr(3)).unwrap().info.reference_hz, 60.0);
    let log = ussd.log();
    assert!(!log.contains("drive 2: reference"), "{log}");
    assert!(!log.contains("drive 3: reference"), "{log}");

    // 25 Hz of the drive's 50 Hz is 50 %.
    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    assert_eq!(c.inputs().info().reference_hz, 50.0);
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(2))
        .unwrap();
    c.run_hz(25.0).unwrap();
    assert_eq!(c.words(), [0x047F, 0x2000]);
    c.stop().unwrap();
    let mut stats = ussd.ussctl(&["stats"]);
    let (_, out, _) = stats.finish();
    assert!(out.contains("reference 50 Hz,"), "{out}");
}

/// `ussctl run --percent` (issue 46, item 6: `run` took Hz only, which a drive whose reference
/// is a speed, a G120's p2000 in rpm, does not): the setpoint is the percentage of the drive's
/// own reference, sent as it is (20 % is 0x0CCC), with no reference frequency needed.
#[test]
fn ussctl_runs_a_drive_at_a_percentage_of_its_reference() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    quick_ramps(&ussd.bus(), 1);
    let (status, out, err) = ussd
        .ussctl(&["run", "1", "--percent", "20", "--for", "1.5"])
        .finish();
    let out = format!("{out}{err}");
    assert!(status.success(), "{out}");
    assert!(
        out.contains("drive 1: running towards 20 % of its reference (50 Hz)"),
        "{out}"
    );
    assert!(out.contains("drive 1: ran; OFF1 sent"), "{out}");
    let peak: f32 = out
        .split("peak ")
        .nth(1)
        .and_then(|p| p.split(" Hz").next())
        .and_then(|p| p.trim().parse().ok())
        .unwrap_or_else(|| panic!("{out}"));
    assert!((9.0..=10.5).contains(&peak), "20 % of 50 Hz: {out}");
    let (status, _, err) = ussd.ussctl(&["run", "1"]).finish();
    assert!(!status.success() && err.contains("--hz"), "{err}");
}

#[test]
fn a_drive_without_telegram_monitoring_is_reported_and_refused_on_when_required() {
    let _serial = serial();
    let ussd = Ussd::start(
        "",
        &[
            (1, ""),
            (2, "require_monitoring = true"),
            (3, "require_monitoring = true\nsim.p2014 = 100"),
        ],
    );
    let bus = ussd.bus();
    let off = diag_when(&bus, 1, |d| d.monitoring != Monitoring::Unknown.code());
    assert_eq!(
        (off.monitoring, off.monitoring_ms),
        (Monitoring::Off.code(), 0)
    );
    let on = diag_when(&bus, 3, |d| d.monitoring != Monitoring::Unknown.code());
    assert_eq!(
        (on.monitoring, on.monitoring_ms),
        (Monitoring::On.code(), 100)
    );
    assert!(
        logged(&ussd, "drive 1: telegram monitoring is OFF (P2014[0] = 0)"),
        "{}",
        ussd.log()
    );

    let mut status = ussd.ussctl(&["status"]);
    let (_, out, _) = status.finish();
    assert!(
        out.contains("warning: drive 1: telegram monitoring is OFF"),
        "{out}"
    );
    assert!(
        out.contains("warning: drive 2: telegram monitoring is OFF"),
        "{out}"
    );
    assert!(!out.contains("warning: drive 3"), "{out}");

    // Required and off: OFF1 arms, ON is refused and latches.
    let mut refused = ussd.ussctl(&["run", "2", "--hz", "10"]);
    let (status, _, err) = refused.finish();
    assert_eq!(status.code(), Some(1));
    assert!(
        err.contains("telegram monitoring is required but off"),
        "{err}"
    );
    let i = bus.watch(addr(2)).unwrap().latest();
    assert_eq!(
        (i.latch_reason, i.sent_stw1),
        (LatchReason::MonitoringOff.code(), OFF1)
    );
    assert_ne!(state_of(&i), DriveState::OperationEnabled);
    // Required and on: it runs.
    let mut ok = ussd.ussctl(&["run", "3", "--hz", "10", "--for", "0.3"]);
    let (status, out, err) = ok.finish();
    assert!(status.success(), "{out}{err}");
}

#[test]
fn a_frozen_controller_over_a_pty_to_uss_sim_does_not_restart_the_drive() {
    let _serial = serial();
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1"]);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);
    let mut controller = run(&ussd, 1, "20");
    first_image(&bus, 1, Duration::from_secs(5), |i| hz(i) >= 19.9);
    let frozen_at = signal(&controller, Signal::SIGSTOP);
    let trip = first_image(&bus, 1, Duration::from_secs(2), |i| !i.is_live());
    println!(
        "failsafe (pty): latched {:.1} ms after SIGSTOP",
        trip.timestamp_ns.saturating_sub(frozen_at) as f64 / 1e6
    );
    first_image(&bus, 1, Duration::from_secs(3), |i| i.hiw == 0);
    signal(&controller, Signal::SIGCONT);
    stays_stopped(&bus, 1, LatchReason::Stale, Duration::from_millis(500));
    let (code, _) = ended(&mut controller, Duration::from_secs(3));
    assert_eq!(code, Some(1));
    drop(ussd);
    let summary = sim.stop();
    // uss-sim's own view of its drive, over the pty: S2 at 0 Hz.
    assert!(
        summary.contains("drive  1:")
            && summary.contains("S2 ready to switch on")
            && summary.contains("0.00 Hz"),
        "{summary}"
    );
}

/// A ussd paused past the watchdog time (SIGSTOP, as a suspended machine or a starved CPU
/// would) latches its running drive on resuming, although its controller went on publishing
/// fresh samples meanwhile: the gap is ussd's own, and whatever waits was not seen in time. On
/// main before issue 21 it took the newest sample as fresh and kept the pre-pause ON.
#[test]
fn a_paused_ussd_latches_its_running_drive_on_resuming_over_a_pty() {
    let _serial = serial();
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1"]);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "")]);
    let bus = ussd.bus();
    quick_ramps(&bus, 1);
    let mut raw = RawController::open(&ussd.bus, 1);
    raw.words(&[OFF1, 0]);
    first_image(&bus, 1, Duration::from_secs(2), PzdInput::is_live);
    let run = Setpoint::from_hz(20.0, 50.0).word();
    let until = |raw: &mut RawController, done: &dyn Fn(&PzdInput) -> bool| {
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            raw.words(&[RUN, run]);
            let i = raw.watch.latest();
            if done(&i) {
                return i;
            }
            assert!(Instant::now() < deadline, "still {i:?}");
            std::thread::sleep(Duration::from_millis(10));
        }
    };
    until(&mut raw, &|i| hz(i) >= 19.9);
    let ussd_pid = Pid::from_raw(i32::try_from(ussd.child.id()).unwrap());
    kill(ussd_pid, Signal::SIGSTOP).unwrap();
    // The last image before the pause (read once ussd has surely stopped).
    std::thread::sleep(Duration::from_millis(20));
    let before_pause = raw.watch.latest().sequence;
    // The controller goes on publishing "run" for the whole pause, straight to the service.
    let paused = Instant::now();
    while paused.elapsed() < Duration::from_millis(800) {
        raw.words_naming(&[RUN, run], 0);
        std::thread::sleep(Duration::from_millis(10));
    }
    kill(ussd_pid, Signal::SIGCONT).unwrap();
    // Rule 3: no image made after the pause shows the drive live, not even the one of the
    // exchange that straddled it (the third adversarial run saw it live for 20-50 ms).
    let resumed = Instant::now();
    let i = loop {
        let i = raw.watch.latest();
        if i.sequence > before_pause && !i.is_live() {
            break i;
        }
        assert!(
            i.sequence <= before_pause,
            "an image after the pause shows the drive live: {i:?}"
        );
        assert!(resumed.elapsed() < Duration::from_secs(5), "still {i:?}");
        std::thread::sleep(Duration::from_micros(200));
    };
    assert_eq!(i.latch_reason, LatchReason::Paused.code(), "{i:?}");
    // The exchange that straddled the pause shows the word its telegram carried before it (its
    // image latched already); every telegram after the pause carries OFF1.
    if i.sent_stw1 != OFF1 {
        assert_eq!(
            i.sequence,
            before_pause + 1,
            "an ON went out after the pause: {i:?}"
        );
        let next = loop {
            let n = raw.watch.latest();
            if n.sequence > i.sequence {
                break n;
            }
            assert!(resumed.elapsed() < Duration::from_secs(5), "still {n:?}");
            std::thread::sleep(Duration::from_micros(200));
        };
        assert_eq!(next.sent_stw1, OFF1, "{next:?}");
    }
    // The drive stays stopped while the controller goes on sending "run".
    let deadline = Instant::now() + Duration::from_millis(500);
    while Instant::now() < deadline {
        raw.words_naming(&[RUN, run], 0);
        let i = raw.watch.latest();
        assert_eq!(
            (i.latch_reason, i.sent_stw1),
            (LatchReason::Paused.code(), OFF1)
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(logged(&ussd, "ussd paused"), "{}", ussd.log());
}

/// An operator's stop that comes while `ussctl run` starts (after the run was asked for, before
/// it re-armed the drive) is not undone by that run: a run re-arms only latches older than
/// itself, and its process's start is when it was asked (not `main()`'s, which comes
/// milliseconds later, tens of them under load). Found by the adversarial run of issue 35: a
/// coast 30 to 80 ms after `ussctl run` was started was re-armed over by it; and by issue 45's:
/// a coast 5 to 25 ms after the start, before `main()` ran, was still re-armed in 5 of 12 runs.
#[test]
fn a_stop_while_a_run_starts_is_not_undone_by_it() {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let watch = bus.watch(addr(1)).unwrap();
    for after_ms in [0, 0, 0, 1, 2, 2, 5, 10, 25, 40, 70] {
        let before = watch.latest().latch_id;
        let mut run = ussd.ussctl(&["run", "1", "--hz", "8", "--for", "2"]);
        std::thread::sleep(Duration::from_millis(after_ms));
        bus.stop_drive(addr(1), StopCommand::Off2).unwrap();
        let coasted = watch
            .wait_for(Duration::from_secs(2), "the coast", |i| i.latch_id > before)
            .unwrap();
        assert_eq!(
            coasted.latch_reason,
            LatchReason::Override.code(),
            "{coasted:?}"
        );
        // From the coast on, nothing but stops reaches the drive: either the run saw the
        // coast before its re-arm and refused, or it was running and the coast tripped it.
        let deadline = Instant::now() + Duration::from_millis(1500);
        while Instant::now() < deadline {
            let i = watch.latest();
            assert_eq!(
                i.sent_stw1 & 0x0001,
                0,
                "{after_ms} ms: an ON went out after the operator's coast: {i:?}"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
        let (status, out, err) = run.finish();
        println!("failsafe: a coast {after_ms} ms into a run: {status}\n{out}{err}");
        assert!(
            !status.success(),
            "the run ended as if nothing stopped it: {out}{err}"
        );
        assert!(err.contains("an operator sent OFF2 from process"), "{err}");
    }
}

/// 20 stops of drive 1 of `ussd` (OFF2 and OFF3 in turn, a few ms apart), each from the call
/// to the moment the bus thread latched the drive (the latch's id is that moment, taken by
/// ussd), in exchanges of the bus (one drive: its poll period): the median and the worst.
fn stop_delays(ussd: &Ussd) -> (f64, f64, Vec<f64>) {
    let bus = ussd.bus();
    let watch = bus.watch(addr(1)).unwrap();
    let mut delays = Vec::new();
    for i in 0..20u64 {
        let before = watch.latest();
        let command = if i % 2 == 0 {
            StopCommand::Off2
        } else {
            StopCommand::Off3
        };
        let asked = monotonic_ns();
        bus.stop_drive(addr(1), command)
            .unwrap_or_else(|e| panic!("stop {i}: {e}"));
        let latched = watch
            .wait_for(Duration::from_secs(5), "the stop's latch", |l| {
                l.latch_id > before.latch_id
            })
            .unwrap();
        let exchange = before.period_ns.max(1);
        delays.push(latched.latch_id.saturating_sub(asked) as f64 / exchange as f64);
        std::thread::sleep(Duration::from_millis(7 + i % 5));
    }
    delays.sort_by(f64::total_cmp);
    (delays[delays.len() / 2], delays[delays.len() - 1], delays)
}

/// STOP-NOWAIT (issue 45, item 3): a storm of connections to the stop socket from 40 other
/// processes of the access group (each connecting and closing in a tight loop) does not delay
/// another process's stop beyond the exchange in progress. Measured from the stop call to the
/// moment the bus thread latched the drive (the latch's id is that moment, taken by ussd), in
/// exchanges of the bus (one drive: its poll period). Before the fix forty flooding processes
/// delayed a stop by 13 exchanges at the median and 15 at worst (four: 9 and 15), one of the
/// adversarial run by 98 to 333 ms.
#[test]
fn a_storm_of_connections_to_the_stop_socket_does_not_delay_another_processs_stop() {
    stops_beside(
        "40 processes flooding the stop socket",
        |path| flooders(path, 40),
        (1.5, 4.0),
    );
}

/// STOP-NOWAIT (issue 45's adversarial run): 400 processes that each hold one connection to
/// the stop socket that says nothing (made again as soon as ussd closes it: no per-process
/// bound is reached, ussd's 256 are, and its queue stays full) do not delay a stop either: the
/// stop goes onto the bus's stop board, which no queue holds back, while its connection waits.
/// Before the board the run measured a median of 34 ms (some 13 exchanges) and up to 95 ms;
/// here, without it, median 1.72 and worst 20.99 exchanges; with it median 1.2-1.5, worst 2.1-2.6
/// (the stop thread, busy with the storm, reads the board between its turns).
#[test]
fn a_storm_of_idle_connections_from_many_processes_does_not_delay_a_stop() {
    stops_beside(
        "400 processes holding an idle stop connection each",
        |path| {
            stop_socket_users(
                "uss-idle-connections",
                &[path.as_os_str(), "400".as_ref(), "--processes".as_ref()],
                "holding 400",
                1,
            )
        },
        (2.5, 5.0),
    );
}

/// [`stop_delays`] of a ussd of one drive beside `storm` (the processes it starts on the stop
/// socket's path, ended after): the median and the worst at most `bounds`. The delay is timed
/// from this process's call, so it holds this process's own wait for a core among hundreds of
/// runnable ones too (once, on a loaded CI run: one stop of 20 at 12 exchanges, the median 1.6):
/// a worst beyond the bound with the median within it is measured once more, and the bound
/// must hold in one of the two. A delay of ussd's own (a stop waiting behind the connections)
/// is in every stop and both runs.
fn stops_beside(
    what: &str,
    storm: impl FnOnce(&std::path::Path) -> Vec<ChildProc>,
    (median_at_most, worst_at_most): (f64, f64),
) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let path = names::stop_socket(&BusName::new(&ussd.bus).unwrap());
    let storm = storm(&path);
    let mut runs = Vec::new();
    for _ in 0..2 {
        let (median, worst, delays) = stop_delays(&ussd);
        println!(
            "failsafe: 20 stops beside {what}: from the call to the latch median {median:.2}, \
             worst {worst:.2} exchanges"
        );
        assert!(
            median <= median_at_most,
            "{what} delayed a stop: median {median:.2}, worst {worst:.2} exchanges ({delays:?})"
        );
        if worst <= worst_at_most {
            drop(storm);
            return;
        }
        runs.push(delays);
    }
    drop(storm);
    panic!("{what} delayed a stop beyond {worst_at_most} exchanges in both runs: {runs:?}");
}

/// STOP-ANYWHERE across versions (issue 45): a stop request of an older layout version (an
/// older `ussctl` or libussrt still installed beside a newer ussd) stops the drive, and its
/// answer speaks the request's version; one from before the stop socket existed is refused.
#[test]
fn a_stop_of_an_older_clients_version_still_stops_the_drive() {
    use std::io::{Read as _, Write as _};
    use std::os::unix::net::UnixStream;
    use uss_shm_types::{OperatorRequest, OperatorResponse, STOP_BYTES_SINCE};
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let watch = ussd.bus().watch(addr(1)).unwrap();
    let path = names::stop_socket(&BusName::new(&ussd.bus).unwrap());
    let ask = |version: u32| {
        let request = OperatorRequest {
            version,
            ..OperatorRequest::new(1, StopCommand::Off2)
        };
        let mut stream = UnixStream::connect(&path).unwrap();
        stream.write_all(&request.to_bytes()).unwrap();
        let mut answer = [0u8; uss_shm_types::OPERATOR_RESPONSE_BYTES];
        stream.read_exact(&mut answer).unwrap();
        OperatorResponse::from_bytes(&answer).unwrap()
    };
    let before = watch.latest().latch_id;
    let answer = ask(LAYOUT_VERSION - 1);
    assert_eq!(
        (answer.error(), answer.version, answer.drives),
        (
            Ok(uss_shm_types::CommandError::Ok),
            LAYOUT_VERSION - 1,
            1 << 1
        )
    );
    let coasted = watch
        .wait_for(Duration::from_secs(2), "the older client's coast", |i| {
            i.latch_id > before
        })
        .unwrap();
    assert_eq!(
        (coasted.sent_stw1, coasted.latch_reason),
        (OFF2, LatchReason::Override.code())
    );
    let refused = ask(STOP_BYTES_SINCE - 1);
    assert_eq!(refused.error(), Ok(uss_shm_types::CommandError::Version));
}
