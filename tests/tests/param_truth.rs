//! Every parameter answer true (issue 33), with real processes: ussd over a pty to `uss-sim`,
//! `ussctl` and the Rust client. Each test reproduces what a commissioning engineer was told
//! that was not so, and checks what is told now.
#![allow(clippy::unwrap_used)]

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use std::time::{Duration, Instant};
use uss_client::ParamError;
use uss_integration_tests::{ChildProc, SimProcess, Ussd, addr, param, read};
use uss_protocol::Value;

/// One drive over a pty at 115200 baud.
fn one_drive(sim_args: &[&str]) -> (SimProcess, Ussd) {
    let mut args = vec!["--baud", "115200", "--drive", "1"];
    args.extend_from_slice(sim_args);
    let sim = SimProcess::start(&args);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "")]);
    (sim, ussd)
}

fn word(v: Value) -> u32 {
    match v {
        Value::Word(w) => u32::from(w),
        Value::Dword(d) => d,
    }
}

/// r2024[0] counts the telegrams the drive received on its COM link: every read of it that
/// the drive executes gives a new value. Identical tasks one after another are each executed,
/// not answered from the drive's stored reply (USS.md section 6: a slave takes a task as new
/// only when the PKW area changes).
#[test]
fn identical_reads_back_to_back_are_each_a_fresh_read() {
    let (_sim, ussd) = one_drive(&[]);
    let bus = ussd.bus();
    // One request of five identical items: they go out one after the other.
    let values: Vec<u32> = bus
        .batch(addr(1), &[read(2024, Some(0)); 5])
        .iter()
        .map(|r| word(*r.as_ref().unwrap()))
        .collect();
    println!("param_truth: five reads of r2024[0] in one request: {values:?}");
    assert!(
        values.windows(2).all(|w| w[0] < w[1]),
        "a read answered from the drive's stored reply: {values:?}"
    );
    // Three commissioning engineers at once, each with ussctl, several times over.
    for round in 0..2 {
        let mut readers: Vec<_> = (0..3)
            .map(|_| ussd.ussctl(&["--json", "param", "read", "1", "r2024[0]"]))
            .collect();
        let mut seen: Vec<u64> = readers
            .iter_mut()
            .map(|r| {
                let (status, out, err) = r.finish();
                assert!(status.success(), "{out}{err}");
                let json: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
                json["value"].as_u64().unwrap()
            })
            .collect();
        println!("param_truth: round {round}, three ussctl reads of r2024[0]: {seen:?}");
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(seen.len(), 3, "two reads got one stored reply");
    }
}

