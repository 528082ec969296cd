//! The safety conformance suite (docs/SAFETY.md): each rule's scenario, written once, run
//! against every front-end that can break it, with real processes and signals. A front-end is a
//! program driven line by line (open, keepalive, run, rearm, a second thread's call, ...): the
//! Rust client (`uss-conformance-rust`), the C ABI (`capi/tests/c/conformance.c`), the C++
//! wrapper (`conformance.cpp`) and the Python module (`python/tests/conformance_driver.py`).
//! The harness starts ussd, the programs, kills and pauses them, acts as the operator, and
//! reads what the drive got from its input image.
//!
//! `ussctl`, the `LinuxCNC` component and the Zenoh client are no scriptable libraries: their
//! scenarios live beside them (docs/SAFETY.md names each), and
//! `every_rule_has_a_scenario_for_every_front_end` fails when a cell of the rule table names no
//! test that exists.
#![allow(clippy::unwrap_used)]

use std::collections::VecDeque;
use std::io::{BufRead as _, BufReader, Write as _};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use uss_client::{Bus, PzdInput, StopCommand};
use uss_integration_tests::{SimProcess, Ussd, addr, binary, c_program, param, root};

/// One ussd at a time: each runs a paced bus thread, and the machine may have two cores.
fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(PoisonError::into_inner)
}

const RUN: u16 = 0x047F;
const OFF1: u16 = 0x047E;
const OFF2: u16 = 0x047C;
/// OFF2 with the fault-acknowledge bit: the edge of an acknowledgement that keeps a coast.
const OFF2_ACK: u16 = 0x04FC;

/// A front-end under test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FrontEnd {
    Rust,
    C,
    Cpp,
    Python,
}

/// Runs a program in a time namespace of its own whose `CLOCK_MONOTONIC` is `ahead_ns` ahead of
/// the host's (a container's can be): unshare(2) `CLONE_NEWTIME`, the offset written, then the
/// program in a child that lives in it.
const TIME_NAMESPACE: &str = "import ctypes, os, sys
libc = ctypes.CDLL(None, use_errno=True)
if libc.unshare(0x80) != 0:
    raise OSError(ctypes.get_errno(), 'unshare(CLONE_NEWTIME)')
with open('/proc/self/timens_offsets', 'w') as f:
    f.write('monotonic 0 %s' % sys.argv[1])
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[2], sys.argv[2:])
sys.exit(os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]))
";

impl FrontEnd {
    /// The front-end's program in a time namespace whose clock runs `ahead_ns` ahead.
    fn command_ahead(self, ahead_ns: u64) -> Command {
        let inner = self.command();
        let mut c = Command::new("python3");
        c.args(["-c", TIME_NAMESPACE, &ahead_ns.to_string()])
            .arg(inner.get_program())
            .args(inner.get_args());
        // The inner program's environment (Python's module path) reaches it through this one.
        for (key, value) in inner.get_envs() {
            match value {
                Some(v) => c.env(key, v),
                None => c.env_remove(key),
            };
        }
        c
    }

    fn command(self) -> Command {
        match self {
            Self::Rust => Command::new(binary("uss-integration-tests", "uss-conformance-rust")),
            Self::C => Command::new(c_program("cc", "capi/tests/c/conformance.c", &["-std=c11"])),
            Self::Cpp => Command::new(c_program(
                "c++",
                "capi/tests/c/conformance.cpp",
                &["-std=c++17"],
            )),
            Self::Python => {
                let mut c = uss_integration_tests::python();
                c.arg(root().join("python/tests/conformance_driver.py"));
                c
            }
        }
    }
}

/// What a command came to: `Ok`, or the error's kind (`tripped`, ...) and message.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Reply {
    Ok,
    Err(String, String),
}

impl Reply {
    fn parse(line: &str) -> Self {
        match line.strip_prefix("err ") {
            None if line == "ok" => Self::Ok,
            None => panic!("not a reply: {line:?}"),
            Some(rest) => {
                let (kind, message) = rest.split_once(' ').unwrap_or((rest, ""));
                Self::Err(kind.to_owned(), message.to_owned())
            }
        }
    }

