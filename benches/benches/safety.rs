//! Safety latencies (issue 21), printed as figures measured in one run, before (a drive's words
//! decided at its turn in the circulating list alone, `EngineConfig::safety_first = false`) and
//! after (safety telegrams jump the queue, stops of every drive are broadcasts):
//!
//! 1. Stop latency: an operator's stop of a running drive, from the request to the start of
//!    the first telegram to that drive with the stop word.
//! 2. Trip latency: a controller that stops publishing, from its watchdog deadline (last
//!    sample + `watchdog_ms`) to the start of the first telegram with the safe command.
//! 3. Stop-all latency: a stop of every drive, from the request to the start of the first
//!    telegram that carries it to the last drive (a broadcast reaches every drive at once).
//!
//! Each for 4, 16 and 31 drives at 9600, 19200 and 187500 baud, on the virtual clock against
//! the simulated wire (every byte takes its wire time; the drives answer after 1 ms): the
//! request comes at a uniformly random moment of the exchange in progress, after a random
//! number of exchanges. p50 / p99 / max in exchanges (of the bus's median exchange) and in ms.
//! 4. Through a real ussd (31 simulated drives at 9600 baud), the same stop latency with the
//!    IPC: `uss_client::stop` from this process to the first telegram with the stop word, as
//!    ussd's telegram capture timestamps it; alone, beside 64 idle connections to the stop
//!    socket, and beside 40 processes that connect to it and close in a tight loop.
//!
//! `cargo bench -p uss-benches --bench safety` (`-- matrix` or `-- ussd` for one part).

use rand::{Rng, SeedableRng};
use std::fmt::Write as _;
use std::time::{Duration, Instant};
use uss_benches::{Parts, engine_config};
use uss_drive_sim::{DriveConfig, SimBus, SimTransport, VirtualWire};
use uss_engine::{Clock, DriveSetup, Engine, EngineConfig, EngineHandle, VirtualClock};
use uss_protocol::telegram::{Layout, PkwMode, PzdCount};
use uss_protocol::{Address, Baud, Timing};
use uss_shm_types::{StopCommand, TelegramRecord};

type Sim = Engine<SimTransport, VirtualClock>;

const RUN: [u16; 2] = [0x047F, 0x2000];
const OFF1: [u16; 2] = [0x047E, 0];
/// Stops, trips and stops of every drive per row ([`uss_benches::rounds`]: fewer in a short run).
fn stops() -> usize {
    usize::try_from(uss_benches::rounds(100, 5)).expect("rounds")
}
fn trips() -> usize {
    usize::try_from(uss_benches::rounds(60, 3)).expect("rounds")
}
fn stop_alls() -> usize {
    usize::try_from(uss_benches::rounds(60, 3)).expect("rounds")
}
const WATCHDOG: Duration = Duration::from_millis(100);

fn addr(a: u8) -> Address {
    Address::new(a).expect("address")
}

/// One bus: drives 1..=n at `baud`, every telegram captured.
struct Bus {
    engine: Sim,
    handle: EngineHandle,
    n: u8,
    /// Start and end of each exchange so far (bus time).
    exchanges: Vec<Duration>,
}

impl Bus {
    fn new(n: u8, baud: u32, safety_first: bool) -> Self {
        let timing = Timing::new(Baud::new(baud).expect("baud"));
        let layout = Layout::new(PkwMode::Four, PzdCount::new(2).expect("pzd"));
        let mut sim = SimBus::new(5);
        let mut drives = Vec::new();
        for a in 1..=n {
            sim.add(DriveConfig::new(addr(a), layout)).expect("unique");
            drives.push(DriveSetup::new(addr(a), layout));
        }
        let config = EngineConfig {
            safety_first,
            ..engine_config(timing, drives, true)
        };
        let transport = SimTransport::new(VirtualWire::new(sim, timing));
        let (engine, handle, _events) = Engine::new(config, transport, VirtualClock::new());
        Self {
            engine,
            handle,
            n,
            exchanges: Vec::new(),
        }
    }

