//! The C/C++ side of the contract: `include/uss_shm_types.h` is exactly what cbindgen makes of
//! this crate, and a C program (`c-test/layout_check.c`) compiled against it sees the sizes,
//! alignments and field offsets of [`LAYOUTS`], the codes of every code table, the iceoryx2
//! type names and the service names that the Rust side uses.
//!
//! After changing the contract, regenerate the header with
//! `UPDATE_C_HEADER=1 cargo test -p uss-shm-types --test c_header -- checked_in_header`.
#![allow(clippy::unwrap_used)]

use core::fmt::Write as _;
use iceoryx2::prelude::ZeroCopySend;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use uss_shm_types::layout::{FieldLayout, LAYOUTS, TypeLayout};
use uss_shm_types::names::{self, BlackboardKey};
use uss_shm_types::{
    Address, BusName, BusState, BusStatus, CommandError, ControlState, Direction, DriveCounters,
    DriveDiag, DriveFamily, DriveInfo, Generation, Heartbeat, Instance, LastFailure, LatchReason,
    LineFault, LineState, Monitoring, OperatorRequest, OperatorResponse, Outcome, ParamItem,
    ParamRequest, ParamResponse, ParamResult, PzdInput, PzdOutput, Rejection, RequestError, RtMode,
    StopCommand, Storage, TaskCode, TelegramRecord,
};

const REGENERATE: &str =
    "UPDATE_C_HEADER=1 cargo test -p uss-shm-types --test c_header -- checked_in_header";

fn crate_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn header_path() -> PathBuf {
    crate_dir().join("include/uss_shm_types.h")
}

/// A scratch directory of this test binary.
fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

use uss_shm_types::screaming_snake as screaming;

/// The C name of a contract type: `PzdOutput` -> `UssPzdOutput`.
fn c_type(rust: &str) -> String {
    format!("Uss{rust}")
}

// ---------------------------------------------------------------------------------------------
// The header
// ---------------------------------------------------------------------------------------------

/// The `code_table!` invocations of one source file as plain `#[repr(u8)]` enums, doc comments
/// and all, so cbindgen (which does not expand macros) sees them: each
/// `Variant = 3 => "text",` line loses its `=> "text"`. Adds the enums' names to `names`.
fn code_tables_of(source: &str, names: &mut Vec<String>) -> String {
    let mut out = String::new();
    let mut rest = source;
    while let Some(at) = rest.find("code_table! {") {
        let body = &rest[at + "code_table! {".len()..];
        let mut depth = 1;
        let end = body
            .char_indices()
            .find_map(|(i, c)| {
                depth += match c {
                    '{' => 1,
                    '}' => -1,
                    _ => 0,
                };
                (depth == 0).then_some(i)
            })
            .expect("a code_table! invocation closes its brace");
        for line in body[..end].lines() {
            let line = line.trim();
            if let Some(name) = line.strip_prefix("pub enum ") {
                names.push(name.trim_end_matches(" {").to_owned());
                out.push_str("#[repr(u8)]\n");
            }
            if let Some(arrow) = line.find(" => \"") {
                assert!(line.ends_with("\","), "one variant per line: {line}");
                out.push_str(&line[..arrow]);
                out.push_str(",\n");
            } else {
                out.push_str(line);
                out.push('\n');
            }
        }
        rest = &body[end..];
    }
    out
}

/// The codec's enum `name` (in `protocol/src/<file>`), which the contract uses as it is, doc
/// comments and all, for cbindgen: from its doc comment to its closing brace, without
/// `#[default]`. Adds `name` to `names`.
fn codec_enum(file: &str, name: &str, names: &mut Vec<String>) -> String {
    let path = crate_dir().join("../protocol/src").join(file);
    let source = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = source.lines().collect();
    let at = lines
        .iter()
        .position(|l| *l == format!("pub enum {name} {{"))
        .expect("the codec defines the enum");
    let start = (0..at)
        .rev()
        .take_while(|&i| lines[i].starts_with("///") || lines[i].starts_with("#["))
        .last()
        .unwrap_or(at);
    let end = at + lines[at..].iter().position(|l| *l == "}").expect("closes");
    names.push(name.to_owned());
    let mut out = String::new();
    for l in &lines[start..=end] {
        if l.trim() != "#[default]" && !l.starts_with("#[derive") {
            out.push_str(l);
            out.push('\n');
        }
    }
    out
}