    fn kind(&self) -> &str {
        match self {
            Self::Ok => "ok",
            Self::Err(kind, _) => kind,
        }
    }
}

/// A front-end's program, its stdout read by a thread.
struct Program {
    front: FrontEnd,
    child: Child,
    lines: Receiver<String>,
    /// Lines read that were not asked for yet (a thread's answer while the main one waits).
    held: VecDeque<String>,
}

impl Program {
    fn start(front: FrontEnd) -> Self {
        Self::start_with(front, front.command())
    }

    fn start_with(front: FrontEnd, mut command: Command) -> Self {
        let mut child = command
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let out = BufReader::new(child.stdout.take().unwrap());
        let (tx, lines) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in out.lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Self {
            front,
            child,
            lines,
            held: VecDeque::new(),
        }
    }

    fn tell(&mut self, line: &str) {
        let stdin = self.child.stdin.as_mut().unwrap();
        writeln!(stdin, "{line}").unwrap();
        stdin.flush().unwrap();
    }

    /// The next answer tagged `tag` (`<<` the main thread's, `<&` another thread's).
    fn answer(&mut self, tag: &str) -> Reply {
        let prefix = format!("{tag} ");
        if let Some(i) = self.held.iter().position(|l| l.starts_with(&prefix)) {
            let line = self.held.remove(i).unwrap();
            return Reply::parse(&line[prefix.len()..]);
        }
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) if line.starts_with(&prefix) => {
                    return Reply::parse(&line[prefix.len()..]);
                }
                Ok(line) => self.held.push_back(line),
                Err(RecvTimeoutError::Timeout) => panic!("{:?}: no {tag} answer", self.front),
                Err(RecvTimeoutError::Disconnected) => {
                    panic!("{:?} ended before its {tag} answer", self.front)
                }
            }
        }
    }

    /// Runs `command` on the program's main thread; its answer.
    fn call(&mut self, command: &str) -> Reply {
        self.tell(command);
        self.answer("<<")
    }

    /// Runs `command` on the program's main thread; it must succeed.
    fn ok(&mut self, command: &str) {
        assert_eq!(self.call(command), Reply::Ok, "{:?}: {command}", self.front);
    }

    /// Starts `command` on a thread of its own; [`Program::answer`]`("<&")` gives its answer.
    fn spawn(&mut self, command: &str) {
        self.tell(&format!("&{command}"));
    }

    fn signal(&self, signal: nix::sys::signal::Signal) {
        let pid = nix::unistd::Pid::from_raw(i32::try_from(self.child.id()).unwrap());
        nix::sys::signal::kill(pid, signal).unwrap();
    }

    /// SIGKILL: nothing of the program runs on the way out.
    fn kill(&mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }

    /// `exit`: the program hands its drive back and ends.
    fn exit(mut self) {
        self.tell("exit");
        assert!(
            self.child.wait().unwrap().success(),
            "{:?} exit",
            self.front
        );
    }
}

