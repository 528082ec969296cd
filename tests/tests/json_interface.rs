//! ussctl's machine interface: every command's `--json` output, as a script reads it from a
//! real ussd on a simulated bus, carries `"v"` and matches the JSON Schema shipped for it in
//! `docs/schema/ussctl/` (`ussctl schema` prints the same).

use std::process::Command;
use uss_integration_tests::{Ussd, assert_report, binary};

/// Runs `ussctl --bus <bus> --json <args>` to its end: its stdout, which must be a success.
fn json(ussd: &Ussd, args: &[&str]) -> String {
    json_exiting(ussd, args, 0)
}

/// [`json`] of a command that exits with `code` (`param diff` with differences: 1).
fn json_exiting(ussd: &Ussd, args: &[&str], code: i32) -> String {
    let out = Command::new(binary("ussctl", "ussctl"))
        .args(["--bus", &ussd.bus, "--json"])
        .args(args)
        .output()
        .expect("ussctl runs");
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.code() == Some(code),
        "ussctl --json {}: {text}{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    text
}

/// Each line of `text` is a `report` of version 1.
fn every_line(report: &str, text: &str) {
    let lines: Vec<&str> = text.lines().filter(|l| !l.is_empty()).collect();
    assert!(!lines.is_empty(), "no {report} line");
    for line in lines {
        assert!(line.starts_with("{\"v\":1,"), "{line}");
        assert_report(&format!("ussctl/{report}"), line);
    }
}

#[test]
fn every_json_output_carries_its_version_and_matches_its_shipped_schema() {
    // Started: every drive answered.
    let ussd = Ussd::start("", &[(1, ""), (2, "")]);
    every_line("status", &json(&ussd, &["status"]));
    every_line("stats", &json(&ussd, &["stats"]));
    every_line("watch", &json(&ussd, &["watch", "--count", "2", "1"]));
    every_line("param", &json(&ussd, &["param", "read", "1", "P1082"]));
    every_line("param", &json(&ussd, &["param", "read", "1", "r0052"]));
    every_line(
        "param",
        &json(&ussd, &["param", "write", "2", "P1121", "8"]),
    );
    every_line(
        "describe",
        &json(&ussd, &["param", "describe", "1", "P1082"]),
    );
    every_line("faults", &json(&ussd, &["faults", "1"]));
    // Drive 2's P1121 differs: diff says so by its exit status too.
    every_line(
        "diff",
        &json_exiting(&ussd, &["param", "diff", "1", "2"], 1),
    );
    let backup = std::env::temp_dir().join(format!("uss-json-{}.toml", std::process::id()));
    let file = backup.to_str().unwrap();
    json(&ussd, &["param", "backup", "1", "-o", file]);
    every_line("restore", &json(&ussd, &["param", "restore", "2", file]));
    every_line("save", &json(&ussd, &["param", "save", "2"]));
    every_line(
        "quick",
        &json(
            &ussd,
            &[
                "param",
                "quick-commission",
                "2",
                "--set",
                "P0304=400",
                "--unsafe",
            ],
        ),
    );
    let _ = std::fs::remove_file(&backup);
    every_line(
        "drive",
        &json(&ussd, &["run", "1", "--hz", "5", "--for", "1"]),
    );
    every_line("stop", &json(&ussd, &["stop", "1"]));
    every_line(
        "capture",
        &json(&ussd, &["capture", "--drive", "2", "--count", "6"]),
    );
    let csv = std::env::temp_dir().join(format!("uss-json-{}.csv", std::process::id()));
    every_line(
        "trace",
        &json(
            &ussd,
            &["trace", "1", "--for", "300ms", "-o", csv.to_str().unwrap()],
        ),
    );
    let _ = std::fs::remove_file(&csv);
}

/// The shipped schemas are what `ussctl schema` prints: one source, the report types.
#[test]
fn ussctl_schema_prints_the_shipped_schemas() {
    let out = Command::new(binary("ussctl", "ussctl"))
        .arg("schema")
        .output()
        .unwrap();
    let list = String::from_utf8_lossy(&out.stdout);
    let names: Vec<&str> = list
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert!(names.len() >= 13, "{list}");
    for name in names {
        let out = Command::new(binary("ussctl", "ussctl"))
            .args(["schema", name])
            .output()
            .unwrap();
        assert!(out.status.success());
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("../docs/schema/ussctl/{name}.json"));
        assert_eq!(
            String::from_utf8_lossy(&out.stdout),
            std::fs::read_to_string(&path).unwrap(),
            "{}",
            path.display()
        );
    }
}