/// Text cbindgen cannot produce from the crate (it skips string constants): the iceoryx2 type
/// names and the service name patterns, in the header's comment style.
fn strings_section() -> String {
    let mut s = String::from(
        "\n/*\n * iceoryx2 type names. Every port on a ussd service must declare its payload (and \
         blackboard key)\n * with these names: iceoryx2 compares type name, size and alignment \
         when a port is opened.\n * C: pass them to iox2_service_builder_*_set_*_type_details; \
         C++: the structs carry them\n * as IOX2_TYPE_NAME.\n */\n",
    );
    for t in LAYOUTS {
        let _ = writeln!(
            s,
            "#define USS_{}_TYPE_NAME \"{}\"",
            screaming(t.name),
            t.type_name
        );
    }
    s.push_str(
        "\n/*\n * Service names (snprintf patterns; %s = bus name, 1 to 32 of [A-Za-z0-9_-]; \
         %016llx = the\n * serving ussd's generation from its newest heartbeat, as an unsigned \
         long long; %u = drive\n * address 0..31 in decimal). Every service carries the \
         attribute USS_LAYOUT_VERSION_ATTRIBUTE whose\n * value is USS_LAYOUT_VERSION in \
         decimal.\n */\n",
    );
    let _ = writeln!(
        s,
        "#define USS_LAYOUT_VERSION_ATTRIBUTE \"{}\"",
        names::LAYOUT_VERSION_ATTRIBUTE
    );
    for service in services() {
        let _ = writeln!(
            s,
            "/** {} */\n#define USS_{} \"{}\"",
            service.what,
            service.c_name,
            service.pattern()
        );
    }
    s.pop(); // cbindgen ends the section's last line
    s
}

/// What a name of [`names`] is made of besides the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scope {
    /// The bus alone (`%s`).
    Bus,
    /// One ussd instance: the bus and its generation (`%s`, `%016llx`).
    Instance,
    /// One drive of an instance (`%s`, `%016llx`, `%u`).
    Drive,
}

/// One name of [`names`], for C.
struct Service {
    /// After `USS_`.
    c_name: &'static str,
    scope: Scope,
    what: &'static str,
    name: fn(&Instance, Address) -> String,
}

/// The stand-ins a pattern is found with.
const BUS: &str = "BUS";
const GENERATION: Generation = Generation(0x0123_4567_89ab_cdef);
const ADDRESS: u8 = 31;

impl Service {
    /// The name as a printf pattern, found by asking [`names`] for stand-ins.
    fn pattern(&self) -> String {
        let instance = Instance::new(BusName::new(BUS).unwrap(), GENERATION);
        let name = (self.name)(&instance, Address::new(ADDRESS).unwrap());
        let p = name
            .replace(&format!("/{ADDRESS}/"), "/%u/")
            .replace(&GENERATION.to_string(), "%016llx")
            .replace(BUS, "%s");
        assert_eq!(p.matches("%s").count(), 1, "{name}");
        assert_eq!(p.contains("%016llx"), self.scope != Scope::Bus, "{name}");
        assert_eq!(p.contains("%u"), self.scope == Scope::Drive, "{name}");
        p
    }
}

