//! The client API and `ussctl` against a real `ussd` in its own process, on a simulated bus.
//!
//! Every test starts its own ussd (`ussd --config FILE`, `device = "sim"`, drives 1, 2 and 3)
//! on a bus named after this process and the test, so parallel test runs never share a
//! service; the tests here take turns (two cores, one real-time bus thread each) and stop
//! their ussd with SIGTERM, so it removes its services. ussctl runs as a separate process.
#![allow(clippy::unwrap_used, clippy::float_cmp)]

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Output, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use uss_client::DriveError;
use uss_client::uss_protocol::ErrorNumber;
use uss_client::{
    Bus, Catalogue, ClientError, ControlOptions, CycleEvent, DataType, DriveState, LatchReason,
    ParamError, ParamItem, ParamRequest, RequestError, StopCommand, Typed, Value,
};
use uss_integration_tests::{addr, param, param_at};
use uss_integration_tests::{binary, read, terminate};

/// One ussd at a time: each runs a paced bus thread, and the machine has two cores.
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(PoisonError::into_inner)
}

/// A ussd process on a bus of its own; stopped with SIGTERM when dropped.
struct Ussd {
    child: Child,
    bus: String,
    config: std::path::PathBuf,
}

impl Ussd {
    /// Starts ussd with drives 1, 2, 3 and waits until every drive answered.
    fn start() -> Ussd {
        Self::start_with("")
    }

    /// Like [`Ussd::start`], with drive 3 simulated as `drive3_sim` says (the keys of its
    /// `[bus.drive.sim]` table, as an inline table's contents).
    fn start_with(drive3_sim: &str) -> Ussd {
        Self::start_custom("", drive3_sim)
    }