impl Drop for Program {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The drive's input image, once `done` holds for it (at most 5 s).
fn image_until(bus: &Bus, drive: u8, what: &str, done: impl Fn(&PzdInput) -> bool) -> PzdInput {
    bus.watch(addr(drive))
        .unwrap()
        .wait_for(Duration::from_secs(5), what, |i| done(i))
        .unwrap()
}

/// The image after every poll for `span`: none may be `bad`.
fn never(bus: &Bus, drive: u8, span: Duration, what: &str, bad: impl Fn(&PzdInput) -> bool) {
    let watch = bus.watch(addr(drive)).unwrap();
    let end = Instant::now() + span;
    while Instant::now() < end {
        let i = watch.latest();
        assert!(!bad(&i), "{what}: {i:?}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// The program's deliberate re-arm and an ON at 10 Hz, until drive 1 gets it.
fn runs(p: &mut Program, bus: &Bus) {
    p.ok("rearm");
    p.ok("run 10");
    image_until(bus, 1, "ON on the wire", |i| i.sent_stw1 == RUN);
}

fn opened(front: FrontEnd, ussd: &Ussd, drive: u8) -> Program {
    let mut p = Program::start(front);
    p.ok(&format!("open {} {drive}", ussd.bus));
    p
}

/// REARM (opening is none): a program that opens a drive latched at ussd's start, refreshes it and runs it
/// does not run the motor: its ON is `tripped` and the drive keeps its safe command until the
/// program's explicit re-arm.
fn opening_is_no_rearm(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut p = opened(front, &ussd, 1);
    for _ in 0..5 {
        p.ok("keepalive");
        std::thread::sleep(Duration::from_millis(20));
    }
    p.ok("enable");
    assert_eq!(p.call("run 10").kind(), "tripped", "{front:?}");
    never(&bus, 1, Duration::from_millis(300), "ON after open", |i| {
        i.sent_stw1 == RUN || i.is_live()
    });
    assert_eq!(
        bus.watch(addr(1)).unwrap().latest().latch_reason_name(),
        "ussd started"
    );
    // The deliberate act.
    runs(&mut p, &bus);
    p.exit();
}

/// REARM (reconnecting is none): an operator's stop of a running drive survives its controller's exit and a
/// new program that opens, refreshes and runs it.
fn an_operators_stop_survives_a_reconnect(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut first = opened(front, &ussd, 1);
    runs(&mut first, &bus);
    bus.stop_drive(addr(1), StopCommand::Off2).unwrap();
    bus.wait_stopped(addr(1), StopCommand::Off2, None).unwrap();
    first.exit();
    let mut second = opened(front, &ussd, 1);
    for _ in 0..5 {
        second.ok("keepalive");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(second.call("run 10").kind(), "tripped", "{front:?}");
    never(
        &bus,
        1,
        Duration::from_millis(300),
        "the coast undone",
        |i| i.sent_stw1 != OFF2,
    );
    assert_eq!(
        bus.watch(addr(1)).unwrap().latest().latch_reason_name(),
        "operator stop"
    );
    second.exit();
}

/// REARM (a stop between the ask and the re-arm wins): the program is asked to re-arm and makes
/// the call [`ASK_WINDOW`] later, as a program that re-arms once it is set up (`rearm MS`: the
/// ask is when the line arrives). An operator's coast that lands anywhere in that window (swept
/// from its start to two thirds of it) is not re-armed: the call is `tripped`, the coast stays on
/// the wire. With no stop in between, the same call re-arms and an ON runs.
fn a_stop_between_the_ask_and_the_rearm_wins(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let watch = bus.watch(addr(1)).unwrap();
    let mut p = opened(front, &ussd, 1);
    let window = ASK_WINDOW.as_millis();
    for offset in [0, window / 3, 2 * window / 3] {
        let before = watch.latest().latch_id;
        p.tell(&format!("rearm {window}"));
        let asked = Instant::now();
        std::thread::sleep(Duration::from_millis(u64::try_from(offset).unwrap()));
        bus.stop_drive(addr(1), StopCommand::Off2).unwrap();
        image_until(&bus, 1, "the coast's latch", |i| i.latch_id > before);
        let landed = asked.elapsed();
        let reply = p.answer("<<");
        // A coast that landed only after the call (a starved machine) came after the re-arm:
        // then the re-arm may stand. Inside the window it never does.
        if landed < ASK_WINDOW {
            assert_eq!(
                reply.kind(),
                "tripped",
                "{front:?}: a coast {offset} ms into the window (landed after {landed:?}) was re-armed: {reply:?}"
            );
        }
        assert_eq!(p.call("run 10").kind(), "tripped", "{front:?}");
        never(
            &bus,
            1,
            Duration::from_millis(150),
            "the coast undone",
            |i| i.sent_stw1 != OFF2 || i.is_live(),
        );
    }
    // Nothing in between: the deliberate act re-arms.
    p.ok(&format!("rearm {window}"));
    p.ok("run 10");
    image_until(&bus, 1, "ON on the wire", |i| i.sent_stw1 == RUN);
    p.exit();
}

/// REARM on another clock (issue 45's adversarial run): a program in a time namespace whose
/// clock runs 80 ms ahead of ussd's (a container's can: ussd's images still look fresh) asks for
/// a re-arm, and an operator's coast lands after the ask: not re-armed. Its `asked_ns` is on its
/// own clock, 80 ms later than ussd's latch ids; the client library moves it onto ussd's clock
/// by the freshest stamp of ussd's it saw. Before, 5 of 5 such coasts were re-armed.
fn a_program_whose_clock_runs_ahead_re_arms_no_later_stop(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let watch = bus.watch(addr(1)).unwrap();
    let mut p = Program::start_with(front, front.command_ahead(80_000_000));
    p.ok(&format!("open {} 1", ussd.bus));
    for offset in [0, 10, 20] {
        let before = watch.latest().latch_id;
        p.tell("rearm 40");
        std::thread::sleep(Duration::from_millis(offset));
        bus.stop_drive(addr(1), StopCommand::Off2).unwrap();
        image_until(&bus, 1, "the coast's latch", |i| i.latch_id > before);
        let reply = p.answer("<<");
        assert_eq!(
            reply.kind(),
            "tripped",
            "{front:?}: a coast {offset} ms after the ask of a program 80 ms ahead was re-armed: {reply:?}"
        );
        never(
            &bus,
            1,
            Duration::from_millis(100),
            "the coast undone",
            |i| i.sent_stw1 != OFF2 || i.is_live(),
        );
    }
    // Nothing in between: its re-arm goes through.
    p.ok("rearm 40");
    p.ok("run 10");
    image_until(&bus, 1, "ON on the wire", |i| i.sent_stw1 == RUN);
    p.exit();
}

/// The time between the ask and the re-arm call in [`a_stop_between_the_ask_and_the_rearm_wins`]:
/// below the drive's watchdog (100 ms), so the program's silence in it is no stall.
const ASK_WINDOW: Duration = Duration::from_millis(90);

/// REPLACED: a controller killed while its drive runs and replaced by a new program within the
/// drive's watchdog time is a trip ("controller replaced"): the drive stops, and the new program
/// must re-arm it.
fn a_replaced_controller_is_a_trip(front: FrontEnd) {
    let _serial = serial();
    // A watchdog long enough that the replacement comes well within it.
    let ussd = Ussd::start("", &[(1, "watchdog_ms = 2000")]);
    let bus = ussd.bus();
    let mut first = opened(front, &ussd, 1);
    runs(&mut first, &bus);
    let mut second = Program::start(front);
    first.kill();
    second.ok(&format!("open {} 1", ussd.bus));
    let refused = second.call("run 20");
    let image = image_until(&bus, 1, "a latch", |i| !i.is_live());
    assert_eq!(
        image.latch_reason_name(),
        "controller replaced",
        "{front:?}"
    );
    assert_eq!(image.sent_stw1, OFF1, "{front:?}");
    // The diagnostics follow within their publication period.
    let deadline = Instant::now() + Duration::from_secs(2);
    let mut counters = bus.diag(addr(1)).unwrap().counters;
    while counters.replacements == 0 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(10));
        counters = bus.diag(addr(1)).unwrap().counters;
    }
    assert_eq!(
        (counters.replacements, counters.watchdog_trips),
        (1, 0),
        "{front:?}"
    );
    // Whether the run came before or after ussd showed the trip, it ran nothing.
    if refused != Reply::Ok {
        assert_eq!(refused.kind(), "tripped", "{front:?}");
    }
    assert_eq!(second.call("run 20").kind(), "tripped", "{front:?}");
    second.ok("rearm");
    second.ok("run 20");
    image_until(&bus, 1, "ON on the wire", |i| i.sent_stw1 == RUN);
    second.exit();
}

/// STOP-NOWAIT: a stop from one thread of a program is not held back by a long call of another
/// thread on the same handle (here a wait for a state that does not come).
fn a_stop_never_waits_for_another_thread(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut p = opened(front, &ussd, 1);
    runs(&mut p, &bus);
    // S3 does not come while the drive runs (S4) or coasts (S1): the wait lasts its 4 s.
    p.spawn("wait_state 3 4000");
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(p.call("coast"), Reply::Ok, "{front:?}");
    // The coast answered while the other thread still waits, and it is on the wire.
    assert!(
        !p.held.iter().any(|l| l.starts_with("<& ")),
        "{front:?}: the coast waited for the other thread: {:?}",
        p.held
    );
    image_until(&bus, 1, "OFF2 on the wire", |i| i.sent_stw1 == OFF2);
    // A timeout: `timeout` in C, `wait_timeout` in Rust and Python.
    let waited = p.answer("<&");
    assert!(waited.kind().ends_with("timeout"), "{front:?}: {waited:?}");
    p.exit();
}

/// WATCHDOG (a gap is a trip): a program paused (SIGSTOP) longer than the drive's watchdog time trips its
/// drive, and when it resumes (SIGCONT) nothing it or its library does restarts the motor: its
/// next ON is `tripped` or `stalled`, until its explicit re-arm.
fn a_paused_program_trips_and_does_not_resume(front: FrontEnd) {
    use nix::sys::signal::Signal;
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut p = opened(front, &ussd, 1);
    runs(&mut p, &bus);
    p.signal(Signal::SIGSTOP);
    let image = image_until(&bus, 1, "the trip", |i| !i.is_live());
    std::thread::sleep(Duration::from_millis(300));
    p.signal(Signal::SIGCONT);
    assert_eq!(image.latch_reason_name(), "controller stale", "{front:?}");
    let resumed = p.call("run 10");
    assert!(
        matches!(resumed.kind(), "tripped" | "stalled"),
        "{front:?}: {resumed:?}"
    );
    never(
        &bus,
        1,
        Duration::from_millis(300),
        "ON after the pause",
        |i| i.sent_stw1 == RUN || i.is_live(),
    );
    runs(&mut p, &bus);
    p.exit();
}

/// DEAD: a program killed (SIGKILL) while its drive runs trips it within the watchdog
/// time: the drive gets its safe command, latched, counted as a watchdog trip.
fn a_killed_program_trips_its_drive(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut p = opened(front, &ussd, 1);
    runs(&mut p, &bus);
    p.kill();
    let image = image_until(&bus, 1, "the trip", |i| !i.is_live() && i.sent_stw1 == OFF1);
    assert_eq!(image.latch_reason_name(), "controller stale", "{front:?}");
    never(
        &bus,
        1,
        Duration::from_millis(300),
        "ON after the kill",
        |i| i.sent_stw1 == RUN || i.is_live(),
    );
}

/// STW1-VALID: words ussd would refuse and latch the drive for (STW1 bit 10 clear, another
/// word count) are refused before the wire, in every language: nothing of them reaches ussd,
/// and no telegram without bit 10 goes out.
fn words_ussd_would_refuse_never_leave_the_program(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut p = opened(front, &ussd, 1);
    runs(&mut p, &bus);
    for words in ["0x007F 0x2000", "0x047F", "0x047F 0x2000 0x0000"] {
        let refused = p.call(&format!("set_words {words}"));
        assert_eq!(
            refused.kind(),
            "invalid_sample",
            "{front:?} {words}: {refused:?}"
        );
    }
    // Nothing reached ussd: no telegram without bit 10, no sample it had to reject.
    never(
        &bus,
        1,
        Duration::from_millis(300),
        "a refused word on the wire",
        |i| i.sent_stw1 & 0x0400 == 0 || i.latch_reason_name() == "sample rejected",
    );
    p.exit();
}

/// STOP-ANYWHERE while ussd's heartbeat is late (found by the adversarial review): a
/// controller's own coast while ussd is paused (SIGSTOP, 0.7 s: its heartbeat says "gone") was
/// refused with `ussd_gone` and its ON words kept, so the program's next keepalives republished
/// ON when ussd came back within the drive's watchdog time. The coast goes out whatever the
/// heartbeat says, and the words stay a stop.
fn a_stop_goes_out_while_ussds_heartbeat_is_late(front: FrontEnd) {
    use nix::sys::signal::{Signal, kill};
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "watchdog_ms = 2000")]);
    let bus = ussd.bus();
    let mut p = opened(front, &ussd, 1);
    runs(&mut p, &bus);
    let pid = nix::unistd::Pid::from_raw(i32::try_from(ussd.child.id()).unwrap());
    kill(pid, Signal::SIGSTOP).unwrap();
    std::thread::sleep(Duration::from_millis(700));
    let coasted = p.call("coast");
    kill(pid, Signal::SIGCONT).unwrap();
    assert!(
        matches!(coasted.kind(), "ok" | "ussd_gone"),
        "{front:?}: {coasted:?}"
    );
    // The program goes on with its loop.
    for _ in 0..10 {
        let _ = p.call("keepalive");
        std::thread::sleep(Duration::from_millis(50));
    }
    image_until(&bus, 1, "the coast on the wire", |i| i.sent_stw1 == OFF2);
    never(
        &bus,
        1,
        Duration::from_millis(300),
        "ON after the coast",
        |i| i.sent_stw1 == RUN,
    );
    p.exit();
}