/// Every name of [`names`].
fn services() -> [Service; 13] {
    let s = |c_name, scope, what, name| Service {
        c_name,
        scope,
        what,
        name,
    };
    [
        s(
            "SERVICE_HEARTBEAT",
            Scope::Bus,
            "publish-subscribe, UssHeartbeat: ussd's heartbeat; its generation names the services below.",
            |i, _| names::heartbeat(&i.bus).as_str().into(),
        ),
        s(
            "SERVICE_DRIVE_OUT",
            Scope::Drive,
            "publish-subscribe, UssPzdOutput: the controller's output image (one publisher).",
            |i, a| names::drive_out(i, a).as_str().into(),
        ),
        s(
            "SERVICE_DRIVE_IN",
            Scope::Drive,
            "blackboard, key UssBlackboardKey_IMAGE (value 0) -> UssPzdInput.",
            |i, a| names::drive_in(i, a).as_str().into(),
        ),
        s(
            "SERVICE_DIAG",
            Scope::Instance,
            "blackboard, key = drive address -> UssDriveDiag.",
            |i, _| names::diag(i).as_str().into(),
        ),
        s(
            "SERVICE_STATUS",
            Scope::Instance,
            "blackboard, key UssBlackboardKey_IMAGE (value 0) -> UssBusStatus.",
            |i, _| names::status(i).as_str().into(),
        ),
        s(
            "SERVICE_CYCLE",
            Scope::Instance,
            "event: drive address (exchange completed), USS_CYCLE_COMPLETED, \
             USS_STATUS_PUBLISHED, USS_USSD_GONE.",
            |i, _| names::cycle(i).as_str().into(),
        ),
        s(
            "SERVICE_PARAMS",
            Scope::Instance,
            "request-response, UssParamRequest -> UssParamResponse.",
            |i, _| names::params(i).as_str().into(),
        ),
        s(
            "STOP_SOCKET",
            Scope::Bus,
            "Unix stream socket in the service root (/dev/shm/uss-rt, or $USS_RT_SHM): operator \
             stops, one UssOperatorRequest (8 bytes, version little-endian) in, one \
             UssOperatorResponse (12 bytes, little-endian) out.",
            |i, _| {
                names::stop_socket(&i.bus)
                    .file_name()
                    .map(|f| f.to_string_lossy().into_owned())
                    .unwrap_or_default()
            },
        ),
        s(
            "SERVICE_CAPTURE",
            Scope::Instance,
            "publish-subscribe, UssTelegramRecord: every telegram of the bus (ussd publishes).",
            |i, _| names::capture(i).as_str().into(),
        ),
        s(
            "SERVICE_REQUESTS",
            Scope::Instance,
            "event: notify USS_REQUEST_SENT after sending on params (else ussd finds the \
             request within USS_REQUEST_POLL_NS).",
            |i, _| names::requests(i).as_str().into(),
        ),
        s(
            "SERVICE_ANSWERS",
            Scope::Instance,
            "event: ussd notifies USS_ANSWER_SENT after each answer on params.",
            |i, _| names::answers(i).as_str().into(),
        ),
        s(
            "USSD_NODE",
            Scope::Bus,
            "ussd's node name for a bus.",
            |i, _| names::ussd_node(&i.bus).as_str().into(),
        ),
        s(
            "GENERATION_FORMAT",
            Scope::Instance,
            "how a generation is written in service names (after the bus).",
            |i, _| format!("uss/{}/{}", i.bus, i.generation),
        ),
    ]
}

/// cbindgen's configuration for the payload types and `code_tables`.
fn config(code_tables: &[String]) -> cbindgen::Config {
    let mut c = cbindgen::Config {
        language: cbindgen::Language::C,
        cpp_compat: true,
        include_guard: Some("USS_SHM_TYPES_H".into()),
        no_includes: true,
        sys_includes: vec!["stdint.h".into()],
        documentation: true,
        header: Some(format!(
            "/*\n * uss_shm_types.h: the shared-memory contract between ussd and its clients \
             (crate uss-shm-types),\n * for C and C++. Payload types, code tables, limits, \
             iceoryx2 type names and service names.\n * Fields are fixed-width with no implicit \
             padding; `version` is USS_LAYOUT_VERSION, readers check it.\n *\n * Generated by \
             cbindgen from shm-types/src: do not edit. Regenerate with\n *   {REGENERATE}\n */"
        )),
        after_includes: Some(strings_section()),
        ..cbindgen::Config::default()
    };
    c.enumeration.rename_variants = cbindgen::RenameRule::QualifiedScreamingSnakeCase;
    // Constants become USS_*, types Uss* (renames override the prefix).
    c.export.prefix = Some("USS_".into());
    c.export.renaming_overrides_prefixing = true;
    let types = LAYOUTS
        .iter()
        .map(|t| t.name)
        .chain(code_tables.iter().map(String::as_str));
    c.export.include = types.clone().map(String::from).collect();
    // The rules' own types (uss-control) are no part of the contract.
    c.export.exclude = vec!["LatchView".into(), "Session".into(), "Sample".into()];
    c.export.rename = types.map(|t| (t.to_string(), c_type(t))).collect();
    // C++ gets the iceoryx2 type name as the member its bindings look for.
    c.export.body = LAYOUTS
        .iter()
        .map(|t| {
            (
                t.name.to_string(),
                format!(
                    "#ifdef __cplusplus\n  static constexpr const char *IOX2_TYPE_NAME = \
                     \"{}\";\n#endif",
                    t.type_name
                ),
            )
        })
        .collect::<HashMap<_, _>>();
    c
}

