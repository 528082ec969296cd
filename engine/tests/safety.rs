//! Safety telegrams on full-size buses (issue 21), on the virtual clock against the simulator's
//! virtual wire: bounds in exchanges, whatever the bus size.
//!
//! - an operator's stop reaches its drive in the next telegram on the wire, not at the drive's
//!   turn in the circulating list;
//! - a watchdog trip reaches its drive within one exchange of the deadline;
//! - a re-arm reaches its drive in the next telegram;
//! - a rogue controller that flips its drive between run, release and re-arm as fast as it can
//!   does not starve the others: their poll period at most doubles;
//! - a ussd paused past the watchdog time (SIGSTOP, a suspended machine) latches on resuming
//!   instead of sending the pre-pause ON, and a sample older than the watchdog is not fresh;
//! - an offline drive probed once a minute gets an operator's stop in the next telegram.
#![allow(clippy::unwrap_used)]

use std::time::Duration;
use uss_drive_sim::SimTransport;
use uss_drive_sim::{DriveConfig, Fault, SimBus, VirtualWire};
use uss_engine::control::Control;
use uss_engine::{DriveSetup, Engine, EngineConfig, EngineHandle, VirtualClock};
use uss_protocol::telegram::{Layout, PkwMode, PzdCount};
use uss_protocol::{Address, Baud, Stw1, Timing};
use uss_shm_types::{LatchReason, PzdOutput, StopCommand};

type TestEngine = Engine<SimTransport, VirtualClock>;

const RUN: [u16; 2] = [0x047F, 0x2000];
const OFF1: [u16; 2] = [0x047E, 0];

