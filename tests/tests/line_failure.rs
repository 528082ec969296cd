//! A bus whose serial line fails goes down alone and comes back (issue 8): two buses on two
//! pseudo-terminals, each served by its own `uss-sim` process and reached through a symlink,
//! the way udev gives an adapter a stable name. When one `uss-sim` dies its pty disappears:
//! that bus reports "line down", its drives go offline and its parameter jobs end, while the
//! other bus and ussd keep running. When a new `uss-sim` appears behind the same name, ussd
//! reopens it and the drives come back latched. Measured figures are printed.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use uss_client::{Bus, ClientError, Health, LatchReason, ParamError, RequestError, Value};
use uss_integration_tests::{BusSpec, SimProcess, Ussd, monotonic_ns, read};
use uss_integration_tests::{addr, param};

/// A symlink in a directory of its own, pointing at a pty.
struct Link {
    dir: PathBuf,
    path: PathBuf,
}

impl Link {
    fn new(name: &str, target: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("uss-line-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::os::unix::fs::symlink(target, &path).unwrap();
        Self { dir, path }
    }

    /// Points the link at `target`, atomically (a new link renamed over the old one).
    fn retarget(&self, target: &str) {
        let next = self.dir.join("next");
        let _ = std::fs::remove_file(&next);
        std::os::unix::fs::symlink(target, &next).unwrap();
        std::fs::rename(&next, &self.path).unwrap();
    }

    fn path(&self) -> &str {
        self.path.to_str().unwrap()
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn sim() -> SimProcess {
    SimProcess::start(&["--baud", "115200", "--drive", "1:busy=100", "--drive", "2"])
}

/// Waits until bus status `done` holds (republished every 100 ms).
fn status_when(bus: &Bus, done: impl Fn(&uss_client::BusStatus) -> bool) -> uss_client::BusStatus {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let s = bus.status().unwrap();
        if done(&s) {
            return s;
        }
        assert!(Instant::now() < deadline, "bus status still {s:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn exists(p: &Path) -> bool {
    std::fs::metadata(p).is_ok()
}

#[test]
fn a_failed_line_takes_only_its_bus_down_and_ussd_reopens_it_when_it_is_back() {
    let (sim_a, sim_b) = (sim(), sim());
    let (link_a, link_b) = (Link::new("a", &sim_a.path), Link::new("b", &sim_b.path));
    let drives: &[(u8, &str)] = &[(1, ""), (2, "")];
    let mut ussd = Ussd::start_buses(&[
        BusSpec {
            suffix: "a",
            device: link_a.path(),
            keys: "baud = 115200",
            drives,
        },
        BusSpec {
            suffix: "b",
            device: link_b.path(),
            keys: "baud = 115200",
            drives,
        },
    ]);
    let (a, b) = (ussd.bus_named("a"), ussd.bus_named("b"));

    // 39 parameter reads on bus A, each answered after 100 busy replies: seconds of work.
    let requester = {
        let name = format!("{}a", ussd.bus);
        std::thread::spawn(move || {
            let bus = Bus::open(&name).unwrap();
            bus.batch(addr(1), &[read(1082, None); 39])
        })
    };
    std::thread::sleep(Duration::from_millis(300));

    let pty_a = PathBuf::from(&sim_a.path);
    let killed_at = monotonic_ns();
    drop(sim_a);
    let down = status_when(&a, uss_client::BusStatus::is_line_down);
    println!(
        "line: bus A down in its status {:.1} ms after uss-sim was killed",
        (down.line_down_since_ns.saturating_sub(killed_at)) as f64 / 1e6
    );
    assert_eq!(
        down.line_fault_text().as_deref(),
        Some("the line was closed: a serial device unplugged, or its server's connection ended")
    );
    assert!(!exists(&pty_a), "the pty went with its uss-sim");
    for d in [1, 2] {
        let i = a.watch(addr(d)).unwrap().latest();
        assert_eq!(i.online, 0, "drive {d} of bus A: {i:?}");
    }
    // Every item of the request ended: the ones done, then the rest with "line down".
    let results = requester.join().unwrap();
    assert_eq!(results.len(), 39);
    let done = results.iter().filter(|r| r.is_ok()).count();
    assert!(
        results[done..]
            .iter()
            .all(|r| *r == Err(ParamError::Path(uss_client::PathError::LineDown))),
        "{results:?}"
    );
    assert!(done < 39, "the line went down before the request finished");
    // New requests are refused at once while the line is down: by this client when the
    // heartbeat already said so, else by ussd.
    let refused = a.read(addr(2), param(1082));
    assert!(
        matches!(
            refused,
            Err(ParamError::Client(ClientError::LineDown { .. })
                | ParamError::Refused {
                    error: RequestError::LineDown,
                    item: None
                })
        ),
        "{refused:?}"
    );
    let health = a.health();
    assert!(matches!(health, Health::LineDown { .. }), "{health:?}");
    assert!(
        matches!(
            a.watch(addr(1)).unwrap().read(),
            Err(ClientError::LineDown { .. })
        ),
        "a watcher is told"
    );

    // Bus B and ussd carry on.
    let watch_b = b.watch(addr(2)).unwrap();
    let before = watch_b.latest().sequence;
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        watch_b.latest().sequence > before + 20,
        "bus B keeps polling"
    );
    assert_eq!(b.read(addr(2), param(1082)), Ok(Value::Dword(0x4248_0000)));
    assert!(ussd.is_running(), "{}", ussd.log());

    comes_back_latched(&a, &link_a, &ussd);
    drop(sim_b);
}

#[test]
fn a_device_absent_at_start_is_opened_when_it_appears() {
    // The adapter's udev name points nowhere yet (not plugged in).
    let link = Link::new("later", "/nonexistent/uss-adapter");
    let mut ussd = Ussd::launch(
        &[BusSpec {
            suffix: "",
            device: link.path(),
            keys: "baud = 115200",
            drives: &[(1, ""), (2, "")],
        }],
        &[],
    );
    let bus = ussd.open_when_running("");
    let down = status_when(&bus, uss_client::BusStatus::is_line_down);
    assert_eq!(
        down.line_fault_text().as_deref(),
        Some("the line's I/O failed: No such file or directory (os error 2)"),
        "{down:?}"
    );
    for d in [1, 2] {
        assert_eq!(bus.watch(addr(d)).unwrap().latest().online, 0);
    }
    let said = ussd
        .log_line(
            "is not there: the bus starts line down",
            Duration::from_secs(5),
        )
        .expect("ussd says the device is not there");
    assert!(said.contains(link.path()), "{said}");
    assert!(ussd.is_running());

    // Plugged in: the bus opens it at its next attempt, the drives come online latched.
    let sim = sim();
    let plugged = monotonic_ns();
    link.retarget(&sim.path);
    status_when(&bus, |s| !s.is_line_down());
    println!(
        "line: a device absent at start opened {:.0} ms after it appeared ({} attempts)",
        (monotonic_ns() - plugged) as f64 / 1e6,
        bus.status().unwrap().reopen_attempts
    );
    online_latched(&bus);
    assert_eq!(
        bus.read(addr(2), param(1082)),
        Ok(Value::Dword(0x4248_0000))
    );
}

/// Both drives come online again, latched because the line was restored.
fn online_latched(bus: &Bus) {
    for d in [1, 2] {
        let i = bus
            .watch(addr(d))
            .unwrap()
            .wait_for(Duration::from_secs(5), "online", |i| i.online == 1)
            .unwrap();
        assert_eq!(i.latch_reason, LatchReason::LineRestored.code(), "{i:?}");
    }
}

/// A new uss-sim behind bus A's name: ussd reopens it and its drives come back latched.
fn comes_back_latched(a: &Bus, link_a: &Link, ussd: &Ussd) {
    // A new uss-sim behind the same name: bus A reopens it and its drives come back latched.
    let sim_a2 = sim();
    let relinked_at = monotonic_ns();
    link_a.retarget(&sim_a2.path);
    status_when(a, |s| !s.is_line_down());
    let up_at = monotonic_ns();
    println!(
        "line: bus A reopened {:.0} ms after its device came back ({} attempts)",
        (up_at - relinked_at) as f64 / 1e6,
        a.status().unwrap().reopen_attempts
    );
    for d in [1, 2] {
        let i = a
            .watch(addr(d))
            .unwrap()
            .wait_for(Duration::from_secs(5), "online", |i| i.online == 1)
            .unwrap();
        assert_eq!(i.latch_reason, LatchReason::LineRestored.code(), "{i:?}");
        assert_eq!(i.sent_stw1, 0x047E);
    }
    assert_eq!(a.read(addr(2), param(1082)), Ok(Value::Dword(0x4248_0000)));
    assert_eq!(a.status().unwrap().line_downs, 1);
    let log = ussd.log();
    assert!(
        log.contains("line down (the line was closed: a serial device unplugged, or its server's connection ended)"),
        "{log}"
    );
    assert!(log.contains("line back after"), "{log}");
}

/// A line whose output stalls (flow stopped on the pty, as a USB adapter whose writes stop
/// being taken) until ussd's writes fail, then resumes: ussd must come back on the same
/// device. It can only if it let go of the old descriptor first: its exclusive lock (flock)
/// lives with that descriptor and refuses every reopen as "busy" for as long as it is kept.
#[test]
fn a_line_whose_writes_stalled_comes_back_on_the_same_device() {
    use nix::fcntl::{OFlag, open};
    use nix::sys::stat::Mode;
    use nix::sys::termios::{FlowArg, tcflow};
    let sim = sim();
    // Our own descriptor on the pty slave, opened before ussd's exclusive open.
    let tty = open(
        sim.path.as_str(),
        OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_NONBLOCK,
        Mode::empty(),
    )
    .unwrap();
    let mut ussd = Ussd::launch(
        &[BusSpec {
            suffix: "",
            device: &sim.path,
            keys: "baud = 115200",
            drives: &[(1, ""), (2, "")],
        }],
        &[],
    );
    let bus = ussd.open_when_running("");
    for d in [1, 2] {
        bus.watch(addr(d))
            .unwrap()
            .wait_for(Duration::from_secs(5), "online", |i| i.online == 1)
            .unwrap();
    }
    // The line's output stops: ussd's next write finds no room and, after its write-stall
    // allowance, the line is down.
    tcflow(&tty, FlowArg::TCOOFF).unwrap();
    let stalled = monotonic_ns();
    let down = status_when(&bus, uss_client::BusStatus::is_line_down);
    println!(
        "line: down {:.0} ms after its output stalled",
        (down.line_down_since_ns.saturating_sub(stalled)) as f64 / 1e6,
    );
    assert_eq!(
        down.line_fault_text().as_deref(),
        Some("the line's output stalled: no byte could be written for its write-stall allowance")
    );
    std::thread::sleep(Duration::from_millis(1500));
    // The output moves again: the same device must carry the bus again.
    tcflow(&tty, FlowArg::TCOON).unwrap();
    let resumed = monotonic_ns();
    // While it stalled, every reopen succeeded and the next write stalled again; now one sticks.
    let back = status_when(&bus, |s| {
        !s.is_line_down() && s.good > down.good && monotonic_ns() > resumed + 1_000_000_000
    });
    println!(
        "line: carrying the bus again 1 s after its output resumed ({} outages while it stalled)",
        back.line_downs
    );
    assert!(back.line_downs >= 1);
    assert_eq!(
        bus.read(addr(2), param(1082)),
        Ok(Value::Dword(0x4248_0000))
    );
    online_latched(&bus);
    assert!(ussd.is_running());
    let log = ussd.log();
    assert!(!log.contains("busy"), "{log}");
}
