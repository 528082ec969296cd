//! The C ABI's status codes (`capi/src/status.rs`) and Python's exception classes
//! (`python/uss_rt/_errors.py`) are exactly what the one code table (`clients/src/kinds.rs`)
//! makes of them: a kind or status added, renamed or described in one place only fails here.
//!
//! After changing the table, regenerate both with
//! `UPDATE_GENERATED=1 cargo test -p uss-client --test generated`.
#![allow(clippy::unwrap_used)]

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use uss_client::kinds::{ErrorKind, Status};

const REGENERATE: &str = "UPDATE_GENERATED=1 cargo test -p uss-client --test generated";

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn doc_lines(doc: &[&str]) -> Vec<String> {
    doc.iter().map(|l| l.trim().to_owned()).collect()
}

fn c_status() -> String {
    let mut s = format!(
        "//! The C ABI's status codes, generated from the one code table\n\
         //! (`uss_client::kinds::Status`) by `{REGENERATE}`: do not edit.\n\n\
         use core::ffi::CStr;\n\
         use uss_client::kinds::Status;\n\n\
         /// What a call came to. `USSRT_STATUS_OK` is 0; every other code has a message\n\
         /// (`ussrt_last_error`).\n\
         #[repr(C)]\n\
         #[derive(Debug, Clone, Copy, PartialEq, Eq)]\n\
         pub enum UssrtStatus {{\n"
    );
    for status in Status::ALL {
        for line in doc_lines(status.doc()) {
            let _ = writeln!(s, "    /// {line}");
        }
        let _ = writeln!(s, "    {} = {},", status.name(), status.code());
    }
    s.push_str("}\n\nimpl UssrtStatus {\n    /// Every status, in code order.\n");
    let _ = writeln!(
        s,
        "    pub(crate) const ALL: [Self; {}] = [",
        Status::ALL.len()
    );
    for status in Status::ALL {
        let _ = writeln!(s, "        Self::{},", status.name());
    }
    s.push_str(
        "    ];\n\n    /// The code of the table's `status`.\n    \
         pub(crate) const fn of(status: Status) -> Self {\n        match status {\n",
    );
    for status in Status::ALL {
        let _ = writeln!(s, "            Status::{0} => Self::{0},", status.name());
    }
    s.push_str(
        "        }\n    }\n\n    /// Its name in snake case, for logs: the same word as the table's.\n    \
         pub(crate) const fn name(self) -> &'static CStr {\n        match self {\n",
    );
    for status in Status::ALL {
        let _ = writeln!(
            s,
            "            Self::{} => c\"{}\",",
            status.name(),
            status.snake()
        );
    }
    s.push_str("        }\n    }\n}\n");
    s
}

fn python_errors() -> String {
    let mut s = format!(
        "\"\"\"The exceptions of uss_rt, generated from the Rust client's code table\n\
         (clients/src/kinds.rs) by `{REGENERATE}`: do not edit.\n\n\
         Every message is the Rust client's own text; what it is about is in attributes.\n\"\"\"\n\n\n\
         class UssError(Exception):\n    \
         \"\"\"Anything this module reports; the message says what to do.\"\"\"\n\n    \
         def __init__(self, message: str = \"\", **details):\n        \
         super().__init__(message)\n        \
         self.__dict__.update(details)\n"
    );
    let mut names = vec!["UssError"];
    for kind in ErrorKind::ALL {
        let class = kind.python_class();
        if class.is_empty() || class == "ValueError" || names.contains(&class) {
            continue;
        }
        names.push(class);
        let doc = doc_lines(kind.doc()).join("\n    ");
        let _ = write!(
            s,
            "\n\nclass {class}({}):\n    \"\"\"{doc}\"\"\"\n",
            kind.python_base()
        );
    }
    s.push_str("\n\n__all__ = [\n");
    for name in names {
        let _ = writeln!(s, "    \"{name}\",");
    }
    s.push_str("]\n");
    s
}

fn check(relative: &str, made: &str) {
    let path = workspace().join(relative);
    if std::env::var_os("UPDATE_GENERATED").is_some() {
        std::fs::write(&path, made).unwrap();
    }
    let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        on_disk == made,
        "{relative} is not what the code table (clients/src/kinds.rs) makes: regenerate it with {REGENERATE}"
    );
}

#[test]
fn the_c_status_codes_are_the_code_tables() {
    check("capi/src/status.rs", &c_status());
}

#[test]
fn the_python_exceptions_are_the_code_tables() {
    check("python/uss_rt/_errors.py", &python_errors());
}
