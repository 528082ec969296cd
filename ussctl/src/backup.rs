//! The parameter backup file: a drive's settable parameters as TOML that people can read and
//! diff, and its checks. A file is checked whole before anything is written: a foreign family,
//! an unknown or read-only parameter, a value of the wrong type, size or range is refused with
//! the line and the parameter.
//!
//! ```toml
//! # uss-rt parameter backup (format 1): ...
//! format = 1
//! family = "MICROMASTER 4 / SINAMICS G110"
//! bus = "bus0"
//! drive = 1
//! firmware = 2.09
//! taken = "2026-11-22T18:40:00Z"
//! not_on_drive = ["P0004"]
//!
//! [param]
//! P0003 = 1
//! P1082 = 50.0
//! P2010 = [6, 6]
//! ```

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use uss_client::Value;
use uss_client::uss_catalogue::{Catalogue, DataType, Param, Values as _};
use uss_client::uss_protocol::{ParamRef, Prefix, Subindex};

/// The file format this ussctl writes and reads.
pub const FORMAT: u32 = 1;

/// A backup file as it is read and written.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackupFile {
    pub format: u32,
    /// The catalogue's drive family the values belong to.
    pub family: String,
    /// The drive's configured `family` in ussd (`micromaster4`, `g110`): a restore to a drive
    /// of another family is refused. Absent in backups taken before families existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_family: Option<String>,
    pub bus: String,
    pub drive: u8,
    /// r0018 of the drive the backup was taken from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub firmware: Option<f64>,
    /// When the backup was taken (UTC).
    pub taken: String,
    /// Catalogue parameters this drive does not have (it answered "illegal parameter number").
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub not_on_drive: Vec<String>,
    /// Each settable parameter by its number in the manuals' notation; an array as a list.
    pub param: BTreeMap<String, Saved>,
}

/// One parameter's value, or an array's values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Saved {
    One(Number),
    Many(Vec<Number>),
}

/// A number as TOML writes it: an integer, or a float (float parameters).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Number {
    Int(i64),
    Float(f64),
}

/// One element of a parameter, checked: what to write and how it is shown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Entry {
    /// With the index of an array element.
    pub param: ParamRef,
    pub info: &'static Param,
    pub value: Value,
}

impl Number {
    /// The value as the parameter's own type stores it.
    pub fn of(data_type: DataType, v: Value) -> Self {
        match data_type.decode(v) {
            uss_client::Typed::Float(f) => {
                // The shortest text that reads back as the same f32, as an f64 for TOML.
                Self::Float(format!("{f:?}").parse().unwrap_or(f64::from(f)))
            }
            t => Self::Int(t.as_f64() as i64),
        }
    }

    fn text(self) -> String {
        match self {
            Self::Int(n) => n.to_string(),
            // A whole float (5.0) is also a valid integer value; -0.0 keeps its sign.
            Self::Float(f)
                if f.fract() == 0.0 && f.abs() < 1e15 && !(f == 0.0 && f.is_sign_negative()) =>
            {
                format!("{}", f as i64)
            }
            Self::Float(f) => format!("{f:?}"),
        }
    }
}

/// The checks of a file failed: where and why.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{origin}{}: {message}", .line.map(|l| format!(":{l}")).unwrap_or_default())]
pub struct FileError {
    pub origin: String,
    pub line: Option<usize>,
    pub message: String,
}

