//! Errors that name the file, line, column, table, key and what is allowed: the parser's and
//! serde's errors carry a byte span, and the span is found again in the file's tables (parsed
//! with spans, [`toml::de::DeTable`]) to name the bus, the drive and the key.

use super::rules::{Broken, Kind};
use core::fmt;
use core::ops::Range;
use toml::Spanned;
use toml::de::{DeTable, DeValue};

/// Why a configuration was refused: where, which key, and what is allowed.
#[derive(Debug, thiserror::Error)]
#[error("{origin}{}: {message}", Position(*.line, *.column))]
pub struct ConfigError {
    /// The file name (or whatever [`super::Config::parse`] was given).
    pub origin: String,
    /// 1-based line; `None` when the error has no place in the text (unreadable file, no bus).
    pub line: Option<usize>,
    /// 1-based column in characters; `None` together with `line`.
    pub column: Option<usize>,
    /// The key the error is about, e.g. `bus[0].drive[2].pzd`; `None` for TOML syntax and I/O
    /// errors.
    pub path: Option<String>,
    /// What is wrong and what is allowed, with the bus and drive it concerns.
    pub message: String,
}

impl ConfigError {
    /// A file that cannot be read: an error without a line.
    pub fn unreadable(origin: &str, e: &std::io::Error) -> Self {
        ConfigError {
            origin: origin.to_owned(),
            line: None,
            column: None,
            path: None,
            message: format!("cannot read the configuration: {e}"),
        }
    }
}

/// `:line:column`, or nothing.
struct Position(Option<usize>, Option<usize>);

impl fmt::Display for Position {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Position(Some(line), Some(column)) => write!(f, ":{line}:{column}"),
            Position(Some(line), None) => write!(f, ":{line}"),
            Position(None, _) => Ok(()),
        }
    }
}

/// 1-based line and character column of a byte offset.
pub fn position(text: &str, offset: usize) -> (usize, usize) {
    let mut offset = offset.min(text.len());
    while !text.is_char_boundary(offset) {
        offset -= 1;
    }
    let before = &text[..offset];
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    (
        before.matches('\n').count() + 1,
        before[line_start..].chars().count() + 1,
    )
}

/// Builds errors for one file.
pub struct Reporter<'t> {
    pub text: &'t str,
    pub origin: &'t str,
    /// The file's tables with spans; `None` when it is not valid TOML.
    pub root: Option<DeTable<'t>>,
}

/// Where a span is in the file's tables.
#[derive(Debug, Default)]
struct Place {
    /// `bus[0].drive[1]`; empty for the file itself.
    table: String,
    /// `bus "line1" drive 3`; empty for the file itself.
    label: String,
    /// What takes the keys: "the file", "a [[bus]] table", ...
    kind: &'static str,
    /// The key whose key or value holds the span, with its value as written.
    key: Option<(String, String)>,
}

