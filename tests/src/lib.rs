//! What the multi-process tests in `tests/tests/` share: building and finding the workspace's
//! binaries, running `uss-sim --pty`, `ussd` on a bus of its own with its log, and other
//! processes (`ussctl`) with their output.
// Test support: a failed set-up is a failed test, so `unwrap` says it best.
#![allow(clippy::unwrap_used, clippy::missing_panics_doc)]

use std::fmt::Write as _;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, ExitStatus, Stdio};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use uss_client::{Address, Bus, ClientError, ParamRef};

/// Drive `a` of a test's bus (the tests name their drives 1..=31).
pub fn addr(a: impl TestAddress) -> Address {
    a.address()
}

/// What a test writes as a drive's address: a number, or an address already.
pub trait TestAddress {
    fn address(self) -> Address;
}

impl TestAddress for Address {
    fn address(self) -> Address {
        self
    }
}

macro_rules! test_address {
    ($($t:ty),*) => {$(
        impl TestAddress for $t {
            fn address(self) -> Address {
                u8::try_from(self)
                    .ok()
                    .and_then(|a| Address::new(a).ok())
                    .expect("a test drive's address is 0..=31")
            }
        }
    )*};
}
test_address!(u8, i32, u32, usize);

/// Parameter `pnu` (P + the number).
pub fn param(pnu: u16) -> ParamRef {
    ParamRef::p(pnu)
}

/// Element `index` of parameter `pnu`.
pub fn param_at(pnu: u16, index: u8) -> ParamRef {
    ParamRef::numbered(pnu, Some(index)).expect("a test's index is 0..=254")
}

/// Builds (if needed) and returns the path of a workspace binary. Integration tests only get
/// their own package's binaries from cargo, so other packages' binaries are built here with the
/// same cargo and profile.
/// Checks `line` against the JSON Schema shipped as `docs/schema/<schema>.json`
/// (`ussctl/status`, `zenoh/in`, ...): what the machine interface promises a script.
pub fn assert_report(schema: &str, line: &str) {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!("../docs/schema/{schema}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let schema_json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let validator = jsonschema::validator_for(&schema_json)
        .unwrap_or_else(|e| panic!("{}: not a schema: {e}", path.display()));
    let value: serde_json::Value =
        serde_json::from_str(line).unwrap_or_else(|e| panic!("{schema}: not JSON ({e}): {line}"));
    let errors: Vec<String> = validator
        .iter_errors(&value)
        .map(|e| e.to_string())
        .collect();
    assert!(
        errors.is_empty(),
        "{schema}: {line}\ndoes not match {}:\n{}",
        path.display(),
        errors.join("\n")
    );
}

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

/// The workspace's root directory.
pub fn root() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// `target/<profile>` of the running test.
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.parent()
        .and_then(std::path::Path::parent)
        .unwrap()
        .to_path_buf()
}

/// Where C programs of the tests link libussrt from: `libussrt.so` and its soname
/// `libussrt.so.0`, as capi/install.sh lays them out.
pub fn libussrt_dir() -> PathBuf {
    target_dir().join("ussrt-lib")
}

