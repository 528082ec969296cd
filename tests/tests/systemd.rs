//! ussd under systemd's notify protocol (`sd_notify(3)`), without systemd: a real ussd whose
//! `NOTIFY_SOCKET` is a datagram socket this test binds and reads, as systemd would, with
//! `WATCHDOG_USEC` set as `WatchdogSec=` sets it. One of its two simulated buses hangs
//! (`hang=` makes the virtual wire's send never return, like a wedged USB-serial driver).
#![allow(clippy::unwrap_used)]

use std::os::unix::net::UnixDatagram;
use std::time::{Duration, Instant};
use uss_client::ClientError;
use uss_integration_tests::{BusSpec, Ussd};

/// The notification socket, as systemd's: every datagram is one notification of
/// newline-separated `KEY=VALUE` lines.
struct NotifySocket {
    socket: UnixDatagram,
    path: std::path::PathBuf,
}

impl NotifySocket {
    /// A socket of this test (`name`): tests run in parallel.
    fn bind(name: &str) -> Self {
        let path =
            std::env::temp_dir().join(format!("ussd-notify-{}-{name}.sock", std::process::id()));
        let _ = std::fs::remove_file(&path);
        let socket = UnixDatagram::bind(&path).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(20)))
            .unwrap();
        Self { socket, path }
    }

    /// Every notification that arrived, waiting at most 20 ms for the first.
    fn take(&self) -> Vec<String> {
        let mut got = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = self.socket.recv(&mut buf) {
            got.push(String::from_utf8_lossy(&buf[..n]).into_owned());
        }
        got
    }

    /// Every notification that arrives during `d`.
    fn during(&self, d: Duration) -> Vec<String> {
        let from = Instant::now();
        let mut got = Vec::new();
        while from.elapsed() < d {
            got.extend(self.take());
        }
        got
    }
}