/// The header as cbindgen generates it now.
fn generate_header() -> String {
    // The contract's own sources, and the control vocabulary's (`uss-control`) whose codes the
    // contract carries as bytes.
    let mut files: Vec<PathBuf> = [crate_dir().join("src"), crate_dir().join("../control/src")]
        .iter()
        .flat_map(|dir| std::fs::read_dir(dir).unwrap())
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "rs"))
        // Of the rule machines, only what C names: the gate is ussd's own (and the crate root
        // would bring it in).
        .filter(|p| !p.ends_with("control/src/gate.rs") && !p.ends_with("control/src/lib.rs"))
        .collect();
    files.sort_by_key(|p| p.file_name().map(std::ffi::OsStr::to_owned));
    let mut table_names = Vec::new();
    let mut tables: String = files
        .iter()
        .map(|f| code_tables_of(&std::fs::read_to_string(f).unwrap(), &mut table_names))
        .collect();
    tables.push_str(&codec_enum("pkw.rs", "Storage", &mut table_names));
    let tables_file = scratch("code-tables").join("code_tables.rs");
    std::fs::write(&tables_file, tables).unwrap();

    let mut builder = cbindgen::Builder::new()
        .with_config(config(&table_names))
        .with_src(&tables_file);
    for f in &files {
        builder = builder.with_src(f);
    }
    let mut out = Vec::new();
    builder.generate().unwrap().write(&mut out);
    String::from_utf8(out).unwrap()
}

#[test]
fn checked_in_header_is_what_cbindgen_generates() {
    let generated = generate_header();
    let path = header_path();
    if std::env::var_os("UPDATE_C_HEADER").is_some() {
        std::fs::write(&path, &generated).unwrap();
        return;
    }
    let checked_in = std::fs::read_to_string(&path).unwrap_or_default();
    if checked_in != generated {
        let line = checked_in
            .lines()
            .zip(generated.lines())
            .position(|(a, b)| a != b)
            .map_or_else(|| "at the end".into(), |i| format!("at line {}", i + 1));
        panic!(
            "{} differs from what cbindgen generates ({line}): regenerate it with\n  {REGENERATE}",
            path.display()
        );
    }
}

// ---------------------------------------------------------------------------------------------
// The C program
// ---------------------------------------------------------------------------------------------

/// `layout_expected.h` for `c-test/layout_check.c`: one check per line, every number and string
/// taken from the Rust side.
fn expected_checks(layouts: &[TypeLayout]) -> String {
    let mut s = String::from("/* Generated by shm-types/tests/c_header.rs for one run. */\n");
    for t in layouts {
        let c = c_type(t.name);
        let _ = writeln!(s, "EXPECT_TYPE({c}, {}, {})", t.size, t.align);
        for f in t.fields {
            let _ = writeln!(s, "EXPECT_FIELD({c}, {}, {}, {})", f.name, f.offset, f.size);
        }
        let _ = writeln!(
            s,
            "EXPECT_TYPE_NAME({c}, USS_{}_TYPE_NAME, \"{}\")",
            screaming(t.name),
            actual_type_name(t.name)
        );
    }
    for (name, value) in numbers() {
        let _ = writeln!(s, "EXPECT_NUMBER(USS_{name}, {value}ull)");
    }
    for (c_name, code) in codes() {
        let _ = writeln!(s, "EXPECT_NUMBER({c_name}, {code}ull)");
    }
    let bus = BusName::new("line-1_A").unwrap();
    let g = Generation(0x0000_1234_abcd_ef01);
    let instance = Instance::new(bus.clone(), g);
    let a = Address::new(7).unwrap();
    for service in services() {
        let (c_name, expected) = (service.c_name, (service.name)(&instance, a));
        let call = match service.scope {
            Scope::Drive => format!(
                "EXPECT_DRIVE_NAME(USS_{c_name}, \"{bus}\", {}ull, {a}u, \"{expected}\")",
                g.0
            ),
            Scope::Instance => format!(
                "EXPECT_INSTANCE_NAME(USS_{c_name}, \"{bus}\", {}ull, \"{expected}\")",
                g.0
            ),
            Scope::Bus => format!("EXPECT_BUS_NAME(USS_{c_name}, \"{bus}\", \"{expected}\")"),
        };
        let _ = writeln!(s, "{call}");
    }
    let _ = writeln!(
        s,
        "EXPECT_STRING(USS_LAYOUT_VERSION_ATTRIBUTE, \"{}\")",
        names::LAYOUT_VERSION_ATTRIBUTE
    );
    s
}

