//! The bus engine with its real serial transport, against `uss-sim --pty` in a separate process:
//! a drive brought from S1 to running through PZD, parameters read and written (RAM and EEPROM),
//! fault injection on a second drive, and counters that agree with the simulator's.
#![allow(clippy::unwrap_used)]

use std::time::{Duration, Instant};
use uss_engine::{DriveSetup, Engine, EngineConfig, EngineHandle, Job, MonotonicClock};
use uss_integration_tests::SimProcess;
use uss_protocol::telegram::{Layout, PkwMode, PzdCount};
use uss_protocol::{
    Address, Baud, DriveState, ParamTask, Pnu, Setpoint, Storage, Stw1, Timing, Value, Zsw1,
};
use uss_serial::{SerialOptions, SerialTransport};
use uss_shm_types::{Answer, DriveError, ItemOutcome as Outcome};

fn addr(a: u8) -> Address {
    Address::new(a).unwrap()
}

fn setup(a: u8, pkw: PkwMode, pzd: usize) -> DriveSetup {
    DriveSetup {
        watchdog: Duration::from_millis(200),
        ..DriveSetup::new(addr(a), Layout::new(pkw, PzdCount::new(pzd).unwrap()))
    }
}

fn ask(handle: &EngineHandle, id: u64, a: u8, task: ParamTask) -> Outcome {
    handle
        .submit(Job {
            id,
            address: addr(a),
            task,
        })
        .unwrap();
    let r = handle
        .recv_result(Duration::from_secs(5))
        .expect("a result within 5 s");
    assert_eq!(r.job.id, id);
    r.outcome
}

/// Refreshes drive 1's output for `d`, as a controller would.
fn control(handle: &EngineHandle, words: [u16; 2], d: Duration) {
    let until = Instant::now() + d;
    while Instant::now() < until {
        handle.set_output(addr(1), &words).unwrap();
        std::thread::sleep(Duration::from_millis(10));
    }
}

type BusThread = std::thread::JoinHandle<Result<(), uss_engine::TransportError>>;

/// The engine on the serial transport to `path`, running in its own thread.
fn start_engine(path: &str) -> (EngineHandle, BusThread) {
    let baud = Baud::new(115_200).unwrap();
    let options = SerialOptions {
        baud,
        kernel_rs485: false,
        rs485_settings: uss_serial::Rs485Wanted::default(),
        low_latency: true,
        rx_latency: core::time::Duration::ZERO,
    };
    let (transport, report) = SerialTransport::open(std::path::Path::new(path), &options).unwrap();
    assert!(report.pseudo_terminal);
    let config = EngineConfig {
        timing: Timing::new(baud),
        response_timeout: Duration::from_millis(20),
        retries: 2,
        offline_after: 3,
        offline_probe: Duration::from_millis(200),
        cycle_time: None,
        param_timeout: Duration::from_secs(2),
        echo: false,
        mailbox_depth: 16,
        publish_every: Duration::from_millis(50),
        param_priority: false,
        safety_first: true,
        rx_latency: Duration::ZERO,
        capture: false,
        drives: vec![setup(1, PkwMode::Four, 2), setup(2, PkwMode::Variable, 4)],
    };
    let (mut engine, handle, _events) = Engine::new(config, transport, MonotonicClock::new());
    let bus = std::thread::spawn(move || engine.run());
    (handle, bus)
}

/// Drive 2 (variable PKW, faults on): an EEPROM write through busy replies, a refused write,
/// and reads that all come back right despite dropped and corrupted replies.
fn parameters_through_faults(handle: &EngineHandle) {
    let two_seconds = Value::from_f32(2.0);
    let eeprom = ParamTask::Write {
        pnu: Pnu::from_u16(1121),
        value: two_seconds,
        storage: Storage::RamAndEeprom,
    };
    assert_eq!(
        ask(handle, 4, 2, eeprom),
        Ok(Ok(Answer::Value(two_seconds)))
    );
    // P2014 needs access level 3 (P0003 = 1 here): the drive's error 204 reaches us.
    let p2014 = ParamTask::Write {
        pnu: Pnu::from_u16(2014),
        value: Value::Word(500),
        storage: Storage::Ram,
    };
    assert_eq!(
        ask(handle, 5, 2, p2014),
        Ok(Err(DriveError::Refused(
            uss_protocol::ErrorNumber::AccessLevelTooLow
        )))
    );
    for id in 10..40 {
        let outcome = ask(
            handle,
            id,
            2,
            ParamTask::Read {
                pnu: Pnu::from_u16(2000),
            },
        );
        assert_eq!(
            outcome,
            Ok(Ok(Answer::Value(Value::from_f32(50.0)))),
            "job {id}"
        );
    }
    let a0 = ask(
        handle,
        50,
        2,
        ParamTask::ReadArrayLen {
            pnu: Pnu::from_u16(947),
        },
    );
    assert_eq!(a0, Ok(Ok(Answer::ElementCount(8))));
}

