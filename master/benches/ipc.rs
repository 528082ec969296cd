//! Shared-memory benchmarks (issue "Process images and parameter requests over iceoryx2"),
//! printed as ratios measured in one run on this machine. The bus runs as in ussd (engine with
//! `RtBridge` in a `SCHED_FIFO` thread on CPU 1, simulated drives on the real-time-paced virtual
//! wire, `MonotonicClock`); every client is another process: this binary again, with
//! `USS_BENCH_IPC_ROLE` naming what it does ([`client`]). Clients run on CPU 0.
//!
//! 1. Input path: a validated reply -> its input image seen by a client through `uss-client`
//!    (`DriveWatch::latest`), busy-polling and woken by the exchange event
//!    (`CycleListener::wait`), next to raw iceoryx2 measured the same way in the same run (a
//!    blackboard of the same `PzdInput`, an event), and the ratio ours / raw. See
//!    [`input_path`] for what each interval covers.
//! 2. Output path: `Controller::set_setpoint` in a client -> the first telegram to that drive
//!    carrying the setpoint, relative to the drive's poll period. See [`output_path`].
//! 3. Parameter read round trip through `Bus::send_request` (what `ussctl param read` does, in a
//!    long-lived client) -> ussd's `ParamServer` -> the drive's mailbox -> PKW exchange -> back,
//!    against the bare exchange on the wire. See [`parameter_round_trip`].
//!
//! `cargo bench -p uss-master --bench ipc -- input` runs only part 1 (`output`, `params`: the
//! others).

use hdrhistogram::Histogram;
use iceoryx2::prelude::*;
use nix::sched::{CpuSet, sched_setaffinity};
use nix::unistd::Pid;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use std::fmt::Write as _;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use uss_benches::{Parts, addr, percentiles_us};
use uss_client::{
    Bus, ControlOptions, CycleEvent, ParamItem, ParamRequest, ParamTask, Pnu, PzdInput, Setpoint,
    Value,
};
use uss_drive_sim::SimTransport;
use uss_engine::control::ControllerId;
use uss_engine::image::DriveImages;
use uss_engine::{
    Bridge, Clock, DriveStatus, Engine, EngineHandle, MonotonicClock, Rx, Stats, Transport,
    TransportError,
};
use uss_master::config::Config;
use uss_master::daemon::ipc::{IpcNode, RtBridge};
use uss_master::daemon::runtime;
use uss_protocol::{Layout, Telegram};
use uss_realtime::{RtRequest, apply_to_current_thread};
use uss_shm_types::names::EVENT_ID_MAX;
use uss_shm_types::service::Ipc;
use uss_shm_types::{Address, BlackboardKey, PzdOutput};

/// What a client process does; unset in the benchmark itself.
const ROLE_ENV: &str = "USS_BENCH_IPC_ROLE";
/// The bus (or raw service prefix) the client opens.
const NAME_ENV: &str = "USS_BENCH_IPC_NAME";
/// How long the client measures, in seconds.
const SECS_ENV: &str = "USS_BENCH_IPC_SECS";
/// The drive's poll period in ns, for clients that act at random phases of it.
const PERIOD_ENV: &str = "USS_BENCH_IPC_PERIOD_NS";

/// The bus thread's CPU and `SCHED_FIFO` priority (`cpu` and `priority` in ussd's
/// configuration); the raw writer of part 1 gets the same.
const BUS_CPU: usize = 1;
const BUS_PRIORITY: u8 = 80;
/// Clients run on the other core; an event-woken client as a control loop would, `SCHED_FIFO`
/// below the bus.
const CLIENT_CPU: usize = 0;
const CLIENT_PRIORITY: u8 = 70;

/// Part 1 measures its four variants in rounds, each variant for a second per round in turn,
/// so a change in the machine's background load affects ours and raw alike.
/// A short run (`USS_BENCH_SHORT=1`, CI: it still runs from a fresh clone) takes 2 rounds of
/// 0.2 s and 1 s of the other parts; its figures mean nothing.
fn short() -> bool {
    std::env::var_os("USS_BENCH_SHORT").is_some_and(|v| v == "1")
}
fn rounds() -> usize {
    if short() { 2 } else { 8 }
}
fn round_secs() -> f64 {
    if short() { 0.2 } else { 1.0 }
}
/// How long a paused writer sleeps before it looks at its flag again.
const NAP: Duration = Duration::from_millis(1);
/// Seconds the other parts measure.
fn output_secs() -> f64 {
    if short() { 1.0 } else { 6.0 }
}
fn param_secs() -> f64 {
    if short() { 1.0 } else { 6.0 }
}

/// The drive whose images part 1 watches (the only one on its bus) and whose parameters part 3
/// reads.
const WATCHED: u8 = 1;
/// Event id of the raw writer's notifications (ussd's exchange event id is the address).
const RAW_EVENT_ID: usize = WATCHED as usize;
/// How long an event-woken client waits before it looks at the clock.
const WAKE_TIMEOUT: Duration = Duration::from_millis(50);
/// Stamps, telegrams and samples kept, allocated before measuring.
const CAPACITY: usize = 1 << 16;
/// P1082 (maximum frequency, a float): 50.0 Hz on the simulated drives.
const P1082: u16 = 1082;
const P1082_VALUE: u32 = 0x4248_0000;

