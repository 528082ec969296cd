//! `ussctl scan` against `uss-sim` over a real pseudo-terminal: several drives of different
//! layouts on one line, each answering only telegrams of its own length; the scan finds exactly
//! that set, and leaves them in S2 (every probe carries OFF1). A device that does not exist, is not a tty, or is held by another process is a
//! clear error with exit code 1.
#![allow(clippy::unwrap_used)]

use std::process::Command;
use uss_integration_tests::{SimProcess, binary};
use uss_serial::{SerialOptions, SerialTransport};

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
        json.contains("\"drives\":[{\"baud\":19200,\"address\":5,\"pkw\":\"variable (127)\",\"pzd\":6,\"zsw1\":47921,\"firmware\":2.09,\"family\":\"micromaster4\",\"unsure\":null},{\"baud\":19200,\"address\":7,\"pkw\":\"3\",\"pzd\":4,\"zsw1\":47921,\"firmware\":null,\"family\":null,\"unsure\":null}]"),
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
        rs485_settings: uss_serial::Rs485Wanted::default(),
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

/// Two generic slaves of the same telegram length (10 words): PKW 4 with PZD 6 and PKW 3 with PZD
/// 7. The first answers the P0003 probe with a double word (a generic slave's own parameter),
/// which only a 4-word channel carries: it was reported as "PKW 3, PZD 7, ZSW1 0x0000" with no
/// UNSURE mark (issue 46, item 6).
#[test]
fn a_generic_slave_whose_answer_is_a_double_word_has_a_4_word_channel() {
    let sim = SimProcess::start(&[
        "--baud",
        "19200",
        "--drive",
        "4:pkw=4,pzd=6,family=generic",
        "--drive",
        "6:pkw=3,pzd=7,family=generic",
    ]);
    let (code, said, err) = ussctl(&["scan", &sim.path, "--baud", "19200", "--addresses", "3-7"]);
    assert_eq!(code, Some(0), "{err}");
    let lines: Vec<&str> = said.lines().collect();
    assert_eq!(
        lines[..2],
        [
            " 19200 baud  drive  4: PKW 4, PZD 6, ZSW1 0xBB31 (S2)",
            " 19200 baud  drive  6: PKW 3, PZD 7, ZSW1 0xBB31 (S2)",
        ],
        "{said}"
    );
}

/// What a sure line says of each drive of [`LOSSY_LINE`].
const LOSSY_EXPECTED: [(u8, &str); 6] = [
    (
        2,
        "PKW 4, PZD 2, ZSW1 0xBB31 (S2), firmware 4.70, family = \"g120\"",
    ),
    (
        3,
        "PKW 4, PZD 2, ZSW1 0xBB31 (S2), firmware 2.09, family = \"micromaster4\" (or \"g110\" for a G110)",
    ),
    (
        5,
        "PKW variable (127), PZD 6, ZSW1 0xBB31 (S2), firmware 2.09, family = \"micromaster4\" (or \"g110\" for a G110)",
    ),
    (7, "PKW 3, PZD 4, ZSW1 0xBB31 (S2)"),
    (9, "PKW 0, PZD 2, ZSW1 0xBB31 (S2)"),
    (
        11,
        "PKW 4, PZD 2, ZSW1 0xBB31 (S2), firmware 2.09, family = \"micromaster4\" (or \"g110\" for a G110)",
    ),
];

/// A 19200 baud line whose drives lose 35 % of their replies (drive 11: 30 % bad BCC).
const LOSSY_LINE: [&str; 6] = [
    "2:pkw=4,pzd=2,family=g120,drop=0.35",
    "3:pkw=4,pzd=2,drop=0.35",
    "5:pkw=127,pzd=6,drop=0.35",
    "7:pkw=3,pzd=4,drop=0.35",
    "9:pkw=0,pzd=2,drop=0.35",
    "11:pkw=4,pzd=2,bcc=0.3",
];

/// How `scan` did on [`LOSSY_LINE`] with the simulator's seed `seed`: (lines right, lines
/// marked unsure, lines wrong and not marked, drives missed), and what it printed.
fn lossy_scan(seed: u64, extra: &[&str]) -> ([usize; 4], String) {
    let seed = seed.to_string();
    let mut args = vec!["--baud", "19200", "--seed", &seed];
    for d in LOSSY_LINE {
        args.extend(["--drive", d]);
    }
    let sim = SimProcess::start(&args);
    let mut scan = vec!["scan", &sim.path, "--baud", "19200", "--addresses", "0-11"];
    scan.extend_from_slice(extra);
    let (code, said, err) = ussctl(&scan);
    assert_eq!(code, Some(0), "{err}");
    let mut tally = [0; 4];
    for (address, expected) in LOSSY_EXPECTED {
        let head = format!(" 19200 baud  drive {address:2}: ");
        match said.lines().find(|l| l.starts_with(&head)) {
            Some(line) if line.contains("; UNSURE: ") => tally[1] += 1,
            Some(line) if line[head.len()..] == *expected => tally[0] += 1,
            Some(_) => tally[2] += 1,
            None => tally[3] += 1,
        }
    }
    (tally, said)
}