    /// Like [`Ussd::start_with`], with more keys for drive 1's table (`key = value` lines).
    fn start_custom(drive1: &str, drive3_sim: &str) -> Ussd {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let bus = format!(
            "t{}n{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let config = std::env::temp_dir().join(format!("ussd-ipc-client-{bus}.toml"));
        std::fs::write(
            &config,
            format!(
                "[[bus]]\nname = \"{bus}\"\ndevice = \"sim\"\n\n\
                 [[bus.drive]]\naddress = 1\n{drive1}\n\n[[bus.drive]]\naddress = 2\n\n\
                 [[bus.drive]]\naddress = 3\nsim = {{ {drive3_sim} }}\n"
            ),
        )
        .unwrap();
        let child = Command::new(binary("uss-master", "ussd"))
            .arg("--config")
            .arg(&config)
            .args(["--summary-every", "3600"])
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        let mut ussd = Ussd { child, bus, config };
        let deadline = Instant::now() + Duration::from_secs(20);
        let bus = loop {
            match Bus::open(&ussd.bus) {
                Ok(bus) => break bus,
                Err(ClientError::NotRunning { .. }) if Instant::now() < deadline => {
                    assert!(
                        ussd.child.try_wait().unwrap().is_none(),
                        "ussd ended before it created its services"
                    );
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => panic!("{e}"),
            }
        };
        for a in [1, 2, 3] {
            bus.watch(addr(a))
                .unwrap()
                .wait_for(Duration::from_secs(10), "a reply", |i| {
                    i.online != 0 && i.sequence > 0
                })
                .unwrap();
        }
        // Diagnostics lag the images (the engine hands its counters over every 250 ms, ussd
        // republishes them every 100 ms): wait until they show the replies too.
        while bus
            .drives()
            .iter()
            .any(|&a| bus.diag(addr(a)).unwrap().counters.good == 0)
        {
            assert!(Instant::now() < deadline, "no diagnostics published");
            std::thread::sleep(Duration::from_millis(20));
        }
        ussd
    }

    fn bus(&self) -> Bus {
        Bus::open(&self.bus).unwrap()
    }

    /// ussctl's exit code, stdout and stderr.
    fn ussctl_said(&self, args: &[&str]) -> (Option<i32>, String, String) {
        let out = self.ussctl(args);
        (out.status.code(), text(&out.stdout), text(&out.stderr))
    }

    fn ussctl(&self, args: &[&str]) -> Output {
        Command::new(binary("ussctl", "ussctl"))
            .args(["--bus", &self.bus])
            .args(args)
            .output()
            .unwrap()
    }
}

impl Drop for Ussd {
    fn drop(&mut self) {
        terminate(&mut self.child);
        let _ = std::fs::remove_file(&self.config);
    }
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn client_reads_inputs_status_diagnostics_and_cycle_events() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    assert_eq!(bus.drives(), [addr(1), addr(2), addr(3)]);

    // No controller: every drive gets the safe command OFF1, which leads it S1 -> S2.
    let watch = bus.watch(addr(2)).unwrap();
    watch
        .wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(2))
        .unwrap();
    let first = watch.latest();
    assert_eq!((first.online, first.word_count, first.hiw), (1, 2, 0));
    assert_eq!(watch.actual_hz(), 0.0);
    let later = watch.wait_exchanges(3, Duration::from_secs(2)).unwrap();
    assert!(later.timestamp_ns > first.timestamp_ns);
    assert!(later.age_ns > 0, "the update period is published");

    let events = bus.cycle_listener().unwrap();
    assert!(
        events
            .wait_for(CycleEvent::Exchange(2), Duration::from_secs(2))
            .unwrap()
    );
    assert!(
        events
            .wait_for(CycleEvent::CycleCompleted, Duration::from_secs(2))
            .unwrap()
    );
    assert!(
        events
            .wait_for(CycleEvent::StatusPublished, Duration::from_secs(2))
            .unwrap()
    );

    let status = bus.status().unwrap();
    assert_eq!((status.running, status.drive_count), (1, 3));
    // Timing percentiles leave ussd, not only means: p50 <= p99 <= p99.9 <= max, all measured.
    for q in [
        status.exchange_ns,
        status.response_delay_ns,
        status.turnaround_ns,
    ] {
        assert!(q[0] > 0 && q.windows(2).all(|w| w[0] <= w[1]), "{q:?}");
    }
    let out = ussd.ussctl(&["stats"]);
    assert!(
        text(&out.stdout).contains("  exchange        p50 "),
        "{}",
        text(&out.stdout)
    );
    assert!(status.cycles > 0 && status.good > 0, "{status:?}");
    let diag = bus.diag(addr(2)).unwrap();
    assert_eq!((diag.address, diag.online), (2, 1));
    assert!(
        diag.counters.good > 0 && diag.counters.requests >= diag.counters.good,
        "{diag:?}"
    );
    // Per drive too: each drive's own percentiles, within the bus's (to the drive histograms'
    // 6 %; the bus's were published at the same moment or later).
    for a in [1, 2, 3] {
        let d = bus.diag(addr(a)).unwrap();
        for q in [d.exchange_ns, d.response_delay_ns] {
            assert!(q[0] > 0 && q.windows(2).all(|w| w[0] <= w[1]), "{q:?}");
        }
        assert!(
            d.exchange_ns[3]
                <= status.exchange_ns[3].max(bus.status().unwrap().exchange_ns[3]) * 107 / 100,
            "drive {a}: {:?} vs the bus's {:?}",
            d.exchange_ns,
            status.exchange_ns
        );
    }
    let shown = text(&ussd.ussctl(&["stats"]).stdout);
    assert_eq!(
        shown.matches("  response delay  p50 ").count(),
        4,
        "the bus and each of its 3 drives: {shown}"
    );

    let unknown = bus.watch(addr(9)).unwrap_err();
    assert_eq!(
        unknown.to_string(),
        format!(
            "drive 9 is not on {} (ussd polls drives 1, 2, 3 there): use one of those or add it to ussd's configuration",
            ussd.bus
        )
    );
    assert!(matches!(
        bus.diag(addr(9)),
        Err(ClientError::UnknownDrive { address: 9, .. })
    ));
}

/// A bus nobody serves: the client says how to start ussd, or (issue 47, item 4: the package's
/// bus is `sim`, ussctl's default `bus0`) which buses ussd serves on this machine. Each case on a
/// shared-memory root of its own, so other tests' ussd processes are not in the list.
#[test]
fn client_without_ussd_is_told_how_to_start_it_or_which_buses_are_served() {
    let pid = std::process::id();
    let bus = format!("absent{pid}");
    assert!(
        Bus::open(&bus)
            .unwrap_err()
            .to_string()
            .starts_with(&format!("ussd is not running on {bus}"))
    );
    let root = format!("/dev/shm/uss-rt-absent-{pid}");
    let ussctl = |args: &[&str]| {
        Command::new(binary("ussctl", "ussctl"))
            .args(args)
            .env(uss_shm_types::service::ROOT_ENV, &root)
            .output()
            .unwrap()
    };
    let out = ussctl(&["--bus", &bus, "status"]);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(
        text(&out.stderr),
        format!(
            "ussctl: ussd is not running on {bus}: start it with `ussd` (or `ussd --config FILE`; \
             the package's service: `systemctl start ussd`)\n"
        )
    );
    let served = format!("here{pid}");
    let mut ussd = Command::new(binary("uss-master", "ussd"))
        .args(["--bus", &served, "--duration", "20"])
        .env(uss_shm_types::service::ROOT_ENV, &root)
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    let said = loop {
        let out = ussctl(&["--bus", &bus, "status"]);
        let said = text(&out.stderr);
        if said.contains("ussd serves") || std::time::Instant::now() > deadline {
            break said;
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    let _ = ussd.kill();
    let _ = ussd.wait();
    let _ = std::fs::remove_dir_all(&root);
    assert_eq!(
        said,
        format!(
            "ussctl: ussd is not running on {bus}; on this machine ussd serves {served}: name it \
             (ussctl --bus {served})\n"
        )
    );
}

#[test]
fn parameters_read_and_write_with_typed_values_and_drive_errors() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();

    // USS.md section 6: P1082 reads 0x4248_0000 = 50.0 Hz.
    assert_eq!(
        bus.read(addr(1), param(1082)),
        Ok(Value::Dword(0x4248_0000))
    );
    assert_eq!(bus.read_f32(addr(1), param(1082)), Ok(50.0));
    assert_eq!(bus.read_f32(addr(1), param(2000)), Ok(50.0), "P2000, paged");

    // P1120 ramp-up time: written as a float, read back.
    assert_eq!(
        bus.write(addr(1), param(1120), Value::from_f32(2.5), false),
        Ok(Value::Dword(2.5f32.to_bits()))
    );
    assert_eq!(bus.read_f32(addr(1), param(1120)), Ok(2.5));
    assert_eq!(
        bus.write(addr(1), param(1120), Value::from_f32(3.0), true),
        Ok(Value::from_f32(3.0)),
        "RAM + EEPROM"
    );
    assert_eq!(bus.read_f32(addr(1), param(1120)), Ok(3.0));

    // Arrays: r0947, the fault buffer, has 8 word elements, all empty.
    assert_eq!(
        bus.read_array_len(addr(1), uss_client::Pnu::from_u16(947)),
        Ok(8)
    );
    assert_eq!(bus.read(addr(1), param_at(947, 7)), Ok(Value::Word(0)));
    assert_eq!(bus.faults(addr(1)), Ok(vec![0; 8]));

    // Drive errors carry their number and name (USS.md section 6).
    let err = bus.read(addr(1), param(1999)).unwrap_err();
    assert_eq!(
        err,
        ParamError::Drive(DriveError::Refused(ErrorNumber::IllegalPnu))
    );
    assert_eq!(
        err.to_string(),
        "the drive refused the task with error 0: illegal parameter number"
    );
    assert_eq!(
        bus.read(addr(1), param_at(947, 8)),
        Err(ParamError::Drive(DriveError::Refused(
            ErrorNumber::FaultySubindex
        )))
    );
    assert_eq!(
        bus.write(addr(1), param_at(947, 0), Value::Word(1), false),
        Err(ParamError::Drive(DriveError::Refused(
            ErrorNumber::ValueNotChangeable
        )))
    );
    assert_eq!(
        bus.write(addr(1), param(1120), Value::Word(2), false),
        Err(ParamError::Drive(DriveError::Refused(
            ErrorNumber::WrongDataType
        )))
    );
    // P0927 (access level 2, so raise P0003 first) with bit 3 clear: no more changes over
    // USS (reply 8). It can lock ussd out: guarded, written only when marked unsafe.
    assert_eq!(
        bus.write(addr(3), param(927), Value::Word(15), false),
        Err(ParamError::Refused {
            error: uss_client::RequestError::Guarded,
            item: Some(0)
        })
    );
    assert_eq!(
        bus.write_with(addr(3), param(927), Value::Word(15), deliberate()),
        Err(ParamError::Drive(DriveError::Refused(
            ErrorNumber::AccessLevelTooLow
        )))
    );
    assert_eq!(
        bus.write(addr(3), param(3), Value::Word(3), false),
        Ok(Value::Word(3))
    );
    assert_eq!(
        bus.write_with(addr(3), param(927), Value::Word(0b0111), deliberate()),
        Ok(Value::Word(0b0111))
    );
    assert_eq!(
        bus.write(addr(3), param(1120), Value::from_f32(1.0), false),
        Err(ParamError::Drive(DriveError::NoChangeRights))
    );
}

/// A write of a guarded parameter, marked deliberate (`--unsafe`).
fn deliberate() -> uss_client::WriteOptions {
    uss_client::WriteOptions {
        unsafe_write: true,
        ..uss_client::WriteOptions::default()
    }
}

#[test]
fn a_batch_of_39_reads_gets_39_results_in_order() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    let pnus = [1082, 2000, 1120, 1121, 947];
    let items: Vec<_> = (0..39)
        .map(|i| match pnus[i % pnus.len()] {
            947 => read(947, Some((i % 8) as u8)),
            pnu => read(pnu, None),
        })
        .collect();
    let results = bus.batch(addr(2), &items);
    assert_eq!(results.len(), 39);
    for (i, r) in results.iter().enumerate() {
        let expected = match pnus[i % pnus.len()] {
            1082 | 2000 => Value::from_f32(50.0),
            1120 | 1121 => Value::from_f32(10.0),
            _ => Value::Word(0),
        };
        assert_eq!(r, &Ok(expected), "item {i}: {:?}", items[i]);
    }
    // Items that fail fail alone.
    let mixed = bus.batch(
        addr(2),
        &[read(1082, None), read(1999, None), read(2000, None)],
    );
    assert_eq!(
        mixed,
        [
            Ok(Value::from_f32(50.0)),
            Err(ParamError::Drive(DriveError::Refused(
                ErrorNumber::IllegalPnu
            ))),
            Ok(Value::from_f32(50.0))
        ]
    );
    // 40 items do not fit one request: refused on this side, for every item.
    let too_many = bus.batch(addr(2), &[read(1082, None); 40]);
    assert_eq!(too_many.len(), 40);
    assert!(too_many.iter().all(|r| *r
        == Err(ParamError::Refused {
            error: RequestError::BadCount,
            item: None
        })));
}

/// A batch is taken whole or not at all. An adversarial run sent six 39-item batches at once to
/// one drive (234 jobs for its mailbox of 64): the second ran items 1..25 and failed 26..39
/// with "queue full", so a batch of writes could end half applied. Each batch now ends all
/// answered, or refused as a whole (busy) with nothing of it run. A request for a drive ussd
/// does not serve is refused as a whole too, and every front-end hears "unknown drive" (C said
/// "refused": only Python mapped it).
#[test]
fn a_batch_runs_whole_or_is_refused_whole_and_an_unknown_drive_is_named() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    let items = vec![read(1082, None); 39];
    let batches: Vec<_> = std::thread::scope(|s| {
        let threads: Vec<_> = (0..6)
            .map(|_| {
                let (bus, items) = (&bus, &items);
                s.spawn(move || bus.try_batch(addr(1), items, false))
            })
            .collect();
        threads.into_iter().map(|t| t.join().unwrap()).collect()
    });
    let mut whole = 0;
    for (k, batch) in batches.iter().enumerate() {
        match batch {
            Ok(results) => {
                assert!(
                    results.iter().all(|r| *r == Ok(Value::from_f32(50.0))),
                    "batch {k} ran in part: {results:?}"
                );
                whole += 1;
            }
            Err(e) => assert_eq!(
                *e,
                ParamError::Refused {
                    error: RequestError::Busy,
                    item: None
                },
                "batch {k}"
            ),
        }
    }
    assert!(whole >= 1, "{batches:?}");
    let unknown = bus.read(addr(9), param(1082));
    assert!(
        matches!(
            unknown,
            Err(ParamError::Client(ClientError::UnknownDrive {
                address: 9,
                ..
            }))
        ),
        "{unknown:?}"
    );
}