impl Reporter<'_> {
    pub fn syntax(&self, e: &toml::de::Error) -> ConfigError {
        let (line, column) = e.span().map(|s| position(self.text, s.start)).unzip();
        ConfigError {
            origin: self.origin.to_owned(),
            line,
            column,
            path: None,
            message: format!("invalid TOML: {}", e.message().trim_end()),
        }
    }

    fn error(&self, span: Option<&Range<usize>>, path: String, message: String) -> ConfigError {
        let (line, column) = span.map(|s| position(self.text, s.start)).unzip();
        ConfigError {
            origin: self.origin.to_owned(),
            line,
            column,
            path: Some(path),
            message,
        }
    }

    /// A value serde refused (wrong type, out of range, unknown or missing key), in our words.
    pub fn serde(&self, e: &toml::de::Error) -> ConfigError {
        let span = e.span();
        let place = span
            .as_ref()
            .map(|s| self.place(s.start))
            .unwrap_or_default();
        let message = e.message().trim_end();
        let label = |text: String| {
            if place.label.is_empty() {
                text
            } else {
                format!("{}: {text}", place.label)
            }
        };
        let join = |key: &str| {
            if place.table.is_empty() {
                key.to_owned()
            } else {
                format!("{}.{key}", place.table)
            }
        };
        if let Some(rest) = message.strip_prefix("unknown field `") {
            let (key, expected) = rest.split_once('`').unwrap_or((rest, ""));
            let known = expected
                .trim_start_matches(", expected one of ")
                .trim_start_matches(", expected ")
                .replace('`', "");
            let text = format!("unknown key `{key}`: {} takes {known}", place.kind);
            return self.error(span.as_ref(), join(key), label(text));
        }
        if let Some(rest) = message.strip_prefix("missing field `") {
            let key = rest.trim_end_matches('`');
            let text = match required(key) {
                "" => format!("{key} is missing"),
                allowed => format!("{key} is missing: {allowed}"),
            };
            return self.error(span.as_ref(), join(key), label(text));
        }
        let (key, written) = place.key.clone().unwrap_or_default();
        let text = if let Some(rest) = message.strip_prefix("invalid type: ") {
            let (found, expected) = rest.split_once(", expected ").unwrap_or((rest, "?"));
            let expected = match expected {
                "a sequence" => {
                    let header = if key == "bus" {
                        "[[bus]]"
                    } else {
                        "[[bus.drive]]"
                    };
                    format!("{header} tables: write a {header} table for each")
                }
                "a boolean" => "a boolean: write true or false".to_owned(),
                "f64" => "a number".to_owned(),
                "u8" | "u16" | "u32" | "u64" | "i64" => "an integer".to_owned(),
                "a string" if !required(&key).is_empty() => format!("a string: {}", required(&key)),
                e if e.starts_with("struct SimOptions") => {
                    "a table of uss-sim's drive keys, e.g. sim = { delay = 1, drop = 0.01 }"
                        .to_owned()
                }
                other => other.to_owned(),
            };
            if found.starts_with("map") {
                format!("{key} is a table, not {expected}")
            } else if found.starts_with("sequence") {
                format!("{key} is an array, not {expected}")
            } else {
                format!("{key} = {written} is not {expected}")
            }
        } else if let Some(rest) = message.strip_prefix("unknown variant `") {
            let expected = rest.split_once(", expected ").map_or("", |(_, e)| e);
            let expected = expected.trim_start_matches("one of ").replace('`', "\"");
            format!("{key} = {written} is not allowed: use {expected}")
        } else if message.starts_with("is ") {
            format!("{key} = {written} {message}")
        } else {
            format!("{key} = {written}: {message}")
        };
        self.error(span.as_ref(), join(&key), label(text))
    }

    /// A broken rule, in our words.
    pub fn rule(&self, b: &Broken) -> ConfigError {
        let path = if b.table.is_empty() {
            b.key.to_owned()
        } else {
            format!("{}.{}", b.table, b.key)
        };
        let place = b
            .span
            .as_ref()
            .map(|s| self.place(s.start))
            .unwrap_or_default();
        let written = b
            .span
            .as_ref()
            .and_then(|s| self.text.get(s.clone()))
            .map(|w| w.lines().next().unwrap_or_default().trim().to_owned())
            .unwrap_or_default();
        let text = match b.kind {
            Kind::Value => format!("{} = {written} {}", b.key, b.problem),
            Kind::Whole => b.problem.clone(),
        };
        let message = if place.label.is_empty() {
            text
        } else {
            format!("{}: {text}", place.label)
        };
        self.error(b.span.as_ref(), path, message)
    }

    /// Where the table at `path` (`[("bus", 0), ("drive", 2)]`) writes `key`'s value, or where
    /// the table is when it does not write `key` (or no key is asked for).
    pub fn span(&self, path: &[(&str, usize)], key: Option<&str>) -> Option<Range<usize>> {
        let mut table = self.root.as_ref()?;
        let mut span = None;
        for &(array, i) in path {
            let DeValue::Array(items) = table.get(array)?.get_ref() else {
                return None;
            };
            let item = items.get(i)?;
            let DeValue::Table(inner) = item.get_ref() else {
                return None;
            };
            span = Some(item.span());
            table = inner;
        }
        key.and_then(|k| table.get(k)).map(Spanned::span).or(span)
    }

    /// The innermost table around `offset` and the key there.
    fn place(&self, offset: usize) -> Place {
        let mut place = Place {
            kind: "the file",
            ..Place::default()
        };
        let Some(root) = &self.root else {
            return place;
        };
        let mut table = root;
        let mut key_at = find_key(self.text, table, offset);
        for (key, header, kind) in [
            ("bus", "bus", "a [[bus]] table"),
            ("drive", "drive", "a [[bus.drive]] table"),
        ] {
            let Some((i, inner)) = array_table_at(table, key, offset) else {
                break;
            };
            let index = if place.table.is_empty() {
                format!("{header}[{i}]")
            } else {
                format!("{}.{header}[{i}]", place.table)
            };
            place.label = label(&place.label, key, i, inner);
            place.table = index;
            place.kind = kind;
            table = inner;
            key_at = find_key(self.text, table, offset);
        }
        // The drive's `sim` table: inline, dotted keys, or a `[bus.drive.sim]` header (whose
        // span is the header alone, so its keys are looked up whenever the offset is past it).
        if let Some(sim_value) = table.get("sim")
            && let DeValue::Table(sim) = sim_value.get_ref()
            && sim_value.span().start <= offset
            && let Some(inner) = find_key(self.text, sim, offset)
        {
            place.table = format!("{}.sim", place.table);
            place.kind = "a [bus.drive.sim] table";
            key_at = Some(inner);
        }
        place.key = key_at;
        place
    }
}

