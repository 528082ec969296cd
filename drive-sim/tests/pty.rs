//! End to end over a real pseudo-terminal: `uss-sim --pty` in its own process, the test as the
//! master opening the printed path with real termios (8E1) through the serialport crate.
#![allow(clippy::unwrap_used)]

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use uss_protocol::telegram::{MAX_TELEGRAM_BYTES, encode};
use uss_protocol::{Address, Adr, DriveState, Telegram, Zsw1};

const SIM: &str = env!("CARGO_BIN_EXE_uss-sim");

struct Sim {
    child: Child,
    path: String,
}

impl Sim {
    fn start(args: &[&str]) -> Sim {
        let mut child = Command::new(SIM)
            .args(["--pty", "--baud", "115200"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.as_mut().unwrap())
            .read_line(&mut line)
            .unwrap();
        let path = line
            .trim()
            .strip_prefix("PTY ")
            .unwrap_or_else(|| panic!("first line: {line:?}"))
            .to_owned();
        Sim { child, path }
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn open(path: &str) -> serialport::TTYPort {
    serialport::new(path, 115_200)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::Even)
        .stop_bits(serialport::StopBits::One)
        .timeout(Duration::from_millis(50))
        .open_native()
        .unwrap()
}

/// Sends a telegram and reads one reply by its LGE, or `None` after 100 ms of silence.
fn exchange(
    port: &mut serialport::TTYPort,
    address: u8,
    pkw: &[u16],
    pzd: &[u16],
) -> Option<Vec<u8>> {
    // Observe a generous start pause: the simulator enforces it.
    std::thread::sleep(Duration::from_millis(2));
    let mut buf = [0u8; MAX_TELEGRAM_BYTES];
    let n = encode(&mut buf, Adr::to(Address::new(address).unwrap()), pkw, pzd).unwrap();
    port.write_all(&buf[..n]).unwrap();
    let mut reply = Vec::new();
    let deadline = Instant::now() + Duration::from_millis(100);
    while Instant::now() < deadline {
        let mut chunk = [0u8; 64];
        match port.read(&mut chunk) {
            Ok(k) => reply.extend_from_slice(&chunk[..k]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("read: {e}"),
        }
        if reply.len() >= 2 && reply.len() >= reply[1] as usize + 2 {
            return Some(reply);
        }
    }
    assert!(reply.is_empty(), "partial reply {reply:02X?}");
    None
}

#[test]
fn raw_telegrams_over_a_pty_bring_a_drive_from_s1_to_running() {
    let sim = Sim::start(&["--drive", "3:pkw=4,pzd=2", "--drive", "5:pkw=127,pzd=2"]);
    let mut port = open(&sim.path);

    // STW1 0x047E to drive 3: S1 -> S2. Exact reply bytes: PKW zeros, ZSW1 of S2, HIW 0.
    let reply = exchange(&mut port, 3, &[0, 0, 0, 0], &[0x047E, 0]).unwrap();
    let zsw1 = Zsw1::READY_TO_SWITCH_ON
        | Zsw1::NO_OFF2
        | Zsw1::NO_OFF3
        | Zsw1::AT_SETPOINT
        | Zsw1::CONTROL_REQUESTED
        | Zsw1::NO_CURRENT_LIMIT
        | Zsw1::NO_HOLDING_BRAKE
        | Zsw1::NO_MOTOR_OVERLOAD
        | Zsw1::NO_INVERTER_OVERLOAD;
    let mut expected = [0u8; 16];
    encode(
        &mut expected,
        Adr::to(Address::new(3).unwrap()),
        &[0, 0, 0, 0],
        &[zsw1.bits(), 0],
    )
    .unwrap();
    assert_eq!(reply, expected);

    // 0x047F with 50 %: S4, and the actual value rises with the ramp.
    let reply = exchange(&mut port, 3, &[0, 0, 0, 0], &[0x047F, 0x2000]).unwrap();
    let t = Telegram::parse(&reply).unwrap();
    assert_eq!(
        DriveState::from_zsw1(Zsw1::from_bits_retain(u16::from_be_bytes([
            t.net()[8],
            t.net()[9]
        ]))),
        DriveState::OperationEnabled
    );
    std::thread::sleep(Duration::from_millis(300));
    let reply = exchange(&mut port, 3, &[0, 0, 0, 0], &[0x047F, 0x2000]).unwrap();
    let hiw = u16::from_be_bytes([reply[13], reply[14]]);
    assert!(hiw > 0 && hiw < 0x2000, "ramping: HIW 0x{hiw:04X}");

    // Read P1082 on drive 5 (variable PKW): a float in a 4-word reply.
    let reply = exchange(&mut port, 5, &[0x1000 | 1082, 0, 0, 0], &[0x047E, 0]).unwrap();
    assert_eq!(
        &reply[3..11],
        &[0x24, 0x3A, 0x00, 0x00, 0x42, 0x48, 0x00, 0x00]
    );
    // Read P0700 on drive 5: a word in a 3-word reply (LGE 12).
    let reply = exchange(&mut port, 5, &[0x1000 | 700, 0, 0, 0], &[0x047E, 0]).unwrap();
    assert_eq!(reply[1], 12);
    assert_eq!(&reply[3..9], &[0x12, 0xBC, 0x00, 0x00, 0x00, 0x05]);

    // No drive at address 9, a bad BCC, and a wrong length: silence, and the drive lives on.
    assert_eq!(exchange(&mut port, 9, &[0, 0, 0, 0], &[0x047E, 0]), None);
    std::thread::sleep(Duration::from_millis(2));
    port.write_all(&[
        0x02, 0x0E, 0x03, 0, 0, 0, 0, 0, 0, 0, 0, 0x04, 0x7E, 0, 0, 0x00,
    ])
    .unwrap();
    std::thread::sleep(Duration::from_millis(50));
    assert_eq!(exchange(&mut port, 3, &[0, 0, 0], &[0x047E, 0]), None);
    assert!(exchange(&mut port, 3, &[0, 0, 0, 0], &[0x047E, 0]).is_some());
}

#[test]
fn injected_faults_reach_the_master_over_the_pty() {
    let sim = Sim::start(&["--drive", "2:drop=0.5", "--seed", "3"]);
    let mut port = open(&sim.path);
    let answered = (0..40)
        .filter(|_| exchange(&mut port, 2, &[0, 0, 0, 0], &[0x047E, 0]).is_some())
        .count();
    assert!(
        (8..=32).contains(&answered),
        "{answered} of 40 answered with drop=0.5"
    );
}

#[test]
fn sigterm_stops_the_simulator_with_a_summary() {
    let mut sim = Sim::start(&["--drive", "1"]);
    let mut port = open(&sim.path);
    exchange(&mut port, 1, &[0, 0, 0, 0], &[0x047E, 0]).unwrap();
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(sim.child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    let status = sim.child.wait().unwrap();
    assert!(status.success());
    let mut out = String::new();
    sim.child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .unwrap();
    assert!(out.contains("stopped; final state:"), "{out}");
    assert!(
        out.contains("drive  1: PKW 4 PZD 2, S2 ready to switch on"),
        "{out}"
    );
    assert!(out.contains("good 1 rejected 0"), "{out}");
}

/// `--link PATH` (issue 47: the guide's scan runs on `./line`): the pty is reached by the link,
/// a stale link of a killed uss-sim is replaced, another file is refused untouched, and the link
/// goes with uss-sim.
#[test]
fn a_link_reaches_the_pty_and_goes_with_the_simulator() {
    let dir = std::env::temp_dir().join(format!("uss-sim-link-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let link = dir.join("line");
    // A link left behind by a uss-sim killed with SIGKILL.
    std::os::unix::fs::symlink("/dev/pts/nonexistent", &link).unwrap();
    let link_arg = link.to_str().unwrap();
    let mut sim = Sim::start(&["--link", link_arg, "--drive", "1"]);
    assert_eq!(
        std::fs::read_link(&link).unwrap().to_str(),
        Some(sim.path.as_str())
    );
    let mut port = open(link_arg);
    assert!(exchange(&mut port, 1, &[0, 0, 0, 0], &[0x047E, 0]).is_some());
    drop(port);
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(sim.child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    assert!(sim.child.wait().unwrap().success());
    assert!(std::fs::symlink_metadata(&link).is_err(), "the link stayed");
    // A link of a live pty (another uss-sim's, a terminal's) or to anything else is not
    // replaced.
    for to in ["/dev/pts/ptmx", "/etc/hostname"] {
        std::os::unix::fs::symlink(to, &link).unwrap();
        let out = Command::new(SIM)
            .args([
                "--pty",
                "--link",
                link_arg,
                "--drive",
                "1",
                "--duration",
                "1",
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{to}: {err}");
        assert!(err.contains("uss-sim replaces only such a link"), "{err}");
        assert_eq!(std::fs::read_link(&link).unwrap().to_str(), Some(to));
        std::fs::remove_file(&link).unwrap();
    }
    // A file of someone else's is no link to replace.
    std::fs::write(&link, "mine").unwrap();
    let out = Command::new(SIM)
        .args(["--pty", "--link", link_arg, "--drive", "1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("exists and is no symbolic link"), "{err}");
    assert_eq!(std::fs::read_to_string(&link).unwrap(), "mine");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_command_lines_exit_non_zero_with_a_clear_error() {
    let run = |args: &[&str]| {
        let out = Command::new(SIM).args(args).output().unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let (code, err) = run(&["--pty", "--drive", "40:pkw=4"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("address 40 is out of range"), "{err}");
    let (code, err) = run(&["--pty", "--drive", "1:pkw=5"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("0, 3, 4 or 127"), "{err}");
    let (code, err) = run(&["--pty", "--drive", "1", "--drive", "1"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("two drives have address 1"), "{err}");
    let (code, err) = run(&["--pty"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("give at least one --drive"), "{err}");
    let (code, _) = run(&["--drive", "1"]);
    assert_eq!(code, Some(2), "a mode is required");
    let (code, err) = run(&["--pty", "--drive", "1", "--baud", "0"]);
    assert_eq!(code, Some(2));
    assert!(err.contains("baud rate 0 is out of range"), "{err}");
    let (code, err) = run(&["--device", "/nonexistent/tty", "--drive", "1"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("cannot open /nonexistent/tty"), "{err}");
}

/// `uss-sim --demo | head -1`: the reader goes away after one line; the demo ends quietly
/// (it used to abort with exit 134 on the broken pipe).
#[test]
fn the_demo_ends_quietly_when_its_reader_goes_away() {
    use std::io::BufRead as _;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_uss-sim"))
        .arg("--demo")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    // The reader is dropped here: the demo's next line meets a closed pipe.
    assert!(first.starts_with("demo: 4 simulated drives"), "{first}");
    let out = child.wait_with_output().unwrap();
    assert!(
        out.status.success(),
        "{:?}: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