/// The type name the `ZeroCopySend` derive gave a type (not the table's copy of it).
fn actual_type_name(rust: &str) -> &'static str {
    // SAFETY: `type_name` only returns the string the derive was given.
    unsafe {
        match rust {
            "BlackboardKey" => BlackboardKey::type_name(),
            "PzdOutput" => PzdOutput::type_name(),
            "PzdInput" => PzdInput::type_name(),
            "DriveInfo" => DriveInfo::type_name(),
            "DriveCounters" => DriveCounters::type_name(),
            "DriveDiag" => DriveDiag::type_name(),
            "BusStatus" => BusStatus::type_name(),
            "ParamItem" => ParamItem::type_name(),
            "ParamRequest" => ParamRequest::type_name(),
            "ParamResult" => ParamResult::type_name(),
            "ParamResponse" => ParamResponse::type_name(),
            "Heartbeat" => Heartbeat::type_name(),
            "OperatorRequest" => OperatorRequest::type_name(),
            "OperatorResponse" => OperatorResponse::type_name(),
            "TelegramRecord" => TelegramRecord::type_name(),
            other => panic!("{other} is in LAYOUTS but not here"),
        }
    }
}

/// The crate's public numeric constants, by Rust name.
fn numbers() -> Vec<(&'static str, u64)> {
    use uss_shm_types::{control, diag, params, pzd};
    vec![
        ("LAYOUT_VERSION", u64::from(uss_shm_types::LAYOUT_VERSION)),
        ("MAX_PZD_WORDS", pzd::MAX_PZD_WORDS as u64),
        ("EXTRA_PZD_WORDS", pzd::EXTRA_PZD_WORDS as u64),
        ("MAX_PARAM_ITEMS", params::MAX_PARAM_ITEMS as u64),
        ("MAX_SUBINDEX", u64::from(params::MAX_SUBINDEX)),
        ("NO_ITEM", u64::from(params::NO_ITEM)),
        ("NEVER", diag::NEVER),
        ("OUTPUT_RELEASE", u64::from(pzd::OUTPUT_RELEASE)),
        ("OUTPUT_FLAGS", u64::from(pzd::OUTPUT_FLAGS)),
        ("STW1_CONTROL_BY_PLC", u64::from(pzd::STW1_CONTROL_BY_PLC)),
        ("STW1_ON", u64::from(pzd::STW1_ON)),
        ("REQUEST_FORCE", u64::from(params::REQUEST_FORCE)),
        ("REQUEST_UNSAFE", u64::from(params::REQUEST_UNSAFE)),
        ("REQUEST_FLAGS", u64::from(params::REQUEST_FLAGS)),
        ("ALL_DRIVES", u64::from(control::ALL_DRIVES)),
        ("MAX_BUS_NAME_LEN", names::MAX_BUS_NAME_LEN as u64),
        ("MAX_ADDRESS", u64::from(names::MAX_ADDRESS)),
        ("OUT_MAX_PUBLISHERS", names::OUT_MAX_PUBLISHERS as u64),
        ("OUT_LATEST_ONLY", names::OUT_LATEST_ONLY as u64),
        ("OUT_HISTORY", names::OUT_HISTORY as u64),
        ("EVENT_ID_MAX", names::EVENT_ID_MAX as u64),
        ("CYCLE_COMPLETED", names::CYCLE_COMPLETED as u64),
        ("STATUS_PUBLISHED", names::STATUS_PUBLISHED as u64),
        ("USSD_GONE", names::USSD_GONE as u64),
        ("HEARTBEAT_PERIOD_NS", names::HEARTBEAT_PERIOD_NS),
        ("GONE_AFTER_NS", names::GONE_AFTER_NS),
        ("DIAG_AGE_NS", names::DIAG_AGE_NS),
        ("CAPTURE_BYTES", uss_shm_types::CAPTURE_BYTES as u64),
        (
            "CAPTURE_TRUNCATED",
            u64::from(uss_shm_types::CAPTURE_TRUNCATED),
        ),
        ("CAPTURE_TASK", u64::from(uss_shm_types::CAPTURE_TASK)),
        ("CAPTURE_BUFFER", names::CAPTURE_BUFFER as u64),
    ]
}