fn monotonic_ns() -> u64 {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC)
        .expect("CLOCK_MONOTONIC is always readable");
    as_ns(Duration::from(t))
}

fn as_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 60_000_000_000, 3).expect("valid histogram bounds")
}

fn record(h: &mut Histogram<u64>, ns: u64) {
    h.saturating_record(ns.max(1));
}

// ---------------------------------------------------------------------------------------------
// The bus under test: ussd's bus thread and parameter bridge, with two probes.

/// A telegram as it went on the wire: the drive, its PZD2 (the setpoint HSW) and when its
/// first character started, `CLOCK_MONOTONIC` ns.
#[derive(Debug, Clone, Copy)]
struct Sent {
    address: u8,
    setpoint: u16,
    at_ns: u64,
}

/// The simulated line, recording every request. `send` is where the engine starts a telegram
/// (after the start pause), so a setpoint found in these bytes is exactly "contained in the
/// telegram", at the moment it leaves.
struct Recording {
    inner: SimTransport,
    layout: Layout,
    origin_ns: u64,
    sent: Vec<Sent>,
}

impl Transport for Recording {
    fn flush_input(&mut self, now: Duration) -> Result<(), TransportError> {
        self.inner.flush_input(now)
    }

    fn send(&mut self, bytes: &[u8], now: Duration) -> Result<Duration, TransportError> {
        // Within the capacity reserved at start-up: the bus thread does not allocate.
        if self.sent.len() < self.sent.capacity()
            && let Ok(telegram) = Telegram::parse(bytes)
            && let Ok(words) = telegram.words(self.layout)
        {
            self.sent.push(Sent {
                address: telegram.adr().address.get(),
                setpoint: words.pzd().get(1).copied().unwrap_or(0),
                at_ns: self.origin_ns + as_ns(now),
            });
        }
        self.inner.send(bytes, now)
    }

    fn recv(
        &mut self,
        deadline: Duration,
        clock: &mut impl Clock,
    ) -> Result<Option<Rx>, TransportError> {
        self.inner.recv(deadline, clock)
    }
}

/// ussd's `RtBridge`, stamped: when the bus thread hands a validated reply of the watched drive
/// (slot 0) to the bridge, `after_poll` right after the engine checked the reply and wrote its
/// image, before `RtBridge` copies it into the blackboard. Indexed by the image's sequence
/// number (good replies so far), which the client reports with what it saw.
struct Stamping {
    inner: RtBridge,
    handed_over: Arc<[AtomicU64]>,
}

impl Bridge for Stamping {
    fn take_sample(
        &mut self,
        slot: usize,
        images: &DriveImages,
    ) -> Option<(PzdOutput, ControllerId)> {
        self.inner.take_sample(slot, images)
    }

    fn after_poll(&mut self, slot: usize, images: &DriveImages, status: &DriveStatus) {
        let at = monotonic_ns();
        self.inner.after_poll(slot, images, status);
        if slot == 0
            && let Some(words) = images.input.read()
            && let Some(stamp) = usize::try_from(words.number)
                .ok()
                .and_then(|n| self.handed_over.get(n))
        {
            // A failed poll republishes the last reply: its first publication counts.
            let _ = stamp.compare_exchange(0, at, Ordering::Relaxed, Ordering::Relaxed);
        }
    }

    fn cycle_completed(&mut self) {
        self.inner.cycle_completed();
    }

    fn job_done(&mut self) {
        self.inner.job_done();
    }

    fn requester_ended(&self, requester: uss_engine::jobs::Requester) -> bool {
        self.inner.requester_ended(requester)
    }
}

/// What the bus thread leaves when it stops.
struct Finished {
    stats: Stats,
    sent: Vec<Sent>,
    mode: String,
    handed_over: Arc<[AtomicU64]>,
}

/// One bus run as ussd runs it (see `runtime::start`), from a configuration in ussd's format.
struct BusUnderTest {
    name: String,
    handle: EngineHandle,
    /// While set, the bus thread sleeps between exchanges (in steps of [`NAP`]).
    paused: Arc<AtomicBool>,
    handed_over: Arc<[AtomicU64]>,
    engine: JoinHandle<(Stats, Vec<Sent>, String)>,
    params: Option<JoinHandle<()>>,
    // Held until the threads above have ended: they use ports of this node.
    /// Publishes status, diagnostics and the heartbeat every 50 ms, as ussd's housekeeping
    /// thread does (clients open a bus only while its heartbeat says it is served).
    status: std::thread::JoinHandle<()>,
    _node: IpcNode,
}

/// A simulated bus at 187500 baud, in ussd's configuration format.
fn bus_toml(name: &str, drives: &str) -> String {
    format!("[[bus]]\nname = \"{name}\"\ndevice = \"sim\"\nbaud = 187500\n\n{drives}")
}

/// Sets the calling thread up as ussd sets up a bus thread (without locking memory, like the
/// bus benchmarks); returns the mode obtained.
fn become_bus_thread() -> String {
    let report = apply_to_current_thread(&RtRequest {
        cpu: Some(BUS_CPU),
        priority: BUS_PRIORITY,
        lock_memory: false,
        prefault_stack_bytes: 128 * 1024,
    });
    // Wake-ups as precise as the kernel allows (the default slack is 50 us).
    let _ = nix::sys::prctl::set_timerslack(1);
    mode(&report)
}

