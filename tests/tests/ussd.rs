//! `ussd` as a daemon: against `uss-sim --pty` in a separate process with faults and an unplugged
//! drive, the embedded default, `--check-config` and `--require-rt`.
#![allow(clippy::unwrap_used)]

use std::process::Command;
use uss_integration_tests::{SimProcess, binary};

fn ussd() -> Command {
    Command::new(binary("uss-master", "ussd"))
}

fn config_file(name: &str, text: &str) -> std::path::PathBuf {
    let path = std::env::temp_dir().join(format!("ussd-test-{}-{name}.toml", std::process::id()));
    std::fs::write(&path, text).unwrap();
    path
}

/// The counters of `drive N:` in the last summary ussd printed.
fn final_line(out: &str, address: u8) -> &str {
    let tail = &out[out.rfind("final").expect("a final summary")..];
    tail.lines()
        .find(|l| l.contains(&format!("drive {address:2}:")))
        .unwrap()
}

fn counter(line: &str, name: &str) -> u64 {
    let at = line
        .find(&format!("{name} "))
        .unwrap_or_else(|| panic!("no {name} in {line}"))
        + name.len()
        + 1;
    line[at..]
        .split(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn ussd_polls_a_pty_bus_with_faults_and_its_summary_tells_the_truth() {
    let sim = SimProcess::start(&[
        "--baud",
        "57600",
        "--drive",
        "1",
        "--drive",
        "2:drop=0.1,bcc=0.05",
        "--drive",
        "3:unplug=1000..2500",
    ]);
    let config = config_file(
        "pty",
        &format!(
            "[[bus]]\nname = \"line1\"\ndevice = \"{}\"\nbaud = 57600\nretries = 2\noffline_probe_ms = 200\n\n\
             [[bus.drive]]\naddress = 1\n\n[[bus.drive]]\naddress = 2\n\n[[bus.drive]]\naddress = 3\n",
            sim.path
        ),
    );
    let out = ussd()
        .args([
            "--config",
            config.to_str().unwrap(),
            "--summary-every",
            "1",
            "--duration",
            "4",
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("drive 3 does not respond (no response): offline"),
        "{stdout}"
    );
    assert!(stdout.contains("drive 3 online"), "{stdout}");
    assert!(stdout.contains("bus line1: 57600 baud"), "{stdout}");
    // A pty carries replies faster than its baud rate: the wire timed nothing, so no
    // efficiency is claimed (issue 35: it printed "efficiency 0.000 of wire floor").
    assert!(!stdout.contains("of wire floor"), "{stdout}");
    let d1 = final_line(&stdout, 1);
    let d2 = final_line(&stdout, 2);
    let d3 = final_line(&stdout, 3);
    // No controller: every drive got the safe command OFF1, which takes it from S1 to S2.
    for line in [d1, d2, d3] {
        assert!(line.contains("online  S2"), "{line}");
    }
    // Drive 1 has no injected faults; a reply can still miss its 20 ms when the machine is busy.
    assert!(counter(d1, "rejected") * 100 <= counter(d1, "sent"), "{d1}");
    assert!(
        counter(d2, "timeouts") > 0 && counter(d2, "bcc") > 0,
        "{d2}"
    );
    assert!(counter(d3, "timeouts") >= 3, "{d3}");
    let sim_out = sim.stop();
    let sim_d1 = sim_out.lines().find(|l| l.contains("drive  1:")).unwrap();
    // Every telegram ussd sent to drive 1 arrived intact, and nothing else did, unless a reply
    // was late (the machine was busy): then the retry can meet the late reply on the line,
    // which uss-sim rejects as a start-pause violation: at most one telegram spoilt, and one
    // rejection, per timeout. uss-sim also sees the safe command ussd sends drive 1 at shutdown,
    // after its last summary; it can meet a reply of drive 2 still on its way (seen once in CI:
    // good 541 = sent 541, rejected 1 for the start pause), so one more rejection is allowed.
    // A late reply can also be drive 2's, arriving while ussd already talks to drive 1: ussd then
    // counts it on drive 1 as a wrong-address reply, not a timeout (seen once in CI), so both are
    // late replies here.
    let sent = counter(d1, "sent");
    let timeouts = counter(d1, "timeouts") + counter(d1, "wrong-addr");
    let (good, rejected) = (counter(sim_d1, "good"), counter(sim_d1, "rejected"));
    assert!(
        good <= sent + 1 && sent.saturating_sub(good) <= timeouts && rejected <= timeouts + 1,
        "uss-sim: {sim_d1}\nussd: {d1}"
    );
    let _ = std::fs::remove_file(config);
}

#[test]
fn ussd_without_arguments_runs_the_embedded_simulated_bus() {
    // Its own bus name (the embedded default's is bus0): the tests pass beside a user's ussd.
    let bus = format!("embedded{}", std::process::id());
    let out = ussd()
        .args(["--bus", &bus, "--summary-every", "1", "--duration", "2.5"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{stdout}");
    assert!(stdout.contains("running the embedded default"), "{stdout}");
    assert!(
        stdout.contains(&format!("bus {bus}: 115200 baud")),
        "{stdout}"
    );
    // A live summary every second for 2.5 s, and the final one: not a summary at every wake-up
    // of the housekeeping thread (since 2bfcf5b it logged one every 10 ms after the first).
    let summaries = stdout.matches(&format!("bus {bus}: 115200 baud")).count();
    assert!(summaries <= 4, "{summaries} summaries in 2.5 s:\n{stdout}");
    for a in 1..=4 {
        let line = final_line(&stdout, a);
        assert!(
            line.contains("online  S2") && counter(line, "good") > 100,
            "{line}"
        );
        assert_eq!(counter(line, "rejected"), 0, "{line}");
    }
    let efficiency: f64 = stdout
        .rsplit("efficiency ")
        .next()
        .and_then(|s| s.split(' ').next())
        .and_then(|s| s.parse().ok())
        .unwrap();
    assert!(efficiency > 0.5 && efficiency <= 1.001, "{efficiency}");
}

#[test]
fn check_config_prints_the_effective_configuration_or_names_the_bad_line() {
    let good = config_file(
        "good",
        "[[bus]]\nname = \"b\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 7\npzd = 4\n",
    );
    let out = ussd().arg("--check-config").arg(&good).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("address = 7") && text.contains("pzd = 4") && text.contains("retries = 2"),
        "{text}"
    );
    let bad = config_file(
        "bad",
        "[[bus]]\nname = \"b\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 7\npzd = 17\n",
    );
    let out = ussd().arg("--check-config").arg(&bad).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(":7:") && err.contains("pzd = 17"), "{err}");
    let out = ussd().arg("--config").arg(&bad).output().unwrap();
    assert_eq!(out.status.code(), Some(2), "nothing starts on a bad config");
    for p in [good, bad] {
        let _ = std::fs::remove_file(p);
    }
}

/// A device that exists but is no tty (a directory, /dev/null) is refused by `--check-config`
/// and by `--config` with the file, line and field; a device that is not there yet is a warning
/// said as one, and the configuration passes (issue 35).
#[test]
fn check_config_refuses_a_device_that_is_no_tty_and_warns_of_one_not_there_yet() {
    let with_device = |name: &str, device: &str| {
        config_file(
            name,
            &format!(
                "[[bus]]\nname = \"b\"\ndevice = \"{device}\"\n\n[[bus.drive]]\naddress = 7\n"
            ),
        )
    };
    for (device, what) in [("/tmp", "is a directory"), ("/dev/null", "mem class")] {
        let file = with_device("notty", device);
        for flag in ["--check-config", "--config"] {
            let out = ussd().arg(flag).arg(&file).output().unwrap();
            let err = String::from_utf8_lossy(&out.stderr);
            println!("ussd {flag} with device {device}: {err}");
            assert_eq!(out.status.code(), Some(2), "{flag} {device}: {err}");
            assert!(
                err.contains(&format!(
                    "{}:3:10: bus \"b\": device = \"{device}\"",
                    file.display()
                )) && err.contains(what)
                    && err.contains("not a serial device"),
                "{flag} {device}: {err}"
            );
        }
        let _ = std::fs::remove_file(file);
    }
    let later = with_device("later", "/dev/ttyUSB-uss-not-plugged-in");
    let out = ussd().arg("--check-config").arg(&later).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("ussd: warning: ")
            && err.contains("device /dev/ttyUSB-uss-not-plugged-in does not exist now"),
        "{err}"
    );
    let _ = std::fs::remove_file(later);
}

/// `ussd --qualify` measures as the bus thread runs (the configuration's priority and CPU),
/// gives a verdict at the bus's rate with the USS rules at every fast rate, checks what breaks a
/// deployment, and draws the histogram; its exit code is the verdict (0 holds, 1 does not).
#[test]
fn qualify_measures_like_the_bus_thread_and_gives_a_verdict_with_its_fixes() {
    let config = config_file(
        "qualify",
        "[[bus]]\nname = \"q\"\ndevice = \"sim\"\nbaud = 187500\ncpu = 0\npriority = 70\n\n\
         [[bus.drive]]\naddress = 1\n",
    );
    let plot = std::env::temp_dir().join(format!("qualify-{}.svg", std::process::id()));
    let out = ussd()
        .args(["--qualify", "--seconds", "1", "--plot"])
        .arg(&plot)
        .arg("--config")
        .arg(&config)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}");
    assert!(
        matches!(out.status.code(), Some(0 | 1)),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for expected in [
        "bus q (187500 baud): 1 s of wake-ups every 1000 us at SCHED_FIFO 70, CPU 0",
        "wake-up latency: p50 ",
        "start pause (2 tz)",
        "* 187500    117.3 us: ",
        "  verdict: ",
        "bus q is the built-in simulated bus: no adapter to check",
    ] {
        assert!(text.contains(expected), "{expected:?} in\n{text}");
    }
    let holds = text.contains("this machine holds bus q's timing");
    assert_eq!(out.status.code() == Some(0), holds, "{text}");
    // In a pipe, no progress bar (issue 47, item 5: it shows on a terminal only).
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("measuring"), "{err}");
    let svg = std::fs::read_to_string(&plot).unwrap();
    assert!(
        svg.starts_with("<svg")
            && svg.contains("start pause at 187500 baud: 117 us")
            && svg.contains("wake-up latency (us, log scale)"),
        "{svg}"
    );
    let _ = std::fs::remove_file(&plot);
    let _ = std::fs::remove_file(&config);
}

/// Issue 47, item 5: `--qualify` ran a minute silent. On a terminal (script(1) gives it one) it
/// shows how far it is, and clears the bar before its report.
#[test]
fn qualify_shows_its_progress_on_a_terminal() {
    let config = config_file(
        "qualify-tty",
        "[[bus]]\nname = \"qt\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 1\n",
    );
    let command = format!(
        "{} --qualify --seconds 2 --config {}",
        binary("uss-master", "ussd").display(),
        config.display()
    );
    let out = std::process::Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&config);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("measuring ") && text.contains(" of 2 s"),
        "{text}"
    );
    // The report comes after the bar is cleared (an erase-line), not on its line.
    let report = text.find("bus qt (").unwrap_or_else(|| panic!("{text}"));
    assert!(text[..report].ends_with("\x1b[2K"), "{text}");
}

