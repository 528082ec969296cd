//! The `LinuxCNC` HAL component `uss_vfd` (`linuxcnc/uss_vfd.c`, on `libussrt`) in a real `halrun`
//! against a real ussd and simulated drive, pins set and read with `halcmd`, its watchdog-in fed
//! by siggen in a servo thread: latched at start while idle; spindle on (its rise re-arms) ->
//! at-speed, a speed change, off; an operator's stop -> latched, high or low, until spindle-on
//! rises again; the servo thread stopped -> the component stops refreshing, the drive trips and
//! stays latched until a spindle-on cycle; ussd killed -> comm-ok false.
//!
//! Needs Debian's linuxcnc-uspace and linuxcnc-uspace-dev (`halrun`, `halcmd`, hal.h) and root;
//! without them the test says it is skipped, unless `USS_REQUIRE_LINUXCNC` is set (`.ci/run`
//! installs them and sets it).
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};
use uss_client::{StopCommand, WriteOptions};
use uss_integration_tests::Ussd;
use uss_integration_tests::addr;

fn root() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// Whether `LinuxCNC` is here; panics when it must be.
fn linuxcnc_here() -> bool {
    // SAFETY: geteuid has no preconditions and cannot fail.
    let root_user = unsafe { nix::libc::geteuid() } == 0;
    let here = root_user
        && Path::new("/usr/include/linuxcnc/hal.h").exists()
        && Command::new("halcmd").arg("-v").output().is_ok();
    if !here {
        assert!(
            std::env::var_os("USS_REQUIRE_LINUXCNC").is_none(),
            "USS_REQUIRE_LINUXCNC is set, but halrun, halcmd, hal.h or root are missing \
             (apt-get install linuxcnc-uspace linuxcnc-uspace-dev)"
        );
        println!("skipped: LinuxCNC (linuxcnc-uspace, linuxcnc-uspace-dev) and root are needed");
    }
    here
}

/// Builds the component the way the guide says: `make -C linuxcnc`.
fn build() -> PathBuf {
    let out = Command::new("make")
        .args(["-C", "linuxcnc", "--no-print-directory"])
        .current_dir(root())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "make -C linuxcnc:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let target =
        std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root().join("target"), PathBuf::from);
    target.join("release/uss_vfd")
}

/// One halrun at a time: `LinuxCNC` runs one RTAPI session per machine.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The HAL file of a test: the guide's `linuxcnc/examples/uss_vfd.hal` as shipped (a servo
/// thread of 1 ms, siggen's clock on the component's watchdog-in), on drive 1 of the bus
/// [`Hal::start`] names, and the test's own tolerance; halrun stays until the component ends.
fn hal_text() -> String {
    format!(
        "source {}\nsetp uss_vfd.tolerance 0.02\nwaitusr uss_vfd\n",
        root().join("linuxcnc/examples/uss_vfd.hal").display()
    )
}

/// A `halrun` session of this test: RTAPI as an unprivileged user (`rtapi_app` refuses root), its
/// socket in a directory of the test.
struct Hal {
    halrun: Child,
    env: Vec<(String, String)>,
    log: PathBuf,
}

