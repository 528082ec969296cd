//! Bus engine benchmarks (issue "the real-time bus engine"), printed as ratios measured in one
//! run on this machine:
//!
//! 1. Exchange efficiency: on the real-time-paced virtual wire (bytes take 11 bits of wire time,
//!    the drives answer after 1 ms, at 19200 baud after the start pause and one character time,
//!    1.72 ms), the wire-time floor of USS.md section 4 over the achieved
//!    exchange time, at 19200, 115200 and 187500 baud with PKW 4 + PZD 2 and PKW 4 + PZD 8; and
//!    for PKW 4 + PZD 8 at 19200 the speed-up over the S7-1200 library's 68.2 ms per exchange.
//! 2. Master turnaround (reply complete -> next request written) against the start pause the
//!    protocol demands anyway (117 us at 187500 baud).
//! 3. Scale: 8 simulated buses x 31 drives in one ussd process: the daemon's own benchmark,
//!    `cargo bench -p uss-master --bench scale`.
//! 4. Telegram capture: the bus thread's cost with every telegram captured, against without.
//! 5. Publishing the statistics (every 50 ms, for ussctl stats, the exporter, the status
//!    service): what the bus thread spends per publication handing its timing over, against
//!    copying the histograms as it did before, with 4 and 31 drives.
//!
//! 6. The master's own work per exchange without the wire (`work`): the engine on the virtual
//!    clock, the bus thread's CPU per exchange with 4 and 31 drives, and apart from it the
//!    simulated drives' share (the time inside the wire's flush and send, where every drive's
//!    model moves), so that two builds compare by the engine's own work even where their
//!    simulators differ.
//!
//! 7. The fresh-task rule's cost (`fresh`): a drive answers a repeated task from its stored
//!    reply, so the same read twice in a row needs a telegram without a task between (issue
//!    33). Exchanges on the bus per parameter read, for a client reading one parameter back to
//!    back against one alternating two parameters (never separated), with `param_priority` off
//!    and on, on the virtual clock.
//!
//! The bus threads run `SCHED_FIFO` where the machine allows (root here); the mode is printed.

use std::time::{Duration, Instant};
use uss_benches::{Parts, engine_config, percentiles_us};
use uss_drive_sim::{DriveConfig, SimBus, SimTransport, VirtualWire};
use uss_engine::clock::SPIN_BEFORE_DEADLINE;
use uss_engine::control::Control;
use uss_engine::stats::{FreshTiming, Published};
use uss_engine::{DriveSetup, Engine, Job, MonotonicClock, Stats, VirtualClock};
use uss_protocol::telegram::{Layout, PkwMode, PzdCount};
use uss_protocol::{Address, Baud, ParamTask, Pnu, Timing};
use uss_realtime::{RtRequest, apply_to_current_thread};

/// The S7-1200 library's documented minimum call interval per exchange at 19200 baud (USS.md
/// section 8).
const S7_1200_AT_19200_MS: f64 = 68.2;

/// `drives` simulated drives (addresses 1..) with PKW 4 + `pzd` words at `baud`: the virtual
/// wire to them, their setups for the engine, and the timing.
fn simulated_drives(drives: u8, baud: u32, pzd: usize) -> (SimTransport, Vec<DriveSetup>, Timing) {
    let timing = Timing::new(Baud::new(baud).expect("benchmark baud"));
    let layout = Layout::new(PkwMode::Four, PzdCount::new(pzd).expect("pzd"));
    let mut bus = SimBus::new(1);
    let mut setups = Vec::new();
    for a in 1..=drives {
        let address = Address::new(a).expect("address");
        bus.add(DriveConfig::new(address, layout)).expect("unique");
        setups.push(DriveSetup::new(address, layout));
    }
    (
        SimTransport::new(VirtualWire::new(bus, timing)),
        setups,
        timing,
    )
}