/// Through replies lost (35 %) or spoilt (30 % bad BCC), every line of a scan is right or says
/// it is not sure: a layout is confirmed by a second reply, a PKW 0 layout is checked like the
/// others, a lost identification is asked again and its value checked. Over 20 scans with the
/// default 4 tries it prints the success rate (issue 33); a scan that missed a drive (silent to
/// 4 mirror telegrams in a row) finds it with more tries.
#[test]
fn a_scan_through_lost_replies_is_right_or_says_it_is_unsure() {
    let mut total = [0; 4];
    let mut whole = 0;
    for seed in 1..=20 {
        let (tally, said) = lossy_scan(seed, &[]);
        println!("scan: seed {seed}: right, unsure, wrong, missed = {tally:?}\n{said}");
        for (t, n) in total.iter_mut().zip(tally) {
            *t += n;
        }
        if tally[2] + tally[3] == 0 {
            whole += 1;
        }
        if tally[3] > 0 {
            let (again, said) = lossy_scan(seed, &["--tries", "8"]);
            println!("scan: seed {seed} with --tries 8: {again:?}\n{said}");
            assert_eq!(again[2] + again[3], 0, "with more tries: {said}");
        }
    }
    println!(
        "scan: 20 scans of 6 drives at 35 % lost replies: lines right {}, marked unsure {}, \
         wrong and not marked {}, drives missed {}; scans with every line right or marked \
         unsure and no drive missed: {whole} of 20",
        total[0], total[1], total[2], total[3]
    );
    assert_eq!(total[2], 0, "lines wrong and not marked unsure");
}

/// A drive whose every reply has a bad BCC answered: it is not reported as absent, but as a
/// line that says what was heard.
#[test]
fn a_drive_heard_only_garbled_is_an_unsure_line_not_an_empty_address() {
    let sim = SimProcess::start(&["--baud", "19200", "--drive", "5:bcc=1.0"]);
    let (code, said, err) = ussctl(&["scan", &sim.path, "--baud", "19200", "--addresses", "4-6"]);
    assert_eq!(code, Some(0), "{err}");
    let line = said
        .lines()
        .find(|l| l.starts_with(" 19200 baud  drive  5: "))
        .unwrap_or_else(|| panic!("drive 5 missing: {said}"));
    assert!(
        line.contains("; UNSURE: something answered at this address, but never intact"),
        "{said}"
    );
    assert!(said.contains(": 1 drive found"), "{said}");
}

/// Issue 47, item 3: a scan of a pty without `--baud` ran 35 s silently and reported each drive
/// at every rate. A pseudo-terminal carries every rate alike: the scan asks at one and says so.
#[test]
fn a_scan_of_a_pseudo_terminal_asks_at_one_rate_and_says_why() {
    let sim = SimProcess::start(&["--baud", "19200", "--drive", "3"]);
    let (code, said, err) = ussctl(&["scan", &sim.path, "--addresses", "2-4"]);
    assert_eq!(code, Some(0), "{said}{err}");
    assert!(
        err.contains("is a pseudo-terminal: it carries every baud rate alike")
            && err.contains("asks at 19200 baud only"),
        "{err}"
    );
    let found: Vec<&str> = said.lines().filter(|l| l.contains("drive  3:")).collect();
    assert_eq!(found.len(), 1, "drive 3 once, at 19200 baud: {said}");
    assert!(found[0].starts_with(" 19200 baud"), "{said}");
    assert!(said.contains("3 addresses x 1 baud rate"), "{said}");
}

/// Issue 47, item 6: a scan's drives as ready-to-paste `[[bus.drive]]` TOML, which ussd's
/// configuration takes as it is (`ussd --check-config`), with the layouts found.
#[test]
fn a_scan_prints_the_drives_as_a_configuration_ussd_takes() {
    let sim = SimProcess::start(&[
        "--baud",
        "19200",
        "--drive",
        "3:pkw=4,pzd=2",
        "--drive",
        "5:pkw=127,pzd=6",
        "--drive",
        "7:pkw=3,pzd=4",
    ]);
    let (code, toml, err) = ussctl(&[
        "scan",
        &sim.path,
        "--baud",
        "19200",
        "--addresses",
        "2-8",
        "--toml",
    ]);
    assert_eq!(code, Some(0), "{toml}{err}");
    for entry in [
        "[[bus]]\nname = \"line1\"",
        "baud = 19200",
        "[[bus.drive]]\naddress = 3\npkw = 4\npzd = 2\nfamily = \"micromaster4\"",
        "[[bus.drive]]\naddress = 5\npkw = 127\npzd = 6",
        // Not told: generic, which assumes nothing (issue 47's sweep: left as a comment, ussd
        // took its default micromaster4 for a SIMOREG).
        "[[bus.drive]]\naddress = 7\npkw = 3\npzd = 4\nfamily = \"generic\"   # not told by the drive",
    ] {
        assert!(toml.contains(entry), "{entry:?} in\n{toml}");
    }
    let file = std::env::temp_dir().join(format!("uss-scan-{}.toml", std::process::id()));
    std::fs::write(&file, &toml).unwrap();
    let out = Command::new(binary("uss-master", "ussd"))
        .arg("--check-config")
        .arg(&file)
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&file);
    assert!(
        out.status.success(),
        "{toml}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
