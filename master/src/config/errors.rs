//! Errors that name the file, line, column, table, key and what is allowed. serde's errors
//! carry a byte span and, read through `serde_path_to_error`, the key's path; the bus and
//! drive are named from the file's tables, parsed with spans ([`toml::de::DeTable`]).

use super::allowed::{BUS_NAMES, DEVICES, valid_bus_name};
use core::ops::Range;
use serde_path_to_error::Segment;
use toml::Spanned;
use toml::de::{DeTable, DeValue};

/// Why a configuration was refused: where, which key, and what is allowed.
#[derive(Debug, thiserror::Error)]
#[error("{origin}{}: {message}", line.zip(*column).map(|(l, c)| format!(":{l}:{c}")).unwrap_or_default())]
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
        let message = format!("cannot read the configuration: {e}");
        Reporter::new("", origin).error(None, None, message)
    }
}

/// A broken rule: where (byte span; `None`: nowhere in the text), which key of which table, and
/// what is wrong and allowed.
#[derive(Debug)]
pub struct Broken {
    pub span: Option<Range<usize>>,
    /// The table: `[("bus", 0), ("drive", 2)]`, or empty for the file.
    pub at: Vec<(&'static str, usize)>,
    pub key: &'static str,
    pub text: String,
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

/// A table of the file: the array it is in (`bus`, `drive`) and its index.
pub type At<'a> = [(&'a str, usize)];

/// Builds errors for one file.
pub struct Reporter<'t> {
    pub text: &'t str,
    origin: &'t str,
    /// The file's tables with spans; `None` when it is not valid TOML.
    pub root: Option<DeTable<'t>>,
}

impl<'t> Reporter<'t> {
    pub fn new(text: &'t str, origin: &'t str) -> Self {
        Reporter {
            text,
            origin,
            root: None,
        }
    }

    pub fn syntax(&self, e: &toml::de::Error) -> ConfigError {
        let message = format!("invalid TOML: {}", e.message().trim_end());
        self.error(e.span(), None, message)
    }

    fn error(
        &self,
        span: Option<Range<usize>>,
        path: Option<String>,
        message: String,
    ) -> ConfigError {
        let (line, column) = span.map(|s| position(self.text, s.start)).unzip();
        ConfigError {
            origin: self.origin.to_owned(),
            line,
            column,
            path,
            message,
        }
    }

    /// The first line of what the file writes at `span`.
    pub fn written(&self, span: Option<&Range<usize>>) -> &str {
        let written = span
            .and_then(|s| self.text.get(s.clone()))
            .unwrap_or_default();
        written.lines().next().unwrap_or_default().trim()
    }