/// Runs one engine for `exchanges` exchanges with four drives in real time; returns its stats
/// and the real-time mode its thread got.
fn run_engine(baud: u32, pzd: usize, exchanges: u64) -> (Stats, &'static str) {
    let (stats, mode, _) = run_engine_spinning(baud, pzd, exchanges, SPIN_BEFORE_DEADLINE, false);
    (stats, mode)
}

/// [`run_engine`] with the clock spinning `spin` before each start-pause deadline and, with
/// `capture`, every telegram captured (and taken by another thread, as ussd's housekeeping
/// thread does); also returns the bus thread's CPU time.
fn run_engine_spinning(
    baud: u32,
    pzd: usize,
    exchanges: u64,
    spin: Duration,
    capture: bool,
) -> (Stats, &'static str, Duration) {
    let (transport, drives, timing) = simulated_drives(4, baud, pzd);
    let config = engine_config(timing, drives, capture);
    std::thread::spawn(move || {
        let report = apply_to_current_thread(&RtRequest {
            cpu: Some(1),
            priority: 80,
            lock_memory: false,
            prefault_stack_bytes: 128 * 1024,
        });
        let _ = nix::sys::prctl::set_timerslack(1);
        let clock = MonotonicClock::new().with_spin(spin);
        let (mut engine, handle, _events) = Engine::new(config, transport, clock);
        let captures = handle.captures().clone();
        // Taken as ussd's housekeeping thread takes them: every 10 ms, never waiting on the
        // channel (a waiting receiver would turn each send into a wake-up).
        let drain = std::thread::spawn(move || {
            let mut taken = 0usize;
            loop {
                loop {
                    match captures.try_recv() {
                        Ok(_) => taken += 1,
                        Err(e) if e.is_disconnected() => return taken,
                        Err(_) => break,
                    }
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        });
        let cpu_start = thread_cpu();
        while engine.counters().exchanges < exchanges {
            engine.poll_next().expect("virtual wire never fails");
        }
        let cpu = thread_cpu().saturating_sub(cpu_start);
        let stats = engine.stats().clone();
        drop((engine, handle));
        let taken = drain.join().expect("capture drain");
        if capture {
            assert!(taken as u64 >= 2 * exchanges, "every telegram captured");
        }
        let mode = if report.priority.is_some() {
            "SCHED_FIFO"
        } else {
            "best-effort"
        };
        (stats, mode, cpu)
    })
    .join()
    .expect("bench thread")
}

/// CPU time of the calling thread.
fn thread_cpu() -> Duration {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map_or(Duration::ZERO, Duration::from)
}

fn efficiency() {
    println!(
        "== exchange efficiency on the real-time-paced virtual wire (4 drives, 1 ms response delay, 1.72 ms at 19200 baud)"
    );
    println!("   baud    layout        mean exchange   wire floor   efficiency (floor / achieved)");
    for pzd in [2, 8] {
        for baud in [19200, 115_200, 187_500] {
            let count = uss_benches::rounds(if baud == 19200 { 150 } else { 1500 }, 20);
            let (stats, mode) = run_engine(baud, pzd, count);
            let eff = stats.bus.efficiency().unwrap_or(0.0);
            let mean_ns = stats.bus.timed_exchange_ns as f64 / stats.bus.good.max(1) as f64;
            let floor_ns = stats.bus.timed_wire_floor_ns as f64 / stats.bus.good.max(1) as f64;
            println!(
                "  {baud:6}  PKW 4 + PZD {pzd}   {:9.3} ms   {:9.3} ms   {eff:.4}   [{mode}, {} exchanges]",
                mean_ns / 1e6,
                floor_ns / 1e6,
                stats.bus.good
            );
            if baud == 19200 && pzd == 8 {
                println!(
                    "          speed-up over the S7-1200 library's {S7_1200_AT_19200_MS} ms per exchange at 19200: {:.2}x",
                    S7_1200_AT_19200_MS / (mean_ns / 1e6)
                );
            }
        }
    }
}

fn turnaround() {
    let baud = 187_500;
    let pause = Timing::new(Baud::new(baud).expect("baud")).start_pause();
    // The same run with a plain sleep to the start-pause deadline, then with the precise wait
    // (sleep, then spin the last stretch): the spin's effect and its CPU cost, in one run.
    println!(
        "== start-pause wait at {baud} baud: plain sleep vs sleep + spin ({} us), 5000 exchanges each",
        SPIN_BEFORE_DEADLINE.as_micros()
    );
    let mut spun = None;
    for spin in [Duration::ZERO, SPIN_BEFORE_DEADLINE] {
        let (stats, mode, cpu) =
            run_engine_spinning(baud, 2, uss_benches::rounds(5000, 50), spin, false);
        let h = &stats.histograms.turnaround;
        let n = stats.bus.exchanges.max(1);
        println!(
            "   spin {:3} us: turnaround p50 / pause = {:.3}, p99 / pause = {:.3}; efficiency {:.4}; bus thread CPU {:.1} us per exchange [{mode}]",
            spin.as_micros(),
            h.value_at_quantile(0.5) as f64 / pause.as_nanos() as f64,
            h.value_at_quantile(0.99) as f64 / pause.as_nanos() as f64,
            stats.bus.efficiency().unwrap_or(0.0),
            cpu.as_secs_f64() * 1e6 / n as f64
        );
        // Where the rest of the efficiency goes: the turnarounds above their median, i.e.
        // the machine's scheduling stalls (the tail), against the mean exchange.
        let mean_exchange = stats.bus.timed_exchange_ns as f64 / stats.bus.good.max(1) as f64;
        let tail = h.mean() - h.value_at_quantile(0.5) as f64;
        println!(
            "              mean turnaround {:.1} us vs median {:.1} us (max {:.1} ms): the tail costs {:.4} of efficiency, so with every turnaround at its median it would be {:.4}",
            h.mean() / 1e3,
            h.value_at_quantile(0.5) as f64 / 1e3,
            h.max() as f64 / 1e6,
            tail / mean_exchange,
            stats.bus.efficiency().unwrap_or(0.0) * mean_exchange / (mean_exchange - tail)
        );
        spun = Some((stats, mode));
    }
    let Some((stats, mode)) = spun else {
        return;
    };
    let h = &stats.histograms.turnaround;
    println!(
        "== master turnaround at {baud} baud (reply complete -> next request written) [{mode}]"
    );
    println!("   {}", percentiles_us(h));
    println!(
        "   start pause {:.1} us; p50 / pause = {:.3}, p99 / pause = {:.3}, max / pause = {:.3} (1.000 = the master's work hides inside the pause)",
        pause.as_secs_f64() * 1e6,
        h.value_at_quantile(0.5) as f64 / pause.as_nanos() as f64,
        h.value_at_quantile(0.99) as f64 / pause.as_nanos() as f64,
        h.max() as f64 / pause.as_nanos() as f64
    );
    let work = &stats.histograms.work;
    println!(
        "   of which the master's own work (reply seen -> ready to send): {}",
        percentiles_us(work)
    );
    println!(
        "   work / pause: p50 {:.3}, p99 {:.3}, p99.9 {:.3} (below 1.000 the work hides inside the pause; the rest of the turnaround is wake-up latency)",
        work.value_at_quantile(0.5) as f64 / pause.as_nanos() as f64,
        work.value_at_quantile(0.99) as f64 / pause.as_nanos() as f64,
        work.value_at_quantile(0.999) as f64 / pause.as_nanos() as f64
    );
    println!(
        "   response delay seen by the master: {}",
        percentiles_us(&stats.histograms.response_delay)
    );
}

/// Part 4, what capturing every telegram costs the bus thread: the same run without and with
/// capture (a copy of each telegram into a preallocated queue), the master's own work per
/// exchange (reply seen -> ready to send) and the bus thread's CPU per exchange.
fn capture_cost() {
    let baud = 187_500;
    println!(
        "== telegram capture at {baud} baud, 4 drives PKW 4 + PZD 2, 5000 exchanges each: off vs on"
    );
    let mut runs = Vec::new();
    for capture in [false, true] {
        let (stats, mode, cpu) = run_engine_spinning(
            baud,
            2,
            uss_benches::rounds(5000, 50),
            SPIN_BEFORE_DEADLINE,
            capture,
        );
        let h = &stats.histograms.work;
        let n = stats.bus.exchanges.max(1);
        let per_exchange_us = cpu.as_secs_f64() * 1e6 / n as f64;
        println!(
            "   capture {}: master work p50 {:.2} us, p99 {:.2} us; bus thread CPU {per_exchange_us:.1} us per exchange; efficiency {:.4} [{mode}]",
            if capture { "on " } else { "off" },
            h.value_at_quantile(0.5) as f64 / 1e3,
            h.value_at_quantile(0.99) as f64 / 1e3,
            stats.bus.efficiency().unwrap_or(0.0)
        );
        runs.push((h.value_at_quantile(0.5) as f64, per_exchange_us));
    }
    if let [(work_off, cpu_off), (work_on, cpu_on)] = runs[..] {
        println!(
            "   on / off: master work p50 {:.3}, bus thread CPU per exchange {:.3}",
            work_on / work_off.max(1.0),
            cpu_on / cpu_off.max(1e-9)
        );
    }
}

/// Statistics of `drives` drives whose histograms look like a bus that ran for a while: each
/// drive 1000 exchange times, response delays and update periods, the bus 10000 exchanges.
fn busy_stats(drives: u8) -> Stats {
    let addresses = (1..=drives).map(|a| (Address::new(a).expect("address"), Control::Live));
    let mut stats = Stats::new(addresses);
    for (i, d) in stats.drive_histograms.iter_mut().enumerate() {
        for k in 0..1000 {
            d.exchange
                .saturating_record(2_000_000 + k * 1000 + i as u64);
            d.response_delay.saturating_record(1_000_000 + k * 50);
        }
    }
    for (i, h) in stats.update_period.iter_mut().enumerate() {
        for k in 0..1000 {
            h.saturating_record(12_000_000 + k * 3000 + i as u64);
        }
    }
    let h = &mut stats.histograms;
    for k in 0..10_000 {
        for x in [
            &mut h.exchange,
            &mut h.response_delay,
            &mut h.turnaround,
            &mut h.work,
        ] {
            x.saturating_record(100_000 + k * 300);
        }
        h.cycle.saturating_record(10_000_000 + k * 1000);
    }
    stats
}

/// What the bus thread did to publish before: every histogram copied (reset, then added).
fn copy_all(dst: &mut Stats, src: &Stats) {
    dst.at = src.at;
    dst.bus = src.bus;
    dst.line = src.line;
    dst.drives.copy_from_slice(&src.drives);
    let (d, s) = (&mut dst.histograms, &src.histograms);
    for (d, s) in [
        (&mut d.exchange, &s.exchange),
        (&mut d.response_delay, &s.response_delay),
        (&mut d.turnaround, &s.turnaround),
        (&mut d.work, &s.work),
        (&mut d.cycle, &s.cycle),
    ] {
        d.reset();
        let _ = d.add(s);
    }
    for (d, s) in dst.update_period.iter_mut().zip(&src.update_period) {
        d.reset();
        let _ = d.add(s);
    }
    for (d, s) in dst.drive_histograms.iter_mut().zip(&src.drive_histograms) {
        d.exchange.reset();
        let _ = d.exchange.add(&s.exchange);
        d.response_delay.reset();
        let _ = d.response_delay.add(&s.response_delay);
    }
}

/// Part 5: one publication of the statistics, as the bus thread does it (the median of 300).
fn publish_cost() {
    println!("== publishing the statistics: the bus thread's share, median of 300 publications");
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    for drives in [4, 31] {
        let stats = busy_stats(drives);
        let mut copy = stats.clone();
        let mut before = Vec::new();
        for _ in 0..uss_benches::rounds(300, 10) {
            let t = Instant::now();
            copy_all(&mut copy, &stats);
            before.push(t.elapsed().as_secs_f64() * 1e6);
        }
        let mut published = Published::new(&stats);
        let mut fresh = FreshTiming::new(usize::from(drives));
        let (mut now, mut merge) = (Vec::new(), Vec::new());
        for _ in 0..uss_benches::rounds(300, 10) {
            // 50 ms of a busy bus: one exchange per drive and some.
            for (i, d) in fresh.drive_histograms.iter_mut().enumerate() {
                d.exchange.saturating_record(2_000_000 + i as u64);
            }
            fresh.histograms.exchange.saturating_record(2_000_000);
            let t = Instant::now();
            let (counters, pending) = published.hand_over();
            counters.copy_counters_from(&stats);
            if let Some(pending) = pending {
                std::mem::swap(pending, &mut fresh);
            }
            now.push(t.elapsed().as_secs_f64() * 1e6);
            // The reader's side (housekeeping, not the bus thread).
            let t = Instant::now();
            let _ = published.read();
            merge.push(t.elapsed().as_secs_f64() * 1e6);
        }
        let (before, now, merge) = (median(before), median(now), median(merge));
        println!(
            "   {drives:2} drives: histograms copied {before:.1} us, handed over {now:.2} us: {:.0}x less for the bus thread (the reader merges them in {merge:.1} us)",
            before / now.max(1e-3)
        );
    }
}

/// Part 6: the bus thread's CPU per exchange on the virtual clock (no waiting: every sleep
/// returns at once), median of 5 runs of 20000 exchanges after 2000 to warm up.
fn master_work() {
    println!(
        "== master work per exchange on the virtual clock, PKW 4 + PZD 2 at 19200 baud: bus thread CPU, median of 5 runs of 20000 exchanges"
    );
    println!(
        "   (the simulated drives run in the same thread: their share, the time inside the wire's flush and send where every drive's model moves, is shown apart, and the engine's is the rest, to compare two builds whose simulators differ)"
    );
    for drives in [4u8, 31] {
        let exchanges = u32::try_from(uss_benches::rounds(20_000, 200)).expect("rounds");
        let mut runs: Vec<Work> = (0..5).map(|_| virtual_run(drives, exchanges)).collect();
        runs.sort_by(|a, b| a.engine.total_cmp(&b.engine));
        let median = runs[2];
        println!(
            "   {drives:2} drives: {:.2} us per exchange, of which the simulated drives {:.2} us and the engine {:.2} us (engine runs from {:.2} to {:.2})",
            median.thread, median.drives, median.engine, runs[0].engine, runs[4].engine
        );
    }
}

/// One run of [`virtual_run`]: CPU per exchange, us.
#[derive(Debug, Clone, Copy)]
struct Work {
    /// The bus thread's CPU.
    thread: f64,
    /// Of which inside the simulated drives' models.
    drives: f64,
    /// The rest: the engine's own work (and reading the wire's bytes).
    engine: f64,
}

/// The virtual wire with the time spent inside its `flush_input` and `send` (where every
/// simulated drive's model moves up to the time and the addressed one answers) summed:
/// simulator work, not the engine's. `recv` hands over one byte already computed.
struct Timed {
    inner: SimTransport,
    in_drives: Duration,
}

impl uss_engine::Transport for Timed {
    fn flush_input(&mut self, now: Duration) -> Result<(), uss_engine::TransportError> {
        let t = Instant::now();
        let r = self.inner.flush_input(now);
        self.in_drives += t.elapsed();
        r
    }

    fn send(
        &mut self,
        bytes: &[u8],
        now: Duration,
    ) -> Result<Duration, uss_engine::TransportError> {
        let t = Instant::now();
        let r = self.inner.send(bytes, now);
        self.in_drives += t.elapsed();
        r
    }

    fn recv(
        &mut self,
        deadline: Duration,
        clock: &mut impl uss_engine::Clock,
    ) -> Result<Option<uss_engine::Rx>, uss_engine::TransportError> {
        self.inner.recv(deadline, clock)
    }
}

/// One engine with `drives` simulated drives on the virtual clock: its thread's CPU per
/// exchange over `exchanges` of them, and the simulated drives' share of it.
fn virtual_run(drives: u8, exchanges: u32) -> Work {
    let (transport, setups, timing) = simulated_drives(drives, 19_200, 2);
    let config = engine_config(timing, setups, false);
    let timed = Timed {
        inner: transport,
        in_drives: Duration::ZERO,
    };
    let (mut engine, _handle, events) = Engine::new(config, timed, VirtualClock::new());
    for _ in 0..2000 {
        engine.poll_next().expect("virtual wire never fails");
        while events.try_recv().is_ok() {}
    }
    let before = engine.transport().in_drives;
    let start = thread_cpu();
    for _ in 0..exchanges {
        engine.poll_next().expect("virtual wire never fails");
    }
    let cpu = thread_cpu().saturating_sub(start);
    let in_drives = engine.transport().in_drives.saturating_sub(before);
    let per = |d: Duration| d.as_secs_f64() * 1e6 / f64::from(exchanges);
    Work {
        thread: per(cpu),
        drives: per(in_drives),
        engine: per(cpu.saturating_sub(in_drives)),
    }
}

/// Exchanges on the bus per read for a client that reads back to back (one read at a time, the
/// next submitted as soon as the last one's result is in) from drive 1 of 4: the same
/// parameter each time (`same`) or two in turn.
fn exchanges_per_read(param_priority: bool, same: bool, reads: u64) -> f64 {
    let (transport, setups, timing) = simulated_drives(4, 19_200, 2);
    let mut config = engine_config(timing, setups, false);
    config.param_priority = param_priority;
    let (mut engine, handle, events) = Engine::new(config, transport, VirtualClock::new());
    let drive = Address::new(1).expect("address");
    for _ in 0..100 {
        engine.poll_next().expect("virtual wire never fails");
        while events.try_recv().is_ok() {}
    }
    let start = engine.counters().exchanges;
    for id in 0..reads {
        let pnu = if same || id % 2 == 0 { 1082 } else { 1080 };
        let task = ParamTask::read(Pnu::from_u16(pnu), None);
        handle
            .submit(Job {
                id,
                address: drive,
                task,
            })
            .expect("submitted");
        let result = loop {
            engine.poll_next().expect("virtual wire never fails");
            while events.try_recv().is_ok() {}
            if let Some(r) = handle.recv_result(Duration::ZERO) {
                break r;
            }
        };
        assert!(matches!(result.outcome, Ok(Ok(_))), "{result:?}");
    }
    (engine.counters().exchanges - start) as f64 / reads as f64
}

fn fresh_task_cost() {
    println!(
        "== the fresh-task rule's cost: exchanges on the bus per parameter read, one client reading drive 1 of 4 back to back, PKW 4 + PZD 2 at 19200 baud, 2000 reads each"
    );
    for priority in [false, true] {
        let reads = uss_benches::rounds(2000, 50);
        let same = exchanges_per_read(priority, true, reads);
        let other = exchanges_per_read(priority, false, reads);
        println!(
            "   param_priority = {priority:5}: the same parameter {same:.2}, two in turn {other:.2} exchanges per read: the rule costs {:.2} exchanges per repeated read ({:.2}x)",
            same - other,
            same / other
        );
    }
}

fn main() {
    let parts = Parts::from_args();
    let wanted = |name: &str| parts.wanted(name);
    if wanted("efficiency") {
        efficiency();
    }
    if wanted("turnaround") {
        turnaround();
    }
    if wanted("capture") {
        capture_cost();
    }
    if wanted("publish") {
        publish_cost();
    }
    if wanted("work") {
        master_work();
    }
    if wanted("fresh") {
        fresh_task_cost();
    }
}