impl BusUnderTest {
    /// Starts the bus of `toml`; with `serve_params`, ussd's parameter bridge thread too.
    fn start(toml: &str, serve_params: bool) -> Self {
        let config = Config::parse(toml, "ipc benchmark").expect("benchmark configuration");
        let bus = &config.buses[0];
        let clock = MonotonicClock::new();
        let engine_config = runtime::engine_config(bus);
        let ipc = uss_master::daemon::ipc::create(&bus.name, &engine_config.drives, clock.origin())
            .expect("the bus's services");
        let transport = Recording {
            inner: runtime::sim_transport(bus).expect("simulated drives"),
            layout: bus.drives[0].layout(),
            origin_ns: as_ns(clock.origin()),
            sent: Vec::with_capacity(CAPACITY),
        };
        let handed_over: Arc<[AtomicU64]> = (0..CAPACITY).map(|_| AtomicU64::new(0)).collect();
        let bridge = Stamping {
            inner: ipc.rt,
            handed_over: Arc::clone(&handed_over),
        };
        let (mut engine, handle, _events) =
            Engine::with_bridge(engine_config, transport, clock, bridge);
        let params = serve_params.then(|| {
            let handle = handle.clone();
            let server = ipc.params;
            std::thread::spawn(move || server.run(&handle))
        });
        let paused = Arc::new(AtomicBool::new(false));
        let (pause, running) = (Arc::clone(&paused), handle.clone());
        let engine = std::thread::spawn(move || {
            let mode = become_bus_thread();
            // `Engine::run` with a pause.
            while !running.is_stopped() {
                if pause.load(Ordering::Relaxed) {
                    let clock = engine.clock_mut();
                    let wake = clock.now() + NAP;
                    clock.sleep_until(wake);
                } else {
                    engine.poll_next().expect("the virtual wire never fails");
                }
            }
            engine.shutdown().expect("the virtual wire never fails");
            let sent = std::mem::take(&mut engine.transport_mut().sent);
            (engine.stats().clone(), sent, mode)
        });
        let status = {
            let handle = handle.clone();
            let mut publisher = ipc.status;
            std::thread::spawn(move || {
                while !handle.is_stopped() {
                    publisher.publish(&handle.stats(), true, 0);
                    std::thread::sleep(Duration::from_millis(50));
                }
                publisher.publish(&handle.stats(), false, 0);
            })
        };
        Self {
            name: bus.name.clone(),
            handle,
            paused,
            handed_over,
            engine,
            params,
            status,
            _node: ipc.node,
        }
    }

