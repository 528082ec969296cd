//! `ussctl top` in a real terminal (tmux, on a server of the test's own): what it shows of a
//! running ussd with simulated drives, the selected drive's detail, the operator stops with
//! their confirmation (a refused one sends nothing; a confirmed one stops a drive a running
//! `ussctl run` controls), ussd killed (STALE) and restarted, and a bus without ussd.
//!
//! Without tmux the test says it is skipped; CI installs tmux and sets `USS_REQUIRE_TMUX`, so
//! there it cannot be skipped.

#![allow(clippy::unwrap_used)]

use std::process::{Command, Output};
use std::time::{Duration, Instant};
use uss_integration_tests::{Ussd, binary};

/// A tmux server of this test's own, with one session running a command.
struct Tmux {
    socket: String,
}

impl Tmux {
    fn run(&self, args: &[&str]) -> Output {
        Command::new("tmux")
            .args(["-L", &self.socket])
            .args(args)
            .output()
            .unwrap()
    }

    /// Starts `command` in a 200 x 50 terminal; the pane stays after it ends and says how.
    fn start(name: &str, command: &str) -> Option<Tmux> {
        Self::start_sized(name, command, 200)
    }

    /// [`Tmux::start`] in a terminal `width` columns wide.
    fn start_sized(name: &str, command: &str, width: u16) -> Option<Tmux> {
        let tmux = Tmux {
            socket: format!("uss-top-{}-{name}", std::process::id()),
        };
        let shell = format!("{command}; echo \"EXITED $?\"; sleep 600");
        let started = Command::new("tmux")
            .args(["-L", &tmux.socket, "new-session", "-d", "-s", "top"])
            .args(["-x", &width.to_string(), "-y", "50", &shell])
            .status();
        match started {
            Ok(s) if s.success() => Some(tmux),
            _ if std::env::var_os("USS_REQUIRE_TMUX").is_none() => {
                eprintln!("SKIPPED: tmux does not run; install it with `apt-get install tmux`");
                None
            }
            other => panic!("tmux does not run ({other:?}) but USS_REQUIRE_TMUX is set"),
        }
    }

    fn screen(&self) -> String {
        String::from_utf8_lossy(&self.run(&["capture-pane", "-p", "-t", "top"]).stdout).into_owned()
    }

    fn keys(&self, keys: &[&str]) {
        for k in keys {
            self.run(&["send-keys", "-t", "top", k]);
            std::thread::sleep(Duration::from_millis(150));
        }
    }

