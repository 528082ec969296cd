//! Every front-end offers the same calls (issue 34.3): one table names each call's spelling in
//! Rust (`uss_client`), in C (`ussrt.h`) and in Python (`uss_rt`), and this test fails when a
//! spelling is missing from its front-end, when the Rust `Controller` gains a call the table
//! does not name, or when `ussrt.h` exports a function it does not name. A call one front-end
//! keeps for itself is listed below with the reason.
#![allow(clippy::unwrap_used)]

use std::path::Path;
use uss_integration_tests::root;

/// (Rust, C, Python). Rust names a `pub fn` of `uss_client`; C an exported function of
/// `ussrt.h`; Python a function of `uss_rt` or a method of its `Bus`/`Controller` (written in
/// Python or in the native module).
const CALLS: &[(&str, &str, &str)] = &[
    // The bus.
    ("open", "ussrt_bus_open", "open_bus"),
    ("drives", "ussrt_bus_drives", "drives"),
    ("health", "ussrt_bus_health", "health"),
    ("status", "ussrt_bus_status", "status"),
    ("diag", "ussrt_drive_diag", "diag"),
    ("snapshot", "ussrt_drive_read", "read_input"),
    ("wait_exchanges", "ussrt_wait_exchange", "wait_exchange"),
    // Parameters.
    ("read_param", "ussrt_param_read", "read"),
    ("read", "ussrt_param_read_raw", "read_param"),
    (
        "read_elements",
        "ussrt_param_read_elements",
        "read_elements",
    ),
    ("write_param", "ussrt_param_write", "write"),
    ("write_with", "ussrt_param_write_raw", "write"),
    ("try_batch", "ussrt_param_batch", "batch"),
    ("fault_report", "ussrt_fault_report", "fault_report"),
    ("drive_description", "ussrt_param_describe", "describe"),
    // Commissioning.
    ("save_to_rom", "ussrt_param_save", "save_to_rom"),
    ("upload", "ussrt_param_backup", "backup"),
    ("upload_with", "ussrt_param_backup_discover", "backup"),
    ("diff_file", "ussrt_param_diff", "diff"),
    ("restore", "ussrt_param_restore", "restore"),
    (
        "factory_reset",
        "ussrt_param_factory_reset",
        "factory_reset",
    ),
    (
        "quick_commission",
        "ussrt_param_quick_commission",
        "quick_commission",
    ),
    ("scan", "ussrt_scan", "scan"),
    // An operator's stops.
    ("stop_drive", "ussrt_stop_drive", "stop_drive"),
    ("stop_all", "ussrt_stop_all", "stop_all"),
    ("wait_stopped", "ussrt_wait_stopped", "wait_stopped"),
    // The controller.
    ("control", "ussrt_control_open", "control"),
    ("check", "ussrt_control_check", "check"),
    ("keepalive", "ussrt_control_keepalive", "keepalive"),
    ("rearm", "ussrt_control_rearm_at", "rearm"),
    // When a re-arm was asked for: the program's start.
    (
        "process_start_ns",
        "ussrt_process_start_ns",
        "process_start_ns",
    ),
    ("enable", "ussrt_control_enable", "enable"),
    ("run_hz", "ussrt_control_run_hz", "run_hz"),
    ("run_percent", "ussrt_control_run_percent", "run_percent"),
    ("run_rpm", "ussrt_control_run_rpm", "run_rpm"),
    ("set_hz", "ussrt_control_set_hz", "set_hz"),
    ("stop", "ussrt_control_stop", "stop"),
    ("coast", "ussrt_control_coast", "coast"),
    ("quick_stop", "ussrt_control_quick_stop", "quick_stop"),
    ("reverse", "ussrt_control_reverse", "reverse"),
    ("jog", "ussrt_control_jog", "jog"),
    (
        "acknowledge_fault",
        "ussrt_control_acknowledge_fault",
        "acknowledge",
    ),
    ("set_words", "ussrt_control_set_words", "set_words"),
    (
        "wait_for_state",
        "ussrt_control_wait_state",
        "wait_for_state",
    ),
    (
        "refresh_period",
        "ussrt_control_refresh_period",
        "handshake",
    ),
    ("release", "ussrt_control_release", "release"),
];

/// `Controller` calls that are Rust's alone, and why.
const RUST_ONLY: &[(&str, &str)] = &[
    (
        "rearm_keeping_stop",
        "for ussctl ack, which only acknowledges a fault and lets go: a program of C, Python or LinuxCNC that acknowledges keeps its own coast through acknowledge_fault, and its re-arm is the one that leads to an ON (OFF1 first)",
    ),
    (
        "address",
        "an accessor: C and Python keep the address they opened with",
    ),
    (
        "inputs",
        "the controller's DriveWatch: C reads with ussrt_control_check, Python with inputs()",
    ),
    (
        "words",
        "the words sent: Python has words(); C keeps the words it set",
    ),
    ("stw1", "STW1 of words()"),
    (
        "sequence",
        "the sample's sequence number, for the Zenoh bridge's relay",
    ),
    ("refresh", "the Refresher thread's call"),
    (
        "run_setpoint",
        "a raw setpoint word: C and Python take Hz or %",
    ),
    (
        "set_setpoint",
        "a raw setpoint word: C and Python take Hz (set_hz)",
    ),
    (
        "acknowledge_latch",
        "a relay's re-arm naming a latch (the Zenoh bridge)",
    ),
    (
        "wait_for",
        "takes a Rust closure: Python's wait_for takes a callable; C waits for a state",
    ),
    ("wait_polled", "wait_for with a poll hook, for the bridge"),
    (
        "spawn_refresher",
        "Python starts one with every controller; C programs call keepalive",
    ),
    (
        "release_shared",
        "release of a shared handle: what C's and Python's release call",
    ),
];