/// Builds libussrt (once per test binary) and compiles `source` (relative to the workspace)
/// with `compiler` and the flags `extra` against it, warnings as errors; the executable.
pub fn c_program(compiler: &str, source: &str, extra: &[&str]) -> PathBuf {
    static BUILT: std::sync::Mutex<bool> = std::sync::Mutex::new(false);
    static COMPILED: std::sync::Mutex<Vec<(String, PathBuf)>> = std::sync::Mutex::new(Vec::new());
    let mut built = BUILT
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let target = target_dir();
    let mut programs = COMPILED
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some((_, exe)) = programs.iter().find(|(s, _)| s == source) {
        // Once per test binary: a program of a running test is not replaced under it.
        return exe.clone();
    }
    if !*built {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.args(["build", "--quiet", "-p", "uss-rt-c", "--lib"]);
        if target.file_name().is_some_and(|p| p == "release") {
            cmd.arg("--release");
        }
        assert!(cmd.status().unwrap().success(), "cargo build -p uss-rt-c");
        let lib = libussrt_dir();
        std::fs::create_dir_all(&lib).unwrap();
        for name in ["libussrt.so", "libussrt.so.0"] {
            let _ = std::fs::remove_file(lib.join(name));
            std::os::unix::fs::symlink(target.join("libussrt.so"), lib.join(name)).unwrap();
        }
        *built = true;
    }
    let source_name = source.to_owned();
    let source = root().join(source);
    let exe = target.join(format!(
        "capi-{}-{}",
        source.file_stem().unwrap().to_string_lossy(),
        source.extension().unwrap().to_string_lossy()
    ));
    let out = Command::new(compiler)
        .args(["-Wall", "-Wextra", "-Werror", "-O1"])
        .args(extra)
        .arg("-I")
        .arg(root().join("capi/include"))
        .arg("-I")
        .arg(root().join("shm-types/include"))
        .arg(&source)
        .arg("-o")
        .arg(&exe)
        .arg(format!("-L{}", libussrt_dir().display()))
        .arg(format!("-Wl,-rpath,{}", libussrt_dir().display()))
        .args(["-lussrt", "-lm", "-lpthread"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{compiler} {}:\n{}",
        source.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    programs.push((source_name, exe.clone()));
    exe
}

/// `python3` with the Python module `uss_rt` of this checkout on its path: built once (maturin,
/// through pip, as `pip install ./python` builds it) into `target/python-module`, and again
/// only when a source it is made of is newer, so a fresh clone's `cargo test --workspace`
/// needs nothing installed first and a module installed in the system is never the one
/// tested. Test binaries running at once build it once (a file lock).
///
/// # Panics
/// When pip cannot build it (its output is in the message).
pub fn python() -> Command {
    static BUILT: OnceLock<PathBuf> = OnceLock::new();
    let site = BUILT.get_or_init(|| {
        let site = root().join("target/python-module");
        std::fs::create_dir_all(&site).unwrap();
        let lock = std::fs::File::create(root().join("target/python-module.lock")).unwrap();
        let _held = nix::fcntl::Flock::lock(lock, nix::fcntl::FlockArg::LockExclusive)
            .map_err(|(_, e)| e)
            .expect("lock target/python-module.lock");
        let stamp = site.join(".built");
        let built = std::fs::metadata(&stamp).and_then(|m| m.modified()).ok();
        let sources = [
            "python/src",
            "python/uss_rt",
            "python/Cargo.toml",
            "python/pyproject.toml",
            "clients/src",
            "catalogue/src",
            "catalogue/data",
            "shm-types/src",
            "protocol/src",
        ];
        let newest = sources.iter().filter_map(|s| newest(&root().join(s))).max();
        if built.is_none() || newest > built {
            let out = Command::new("python3")
                .args(["-m", "pip", "install", "--quiet", "--upgrade", "--no-deps"])
                .args(["--disable-pip-version-check", "--root-user-action=ignore"])
                .arg("--target")
                .arg(&site)
                .arg(root().join("python"))
                .output()
                .expect("python3 -m pip (CPython with pip)");
            assert!(
                out.status.success(),
                "building the Python module uss_rt (python3 -m pip install --target {} ./python):\n{}{}",
                site.display(),
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            );
            std::fs::write(&stamp, b"").unwrap();
        }
        site
    });
    let mut c = Command::new("python3");
    let path = std::env::var_os("PYTHONPATH").map_or_else(
        || site.clone().into_os_string(),
        |p| {
            let mut all = site.clone().into_os_string();
            all.push(":");
            all.push(p);
            all
        },
    );
    c.env("PYTHONPATH", path);
    c
}

/// The newest modification time of a file at or below `path`.
fn newest(path: &std::path::Path) -> Option<std::time::SystemTime> {
    let meta = std::fs::metadata(path).ok()?;
    if !meta.is_dir() {
        return meta.modified().ok();
    }
    std::fs::read_dir(path)
        .ok()?
        .filter_map(Result::ok)
        .filter_map(|e| newest(&e.path()))
        .max()
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

/// `CLOCK_MONOTONIC` in ns, the clock of every time stamp ussd publishes.
pub fn monotonic_ns() -> u64 {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).unwrap();
    t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64
}

/// A ussd process on a bus of its own, its output in a file; stopped with SIGTERM when dropped.
/// `ussd --config CONFIG`, its output appended to `log`.
fn spawn_ussd(config: &std::path::Path, log: &std::path::Path, env: &[(String, String)]) -> Child {
    let log = std::fs::OpenOptions::new().append(true).open(log).unwrap();
    Command::new(binary("uss-master", "ussd"))
        .arg("--config")
        .arg(config)
        .args(["--summary-every", "3600"])
        .envs(env.iter().map(|(k, v)| (k, v)))
        .stdout(log.try_clone().unwrap())
        .stderr(log)
        .spawn()
        .unwrap()
}

/// One bus of [`Ussd::start_buses`].
#[derive(Debug, Clone, Copy)]
pub struct BusSpec<'a> {
    /// Appended to the test's bus name.
    pub suffix: &'a str,
    /// "sim", or a serial device or pty path.
    pub device: &'a str,
    /// Further `[[bus]]` keys, one per line.
    pub keys: &'a str,
    /// Each drive's address and further `[[bus.drive]]` keys.
    pub drives: &'a [(u8, &'a str)],
}