    /// Waits until every drive has answered and the engine has published statistics.
    fn wait_until_answering(&self) {
        let deadline = Instant::now() + Duration::from_secs(10);
        for drive in self.handle.drives() {
            while self
                .handle
                .input(drive.address)
                .expect("a configured drive")
                .0
                .is_none_or(|w| w.number == 0)
            {
                assert!(
                    Instant::now() < deadline,
                    "drive {} is silent",
                    drive.address
                );
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        while self.handle.stats().histograms.cycle.len() < 10 {
            assert!(Instant::now() < deadline, "no statistics published");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The median time between two telegrams to one drive, from the engine's statistics.
    fn poll_period(&self) -> Duration {
        Duration::from_nanos(self.handle.stats().histograms.cycle.value_at_quantile(0.5))
    }

    fn pause(&self, paused: bool) {
        self.paused.store(paused, Ordering::Relaxed);
    }

    fn stop(self) -> Finished {
        self.handle.stop();
        let (stats, sent, mode) = self.engine.join().expect("bus thread");
        if let Some(params) = self.params {
            params.join().expect("parameter bridge thread");
        }
        self.status.join().expect("status thread");
        Finished {
            stats,
            sent,
            mode,
            handed_over: self.handed_over,
        }
    }
}

/// Exchanges that needed another attempt or failed: a stalled bus thread shows up here, or, when
/// these are 0, only as long exchanges.
fn failures(stats: &Stats) -> String {
    let sum = |f: fn(&DriveStatus) -> u64| stats.drives.iter().map(f).sum::<u64>();
    format!(
        "{} exchanges, {} retries, {} failed polls",
        stats.bus.exchanges,
        sum(|d| d.counters.retries),
        sum(|d| d.counters.failed_polls)
    )
}

fn mode(report: &uss_realtime::RtReport) -> String {
    match (report.priority, report.cpu) {
        (Some(p), Some(cpu)) => format!("SCHED_FIFO {p} on CPU {cpu}"),
        _ => format!("best-effort: {}", report.summary()),
    }
}

/// Runs this binary again as client `role` on `name` for `secs` and returns its output lines.
fn run_client(role: &str, name: &str, secs: f64, period: Duration) -> Vec<String> {
    let out = Command::new(std::env::current_exe().expect("own executable"))
        .env(ROLE_ENV, role)
        .env(NAME_ENV, name)
        .env(SECS_ENV, secs.to_string())
        .env(PERIOD_ENV, period.as_nanos().to_string())
        .stderr(Stdio::inherit())
        .output()
        .expect("start a client process");
    assert!(out.status.success(), "client {role}: {}", out.status);
    String::from_utf8(out.stdout)
        .expect("clients print ASCII")
        .lines()
        .map(str::to_owned)
        .collect()
}

/// The numbers after `tag` on each of `lines` that starts with it.
fn rows<const N: usize>(lines: &[String], tag: &str) -> Vec<[u64; N]> {
    lines
        .iter()
        .filter_map(|l| l.strip_prefix(tag))
        .map(|rest| {
            let mut row = [0; N];
            for (v, field) in row.iter_mut().zip(rest.split_whitespace()) {
                *v = field.parse().expect("a number");
            }
            row
        })
        .collect()
}

fn client_mode(lines: &[String]) -> &str {
    lines
        .iter()
        .find_map(|l| l.strip_prefix("MODE "))
        .unwrap_or("?")
}

// ---------------------------------------------------------------------------------------------
// 1. Input path.

/// The raw iceoryx2 counterpart of `RtBridge`'s input path: a thread like the bus thread (same
/// CPU, priority and timer slack) that, once per `period`, stamps the time, builds a `PzdInput`
/// and writes it into a blackboard, then notifies an event: what `RtBridge::after_poll` does.
/// It starts paused.
struct RawWriter {
    mode: String,
    stop: Arc<AtomicBool>,
    paused: Arc<AtomicBool>,
    thread: JoinHandle<()>,
}

fn raw_service(prefix: &str, what: &str) -> ServiceName {
    ServiceName::new(&format!("{prefix}/raw/{what}")).expect("a valid service name")
}

fn raw_node() -> Node<Ipc> {
    NodeBuilder::new()
        .config(&uss_shm_types::service::config().expect("the shared-memory root"))
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .expect("an iceoryx2 node")
}

impl RawWriter {
    fn start(prefix: &str, period: Duration) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let paused = Arc::new(AtomicBool::new(true));
        let (ready_tx, ready) = std::sync::mpsc::channel();
        let thread = {
            let (stop, pause) = (Arc::clone(&stop), Arc::clone(&paused));
            let prefix = prefix.to_owned();
            std::thread::spawn(move || {
                let node = raw_node();
                let board = node
                    .service_builder(&raw_service(&prefix, "in"))
                    .blackboard_creator::<BlackboardKey>()
                    .add::<PzdInput>(BlackboardKey::IMAGE, PzdInput::EMPTY)
                    .create()
                    .expect("raw blackboard");
                let writer = board.writer_builder().create().expect("raw writer");
                let entry = writer
                    .entry::<PzdInput>(&BlackboardKey::IMAGE)
                    .expect("raw entry");
                let notifier = node
                    .service_builder(&raw_service(&prefix, "event"))
                    .event()
                    .event_id_max_value(EVENT_ID_MAX)
                    .create()
                    .expect("raw event service")
                    .notifier_builder()
                    .create()
                    .expect("raw notifier");
                let _ = ready_tx.send(become_bus_thread());
                let mut clock = MonotonicClock::new();
                let (mut next, mut sequence) = (clock.now(), 0u64);
                while !stop.load(Ordering::Relaxed) {
                    if pause.load(Ordering::Relaxed) {
                        next = clock.now() + NAP;
                        clock.sleep_until(next);
                        continue;
                    }
                    next += period;
                    clock.sleep_until(next);
                    sequence += 1;
                    let at = monotonic_ns();
                    let image = PzdInput::from_words(&[0xFB31, sequence as u16], sequence, at, 0)
                        .expect("two words fit");
                    entry.update_with_copy(image);
                    let _ = notifier.notify_with_custom_event_id(EventId::new(RAW_EVENT_ID));
                }
            })
        };
        let mode = ready.recv().expect("raw writer ready");
        Self {
            mode,
            stop,
            paused,
            thread,
        }
    }

    fn pause(&self, paused: bool) {
        self.paused.store(paused, Ordering::Relaxed);
    }

    /// Stops the writer; returns the real-time mode it had.
    fn stop(self) -> String {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().expect("raw writer");
        self.mode
    }
}

/// An input image a client saw: its sequence number, its `timestamp_ns` (ours: the reply's
/// completion on the wire; raw: the writer's stamp) and when the client saw it.
#[derive(Debug, Clone, Copy)]
struct Seen {
    sequence: u64,
    stamp_ns: u64,
    at_ns: u64,
}

/// What one client saw over all its runs.
struct Observed {
    mode: String,
    seen: Vec<Seen>,
    /// Images published but never seen (a later one was seen first).
    missed: u64,
}

/// The `S` lines of `runs`, each run one client process.
fn observed(runs: &[Vec<String>]) -> Observed {
    let mut all = Observed {
        mode: runs.first().map_or("?", |r| client_mode(r)).to_owned(),
        seen: Vec::new(),
        missed: 0,
    };
    for run in runs {
        let seen: Vec<Seen> = rows::<3>(run, "S ")
            .into_iter()
            .map(|[sequence, stamp_ns, at_ns]| Seen {
                sequence,
                stamp_ns,
                at_ns,
            })
            .collect();
        all.missed += seen
            .windows(2)
            .map(|w| w[1].sequence.saturating_sub(w[0].sequence + 1))
            .sum::<u64>();
        all.seen.extend(seen);
    }
    all
}

/// The client roles of part 1 and whether each watches ours (else the raw writer).
const VARIANTS: [(&str, bool); 4] = [
    ("ours-poll", true),
    ("raw-poll", false),
    ("ours-event", true),
    ("raw-event", false),
];

/// Part 1. Three points in time per good reply of the watched drive:
///
/// - A, the reply complete on the wire: `PzdInput::timestamp_ns`, the arrival of the reply's
///   last character on the bus clock (`CLOCK_MONOTONIC` via the clock's origin).
/// - B, handed over: the bus thread, having woken for that character, framed and checked the
///   reply and written its image, calls the bridge (stamped by [`Stamping`]).
/// - C, seen: the client process reads an image with a new sequence number and reads
///   `CLOCK_MONOTONIC` (after `DriveWatch::latest` when busy-polling; after
///   `CycleListener::wait` returned with the drive's exchange event, then `latest`, when
///   event-woken).
///
/// B -> C is our IPC path (building the `PzdInput`, blackboard `update_with_copy`, for the
/// event-woken client the `notify` and its wake-up, the client's read). The raw measurement
/// covers the same span with bare iceoryx2: stamp, build the same 64-byte `PzdInput`, write,
/// notify -> a client process reads it, with the same threads on the same CPUs at the same
/// period. A -> B is the bus thread's own latency (on this virtual wire mostly its
/// `clock_nanosleep` wake-up for the last character; on a serial line the tty's latency).
///
/// Both writers exist throughout; the one not measured is paused (it naps in 1 ms steps), and
/// the variants take turns in [`rounds`] rounds, ours and raw in alternating order.
fn input_path() {
    let name = format!("ipcin{}", std::process::id());
    let drive =
        format!("[[bus.drive]]\naddress = {WATCHED}\npkw = 0\npzd = 2\nsim = {{ delay = 0.1 }}\n");
    let bus = BusUnderTest::start(&bus_toml(&name, &drive), false);
    bus.wait_until_answering();
    // One drive: its poll period is the exchange time, and the raw writer's period.
    let period = bus.poll_period();
    let prefix = format!("uss-bench-{}", std::process::id());
    let writer = RawWriter::start(&prefix, period);
    let mut runs: [Vec<Vec<String>>; 4] = Default::default();
    for round in 0..rounds() {
        for pair in [[0, 1], [2, 3]] {
            for v in if round % 2 == 0 {
                pair
            } else {
                [pair[1], pair[0]]
            } {
                let (role, ours) = VARIANTS[v];
                bus.pause(!ours);
                writer.pause(ours);
                let target = if ours { &name } else { &prefix };
                runs[v].push(run_client(role, target, round_secs(), Duration::ZERO));
            }
        }
    }
    let raw_mode = writer.stop();
    let finished = bus.stop();
    println!(
        "== input path: reply -> input image seen by a client process (1 drive, PKW 0 + PZD 2 at 187500 baud, 0.1 ms response delay: one image every {:.3} ms; {}-byte PzdInput; {} rounds of {} s per variant) [bus thread {}; raw writer {raw_mode}]",
        period.as_secs_f64() * 1e3,
        size_of::<PzdInput>(),
        rounds(),
        round_secs(),
        finished.mode
    );
    println!("   bus: {}", failures(&finished.stats));
    let [ours_poll, raw_poll, ours_event, raw_event] = &runs;
    report_input("busy-polling", ours_poll, raw_poll, &finished.handed_over);
    report_input("event-woken", ours_event, raw_event, &finished.handed_over);
}

fn report_input(kind: &str, ours: &[Vec<String>], raw: &[Vec<String>], handed: &[AtomicU64]) {
    let (ours, raw) = (observed(ours), observed(raw));
    let (mut ours_ipc, mut wire_to_seen, mut bus_thread, mut raw_ipc) =
        (histogram(), histogram(), histogram(), histogram());
    for s in &ours.seen {
        record(&mut wire_to_seen, s.at_ns.saturating_sub(s.stamp_ns));
        let b = usize::try_from(s.sequence)
            .ok()
            .and_then(|n| handed.get(n))
            .map_or(0, |a| a.load(Ordering::Relaxed));
        if b != 0 {
            record(&mut ours_ipc, s.at_ns.saturating_sub(b));
            record(&mut bus_thread, b.saturating_sub(s.stamp_ns));
        }
    }
    for s in &raw.seen {
        record(&mut raw_ipc, s.at_ns.saturating_sub(s.stamp_ns));
    }
    println!("   {kind} [client {}]:", ours.mode);
    println!(
        "     ours, handed to the bridge -> seen:   {}",
        percentiles_us(&ours_ipc)
    );
    println!(
        "     raw iceoryx2, write -> seen:          {}",
        percentiles_us(&raw_ipc)
    );
    let mut ratios = String::new();
    for (label, q) in [("p50", 0.5), ("p99", 0.99), ("p99.9", 0.999), ("max", 1.0)] {
        let (o, r) = (ours_ipc.value_at_quantile(q), raw_ipc.value_at_quantile(q));
        let _ = write!(ratios, "{label} {o}/{r} ns = {:.2}   ", o as f64 / r as f64);
    }
    println!("     ours / raw: {ratios}(goal: at most 2)");
    println!(
        "     ours end to end, reply complete on the wire -> seen: {}",
        percentiles_us(&wire_to_seen)
    );
    println!(
        "       of which the bus thread (wake-up for the last character, framing, image): {}",
        percentiles_us(&bus_thread)
    );
    println!(
        "     images not seen because a newer one came first: ours {}, raw {}",
        ours.missed, raw.missed
    );
}

// ---------------------------------------------------------------------------------------------
// 2. Output path.

/// Part 2. Four controllers in one client process, one per drive, each publish a new setpoint
/// (`Controller::set_setpoint`, word k = 1, 2, 3, ...) at random phases of the poll period
/// (1.1 to 2.1 periods apart, so none is superseded unless a poll period stretches), stamping
/// `CLOCK_MONOTONIC` just before the call. [`Recording`] stamps each telegram as it starts on
/// the wire. The latency of k is from its stamp to the first telegram to that drive whose PZD2
/// is k: the controller's publish, `RtBridge::before_poll` taking the sample when that drive's
/// turn comes, and the start pause before the telegram.
fn output_path(bus: &BusUnderTest, period: Duration) -> Vec<[u64; 3]> {
    rows::<3>(
        &run_client("control", &bus.name, output_secs(), period),
        "O ",
    )
}

fn report_output(published: &[[u64; 3]], finished: &Finished) {
    let (mut latency, mut gaps) = (histogram(), histogram());
    let (mut next, mut later, mut superseded) = (0, 0, 0);
    for address in 1..=4u8 {
        let to_drive: Vec<&Sent> = finished
            .sent
            .iter()
            .filter(|s| s.address == address)
            .collect();
        for w in to_drive.windows(2) {
            record(&mut gaps, w[1].at_ns - w[0].at_ns);
        }
        for &[_, k, at] in published.iter().filter(|p| p[0] == u64::from(address)) {
            let Some(carrier) = to_drive
                .iter()
                .position(|s| u64::from(s.setpoint) == k && s.at_ns > at)
            else {
                superseded += 1;
                continue;
            };
            record(&mut latency, to_drive[carrier].at_ns - at);
            if to_drive[..carrier].iter().any(|s| s.at_ns > at) {
                later += 1;
            } else {
                next += 1;
            }
        }
    }
    let period = gaps.value_at_quantile(0.5);
    println!(
        "== output path: Controller::set_setpoint in a client process -> first telegram to the drive carrying it (4 drives, PKW 4 + PZD 2 at 187500 baud, 1 ms response delay) [bus thread {}]",
        finished.mode
    );
    println!("   bus: {}", failures(&finished.stats));
    println!(
        "   poll period of a drive (telegram to telegram): {}",
        percentiles_us(&gaps)
    );
    println!("   latency: {}", percentiles_us(&latency));
    let r = |q: f64| latency.value_at_quantile(q) as f64 / period as f64;
    println!(
        "   latency / poll period ({:.3} ms): p50 {:.3}  p99 {:.3}  p99.9 {:.3}  max {:.3}  (0 to 1 expected: the setpoint waits for the drive's turn)",
        period as f64 / 1e6,
        r(0.5),
        r(0.99),
        r(0.999),
        r(1.0)
    );
    println!(
        "   carried by the next telegram to the drive: {next} of {}; by the one after: {later} (published within the start pause before the next one: its PZD was fixed already); superseded before the drive's turn came: {superseded}",
        next + later + superseded
    );
}

// ---------------------------------------------------------------------------------------------
// 3. Parameter request round trip.

/// Part 3. A client process (like `ussctl param read 1 1082`, but long-lived: no process start
/// or node creation per request) reads P1082 of drive 1 with `Bus::send_request`, at random
/// phases of the poll period, and times each call. The round trip covers: the request through
/// iceoryx2, `ParamServer` picking it up (it looks for requests every millisecond), the job
/// waiting in the drive's mailbox for the drive's turn in the circulating list, the PKW exchange,
/// the result back through the engine's channel, the response through iceoryx2, and the client
/// noticing it (it polls, 50 us doubling to 2 ms). The bare exchange is the engine's own
/// histogram: line free -> reply complete, the same PKW 4 + PZD 2 exchange.
fn parameter_round_trip(bus: &BusUnderTest, period: Duration) -> Vec<[u64; 3]> {
    rows::<3>(&run_client("params", &bus.name, param_secs(), period), "P ")
}

fn report_params(answered: &[[u64; 3]], finished: &Finished, option: &str) {
    let (mut round_trip, mut on_wire, mut rest) = (histogram(), histogram(), histogram());
    for &[rt, wire, _] in answered {
        record(&mut round_trip, rt);
        record(&mut on_wire, wire);
        record(&mut rest, rt.saturating_sub(wire));
    }
    let h = &finished.stats.histograms;
    let exchange = h.exchange.value_at_quantile(0.5);
    let floor = exchange + h.cycle.value_at_quantile(0.5) / 2;
    let b = &finished.stats.bus;
    println!(
        "== parameter read round trip, {option}: Bus::send_request in a client process -> ussd's ParamServer -> PKW exchange -> response (drive 1 of 4) [bus thread {}]",
        finished.mode
    );
    println!(
        "   round trip:                        {}",
        percentiles_us(&round_trip)
    );
    println!(
        "   bare PKW exchange on the wire:     {}",
        percentiles_us(&h.exchange)
    );
    println!(
        "   (wire floor of an exchange, USS.md section 4: {:.3} ms mean)",
        b.timed_wire_floor_ns as f64 / b.good.max(1) as f64 / 1e6
    );
    let r = |q: f64, of: u64| round_trip.value_at_quantile(q) as f64 / of as f64;
    println!(
        "   round trip / exchange p50: p50 {:.2}  p99 {:.2}  p99.9 {:.2}  max {:.2}",
        r(0.5, exchange),
        r(0.99, exchange),
        r(0.999, exchange),
        r(1.0, exchange)
    );
    println!(
        "   task on the wire (engine: first telegram with the task -> result): {}",
        percentiles_us(&on_wire)
    );
    println!(
        "   the rest (drive's turn, bridge, IPC, client polling):             {}",
        percentiles_us(&rest)
    );
    println!(
        "   vs the circulating list's own floor (exchange + half a cycle, the mean wait for the drive's turn = {:.3} ms): p50 {:.2}  p99 {:.2}",
        floor as f64 / 1e6,
        r(0.5, floor),
        r(0.99, floor)
    );
    // The other drives (2..4): their longest time between two good replies against the
    // cycle's median.
    let worst = finished.stats.update_period[1..]
        .iter()
        .map(Histogram::max)
        .max()
        .unwrap_or(0);
    let cycle = h.cycle.value_at_quantile(0.5).max(1);
    println!(
        "   worst poll period of the other drives: {:.3} ms = {:.2} x the median cycle ({:.3} ms)",
        worst as f64 / 1e6,
        worst as f64 / cycle as f64,
        cycle as f64 / 1e6
    );
}

// ---------------------------------------------------------------------------------------------
// Client processes.

/// Pins the client to [`CLIENT_CPU`]; `fifo`: at `SCHED_FIFO` [`CLIENT_PRIORITY`] too.
/// A busy-polling client stays `SCHED_OTHER`: spinning at `SCHED_FIFO` would starve the core.
fn client_sched(fifo: bool) -> String {
    if fifo {
        let report = apply_to_current_thread(&RtRequest {
            cpu: Some(CLIENT_CPU),
            priority: CLIENT_PRIORITY,
            lock_memory: false,
            prefault_stack_bytes: 0,
        });
        return mode(&report);
    }
    let mut cpus = CpuSet::new();
    let pinned = cpus.set(CLIENT_CPU).is_ok() && sched_setaffinity(Pid::from_raw(0), &cpus).is_ok();
    if pinned {
        format!("SCHED_OTHER on CPU {CLIENT_CPU}")
    } else {
        "SCHED_OTHER, not pinned".to_owned()
    }
}

/// Reads images until `duration` has passed: `wait` returns whether there may be news
/// (busy-polling: at once, always; event-woken: after the watched drive's exchange event),
/// then a new sequence number is stamped. One `S sequence timestamp_ns seen_at_ns` line each.
fn observe(
    duration: Duration,
    mode: &str,
    read: impl Fn() -> PzdInput,
    mut wait: impl FnMut() -> bool,
) -> String {
    let mut seen = Vec::with_capacity(CAPACITY);
    let mut last = read().sequence;
    let end = Instant::now() + duration;
    let mut idle = 0u32;
    loop {
        if wait() {
            let image = read();
            if image.sequence != last {
                let at = monotonic_ns();
                last = image.sequence;
                if seen.len() < seen.capacity() {
                    seen.push((image.sequence, image.timestamp_ns, at));
                }
                if Instant::now() >= end {
                    break;
                }
                continue;
            }
        }
        idle = idle.wrapping_add(1);
        if idle.is_multiple_of(65_536) && Instant::now() >= end {
            break;
        }
    }
    let mut out = format!("MODE {mode}\n");
    for (sequence, stamp, at) in seen {
        let _ = writeln!(out, "S {sequence} {stamp} {at}");
    }
    out
}

fn watch_ours(name: &str, duration: Duration, woken: bool) -> String {
    let bus = Bus::open(name).expect("open the bus");
    let watch = bus.watch(addr(WATCHED)).expect("watch the drive");
    let read = || watch.latest();
    if woken {
        let listener = bus.cycle_listener().expect("listen to the bus");
        let mode = client_sched(true);
        observe(duration, &mode, read, || {
            let mut hit = false;
            listener
                .wait(WAKE_TIMEOUT, |e| hit |= e == CycleEvent::Exchange(WATCHED))
                .expect("wait for events");
            hit
        })
    } else {
        observe(duration, &client_sched(false), read, || true)
    }
}

fn watch_raw(prefix: &str, duration: Duration, woken: bool) -> String {
    let node = raw_node();
    let entry = node
        .service_builder(&raw_service(prefix, "in"))
        .blackboard_opener::<BlackboardKey>()
        .open()
        .expect("raw blackboard")
        .reader_builder()
        .create()
        .expect("raw reader")
        .entry::<PzdInput>(&BlackboardKey::IMAGE)
        .expect("raw entry");
    let read = || *entry.get();
    if woken {
        let listener = node
            .service_builder(&raw_service(prefix, "event"))
            .event()
            .open()
            .expect("raw event service")
            .listener_builder()
            .create()
            .expect("raw listener");
        let mode = client_sched(true);
        observe(duration, &mode, read, || {
            let mut hit = false;
            listener
                .timed_wait(|e| hit |= e.id.as_value() == RAW_EVENT_ID, WAKE_TIMEOUT)
                .expect("wait for events");
            hit
        })
    } else {
        observe(duration, &client_sched(false), read, || true)
    }
}

/// One controller per drive, each in its own thread: `O address k published_ns` per setpoint.
fn control(name: &str, duration: Duration, period: Duration) -> String {
    let bus = Bus::open(name).expect("open the bus");
    let mut out = format!("MODE {}\n", client_sched(false));
    std::thread::scope(|s| {
        let controllers: Vec<_> = (1..=4u8)
            .map(|address| {
                let bus = &bus;
                s.spawn(move || {
                    client_sched(false);
                    let drive = bus
                        .control(addr(address), ControlOptions::words(2))
                        .expect("control the drive");
                    drive.rearm(uss_client::monotonic_ns()).expect("re-arm");
                    let mut rng = SmallRng::seed_from_u64(u64::from(address));
                    let mut published = Vec::with_capacity(CAPACITY);
                    let end = Instant::now() + duration;
                    let mut k = 0i16;
                    while Instant::now() < end {
                        std::thread::sleep(period.mul_f64(rng.random_range(1.1..2.1)));
                        k += 1;
                        let at = monotonic_ns();
                        drive.set_setpoint(Setpoint::from_raw(k)).expect("publish");
                        published.push((k, at));
                    }
                    // Stay in control until the last setpoint has gone out.
                    std::thread::sleep(period * 2);
                    (address, published)
                })
            })
            .collect();
        for c in controllers {
            let (address, published) = c.join().expect("controller thread");
            for (k, at) in published {
                let _ = writeln!(out, "O {address} {k} {at}");
            }
        }
    });
    out
}

/// Reads P1082 of drive 1 at random phases: `P round_trip_ns on_wire_ns telegrams` each.
fn params(name: &str, duration: Duration, period: Duration) -> String {
    let bus = Bus::open(name).expect("open the bus");
    let drive = Address::new(WATCHED).expect("a drive address");
    let request = ParamRequest::new(
        drive,
        &[ParamItem::from(&ParamTask::read(
            Pnu::from_u16(P1082),
            None,
        ))],
    )
    .expect("a valid request");
    // The first request opens the client port: not timed.
    bus.send_request(&request).expect("an answer");
    let mut rng = SmallRng::seed_from_u64(7);
    let mut out = String::from("MODE SCHED_OTHER, not pinned (like ussctl)\n");
    let end = Instant::now() + duration;
    while Instant::now() < end {
        std::thread::sleep(period.mul_f64(rng.random_range(0.0..1.0)));
        let start = Instant::now();
        let response = bus.send_request(&request).expect("an answer");
        let round_trip = start.elapsed();
        let results = uss_client::params::response_results(&response, addr(WATCHED), 1)
            .expect("a response to this request");
        assert_eq!(results, [Ok(Value::Dword(P1082_VALUE))], "P1082 reads 50.0");
        let r = response.results()[0];
        let _ = writeln!(
            out,
            "P {} {} {}",
            as_ns(round_trip),
            r.on_wire_ns,
            r.telegrams
        );
    }
    out
}

/// A client process: what [`ROLE_ENV`] names, printed to stdout for the benchmark.
fn client(role: &str) {
    set_log_level(LogLevel::Error);
    let var = |key: &str| std::env::var(key).unwrap_or_else(|_| panic!("{key} is set"));
    let name = var(NAME_ENV);
    let duration = Duration::from_secs_f64(var(SECS_ENV).parse().expect("seconds"));
    let period = Duration::from_nanos(var(PERIOD_ENV).parse().expect("nanoseconds"));
    let out = match role {
        "ours-poll" | "ours-event" => watch_ours(&name, duration, role == "ours-event"),
        "raw-poll" | "raw-event" => watch_raw(&name, duration, role == "raw-event"),
        "control" => control(&name, duration, period),
        "params" => params(&name, duration, period),
        other => panic!("unknown client role {other}"),
    };
    print!("{out}");
}

fn main() {
    if let Ok(role) = std::env::var(ROLE_ENV) {
        client(&role);
        return;
    }
    let parts = Parts::from_args();
    let wanted = |name: &str| parts.wanted(name);
    if wanted("input") {
        input_path();
    }
    if !wanted("output") && !wanted("params") {
        return;
    }
    let name = format!("ipcout{}", std::process::id());
    let drives = "[[bus.drive]]\naddress = 1\n\n[[bus.drive]]\naddress = 2\n\n\
                  [[bus.drive]]\naddress = 3\n\n[[bus.drive]]\naddress = 4\n";
    let bus = BusUnderTest::start(&bus_toml(&name, drives), true);
    bus.wait_until_answering();
    let period = bus.poll_period();
    let published = if wanted("output") {
        output_path(&bus, period)
    } else {
        Vec::new()
    };
    let answered = if wanted("params") {
        parameter_round_trip(&bus, period)
    } else {
        Vec::new()
    };
    let finished = bus.stop();
    if wanted("output") {
        report_output(&published, &finished);
    }
    if wanted("params") {
        report_params(&answered, &finished, "param_priority = false");
        // The same with the drive that has a job waiting polled after each regular poll.
        let name = format!("ipcprio{}", std::process::id());
        let toml = bus_toml(&name, drives)
            .replace("baud = 187500\n", "baud = 187500\nparam_priority = true\n");
        let bus = BusUnderTest::start(&toml, true);
        bus.wait_until_answering();
        let answered = parameter_round_trip(&bus, bus.poll_period());
        report_params(&answered, &bus.stop(), "param_priority = true");
    }
}