/// An array parameter named without an index is not element 0 in disguise: a write is refused
/// naming the elements (before, `param write 1 P2014 300` set P2014[0] and said "P2014 := 300
/// ms", which element never shown), a read reads every element, and a client's request is refused by ussd
/// whichever front-end sent it.
#[test]
fn an_array_parameter_without_an_index_is_refused_or_read_whole() {
    let (_sim, ussd) = one_drive(&[]);
    let bus = ussd.bus();
    // P2014 is an expert parameter (access level 3).
    let (status, out, err) = ussd.ussctl(&["param", "write", "1", "P0003", "3"]).finish();
    assert!(status.success(), "{out}{err}");
    let before: Vec<u32> = bus
        .batch(addr(1), &[read(2014, Some(0)), read(2014, Some(1))])
        .iter()
        .map(|r| word(*r.as_ref().unwrap()))
        .collect();
    let (status, out, err) = ussd
        .ussctl(&["param", "write", "1", "P2014", "300"])
        .finish();
    println!("param_truth: ussctl param write 1 P2014 300: {status}\n{out}{err}");
    assert!(!status.success(), "{out}");
    assert!(
        err.contains("P2014[0]") && err.contains("P2014[1]") && err.contains("COM link"),
        "the refusal names the elements: {err}"
    );
    let after: Vec<u32> = bus
        .batch(addr(1), &[read(2014, Some(0)), read(2014, Some(1))])
        .iter()
        .map(|r| word(*r.as_ref().unwrap()))
        .collect();
    assert_eq!(before, after, "nothing was written");
    // The element asked for is written, and said so.
    let (status, out, err) = ussd
        .ussctl(&["param", "write", "1", "P2014[0]", "300"])
        .finish();
    assert!(status.success(), "{out}{err}");
    assert!(out.contains("P2014[0] := 300 ms"), "{out}");
    // A read without an index reads them all.
    let (status, out, err) = ussd.ussctl(&["param", "read", "1", "r0947"]).finish();
    println!("param_truth: ussctl param read 1 r0947:\n{out}{err}");
    assert!(status.success(), "{out}{err}");
    for i in 0..8 {
        assert!(
            out.contains(&format!("r0947[{i}] = ")),
            "element {i}: {out}"
        );
    }
    let (status, out, err) = ussd
        .ussctl(&["--json", "param", "read", "1", "P2014"])
        .finish();
    assert!(status.success(), "{out}{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 2, "{out}");
    for line in &lines {
        uss_integration_tests::assert_report("ussctl/param", line);
    }
    assert!(lines[0].contains("300"), "{out}");
    // Any front-end: ussd itself refuses the request.
    let refused = bus.batch(addr(1), &[read(2014, None)]);
    println!("param_truth: a client's read of P2014 without an index: {refused:?}");
    assert!(
        matches!(
            &refused[0],
            Err(uss_client::ParamError::Refused { error, .. })
                if error.to_string().contains("index")
        ),
        "{refused:?}"
    );
}

/// A write whose task reached the drive but whose answer did not come back is not reported as
/// not done: a slow EEPROM (the job timed out while the drive answered "busy") and a drive
/// unplugged while it was busy both leave the value in the drive, which a read shows. The
/// result says the value may be applied and how to check.
#[test]
fn a_write_that_reached_the_drive_is_reported_as_may_be_applied() {
    // An EEPROM that answers "busy" for 500 telegrams, against a 50 ms parameter timeout.
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1:eeprom-busy=500"]);
    let ussd = Ussd::start_on(
        &sim.path,
        "baud = 115200\nparam_timeout_ms = 50",
        &[(1, "")],
    );
    let (status, out, err) = ussd
        .ussctl(&["param", "write", "1", "P1120", "7.5", "--eeprom"])
        .finish();
    println!("param_truth: a slow EEPROM write: {status}\n{out}{err}");
    assert!(
        err.contains("may have been applied")
            && err.contains(&format!("`ussctl --bus {} param read 1 P1120`", ussd.bus)),
        "the result says the value may be applied and how to check (on its bus): {out}{err}"
    );
    let (_, out, _) = ussd.ussctl(&["param", "read", "1", "P1120"]).finish();
    assert!(out.contains("P1120 = 7.50 s"), "the drive holds it: {out}");
    // The client library says so to every front-end; a read that timed out is a timeout.
    let bus = ussd.bus();
    let eeprom = uss_client::WriteOptions {
        eeprom: true,
        ..Default::default()
    };
    let written = bus.write_with(
        addr(1),
        uss_client::ParamRef::p(1120),
        Value::from_f32(2.5),
        eeprom,
    );
    assert!(
        matches!(
            written,
            Err(uss_client::ParamError::MaybeApplied {
                failure: uss_client::uss_shm_types::PathError::Timeout,
                telegrams: 1..,
            })
        ),
        "{written:?}"
    );
    // A restore with --eeprom writes RAM, then copies RAM to ROM: the copy whose answer is
    // lost is said, not taken for done, and the restore is incomplete.
    let dir = std::env::temp_dir().join(format!("uss-maybe-{}", ussd.bus));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("drive1.toml").to_str().unwrap().to_owned();
    let (status, out, err) = ussd.ussctl(&["param", "backup", "1", "-o", &path]).finish();
    assert!(status.success(), "{out}{err}");
    bus.write(addr(1), param(1121), Value::from_f32(4.5), false)
        .unwrap();
    let (status, out, err) = ussd
        .ussctl(&["param", "restore", "1", &path, "--eeprom"])
        .finish();
    println!("param_truth: a restore whose copy to ROM timed out: {status}\n{out}{err}");
    assert_eq!(status.code(), Some(1), "incomplete: {out}{err}");
    assert!(
        out.contains("P1121[0]   4.50 s -> 10.00 s: written")
            && out.contains("EEPROM: not stored: ")
            && out.contains("may have been applied"),
        "{out}"
    );
    // Once more, as JSON.
    let (_, json, _) = ussd
        .ussctl(&["--json", "param", "restore", "1", &path, "--eeprom"])
        .finish();
    uss_integration_tests::assert_report("ussctl/restore", json.trim());
    assert!(json.contains("\"stored\":\"not stored: "), "{json}");
    let _ = std::fs::remove_dir_all(&dir);
    drop(ussd);
    drop(sim);
    // A drive unplugged while its EEPROM is busy with the write: offline, and the value is in.
    let sim = SimProcess::start(&[
        "--baud",
        "115200",
        "--drive",
        "1:eeprom-busy=1000000,unplug=4000..6000",
    ]);
    let ussd = Ussd::start_on(
        &sim.path,
        "baud = 115200\nparam_timeout_ms = 20000",
        &[(1, "")],
    );
    let (status, out, err) = ussd
        .ussctl(&["param", "write", "1", "P1121", "8.5", "--eeprom"])
        .finish();
    println!("param_truth: an EEPROM write cut by an unplug: {status}\n{out}{err}");
    assert!(
        err.contains("may have been applied")
            && err.contains(&format!("`ussctl --bus {} param read 1 P1121`", ussd.bus)),
        "{out}{err}"
    );
    let bus = ussd.bus();
    bus.watch(addr(1))
        .unwrap()
        .wait_for(Duration::from_secs(10), "back online", |i| i.online != 0)
        .unwrap();
    let (_, out, _) = ussd.ussctl(&["param", "read", "1", "P1121"]).finish();
    assert!(out.contains("P1121 = 8.50 s"), "the drive holds it: {out}");
}

/// Drive 1 with settings that differ from its backup in `dir`: an expert one (level 3, so the
/// restore raises the access level P0003 on the way), a commissioning one (so it enters quick
/// commissioning, P0010 = 1) and plain ones. Returns the backup's path.
fn changed_since_backup(ussd: &Ussd, dir: &std::path::Path) -> String {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join("drive1.toml").to_str().unwrap().to_owned();
    let (status, out, err) = ussd.ussctl(&["param", "backup", "1", "-o", &path]).finish();
    assert!(status.success(), "{out}{err}");
    uss_integration_tests::change_what_a_restore_raises(&ussd.bus(), 1, 60.0);
    path
}

/// Starts `ussctl param restore 1 PATH ARGS` and returns once the drive is in quick
/// commissioning (P0010 = 1), which the restore entered on the way.
fn restore_until_raised(ussd: &Ussd, path: &str, args: &[&str]) -> ChildProc {
    let mut all = vec!["param", "restore", "1", path, "--unsafe"];
    all.extend_from_slice(args);
    let mut restore = ussd.ussctl(&all);
    let bus = ussd.bus();
    let deadline = Instant::now() + Duration::from_secs(30);
    while bus.read(addr(1), param(10)) != Ok(Value::Word(1)) {
        assert!(Instant::now() < deadline, "the restore never raised P0010");
        assert!(
            restore.child.try_wait().unwrap().is_none(),
            "the restore ended: {:?}",
            restore.finish()
        );
    }
    restore
}

/// P0010 and P0003 of drive 1, once ussd (a restarted one too) has it online.
fn raised_now(ussd: &Ussd) -> (Result<Value, ParamError>, Result<Value, ParamError>) {
    let bus = ussd.bus();
    bus.watch(addr(1))
        .unwrap()
        .wait_for(Duration::from_secs(20), "online", |i| i.online != 0)
        .unwrap();
    (bus.read(addr(1), param(10)), bus.read(addr(1), param(3)))
}

/// A restore that ended (`ended`: its exit status, stdout, stderr) incomplete, exit 1, with
/// P0010 and P0003 back where they were and its report saying "put back {how}" for each.
fn assert_both_put_back(
    ussd: &Ussd,
    ended: &(std::process::ExitStatus, String, String),
    how: &str,
) {
    let (status, out, err) = ended;
    assert_eq!(status.code(), Some(1), "incomplete: {out}{err}");
    assert_eq!(
        raised_now(ussd),
        (Ok(Value::Word(0)), Ok(Value::Word(1))),
        "{out}"
    );
    assert!(
        out.contains(&format!("P0010      1 -> 0: put back {how}"))
            && out.contains(&format!("P0003      3 -> 1: put back {how}")),
        "{out}"
    );
}

/// A restore cut short by the drive going offline, or by ussd killed, after it raised the
/// access level and entered quick commissioning puts both back once the drive answers again
/// (within its bound), and the report says so: the drive is not left where it will not run.
#[test]
fn a_restore_cut_short_by_anything_puts_back_what_it_raised() {
    // Every parameter task is answered after 10 "busy" replies: the restore takes a while.
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1:busy=10"]);
    let sim_pid = Pid::from_raw(i32::try_from(sim.child.id()).unwrap());
    let mut ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "")]);
    let dir = std::env::temp_dir().join(format!("uss-putback-{}", ussd.bus));
    let path = changed_since_backup(&ussd, &dir);

    // 1. The drive stops answering (its process stopped) for 3 s.
    let mut restore = restore_until_raised(&ussd, &path, &[]);
    kill(sim_pid, Signal::SIGSTOP).unwrap();
    std::thread::sleep(Duration::from_secs(3));
    kill(sim_pid, Signal::SIGCONT).unwrap();
    let ended = restore.finish();
    let (status, out, err) = &ended;
    println!("param_truth: a restore cut short by the drive offline: {status}\n{out}{err}");
    assert!(out.contains("cut short: "), "{out}");
    assert_both_put_back(&ussd, &ended, "after");

    // 2. ussd killed and started again 2 s later.
    let (status, _, err) = changed_since_restore(&ussd);
    assert!(status.success(), "{err}");
    let mut restore = restore_until_raised(&ussd, &path, &[]);
    ussd.kill();
    std::thread::sleep(Duration::from_secs(2));
    ussd.restart();
    let ended = restore.finish();
    let (status, out, err) = &ended;
    println!("param_truth: a restore cut short by ussd killed: {status}\n{out}{err}");
    assert_both_put_back(&ussd, &ended, "after");

    // 3. ussd killed and not back within --put-back-within: the report names what is left
    //    raised and the command that puts it back; that command does.
    let (status, _, err) = changed_since_restore(&ussd);
    assert!(status.success(), "{err}");
    let mut restore = restore_until_raised(&ussd, &path, &["--put-back-within", "2s"]);
    ussd.kill();
    let (status, out, err) = restore.finish();
    println!("param_truth: a restore cut short by ussd gone for good: {status}\n{out}{err}");
    assert_eq!(status.code(), Some(1), "incomplete: {out}{err}");
    let command = format!("ussctl --bus {} param write 1 P0010 0", ussd.bus);
    assert!(
        out.contains(&format!(
            "left raised: P0010 = 1: the drive stays in quick commissioning and will not run; put it back with `{command}`"
        )) && out.contains("left raised: P0003 = 3: the access level stays raised"),
        "{out}"
    );
    ussd.restart();
    ussd.open_when_running("");
    assert_eq!(raised_now(&ussd).0, Ok(Value::Word(1)), "left raised");
    let (status, out, err) = ussd.ussctl(&["param", "write", "1", "P0010", "0"]).finish();
    assert!(status.success(), "{out}{err}");
    assert_eq!(raised_now(&ussd).0, Ok(Value::Word(0)), "put back by hand");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 46's adversarial sweep (break 4): a restore killed with SIGKILL while the drive was in