    fn now(&self) -> Duration {
        self.engine.clock().now()
    }

    /// One exchange; returns its start.
    fn exchange(&mut self, outputs: &[(u8, [u16; 2])]) -> Duration {
        for (a, w) in outputs {
            self.handle.set_output(addr(*a), w).expect("output");
        }
        let start = self.now();
        self.engine.poll_next().expect("virtual wire");
        self.exchanges.push(self.now().saturating_sub(start));
        start
    }

    /// Every drive armed, then the drives in `running` running; the capture emptied.
    fn warm(&mut self, running: &[u8]) {
        let armed: Vec<(u8, [u16; 2])> = (1..=self.n).map(|a| (a, OFF1)).collect();
        while self.engine.stats().bus.cycles < 2 {
            self.exchange(&armed);
        }
        let words = self.words(running);
        let mut left = 4 * usize::from(self.n);
        while left > 0 {
            self.exchange(&words);
            left -= 1;
        }
        while self.handle.captures().try_recv().is_ok() {}
    }

    /// Every drive's words: RUN for `running`, OFF1 for the rest.
    fn words(&self, running: &[u8]) -> Vec<(u8, [u16; 2])> {
        (1..=self.n)
            .map(|a| (a, if running.contains(&a) { RUN } else { OFF1 }))
            .collect()
    }

    /// The median exchange time so far.
    fn exchange_time(&self) -> Duration {
        let mut v = self.exchanges.clone();
        v.sort_unstable();
        v.get(v.len() / 2).copied().unwrap_or_default()
    }
}

/// STW1 of a captured request, and whether it was a broadcast.
fn stw1_of(r: &TelegramRecord) -> Option<(u16, bool)> {
    let b = r.bytes();
    (r.is_request() && b.len() >= 15)
        .then(|| (u16::from_be_bytes([b[11], b[12]]), b[2] & 0x20 != 0))
}

/// Exchanges until every drive in `drives` got a telegram with STW1 `stw1` (a broadcast counts
/// for all); the start of the last of those first telegrams.
fn reached(bus: &mut Bus, drives: &[u8], stw1: u16, outputs: &[(u8, [u16; 2])]) -> Duration {
    let mut first: Vec<Option<Duration>> = vec![None; drives.len()];
    for _ in 0..(8 * usize::from(bus.n) + 200) {
        bus.exchange(outputs);
        while let Ok(r) = bus.handle.captures().try_recv() {
            let Some((word, broadcast)) = stw1_of(&r) else {
                continue;
            };
            if word != stw1 {
                continue;
            }
            let at = Duration::from_nanos(r.start_ns);
            for (i, &d) in drives.iter().enumerate() {
                if first[i].is_none() && (broadcast || r.address == d) {
                    first[i] = Some(at);
                }
            }
        }
        if first.iter().all(Option::is_some) {
            return first.into_iter().flatten().max().unwrap_or_default();
        }
    }
    panic!("drives {drives:?} never got {stw1:#06X}")
}

/// Latencies of one kind, in ms, with the bus's exchange time.
struct Figures {
    ms: Vec<f64>,
    exchange_ms: f64,
}