#[test]
fn twelve_threads_sharing_one_bus_take_turns_and_every_request_is_answered() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    // Three times as many threads as a client port may have requests on their way: the client
    // queues the rest instead of failing them.
    let answers: Vec<Vec<Result<Value, ParamError>>> = std::thread::scope(|s| {
        let threads: Vec<_> = (0..12u8)
            .map(|k| {
                let bus = &bus;
                s.spawn(move || {
                    (0..20)
                        .map(|_| bus.read(addr(1 + k % 3), param(1082)))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        threads.into_iter().map(|t| t.join().unwrap()).collect()
    });
    for (k, a) in answers.iter().enumerate() {
        assert!(
            a.iter().all(|r| *r == Ok(Value::from_f32(50.0))),
            "thread {k}: {a:?}"
        );
    }
}

#[test]
fn bad_requests_are_answered_with_errors() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();

    // A drive ussd does not poll: refused as a whole, and named so, with the drives it polls.
    assert_eq!(
        bus.read(addr(9), param(1082)),
        Err(ParamError::Client(ClientError::UnknownDrive {
            bus: bus.name().to_owned(),
            address: 9,
            known: vec![1, 2, 3]
        }))
    );
    let out = ussd.ussctl(&["param", "read", "9", "1082"]);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(
        text(&out.stderr),
        format!(
            "ussctl: drive 9 P1082: drive 9 is not on {} (ussd polls drives 1, 2, 3 there): use one of those or add it to ussd's configuration\n",
            bus.name()
        )
    );

    // Malformed requests, sent as they are: each gets exactly one refusal.
    let good = ParamRequest::new(
        uss_client::uss_shm_types::Address::new(1).unwrap(),
        &[
            ParamItem::from(&read(1082, None)),
            ParamItem::from(&read(947, Some(1))),
        ],
    )
    .unwrap();
    let mut bad_index = good;
    bad_index.items[1].index = 300;
    let mut bad_version = good;
    bad_version.version = 0;
    let mut no_items = good;
    no_items.count = 0;
    let mut bad_address = good;
    bad_address.address = 40;
    let mut bad_task = good;
    bad_task.items[0].task = 0;
    // A subindex with a task that takes none, storage with a read: refused, not ignored.
    let mut index_on_read = good;
    index_on_read.items[0].index = 3;
    let mut storage_on_read = good;
    storage_on_read.items[1].storage = 1;
    for (request, error, item) in [
        (index_on_read, RequestError::BadSubindex, 0),
        (storage_on_read, RequestError::BadStorage, 1),
        (bad_index, RequestError::BadSubindex, 1),
        (bad_version, RequestError::Version, u8::MAX),
        (no_items, RequestError::BadCount, u8::MAX),
        (bad_address, RequestError::UnknownDrive, u8::MAX),
        (bad_task, RequestError::BadTask, 0),
    ] {
        let response = bus.send_request(&request).unwrap();
        assert_eq!(
            (response.error(), response.error_item, response.count),
            (Ok(error), item, 0),
            "{request:?}"
        );
    }
    // The engine is unaffected.
    assert_eq!(
        uss_client::params::response_results(&bus.send_request(&good).unwrap(), addr(1), 2),
        Ok(vec![Ok(Value::from_f32(50.0)), Ok(Value::Word(0))])
    );
}

/// ussd checks a request once, first: a malformed request that also writes a guarded
/// parameter is refused for what is wrong with it, not as guarded (the guards used to read the
/// items before they were checked).
#[test]
fn a_malformed_request_with_a_guarded_write_is_refused_for_what_is_wrong_with_it() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    let guarded = uss_client::uss_protocol::ParamTask::Write {
        pnu: uss_client::uss_protocol::Pnu::new(927).unwrap(),
        value: Value::Word(15),
        storage: uss_client::uss_protocol::Storage::Ram,
    };
    let mut request = ParamRequest::new(
        uss_client::uss_shm_types::Address::new(1).unwrap(),
        &[
            ParamItem::from(&guarded),
            ParamItem::from(&read(947, Some(1))),
        ],
    )
    .unwrap();
    request.items[1].index = 300;
    let response = bus.send_request(&request).unwrap();
    assert_eq!(
        (response.error(), response.error_item),
        (Ok(RequestError::BadSubindex), 1),
        "refused for what is wrong with it"
    );
}

#[test]
fn a_second_controller_is_refused_with_the_controlling_process_id() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    let me = std::process::id();

    // This process controls drive 2: a second handle here, and ussctl, are refused.
    let first = bus.control(addr(2), ControlOptions::default()).unwrap();
    first.rearm(uss_client::monotonic_ns()).unwrap();
    let refused = bus.control(addr(2), ControlOptions::default()).unwrap_err();
    assert!(
        matches!(refused, ClientError::Controlled { address: 2, pid: Some(pid), .. } if pid == me as i32),
        "{refused:?}"
    );
    let prefix = format!("drive 2 on {} is controlled by process {me}", ussd.bus);
    assert!(refused.to_string().starts_with(&prefix), "{refused}");
    let out = ussd.ussctl(&["ack", "2"]);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(err.starts_with(&format!("ussctl: {prefix}")), "{err}");
    assert!(err.contains("only one controller per drive"), "{err}");
    // Drive 2 is untouched by the refused attempts: still this controller's 0x047E.
    assert_eq!(first.words(), [0x047E, 0]);
    drop(first);

    // `ussctl run` in another process holds drive 3.
    let mut run = Command::new(binary("ussctl", "ussctl"))
        .args(["--bus", &ussd.bus, "run", "3", "--hz", "5", "--for", "20"])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdout = BufReader::new(run.stdout.take().unwrap());
    let mut line = String::new();
    stdout.read_line(&mut line).unwrap();
    assert!(line.starts_with("drive 3: running towards 5 Hz"), "{line}");
    let refused = bus.control(addr(3), ControlOptions::default()).unwrap_err();
    assert!(
        refused.to_string().starts_with(&format!(
            "drive 3 on {} is controlled by process {} (node \"ussctl\")",
            ussd.bus,
            run.id()
        )),
        "{refused}"
    );
    // Ctrl-C: ussctl stops the drive (OFF1) and lets go; then the drive can be taken.
    let pid = nix::unistd::Pid::from_raw(i32::try_from(run.id()).unwrap());
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGINT).unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stdout, &mut rest).unwrap();
    assert!(run.wait().unwrap().success(), "{rest}");
    assert!(rest.contains("drive 3: ran; OFF1 sent"), "{rest}");
    bus.control(addr(3), ControlOptions::default()).unwrap();
}

