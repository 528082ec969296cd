//! `ussctl scan` against `uss-sim` over a real pseudo-terminal: several drives of different
//! layouts on one line, each answering only telegrams of its own length; the scan finds exactly
//! that set, and leaves them in S2 (every probe carries OFF1). A device that does not exist, is not a tty, or is held by another process is a
//! clear error with exit code 1.
#![allow(clippy::unwrap_used)]

use std::process::Command;
use uss_integration_tests::{SimProcess, binary};
use uss_master::transports::serial::{SerialOptions, SerialTransport};

fn ussctl(args: &[&str]) -> (Option<i32>, String, String) {
    let out = Command::new(binary("ussctl", "ussctl"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_scan_finds_exactly_the_drives_on_the_line_with_their_layouts() {
    let sim = SimProcess::start(&[
        "--baud",
        "19200",
        "--drive",
        "3:pkw=4,pzd=2",
        "--drive",
        "5:pkw=127,pzd=6",
        "--drive",
        "7:pkw=3,pzd=4",
        "--drive",
        "9:pkw=0,pzd=2",
    ]);
    let (code, said, err) = ussctl(&["scan", &sim.path, "--baud", "19200"]);
    assert_eq!(code, Some(0), "{err}");
    let lines: Vec<&str> = said.lines().collect();
    assert_eq!(
        lines[..4],
        [
            " 19200 baud  drive  3: PKW 4, PZD 2, ZSW1 0xBB31 (S2), firmware 2.09, family = \"micromaster4\" (or \"g110\" for a G110)",
            " 19200 baud  drive  5: PKW variable (127), PZD 6, ZSW1 0xBB31 (S2), firmware 2.09, family = \"micromaster4\" (or \"g110\" for a G110)",
            " 19200 baud  drive  7: PKW 3, PZD 4, ZSW1 0xBB31 (S2)",
            " 19200 baud  drive  9: PKW 0, PZD 2, ZSW1 0xBB31 (S2)",
        ],
        "{said}"
    );
    assert!(
        lines[4].starts_with(&format!(
            "{}: 4 drives found, 32 addresses x 1 baud rate in ",
            sim.path
        )),
        "{said}"
    );
    let (code, json, _) = ussctl(&[
        "--json",
        "scan",
        &sim.path,
        "--baud",
        "19200",
        "--addresses",
        "5-7",
    ]);
    assert_eq!(code, Some(0));
    uss_integration_tests::assert_report("ussctl/scan", json.trim());
    assert!(
        json.contains("\"drives\":[{\"baud\":19200,\"address\":5,\"pkw\":\"variable (127)\",\"pzd\":6,\"zsw1\":47921,\"firmware\":2.09,\"family\":\"micromaster4\"},{\"baud\":19200,\"address\":7,\"pkw\":\"3\",\"pzd\":4,\"zsw1\":47921,\"firmware\":null,\"family\":null}]"),
        "{json}"
    );
    // Every probe carries OFF1 (STW1 0x047E, bit 10 set): the drives went S1 -> S2, ready but
    // not switched on, and none runs.
    let summary = sim.stop();
    assert_eq!(
        summary.matches("S2 ready to switch on   0.00 Hz").count(),
        4,
        "{summary}"
    );
}

#[test]
fn a_device_that_is_missing_not_a_tty_or_busy_is_a_clear_error() {
    let (code, _, err) = ussctl(&["scan", "/dev/uss-rt-no-such-device", "--baud", "9600"]);
    assert_eq!(code, Some(1));
    assert_eq!(
        err,
        "ussctl: cannot open /dev/uss-rt-no-such-device: No such file or directory\n"
    );
    let file = std::env::temp_dir().join(format!("uss-scan-{}", std::process::id()));
    std::fs::write(&file, "not a tty").unwrap();
    let (code, _, err) = ussctl(&["scan", file.to_str().unwrap(), "--baud", "9600"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("is not a serial device (not a tty)"), "{err}");
    let _ = std::fs::remove_file(&file);

    // A line another process holds (as ussd does): busy, and the scan says why.
    let sim = SimProcess::start(&["--baud", "9600", "--drive", "1"]);
    let options = SerialOptions {
        baud: uss_client::uss_protocol::Baud::new(9600).unwrap(),
        kernel_rs485: false,
        rs485_settings: uss_master::transports::serial::Rs485Wanted::default(),
        low_latency: false,
        rx_latency: core::time::Duration::ZERO,
    };
    let _held = SerialTransport::open(std::path::Path::new(&sim.path), &options).unwrap();
    let (code, _, err) = ussctl(&["scan", &sim.path, "--baud", "9600"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("device is busy"), "{err}");
    assert!(err.contains("is ussd serving this line?"), "{err}");
}

#[test]
fn a_scan_tells_a_g120_by_its_device_identification_and_leaves_an_unknown_slave_unnamed() {
    let sim = SimProcess::start(&[
        "--baud",
        "19200",
        "--drive",
        "2:pkw=4,pzd=2,family=g120",
        "--drive",
        "4:pkw=4,pzd=2,family=simoreg",
        "--drive",
        "6:pkw=127,pzd=2,family=g110",
    ]);
    let (code, said, err) = ussctl(&["scan", &sim.path, "--baud", "19200", "--addresses", "0-7"]);
    assert_eq!(code, Some(0), "{err}");
    let lines: Vec<&str> = said.lines().collect();
    assert_eq!(
        lines[..3],
        [
            " 19200 baud  drive  2: PKW 4, PZD 2, ZSW1 0xBB31 (S2), firmware 4.70, family = \"g120\"",
            " 19200 baud  drive  4: PKW 4, PZD 2, ZSW1 0xBB31 (S2)",
            " 19200 baud  drive  6: PKW variable (127), PZD 2, ZSW1 0xBB31 (S2), firmware 1.18, family = \"micromaster4\" (or \"g110\" for a G110)",
        ],
        "{said}"
    );
}
