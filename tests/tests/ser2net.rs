//! USS through a serial device server (issue 48): Debian's `ser2net` bridges a TCP port to a
//! `uss-sim --pty` line, as a ser2net host, a Moxa or a Lantronix server in TCP-server mode
//! bridges its RS485 port; ussd's bus is `device = "tcp://127.0.0.1:PORT"`. The drives are
//! polled through it without errors; ser2net killed is the line down (every drive offline, the
//! status says so); ser2net started again is the line back, every drive latched "line
//! restored", a parameter read through it true. `ussd --check-config` takes the device as
//! written.
//!
//! Without ser2net the test says so and passes; CI installs it and sets `USS_REQUIRE_SER2NET`,
//! so there it must run.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};
use uss_client::{Bus, LatchReason, Value};
use uss_integration_tests::{BusSpec, SimProcess, Ussd, addr, binary, monotonic_ns, param};

/// ser2net, or why not.
fn ser2net() -> Option<PathBuf> {
    let found = ["/usr/sbin/ser2net", "/usr/bin/ser2net"]
        .into_iter()
        .map(PathBuf::from)
        .find(|p| p.exists());
    match found {
        Some(p) => Some(p),
        None if std::env::var_os("USS_REQUIRE_SER2NET").is_none() => {
            println!("skipped: ser2net is not installed (apt-get install ser2net)");
            None
        }
        None => panic!("ser2net is not installed but USS_REQUIRE_SER2NET is set"),
    }
}

/// A TCP port free now on the loopback.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// ser2net in the foreground, serving `port` with the line `device` at 115200 8E1 (its own
/// YAML configuration, its own pid file; the modem lines ignored, a pty has none).
struct Server {
    child: Child,
    dir: PathBuf,
}

impl Server {
    fn start(ser2net: &PathBuf, port: u16, device: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("uss-ser2net-{}-{port}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let config = dir.join("ser2net.yaml");
        std::fs::write(
            &config,
            format!(
                "connection: &uss\n  accepter: tcp,127.0.0.1,{port}\n  connector: \
                 serialdev,{device},115200e81,local\n  options:\n    kickolduser: true\n"
            ),
        )
        .unwrap();
        let child = Command::new(ser2net)
            .arg("-n")
            .arg("-u")
            .arg("-P")
            .arg(dir.join("ser2net.pid"))
            .arg("-c")
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // Listening once a connection is taken (and let go at once).
        let deadline = Instant::now() + Duration::from_secs(10);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "ser2net never listened on {port}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        Self { child, dir }
    }

    /// SIGKILL: the server gone at once, as a device server that loses power.
    fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn status_when(bus: &Bus, what: &str, done: impl Fn(&uss_client::BusStatus) -> bool) {
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let s = bus.status().unwrap();
        if done(&s) {
            return;
        }
        assert!(Instant::now() < deadline, "{what}: bus status still {s:?}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

#[test]
fn a_bus_through_ser2net_polls_goes_down_with_it_and_comes_back_latched() {
    let Some(ser2net) = ser2net() else {
        return;
    };
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1", "--drive", "2"]);
    let port = free_port();
    let server = Server::start(&ser2net, port, &sim.path);
    let device = format!("tcp://127.0.0.1:{port}");
    let drives: &[(u8, &str)] = &[(1, ""), (2, "")];
    let spec = BusSpec {
        suffix: "",
        device: &device,
        keys: "baud = 115200",
        drives,
    };

    // The configuration check takes the device as written and says what it is.
    let config = std::env::temp_dir().join(format!("ussd-ser2net-{}.toml", std::process::id()));
    std::fs::write(
        &config,
        format!(
            "[[bus]]\nname = \"s2n\"\ndevice = \"{device}\"\nbaud = 115200\n\n[[bus.drive]]\n\
             address = 1\n"
        ),
    )
    .unwrap();
    let checked = Command::new(binary("uss-master", "ussd"))
        .arg("--check-config")
        .arg(&config)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&config);
    let out = String::from_utf8_lossy(&checked.stdout);
    assert!(checked.status.success(), "{out}");
    assert!(out.contains(&format!("device = \"{device}\"")), "{out}");
    assert!(out.contains("is a serial device server's port"), "{out}");

    let ussd = Ussd::start_buses(&[spec]);
    let bus = ussd.bus();
    // Polled through the server, without errors.
    let before = bus.diag(addr(1)).unwrap().counters;
    std::thread::sleep(Duration::from_millis(500));
    let after = bus.diag(addr(1)).unwrap().counters;
    let polls = after.good - before.good;
    println!("ser2net: drive 1 answered {polls} polls in 0.5 s through the server");
    assert!(polls > 20, "{before:?} -> {after:?}");
    assert_eq!(after.timeouts, 0, "{after:?}");
    assert_eq!(
        bus.read(addr(2), param(1082)),
        Ok(Value::Dword(0x4248_0000))
    );
    let log = ussd.log();
    assert!(
        log.contains("connected to the serial device server at 127.0.0.1"),
        "{log}"
    );
    assert!(log.contains("receive latency"), "{log}");

    // The server gone: the line is down, every drive offline.
    let killed_at = monotonic_ns();
    server.kill();
    status_when(&bus, "line down", uss_client::BusStatus::is_line_down);
    let down = bus.status().unwrap();
    println!(
        "ser2net: line down in the status {:.1} ms after ser2net was killed",
        down.line_down_since_ns.saturating_sub(killed_at) as f64 / 1e6
    );
    assert_eq!(
        down.line_fault_text().as_deref(),
        Some("the line was closed: a serial device unplugged, or its server's connection ended")
    );
    for d in [1, 2] {
        let i = bus
            .watch(addr(d))
            .unwrap()
            .wait_for(Duration::from_secs(5), "offline", |i| i.online == 0)
            .unwrap();
        assert_eq!(i.online, 0, "drive {d}");
    }

    // The server back on its port: ussd connects again, the drives come back latched.
    let started_at = monotonic_ns();
    let server = Server::start(&ser2net, port, &sim.path);
    status_when(&bus, "line back", |s| !s.is_line_down());
    println!(
        "ser2net: line back {:.0} ms after ser2net listened again ({} attempts)",
        (monotonic_ns() - started_at) as f64 / 1e6,
        bus.status().unwrap().reopen_attempts
    );
    for d in [1, 2] {
        let i = bus
            .watch(addr(d))
            .unwrap()
            .wait_for(Duration::from_secs(5), "online", |i| i.online == 1)
            .unwrap();
        assert_eq!(i.latch_reason, LatchReason::LineRestored.code(), "{i:?}");
        assert_eq!(i.sent_stw1, 0x047E, "drive {d} gets its safe command");
    }
    assert_eq!(
        bus.read(addr(2), param(1082)),
        Ok(Value::Dword(0x4248_0000))
    );
    assert_eq!(bus.status().unwrap().line_downs, 1);
    let log = ussd.log();
    assert!(log.contains("line reopened after"), "{log}");
    drop(server);
}
