//! What a ussd may do to the shared-memory root (`USS_RT_SHM`), found by issue 47's sweep with
//! real processes: two ussds started at one moment on an empty root both made it as each asked
//! (the last one winning: a group ussd's members were cut off); a root naming a shared
//! directory (`/dev/shm` itself) or one inside a running ussd's root was taken over, its mode
//! changed to 0700; a client whose node was named `ussd-<bus>` made ussd refuse that bus as
//! served. Each test works in a directory of its own under /dev/shm: nothing outside changes.
#![allow(clippy::unwrap_used)]

use std::os::unix::fs::PermissionsExt as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};
use uss_integration_tests::binary;

/// A directory of this test under /dev/shm (mode 0755), removed when dropped.
struct Place(PathBuf);

impl Place {
    fn new(name: &str) -> Place {
        let path = PathBuf::from(format!("/dev/shm/uss-test-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).unwrap();
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
        Place(path)
    }
}

impl Drop for Place {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn ussd(root: &Path) -> Command {
    let mut c = Command::new(binary("uss-master", "ussd"));
    c.env("USS_RT_SHM", root)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    c
}

fn mode(path: &Path) -> u32 {
    std::fs::metadata(path).unwrap().permissions().mode() & 0o7777
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

#[test]
fn two_ussds_started_at_one_moment_never_both_make_the_root() {
    let pid = std::process::id();
    for round in 0..4 {
        let place = Place::new(&format!("race{round}"));
        let root = place.0.join("root");
        // One with a group (gid 0, mode 2770), one owner-only (0700): they cannot both run.
        let config = place.0.join("group.toml");
        std::fs::write(
            &config,
            format!(
                "access_group = \"root\"\n\n[[bus]]\nname = \"ra{pid}r{round}\"\ndevice = \
                 \"sim\"\n\n[[bus.drive]]\naddress = 1\n"
            ),
        )
        .unwrap();
        let group = ussd(&root)
            .arg("--config")
            .arg(&config)
            .args(["--duration", "2"])
            .spawn()
            .unwrap();
        let alone = ussd(&root)
            .args(["--bus", &format!("rb{pid}r{round}"), "--duration", "2"])
            .spawn()
            .unwrap();
        let (group, alone) = (
            group.wait_with_output().unwrap(),
            alone.wait_with_output().unwrap(),
        );
        let ran = [&group, &alone]
            .iter()
            .filter(|o| o.status.success())
            .count();
        let refused = [&group, &alone]
            .iter()
            .filter(|o| !o.status.success() && text(o).contains("is in use by ussd process"))
            .count();
        assert_eq!(
            (ran, refused),
            (1, 1),
            "round {round}:\n--- group ussd:\n{}\n--- owner-only ussd:\n{}",
            text(&group),
            text(&alone)
        );
        let expected = if group.status.success() {
            0o2770
        } else {
            0o700
        };
        assert_eq!(
            mode(&root),
            expected,
            "round {round}: the root as its ussd made it"
        );
    }
}

#[test]
fn a_directory_that_is_no_uss_rt_root_is_never_changed() {
    let pid = std::process::id();
    let place = Place::new("notroot");
    // A shared directory, as /dev/shm and /tmp are.
    let shared = place.0.join("shared");
    std::fs::create_dir(&shared).unwrap();
    std::fs::set_permissions(&shared, std::fs::Permissions::from_mode(0o1777)).unwrap();
    // A directory of someone's own files.
    let data = place.0.join("data");
    std::fs::create_dir(&data).unwrap();
    std::fs::write(data.join("notes.txt"), "mine").unwrap();
    std::fs::set_permissions(&data, std::fs::Permissions::from_mode(0o755)).unwrap();
    for (dir, said, was) in [
        (&shared, "a shared directory (mode 1777, sticky)", 0o1777),
        (&data, "it holds \"notes.txt\"", 0o755),
    ] {
        let out = ussd(dir)
            .args(["--bus", &format!("nr{pid}"), "--duration", "1"])
            .output()
            .unwrap();
        let all = text(&out);
        assert!(
            !out.status.success()
                && all.contains("is not a shared-memory root of uss-rt")
                && all.contains(said)
                && all.contains("nothing was changed"),
            "{all}"
        );
        assert_eq!(mode(dir), was, "{}", dir.display());
    }
    // Inside the root of a running ussd: its iceoryx2 directories.
    let root = place.0.join("root");
    let mut running = ussd(&root)
        .args(["--bus", &format!("in{pid}"), "--duration", "20"])
        .spawn()
        .unwrap();
    let until = Instant::now() + Duration::from_secs(20);
    while !(root.join("nodes").is_dir() && root.join("services").is_dir()) {
        assert!(Instant::now() < until, "ussd made no root");
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(500));
    for inner in ["nodes", "services"] {
        let dir = root.join(inner);
        let was = mode(&dir);
        let out = ussd(&dir)
            .args(["--bus", &format!("in{pid}b"), "--duration", "1"])
            .output()
            .unwrap();
        let all = text(&out);
        assert!(
            !out.status.success() && all.contains("is not a shared-memory root of uss-rt"),
            "{inner}: {all}"
        );
        assert_eq!(mode(&dir), was, "{inner}");
    }
    assert_eq!(mode(&root), 0o700, "the running ussd's root");
    assert!(running.try_wait().unwrap().is_none(), "the running ussd");
    let _ = running.kill();
    let _ = running.wait();
}

/// A node name is what a process says of itself: a client named `ussd-<bus>` is no ussd, and
/// a ussd for that bus starts.
#[test]
fn a_client_named_like_a_ussd_is_not_taken_for_one() {
    let pid = std::process::id();
    let place = Place::new("fake");
    let root = place.0.join("root");
    let mut real = ussd(&root)
        .args(["--bus", &format!("fr{pid}"), "--duration", "20"])
        .spawn()
        .unwrap();
    // A client of the real bus, in a process of its own (the iceoryx2 root is read once per
    // process), whose node says it is the ussd of another bus.
    let forged = format!("ussd-ff{pid}");
    let script = format!(
        "import time\nimport uss_rt\n\
         for _ in range(100):\n    try:\n        b = uss_rt.open_bus('fr{pid}', node_name={forged:?})\n        break\n    \
         except Exception:\n        time.sleep(0.1)\nprint('open', flush=True)\ntime.sleep(8)\n"
    );
    let mut client = uss_integration_tests::python()
        .args(["-c", &script])
        .env("USS_RT_SHM", &root)
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufRead::read_line(
        &mut std::io::BufReader::new(client.stdout.as_mut().unwrap()),
        &mut line,
    )
    .unwrap();
    assert_eq!(line.trim(), "open");
    let out = ussd(&root)
        .args(["--bus", &format!("ff{pid}"), "--duration", "1"])
        .output()
        .unwrap();
    let all = text(&out);
    assert!(out.status.success(), "{all}");
    for child in [&mut real, &mut client] {
        let _ = child.kill();
        let _ = child.wait();
    }
}