/// The table of array `key` in `table` whose span holds `offset`, with its index.
fn array_table_at<'a, 't>(
    table: &'a DeTable<'t>,
    key: &str,
    offset: usize,
) -> Option<(usize, &'a DeTable<'t>)> {
    let DeValue::Array(items) = table.get(key)?.get_ref() else {
        return None;
    };
    // Header tables have the span of their header: the last one starting at or before offset.
    items
        .iter()
        .enumerate()
        .rev()
        .find(|(_, item)| item.span().start <= offset)
        .and_then(|(i, item)| match item.get_ref() {
            DeValue::Table(t) => Some((i, t)),
            _ => None,
        })
}

/// The key of `table` whose key or value holds `offset`, and its value as written.
fn find_key(text: &str, table: &DeTable<'_>, offset: usize) -> Option<(String, String)> {
    table.iter().find_map(|(key, value)| {
        let holds = |s: Range<usize>| s.start <= offset && offset < s.end.max(s.start + 1);
        (holds(key.span()) || holds(value.span())).then(|| {
            let written = text.get(value.span()).unwrap_or_default();
            let first = written.lines().next().unwrap_or_default().trim();
            (key.get_ref().to_string(), first.to_owned())
        })
    })
}

/// `bus "line1"` / `bus "line1" drive 3`, or by index when the name or address is not usable.
fn label(outer: &str, key: &str, index: usize, table: &DeTable<'_>) -> String {
    let value = |k: &str| table.get(k).map(Spanned::get_ref);
    let own = match (key, value(if key == "bus" { "name" } else { "address" })) {
        ("bus", Some(DeValue::String(name))) if super::rules::valid_bus_name(name) => {
            format!("bus {name:?}")
        }
        ("drive", Some(DeValue::Integer(i)))
            if i64::from_str_radix(i.as_str(), i.radix()).is_ok_and(|a| (0..=31).contains(&a)) =>
        {
            let a = i64::from_str_radix(i.as_str(), i.radix()).unwrap_or_default();
            format!("drive {a}")
        }
        _ => format!("{key}[{index}]"),
    };
    if outer.is_empty() {
        own
    } else {
        format!("{outer} {own}")
    }
}

/// What a required key allows.
fn required(key: &str) -> &'static str {
    match key {
        "name" => {
            "a bus name is 1..=32 characters from A-Z, a-z, 0-9, _ and - (it becomes part of \
             shared-memory service names)"
        }
        "device" => "device is \"sim\" (the built-in simulated bus) or the path of a serial device",
        "address" => "USS addresses are 0..=31",
        _ => "",
    }
}