/// C functions with no call of their own elsewhere, and why.
const C_ONLY: &[(&str, &str)] = &[
    (
        "ussrt_bus_close",
        "frees the handle (Rust and Python drop it)",
    ),
    ("ussrt_control_close", "frees the handle"),
    (
        "ussrt_param_restore_cancellable",
        "restore with a cancel: Rust's restore takes a Cancel (CancelHandle), Python's is cut short by Ctrl-C",
    ),
    (
        "ussrt_cancel",
        "asks a cancel, from a signal handler too: Rust's CancelHandle::cancel, Python's Ctrl-C",
    ),
    ("ussrt_cancel_new", "makes the cancel handle"),
    ("ussrt_cancel_free", "frees the cancel handle"),
    (
        "ussrt_last_error",
        "C's error message (Rust and Python return errors)",
    ),
    ("ussrt_last_error_info", "C's error details"),
    ("ussrt_status_name", "a status code's name"),
    ("ussrt_version", "the library's version"),
    (
        "ussrt_monotonic_ns",
        "CLOCK_MONOTONIC now, a re-arm's asked_ns: Rust has uss_client::monotonic_ns, Python time.monotonic_ns (the same clock)",
    ),
];

fn read(path: &str) -> String {
    std::fs::read_to_string(root().join(path)).unwrap()
}

fn read_dir(dir: &str, ext: &str) -> String {
    let mut all = String::new();
    for entry in std::fs::read_dir(root().join(dir)).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) == Some(ext) {
            all += &std::fs::read_to_string(&path).unwrap();
        }
    }
    all
}

/// The functions `ussrt.h` declares (not those its comments mention).
fn c_functions() -> Vec<String> {
    let header = read("capi/include/ussrt.h");
    let mut names: Vec<String> = header
        .lines()
        .filter(|l| !l.trim_start().starts_with('*') && !l.trim_start().starts_with('/'))
        .filter_map(|l| {
            let at = l.find("ussrt_")?;
            let name: String = l[at..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            l[at + name.len()..].starts_with('(').then_some(name)
        })
        .collect();
    names.sort();
    names.dedup();
    names
}

/// The `pub fn`s of `impl Controller` in `clients/src/control.rs`.
fn controller_calls() -> Vec<String> {
    let source = read("clients/src/control.rs");
    let start = source.find("\nimpl Controller {").unwrap();
    let body = &source[start..];
    let body = &body[..body[1..].find("\n}").unwrap()];
    body.lines()
        .filter_map(|l| l.trim_start().strip_prefix("pub fn "))
        .map(|l| l.split(['(', '<']).next().unwrap().to_owned())
        .collect()
}

#[test]
fn every_call_has_its_spelling_in_every_front_end() {
    let rust = read_dir("clients/src", "rs");
    let c = c_functions();
    let python = read_dir("python/uss_rt", "py") + &read_dir("python/src", "rs");
    let mut missing = Vec::new();
    for &(r, cn, py) in CALLS {
        if !rust.contains(&format!("pub fn {r}(")) && !rust.contains(&format!("pub fn {r}<")) {
            missing.push(format!("Rust {r}"));
        }
        if !c.iter().any(|f| f == cn) {
            missing.push(format!("C {cn}"));
        }
        let in_python = [
            format!("def {py}("),
            format!("fn {py}("),
            format!("fn {py}<"),
        ]
        .iter()
        .any(|s| python.contains(s.as_str()));
        if !in_python {
            missing.push(format!("Python {py}"));
        }
    }
    assert!(
        missing.is_empty(),
        "calls missing in a front-end: {missing:?}"
    );
}

#[test]
fn a_call_added_to_one_front_end_is_in_the_table() {
    let named =
        |f: &str| CALLS.iter().any(|&(r, _, _)| r == f) || RUST_ONLY.iter().any(|&(r, _)| r == f);
    let unnamed: Vec<String> = controller_calls()
        .into_iter()
        .filter(|f| !named(f))
        .collect();
    assert!(
        unnamed.is_empty(),
        "Controller calls the parity table does not name (give them a C and a Python \
         spelling, or say in RUST_ONLY why not): {unnamed:?}"
    );
    let unnamed: Vec<String> = c_functions()
        .into_iter()
        .filter(|f| !CALLS.iter().any(|&(_, c, _)| c == f) && !C_ONLY.iter().any(|&(c, _)| c == f))
        .collect();
    assert!(
        unnamed.is_empty(),
        "ussrt.h exports functions the parity table does not name: {unnamed:?}"
    );
    assert!(Path::new(&root().join("capi/include/ussrt.h")).exists());
}