    /// A value serde refused (wrong type, out of range, unknown or missing key), in our words.
    pub fn serde(&self, e: &serde_path_to_error::Error<toml::de::Error>) -> ConfigError {
        let (mut at, mut keys) = tables_and_keys(e.path());
        let span = e.inner().span();
        let message = e.inner().message().trim_end();
        let missing = message.strip_prefix("missing field `");
        let mut path = e.path().to_string();
        // toml gives serde a date-time as a table of one private key.
        let datetime = keys.last() == Some(&"$__toml_private_datetime");
        if datetime {
            keys.pop();
            path.truncate(path.rfind('.').unwrap_or_default());
        }
        if let Some(key) = missing {
            keys.push(key.trim_end_matches('`'));
            path = format!("{path}.{}", key.trim_end_matches('`'));
        } else if keys.is_empty()
            && let Some((array, _)) = at.pop()
        {
            // An item of `drive = [...]` that is not a table: the array is wrong.
            keys.push(array);
            path.truncate(path.rfind('[').unwrap_or(path.len()));
        }
        let key = keys.last().copied().unwrap_or_default();
        // The key's value as written; serde's span may be inside it (a table, an array). A table
        // written as a [header] or by dotted keys has no text of its own: then serde's place.
        let value = self
            .value(&at, &keys)
            .map(|v| (self.written(Some(&v.span())), v.get_ref()));
        let written = match value {
            Some((w, v)) if w.starts_with('{') || !matches!(v, DeValue::Table(_)) => w,
            _ => self.written(span.as_ref()),
        };
        let text = if datetime {
            format!("{key} = {written}: a date-time where a table belongs")
        } else if let Some(rest) = message.strip_prefix("unknown field `") {
            // After the key (which may hold a backtick itself).
            let expected = rest
                .strip_prefix(key)
                .map_or(rest, |r| r.trim_start_matches('`'));
            let known = expected
                .trim_start_matches(", expected one of ")
                .trim_start_matches(", expected ")
                .replace('`', "");
            let table = match (keys.len(), at.len()) {
                (2.., _) => "a [bus.drive.sim] table",
                (_, 0) => "the file",
                (_, 1) => "a [[bus]] table",
                _ => "a [[bus.drive]] table",
            };
            format!("unknown key `{key}`: {table} takes {known}")
        } else if missing.is_some() {
            match required(key) {
                "" => format!("{key} is missing"),
                allowed => format!("{key} is missing: {allowed}"),
            }
        } else if let Some(rest) = message.strip_prefix("invalid type: ") {
            let (found, expected) = rest.split_once(", expected ").unwrap_or((rest, "?"));
            let expected = match expected {
                e if e == "a sequence"
                    || e.starts_with("struct BusConfig")
                    || e.starts_with("struct DriveEntry") =>
                {
                    tables(if key == "bus" { "bus" } else { "drive" }).to_owned()
                }
                "a boolean" => "a boolean: write true or false".to_owned(),
                "f64" => "a number".to_owned(),
                "u8" | "u16" | "u32" | "u64" | "i64" => "an integer".to_owned(),
                "a string" if !required(key).is_empty() => format!("a string: {}", required(key)),
                e if e.starts_with("struct SimOptions") => tables("sim").to_owned(),
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
        self.error(span, Some(path), self.label(&at, text))
    }

    /// A broken rule, in our words.
    pub fn rule(&self, b: &Broken) -> ConfigError {
        let mut path: Vec<String> = b.at.iter().map(|(t, i)| format!("{t}[{i}]")).collect();
        path.push(b.key.to_owned());
        let text = self.label(&b.at, b.text.clone());
        self.error(b.span.clone(), Some(path.join(".")), text)
    }

    /// serde would read a table written as an array (`drive = [[3]]`) field by field and leave
    /// extra items unread: refused before serde sees the file.
    pub fn arrays_for_tables(&self) -> Result<(), ConfigError> {
        let Some(root) = &self.root else {
            return Ok(());
        };
        let fail = |at: &At<'static>, key: &'static str, item: &Spanned<DeValue<'_>>| {
            let written = self.written(self.span(at, Some(key)).as_ref());
            let text = format!("{key} = {written} is not {}", tables(key));
            let (span, at) = (Some(item.span()), at.to_vec());
            Err(self.rule(&Broken {
                span,
                at,
                key,
                text,
            }))
        };
        for (b, bus) in items(root, "bus").iter().enumerate() {
            let DeValue::Table(bus_table) = bus.get_ref() else {
                if matches!(bus.get_ref(), DeValue::Array(_)) {
                    return fail(&[], "bus", bus);
                }
                continue;
            };
            for (d, drive) in items(bus_table, "drive").iter().enumerate() {
                match drive.get_ref() {
                    DeValue::Array(_) => return fail(&[("bus", b)], "drive", drive),
                    DeValue::Table(t) => {
                        if let Some(sim) = t.get("sim")
                            && let DeValue::Array(_) = sim.get_ref()
                        {
                            return fail(&[("bus", b), ("drive", d)], "sim", sim);
                        }
                    }
                    _ => {}
                }
            }
        }
        Ok(())
    }

    /// The table at `at` (`[("bus", 0), ("drive", 2)]`) with its span, if the file has it.
    fn table(&self, at: &At<'_>) -> Option<(&DeTable<'t>, Option<Range<usize>>)> {
        let mut table = (self.root.as_ref()?, None);
        for &(array, i) in at {
            let DeValue::Array(items) = table.0.get(array)?.get_ref() else {
                return None;
            };
            let item = items.get(i)?;
            let DeValue::Table(inner) = item.get_ref() else {
                return None;
            };
            table = (inner, Some(item.span()));
        }
        Some(table)
    }

    /// The value of `keys` (`["sim", "delay"]`) in the table at `at`, if the file writes it.
    fn value(&self, at: &At<'_>, keys: &[&str]) -> Option<&Spanned<DeValue<'t>>> {
        let (mut table, _) = self.table(at)?;
        let (last, inner) = keys.split_last()?;
        for key in inner {
            let DeValue::Table(t) = table.get(*key)?.get_ref() else {
                return None;
            };
            table = t;
        }
        table.get(*last)
    }

    /// Where the table at `at` writes `key`'s value, or where the table is when it does not
    /// write `key` (or no key is asked for).
    pub fn span(&self, at: &At<'_>, key: Option<&str>) -> Option<Range<usize>> {
        key.and_then(|k| self.value(at, &[k]))
            .map(Spanned::span)
            .or_else(|| self.table(at)?.1)
    }

    /// `text` after the bus and drive it is about: `bus "line1" drive 3: `, or by index when the
    /// name or address is not usable.
    fn label(&self, at: &At<'_>, text: String) -> String {
        let mut label = Vec::new();
        for (n, &(key, index)) in at.iter().enumerate() {
            let value = |k| Some(self.table(&at[..=n])?.0.get(k)?.get_ref());
            let own = match (key, value(if key == "bus" { "name" } else { "address" })) {
                ("bus", Some(DeValue::String(name))) => Some(name.as_ref())
                    .filter(|n| valid_bus_name(n))
                    .map(|n| format!("bus {n:?}")),
                ("drive", Some(DeValue::Integer(i))) => i64::from_str_radix(i.as_str(), i.radix())
                    .ok()
                    .filter(|a| (0..=31).contains(a))
                    .map(|a| format!("drive {a}")),
                _ => None,
            };
            label.push(own.unwrap_or_else(|| format!("{key}[{index}]")));
        }
        if label.is_empty() {
            text
        } else {
            format!("{}: {text}", label.join(" "))
        }
    }
}

/// The tables of a path (`bus[0]`, `drive[2]`) and the keys below them (`sim`, `delay`).
fn tables_and_keys(path: &serde_path_to_error::Path) -> (Vec<(&str, usize)>, Vec<&str>) {
    let (mut at, mut keys) = (Vec::new(), Vec::new());
    let mut segments = path.iter().peekable();
    while let Some(segment) = segments.next() {
        if let Segment::Map { key } = segment {
            match segments.peek() {
                Some(Segment::Seq { index }) if ["bus", "drive"].contains(&key.as_str()) => {
                    at.push((key.as_str(), *index));
                    segments.next();
                }
                _ => keys.push(key.as_str()),
            }
        }
    }
    (at, keys)
}

/// The items of array `key` of `table` (none when it is not an array).
fn items<'a, 't>(table: &'a DeTable<'t>, key: &str) -> &'a [Spanned<DeValue<'t>>] {
    match table.get(key).map(Spanned::get_ref) {
        Some(DeValue::Array(items)) => items,
        _ => &[],
    }
}

/// What `bus`, `drive` or `sim` is.
fn tables(key: &str) -> &'static str {
    match key {
        "bus" => "[[bus]] tables: write a [[bus]] table for each",
        "drive" => "[[bus.drive]] tables: write a [[bus.drive]] table for each",
        _ => "a table of uss-sim's drive keys, e.g. sim = { delay = 1, drop = 0.01 }",
    }
}

/// What a required key allows.
fn required(key: &str) -> &'static str {
    match key {
        "name" => BUS_NAMES,
        "device" => DEVICES,
        "address" => "USS addresses are 0..=31",
        _ => "",
    }
}