    /// Waits until the screen shows what `done` looks for; returns that screen.
    fn wait(&self, what: &str, done: impl Fn(&str) -> bool) -> String {
        let deadline = Instant::now() + Duration::from_secs(15);
        loop {
            let screen = self.screen();
            if done(&screen) {
                return screen;
            }
            assert!(
                Instant::now() < deadline,
                "the screen never showed {what}:\n{screen}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn wait_for(&self, text: &str) -> String {
        self.wait(text, |s| s.contains(text))
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        self.run(&["kill-server"]);
    }
}

/// The table row of drive `address` on `screen`.
fn row(screen: &str, address: u8) -> &str {
    screen
        .lines()
        .find(|l| {
            l.trim_start_matches('│')
                .trim_start_matches('>')
                .trim_start()
                .starts_with(&format!("{address} "))
        })
        .unwrap_or_else(|| panic!("no row of drive {address}:\n{screen}"))
}

#[test]
fn top_shows_the_bus_stops_drives_when_confirmed_and_follows_ussd() {
    let mut ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let bus = ussd.bus.clone();
    let ussctl = binary("ussctl", "ussctl");
    let Some(tmux) = Tmux::start("main", &format!("{} --bus {bus} top", ussctl.display())) else {
        return;
    };

    // The status bar, both drives, the selected drive's detail with the drive's own counters.
    let screen = tmux.wait("drive 1's own counters", |s| {
        s.contains("r2024 error-free") && s.contains("fault buffer: empty")
    });
    let pid = ussd.child.id();
    for wanted in [
        format!(" bus {bus} "),
        format!("ussd {pid} running, heartbeat fresh"),
        "exchanges/s".to_owned(),
        "line up".to_owned(),
        "RT ".to_owned(),
        "drive 1 - reference 50 Hz, PZD 2, PKW 4".to_owned(),
        "timing: exchange p50".to_owned(),
    ] {
        assert!(screen.contains(&wanted), "no {wanted:?} on\n{screen}");
    }
    for address in [1, 2] {
        let r = row(&screen, address);
        assert!(r.contains("yes") && r.contains("S2"), "{r}");
        assert!(r.contains("latched: ussd started, OFF1"), "{r}");
    }
    assert!(row(&screen, 1).contains('>'), "drive 1 selected first");
    // The sim's r2024 counts the telegrams it took without error: more than none.
    let counted = screen
        .split("r2024 error-free ")
        .nth(1)
        .and_then(|t| t.split(',').next())
        .and_then(|n| n.trim().parse::<u64>().ok())
        .unwrap();
    assert!(counted > 0, "{screen}");

    // Down selects drive 2; a stop asks first, and "no" sends nothing.
    tmux.keys(&["Down"]);
    tmux.wait_for("drive 2 - reference");
    tmux.keys(&["s"]);
    tmux.wait_for(
        "Stop (OFF1, along the ramp) drive 2? It stays latched until its controller re-arms it.",
    );
    tmux.keys(&["n"]);
    let screen = tmux.wait_for("cancelled: nothing was sent");
    assert!(
        row(&screen, 2).contains("latched: ussd started"),
        "{screen}"
    );

    // A controller runs drive 1; "stop every drive" confirmed stops it: the controller is told.
    let mut run = ussd.ussctl(&["run", "1", "--hz", "10"]);
    run.says("running");
    // Live (from the input image) and its controller's process (from the diagnostics, which
    // ussd publishes every 50 ms: a frame may show the one before the other).
    let run_pid = run.pid().to_string();
    tmux.wait("drive 1 live under ussctl run", |s| {
        row(s, 1).contains("live") && row(s, 1).contains(&run_pid)
    });
    tmux.keys(&["S"]);
    tmux.wait_for("Stop (OFF1, along the ramp) EVERY drive of bus");
    tmux.keys(&["y"]);
    let screen = tmux.wait_for("OFF1 sent to every drive of bus");
    assert!(screen.contains("(2 drives)"), "{screen}");
    let (status, _, stderr) = run.finish();
    assert!(!status.success(), "{stderr}");
    assert!(
        stderr.contains("an operator sent OFF1 from process"),
        "{stderr}"
    );
    // The run has ended: its process controls nothing now, and the row no longer names it
    // (it kept the last controller's process id for good).
    tmux.wait(
        "drive 1 latched by the operator, without a controller",
        |s| row(s, 1).contains("latched: operator stop, OFF1") && !row(s, 1).contains(&run_pid),
    );
    // The coast key on the selected drive 2.
    tmux.keys(&["c"]);
    tmux.wait_for("Coast (OFF2, pulses off at once) drive 2?");
    tmux.keys(&["y"]);
    tmux.wait_for("OFF2 sent to drive 2");
    tmux.wait("drive 2 coasting", |s| {
        row(s, 2).contains("operator stop, OFF2")
    });

    // ussd killed: the last picture, marked stale; restarted: live again, new process.
    ussd.kill();
    let screen = tmux.wait("ussd gone", |s| s.contains("GONE") && s.contains("STALE"));
    assert!(screen.contains(&format!("ussd {pid} GONE")), "{screen}");
    ussd.restart();
    let pid = ussd.child.id();
    tmux.wait_for(&format!("ussd {pid} running, heartbeat fresh"));
    // The header follows the new heartbeat first; each drive's row follows with the new
    // ussd's first image of it (until then it says `stale`, in its state column).
    tmux.wait("drive 1 as the new ussd shows it", |s| {
        !s.contains("STALE") && row(s, 1).contains("latched: ussd started")
    });

    tmux.keys(&["q"]);
    tmux.wait_for("EXITED 0");
}

/// `top` in a tmux of its own (`name`) on a bus no ussd serves, once it says it keeps trying;
/// `None` where tmux does not run (and need not). Also the bus's name.
fn top_without_ussd(name: &str) -> Option<(Tmux, String)> {
    let ussctl = binary("ussctl", "ussctl");
    let bus = format!("top-{name}-{}", std::process::id());
    let tmux = Tmux::start(name, &format!("{} --bus {bus} top", ussctl.display()))?;
    tmux.wait_for(&format!("NO USSD: ussd is not running on {bus}"));
    tmux.wait_for("trying again every second");
    Some((tmux, bus))
}

#[test]
fn top_without_ussd_says_so_and_keeps_trying() {
    let Some((tmux, _)) = top_without_ussd("none") else {
        return;
    };
    tmux.keys(&["q"]);
    tmux.wait_for("EXITED 0");
}

/// A `top` whose terminal goes away (its tmux server killed, an ssh connection lost) ends: it
/// does not spin on the dead terminal, and it does not ignore SIGTERM (the adversarial run
/// found it at 62-90 % CPU, deaf to SIGTERM, after its terminal was gone).
#[test]
fn top_ends_when_its_terminal_goes_away() {
    let Some((tmux, bus)) = top_without_ussd("hangup") else {
        return;
    };
    let pids = || {
        let out = Command::new("pgrep")
            .args(["-f", "--", &format!("--bus {bus} top")])
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout)
            .split_whitespace()
            .filter_map(|p| p.parse::<i32>().ok())
            .filter(|&p| {
                std::fs::read_to_string(format!("/proc/{p}/comm"))
                    .is_ok_and(|c| c.trim() == "ussctl")
            })
            .collect::<Vec<_>>()
    };
    let top = pids();
    assert_eq!(top.len(), 1, "{top:?}");
    tmux.run(&["kill-server"]);
    let deadline = Instant::now() + Duration::from_secs(5);
    while !pids().is_empty() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    let left = pids();
    for &p in &left {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(p),
            nix::sys::signal::Signal::SIGKILL,
        );
    }
    assert!(
        left.is_empty(),
        "top still runs 5 s after its terminal went: {left:?}"
    );
}

/// Issue 47, item 5: at 80 columns (a default terminal) the table dropped the address and
/// state columns and clipped values (good `2063` for 20630). It fits 80 columns as top and
/// htop do: the drive, whether it answers, its control and state first, each value whole.
#[test]
fn top_fits_80_columns_with_the_drive_and_its_state() {
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    let ussctl = binary("ussctl", "ussctl");
    let command = format!("{} --bus {} top", ussctl.display(), ussd.bus);
    let Some(tmux) = Tmux::start_sized("narrow", &command, 80) else {
        return;
    };
    let screen = tmux.wait("the table's header", |s| {
        s.contains("addr") && s.contains("state")
    });
    for title in ["addr", "online", "control", "state", "actual Hz"] {
        assert!(screen.contains(title), "{title}:\n{screen}");
    }
    let one = row(&screen, 1);
    assert!(one.contains("yes") && one.contains("S2"), "{one}\n{screen}");
    assert!(screen.lines().all(|l| l.chars().count() <= 80), "{screen}");
}