/// quick commissioning left it there (P0010 = 1: it will not run) at a raised access level, from
/// ussctl, Python, C and the Zenoh bridge alike (one library): ussd cancelled the dead client's
/// queued writes and nothing put the raises back. Each raise now leaves ussd its put-back
/// (`REQUEST_PUT_BACK`), which ussd runs itself when the process dies first, and logs.
#[test]
fn a_restore_killed_halfway_has_ussd_put_back_what_it_raised() {
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1:busy=10"]);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "")]);
    let dir = std::env::temp_dir().join(format!("uss-killed-{}", ussd.bus));
    let path = changed_since_backup(&ussd, &dir);
    let mut restore = restore_until_raised(&ussd, &path, &[]);
    restore.child.kill().unwrap();
    restore.child.wait().unwrap();
    let killed = Instant::now();
    let bus = ussd.bus();
    let until = killed + Duration::from_secs(10);
    while raised_now(&ussd) != (Ok(Value::Word(0)), Ok(Value::Word(1))) && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(
        raised_now(&ussd),
        (Ok(Value::Word(0)), Ok(Value::Word(1))),
        "P0010 and P0003 put back: {}",
        ussd.log()
    );
    println!(
        "param_truth: a restore killed in quick commissioning: put back {:.0} ms after SIGKILL",
        killed.elapsed().as_secs_f64() * 1000.0
    );
    for shown in ["P0010 := 0", "P0003 := 1"] {
        assert!(
            ussd.log_line(
                &format!("ussd put it back, {shown}"),
                Duration::from_secs(2)
            )
            .is_some(),
            "{}",
            ussd.log()
        );
    }
    // A restore that ends by itself leaves nothing for ussd to put back.
    let (status, out, err) = ussd
        .ussctl(&["param", "restore", "1", &path, "--unsafe"])
        .finish();
    assert!(status.success(), "{out}{err}");
    let before = ussd.log().matches("ussd put it back").count();
    let (status, out, err) = changed_since_restore(&ussd);
    assert!(status.success(), "{out}{err}");
    let (status, out, err) = ussd
        .ussctl(&["param", "restore", "1", &path, "--unsafe"])
        .finish();
    assert!(status.success(), "{out}{err}");
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(
        ussd.log().matches("ussd put it back").count(),
        before,
        "{}",
        ussd.log()
    );
    assert_eq!(bus.read(addr(1), param(10)), Ok(Value::Word(0)));
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 46's second sweep: a restore killed while its drive was offline (its `ussctl` waiting
/// to put back once the drive answers) lost its put-back: ussd tried once, at once, and gave
/// up ("failed (Err(DriveOffline)); set it by hand"), leaving P0010 = 1. ussd now goes on
/// trying while the drive does not answer, as long as the client would have (30 s).
#[test]
fn a_restore_killed_while_its_drive_is_offline_is_put_back_when_it_answers() {
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1:busy=10"]);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "")]);
    let dir = std::env::temp_dir().join(format!("uss-offline-{}", ussd.bus));
    let path = changed_since_backup(&ussd, &dir);
    let mut restore = restore_until_raised(&ussd, &path, &[]);
    let sim_pid = Pid::from_raw(i32::try_from(sim.child.id()).unwrap());
    let watch = ussd.bus().watch(addr(1)).unwrap();
    kill(sim_pid, Signal::SIGSTOP).unwrap();
    watch
        .wait_for(Duration::from_secs(10), "offline", |i| i.online == 0)
        .unwrap();
    restore.child.kill().unwrap();
    restore.child.wait().unwrap();
    // Offline for a while after the client died: ussd's first tries find no drive.
    std::thread::sleep(Duration::from_millis(1500));
    kill(sim_pid, Signal::SIGCONT).unwrap();
    let back = Instant::now();
    let until = back + Duration::from_secs(15);
    while raised_now(&ussd) != (Ok(Value::Word(0)), Ok(Value::Word(1))) && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(
        raised_now(&ussd),
        (Ok(Value::Word(0)), Ok(Value::Word(1))),
        "P0010 and P0003 put back once the drive answers: {}",
        ussd.log()
    );
    println!(
        "param_truth: put back {:.0} ms after the drive answered again",
        back.elapsed().as_secs_f64() * 1000.0
    );
    assert!(!ussd.log().contains("set it by hand"), "{}", ussd.log());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Changes drive 1 again after a restore (P0310 to another value than before, so quick
/// commissioning is needed again), then P1120 with ussctl; returns how that write went.
fn changed_since_restore(ussd: &Ussd) -> (std::process::ExitStatus, String, String) {
    uss_integration_tests::change_what_a_restore_raises(&ussd.bus(), 1, 55.0);
    ussd.ussctl(&["param", "write", "1", "P1120", "3.5"])
        .finish()
}

/// `ussctl param` shows and takes values as they are: a type named with `--type` does not
/// turn -1 into 65535 or a float into 0; a whole number is taken however it is written; hex
/// is the bits of any type; what the drive holds is shown in its type's precision; -0.0
/// survives a backup and its restore; `param diff` refuses another family and says by its exit
/// status whether there are differences.
#[test]
fn values_are_shown_and_taken_as_they_are() {
    let ussd = Ussd::start(
        "",
        &[
            (1, ""),
            (2, "family = \"g120\"\nsim = { family = \"g120\" }"),
        ],
    );
    let bus = ussd.bus();
    let run = |args: &[&str]| {
        let (status, out, err) = ussd.ussctl(args).finish();
        println!(
            "param_truth: ussctl {}: {status}\n{out}{err}",
            args.join(" ")
        );
        (status.code(), out, err)
    };
    let raw = |p: uss_client::ParamRef| bus.read(addr(1), p).unwrap();
    let p2014 = uss_integration_tests::param_at(2014, 0);
    // Expert level: P2014 is a level 3 parameter.
    bus.write(addr(1), param(3), Value::Word(3), false).unwrap();
    // 1. A type named does not make -1 a U16, nor a float a word.
    let before = raw(p2014);
    let (code, _, err) = run(&[
        "param", "write", "1", "P2014[0]", "--type", "word", "--", "-1",
    ]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("0..=65535"), "{err}");
    assert_eq!(raw(p2014), before, "nothing written");
    let (code, out, err) = run(&["param", "read", "1", "P2000", "--type", "word"]);
    assert_eq!(code, Some(1), "{out}{err}");
    assert!(err.contains("Float"), "{err}");
    let (code, out, err) = run(&["param", "read", "1", "P2014[0]", "--type", "word"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.starts_with("drive 1 P2014[0] = "), "{out}");
    // 2. A whole number however written; not a fraction.
    let (code, out, err) = run(&["param", "write", "1", "P2014[0]", "300.0"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("P2014[0] := 300 ms"), "{out}");
    let (code, out, err) = run(&["param", "write", "1", "P2014[0]", "1e3"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("P2014[0] := 1000 ms"), "{out}");
    let (code, _, err) = run(&["param", "write", "1", "P2014[0]", "2.5"]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("not a whole number"), "{err}");
    // 3. Hex is the bits of a float too, as the help says.
    let (code, out, err) = run(&["param", "write", "1", "P1120", "0x41200000"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("P1120 := 10.00 s"), "{out}");
    // 4. What the drive holds, in its type's precision.
    let (code, out, err) = run(&["param", "write", "1", "P1120", "0.001"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("P1120 := 0.001 s"), "{out}");
    let (_, out, _) = run(&["param", "read", "1", "P1120"]);
    assert!(out.contains("P1120 = 0.001 s"), "{out}");
    let (_, out, _) = run(&["param", "write", "1", "P1121", "12.345678"]);
    assert!(out.contains("P1121 := 12.345678 s"), "{out}");
    // 5. -0.0 is kept by a backup and put back by its restore; diff sees it.
    let dir = std::env::temp_dir().join(format!("uss-values-{}", ussd.bus));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("drive1.toml").to_str().unwrap().to_owned();
    let (code, _, err) = run(&["param", "write", "1", "P1080", "-0.0"]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(raw(param(1080)), Value::Dword(0x8000_0000));
    let (code, _, err) = run(&["param", "backup", "1", "-o", &path]);
    assert_eq!(code, Some(0), "{err}");
    let (code, _, err) = run(&["param", "write", "1", "P1080", "0"]);
    assert_eq!(code, Some(0), "{err}");
    let (code, out, _) = run(&["param", "diff", "1", &path]);
    assert!(out.contains("P1080"), "diff sees +0 against -0: {out}");
    assert_eq!(code, Some(1), "differences: a script sees them: {out}");
    let (code, out, err) = run(&["param", "restore", "1", &path]);
    assert_eq!(code, Some(0), "{out}{err}");
    assert_eq!(raw(param(1080)), Value::Dword(0x8000_0000), "-0.0 restored");
    let (code, out, _) = run(&["param", "diff", "1", &path]);
    assert_eq!(code, Some(0), "no differences: {out}");
    // 6. Another family's drive or backup is not compared value by value.
    // A refusal is not a difference: like diff(1), 2 for trouble.
    let (code, out, err) = run(&["param", "diff", "2", &path]);
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(
        err.contains("values of another family are neither restored nor compared"),
        "{err}"
    );
    let (code, out, err) = run(&["param", "diff", "1", "2"]);
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(
        err.contains("micromaster4") && err.contains("g120"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A restore hung up (SIGHUP: an ssh session or terminal closed) puts back what it raised like
/// any other ending, and says which signal cut it; a second Ctrl-C, even one that came while a
/// write was waiting for an offline drive, leaves at once and names what is left raised.
#[test]
fn a_restore_hung_up_or_interrupted_twice_puts_back_or_names_what_it_raised() {
    // Every parameter task is answered after 10 "busy" replies; a silent drive goes offline
    // only after 50 failed polls (so a write waits for it a while).
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1:busy=10"]);
    let sim_pid = Pid::from_raw(i32::try_from(sim.child.id()).unwrap());
    let ussd = Ussd::start_on(&sim.path, "baud = 115200\noffline_after = 50", &[(1, "")]);
    let dir = std::env::temp_dir().join(format!("uss-hup-{}", ussd.bus));
    let path = changed_since_backup(&ussd, &dir);

    // 1. SIGHUP.
    let mut restore = restore_until_raised(&ussd, &path, &[]);
    kill(Pid::from_raw(restore.pid() as i32), Signal::SIGHUP).unwrap();
    let ended = restore.finish();
    let (status, out, err) = &ended;
    println!("param_truth: a restore hung up: {status}\n{out}{err}");
    assert!(out.contains("cut short: SIGHUP; not written: "), "{out}");
    assert_both_put_back(&ussd, &ended, "after SIGHUP");

    // 2. The drive stops answering; Ctrl-C twice while the write waits for it.
    let (status, _, err) = changed_since_restore(&ussd);
    assert!(status.success(), "{err}");
    let mut restore = restore_until_raised(&ussd, &path, &[]);
    let ussctl = Pid::from_raw(restore.pid() as i32);
    kill(sim_pid, Signal::SIGSTOP).unwrap();
    std::thread::sleep(Duration::from_millis(100));
    kill(ussctl, Signal::SIGINT).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    kill(ussctl, Signal::SIGINT).unwrap();
    let (status, out, err) = restore.finish();
    kill(sim_pid, Signal::SIGCONT).unwrap();
    println!("param_truth: a restore interrupted twice: {status}\n{out}{err}");
    assert_eq!(status.code(), Some(1), "incomplete: {out}{err}");
    assert!(out.contains("cut short: Ctrl-C"), "{out}");
    assert!(
        out.contains("P0010      1 -> 0: LEFT RAISED: ")
            && out.contains("(a second Ctrl-C: not waited for)")
            && out.contains("left raised: P0010 = 1: the drive stays in quick commissioning"),
        "{out}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A restore with --eeprom whose copy of RAM to ROM goes unanswered (an EEPROM busy past the
/// parameter timeout) after it raised the access level and entered quick commissioning does not
/// end silent: its values are in RAM, the raises put back (in RAM, as a read shows), and the
/// report says the EEPROM was not stored; exit 1.
#[test]
fn a_restore_whose_copy_to_rom_goes_unanswered_says_where_it_left_the_drive() {
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1"]);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(1, "")]);
    let dir = std::env::temp_dir().join(format!("uss-unanswered-{}", ussd.bus));
    let path = changed_since_backup(&ussd, &dir);
    drop(ussd);
    drop(sim);
    // The same drive's settings, now behind an EEPROM that answers "busy" for 500 telegrams.
    let sim = SimProcess::start(&["--baud", "115200", "--drive", "1:eeprom-busy=500"]);
    let ussd = Ussd::start_on(
        &sim.path,
        "baud = 115200\nparam_timeout_ms = 50",
        &[(1, "")],
    );
    let _ = changed_since_backup(&ussd, &dir.join("again"));
    let (status, out, err) = ussd
        .ussctl(&["param", "restore", "1", &path, "--unsafe", "--eeprom"])
        .finish();
    println!("param_truth: a restore whose copy to ROM goes unanswered: {status}\n{out}{err}");
    assert_eq!(status.code(), Some(1), "incomplete: {out}{err}");
    assert!(
        out.contains("EEPROM: not stored: ") && out.contains("may have been applied"),
        "{out}"
    );
    assert_eq!(
        raised_now(&ussd),
        (Ok(Value::Word(0)), Ok(Value::Word(1))),
        "{out}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A commissioning engineer's quick commissioning of an MM4 through ussctl (issue 34.5): the
/// simulated drive has the motor data, the output values and P0971 its family profile lists
/// (before, each was "illegal PNU"). P0010 = 1 opens the motor data, P0971 = 1 keeps them over
/// a power cycle.
#[test]
fn a_quick_commissioning_through_ussctl_reaches_every_parameter_it_names() {
    let (_sim, ussd) = one_drive(&[]);
    let step = |args: &[&str]| {
        let (status, out, err) = ussd.ussctl(args).finish();
        println!("param_truth: ussctl {}: {out}{err}", args.join(" "));
        assert!(status.success(), "ussctl {args:?}: {out}{err}");
        out
    };
    step(&["param", "write", "1", "P0003", "3"]);
    step(&["param", "write", "1", "P0010", "1"]);
    for (p, v) in [
        ("P0100", "1"),
        ("P0304", "400"),
        ("P0305", "1.9"),
        ("P0307", "0.75"),
        ("P0308", "0.82"),
        ("P0311", "1395"),
        ("P0335", "0"),
    ] {
        step(&["param", "write", "1", p, v]);
    }
    step(&["param", "write", "1", "P0010", "0"]);
    step(&["param", "write", "1", "P1300", "2"]);
    step(&["param", "write", "1", "P0340", "1"]);
    step(&["param", "write", "1", "P0640", "120"]);
    step(&["param", "write", "1", "P0971", "1"]);
    assert!(step(&["param", "read", "1", "P0304"]).contains("400 V"));
    assert!(step(&["param", "read", "1", "P0305"]).contains("1.90 A"));
    assert!(step(&["param", "read", "1", "P0640"]).contains("120"));
    for r in ["r0025", "r0026", "r0027"] {
        step(&["param", "read", "1", r]);
    }
}
