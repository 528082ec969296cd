//! ussctl's machine interface. Every line `--json` writes is one of the reports below, with
//! `"v"` (the interface's version, [`VERSION`]) first. Each report has a JSON Schema made from
//! its Rust type and shipped in `docs/schema/ussctl/<name>.json`, so a script can check what it
//! reads; a test keeps the shipped files equal to what the types make, and the integration
//! tests check the real output of each command against them. A change of a field (renamed,
//! removed, retyped, its meaning changed) is a new version, said in `docs/schema/CHANGELOG.md`.

use crate::commands::param::DescribeReport;
use crate::commands::trace::Summary;
use crate::decode::CaptureLine;
use crate::report::{
    DiffReport, DriveReport, FaultsReport, ParamReport, QuickReport, ResetReport, RestoreReport,
    SaveReport, ScanReport, StatsReport, StatusReport, StopReport, WatchLine,
};
use schemars::{JsonSchema, Schema};
use serde::Serialize;
use std::fmt::Write as _;

/// The version of the JSON interface: `"v"` of every `--json` line.
pub(crate) const VERSION: u32 = 1;

/// A report as `--json` writes it: `"v"`, then the report's fields.
#[derive(Debug, Serialize)]
pub(crate) struct Versioned<'a, T> {
    pub v: u32,
    #[serde(flatten)]
    pub report: &'a T,
}

/// The schema of a `--json` line of `T`, for `commands`: the type's schema with `"v"`.
fn schema<T: JsonSchema>(commands: &str) -> Schema {
    // What ussctl writes (a field it skips when empty is not required), not what it reads.
    let mut schema = schemars::generate::SchemaSettings::draft2020_12()
        .for_serialize()
        .into_generator()
        .into_root_schema_for::<T>();
    let v = serde_json::json!({
        "description": "The version of ussctl's JSON interface (docs/schema/CHANGELOG.md).",
        "const": VERSION,
    });
    if let Some(o) = schema.as_object_mut() {
        o.insert(
            "description".to_owned(),
            serde_json::Value::String(format!("One line of `{commands}`.")),
        );
        if let Some(serde_json::Value::Object(p)) = o.get_mut("properties") {
            p.insert("v".to_owned(), v);
        }
        match o.get_mut("required") {
            Some(serde_json::Value::Array(r)) => r.insert(0, "v".into()),
            _ => {
                o.insert("required".to_owned(), serde_json::json!(["v"]));
            }
        }
    }
    schema
}

/// Every report `--json` writes: its file name under `docs/schema/ussctl/`, and its schema.
pub(crate) fn schemas() -> Vec<(&'static str, Schema)> {
    vec![
        ("status", schema::<StatusReport>("ussctl --json status")),
        ("stats", schema::<StatsReport>("ussctl --json stats")),
        ("watch", schema::<WatchLine>("ussctl --json watch")),
        (
            "param",
            schema::<ParamReport>("ussctl --json param read / param write"),
        ),
        (
            "describe",
            schema::<DescribeReport>("ussctl --json param describe"),
        ),
        ("faults", schema::<FaultsReport>("ussctl --json faults")),
        ("drive", schema::<DriveReport>("ussctl --json run / ack")),
        (
            "stop",
            schema::<StopReport>("ussctl --json stop / coast / quick-stop"),
        ),
        ("scan", schema::<ScanReport>("ussctl --json scan")),
        ("capture", schema::<CaptureLine>("ussctl --json capture")),
        ("trace", schema::<Summary>("ussctl --json trace")),
        (
            "restore",
            schema::<RestoreReport>("ussctl --json param restore"),
        ),
        ("diff", schema::<DiffReport>("ussctl --json param diff")),
        ("save", schema::<SaveReport>("ussctl --json param save")),
        (
            "reset",
            schema::<ResetReport>("ussctl --json param factory-reset"),
        ),
        (
            "quick",
            schema::<QuickReport>("ussctl --json param quick-commission"),
        ),
    ]
}

/// `ussctl schema [REPORT]`: the schema of one report, or the list of them.
pub(crate) fn print_schema(report: Option<&str>) -> Result<(), crate::Failure> {
    let all = schemas();
    let text = match report {
        None => all.iter().fold(String::new(), |mut text, (name, s)| {
            let what = s
                .get("description")
                .and_then(serde_json::Value::as_str)
                .unwrap_or_default();
            let _ = writeln!(text, "{name:<9} {what}");
            text
        }),
        Some(r) => {
            let (_, schema) = all.iter().find(|(name, _)| *name == r).ok_or_else(|| {
                crate::Failure::NoSchema {
                    report: r.to_owned(),
                    known: all.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", "),
                }
            })?;
            serde_json::to_string_pretty(schema)? + "\n"
        }
    };
    crate::write_out(&text)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The shipped schemas are the ones the types make: a changed field changes a file, which
    /// a reviewer sees (with the version bump and the changelog line it needs).
    #[test]
    fn the_shipped_schemas_are_what_the_report_types_make() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/schema/ussctl");
        let update = std::env::var_os("UPDATE_SCHEMAS").is_some();
        if update {
            std::fs::create_dir_all(&dir).unwrap();
        }
        for (name, schema) in schemas() {
            let made = serde_json::to_string_pretty(&schema).unwrap() + "\n";
            let path = dir.join(format!("{name}.json"));
            if update {
                std::fs::write(&path, &made).unwrap();
                continue;
            }
            let shipped = std::fs::read_to_string(&path).unwrap_or_default();
            assert!(
                shipped == made,
                "{}: not what the report type makes. If a field changed, raise \
                 interface::VERSION, say what changed in docs/schema/CHANGELOG.md and run \
                 `UPDATE_SCHEMAS=1 cargo test -p ussctl interface`",
                path.display()
            );
        }
        let changelog =
            std::fs::read_to_string(dir.join("../CHANGELOG.md")).expect("docs/schema/CHANGELOG.md");
        assert!(
            changelog.contains(&format!("## v{VERSION}")),
            "docs/schema/CHANGELOG.md says nothing of v{VERSION}"
        );
    }

    #[test]
    fn a_line_is_v_then_the_report() {
        #[derive(Serialize)]
        struct R {
            drive: u8,
        }
        let line = serde_json::to_string(&Versioned {
            v: VERSION,
            report: &R { drive: 3 },
        })
        .unwrap();
        assert_eq!(line, format!("{{\"v\":{VERSION},\"drive\":3}}"));
    }
}
