//! What the multi-process tests in `tests/tests/` share: building and finding the workspace's
//! binaries, and running `uss-sim --pty` as a separate process.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Builds (if needed) and returns the path of a workspace binary. Integration tests only get
/// their own package's binaries from cargo, so other packages' binaries are built here with the
/// same cargo and profile.
pub fn binary(package: &str, name: &str) -> PathBuf {
    static BUILT: OnceLock<std::sync::Mutex<Vec<String>>> = OnceLock::new();
    let built = BUILT.get_or_init(Default::default);
    let mut built = built
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test> -> target/<profile>
    let dir = exe
        .parent()
        .and_then(|d| d.parent())
        .expect("target directory")
        .to_path_buf();
    let path = dir.join(name);
    if !built.iter().any(|b| b == name) {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.args(["build", "--quiet", "-p", package, "--bin", name]);
        if dir.file_name().is_some_and(|p| p == "release") {
            cmd.arg("--release");
        }
        let status = cmd.status().expect("run cargo build");
        assert!(
            status.success(),
            "cargo build -p {package} --bin {name} failed"
        );
        built.push(name.to_owned());
    }
    path
}

/// Stops a child the way an operator would (SIGTERM, so ussd shuts down cleanly and sends its
/// safe commands), waits up to 5 s, then kills it; the child is reaped either way.
pub fn terminate(child: &mut Child) {
    if let Ok(pid) = i32::try_from(child.id()) {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(pid),
            nix::sys::signal::Signal::SIGTERM,
        );
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    while child.try_wait().ok().flatten().is_none() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = child.kill();
    let _ = child.wait();
}

/// `uss-sim --pty` in its own process; killed when dropped.
#[derive(Debug)]
pub struct SimProcess {
    pub child: Child,
    pub path: String,
    pub stdout: BufReader<ChildStdout>,
}

impl SimProcess {
    /// Starts `uss-sim --pty` with `args` and waits for the `PTY <path>` line.
    pub fn start(args: &[&str]) -> SimProcess {
        let mut child = Command::new(binary("uss-drive-sim", "uss-sim"))
            .arg("--pty")
            .args(args)
            .stdout(Stdio::piped())
            .spawn()
            .expect("start uss-sim");
        let mut stdout = BufReader::new(child.stdout.take().expect("piped stdout"));
        let mut line = String::new();
        stdout
            .read_line(&mut line)
            .expect("read uss-sim's first line");
        let path = line
            .trim()
            .strip_prefix("PTY ")
            .unwrap_or_else(|| panic!("uss-sim printed {line:?}"))
            .to_owned();
        SimProcess {
            child,
            path,
            stdout,
        }
    }

    /// Sends SIGTERM and returns the final summary uss-sim prints when it stops.
    pub fn stop(mut self) -> String {
        let pid = nix::unistd::Pid::from_raw(i32::try_from(self.child.id()).expect("pid fits"));
        let _ = nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM);
        let mut out = String::new();
        let _ = std::io::Read::read_to_string(&mut self.stdout, &mut out);
        let _ = self.child.wait();
        out.split_once("stopped; final state:")
            .map(|(_, tail)| tail.to_owned())
            .unwrap_or(out)
    }
}

impl Drop for SimProcess {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