impl Drop for NotifySocket {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

fn keep_alives(notifications: &[String]) -> usize {
    notifications
        .iter()
        .filter(|n| n.lines().any(|l| l == "WATCHDOG=1"))
        .count()
}

#[test]
fn ussd_says_ready_feeds_the_watchdog_and_starves_it_when_a_bus_thread_hangs() {
    let notify = NotifySocket::bind("hang");
    // The watchdog as `WatchdogSec=0.4` sets it: a keep-alive is due every 0.2 s.
    let mut ussd = Ussd::start_buses_with_env(
        &[
            BusSpec {
                suffix: "a",
                device: "sim",
                keys: "",
                drives: &[(1, "")],
            },
            BusSpec {
                suffix: "b",
                device: "sim",
                keys: "",
                drives: &[(1, "sim.hang = 3000")],
            },
        ],
        &[
            ("NOTIFY_SOCKET", notify.path.to_str().unwrap()),
            ("WATCHDOG_USEC", "400000"),
        ],
    );
    let hung_bus = format!("{}b", ussd.bus);
    let bus_b = ussd.bus_named("b");

    // READY=1 first (every bus thread runs by then: both buses answered already), with a status.
    let mut seen = notify.take();
    let ready = seen
        .iter()
        .position(|n| n.lines().any(|l| l == "READY=1"))
        .unwrap_or_else(|| panic!("no READY=1: {seen:?}"));
    assert!(
        seen[ready].contains(&format!("STATUS=bus {}a: ", ussd.bus)),
        "{seen:?}"
    );
    assert_eq!(keep_alives(&seen[..ready]), 0, "a keep-alive before READY");

    // Keep-alives come while both bus threads move; bus b hangs 3 s after its start and is
    // found hung within its stall bound (1 s at 115200 baud).
    let hung = loop {
        seen.extend(notify.take());
        if let Some(line) = ussd.log_line("bus thread hangs", Duration::ZERO) {
            break line;
        }
        assert!(ussd.is_running(), "{}", ussd.log());
        assert!(
            keep_alives(&seen) < 100,
            "no hang reported after {} keep-alives: {}",
            keep_alives(&seen),
            ussd.log()
        );
    };
    seen.extend(notify.take());
    let before = keep_alives(&seen);
    assert!(before >= 5, "{before} keep-alives while both buses ran");
    assert!(hung.contains(&format!("bus={hung_bus}")), "{hung}");
    assert!(
        hung.contains("withholds systemd's watchdog keep-alive"),
        "{hung}"
    );

    // Clients of bus b are told: ussd stopped its heartbeat for the hung bus.
    let gone_from = Instant::now();
    while !matches!(bus_b.status(), Err(ClientError::UssdGone { .. })) {
        assert!(
            gone_from.elapsed() < Duration::from_secs(5),
            "clients of the hung bus are not told: {:?}",
            bus_b.status()
        );
        std::thread::sleep(Duration::from_millis(20));
    }

    // From then on no keep-alive: 1.5 s is over 7 keep-alive periods. Bus a polls on.
    let bus_a = ussd.bus_named("a");
    let polling = bus_a.status().unwrap();
    let after = notify.during(Duration::from_millis(1500));
    assert_eq!(
        keep_alives(&after),
        0,
        "keep-alives for a hung ussd: {after:?}"
    );
    let later = bus_a.status().unwrap();
    assert!(
        later.exchanges > polling.exchanges,
        "bus a stopped too: {polling:?} -> {later:?}"
    );

    // SIGTERM: STOPPING=1; the hung bus thread cannot stop, so ussd leaves it behind, says so
    // and exits 1 (systemd would restart it).
    let (_, code) = ussd.terminate();
    assert_eq!(code, Some(1), "{}", ussd.log());
    let stopping = notify.take();
    assert!(
        stopping
            .iter()
            .any(|n| n.lines().any(|l| l == "STOPPING=1")),
        "{stopping:?}"
    );
    let log = ussd.log();
    assert!(
        log.contains(&format!("bus {hung_bus}: its bus thread hangs")),
        "{log}"
    );
    println!(
        "systemd: {before} keep-alives while both buses ran, none in the 1.5 s after the hang was \
         found; ussd logged: {hung}"
    );
}

#[test]
fn a_line_down_past_its_limit_starves_the_watchdog_so_systemd_restarts_ussd() {
    let notify = NotifySocket::bind("line");
    // A serial bus whose adapter is gone (its udev name points nowhere): line down from the
    // start, reopened with backoff. Past 1.5 s down, a restart is what is left to try.
    let mut ussd = Ussd::launch(
        &[BusSpec {
            suffix: "",
            device: "/nonexistent/uss-adapter",
            keys: "baud = 115200\nline_down_limit_ms = 1500",
            drives: &[(1, "")],
        }],
        &[
            ("NOTIFY_SOCKET", notify.path.to_str().unwrap()),
            ("WATCHDOG_USEC", "400000"),
        ],
    );
    let started = Instant::now();
    let mut seen = Vec::new();
    let said = loop {
        seen.extend(notify.take());
        if let Some(line) = ussd.log_line("line down for", Duration::ZERO) {
            break line;
        }
        assert!(ussd.is_running(), "{}", ussd.log());
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "no line-down limit reported: {}",
            ussd.log()
        );
    };
    seen.extend(notify.take());
    let while_down = keep_alives(&seen);
    println!(
        "systemd: {while_down} keep-alives while the line was down within its limit, then: {said}"
    );
    assert!(while_down >= 3, "{while_down} keep-alives within the limit");
    assert!(
        said.contains("withholds systemd's watchdog keep-alive"),
        "{said}"
    );
    assert!(said.contains("line_down_limit_ms"), "{said}");
    let after = notify.during(Duration::from_millis(1500));
    assert_eq!(
        keep_alives(&after),
        0,
        "keep-alives past the limit: {after:?}"
    );
    assert!(
        ussd.is_running(),
        "ussd itself goes on until systemd restarts it"
    );
}