/// STOP-NOWAIT without losing the stop (found by the review of issue 32): with no lock held
/// through a call, an ON of one thread that waits for ussd to take the re-arm of another, and a
/// coast of a third: the coast names the acknowledged latch, so ussd takes it as the re-arm, and
/// the waiting ON then saw the drive live and ran it. The waiting ON is dropped instead
/// (`superseded`): the stop is the program's later word. 31 drives at 9600 baud, so the re-arm
/// takes a telegram or two.
fn an_on_waiting_for_the_re_arm_never_undoes_a_later_stop(front: FrontEnd) {
    let _serial = serial();
    let drives: Vec<(u8, &str)> = (1..=31).map(|a| (a, "")).collect();
    let ussd = Ussd::start("baud = 9600", &drives);
    let bus = ussd.bus();
    // Until ussd has read drive 1's reference frequency (its own reads take a few of the
    // line's 1.3 s cycles) an ON in Hz is refused as `reference_unknown`: wait for it, so the
    // ON below waits for the re-arm alone.
    let watch = bus.watch(addr(1)).unwrap();
    let until = Instant::now() + Duration::from_secs(20);
    while watch.info().reference().is_none() {
        assert!(Instant::now() < until, "drive 1's reference never read");
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut p = opened(front, &ussd, 1);
    p.spawn("rearm");
    std::thread::sleep(Duration::from_millis(5));
    p.spawn("run 10");
    std::thread::sleep(Duration::from_millis(5));
    p.ok("coast");
    never(
        &bus,
        1,
        Duration::from_millis(1500),
        "ON after the coast",
        |i| i.sent_stw1 == RUN,
    );
    let (first, second) = (p.answer("<&"), p.answer("<&"));
    let kinds = [first.kind(), second.kind()];
    assert!(
        !kinds.contains(&"ok") || kinds.iter().any(|k| ["superseded", "tripped"].contains(k)),
        "{front:?}: {first:?} {second:?}"
    );
    p.exit();
}

/// LATCH (a latch never weakens a stop): a program's own coast stays the drive's stop through
/// its fault acknowledgement (the edge goes out as OFF2 with bit 7, never as OFF1 or ON) and
/// through its death (SIGKILL: the drive latches stale and keeps OFF2, not its safe command
/// OFF1). The rules are `Gate::stop_for` and `Controller::acknowledge_fault`, fixed after an
/// adversarial run; this scenario gives each scriptable front-end its own test of them.
fn a_programs_own_coast_stays_through_its_acknowledgement_and_its_death(front: FrontEnd) {
    let _serial = serial();
    let ussd = Ussd::start("", &[(1, "")]);
    let bus = ussd.bus();
    let mut p = opened(front, &ussd, 1);
    runs(&mut p, &bus);
    p.ok("coast");
    image_until(&bus, 1, "OFF2 on the wire", |i| i.sent_stw1 == OFF2);
    p.spawn("acknowledge 2000");
    let watch = bus.watch(addr(1)).unwrap();
    let mut edge = false;
    let end = Instant::now() + Duration::from_millis(400);
    while Instant::now() < end {
        let i = watch.latest();
        assert!(
            matches!(i.sent_stw1, OFF2 | OFF2_ACK),
            "{front:?}: during the acknowledgement the drive got {:#06x}: {i:?}",
            i.sent_stw1
        );
        edge |= i.sent_stw1 == OFF2_ACK;
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(p.answer("<&"), Reply::Ok, "{front:?}: the acknowledgement");
    assert!(edge, "{front:?}: no acknowledgement edge on the wire");
    p.kill();
    let image = image_until(&bus, 1, "the trip", |i| !i.is_live());
    assert_eq!(image.latch_reason_name(), "controller stale", "{front:?}");
    assert_eq!(
        image.sent_stw1, OFF2,
        "{front:?}: the latch weakened the coast"
    );
    never(
        &bus,
        1,
        Duration::from_millis(300),
        "the coast weakened after the kill",
        |i| i.sent_stw1 != OFF2,
    );
}

/// SCALE (no drive runs at a speed nobody commanded): the program runs the drive at 30 Hz by
/// its P2000 of 60 Hz (written to RAM only), and the drive is power-cycled: it comes back with
/// its EEPROM's 50 Hz. ussd reads the reference again when the drive answers and latches it
/// ("reference changed"): the program's setpoint was 50 % of 60 Hz and would run the motor at
/// 25 Hz. Its next ON is `tripped`; after its re-arm the same 30 Hz are scaled by 50 Hz. The
/// watchdog is long, so the power cycle is all that can latch the drive.
fn a_changed_reference_stops_the_program_and_its_hz_are_scaled_anew(front: FrontEnd) {
    let _serial = serial();
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1", "--power-off-ms", "300"]);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "watchdog_ms = 5000")]);
    let bus = ussd.bus();
    bus.write(addr(1), param(3), uss_protocol::Value::Word(3), false)
        .unwrap();
    bus.write(
        addr(1),
        param(2000),
        uss_protocol::Value::from_f32(60.0),
        false,
    )
    .unwrap();
    let mut p = opened(front, &ussd, 1);
    p.ok("rearm");
    p.ok("run 30");
    let half = 0x2000;
    image_until(&bus, 1, "30 Hz of 60 on the wire", |i| {
        i.sent_stw1 == RUN && i.sent_setpoint == half
    });
    let pid = nix::unistd::Pid::from_raw(i32::try_from(sim.child.id()).unwrap());
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGUSR1).unwrap();
    let latched = image_until(&bus, 1, "the latch", |i| !i.is_live());
    assert_eq!(
        latched.latch_reason_name(),
        "reference changed",
        "{front:?}"
    );
    assert_eq!(p.call("run 30").kind(), "tripped", "{front:?}");
    // The latch is published at once: an image may still show the telegram that went out
    // before it (its exchange's time is older than the latch). None after it carries an ON.
    never(
        &bus,
        1,
        Duration::from_millis(200),
        "an ON after the change",
        |i| i.sent_stw1 == RUN && i.timestamp_ns > latched.latched_since_ns,
    );
    p.ok("rearm");
    p.ok("run 30");
    // 30 of 50 Hz: 60 % of 0x4000.
    let scaled = uss_client::Setpoint::try_from_hz(30.0, 50.0)
        .unwrap()
        .word();
    image_until(&bus, 1, "30 Hz of 50 on the wire", |i| {
        i.sent_stw1 == RUN && i.sent_setpoint == scaled
    });
    p.exit();
}

macro_rules! front_ends {
    ($($scenario:ident),* $(,)?) => {
        $(
            mod $scenario {
                use super::FrontEnd;
                #[test]
                fn rust() {
                    super::$scenario(FrontEnd::Rust);
                }
                #[test]
                fn c() {
                    super::$scenario(FrontEnd::C);
                }
                #[test]
                fn cpp() {
                    super::$scenario(FrontEnd::Cpp);
                }
                #[test]
                fn python() {
                    super::$scenario(FrontEnd::Python);
                }
            }
        )*
    };
}

front_ends!(
    opening_is_no_rearm,
    an_operators_stop_survives_a_reconnect,
    a_stop_between_the_ask_and_the_rearm_wins,
    a_program_whose_clock_runs_ahead_re_arms_no_later_stop,
    a_replaced_controller_is_a_trip,
    a_stop_never_waits_for_another_thread,
    a_paused_program_trips_and_does_not_resume,
    a_killed_program_trips_its_drive,
    words_ussd_would_refuse_never_leave_the_program,
    a_stop_goes_out_while_ussds_heartbeat_is_late,
    an_on_waiting_for_the_re_arm_never_undoes_a_later_stop,
    a_programs_own_coast_stays_through_its_acknowledgement_and_its_death,
    a_changed_reference_stops_the_program_and_its_hz_are_scaled_anew,
);

/// docs/SAFETY.md is executable: every rule of its rule list has a row in its table of
/// scenarios, and every cell names tests that exist (a scenario of this file that runs per
/// front-end) or says `n/a:` with its reason. A rule added without its scenarios, a test renamed
/// or removed, fails here.
#[test]
fn every_rule_has_a_scenario_for_every_front_end() {
    const FRONT_ENDS: [&str; 7] = [
        "Rust",
        "C",
        "C++",
        "Python",
        "ussctl",
        "LinuxCNC",
        "Zenoh client",
    ];
    let spec = std::fs::read_to_string(root().join("docs/SAFETY.md")).unwrap();
    let section = |title: &str| -> Vec<Vec<String>> {
        let start = spec
            .find(title)
            .unwrap_or_else(|| panic!("docs/SAFETY.md has no {title:?}"));
        spec[start..]
            .lines()
            .skip(1)
            .skip_while(|l| !l.starts_with('|'))
            .take_while(|l| l.starts_with('|'))
            .map(|l| {
                l.trim_matches('|')
                    .split('|')
                    .map(|c| c.trim().to_owned())
                    .collect()
            })
            .collect()
    };
    let rules: Vec<String> = section("## Rules")
        .iter()
        .skip(2)
        .map(|row| row[0].trim_matches('`').to_owned())
        .collect();
    assert!(rules.len() >= 10, "{rules:?}");
    let table = section("## Scenarios per front-end");
    assert_eq!(table[0][1..], FRONT_ENDS, "the table's front-ends");
    let this = std::fs::read_to_string(root().join("tests/tests/conformance.rs")).unwrap();
    let per_front_end = &this[this.find("\nfront_ends!(").unwrap()..];
    let mut covered = Vec::new();
    for row in &table[2..] {
        let rule = row[0].trim_matches('`');
        assert!(
            rules.iter().any(|r| r == rule),
            "{rule}: not in the rule list"
        );
        assert_eq!(row.len(), 8, "{rule}: one cell per front-end");
        for (front, cell) in FRONT_ENDS.iter().zip(&row[1..]) {
            if let Some(reason) = cell.strip_prefix("n/a:") {
                assert!(
                    reason.trim().len() > 10,
                    "{rule}, {front}: n/a needs its reason"
                );
                continue;
            }
            for reference in cell.split("<br>") {
                let reference = reference.trim().trim_matches('`');
                let (path, name) = reference
                    .rsplit_once("::")
                    .unwrap_or_else(|| panic!("{rule}, {front}: {reference:?} is no file::test"));
                let source = std::fs::read_to_string(root().join(path))
                    .unwrap_or_else(|e| panic!("{rule}, {front}: {path}: {e}"));
                assert!(
                    source.contains(&format!("fn {name}("))
                        || source.contains(&format!("def {name}(")),
                    "{rule}, {front}: {path} has no test {name}"
                );
                if path == "tests/tests/conformance.rs" {
                    assert!(
                        per_front_end.contains(&format!("    {name},")),
                        "{rule}, {front}: {name} does not run per front-end (front_ends!)"
                    );
                }
            }
        }
        covered.push(rule.to_owned());
    }
    for rule in &rules {
        assert!(
            covered.contains(rule),
            "{rule}: no scenarios in docs/SAFETY.md"
        );
    }
}