#[test]
fn controller_runs_a_drive_to_s4_and_sees_the_actual_value_rise() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    // A quick ramp: 50 Hz in 1 s.
    bus.write(addr(1), param(1120), Value::from_f32(1.0), false)
        .unwrap();

    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(2))
        .unwrap();
    c.run_hz(25.0).unwrap();
    assert_eq!(c.words(), [0x047F, 0x2000]);
    c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(2))
        .unwrap();

    // The control loop's own calls keep the drive live.
    let mut seen = vec![c.inputs().actual_hz()];
    let deadline = Instant::now() + Duration::from_secs(5);
    while *seen.last().unwrap() < 24.9 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
        c.keepalive().unwrap();
        seen.push(c.inputs().actual_hz());
    }
    assert!(*seen.last().unwrap() >= 24.9, "{seen:?}");
    assert!(seen[0] < 20.0, "started low: {seen:?}");
    assert!(seen.windows(2).all(|w| w[1] >= w[0]), "rises: {seen:?}");
    assert_eq!(c.inputs().state(), DriveState::OperationEnabled);
    assert!(c.inputs().latest().is_live());

    // Without refreshes the drive latches within its 100 ms watchdog: it gets OFF1.
    let stale = c
        .inputs()
        .wait_for(Duration::from_secs(1), "latched", |i| !i.is_live())
        .unwrap();
    assert_eq!(stale.online, 1);
    assert_eq!(stale.latch_reason, LatchReason::Stale.code());

    // A running drive refuses to change P1082 (error 17, not in this state).
    assert_eq!(
        bus.write(addr(1), param(1082), Value::from_f32(60.0), false),
        Err(ParamError::Drive(DriveError::Refused(
            ErrorNumber::NotInThisState
        )))
    );
    // The controller learns of the trip at its next ON, and every ON fails so until it re-arms
    // the drive (a keepalive of the ON words too); a stop still goes out, and re-arms nothing.
    assert!(
        matches!(c.refresh(), Err(ClientError::Tripped { .. })),
        "told"
    );
    assert!(matches!(c.run_hz(25.0), Err(ClientError::Tripped { .. })));
    c.stop().unwrap();
    assert!(matches!(c.run_hz(25.0), Err(ClientError::Tripped { .. })));
    assert!(!c.inputs().latest().is_live());
    let live = c.rearm(uss_client::monotonic_ns()).unwrap();
    assert!(live.is_live());
    assert_eq!(c.words()[0], 0x047E);
}

/// ussd publishes what it knows of each drive; the Rust API and every ussctl command scale Hz
/// with the reference frequency ussd publishes (here 60 Hz, not the 50 Hz default, in the
/// configuration and in the drive's P2000), so no tool asks for it and all show the same Hz
/// for one drive.
#[test]
fn every_tool_scales_hz_with_the_reference_frequency_ussd_publishes() {
    let _serial = serial();
    let ussd = Ussd::start_custom(
        "reference_hz = 60.0\nwatchdog_ms = 150\nsafe_command = \"off3\"\nsim.p2000 = 60",
        "",
    );
    let bus = ussd.bus();
    // ussd reads each drive's reference (P2000) when it comes online: until then it is not
    // known (0), and a run in Hz waits for it as here (seen on a loaded CI run).
    let deadline = Instant::now() + Duration::from_secs(10);
    while [1, 2]
        .iter()
        .any(|&a| bus.diag(addr(a)).unwrap().info.reference().is_none())
    {
        assert!(Instant::now() < deadline, "ussd never read the references");
        std::thread::sleep(Duration::from_millis(10));
    }
    let info = bus.diag(addr(1)).unwrap().info;
    assert_eq!(
        (
            info.reference_hz,
            info.pzd_words,
            info.pkw_words,
            info.watchdog_ms
        ),
        (60.0, 2, 4, 150)
    );
    assert_eq!(info.safe_command(), Ok(uss_client::StopCommand::Off3));
    assert_eq!((info.params_writable, info.weight), (1, 1));
    assert_eq!(bus.diag(addr(2)).unwrap().info.reference_hz, 50.0);

    // A quick ramp: 100 % in 1 s.
    bus.write(addr(1), param(1120), Value::from_f32(1.0), false)
        .unwrap();
    let c = bus.control(addr(1), ControlOptions::default()).unwrap();
    assert_eq!(c.inputs().info().reference_hz, 60.0);
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(2))
        .unwrap();
    c.run_hz(30.0).unwrap();
    assert_eq!(c.words(), [0x047F, 0x2000], "30 Hz of 60 Hz is 50 %");
    c.wait_for(Duration::from_secs(5), "30 Hz", |i| i.hiw == 0x2000)
        .unwrap();
    assert_eq!(c.inputs().actual_hz(), 30.0);
    // The control loop goes on in a thread of its own while the tools look.
    // The loop ends when the tools are done, and also when one of their checks fails (a
    // failed check would otherwise leave the scope waiting for it forever).
    let looking = AtomicBool::new(true);
    std::thread::scope(|scope| {
        scope.spawn(|| {
            while looking.load(Ordering::Relaxed) {
                c.keepalive().unwrap();
                std::thread::sleep(Duration::from_millis(20));
            }
        });
        let _done = Done(&looking);
        every_tool_shows_30_hz(&ussd, &bus);
    });
}

/// `status`, `watch` and `stats` of drive 1 running at 30 Hz of its 60 Hz reference.
/// Ends a keepalive loop when dropped, so a failed check in the scope ends it too.
struct Done<'a>(&'a AtomicBool);