impl Hal {
    /// `hal_file` in halrun, the component found on `PATH` as a machine finds it, on drive 1
    /// of `bus` (`USS_BUS`, `USS_DRIVE` of the shipped HAL file).
    fn start(hal_file: &Path, log: PathBuf, (component, bus): (&Path, &str)) -> Hal {
        let fifo = std::env::temp_dir().join(format!("rtapi-fifo-{}", std::process::id()));
        let path = std::env::var("PATH").unwrap_or_default();
        let env = vec![
            ("RTAPI_UID".to_owned(), "65534".to_owned()),
            ("RTAPI_FIFO_PATH".to_owned(), fifo.display().to_string()),
            ("USS_BUS".to_owned(), bus.to_owned()),
            ("USS_DRIVE".to_owned(), "1".to_owned()),
            (
                "PATH".to_owned(),
                format!("{}:{path}", component.parent().unwrap().display()),
            ),
        ];
        // A session a crashed run may have left.
        let _ = Command::new("halrun").arg("-U").envs(env.clone()).output();
        let out = std::fs::File::create(&log).unwrap();
        let halrun = Command::new("halrun")
            .arg(hal_file)
            .envs(env.clone())
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            .stdin(Stdio::null())
            .spawn()
            .unwrap();
        let hal = Hal { halrun, env, log };
        hal.until("the component's pins", Duration::from_secs(20), |h| {
            h.halcmd(&["-s", "show", "pin", "uss_vfd.at-speed"])
                .contains("uss_vfd.at-speed")
        });
        hal
    }

    fn run(&self, args: &[&str]) -> Output {
        Command::new("halcmd")
            .args(args)
            .envs(self.env.clone())
            .output()
            .unwrap()
    }

    fn halcmd(&self, args: &[&str]) -> String {
        String::from_utf8_lossy(&self.run(args).stdout).into_owned()
    }