impl BackupFile {
    /// Reads and checks a backup file; `origin` names it in errors. Returns the file and every
    /// element it sets, in catalogue order.
    pub fn parse(
        text: &str,
        origin: &str,
        catalogue: &'static Catalogue,
    ) -> Result<(Self, Vec<Entry>), FileError> {
        let fail = |line: Option<usize>, message: String| FileError {
            origin: origin.to_owned(),
            line,
            message,
        };
        let file: Self = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            fail(line, e.message().trim_end().to_owned())
        })?;
        if file.format != FORMAT {
            return Err(fail(
                line_of(text, "format"),
                format!(
                    "format = {}: this ussctl reads format {FORMAT} backups",
                    file.format
                ),
            ));
        }
        if file.family != catalogue.family {
            return Err(fail(
                line_of(text, "family"),
                format!(
                    "the backup is of a {} drive; this catalogue is {}: values of another family are neither restored nor compared",
                    file.family, catalogue.family
                ),
            ));
        }
        let mut entries = Vec::new();
        for (key, saved) in &file.param {
            let at = line_of(text, key);
            let param: ParamRef = key.parse().map_err(|e| fail(at, format!("{key}: {e}")))?;
            let info = catalogue.param(param.pnu.get()).ok_or_else(|| {
                fail(
                    at,
                    format!("{key}: not a parameter of {}", catalogue.family),
                )
            })?;
            if !info.is_writable() || info.action || param.index.is_some() {
                let why = if param.index.is_some() {
                    "write an array as a list, e.g. P2010 = [6, 6]"
                } else if info.action {
                    "a command (it starts something when written), not a setting: not restored"
                } else {
                    "a read-only (r) parameter is not restored"
                };
                return Err(fail(at, format!("{key}: {why}")));
            }
            let values = match saved {
                Saved::One(n) if info.array == 0 => vec![*n],
                Saved::Many(list) if info.array > 0 && list.len() == usize::from(info.array) => {
                    list.clone()
                }
                _ => {
                    let wanted = if info.array == 0 {
                        "one value".to_owned()
                    } else {
                        format!("a list of {} values", info.array)
                    };
                    return Err(fail(at, format!("{key}: {} takes {wanted}", info.id)));
                }
            };
            for (i, n) in values.into_iter().enumerate() {
                let value = info
                    .data_type
                    .parse(&n.text())
                    .map_err(|e| fail(at, format!("{key}: {e}")))?;
                if !info.within_limits(value) {
                    return Err(fail(
                        at,
                        format!(
                            "{key}: {} is outside the drive's limits {}..={}",
                            n.text(),
                            info.min.unwrap_or(f64::NAN),
                            info.max.unwrap_or(f64::NAN)
                        ),
                    ));
                }
                let param = ParamRef {
                    prefix: Prefix::P,
                    ..info.id
                };
                let param = if info.array > 0 {
                    let index = u8::try_from(i)
                        .ok()
                        .and_then(|i| Subindex::new(i).ok())
                        .ok_or_else(|| fail(at, format!("{key}: too many elements")))?;
                    param.at(index)
                } else {
                    param
                };
                entries.push(Entry { param, info, value });
            }
        }
        entries.sort_by_key(|e| (e.param.pnu, e.param.index));
        Ok((file, entries))
    }

    /// The file as TOML, with a header that says what it is.
    pub fn to_text(&self) -> String {
        let body = toml::to_string(self).unwrap_or_default();
        format!(
            "# uss-rt parameter backup (format {FORMAT}): the settable parameters of drive {} on bus \
             {}.\n# Restore: ussctl param restore DRIVE FILE; compare: ussctl param diff DRIVE FILE.\n{body}",
            self.drive, self.bus
        )
    }
}

/// The line of the first `key = ` in `text`.
fn line_of(text: &str, key: &str) -> Option<usize> {
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            l.strip_prefix(key)
                .or_else(|| l.strip_prefix(&format!("\"{key}\"")))
                .is_some_and(|rest| rest.trim_start().starts_with('='))
        })
        .map(|i| i + 1)
}

/// Today's date and time in UTC, RFC 3339 (`2026-11-22T18:40:00Z`).
pub fn now_utc() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let (days, rem) = (secs / 86_400, secs % 86_400);
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn file(param: BTreeMap<String, Saved>) -> BackupFile {
        BackupFile {
            format: FORMAT,
            family: Catalogue::micromaster4().family.clone(),
            drive_family: None,
            bus: "b".into(),
            drive: 3,
            firmware: Some(2.09),
            taken: now_utc(),
            not_on_drive: vec!["P0004".into()],
            param,
        }
    }

    #[test]
    fn a_written_file_reads_back_with_every_value_checked() {
        let mut param = BTreeMap::new();
        param.insert("P1082".into(), Saved::One(Number::Float(45.5)));
        param.insert("P0700".into(), Saved::One(Number::Int(5)));
        param.insert(
            "P2010".into(),
            Saved::Many(vec![Number::Int(6), Number::Int(7)]),
        );
        let text = file(param).to_text();
        assert!(
            text.starts_with("# uss-rt parameter backup (format 1)"),
            "{text}"
        );
        let (back, entries) = BackupFile::parse(&text, "f", Catalogue::micromaster4()).unwrap();
        assert_eq!((back.drive, back.not_on_drive.len()), (3, 1));
        let shown: Vec<String> = entries.iter().map(|e| e.param.to_string()).collect();
        assert_eq!(shown, ["P0700", "P1082", "P2010[0]", "P2010[1]"]);
        assert_eq!(entries[1].value, Value::from_f32(45.5));
        let taken = now_utc();
        assert_eq!((taken.len(), &taken[10..11], &taken[19..]), (20, "T", "Z"));
    }

    proptest! {
        #[test]
        fn any_text_is_read_or_refused_with_a_reason(text in "(?s).{0,200}") {
            if let Err(e) = BackupFile::parse(&text, "f", Catalogue::micromaster4()) {
                prop_assert!(!e.message.is_empty());
            }
        }

        #[test]
        fn any_float_setting_round_trips(f in prop_oneof![Just(-0.0f32), 0.0f32..650.0]) {
            let mut param = BTreeMap::new();
            param.insert("P1082".into(), Saved::One(Number::of(DataType::Float, Value::from_f32(f))));
            let text = file(param).to_text();
            let (_, entries) = BackupFile::parse(&text, "f", Catalogue::micromaster4()).unwrap();
            prop_assert_eq!(entries[0].value, Value::from_f32(f));
        }
    }
}