#[test]
fn engine_drives_a_simulated_drive_over_a_real_pty() {
    let sim = SimProcess::start(&[
        "--baud",
        "115200",
        "--drive",
        "1:pkw=4,pzd=2",
        "--drive",
        "2:pkw=127,pzd=4,drop=0.05,bcc=0.05,eeprom-busy=2",
        "--seed",
        "5",
    ]);
    let (handle, bus) = start_engine(&sim.path);

    // S1 -> S2 with OFF1, then run at 50 % (25 Hz with P2000 = 50 Hz).
    control(&handle, [Stw1::READY.bits(), 0], Duration::from_millis(200));
    let (input, online) = handle.input(addr(1)).unwrap();
    assert!(online);
    let zsw1 = Zsw1::from_bits_retain(input.unwrap().as_slice()[0]);
    assert_eq!(DriveState::from_zsw1(zsw1), DriveState::ReadyToSwitchOn);
    // Ramp-up time 1 s through the parameter channel first (RAM), then read it back.
    let one_second = Value::from_f32(1.0);
    let write = ParamTask::Write {
        pnu: Pnu::from_u16(1120),
        value: one_second,
        storage: Storage::Ram,
    };
    assert_eq!(ask(&handle, 1, 1, write), Ok(Ok(Answer::Value(one_second))));
    assert_eq!(
        ask(
            &handle,
            2,
            1,
            ParamTask::Read {
                pnu: Pnu::from_u16(1120)
            }
        ),
        Ok(Ok(Answer::Value(one_second)))
    );
    control(
        &handle,
        [Stw1::RUN.bits(), 0x2000],
        Duration::from_millis(1300),
    );
    let input = handle.input(addr(1)).unwrap().0.unwrap();
    let zsw1 = Zsw1::from_bits_retain(input.as_slice()[0]);
    assert_eq!(DriveState::from_zsw1(zsw1), DriveState::OperationEnabled);
    assert!(zsw1.contains(Zsw1::AT_SETPOINT), "{zsw1:?}");
    assert_eq!(
        input.as_slice()[1],
        Setpoint::from_hz(25.0, 50.0).word(),
        "25 Hz"
    );
    // r0021 agrees while running.
    let r0021 = ask(
        &handle,
        3,
        1,
        ParamTask::Read {
            pnu: Pnu::from_u16(21),
        },
    );
    assert_eq!(r0021, Ok(Ok(Answer::Value(Value::from_f32(25.0)))));

    parameters_through_faults(&handle);

    handle.stop();
    bus.join().unwrap().unwrap();
    let stats = handle.stats();
    let d1 = stats.drive(addr(1)).unwrap().counters;
    let d2 = stats.drive(addr(2)).unwrap().counters;
    // No faults on drive 1; a reply can still miss its 20 ms on a busy machine.
    assert!(d1.rejected * 100 <= d1.requests, "{d1:?}");
    assert!(
        d2.timeouts + d2.bcc > 0,
        "faults were injected on drive 2: {d2:?}"
    );
    let out = sim.stop();
    // Every telegram the master sent to drive 1 arrived intact (the simulator's counters are u16).
    let line = out.lines().find(|l| l.contains("drive  1:")).unwrap();
    assert!(
        line.contains(&format!("good {} rejected 0", d1.requests % 65536)),
        "{line} vs {d1:?}"
    );
    assert!(
        line.contains("S5 OFF1 ramp-down") || line.contains("S2 ready to switch on"),
        "OFF1 at shutdown: {line}"
    );
}