    fn set(&self, pin: &str, value: &str) {
        let out = self.run(&["setp", &format!("uss_vfd.{pin}"), value]);
        assert!(
            out.status.success(),
            "setp {pin} {value}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }

    fn get(&self, pin: &str) -> String {
        self.halcmd(&["getp", &format!("uss_vfd.{pin}")])
            .trim()
            .to_owned()
    }

    fn float(&self, pin: &str) -> f64 {
        self.get(pin).parse().unwrap_or(f64::NAN)
    }

    fn until(&self, what: &str, timeout: Duration, done: impl Fn(&Hal) -> bool) {
        let deadline = Instant::now() + timeout;
        while !done(self) {
            assert!(
                Instant::now() < deadline,
                "{what} not within {timeout:?}; pins:\n{}\nhalrun:\n{}",
                self.halcmd(&["show", "pin", "uss_vfd"]),
                std::fs::read_to_string(&self.log).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Unloads the component and ends the session; what halrun printed.
    fn stop(mut self) -> String {
        self.end();
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    fn end(&mut self) {
        if self.halrun.try_wait().ok().flatten().is_some() {
            return;
        }
        let _ = self.run(&["unload", "uss_vfd"]);
        let deadline = Instant::now() + Duration::from_secs(10);
        while self.halrun.try_wait().ok().flatten().is_none() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        if self.halrun.try_wait().ok().flatten().is_none() {
            let _ = Command::new("halrun")
                .arg("-U")
                .envs(self.env.clone())
                .output();
            let _ = self.halrun.kill();
            let _ = self.halrun.wait();
        }
    }
}

impl Drop for Hal {
    /// A failed test leaves no session behind for the next one.
    fn drop(&mut self) {
        self.end();
    }
}

/// A halrun session of the component on drive 1 of a fresh ussd, with the HAL file the guide
/// shows (`what` names its files), once the component talks to ussd and sees the servo thread:
/// `None` where `LinuxCNC` is not installed. Dropped in reverse: the session, then ussd.
fn session(what: &str) -> Option<(std::sync::MutexGuard<'static, ()>, Ussd, Hal, PathBuf)> {
    if !linuxcnc_here() {
        return None;
    }
    let serial = serial();
    let component = build();
    let ussd = Ussd::start("", &[(1, "")]);
    let dir = std::env::temp_dir();
    let hal_file = dir.join(format!("uss_vfd-{what}-{}.hal", std::process::id()));
    std::fs::write(&hal_file, hal_text()).unwrap();
    let hal = Hal::start(
        &hal_file,
        dir.join(format!("halrun-{what}-{}.log", std::process::id())),
        (&component, &ussd.bus),
    );
    let s = Duration::from_secs(10);
    hal.until("comm-ok", s, |h| h.get("comm-ok") == "TRUE");
    hal.until("watchdog-ok", s, |h| h.get("watchdog-ok") == "TRUE");
    Some((serial, ussd, hal, hal_file))
}

#[test]
fn a_spindle_runs_through_halrun_and_stops_latch_until_spindle_on_rises() {
    if !linuxcnc_here() {
        return;
    }
    let _serial = serial();
    let component = build();
    let mut ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    // Quick ramps: 50 Hz in 1 s, up and down.
    for p in ["P1120", "P1121"] {
        bus.write_param(addr(1), p.parse().unwrap(), "1", WriteOptions::default())
            .unwrap();
    }
    let dir = std::env::temp_dir();
    let hal_file = dir.join(format!("uss_vfd-{}.hal", std::process::id()));
    std::fs::write(&hal_file, hal_text()).unwrap();
    let hal = Hal::start(
        &hal_file,
        dir.join(format!("halrun-{}.log", std::process::id())),
        (&component, &ussd.bus),
    );
    let s = Duration::from_secs(10);
    let watch = bus.watch(addr(1)).unwrap();
    // Holds the drive latched with `stw1` for `ms`, whatever the component does.
    let holds = |what: &str, stw1: u16, ms: u64| {
        let end = Instant::now() + Duration::from_millis(ms);
        while Instant::now() < end {
            let i = watch.latest();
            assert!(!i.is_live() && i.sent_stw1 == stw1, "{what}: {i:?}");
            assert_eq!(hal.get("latched"), "TRUE", "{what}");
            std::thread::sleep(Duration::from_millis(20));
        }
    };

    hal.until("comm-ok", s, |h| h.get("comm-ok") == "TRUE");
    hal.until("watchdog-ok", s, |h| h.get("watchdog-ok") == "TRUE");
    // ussd's start-up latch holds while spindle-on is low: idle is no re-arm.
    holds("idle at start", 0x047E, 500);
    // Spindle on at 600 rpm (20 Hz of the 50 Hz reference): its rise re-arms, at speed.
    hal.set("speed-command", "600");
    hal.set("spindle-on", "1");
    hal.until("at speed (600 rpm)", s, |h| h.get("at-speed") == "TRUE");
    assert!((hal.float("spindle-speed-fb") - 600.0).abs() < 12.0);
    assert!((hal.float("spindle-speed-fb-hz") - 20.0).abs() < 0.4);
    assert!((hal.float("frequency-command") - 20.0).abs() < 1e-3);
    // A speed change: off speed until the ramp got there.
    hal.set("speed-command", "900");
    hal.until("at speed (900 rpm)", s, |h| {
        h.get("at-speed") == "TRUE" && (h.float("spindle-speed-fb") - 900.0).abs() < 18.0
    });
    // Off: the drive ramps down (OFF1): the component's own stop, no latch.
    hal.set("spindle-on", "0");
    hal.until("stopped", s, |h| h.float("spindle-speed-fb").abs() < 1.0);
    assert_eq!(hal.get("at-speed"), "FALSE");
    assert_eq!(hal.get("latched"), "FALSE");
    assert_eq!(watch.latest().sent_stw1, 0x047E);

    // On again, then an operator's stop from another process: latched, not restarted while
    // spindle-on stays high, nor when it goes low.
    hal.set("spindle-on", "1");
    hal.until("at speed again", s, |h| h.get("at-speed") == "TRUE");
    bus.stop_drive(addr(1), StopCommand::Off1).unwrap();
    hal.until("latched", s, |h| h.get("latched") == "TRUE");
    assert_eq!(hal.get("at-speed"), "FALSE");
    holds("spindle-on held high", 0x047E, 1500);
    hal.until("stopped by the operator", s, |h| {
        h.float("spindle-speed-fb").abs() < 1.0
    });
    hal.set("spindle-on", "0");
    holds("spindle-on low after the stop", 0x047E, 500);
    // Its rise re-arms (OFF1 naming the latch) and runs.
    hal.set("spindle-on", "1");
    hal.until("running after the rise", s, |h| h.get("at-speed") == "TRUE");

    // LinuxCNC's servo thread stops: watchdog-in stops changing, the component stops
    // refreshing and ussd trips the drive (controller stale).
    hal.halcmd(&["stop"]);
    hal.until("watchdog-ok false", s, |h| h.get("watchdog-ok") == "FALSE");
    let tripped = watch
        .wait_for(Duration::from_secs(2), "the trip", |i| !i.is_live())
        .unwrap();
    assert_eq!(tripped.latch_reason_name(), "controller stale");
    assert_eq!(hal.get("latched"), "TRUE");
    // The thread runs again: still latched while spindle-on stays high; a cycle runs it.
    hal.halcmd(&["start"]);
    hal.until("watchdog-ok again", s, |h| h.get("watchdog-ok") == "TRUE");
    holds("servo thread back, spindle-on high", 0x047E, 500);
    hal.set("spindle-on", "0");
    hal.until("spindle-on low seen", s, |h| h.get("latched") == "TRUE");
    std::thread::sleep(Duration::from_millis(100));
    hal.set("spindle-on", "1");
    hal.until("running after the cycle", s, |h| {
        h.get("at-speed") == "TRUE"
    });

    // ussd killed: comm-ok and at-speed drop.
    ussd.kill();
    hal.until("comm-ok false", Duration::from_secs(3), |h| {
        h.get("comm-ok") == "FALSE" && h.get("at-speed") == "FALSE"
    });
    assert!(hal.get("error-count").parse::<i32>().unwrap() > 0);
    let log = hal.stop();
    let _ = std::fs::remove_file(&hal_file);
    println!("{log}");
}

/// Issue 32, item 3: an operator's coast of an idle spindle (spindle-on low) holds: the
/// component re-armed the drive whenever spindle-on was low and the drive latched, so the coast
/// was undone within 50 ms (OFF1 instead of OFF2) and the next M3 ran the motor. The coast holds
/// until spindle-on rises, the deliberate re-arm. Then the component killed: a stale trip.
#[test]
fn an_operators_coast_of_an_idle_spindle_holds_until_spindle_on_rises() {
    let Some((_serial, ussd, hal, hal_file)) = session("idle") else {
        return;
    };
    let bus = ussd.bus();
    let s = Duration::from_secs(10);
    // Run once and stop: the drive is live under the component, the spindle idle.
    hal.set("speed-command", "600");
    hal.set("spindle-on", "1");
    hal.until("running", s, |h| h.get("at-speed") == "TRUE");
    hal.set("spindle-on", "0");
    hal.until("stopped", s, |h| h.float("spindle-speed-fb").abs() < 1.0);
    // The operator coasts the idle drive from another process.
    bus.stop_drive(addr(1), StopCommand::Off2).unwrap();
    bus.wait_stopped(addr(1), StopCommand::Off2, None).unwrap();
    let watch = bus.watch(addr(1)).unwrap();
    let held = Instant::now() + Duration::from_secs(1);
    while Instant::now() < held {
        let i = watch.latest();
        assert!(
            !i.is_live() && i.sent_stw1 == 0x047C,
            "the coast was undone while idle: {i:?}"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(hal.get("latched"), "TRUE");
    // M3: the rising edge re-arms and runs.
    hal.set("spindle-on", "1");
    hal.until("running after M3", s, |h| h.get("at-speed") == "TRUE");
    // The component killed (SIGKILL) while the spindle runs: nothing of it refreshes the drive,
    // ussd trips it within its watchdog time (controller stale).
    let killed = Command::new("pkill")
        .args([
            "-KILL",
            "-f",
            &format!("uss_vfd --bus {} --drive 1", ussd.bus),
        ])
        .status()
        .unwrap();
    assert!(killed.success(), "pkill uss_vfd");
    let tripped = watch
        .wait_for(Duration::from_secs(2), "the trip", |i| !i.is_live())
        .unwrap();
    assert_eq!(
        (tripped.latch_reason_name(), tripped.sent_stw1),
        ("controller stale", 0x047E)
    );
    let _ = hal.stop();
    let _ = std::fs::remove_file(&hal_file);
}

/// REARM (the rise carries its time): an operator's coast that lands right after M3 (spindle-on
/// rose, the component's loop has not read it yet, or is re-arming) is not re-armed by that
/// rise, swept across two of the component's loop periods (20 ms each, on a line of eight
/// drives), most often in the first few ms where the old component re-armed it; once the coast is in
/// the image, the drive is never live again until spindle-on rises anew. A stale image (ussd
/// stopped by SIGTERM) reads `latched` TRUE.
#[test]
fn an_operators_coast_right_after_m3_is_not_re_armed_by_its_rise() {
    if !linuxcnc_here() {
        return;
    }
    let _serial = serial();
    let component = build();
    // Eight drives: the component's loop, in step with drive 1's exchanges, runs every 20 ms (its
    // refresh period), as on a full line; a stop still goes out in the next telegram.
    let drives: Vec<(u8, &str)> = (1..=8).map(|a| (a, "")).collect();
    let mut ussd = Ussd::start("", &drives);
    let bus = ussd.bus();
    let dir = std::env::temp_dir();
    let hal_file = dir.join(format!("uss_vfd-m3-{}.hal", std::process::id()));
    std::fs::write(&hal_file, hal_text()).unwrap();
    let hal = Hal::start(
        &hal_file,
        dir.join(format!("halrun-m3-{}.log", std::process::id())),
        (&component, &ussd.bus),
    );
    let s = Duration::from_secs(10);
    hal.until("comm-ok", s, |h| h.get("comm-ok") == "TRUE");
    hal.until("watchdog-ok", s, |h| h.get("watchdog-ok") == "TRUE");
    hal.set("speed-command", "600");
    let watch = bus.watch(addr(1)).unwrap();
    let mut rearmed = Vec::new();
    for offset_ms in [0, 0, 0, 0, 2, 4, 6, 8, 10, 20, 30, 40] {
        let before = watch.latest().latch_id;
        hal.set("spindle-on", "1");
        std::thread::sleep(Duration::from_millis(offset_ms));
        bus.stop_drive(addr(1), StopCommand::Off2).unwrap();
        let coast = watch
            .wait_for(Duration::from_secs(2), "the coast", |i| i.latch_id > before)
            .unwrap();
        let held = Instant::now() + Duration::from_millis(600);
        while Instant::now() < held {
            let i = watch.latest();
            if i.is_live() || i.sent_stw1 != 0x047C {
                rearmed.push((offset_ms, i.latch_id == coast.latch_id));
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(hal.get("latched"), "TRUE", "coast {offset_ms} ms after M3");
        hal.set("spindle-on", "0");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(
        rearmed.is_empty(),
        "a coast right after M3 was undone (offset ms, by the rise): {rearmed:?}"
    );
    // The next rise is the deliberate act: it re-arms and runs.
    hal.set("spindle-on", "1");
    hal.until("running after a new M3", s, |h| h.get("at-speed") == "TRUE");
    // ussd stopped (SIGTERM): the image goes stale, and nothing says the drive is live.
    ussd.terminate();
    hal.until("comm-ok FALSE", s, |h| h.get("comm-ok") == "FALSE");
    hal.until("latched while ussd is stopped", s, |h| {
        h.get("latched") == "TRUE"
    });
    let _ = hal.stop();
    let _ = std::fs::remove_file(&hal_file);
}

/// SCALE (issue 46's adversarial sweep, break 3): the component sent its command in percent of
/// the reference (`rpm-at-reference` was 100 %). P2000 changed at the drive from 50 to 60 Hz
/// (and its maximum raised so nothing capped it) between two M3s: the latch held until the
/// rise, as it should, but then the spindle ran at 60 Hz for a 1500 rpm command while the pins
/// showed 1500 rpm and at-speed: 20 % fast, and hidden. rpm are now Hz times `rpm-per-hz` (the
/// machine's constant) and the Hz are scaled by the reference ussd reads: the same 1500 rpm is
/// 50 Hz at either reference, and the feedback is the drive's own.
#[test]
fn a_changed_reference_changes_no_spindle_speed() {
    let Some((_serial, ussd, hal, hal_file)) = session("scale") else {
        return;
    };
    let bus = ussd.bus();
    let write = |p: &str, v: &str| {
        bus.write_param(
            addr(1),
            p.parse().unwrap(),
            v,
            WriteOptions {
                force: true,
                ..WriteOptions::default()
            },
        )
        .unwrap_or_else(|e| panic!("{p} := {v}: {e}"));
    };
    for p in ["P1120", "P1121"] {
        write(p, "1");
    }
    let s = Duration::from_secs(10);
    let watch = bus.watch(addr(1)).unwrap();
    let at_1500 = |what: &str| {
        hal.set("speed-command", "1500");
        hal.set("spindle-on", "1");
        hal.until(what, s, |h| h.get("at-speed") == "TRUE");
        // The drive's own actual frequency, not the component's: 1500 rpm is 50 Hz.
        let hz = watch.actual_hz();
        assert!((hz - 50.0).abs() < 1.0, "{what}: the drive runs at {hz} Hz");
        assert!(
            (hal.float("frequency-command") - 50.0).abs() < 1e-3,
            "{what}"
        );
        assert!(
            (hal.float("spindle-speed-fb") - 1500.0).abs() < 30.0,
            "{what}"
        );
        hal.set("spindle-on", "0");
        hal.until("stopped", s, |h| h.float("spindle-speed-fb").abs() < 1.0);
    };
    at_1500("at speed, P2000 = 50 Hz");
    // P2000 to 60 Hz, the maximum with it, from another process: the drive latches
    // (reference changed) until spindle-on rises.
    write("P0003", "3");
    write("P1082[0]", "60");
    write("P2000", "60");
    hal.until("latched by the reference change", s, |h| {
        h.get("latched") == "TRUE"
    });
    assert_eq!(watch.wait_for_reference(s), Ok(60.0));
    at_1500("at speed, P2000 = 60 Hz");
    let _ = hal.stop();
    let _ = std::fs::remove_file(&hal_file);
}

/// Issue 47, item 3: the guide's HAL snippet failed in halrun ("thread 'servo-thread' not
/// found"). The guide shows the machine configuration's lines as `linuxcnc/examples/machine.hal`
/// ships them, and the file for halrun alone, which the tests above run, makes its own thread.
#[test]
fn the_guides_hal_lines_are_the_shipped_files() {
    let lines = |text: &str| -> Vec<String> {
        text.lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .map(|l| l.split_whitespace().collect::<Vec<_>>().join(" "))
            .collect()
    };
    let guide = std::fs::read_to_string(root().join("docs/guide/src/linuxcnc.md")).unwrap();
    let block = guide
        .split("```text\n")
        .nth(1)
        .and_then(|b| b.split("```").next())
        .unwrap();
    let machine = std::fs::read_to_string(root().join("linuxcnc/examples/machine.hal")).unwrap();
    assert_eq!(lines(block), lines(&machine), "docs/guide/src/linuxcnc.md");
    let alone = std::fs::read_to_string(root().join("linuxcnc/examples/uss_vfd.hal")).unwrap();
    assert!(
        lines(&alone)[0].starts_with("loadrt threads name1=servo-thread"),
        "{alone}"
    );
    assert!(guide.contains("halrun -I linuxcnc/examples/uss_vfd.hal"));
}
