//! Issue 47, item 6: a program of a Rust user's own on `uss-client`, as its project would
//! depend on it (`examples/rust-controller`), runs against a real ussd as its text says.
#![allow(clippy::unwrap_used)]

use std::process::Command;
use uss_integration_tests::{Ussd, binary};

#[test]
fn the_rust_example_program_reads_runs_and_stops_a_drive() {
    let ussd = Ussd::start("", &[(1, "")]);
    let out = Command::new(binary("uss-example-controller", "uss-example-controller"))
        .args([ussd.bus.as_str(), "1"])
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        said,
        "drive 1: P1082 = 50.00 Hz\ndrive 1: running at 10 Hz\ndrive 1: stopped (OFF1)\n"
    );
}