impl Figures {
    fn quantiles(&self) -> [f64; 3] {
        let mut v = self.ms.clone();
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() as f64 * q).ceil() as usize).clamp(1, v.len()) - 1];
        [at(0.5), at(0.99), v[v.len() - 1]]
    }

    /// `p50 / p99 / max` in exchanges, then in ms.
    fn show(&self) -> String {
        let [a, b, c] = self.quantiles();
        let x = self.exchange_ms;
        format!(
            "{:5.2} / {:5.2} / {:5.2} ex ({:6.1} / {:6.1} / {:6.1} ms)",
            a / x,
            b / x,
            c / x,
            a,
            b,
            c
        )
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The request comes at a uniform moment of the exchange that started at `start` and ended now.
fn arrival(bus: &Bus, start: Duration, rng: &mut impl Rng) -> Duration {
    let end = bus.now();
    start + end.saturating_sub(start).mul_f64(rng.random::<f64>())
}

fn stop_latencies(n: u8, baud: u32, safety_first: bool, rng: &mut impl Rng) -> Figures {
    let k = n / 2 + 1;
    let mut out = Vec::new();
    let mut exchange_ms = 0.0;
    for _ in 0..stops() {
        let mut bus = Bus::new(n, baud, safety_first);
        bus.warm(&[k]);
        let words = bus.words(&[k]);
        for _ in 0..rng.random_range(0..2 * usize::from(n)) {
            bus.exchange(&words);
        }
        let start = bus.exchange(&words);
        let asked = arrival(&bus, start, rng);
        while bus.handle.captures().try_recv().is_ok() {}
        bus.handle
            .stop_drive(Some(addr(k)), StopCommand::Off1, 1)
            .expect("stop");
        let at = reached(&mut bus, &[k], OFF1[0], &words);
        out.push(ms(at.saturating_sub(asked)));
        exchange_ms = ms(bus.exchange_time());
    }
    Figures {
        ms: out,
        exchange_ms,
    }
}

fn trip_latencies(n: u8, baud: u32, safety_first: bool, rng: &mut impl Rng) -> Figures {
    let k = n / 2 + 1;
    let mut out = Vec::new();
    let mut exchange_ms = 0.0;
    for _ in 0..trips() {
        let mut bus = Bus::new(n, baud, safety_first);
        bus.warm(&[k]);
        let words = bus.words(&[k]);
        for _ in 0..rng.random_range(0..2 * usize::from(n)) {
            bus.exchange(&words);
        }
        // The controller's last sample, written at a random moment of the exchange in
        // progress, then nothing more from it.
        let start = bus.exchange(&words);
        let written = arrival(&bus, start, rng);
        let last = uss_shm_types::PzdOutput::from_words(
            &RUN,
            1 << 40,
            u64::try_from(written.as_nanos()).expect("ns"),
            1,
        )
        .expect("sample");
        bus.handle.publish_sample(addr(k), last).expect("sample");
        let deadline = written + WATCHDOG;
        let others: Vec<(u8, [u16; 2])> = words.into_iter().filter(|&(a, _)| a != k).collect();
        while bus.handle.captures().try_recv().is_ok() {}
        let at = reached(&mut bus, &[k], OFF1[0], &others);
        out.push(ms(at.saturating_sub(deadline)));
        exchange_ms = ms(bus.exchange_time());
    }
    Figures {
        ms: out,
        exchange_ms,
    }
}

fn stop_all_latencies(n: u8, baud: u32, safety_first: bool, rng: &mut impl Rng) -> Figures {
    let all: Vec<u8> = (1..=n).collect();
    let mut out = Vec::new();
    let mut exchange_ms = 0.0;
    for _ in 0..stop_alls() {
        let mut bus = Bus::new(n, baud, safety_first);
        bus.warm(&all);
        let words = bus.words(&all);
        for _ in 0..rng.random_range(0..2 * usize::from(n)) {
            bus.exchange(&words);
        }
        let start = bus.exchange(&words);
        let asked = arrival(&bus, start, rng);
        while bus.handle.captures().try_recv().is_ok() {}
        bus.handle
            .stop_drive(None, StopCommand::Off1, 1)
            .expect("stop all");
        let at = reached(&mut bus, &all, OFF1[0], &words);
        out.push(ms(at.saturating_sub(asked)));
        exchange_ms = ms(bus.exchange_time());
    }
    Figures {
        ms: out,
        exchange_ms,
    }
}

fn matrix() {
    println!(
        "== safety on the virtual clock (PKW 4 + PZD 2, drives answer after 1 ms; {} stops, \
         {} trips, {} stops of every drive per row; p50 / p99 / max in exchanges \
         of the bus and in ms)",
        stops(),
        trips(),
        stop_alls()
    );
    let mut rng = rand::rngs::SmallRng::seed_from_u64(21);
    for n in [4u8, 16, 31] {
        for baud in [9600u32, 19_200, 187_500] {
            let t0 = Instant::now();
            let figures = [false, true].map(|after| {
                (
                    stop_latencies(n, baud, after, &mut rng),
                    trip_latencies(n, baud, after, &mut rng),
                    stop_all_latencies(n, baud, after, &mut rng),
                )
            });
            let [(s0, t0f, a0), (s1, t1, a1)] = figures;
            println!(
                "{n:2} drives, {baud:6} baud (exchange {:.2} ms, measured in {:.1} s)",
                s1.exchange_ms,
                t0.elapsed().as_secs_f64()
            );
            println!(
                "   stop:                  before {}  after {}",
                s0.show(),
                s1.show()
            );
            println!(
                "   trip beyond watchdog:  before {}  after {}",
                t0f.show(),
                t1.show()
            );
            println!(
                "   stop all, last drive:  before {}  after {}",
                a0.show(),
                a1.show()
            );
        }
    }
}

fn through_ussd() {
    let bus_name = format!("safety{}", std::process::id());
    let mut drives = String::new();
    for a in 1..=31 {
        let _ = write!(drives, "\n[[bus.drive]]\naddress = {a}\n");
    }
    // ussd with 31 simulated drives at 9600 baud; killed when dropped.
    let _ussd = uss_benches::start_ussd(
        &bus_name,
        &format!("[[bus]]\nname = \"{bus_name}\"\ndevice = \"sim\"\nbaud = 9600\n{drives}"),
    );
    let bus = uss_benches::open_bus(&bus_name);
    let (plain, diag_lag) = stops_through_ussd(&bus, &bus_name);
    // 64 connections to the stop socket that say nothing: 8 processes of 8, each connection
    // made again as soon as ussd closes it (issue 32: they held a stop back 2 s and more).
    let socket = uss_shm_types::names::stop_socket(
        &uss_shm_types::BusName::new(&bus_name).expect("bus name"),
    );
    let holders = stop_socket_users(
        "uss-idle-connections",
        &[socket.as_os_str(), "8".as_ref()],
        "holding 8",
        8,
    );
    let (idle, _) = stops_through_ussd(&bus, &bus_name);
    drop(holders);
    // 40 processes connecting to the stop socket and closing at once, in a tight loop (issue
    // 45: they held a stop back up to 2.45 s).
    let storm = stop_socket_users("uss-stop-flood", &[socket.as_os_str()], "flooding", 40);
    let (flood, _) = stops_through_ussd(&bus, &bus_name);
    drop(storm);
    let ratio = idle.quantiles()[1] / plain.quantiles()[1];
    let flood_ratio = flood.quantiles()[1] / plain.quantiles()[1];
    println!(
        "== through ussd: 31 simulated drives at 9600 baud, uss_client::stop -> first telegram with \
         the stop word (ussd's capture), 30 stops: {}",
        plain.show()
    );
    println!(
        "== the same with 64 idle connections to the stop socket (8 processes of 8): {}; p99 {ratio:.2}x",
        idle.show()
    );
    println!(
        "== the same beside 40 processes flooding the stop socket with connections: {}; p99 {flood_ratio:.2}x",
        flood.show()
    );
    println!(
        "== the latch in the diagnostics after the image shows it (the plain stops): {}",
        diag_lag.show()
    );
}

/// `n` runs of `uss-integration-tests`'s `binary` with `args` (the stop socket's path first),
/// each once its first line said `ready`; killed when dropped.
fn stop_socket_users(
    binary: &str,
    args: &[&std::ffi::OsStr],
    ready: &str,
    n: usize,
) -> Vec<uss_benches::Child> {
    let path = uss_benches::release_binary("uss-integration-tests", binary);
    (0..n)
        .map(|_| {
            let mut child = std::process::Command::new(&path)
                .args(args)
                .stdout(std::process::Stdio::piped())
                .spawn()
                .expect(binary);
            let mut said = String::new();
            let out = child.stdout.take().expect("its stdout");
            std::io::BufRead::read_line(&mut std::io::BufReader::new(out), &mut said).expect(ready);
            assert!(said.starts_with(ready), "{binary}: {said}");
            uss_benches::Child { child, file: None }
        })
        .collect()
}

/// 30 stops of a running drive through ussd's stop socket, each at a random moment of the cycle:
/// from the API call to the first telegram that carries the stop (ussd's capture); and how long
/// after the drive's image the diagnostics showed the latch.
fn stops_through_ussd(bus: &uss_client::Bus, bus_name: &str) -> (Figures, Figures) {
    let k = 16u8;
    let watch = bus.watch(addr(k)).expect("watch");
    watch
        .wait_exchanges(2, Duration::from_secs(20))
        .expect("drive 16 polled");
    let mut capture = bus.capture().expect("capture");
    let mut rng = rand::rngs::SmallRng::seed_from_u64(7);
    let (mut out, mut diag_lags) = (Vec::new(), Vec::new());
    for _ in 0..uss_benches::rounds(30, 3) {
        let c = bus
            .control(addr(k), uss_client::ControlOptions::default())
            .expect("control");
        c.rearm(uss_client::monotonic_ns()).expect("re-arm");
        // ussd scales no Hz before it has read the drive's reference.
        watch
            .wait_for_reference(Duration::from_secs(20))
            .expect("reference read");
        // Running: the ON went out (at the drive's turn), then a random moment of the cycle.
        while watch.latest().sent_stw1 != RUN[0] {
            c.run_hz(5.0).expect("run");
            std::thread::sleep(Duration::from_millis(10));
        }
        let started = Instant::now();
        while started.elapsed() < Duration::from_millis(rng.random_range(0..1400)) {
            c.run_hz(5.0).expect("run");
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = capture.take();
        let asked = uss_client::monotonic_ns();
        uss_client::stop(bus_name, Some(addr(k)), StopCommand::Off1).expect("stop");
        let deadline = Instant::now() + Duration::from_secs(5);
        let at = 'found: loop {
            for r in capture.take().expect("capture") {
                if r.address == k && stw1_of(&r).is_some_and(|(w, _)| w == OFF1[0]) {
                    break 'found r.start_ns;
                }
            }
            assert!(Instant::now() < deadline, "no stop telegram");
            std::thread::sleep(Duration::from_millis(2));
        };
        out.push(at.saturating_sub(asked) as f64 / 1e6);
        // Then what a client reads: from the image showing the latch to the diagnostics
        // (`ussctl status`, Python `diag()`, C `ussrt_drive_diag`) showing it.
        let until = |latched: &dyn Fn() -> bool| loop {
            if latched() {
                break Instant::now();
            }
            assert!(Instant::now() < deadline, "no latch shown");
            std::thread::sleep(Duration::from_micros(200));
        };
        let image = until(&|| !watch.latest().is_live());
        let diag = until(&|| !bus.diag(addr(k)).expect("diag").is_live());
        diag_lags.push(diag.saturating_duration_since(image).as_secs_f64() * 1e3);
        drop(c);
    }
    let status = bus.status().expect("status");
    let exchange_ms = status.mean_exchange_ns as f64 / 1e6;
    (
        Figures {
            ms: out,
            exchange_ms,
        },
        Figures {
            ms: diag_lags,
            exchange_ms,
        },
    )
}

fn main() {
    let parts = Parts::from_args();
    if parts.wanted("matrix") {
        matrix();
    }
    if parts.wanted("ussd") {
        through_ussd();
    }
}