/// Every code of every code table: C enumerator name, code.
fn codes() -> Vec<(String, u8)> {
    fn table<T: Copy + core::fmt::Debug + Into<u8>>(name: &str, all: &[T]) -> Vec<(String, u8)> {
        all.iter()
            .map(|&v| {
                let variant = screaming(&format!("{v:?}"));
                (format!("USS_{}_{variant}", screaming(name)), v.into())
            })
            .collect()
    }
    [
        table("LastFailure", LastFailure::ALL),
        table("RtMode", RtMode::ALL),
        table("TaskCode", TaskCode::ALL),
        table("Storage", Storage::ALL),
        table("RequestError", RequestError::ALL),
        table("Outcome", Outcome::ALL),
        table("ControlState", ControlState::ALL),
        table("LatchReason", LatchReason::ALL),
        table("Rejection", Rejection::ALL),
        table("StopCommand", StopCommand::ALL),
        table("Monitoring", Monitoring::ALL),
        table("CommandError", CommandError::ALL),
        table("LineState", LineState::ALL),
        table("LineFault", LineFault::ALL),
        table("DriveFamily", DriveFamily::ALL),
        table("BusState", BusState::ALL),
        table("Direction", Direction::ALL),
    ]
    .concat()
}

/// The C compiler: `$CC`, else `cc`; `None` if it does not run.
fn c_compiler(var: &str, default: &str) -> Option<String> {
    let cc = std::env::var(var).unwrap_or_else(|_| default.into());
    let runs = Command::new(&cc)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    runs.then_some(cc)
}

/// Compiles `c-test/layout_check.c` against the header and `checks` with `compiler` (extra
/// `flags` select the language) and runs it: exit success and its output.
fn compile_and_run(compiler: &str, flags: &[&str], checks: &str, dir: &Path) -> (bool, String) {
    std::fs::write(dir.join("layout_expected.h"), checks).unwrap();
    let exe = dir.join("layout_check");
    let out = Command::new(compiler)
        .args(flags)
        .args(["-Wall", "-Wextra", "-Werror", "-pedantic", "-I"])
        .arg(crate_dir().join("include"))
        .arg("-I")
        .arg(dir)
        .arg(crate_dir().join("c-test/layout_check.c"))
        .arg("-o")
        .arg(&exe)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{compiler} {flags:?} failed to compile c-test/layout_check.c:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let run = Command::new(&exe).output().unwrap();
    let text =
        String::from_utf8_lossy(&run.stdout).into_owned() + &String::from_utf8_lossy(&run.stderr);
    (run.status.success(), text)
}

#[test]
fn c_and_cxx_see_the_layouts_codes_and_names_of_the_rust_contract() {
    let Some(cc) = c_compiler("CC", "cc") else {
        eprintln!("SKIPPED: no C compiler (set CC or install cc); the C layout check did not run");
        return;
    };
    let checks = expected_checks(LAYOUTS);
    let (ok, out) = compile_and_run(&cc, &["-std=c11"], &checks, &scratch("c-layout"));
    assert!(ok, "the C view of the contract differs from Rust:\n{out}");
    assert!(out.contains(" 0 failed"), "{out}");
    // The header is for C++ too; C++ also checks the IOX2_TYPE_NAME members.
    let Some(cxx) = c_compiler("CXX", "c++") else {
        eprintln!("SKIPPED the C++ half: no C++ compiler (set CXX or install c++)");
        return;
    };
    let (ok, out) = compile_and_run(
        &cxx,
        &["-x", "c++", "-std=c++17"],
        &checks,
        &scratch("cxx-layout"),
    );
    assert!(ok, "the C++ view of the contract differs from Rust:\n{out}");
}

#[test]
fn c_check_fails_when_an_offset_differs() {
    let Some(cc) = c_compiler("CC", "cc") else {
        eprintln!("SKIPPED: no C compiler (set CC or install cc)");
        return;
    };
    // Claim that ZSW1 sits two bytes later than it does.
    let moved: Vec<TypeLayout> = LAYOUTS
        .iter()
        .map(|t| {
            let fields: Vec<FieldLayout> = t
                .fields
                .iter()
                .map(|f| match (t.name, f.name) {
                    ("PzdInput", "zsw1") => FieldLayout {
                        offset: f.offset + 2,
                        ..*f
                    },
                    _ => *f,
                })
                .collect();
            TypeLayout {
                fields: fields.leak(),
                ..*t
            }
        })
        .collect();
    let (ok, out) = compile_and_run(
        &cc,
        &["-std=c11"],
        &expected_checks(&moved),
        &scratch("c-layout-moved"),
    );
    assert!(!ok, "a moved offset went unnoticed:\n{out}");
    assert!(
        out.contains("UssPzdInput.zsw1: offset 32, expected 34"),
        "{out}"
    );
    assert!(out.contains(" 1 failed"), "{out}");
}