fn addr(a: u8) -> Address {
    Address::new(a).unwrap()
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn timing(baud: u32) -> Timing {
    Timing::new(Baud::new(baud).unwrap())
}

struct Bench {
    engine: TestEngine,
    handle: EngineHandle,
    baud: u32,
}

/// Drives 1..=`n` at `baud`, PKW 4 + PZD 2, the simulated drives answering after 1 ms (or the
/// earliest they may).
fn bench_with(n: u8, baud: u32, cfg: impl FnOnce(&mut EngineConfig)) -> Bench {
    bench_of(n, baud, |_| {}, cfg)
}

/// Like [`bench_with`], with each simulated drive as `sim` makes it.
fn bench_of(
    n: u8,
    baud: u32,
    sim: impl Fn(&mut DriveConfig),
    cfg: impl FnOnce(&mut EngineConfig),
) -> Bench {
    let layout = Layout::new(PkwMode::Four, PzdCount::new(2).unwrap());
    let mut bus = SimBus::new(11);
    let mut setups = Vec::new();
    for a in 1..=n {
        let mut drive = DriveConfig::new(addr(a), layout);
        sim(&mut drive);
        bus.add(drive).unwrap();
        setups.push(DriveSetup::new(addr(a), layout));
    }
    let mut config = EngineConfig {
        timing: timing(baud),
        response_timeout: ms(20),
        retries: 2,
        offline_after: 1,
        offline_probe: ms(500),
        cycle_time: None,
        param_timeout: ms(2000),
        echo: false,
        mailbox_depth: 16,
        publish_every: ms(100),
        param_priority: false,
        safety_first: true,
        rx_latency: Duration::ZERO,
        capture: false,
        drives: setups,
    };
    cfg(&mut config);
    let wire = VirtualWire::new(bus, timing(baud));
    let (engine, handle, _events) =
        Engine::new(config, SimTransport::new(wire), VirtualClock::new());
    Bench {
        engine,
        handle,
        baud,
    }
}

impl Bench {
    fn now(&self) -> Duration {
        uss_engine::Clock::now(self.engine.clock())
    }

    /// One telegram on the wire (with its reply); the drive polled.
    fn exchange(&mut self) -> u8 {
        self.engine.poll_next().unwrap().unwrap().get()
    }

    /// Polls for `d` of bus time, refreshing `outputs` before every poll like live controllers.
    fn run_for(&mut self, d: Duration, outputs: &[(u8, [u16; 2])]) {
        let until = self.now() + d;
        while self.now() < until {
            self.refresh(outputs);
            self.engine.poll_next().unwrap();
        }
    }

    fn refresh(&self, outputs: &[(u8, [u16; 2])]) {
        for (a, words) in outputs {
            self.handle.set_output(addr(*a), words).unwrap();
        }
    }

    fn stw1(&self, a: u8) -> Stw1 {
        self.engine
            .transport()
            .wire()
            .bus()
            .drive(addr(a))
            .unwrap()
            .stw1()
    }

    fn control(&self, a: u8) -> Control {
        self.engine.stats().drive(addr(a)).unwrap().control
    }

    /// The worst case of one exchange at this baud rate (USS.md section 4).
    fn exchange_time(&self) -> Duration {
        timing(self.baud).worst_case_transaction(12, 12)
    }

    /// Drive `a` armed and running; every other drive's controller refreshes OFF1.
    fn running(n: u8, baud: u32, a: u8) -> Bench {
        let mut b = bench_with(n, baud, |_| {});
        let others: Vec<(u8, [u16; 2])> = (1..=n).filter(|&d| d != a).map(|d| (d, OFF1)).collect();
        let mut all = others.clone();
        all.push((a, OFF1));
        // Two cycles: every drive online and armed.
        while b.engine.stats().bus.cycles < 2 {
            b.run_for(ms(1), &all);
        }
        let mut all = others;
        all.push((a, RUN));
        while b.stw1(a).bits() != 0x047F {
            b.run_for(ms(1), &all);
        }
        assert_eq!(b.control(a), Control::Live);
        b
    }
}

/// Telegrams until drive `a` has `stw1`, at most `limit`.
fn telegrams_until(
    b: &mut Bench,
    a: u8,
    stw1: Stw1,
    refresh: &[(u8, [u16; 2])],
    limit: usize,
) -> usize {
    for n in 1..=limit {
        b.refresh(refresh);
        b.exchange();
        if b.stw1(a) == stw1 {
            return n;
        }
    }
    panic!("drive {a} did not get {stw1:?} within {limit} telegrams")
}

#[test]
fn an_operator_stop_reaches_its_drive_in_the_next_telegram_whatever_the_bus_size() {
    for (n, baud) in [(4, 9600), (16, 19200), (31, 9600)] {
        let a = n / 2 + 1;
        let mut worst = 0;
        // At every phase of the circulating list.
        for phase in 0..usize::from(n) {
            let mut b = Bench::running(n, baud, a);
            let run = [(a, RUN)];
            for _ in 0..phase {
                b.refresh(&run);
                b.exchange();
            }
            b.handle
                .stop_drive(Some(addr(a)), StopCommand::Off1, 7)
                .unwrap();
            // The controller keeps publishing "run": the operator wins.
            let took = telegrams_until(&mut b, a, Stw1::READY, &run, 2 * usize::from(n));
            worst = worst.max(took);
        }
        println!(
            "{n} drives at {baud} baud: an operator stop reached its drive after at most {worst} telegrams"
        );
        assert_eq!(worst, 1, "{n} drives at {baud} baud");
    }
}

#[test]
fn a_watchdog_trip_reaches_its_drive_within_one_exchange_of_the_deadline() {
    for (n, baud) in [(4, 9600), (31, 9600)] {
        let a = n / 2 + 1;
        for phase in [0, usize::from(n) / 3, usize::from(n) - 1] {
            let mut b = Bench::running(n, baud, a);
            for _ in 0..phase {
                b.refresh(&[(a, RUN)]);
                b.exchange();
            }
            // The controller's last sample: it freezes.
            b.refresh(&[(a, RUN)]);
            let frozen = b.now();
            let deadline = frozen + ms(100);
            while b.stw1(a) != Stw1::READY {
                assert!(b.now() < deadline + ms(5000), "never tripped");
                b.exchange();
            }
            let late = b.now().saturating_sub(deadline);
            println!(
                "{n} drives at {baud} baud, phase {phase}: the safe command reached the drive \
                 {late:?} after the watchdog deadline (one exchange: {:?})",
                b.exchange_time()
            );
            // The exchange in progress at the deadline, then the drive's own.
            assert!(late <= b.exchange_time() * 2, "{late:?} late");
            assert!(matches!(
                b.control(a),
                Control::Latched(l) if l.reason == LatchReason::Stale
            ));
        }
    }
}

#[test]
fn a_re_arm_reaches_its_drive_in_the_next_telegram() {
    let (n, a) = (31, 16);
    let mut b = Bench::running(n, 9600, a);
    b.handle
        .stop_drive(Some(addr(a)), StopCommand::Off2, 7)
        .unwrap();
    telegrams_until(&mut b, a, Stw1::COAST, &[], 2 * usize::from(n));
    // Right after the drive's turn, the controller re-arms it with OFF1 naming the latch.
    while b.exchange() != a {}
    b.handle.set_output(addr(a), &OFF1).unwrap();
    b.exchange();
    assert_eq!(b.control(a), Control::Live);
    assert_eq!(b.stw1(a), Stw1::READY);
}

#[test]
fn a_rogue_controller_flipping_its_drive_does_not_starve_the_others() {
    let n = 8;
    let mut b = Bench::running(n, 19200, 1);
    let mut polled = Vec::new();
    for i in 0..800 {
        // Run, release, re-arm, run, ... one change per telegram.
        match i % 3 {
            0 => b.handle.set_output(addr(1), &RUN).unwrap(),
            1 => b.handle.release(addr(1)).unwrap(),
            _ => b.handle.set_output(addr(1), &OFF1).unwrap(),
        }
        polled.push(b.exchange());
    }
    let longest = (2..=n)
        .map(|a| {
            let at: Vec<usize> = polled
                .iter()
                .enumerate()
                .filter(|&(_, &p)| p == a)
                .map(|(i, _)| i)
                .collect();
            at.windows(2)
                .map(|w| w[1] - w[0])
                .max()
                .unwrap_or(usize::MAX)
        })
        .max()
        .unwrap();
    println!(
        "a rogue controller on drive 1: the others wait at most {longest} telegrams (8 per cycle)"
    );
    assert!(longest <= 2 * usize::from(n), "{longest}");
}

#[test]
fn a_paused_ussd_latches_on_resuming_instead_of_sending_the_old_on() {
    let a = 2;
    let mut b = Bench::running(4, 19200, a);
    // ussd is paused for 2 s (SIGSTOP); the controller goes on publishing "run" meanwhile.
    b.engine.clock_mut().advance(ms(2000));
    b.refresh(&[(a, RUN)]);
    b.exchange();
    assert!(
        matches!(b.control(a), Control::Latched(l) if l.reason == LatchReason::Paused),
        "{:?}",
        b.control(a)
    );
    assert_ne!(b.stw1(a).bits(), 0x047F, "the pre-pause ON went out");
}

#[test]
fn a_sample_older_than_the_watchdog_time_is_not_fresh() {
    let a = 2;
    let mut b = Bench::running(4, 19200, a);
    b.run_for(ms(500), &[(a, RUN)]);
    // A sample stamped 300 ms ago (a controller paused after writing it, or a queue): stale.
    let now_ns = u64::try_from(b.now().as_nanos()).unwrap();
    let old = PzdOutput::from_words(&RUN, 1 << 40, now_ns - 300_000_000, 42)
        .unwrap()
        .naming(0);
    b.engine.clock_mut().advance(ms(60));
    b.handle.publish_sample(addr(a), old).unwrap();
    for _ in 0..4 {
        b.exchange();
    }
    assert!(
        matches!(b.control(a), Control::Latched(l) if l.reason == LatchReason::Stale),
        "{:?}",
        b.control(a)
    );
}

#[test]
fn an_offline_drive_probed_once_a_minute_gets_a_stop_in_the_next_telegram() {
    let a = 3;
    let mut b = bench_with(4, 19200, |c| c.offline_probe = Duration::from_secs(60));
    b.run_for(ms(200), &[(a, OFF1)]);
    b.run_for(ms(100), &[(a, RUN)]);
    assert_eq!(b.stw1(a).bits(), 0x047F);
    // The drive stops answering, but still hears the line (a broken TX pair): ussd marks it
    // offline and probes it once a minute.
    b.engine
        .transport_mut()
        .wire_mut()
        .bus_mut()
        .faults_mut(addr(a))
        .unwrap()
        .set_probability(Fault::DropReply, 1.0);
    while b.engine.stats().drive(addr(a)).unwrap().online {
        b.run_for(ms(1), &[(a, RUN)]);
    }
    b.handle
        .stop_drive(Some(addr(a)), StopCommand::Off2, 7)
        .unwrap();
    let took = telegrams_until(&mut b, a, Stw1::COAST, &[(a, RUN)], 100);
    assert_eq!(took, 1);
}

/// Drives 5 and 9 ignore broadcasts (as S110 and G120 firmware 4 do) and are configured so.
const DEAF: [u8; 2] = [5, 9];

#[test]
fn a_stop_of_every_drive_reaches_them_all_within_one_telegram_and_one_exchange() {
    let n = 31;
    let mut b = bench_of(
        n,
        9600,
        |d| d.takes_broadcasts = !DEAF.contains(&d.address.get()),
        |c| {
            for d in &mut c.drives {
                d.broadcast = !DEAF.contains(&d.address.get());
            }
        },
    );
    let all: Vec<(u8, [u16; 2])> = (1..=n).map(|d| (d, OFF1)).collect();
    while b.engine.stats().bus.cycles < 2 {
        b.run_for(ms(1), &all);
    }
    let run: Vec<(u8, [u16; 2])> = (1..=n).map(|d| (d, RUN)).collect();
    while (1..=n).any(|a| b.stw1(a).bits() != 0x047F) {
        b.run_for(ms(1), &run);
    }
    b.handle.stop_drive(None, StopCommand::Off2, 7).unwrap();
    // The next step on the wire: the broadcast, then the first drive that did not hear it.
    b.refresh(&run);
    let first = b.exchange();
    assert_eq!(first, DEAF[0]);
    let missing: Vec<u8> = (1..=n).filter(|&a| b.stw1(a) != Stw1::COAST).collect();
    assert_eq!(missing, DEAF[1..], "after one broadcast and one exchange");
    assert_eq!(b.engine.stats().bus.broadcasts, 1);
    // The other deaf drive, then each drive confirms in its own exchange, out of turn.
    b.refresh(&run);
    assert_eq!(b.exchange(), DEAF[1]);
    let mut confirmed = vec![];
    for _ in 0..n - 2 {
        b.refresh(&run);
        confirmed.push(b.exchange());
    }
    let mut expected: Vec<u8> = (1..=n).filter(|a| !DEAF.contains(a)).collect();
    confirmed.sort_unstable();
    expected.sort_unstable();
    assert_eq!(confirmed, expected);
    for a in 1..=n {
        assert_eq!(b.stw1(a), Stw1::COAST, "drive {a}");
        assert!(matches!(
            b.control(a),
            Control::Latched(l) if l.reason == LatchReason::Override && l.command == StopCommand::Off2
        ));
    }
}

#[test]
fn a_broadcast_never_weakens_a_drive_that_has_a_stronger_stop() {
    let mut b = Bench::running(4, 19200, 2);
    b.handle
        .stop_drive(Some(addr(3)), StopCommand::Off2, 7)
        .unwrap();
    telegrams_until(&mut b, 3, Stw1::COAST, &[(2, RUN)], 2);
    // OFF1 for every drive: drive 3 would hear OFF1 in a broadcast, so none goes out; each
    // drive gets its own telegram, drive 3 keeps OFF2.
    b.handle.stop_drive(None, StopCommand::Off1, 7).unwrap();
    for _ in 0..8 {
        b.refresh(&[(2, RUN)]);
        b.exchange();
        assert_eq!(b.stw1(3), Stw1::COAST);
    }
    assert_eq!(b.engine.stats().bus.broadcasts, 0);
    assert_eq!(b.stw1(2), Stw1::READY);
}