#[test]
fn require_rt_is_fatal_exactly_when_real_time_is_incomplete() {
    // Its own bus name: another test runs the embedded default's bus0 at the same time.
    let bus = format!("rt{}", std::process::id());
    let config = config_file(
        "rt",
        &format!("[[bus]]\nname = \"{bus}\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 1\n"),
    );
    let out = ussd()
        .args([
            "--require-rt",
            "--duration",
            "0.5",
            "--config",
            config.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&config);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let incomplete = stdout.contains("real-time set-up incomplete");
    if incomplete {
        assert_eq!(out.status.code(), Some(1), "{stdout}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("--require-rt") && err.contains(&format!("bus {bus}")),
            "{err}"
        );
    } else {
        assert!(out.status.success(), "{stdout}");
        assert!(stdout.contains("realtime"), "{stdout}");
    }
}

/// Issue 47, item 4: a `--require-rt` failure printed about 900 characters three times, nested,
/// after a "final" summary of a bus that never ran. As a user without real-time rights
/// (setpriv), it is said once on stderr (and once in the log, a file of its own here), each
/// failed step on a line of its own with what to do, and no bus summary follows.
#[test]
fn a_require_rt_failure_is_said_once_with_what_to_do_and_no_summary() {
    use std::os::unix::fs::PermissionsExt as _;
    // SAFETY: geteuid has no preconditions and cannot fail.
    if unsafe { nix::libc::geteuid() } != 0 {
        println!("skipped: running ussd as a user without real-time rights needs root");
        return;
    }
    let pid = std::process::id();
    let exe = std::env::temp_dir().join(format!("ussd-rt-{pid}"));
    std::fs::copy(binary("uss-master", "ussd"), &exe).unwrap();
    std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
    let root = format!("/dev/shm/uss-rt-rt-{pid}");
    let out = Command::new("setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups"])
        .arg(&exe)
        .args([
            "--bus",
            &format!("rtn{pid}"),
            "--require-rt",
            "--duration",
            "2",
        ])
        .env(uss_shm_types::service::ROOT_ENV, &root)
        .output()
        .expect("setpriv (util-linux)");
    let _ = std::fs::remove_file(&exe);
    let _ = std::fs::remove_dir_all(&root);
    let (log, err) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(1), "{log}{err}");
    assert_eq!(err.matches("--require-rt given").count(), 1, "{err}");
    assert!(
        err.contains("so nothing was polled:\n  SCHED_FIFO failed (EPERM"),
        "{err}"
    );
    assert!(
        err.contains("\n  run ussd as the packaged unit does"),
        "{err}"
    );
    assert!(
        !log.contains("final") && !log.contains("running best effort"),
        "no summary of a bus that never ran: {log}"
    );
}

