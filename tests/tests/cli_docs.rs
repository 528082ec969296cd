//! Shell completions and manual pages of the three binaries, generated from their own command
//! lines (`clap_complete`, `clap_mangen`), and help texts that say something.
#![allow(clippy::unwrap_used)]

use std::process::Command;
use uss_integration_tests::binary;

fn run(package: &str, name: &str, args: &[&str]) -> String {
    let out = Command::new(binary(package, name))
        .args(args)
        .output()
        .unwrap();
    assert!(out.status.success(), "{name} {args:?}: {out:?}");
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn every_binary_prints_completions_a_man_page_and_help() {
    for (package, name, completions) in [
        ("uss-master", "ussd", vec!["--completions", "bash"]),
        ("uss-drive-sim", "uss-sim", vec!["--completions", "bash"]),
        ("ussctl", "ussctl", vec!["completions", "bash"]),
    ] {
        let script = run(package, name, &completions);
        let function = format!("_{}()", name.replace('-', "__"));
        assert!(script.contains(&function), "{name}: {script}");
        let man = if name == "ussctl" {
            run(package, name, &["man"])
        } else {
            run(package, name, &["--man"])
        };
        assert!(man.contains(&format!(".TH {name} 1")), "{name}: {man}");
        assert!(man.contains(".SH OPTIONS"), "{name}");
        let help = run(package, name, &["--help"]);
        assert!(help.lines().count() > 5, "{name}: {help}");
    }
    // The exporter has its man page too (uss-zenoh's and uss-zenoh-client's are checked where
    // their package is installed: .ci/packages.sh).
    let man = run("uss-exporter", "uss-exporter", &["--man"]);
    assert!(man.contains(".TH uss-exporter 1"), "{man}");
    let zsh = run("ussctl", "ussctl", &["completions", "zsh"]);
    assert!(zsh.contains("#compdef ussctl"), "{zsh}");
    // Every subcommand of ussctl names what it does.
    let help = run("ussctl", "ussctl", &["--help"]);
    for sub in [
        "status",
        "watch",
        "param",
        "run",
        "stop",
        "faults",
        "scan",
        "completions",
        "man",
    ] {
        let line = help
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{sub} ")))
            .unwrap_or_else(|| panic!("{sub} missing: {help}"));
        assert!(line.split_whitespace().count() > 2, "{line}");
    }
}
