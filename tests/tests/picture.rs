//! What ussd knows of a drive, kept true (issue 46), with real processes: ussd over a pty to
//! `uss-sim`, `ussctl` as the commissioning engineer types it. The reference frequency and the
//! telegram monitoring ussd scales and judges a drive by are read again after a factory reset
//! and after a power cycle, and a controller holding a drive whose reference changed under it
//! is stopped.
#![allow(clippy::unwrap_used)]

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use std::time::{Duration, Instant};
use uss_integration_tests::{SimProcess, Ussd};

/// `ussctl ARGS` to its end: its exit status, stdout and stderr together.
fn ussctl(ussd: &Ussd, args: &[&str]) -> (bool, String) {
    let (status, out, err) = ussd.ussctl(args).finish();
    (status.success(), format!("{out}{err}"))
}

/// The reference `ussctl stats` shows for drive 4 once it shows `wanted`, or what it showed
/// last after 5 s.
fn stats_reference(ussd: &Ussd, wanted: &str) -> String {
    let until = Instant::now() + Duration::from_secs(5);
    loop {
        let (_, out) = ussctl(ussd, &["stats"]);
        let line = out
            .lines()
            .skip_while(|l| !l.starts_with("drive 4:"))
            .find(|l| l.trim_start().starts_with("reference"))
            .unwrap_or_default()
            .trim()
            .to_owned();
        if line.contains(wanted) || Instant::now() > until {
            return line;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A MICROMASTER 4 at address 4, its telegram monitoring at 500 ms, over a pty.
fn drive_4(sim_args: &[&str]) -> (SimProcess, Ussd) {
    let mut args = vec!["--baud", "115200", "--drive", "4:p2014=500"];
    args.extend_from_slice(sim_args);
    let sim = SimProcess::start(&args);
    let ussd = Ussd::start_on(&sim.path, "baud = 115200", &[(4, "")]);
    (sim, ussd)
}

/// The session: P2000 = 60 Hz, then a factory reset (P0010 = 30, P0970 = 1). The reset
/// put P2000 back to 50 Hz and P2014 to 0, but ussd went on scaling with 60 Hz ("running towards
/// 30 Hz (reference 60 Hz)", the drive ran at 25 Hz) and said nothing of the monitoring. Now
/// ussd reads both again when the reset takes effect: `stats` shows 50 Hz, `run --hz 30` scales
/// by it, and the log warns that the monitoring is off.
#[test]
fn after_a_factory_reset_hz_are_scaled_by_the_drives_new_reference() {
    let (_sim, ussd) = drive_4(&[]);
    ussd.log_line("telegram monitoring on", Duration::from_secs(5))
        .expect("monitoring read at start");
    for args in [
        &["param", "write", "4", "P0003", "3"][..],
        &["param", "write", "4", "P2000", "60"],
    ] {
        let (ok, out) = ussctl(&ussd, args);
        assert!(ok, "{args:?}: {out}");
    }
    assert!(
        stats_reference(&ussd, "reference 60 Hz").contains("reference 60 Hz"),
        "the write is seen"
    );
    for args in [
        &["param", "write", "4", "P0010", "30", "--unsafe"][..],
        &["param", "write", "4", "P0970", "1", "--unsafe"],
    ] {
        let (ok, out) = ussctl(&ussd, args);
        assert!(ok, "{args:?}: {out}");
    }
    let shown = stats_reference(&ussd, "reference 50 Hz");
    assert!(
        shown.contains("reference 50 Hz"),
        "stats after the reset: {shown}"
    );
    assert!(
        ussd.log_line("are read again", Duration::from_secs(2))
            .is_some(),
        "the reset's effect is logged:\n{}",
        ussd.log()
    );
    assert!(
        ussd.log_line("telegram monitoring is OFF", Duration::from_secs(2))
            .is_some(),
        "the monitoring the reset switched off is warned about:\n{}",
        ussd.log()
    );
    let (ok, out) = ussctl(&ussd, &["run", "4", "--hz", "30", "--for", "0.3"]);
    assert!(ok, "{out}");
    assert!(
        out.contains("running towards 30 Hz (reference 50 Hz)"),
        "{out}"
    );
}

/// A power cycle while `ussctl run` holds the drive: it comes back with the EEPROM's P2000
/// (50 Hz; the 60 Hz was written to RAM only) and in S1. ussd reads it again when it answers,
/// and the run that scaled its setpoint by 60 Hz is stopped with the reason, not left to run
/// at a speed nobody commanded.
#[test]
fn a_power_cycle_under_a_running_controller_is_read_again_and_stops_it() {
    let (sim, ussd) = drive_4(&["--power-off-ms", "400"]);
    for args in [
        &["param", "write", "4", "P0003", "3"][..],
        &["param", "write", "4", "P2000", "60"],
    ] {
        let (ok, out) = ussctl(&ussd, args);
        assert!(ok, "{args:?}: {out}");
    }
    assert!(stats_reference(&ussd, "reference 60 Hz").contains("reference 60 Hz"));
    let mut run = ussd.ussctl(&["run", "4", "--hz", "30", "--for", "20"]);
    let said = run.says("running towards");
    assert!(said.contains("30 Hz (reference 60 Hz)"), "{said}");
    std::thread::sleep(Duration::from_millis(300));
    let pid = Pid::from_raw(i32::try_from(sim.child.id()).unwrap());
    kill(pid, Signal::SIGUSR1).unwrap();
    let started = Instant::now();
    let (status, out, err) = run.finish();
    assert!(
        started.elapsed() < Duration::from_secs(10),
        "the run ended with the power cycle, not after its 20 s"
    );
    assert!(!status.success(), "{out}{err}");
    let text = format!("{out}{err}");
    assert!(
        text.contains("reference frequency (P2000) changed"),
        "the run says why it stopped:\n{text}"
    );
    let shown = stats_reference(&ussd, "reference 50 Hz");
    assert!(shown.contains("reference 50 Hz"), "{shown}");
    assert!(
        ussd.log().contains("reference changed"),
        "the latch is logged:\n{}",
        ussd.log()
    );
}

/// The adversarial sweep of issue 46 (break 1): for about 50 ms after a drive came back online,
/// clients were shown its old reference as known. The input image (online again) is published
/// at once, the description with the reference only with the next status publication, so the
/// C sampler read `ref=60.00 actual_hz=19.999` and Python's `set_hz(20)` was scaled with a
/// reference ussd was about to read again. A description published for an earlier state of
/// the drive (`DriveDiag::info_for`: another picture count than the image's) now knows no
/// reference: from the first image that shows the drive back, until ussd has read it anew.
#[test]
fn a_drive_back_online_has_no_reference_until_it_is_read_again() {
    let (sim, ussd) = drive_4(&[]);
    let bus = ussd.bus();
    let watch = bus.watch(uss_integration_tests::addr(4)).unwrap();
    assert_eq!(watch.wait_for_reference(Duration::from_secs(5)), Ok(50.0));
    let control = bus
        .control(
            uss_integration_tests::addr(4),
            uss_client::ControlOptions::default(),
        )
        .unwrap();
    control.rearm(uss_client::monotonic_ns()).unwrap();
    // The drive falls silent for 0.3 s (its process stopped): ussd takes it offline.
    let pid = Pid::from_raw(i32::try_from(sim.child.id()).unwrap());
    kill(pid, Signal::SIGSTOP).unwrap();
    let until = Instant::now() + Duration::from_secs(5);
    while watch.latest().online != 0 && Instant::now() < until {
        control.keepalive().ok();
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(watch.latest().online, 0, "offline while silent");
    std::thread::sleep(Duration::from_millis(300));
    kill(pid, Signal::SIGCONT).unwrap();
    // The first look that shows it online again: no reference, and no setpoint in Hz.
    let first = loop {
        let s = watch.snapshot();
        if s.image.online != 0 || Instant::now() > until {
            break s;
        }
        std::thread::sleep(Duration::from_micros(200));
    };
    assert_ne!(first.image.online, 0, "the drive came back online");
    assert_eq!(
        first.info.reference(),
        None,
        "shown as known at the comeback, before ussd read it again"
    );
    assert!(
        matches!(
            control.set_hz(20.0),
            Err(uss_client::ClientError::ReferenceUnknown { .. }
                | uss_client::ClientError::Tripped { .. })
        ),
        "a setpoint in Hz at the comeback"
    );
    let back = Instant::now();
    assert_eq!(watch.wait_for_reference(Duration::from_secs(5)), Ok(50.0));
    println!(
        "picture: drive 4 back online, its reference read again and shown {:.1} ms later",
        back.elapsed().as_secs_f64() * 1000.0
    );
    drop(control);
    drop(sim);
}