/// `deploy/`: the example configuration is valid, and the unit's `ExecStart` options are ones
/// ussd takes (run here with a simulated bus in place of the example's adapter).
#[test]
fn the_deploy_files_fit_this_ussd() {
    let deploy = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy");
    let mut example = std::fs::read_to_string(deploy.join("ussd.toml.example")).unwrap();
    if std::thread::available_parallelism().map_or(1, usize::from) < 2 {
        // It pins its bus to CPU 1, which a one-CPU machine does not have.
        example = example.replace("cpu = 1 ", "cpu = 0 ");
    }
    let example = config_file("example", &example);
    let out = ussd().arg("--check-config").arg(&example).output().unwrap();
    let _ = std::fs::remove_file(&example);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let effective = String::from_utf8_lossy(&out.stdout);
    assert!(
        effective.contains("device = \"/dev/uss-line1\""),
        "{effective}"
    );

    // What the deploy files cite is where they say: the installed guide's files (the package
    // installs docs/ as /usr/share/doc/uss-rt/docs/), and the README's headings (issue 47:
    // they cited README sections that were gone).
    let readme = std::fs::read_to_string(deploy.join("../README.md")).unwrap();
    for name in ["ussd.service", "ussd.toml.example", "debian/ussd.toml"] {
        let text = std::fs::read_to_string(deploy.join(name)).unwrap();
        for cited in text.split("/usr/share/doc/uss-rt/").skip(1) {
            let path: String = cited
                .chars()
                .take_while(|c| !c.is_whitespace() && !matches!(c, ')' | ',' | ';'))
                .collect();
            let path = path.trim_end_matches('.');
            // docs/ from the checkout's docs/, the example from deploy/.
            assert!(
                deploy.join("..").join(path).exists() || deploy.join(path).exists(),
                "deploy/{name} cites /usr/share/doc/uss-rt/{path}, which the package does not install"
            );
        }
        for cited in text.split("README \"").skip(1) {
            let heading = cited.split('"').next().unwrap();
            assert!(
                readme
                    .lines()
                    .any(|l| l.trim_start_matches('#').trim() == heading),
                "deploy/{name} cites README \"{heading}\", which README.md does not have"
            );
        }
    }

    // The other units' programs take the options their ExecStart gives (clap refuses an
    // unknown one before --help).
    for (unit, package, program) in [
        ("uss-exporter.service", "uss-exporter", "uss-exporter"),
        ("uss-zenoh.service", "uss-zenoh", "uss-zenoh"),
    ] {
        let text = std::fs::read_to_string(deploy.join(unit)).unwrap();
        let exec = text
            .lines()
            .find_map(|l| l.strip_prefix("ExecStart="))
            .unwrap_or_else(|| panic!("no ExecStart= in {unit}"));
        let mut args = exec.split_whitespace();
        assert_eq!(
            args.next(),
            Some(format!("/usr/bin/{program}").as_str()),
            "{unit}"
        );
        let out = Command::new(binary(package, program))
            .args(args)
            .arg("--help")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "deploy/{unit}: {exec}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }

    let unit = std::fs::read_to_string(deploy.join("ussd.service")).unwrap();
    let key = |k: &str| {
        unit.lines()
            .find_map(|l| l.strip_prefix(&format!("{k}=")))
            .unwrap_or_else(|| panic!("no {k}= in ussd.service"))
    };
    assert_eq!(key("Type"), "notify");
    assert_eq!(key("LimitMEMLOCK"), "infinity");
    let exec = key("ExecStart");
    let mut args: Vec<&str> = exec.split_whitespace().skip(1).collect();
    let at = args.iter().position(|a| *a == "--config").unwrap();
    let bus = format!("deploy{}", std::process::id());
    let sim = config_file(
        "deploy",
        &format!("[[bus]]\nname = \"{bus}\"\ndevice = \"sim\"\n\n[[bus.drive]]\naddress = 1\n"),
    );
    args[at + 1] = sim.to_str().unwrap();
    // Real time is the machine's business, not the unit's: without it ussd would refuse.
    args.retain(|a| *a != "--require-rt");
    let out = ussd()
        .args(&args)
        .args(["--duration", "0.3"])
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&sim);
    assert!(
        out.status.success(),
        "ussd {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// guide "Access": a process of another user cannot connect, and is told why.
#[test]
fn a_process_of_another_user_cannot_connect_and_is_told_why() {
    // SAFETY: geteuid has no preconditions and cannot fail.
    if unsafe { nix::libc::geteuid() } != 0 {
        println!("skipped: running ussctl as another user needs root");
        return;
    }
    let ussd = uss_integration_tests::Ussd::start("", &[(1, "")]);
    // A copy every user may run (the build directory may not be theirs to enter).
    let ussctl = std::env::temp_dir().join(format!("ussctl-access-{}", std::process::id()));
    std::fs::copy(binary("ussctl", "ussctl"), &ussctl).unwrap();
    std::fs::set_permissions(&ussctl, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let as_nobody = Command::new("setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups"])
        .arg(&ussctl)
        .args(["--bus", &ussd.bus, "status"])
        .output()
        .expect("setpriv (util-linux)");
    let _ = std::fs::remove_file(&ussctl);
    let err = String::from_utf8_lossy(&as_nobody.stderr);
    assert_eq!(as_nobody.status.code(), Some(1), "{err}");
    assert!(
        err.contains("run ussd and this program as the same user (or root)"),
        "{err}"
    );
    let (status, out, _) = ussd.ussctl(&["status"]).finish();
    assert!(status.success(), "{out}");
}

/// A second ussd on a bus that is already served says so in plain words, once, and leaves the
/// first one serving.
/// A group made for one test (groupadd), removed when it goes.
struct TestGroup {
    name: String,
    gid: u32,
}

impl TestGroup {
    fn new(name: String) -> Self {
        let made = Command::new("groupadd").arg(&name).output().unwrap();
        assert!(
            made.status.success(),
            "{}",
            String::from_utf8_lossy(&made.stderr)
        );
        let gid = nix::unistd::Group::from_name(&name)
            .unwrap()
            .unwrap()
            .gid
            .as_raw();
        Self { name, gid }
    }
}

impl Drop for TestGroup {
    fn drop(&mut self) {
        let _ = Command::new("groupdel").arg(&self.name).output();
    }
}

/// `ussctl` on a bus and a shared-memory root, as other users (setpriv).
struct Ussctl {
    /// A copy every user may run (the build directory may not be theirs to enter).
    exe: std::path::PathBuf,
    bus: String,
    root: std::path::PathBuf,
}

impl Ussctl {
    fn new(bus: &str, root: &std::path::Path) -> Self {
        use std::os::unix::fs::PermissionsExt as _;
        let exe = std::env::temp_dir().join(format!("ussctl-group-{}", std::process::id()));
        std::fs::copy(binary("ussctl", "ussctl"), &exe).unwrap();
        std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
        Self {
            exe,
            bus: bus.to_owned(),
            root: root.to_owned(),
        }
    }

    /// `ussctl ARGS` as user `uid` with the supplementary groups `groups`.
    fn run_as(&self, uid: u32, groups: &str, args: &[&str]) -> std::process::Output {
        Command::new("setpriv")
            .args([
                &format!("--reuid={uid}"),
                &format!("--regid={uid}"),
                &format!("--groups={groups}"),
            ])
            .arg(&self.exe)
            .args(["--bus", &self.bus])
            .args(args)
            .env(uss_shm_types::service::ROOT_ENV, &self.root)
            .output()
            .expect("setpriv (util-linux)")
    }
}

impl Drop for Ussctl {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.exe);
    }
}