impl Drop for Done<'_> {
    fn drop(&mut self) {
        self.0.store(false, Ordering::Relaxed);
    }
}

fn every_tool_shows_30_hz(ussd: &Ussd, bus: &Bus) {
    // Diagnostics (what `status` shows) lag the image by up to a few hundred ms.
    let deadline = Instant::now() + Duration::from_secs(5);
    while bus.diag(addr(1)).unwrap().last_hiw != 0x2000 {
        assert!(Instant::now() < deadline, "diagnostics never showed 30 Hz");
        std::thread::sleep(Duration::from_millis(20));
    }

    let out = ussd.ussctl(&["--json", "status"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let status = text(&out.stdout);
    assert!(status.contains("\"address\":1,"), "{status}");
    assert!(
        status.contains("\"hiw\":8192,\"actual_hz\":30.0,"),
        "{status}"
    );
    let out = ussd.ussctl(&["--json", "watch", "--count", "1", "1"]);
    let watch = text(&out.stdout);
    assert!(watch.contains("\"actual_hz\":30.0"), "{watch}");
    let out = ussd.ussctl(&["--json", "stats"]);
    let described: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let drive_1 = described["drives"]
        .as_array()
        .and_then(|d| d.iter().find(|d| d["address"] == 1))
        .unwrap_or_else(|| panic!("no drive 1 in {described}"));
    assert_eq!(
        drive_1["info"],
        serde_json::json!({"reference_hz": 60.0, "pzd_words": 2, "pkw_words": 4, "pkw": 4,
            "watchdog_ms": 150, "safe_command": "OFF3", "params_writable": true, "weight": 1}),
        "{described}"
    );
    let out = ussd.ussctl(&["stats"]);
    assert!(
        text(&out.stdout).contains(
            "reference 60 Hz, PZD 2, PKW 4, watchdog 150 ms, safe command OFF3, weight 1, \
             parameters writable"
        ),
        "{}",
        text(&out.stdout)
    );
}

/// The Rust API reads and writes parameters as their own type; a parameter the catalogue does
/// not know is typed by the drive's own description (AK 4, element 1), asked once.
#[test]
fn parameters_are_read_and_written_as_their_own_type() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    let p = |s: &str| s.parse::<uss_client::uss_protocol::ParamRef>().unwrap();
    let v = bus.read_param(addr(1), p("1082")).unwrap();
    assert_eq!(v.to_string(), "P1082 = 50.00 Hz");
    assert_eq!(
        (v.typed(), v.unit(), v.name()),
        (Typed::Float(50.0), "Hz", Some("Max. frequency"))
    );
    let options = uss_client::WriteOptions::default();
    let v = bus.write_param(addr(1), p("P1120"), "2", options).unwrap();
    assert_eq!(
        (v.typed(), v.to_string()),
        (Typed::Float(2.0), "P1120 = 2.00 s".to_owned())
    );
    assert_eq!(
        bus.write_param(addr(1), p("P0700"), "-1", options),
        Err(ParamError::Value {
            param: "P0700".into(),
            problem: "-1 does not fit U16 (0..=65535)".into()
        })
    );

    // A catalogue that knows nothing: the drive describes each parameter's type, once.
    let empty = Catalogue::parse(
        "family = \"none\"\nparam = []\nfault = []\nwarning = []\n",
        "empty",
    )
    .unwrap();
    let bus = ussd.bus().with_catalogue(Box::leak(Box::new(empty)));
    let jobs_done = |settle: Duration| {
        std::thread::sleep(settle);
        bus.diag(addr(1)).unwrap().counters.jobs_done
    };
    let before = jobs_done(Duration::from_millis(500));
    let v = bus.read_param(addr(1), p("1082")).unwrap();
    assert_eq!(
        (v.data_type, v.info, v.to_string()),
        (DataType::Float, None, "P1082 = 50.00".to_owned())
    );
    let again = bus.read_param(addr(1), p("1082")).unwrap();
    assert_eq!(again.typed(), Typed::Float(50.0));
    let w = bus.read_param(addr(1), p("700")).unwrap();
    assert_eq!((w.data_type, w.typed()), (DataType::U16, Typed::U16(5)));
    // Two descriptions (P1082, P0700) and three reads reached the drive.
    assert_eq!(jobs_done(Duration::from_millis(600)) - before, 5);
}

#[test]
fn ussctl_reads_and_writes_parameters_in_their_own_type_and_unit() {
    let _serial = serial();
    let ussd = Ussd::start();
    // Parameters in their own type and unit, in the manuals' notation.
    let read = |args: &[&str]| {
        let out = ussd.ussctl(&[&["param", "read"], args].concat());
        assert!(out.status.success(), "{}", text(&out.stderr));
        text(&out.stdout)
    };
    assert_eq!(
        read(&["1", "P1082"]),
        "drive 1 P1082 = 50.00 Hz  (Max. frequency)\n"
    );
    assert_eq!(
        read(&["1", "21"]),
        "drive 1 r0021 = 0.00 Hz  (CO: Act. frequency)\n",
        "the catalogue's prefix and four digits"
    );
    assert_eq!(
        read(&["1", "P0700"]),
        "drive 1 P0700 = 5  (Selection of command source)\n"
    );
    assert!(
        read(&["1", "r0052"]).starts_with("drive 1 r0052 = 0xBB31  (CO/BO: Act. status word 1): "),
        "a status word with its bits named"
    );
    assert_eq!(
        read(&["1", "r0947[0]"]),
        "drive 1 r0947[0] = 0  (CO: Last fault code)\n"
    );
    // A type named for a parameter whose type is known: the same kind, or refused (its bits
    // are in --json's "raw" and "hex"). Told the type, ussctl sends one task: the read.
    let bus = ussd.bus();
    let jobs_done = || {
        std::thread::sleep(Duration::from_millis(300));
        bus.diag(addr(1)).unwrap().counters.jobs_done
    };
    let before = jobs_done();
    assert_eq!(
        read(&["1", "1082", "--type", "float"]),
        "drive 1 P1082 = 50.00 Hz  (Max. frequency)\n"
    );
    assert_eq!(jobs_done() - before, 1, "one task");
    let out = ussd.ussctl(&["param", "read", "1", "1082", "--type", "dword"]);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(
        text(&out.stderr),
        "ussctl: drive 1 P1082: its type is Float (a float), not a double word: drop --type, it is read and written as its own\n"
    );
    let out = ussd.ussctl(&["--json", "param", "read", "1", "r0947.2"]);
    assert_eq!(
        text(&out.stdout),
        format!(
            "{{\"v\":1,\"bus\":\"{}\",\"drive\":1,\"param\":\"r0947[2]\",\"pnu\":947,\"index\":2,\"name\":\"CO: Last fault code\",\"type\":\"U16\",\"unit\":\"\",\"raw\":0,\"hex\":\"0x0000\",\"value\":0}}\n",
            ussd.bus
        )
    );
    // Writes convert to the parameter's type: 45 is 45.0 for a float parameter.
    let out = ussd.ussctl(&["param", "write", "2", "P1082", "45"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        text(&out.stdout),
        "drive 2 P1082 := 45.00 Hz, RAM  (Max. frequency)\n"
    );
    assert_eq!(ussd.bus().read_f32(addr(2), param(1082)), Ok(45.0));
    let out = ussd.ussctl(&["param", "write", "2", "1120", "3.5"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        text(&out.stdout),
        "drive 2 P1120 := 3.50 s, RAM  (Ramp-up time)\n"
    );
    assert_eq!(ussd.bus().read_f32(addr(2), param(1120)), Ok(3.5));
    // What does not fit the type, or a read-only parameter, is refused before the bus.
    for (args, said) in [
        (
            ["2", "P0700", "70000"],
            "ussctl: drive 2 P0700: 70000 does not fit U16 (0..=65535)\n",
        ),
        (
            ["2", "P0700", "4.5"],
            "ussctl: drive 2 P0700: 4.5 is not a whole number, and U16 holds only whole numbers\n",
        ),
        (
            ["2", "r0021", "5"],
            "ussctl: drive 2 r0021: read-only: a monitoring (r) parameter cannot be written\n",
        ),
    ] {
        let out = ussd.ussctl(&[&["param", "write"], &args[..]].concat());
        assert_eq!(out.status.code(), Some(1));
        assert_eq!(text(&out.stderr), said);
    }
    // --type of another kind than the parameter's known type is refused before the bus.
    let out = ussd.ussctl(&["param", "write", "2", "1120", "3", "--type", "word"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("its type is Float (a float), not a word"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn ussctl_prints_status_as_json_and_reads_and_writes_parameters() {
    let _serial = serial();
    let ussd = Ussd::start();

    let out = ussd.ussctl(&["--json", "status"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let json = text(&out.stdout);
    assert_eq!(json.lines().count(), 1, "{json}");
    assert!(
        json.starts_with(&format!(
            "{{\"v\":1,\"bus\":{{\"bus\":\"{}\",\"running\":true,",
            ussd.bus
        )),
        "{json}"
    );
    assert!(json.contains("\"drive_count\":3"), "{json}");
    for a in 1..=3 {
        assert!(
            json.contains(&format!(
                "{{\"address\":{a},\"online\":true,\"stale\":false,\"state\":\"S2\","
            )),
            "{json}"
        );
    }

    let out = ussd.ussctl(&["status"]);
    assert!(out.status.success());
    let table = text(&out.stdout);
    assert!(table.contains("addr  online  state"), "{table}");
    assert!(table.contains("   2  yes     S2"), "{table}");

    let out = ussd.ussctl(&["faults", "3"]);
    assert_eq!(
        text(&out.stdout),
        "drive 3: no faults recorded (r0947 empty)\nactive warnings (r2110): none\n"
    );
    let out = ussd.ussctl(&["--json", "watch", "--count", "2", "--interval", "50", "1"]);
    let lines = text(&out.stdout);
    assert_eq!(lines.lines().count(), 2, "{lines}");
    assert!(
        lines
            .lines()
            .all(|l| l.contains("\"drive\":1,\"online\":true")),
        "{lines}"
    );
}

#[test]
fn fault_buffer_names_the_fault_and_ussctl_acknowledges_it() {
    let _serial = serial();
    // Drive 3 watches its telegrams (P2014 = 100 ms) and is unplugged for half a second, so it
    // trips with F0072 (USS telegram off) and answers again in fault.
    let ussd = Ussd::start_with("p2014 = 100, unplug = \"2000..2500\"");
    let bus = ussd.bus();
    let faulted = bus
        .watch(addr(3))
        .unwrap()
        .wait_for(Duration::from_secs(10), "fault", |i| {
            i.online != 0 && uss_client::state_of(i) == DriveState::Fault
        })
        .unwrap();
    assert_eq!(faulted.zsw1 & 0x0008, 0x0008);
    assert_eq!(bus.faults(addr(3)), Ok(vec![72, 0, 0, 0, 0, 0, 0, 0]));
    // The simulated drive's clock was never set: r0948 stamps the trip with the time since it
    // started, taken when a telegram meets it again after the unplugged half second (~2.5 s).
    let report = bus.fault_report(addr(3)).unwrap();
    let time = report.faults.first().and_then(|f| f.time);
    let seconds = time.map_or(0, |t| t.words[0]);
    assert!((2..=9).contains(&seconds), "r0948 = {time:?}");
    assert_eq!(time.map(|t| t.words[1..].to_vec()), Some(vec![0, 0]));
    assert_eq!(
        report,
        uss_client::FaultReport {
            codes: "r0947".parse().unwrap(),
            values: Some("r0949".parse().unwrap()),
            warnings_from: Some("r2110".parse().unwrap()),
            digits: 4,
            param_digits: 4,
            faults: vec![uss_client::Fault {
                slot: 0,
                number: 72,
                value: Some(0),
                time,
                received: None,
                text: Some("USS (COM link) setpoint fault")
            }],
            warnings: Some(Vec::new()),
        }
    );
    let out = ussd.ussctl(&["faults", "3"]);
    assert_eq!(
        text(&out.stdout),
        format!(
            "drive 3 fault buffer r0947, newest first:\n  0: F0072 USS (COM link) setpoint fault (fault value r0949 = 0) at day 0 00:00:{seconds:02}\nactive warnings (r2110): none\n"
        )
    );

    // A faulted drive is not run: ussctl says what to do.
    let out = ussd.ussctl(&["run", "3", "--hz", "5"]);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(
        text(&out.stderr),
        "ussctl: drive 3 is in fault (ZSW1 0xBB38): see `ussctl faults 3`, then acknowledge with `ussctl ack 3`\n"
    );

    let out = ussd.ussctl(&["ack", "3"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let said = text(&out.stdout);
    assert!(
        said.starts_with("drive 3: fault acknowledge sent; now S"),
        "{said}"
    );
    assert_ne!(bus.watch(addr(3)).unwrap().state(), DriveState::Fault);
    // The acknowledged drive runs again.
    let c = bus.control(addr(3), ControlOptions::default()).unwrap();
    c.rearm(uss_client::monotonic_ns()).unwrap();
    c.wait_for_state(DriveState::ReadyToSwitchOn, Duration::from_secs(2))
        .unwrap();
    c.run_percent(10.0).unwrap();
    c.wait_for_state(DriveState::OperationEnabled, Duration::from_secs(2))
        .unwrap();
}

/// A MICROMASTER 4's upload: its identity, every data set and array element, no command and
/// none of the drive's state.
fn an_upload_holds_every_setting(saved: &str) {
    for line in [
        "format = 1",
        "family = \"MICROMASTER 4 / SINAMICS G110\"",
        "firmware = 2.09",
        "P1082 = [50.0, 50.0, 50.0]",
        "P0700 = [5, 5, 5]",
        "P2013 = [4, 127]",
        "P2011 = [1, 0]",
        "P0003 = 1",
    ] {
        assert!(saved.lines().any(|l| l == line), "{line}: {saved}");
    }
    assert!(!saved.contains("P0970"), "a command is not a setting");
    assert!(
        !saved.contains("P0010") && !saved.contains("P0004"),
        "the drive's state is not a setting: {saved}"
    );
}

/// Backup -> change -> restore -> diff shows nothing: the restore writes only what differs, in a
/// safe order (it raises the access level for an expert parameter and enters quick
/// commissioning for a commissioning parameter, then puts both back), and a file that does not
/// fit is refused before anything is written.
#[test]
fn backup_change_restore_and_diff_shows_nothing() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    let dir = std::env::temp_dir().join(format!("uss-backup-{}", ussd.bus));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("drive1.toml");
    let path = file.to_str().unwrap();
    let run = |args: &[&str]| ussd.ussctl_said(args);

    let (code, said, err) = run(&["param", "backup", "1", "-o", path]);
    assert_eq!(code, Some(0), "{err}");
    // The simulated drive has every parameter its family's profile lists (the settings a
    // backup keeps: no actual values, no commands such as P0970 and P0971, not the drive's
    // state P0010 and P0004), each data set of a data-set parameter (an MM440 has three of
    // P0700, P1000, P1080, P1082, P1120, P1121: the drive says so) and each array element.
    assert!(
        said.starts_with("drive 1: 33 parameters (51 values) saved to ")
            && !said.contains("not on this drive"),
        "{said}"
    );
    let saved = std::fs::read_to_string(&file).unwrap();
    an_upload_holds_every_setting(&saved);

    // Change four settings: a plain one, a float, an expert one (level 3) and a commissioning
    // one (P0010 = 1 needed); put the access level back to 1.
    let w = |pnu, v| bus.write(addr(1), param(pnu), v, false).unwrap();
    let p1082 = || bus.read_f32(addr(1), param(1082));
    w(1082, Value::from_f32(45.0));
    // The third drive data set's ramp-up time.
    let third = uss_client::uss_protocol::Subindex::new(2).unwrap();
    bus.write(addr(1), param(1120).at(third), Value::from_f32(2.5), false)
        .unwrap();
    w(3, Value::Word(3));
    // P0719 (command and setpoint source) is guarded: deliberately.
    let guarded = bus.write_with(addr(1), param(719), Value::Word(11), deliberate());
    guarded.unwrap();
    w(10, Value::Word(1));
    w(310, Value::from_f32(60.0));
    w(10, Value::Word(0));
    w(3, Value::Word(1));
    let (code, said, _) = run(&["param", "diff", "1", path]);
    assert_eq!(code, Some(1), "differences: {said}");
    assert!(
        said.contains("P0310      drive 1: 60.00 Hz")
            && said.contains("P1082[0]   drive 1: 45.00 Hz")
            && said.contains("P1120[2]   drive 1: 2.50 s")
            && said.ends_with("4 differences, 47 values the same\n"),
        "{said}"
    );
    let (code, said, _) = run(&["param", "restore", "1", path, "--dry-run"]);
    assert_eq!(code, Some(0));
    assert!(
        said.contains("would write 4; 47 already as in the file"),
        "{said}"
    );
    assert_eq!(p1082(), Ok(45.0), "a dry run writes nothing");

    // Refused while another process controls the drive; nothing is written.
    let controller = bus.control(addr(1), ControlOptions::default()).unwrap();
    let (code, _, err) = run(&["param", "restore", "1", path, "--unsafe"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("is controlled by process"), "{err}");
    assert_eq!(p1082(), Ok(45.0));
    controller.release().unwrap();

    // Without --unsafe the guarded P0719 is named and nothing is written.
    let (code, said, err) = run(&["param", "restore", "1", path]);
    assert_eq!(code, Some(1), "{said}{err}");
    assert!(
        err.contains("the backup changes P0719, which can take the drive away from ussd")
            && err.contains("nothing was written: restore with --unsafe"),
        "{err}"
    );
    assert_eq!(p1082(), Ok(45.0), "nothing written");
    let (code, said, err) = run(&["param", "restore", "1", path, "--unsafe"]);
    assert_eq!(code, Some(0), "{said}{err}");
    assert!(said.contains("P0719      11 -> 0: written"), "{said}");
    assert!(
        said.contains("wrote 4, refused 0; 47 already as in the file"),
        "{said}"
    );
    let (_, said, _) = run(&["param", "diff", "1", path]);
    assert!(said.starts_with("drive 1 and "), "{said}");
    assert!(
        said.ends_with(": no differences (51 values compared)\n"),
        "{said}"
    );
    assert_eq!(
        bus.read(addr(1), param(3)),
        Ok(Value::Word(1)),
        "access level back"
    );
    assert_eq!(
        bus.read(addr(1), param(10)),
        Ok(Value::Word(0)),
        "commissioning left"
    );
    another_drive_keeps_its_com_link(&ussd, path);
    files_that_do_not_fit_are_refused(&ussd, &dir, &saved);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A restore cut short by Ctrl-C after it raised the access level (P0003) and entered quick
/// commissioning (P0010 = 1) on the way puts both back to what the drive had before it stops:
/// the drive is not left in commissioning (where it would not run). The report says so, and
/// says what was not written.
#[test]
fn a_restore_cut_short_by_ctrl_c_leaves_quick_commissioning_and_puts_the_access_level_back() {
    let _serial = serial();
    // Drive 3 answers every parameter task after 2 "busy" replies, and the reads below take
    // turns with the restore's writes: the Ctrl-C comes with most of the writes still to do.
    let ussd = Ussd::start_with("busy = 2");
    let bus = ussd.bus();
    let dir = std::env::temp_dir().join(format!("uss-cut-{}", ussd.bus));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("drive3.toml");
    let path = file.to_str().unwrap();
    let (code, _, err) = ussd.ussctl_said(&["param", "backup", "3", "-o", path]);
    assert_eq!(code, Some(0), "{err}");
    // Settings to put back: an expert one (level 3), commissioning ones and plain ones.
    uss_integration_tests::change_what_a_restore_raises(&bus, 3, 60.0);

    let mut restore = Command::new(binary("ussctl", "ussctl"))
        .args([
            "--bus", &ussd.bus, "param", "restore", "3", path, "--unsafe",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Ctrl-C once the drive is in quick commissioning.
    let deadline = Instant::now() + Duration::from_secs(30);
    while bus.read(addr(3), param(10)) != Ok(Value::Word(1)) {
        assert!(
            Instant::now() < deadline,
            "the restore never entered commissioning"
        );
        assert!(restore.try_wait().unwrap().is_none(), "the restore ended");
    }
    let pid = nix::unistd::Pid::from_raw(i32::try_from(restore.id()).unwrap());
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGINT).unwrap();
    let out = restore.wait_with_output().unwrap();
    let (said, err) = (text(&out.stdout), text(&out.stderr));
    assert_eq!(out.status.code(), Some(1), "incomplete: {said}{err}");
    assert!(said.contains("cut short: Ctrl-C; not written: "), "{said}");
    assert_eq!(
        bus.read(addr(3), param(10)),
        Ok(Value::Word(0)),
        "commissioning left: {said}"
    );
    assert_eq!(
        bus.read(addr(3), param(3)),
        Ok(Value::Word(1)),
        "access level back: {said}"
    );
    assert!(
        said.contains("P0010      1 -> 0: put back after Ctrl-C")
            && said.contains("P0003      3 -> 1: put back after Ctrl-C"),
        "{said}"
    );
    // Run again, it completes the rest.
    let (code, said, err) = ussd.ussctl_said(&["param", "restore", "3", path, "--unsafe"]);
    assert_eq!(code, Some(0), "{said}{err}");
    let (_, said, _) = ussd.ussctl_said(&["param", "diff", "3", path]);
    assert!(said.contains(": no differences"), "{said}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Backup files that do not fit are refused before anything is written, naming line and field.
fn files_that_do_not_fit_are_refused(ussd: &Ussd, dir: &std::path::Path, saved: &str) {
    let bus = ussd.bus();
    let run = |args: &[&str]| ussd.ussctl_said(args);
    let refused = |name: &str, from: &str, to: &str| {
        let bad = dir.join(name);
        std::fs::write(&bad, saved.replacen(from, to, 1)).unwrap();
        let (code, _, err) = run(&["param", "restore", "1", bad.to_str().unwrap()]);
        assert_eq!(code, Some(1), "{err}");
        err
    };
    let line = |key: &str| saved.lines().position(|l| l.starts_with(key)).unwrap() + 1;
    let err = refused(
        "family.toml",
        "MICROMASTER 4 / SINAMICS G110",
        "SINAMICS G120",
    );
    assert!(
        err.contains("the backup is of a SINAMICS G120 drive"),
        "{err}"
    );
    let err = refused(
        "range.toml",
        "P1082 = [50.0, 50.0, 50.0]",
        "P1082 = [700.0, 50.0, 50.0]",
    );
    assert!(
        err.contains(&format!(
            ":{}: P1082: 700 is outside the drive's limits 0..=650; nothing was written",
            line("P1082")
        )),
        "{err}"
    );
    let err = refused("type.toml", "P0003 = 1", "P0003 = 1.5");
    assert!(err.contains("P0003: 1.5 is not a whole number"), "{err}");
    let err = refused("unknown.toml", "P0003 = 1", "P9999 = 1");
    assert!(
        err.contains("P9999: not a parameter of MICROMASTER 4"),
        "{err}"
    );
    let err = refused("array.toml", "P2013 = [4, 127]", "P2013 = 127");
    assert!(
        err.contains("P2013: P2013 takes a list of 2 values"),
        "{err}"
    );
    // A data set the drive does not have (a MICROMASTER 440's backup on a drive with fewer):
    // that element is refused and said, the rest is restored; the restore is incomplete.
    let more = dir.join("more.toml");
    std::fs::write(
        &more,
        saved.replacen(
            "P1120 = [10.0, 10.0, 10.0]",
            "P1120 = [10.0, 10.0, 10.0, 10.0]",
            1,
        ),
    )
    .unwrap();
    let (code, said, err) = run(&["param", "restore", "1", more.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{said}{err}");
    assert!(
        said.contains("P1120[3]") && said.contains("refused: ") && said.contains("refused 1"),
        "{said}{err}"
    );
    // A backup of other firmware is refused, naming both, unless asked for deliberately.
    let err = refused("firmware.toml", "firmware = 2.09", "firmware = 2.1");
    assert!(
        err.contains("the backup was taken from firmware 2.1 and the drive has 2.09")
            && err.contains("nothing was written"),
        "{err}"
    );
    let (code, said, err) = run(&[
        "param",
        "restore",
        "1",
        dir.join("firmware.toml").to_str().unwrap(),
        "--other-firmware",
    ]);
    assert_eq!(code, Some(0), "{said}{err}");
    // A backup taken before uss-rt left the drive's state out holds P0010: during quick
    // commissioning, 1. It is not restored (the drive would not run), and said so.
    let old = dir.join("old.toml");
    std::fs::write(
        &old,
        saved.replacen("P0003 = 1\n", "P0003 = 1\nP0010 = 1\n", 1),
    )
    .unwrap();
    let (code, said, err) = run(&["param", "restore", "1", old.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{said}{err}");
    assert!(
        said.contains("not restored: P0010 (the drive's state"),
        "{said}"
    );
    assert_eq!(bus.read(addr(1), param(10)), Ok(Value::Word(0)));
    assert_eq!(bus.read(addr(1), param(3)), Ok(Value::Word(1)));
}

/// Drive 2 differs from drive 1 in its address on the COM link only; restoring drive 1's
/// backup there keeps the address (and baud rate, PZD and PKW length) of the line ussd talks
/// over.
fn another_drive_keeps_its_com_link(ussd: &Ussd, path: &str) {
    let bus = ussd.bus();
    let run = |args: &[&str]| ussd.ussctl_said(args);
    let (_, said, _) = run(&["param", "diff", "1", "2"]);
    assert_eq!(
        said,
        "  P2011[0]   drive 1: 1              drive 2: 2              (USS address)\n\
         drive 1 and drive 2: 1 difference, 50 values the same\n"
    );
    let (code, said, err) = run(&["param", "restore", "2", path]);
    assert_eq!(code, Some(0), "{said}{err}");
    assert!(
        said.contains("P2011[0]   2 -> 1: kept: the COM link ussd talks over"),
        "{said}"
    );
    assert!(
        said.contains("wrote 0, refused 0; 50 already as in the file, 1 COM-link settings kept"),
        "{said}"
    );
    assert_eq!(bus.read(addr(2), param_at(2011, 0)), Ok(Value::Word(2)));
}

/// `ussctl ack` after an operator's coast keeps the coast: the drive is handed back latched with
/// OFF2, not OFF1 (the adversarial run saw `ack` lower an operator's OFF2 silently: its re-arm
/// sent OFF1 and its release latched the drive with the safe command OFF1). A latch never weakens
/// the stop a controller sends itself.
#[test]
fn an_operators_coast_stays_through_ussctl_ack() {
    let _serial = serial();
    let ussd = Ussd::start();
    let bus = ussd.bus();
    let out = ussd.ussctl(&["coast", "1"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Every image of drive 1 while the ack runs: what each poll sent. No OFF1 (0x047E), not even
    // for the re-arm, so an ack killed at any moment leaves the drive coasting (the second
    // adversarial run killed one between its re-arm and its coast and the OFF2 was gone).
    let done = std::sync::Arc::new(AtomicBool::new(false));
    let seen = std::thread::spawn({
        let (bus, done) = (ussd.bus(), done.clone());
        move || {
            let watch = bus.watch(addr(1)).unwrap();
            let mut sent = Vec::new();
            while !done.load(Ordering::Relaxed) {
                let i = watch.latest();
                if sent.last() != Some(&(i.sequence, i.sent_stw1)) {
                    sent.push((i.sequence, i.sent_stw1));
                }
                std::thread::sleep(Duration::from_micros(500));
            }
            sent
        }
    });
    let out = ussd.ussctl(&["ack", "1"]);
    std::thread::sleep(Duration::from_millis(100));
    done.store(true, Ordering::Relaxed);
    let sent = seen.join().unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        sent.iter().all(|&(_, stw1)| stw1 & 0x0002 == 0),
        "a poll without OFF2 during the ack: {sent:04X?}"
    );
    assert!(
        sent.iter().any(|&(_, stw1)| stw1 == 0x04FC),
        "no edge: {sent:04X?}"
    );
    let said = text(&out.stdout);
    assert!(said.contains("its OFF2 stays"), "{said}");
    let watch = bus.watch(addr(1)).unwrap();
    let i = watch.latest();
    assert!(!i.is_live(), "{i:?}");
    assert_eq!(
        (i.latch_command, i.sent_stw1),
        (StopCommand::Off2.code(), 0x047C),
        "{i:?}"
    );
}