#[derive(Debug)]
pub struct Ussd {
    pub child: Child,
    pub bus: String,
    config: PathBuf,
    log: PathBuf,
    /// Environment variables set for ussd (kept for [`Ussd::restart`]).
    env: Vec<(String, String)>,
}

impl Ussd {
    /// Starts ussd on a simulated bus with the `[[bus]]` keys `bus_keys` and one
    /// `[[bus.drive]]` per entry of `drives` (address, further keys), and waits until every
    /// drive answered.
    pub fn start(bus_keys: &str, drives: &[(u8, &str)]) -> Ussd {
        Self::start_on("sim", bus_keys, drives)
    }

    /// Like [`Ussd::start`], on `device` (a serial device or pty path, or "sim").
    pub fn start_on(device: &str, bus_keys: &str, drives: &[(u8, &str)]) -> Ussd {
        Self::start_buses(&[BusSpec {
            suffix: "",
            device,
            keys: bus_keys,
            drives,
        }])
    }

    /// Starts ussd with one bus per spec, named [`Ussd::bus`] followed by the spec's suffix,
    /// and waits until every drive of every bus answered.
    pub fn start_buses(specs: &[BusSpec<'_>]) -> Ussd {
        Self::start_buses_with_env(specs, &[])
    }

    /// Like [`Ussd::start_buses`], with environment variables `env` set for ussd.
    pub fn start_buses_with_env(specs: &[BusSpec<'_>], env: &[(&str, &str)]) -> Ussd {
        let mut ussd = Self::launch(specs, env);
        for spec in specs {
            let bus = ussd.open_when_running(spec.suffix);
            for &(a, _) in spec.drives {
                bus.watch(addr(a))
                    .unwrap()
                    .wait_for(Duration::from_secs(20), "a reply", |i| {
                        i.online != 0 && i.sequence > 0
                    })
                    .unwrap();
            }
        }
        ussd
    }

    /// Starts ussd with one bus per spec and environment variables `env`, and returns at once
    /// (its services may not be there yet: see [`Ussd::open_when_running`]).
    pub fn launch(specs: &[BusSpec<'_>], env: &[(&str, &str)]) -> Ussd {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let bus = format!(
            "s{}n{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let dir = std::env::temp_dir();
        let config = dir.join(format!("ussd-stress-{bus}.toml"));
        let log = dir.join(format!("ussd-stress-{bus}.log"));
        std::fs::write(&config, config_text(&bus, specs)).unwrap();
        std::fs::File::create(&log).unwrap();
        let env: Vec<(String, String)> = env
            .iter()
            .map(|&(k, v)| (k.to_owned(), v.to_owned()))
            .collect();
        let child = spawn_ussd(&config, &log, &env);
        Ussd {
            child,
            bus,
            config,
            log,
            env,
        }
    }

    /// Starts ussd again with the same configuration (after [`Ussd::kill`] or
    /// [`Ussd::terminate`]), its output appended to the same log; does not wait for it.
    pub fn restart(&mut self) {
        assert!(!self.is_running(), "ussd still runs");
        self.child = spawn_ussd(&self.config, &self.log, &self.env);
    }

    /// Like [`Ussd::restart`], with other buses and drives under the same bus name (a site that
    /// changed its configuration); does not wait for it.
    pub fn restart_with(&mut self, specs: &[BusSpec<'_>]) {
        std::fs::write(&self.config, config_text(&self.bus, specs)).unwrap();
        self.restart();
    }

    /// SIGKILL: ussd gets no chance to say anything. Returns `CLOCK_MONOTONIC` just before.
    pub fn kill(&mut self) -> u64 {
        let at = monotonic_ns();
        self.child.kill().unwrap();
        self.child.wait().unwrap();
        at
    }

    /// SIGTERM, then waits for the clean exit; returns `CLOCK_MONOTONIC` just before the
    /// signal and the exit code.
    pub fn terminate(&mut self) -> (u64, Option<i32>) {
        let at = monotonic_ns();
        let pid = nix::unistd::Pid::from_raw(i32::try_from(self.child.id()).unwrap());
        nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).unwrap();
        let code = self.child.wait().unwrap().code();
        (at, code)
    }

    /// The bus whose name ends in `suffix`, once ussd created it.
    pub fn open_when_running(&mut self, suffix: &str) -> Bus {
        let name = format!("{}{suffix}", self.bus);
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            match Bus::open(&name) {
                Ok(bus) => return bus,
                // A ussd starting on a busy machine can miss its second heartbeat: gone for a
                // moment, not an answer while its process runs.
                Err(ClientError::NotRunning { .. } | ClientError::UssdGone { .. })
                    if Instant::now() < deadline =>
                {
                    assert!(
                        self.child.try_wait().unwrap().is_none(),
                        "ussd ended before it created its services:\n{}",
                        self.log()
                    );
                    std::thread::sleep(Duration::from_millis(50));
                }
                Err(e) => panic!("{e}"),
            }
        }
    }

    pub fn bus(&self) -> Bus {
        Bus::open(&self.bus).unwrap()
    }

    /// The bus whose name ends in `suffix`.
    pub fn bus_named(&self, suffix: &str) -> Bus {
        Bus::open(&format!("{}{suffix}", self.bus)).unwrap()
    }

    pub fn is_running(&mut self) -> bool {
        self.child.try_wait().unwrap().is_none()
    }

    /// What ussd logged so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// The first line of ussd's log that contains `text`, waiting up to `timeout` for it.
    pub fn log_line(&self, text: &str, timeout: Duration) -> Option<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let log = self.log();
            if let Some(line) = log.lines().find(|l| l.contains(text)) {
                return Some(line.to_owned());
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// `ussctl --bus BUS ARGS...` in its own process.
    pub fn ussctl(&self, args: &[&str]) -> ChildProc {
        let mut command = Command::new(binary("ussctl", "ussctl"));
        command.args(["--bus", &self.bus]).args(args);
        ChildProc::spawn(format!("ussctl {}", args.join(" ")), command)
    }
}

impl Drop for Ussd {
    fn drop(&mut self) {
        terminate(&mut self.child);
        let _ = std::fs::remove_file(&self.config);
        if std::env::var_os("USS_KEEP_LOG").is_none() {
            let _ = std::fs::remove_file(&self.log);
        }
    }
}

/// ussd's configuration of `specs`, the buses named `bus` followed by each spec's suffix.
fn config_text(bus: &str, specs: &[BusSpec<'_>]) -> String {
    let mut toml = String::new();
    for spec in specs {
        let _ = write!(
            toml,
            "[[bus]]\nname = \"{bus}{}\"\ndevice = \"{}\"\n{}\n",
            spec.suffix, spec.device, spec.keys
        );
        for (address, keys) in spec.drives {
            let _ = write!(toml, "\n[[bus.drive]]\naddress = {address}\n{keys}\n");
        }
        toml.push('\n');
    }
    toml
}

/// A process the test started: stdout read line by line, stderr collected by a thread;
/// killed (SIGKILL) and reaped when dropped.
#[derive(Debug)]
pub struct ChildProc {
    what: String,
    pub child: Child,
    out: BufReader<ChildStdout>,
    err: Option<JoinHandle<String>>,
}

impl ChildProc {
    pub fn spawn(what: String, mut command: Command) -> ChildProc {
        let mut child = command
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let out = BufReader::new(child.stdout.take().unwrap());
        let mut stderr = child.stderr.take().unwrap();
        let err = std::thread::spawn(move || {
            let mut s = String::new();
            let _ = stderr.read_to_string(&mut s);
            s
        });
        ChildProc {
            what,
            child,
            out,
            err: Some(err),
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// The rest of the next line that contains `tag`; fails with the child's stderr when the
    /// child ends first.
    pub fn says(&mut self, tag: &str) -> String {
        let mut line = String::new();
        loop {
            line.clear();
            if self.out.read_line(&mut line).unwrap() == 0 {
                let status = self.child.wait().unwrap();
                let stderr = self.stderr();
                panic!(
                    "{} ended ({status}) before saying {tag:?}; its stderr:\n{stderr}",
                    self.what
                );
            }
            if let Some((_, rest)) = line.split_once(tag) {
                return rest.trim_end().to_owned();
            }
        }
    }

    /// Sends `line` to the child's stdin.
    pub fn tell(&mut self, line: &str) {
        writeln!(self.child.stdin.as_mut().unwrap(), "{line}").unwrap();
    }

    pub fn close_stdin(&mut self) {
        drop(self.child.stdin.take());
    }

    /// SIGKILL: no destructor runs in the child. Returns `CLOCK_MONOTONIC` just before the
    /// signal, and reaps the child.
    pub fn kill(&mut self) -> u64 {
        let at = monotonic_ns();
        self.child.kill().unwrap();
        self.child.wait().unwrap();
        at
    }

    /// Waits for the end: exit status, the rest of stdout, stderr.
    pub fn finish(&mut self) -> (ExitStatus, String, String) {
        self.close_stdin();
        let mut rest = String::new();
        self.out.read_to_string(&mut rest).unwrap();
        let status = self.child.wait().unwrap();
        (status, rest, self.stderr())
    }

    pub fn stderr(&mut self) -> String {
        self.err
            .take()
            .map(|t| t.join().unwrap_or_default())
            .unwrap_or_default()
    }
}

impl Drop for ChildProc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A read of `pnu`, or of its element `index` (0..=254), as the protocol's task.
/// Changes the settings of drive `address` so that restoring a backup taken before raises the
/// access level on the way (P0719: level 3, and guarded, so it is written deliberately here and
/// restored with --unsafe) and enters quick commissioning (P0310 := `p0310` Hz), with plain
/// ones besides (P1082, P1080, P1120, P1121). It leaves P0003 = 1 and P0010 = 0.
pub fn change_what_a_restore_raises(bus: &Bus, address: u8, p0310: f32) {
    use uss_protocol::Value;
    let w = |pnu, v| bus.write(addr(address), param(pnu), v, false).unwrap();
    w(3, Value::Word(3));
    w(10, Value::Word(1));
    w(310, Value::from_f32(p0310));
    w(10, Value::Word(0));
    w(1082, Value::from_f32(45.0));
    w(1080, Value::from_f32(5.0));
    w(1120, Value::from_f32(2.5));
    w(1121, Value::from_f32(2.5));
    let deliberate = uss_client::WriteOptions {
        unsafe_write: true,
        ..Default::default()
    };
    bus.write_with(addr(address), param(719), Value::Word(11), deliberate)
        .unwrap();
    w(3, Value::Word(1));
}

pub fn read(pnu: u16, index: Option<u8>) -> uss_protocol::ParamTask {
    let index = index.map(|i| uss_protocol::Subindex::new(i).expect("a subindex 0..=254"));
    uss_protocol::ParamTask::read(uss_protocol::Pnu::from_u16(pnu), index)
}

/// A change of `pnu` to `value`, in RAM or, with `eeprom`, RAM and EEPROM.
pub fn write(pnu: u16, value: uss_protocol::Value, eeprom: bool) -> uss_protocol::ParamTask {
    let storage = if eeprom {
        uss_protocol::Storage::RamAndEeprom
    } else {
        uss_protocol::Storage::Ram
    };
    uss_protocol::ParamTask::write(uss_protocol::Pnu::from_u16(pnu), None, value, storage)
}