/// guide "Access": with `access_group`, processes of other users in that group monitor and
/// control drives (`ussctl status`, `ussctl run`); a user outside it is refused and told to
/// join the group; ussd made its root directory the group's, mode 2770.
#[test]
fn members_of_the_access_group_use_the_services_as_their_own_users_and_others_are_refused() {
    use std::os::unix::fs::MetadataExt as _;
    // SAFETY: geteuid has no preconditions and cannot fail.
    if unsafe { nix::libc::geteuid() } != 0 {
        println!("skipped: making a group and running processes as other users needs root");
        return;
    }
    let pid = std::process::id();
    let group = TestGroup::new(format!("ussg{}", pid % 1_000_000));
    // A root of this test's own, so the test's other ussd processes keep theirs.
    let root = std::path::PathBuf::from(format!("/dev/shm/uss-rt-access-{pid}"));
    let bus = format!("grp{pid}");
    let config = config_file(
        "access",
        &format!(
            "access_group = \"{}\"\n\n[[bus]]\nname = \"{bus}\"\ndevice = \"sim\"\n\n\
             [[bus.drive]]\naddress = 1\n",
            group.name
        ),
    );
    let daemon = ussd()
        .arg("--config")
        .arg(&config)
        .env(uss_shm_types::service::ROOT_ENV, &root)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let ussctl = Ussctl::new(&bus, &root);
    let member = (61_000 + pid % 1000, group.gid.to_string());
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    // Until the member's status shows the drive online (ussd may not have polled it yet).
    let status = loop {
        let out = ussctl.run_as(member.0, &member.1, &["status"]);
        let status = String::from_utf8_lossy(&out.stdout).into_owned();
        if out.status.success() && status.contains("   1  yes") {
            break status;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "a member's ussctl status: {status}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    assert!(status.contains(&format!("bus {bus}: running")), "{status}");
    let meta = std::fs::metadata(&root).unwrap();
    assert_eq!((meta.mode() & 0o7777, meta.gid()), (0o2770, group.gid));
    // A member controls a drive: takes it, re-arms, runs, stops and hands it back.
    let run = ussctl.run_as(
        member.0,
        &member.1,
        &["run", "1", "--hz", "5", "--for", "1"],
    );
    assert!(
        run.status.success(),
        "a member's ussctl run: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(String::from_utf8_lossy(&run.stdout).contains("drive 1: ran; OFF1 sent"));
    // A user outside the group is refused, and told what to do.
    let out = ussctl.run_as(62_000 + pid % 1000, "65534", &["status"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let hint = format!(
        "or as a member of group {} (ussd's access_group)",
        group.name
    );
    assert!(err.contains(&hint), "{err}");
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(daemon.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    let log = String::from_utf8_lossy(&daemon.wait_with_output().unwrap().stdout).into_owned();
    let said = format!(
        "the members of group {} (gid {}) may use",
        group.name, group.gid
    );
    assert!(log.contains(&said), "{log}");
    let _ = std::fs::remove_dir_all(&root);
    let _ = std::fs::remove_file(&config);
}

/// A child killed and reaped should the test fail before it ends it.
struct Reaped(Option<std::process::Child>);

impl Reaped {
    fn id(&self) -> u32 {
        self.0.as_ref().map_or(0, std::process::Child::id)
    }
}

impl Drop for Reaped {
    fn drop(&mut self) {
        if let Some(mut child) = self.0.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// `exe` (a ussd every user may run) with `config` on shared-memory root `root`, as user `uid`
/// of group `gid`, its output piped.
fn ussd_as(
    uid: u32,
    gid: u32,
    exe: &std::path::Path,
    config: &std::path::Path,
    root: &std::path::Path,
) -> std::process::Child {
    Command::new("setpriv")
        .args([
            &format!("--reuid={uid}"),
            &format!("--regid={gid}"),
            &format!("--groups={gid}"),
        ])
        .arg(exe)
        .arg("--config")
        .arg(config)
        .env(uss_shm_types::service::ROOT_ENV, root)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("setpriv (util-linux)")
}

/// Issue 47, item 2: a ussd run as root (the first-bus chapter's `ussd`) beside a service's
/// ussd of another user with `access_group` made the shared-memory root root's, mode 0700: the
/// service's clients lost it, its restart failed and its stop panicked. A ussd never changes
/// what a running ussd owns: it refuses first, naming the running one, and the service, its
/// root and its clients go on untouched.
#[test]
fn a_second_ussd_of_another_user_leaves_a_running_one_and_its_clients_untouched() {
    use std::os::unix::fs::{MetadataExt as _, PermissionsExt as _};
    // SAFETY: geteuid has no preconditions and cannot fail.
    if unsafe { nix::libc::geteuid() } != 0 {
        println!("skipped: running ussd as another user needs root");
        return;
    }
    let pid = std::process::id();
    let group = TestGroup::new(format!("usss{}", pid % 1_000_000));
    let root = std::path::PathBuf::from(format!("/dev/shm/uss-rt-second-{pid}"));
    let bus = format!("svc{pid}");
    let config = config_file(
        "service",
        &format!(
            "access_group = \"{}\"\n\n[[bus]]\nname = \"{bus}\"\ndevice = \"sim\"\n\n\
             [[bus.drive]]\naddress = 1\n",
            group.name
        ),
    );
    std::fs::set_permissions(&config, std::fs::Permissions::from_mode(0o644)).unwrap();
    // The service's ussd, as a user of its own in the group (as the package runs it as `uss`).
    let exe = std::env::temp_dir().join(format!("ussd-service-{pid}"));
    std::fs::copy(binary("uss-master", "ussd"), &exe).unwrap();
    std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
    let service_user = 63_000 + pid % 1000;
    let mut service = Reaped(Some(ussd_as(service_user, group.gid, &exe, &config, &root)));
    let ussctl = Ussctl::new(&bus, &root);
    let member = (64_000 + pid % 1000, group.gid.to_string());
    let online = || {
        let out = ussctl.run_as(member.0, &member.1, &["status"]);
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        (out.status.success() && text.contains("   1  yes"), text)
    };
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    while !online().0 {
        assert!(std::time::Instant::now() < deadline, "{}", online().1);
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let owner = |m: &std::fs::Metadata| (m.uid(), m.gid(), m.mode() & 0o7777);
    let before = owner(&std::fs::metadata(&root).unwrap());
    assert_eq!(before, (service_user, group.gid, 0o2770));
    // Root's ussd of its own bus, without access_group, as the first-bus chapter runs it.
    let second = ussd()
        .args(["--bus", &format!("own{pid}"), "--duration", "2"])
        .env(uss_shm_types::service::ROOT_ENV, &root)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{err}");
    let named = format!(
        "is in use by ussd process {} (user {service_user}, bus {bus})",
        service.id()
    );
    assert!(
        err.contains(&named) && err.contains("nothing was changed"),
        "{err}"
    );
    assert_eq!(owner(&std::fs::metadata(&root).unwrap()), before);
    // Root's ussd of the service's own bus: served, said before anything is made.
    let third = ussd()
        .args(["--bus", &bus, "--duration", "2"])
        .env(uss_shm_types::service::ROOT_ENV, &root)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&third.stderr);
    assert!(
        err.contains(&format!(
            "bus {bus} is already served by ussd process {}",
            service.id()
        )),
        "{err}"
    );
    assert!(!String::from_utf8_lossy(&third.stdout).contains("shared memory in"));
    assert_eq!(owner(&std::fs::metadata(&root).unwrap()), before);
    // The service's clients never noticed; it stops cleanly.
    let (still, text) = online();
    assert!(
        still,
        "a member's ussctl status after the second ussd: {text}"
    );
    let _ = nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(service.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    );
    let out = service.0.take().unwrap().wait_with_output().unwrap();
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success() && !log.contains("panicked"), "{log}");
    let _ = std::fs::remove_dir_all(&root);
    let _ = std::fs::remove_file(&config);
    let _ = std::fs::remove_file(&exe);
}

#[test]
fn a_second_ussd_on_a_served_bus_says_who_serves_it() {
    let mut first = uss_integration_tests::Ussd::start("", &[(1, "")]);
    let out = ussd()
        .args(["--bus", &first.bus, "--duration", "1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    let said = format!(
        "bus {} is already served by ussd process {}",
        first.bus,
        first.child.id()
    );
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.matches(&said).count(), 1, "{err}");
    // Refused before it made or said anything (issue 47: it logged its shared-memory line).
    let log = String::from_utf8_lossy(&out.stdout);
    assert!(!log.contains("shared memory in"), "{log}");
    assert!(first.is_running());
    let (status, text, _) = first.ussctl(&["status"]).finish();
    assert!(status.success(), "{text}");
}

/// Rule 3: a ussd that does not poll (paused: SIGSTOP, as a suspended machine or a starved CPU
/// would) is not shown as a healthy bus: `ussctl status` and `stats`, in the table and in
/// `--json`, show no drive online and fail with what the heartbeat says. (Right after it
/// resumes, its last diagnostics are older than their limit: the report's unit tests show those
/// rows stale.)
#[test]
fn a_paused_ussd_shows_no_drive_online() {
    use nix::sys::signal::{Signal, kill};
    use nix::unistd::Pid;
    let ussd = uss_integration_tests::Ussd::start("", &[(1, ""), (2, "")]);
    let (status, out, _) = ussd.ussctl(&["status"]).finish();
    assert!(status.success(), "{out}");
    let pid = Pid::from_raw(i32::try_from(ussd.child.id()).unwrap());
    kill(pid, Signal::SIGSTOP).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(600));
    let mut shown = Vec::new();
    for args in [
        &["status"][..],
        &["--json", "status"],
        &["stats"],
        &["--json", "stats"],
    ] {
        shown.push((args, ussd.ussctl(args).finish()));
    }
    kill(pid, Signal::SIGCONT).unwrap();
    for (args, (status, out, err)) in shown {
        assert_eq!(status.code(), Some(1), "{args:?}: {out}{err}");
        assert!(err.contains("is gone (no heartbeat"), "{args:?}: {err}");
        assert!(
            !out.contains(" yes ") && !out.contains("\"online\":true"),
            "{args:?}: {out}"
        );
    }
}

/// The role [`a_dead_node_child`] plays: set to the root it makes its node in.
const NODE_CHILD_ROOT: &str = "USSD_TEST_NODE_CHILD_ROOT";

/// Child of [`ussd_logs_only_the_dead_nodes_it_removed_and_names_what_it_cannot_remove`] (does
/// nothing in a test run): an iceoryx2 node of uss-rt in the root it is given, until killed.
#[test]
fn a_dead_node_child() {
    use iceoryx2::prelude::*;
    let Some(root) = std::env::var_os(NODE_CHILD_ROOT) else {
        return;
    };
    // SAFETY: this process has no other thread that reads the environment yet.
    unsafe { std::env::set_var(uss_shm_types::service::ROOT_ENV, root) };
    let node = NodeBuilder::new()
        .name(&NodeName::new("orphan").unwrap())
        .config(&uss_shm_types::service::config().unwrap())
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<uss_shm_types::service::Ipc>()
        .unwrap();
    println!("READY {}", node.id().value());
    loop {
        std::thread::sleep(std::time::Duration::from_secs(1));
    }
}

/// A client killed while iceoryx2 made or dropped its node leaves a node monitor whose details
/// are gone. iceoryx2 0.10 "cleans" such a node against its global configuration, not ours: it
/// counts it cleaned on every call and removes nothing. ussd said "cleaned up after dead client
/// processes" for it once a second, for ever (23 such leftovers on a test machine, 6 of this
/// kind). ussd says what it really removed, and names a leftover once.
#[test]
fn ussd_logs_only_the_dead_nodes_it_removed_and_names_what_it_cannot_remove() {
    use std::io::BufRead as _;
    let root = std::path::PathBuf::from(format!("/dev/shm/uss-test-orphan-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    // Two dead nodes: one iceoryx2 can clean, one whose details are gone.
    let mut ids = Vec::new();
    for _ in 0..2 {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args([
                "a_dead_node_child",
                "--exact",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(NODE_CHILD_ROOT, &root)
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        while !line.contains("READY ") {
            line.clear();
            assert_ne!(out.read_line(&mut line).unwrap(), 0, "the child ended");
        }
        ids.push(line[line.find("READY ").unwrap() + 6..].trim().to_owned());
        child.kill().unwrap();
        child.wait().unwrap();
    }
    let details = root.join("nodes").join(&ids[1]);
    assert!(details.is_dir(), "{} is not there", details.display());
    std::fs::remove_dir_all(&details).unwrap();

    let bus = format!("orphans{}", std::process::id());
    let out = ussd()
        .args(["--bus", &bus, "--summary-every", "10", "--duration", "3.5"])
        .env(uss_shm_types::service::ROOT_ENV, &root)
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&root);
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{stdout}");
    let cleaned: Vec<&str> = stdout
        .lines()
        .filter(|l| l.contains("cleaned up after dead client processes"))
        .collect();
    // The node iceoryx2 can clean went when ussd's node was made, before the first look.
    assert!(cleaned.is_empty(), "{stdout}");
    let named: Vec<&str> = stdout.lines().filter(|l| l.contains(&ids[1])).collect();
    assert_eq!(named.len(), 1, "{stdout}");
    assert!(named[0].contains("could not remove"), "{}", named[0]);
}
