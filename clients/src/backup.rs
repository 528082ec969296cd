//! A drive's settings as STARTER uploads them (issue 46), in the client library so that every
//! front-end takes and compares them the same way: [`Bus::upload`] reads every setting of the
//! drive's family catalogue with every element the drive says it has (data sets included:
//! descriptive element 2, AK 4) and its firmware; [`Bus::diff_file`] and [`Bus::diff_drives`]
//! compare. The file is TOML that people can read and diff, checked whole before anything is
//! written: a foreign family, an unknown or read-only parameter, a value of the wrong type,
//! size or range is refused with the line and the parameter. The drive's state (its
//! commissioning parameter P0010, its parameter filter P0004) is not a setting: never saved,
//! and ignored (named) where an older file holds it.
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
//! P1082 = [50.0, 50.0, 50.0]
//! P2010 = [6, 6]
//! ```

use crate::{Bus, DriveError, ParamError};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use uss_catalogue::{Catalogue, DataType, Param, Values as _};
use uss_protocol::{ErrorNumber, ParamRef, ParamTask, Pnu, Prefix, Subindex, Value};
use uss_shm_types::{Address, DriveFamily};

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
    /// r0018 of the drive the backup was taken from: MICROMASTER 4's as a float (2.09), a
    /// G120's as its number (4070000). A restore to a drive of other firmware is refused
    /// unless asked for ([`BackupFile::check_firmware`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub firmware: Option<Number>,
    /// When the backup was taken (UTC).
    pub taken: String,
    /// Catalogue parameters this drive does not have (it answered "illegal parameter number").
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub not_on_drive: Vec<String>,
    /// Each settable parameter by its number in the manuals' notation; an array as a list.
    pub param: BTreeMap<String, Saved>,
    /// Settable parameters the family's catalogue does not list, found on the drive and saved
    /// as it described them (AK 4: type and elements; [`UploadOptions::discover`]). What is
    /// under `param` is the catalogue's; what is here, the drive's own word.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub described: BTreeMap<String, DescribedSetting>,
    /// Parameters the drive described as settable but refused to read (an element of them):
    /// not saved, so a restore does not set them.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub not_read: Vec<String>,
}

/// What a discovery found ([`UploadOptions::discover`]).
#[derive(Debug, Clone, Default)]
struct Discovered {
    settings: BTreeMap<String, DescribedSetting>,
    unread: Vec<String>,
    /// Numbers asked (those of the range the catalogues say nothing of).
    asked: usize,
}

impl Saved {
    /// How many values it holds.
    pub fn len(&self) -> usize {
        match self {
            Self::One(_) => 1,
            Self::Many(list) => list.len(),
        }
    }

    /// Whether it holds none (an empty list).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A setting the drive described itself: its PROFIdrive data type as the drive gave it, and
/// its value or (the drive said it has elements) its values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DescribedSetting {
    /// `U16`, `I16`, `U32`, `I32` or `Float`.
    #[serde(rename = "type")]
    pub data_type: String,
    pub value: Saved,
}

/// Parameter numbers as `--discover` and the bridge's `?discover=` write them: `FROM-TO`, or
/// one number; `None` for anything else (a reversed range too).
pub fn pnu_range(text: &str) -> Option<core::ops::RangeInclusive<u16>> {
    let (a, b) = text.split_once('-').unwrap_or((text, text));
    let (a, b) = (a.trim().parse::<u16>().ok()?, b.trim().parse::<u16>().ok()?);
    (a <= b).then_some(a..=b)
}

/// How an upload goes ([`Bus::upload_with`]).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct UploadOptions {
    /// Besides the catalogue's settings, ask the drive for every parameter number in this
    /// range that the catalogue does not list (AK 4, one description each) and save the
    /// settable ones it has, typed as it describes them: the rest of a drive's list where
    /// uss-rt's is not whole. A number the drive does not have costs one exchange.
    pub discover: Option<core::ops::RangeInclusive<u16>>,
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
    /// The value of a parameter the catalogue lists, in its unit (a fixed-point parameter's
    /// steps as a number of its unit: SIMOREG P303's 1000 is `10.0` s).
    pub fn of_param(info: &Param, v: Value) -> Self {
        match info.scale {
            // The catalogue's one reading of a fixed-point value, exact to its step's digits.
            Some(_) => match info.quantity(info.data_type.decode(v)) {
                uss_catalogue::Quantity::Real(x) => Self::Float(x),
                uss_catalogue::Quantity::Whole(n) => Self::Int(n),
            },
            None => Self::of(info.data_type, v),
        }
    }

    /// The value as the parameter's own type stores it.
    pub fn of(data_type: DataType, v: Value) -> Self {
        match data_type.decode(v) {
            crate::Typed::Float(f) => {
                // The shortest text that reads back as the same f32, as an f64 for TOML.
                Self::Float(format!("{f:?}").parse().unwrap_or(f64::from(f)))
            }
            t => Self::Int(t.as_f64() as i64),
        }
    }

    /// The number as the file writes it (`5`, `45.5`).
    pub fn text(self) -> String {
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

/// A backup file read and checked ([`BackupFile::parse`]).
#[derive(Debug, Clone)]
pub struct Loaded {
    pub file: BackupFile,
    /// Every element it sets, in catalogue order.
    pub entries: Vec<Entry>,
    /// What it holds that is the drive's state, not a setting (P0010, P0004 in backups taken
    /// before uss-rt left them out): not restored, not compared.
    pub ignored: Vec<String>,
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
    /// Reads and checks a backup file; `origin` names it in errors. Returns the file, every
    /// element it sets (in catalogue order) and what it holds that is not restored.
    pub fn parse(
        text: &str,
        origin: &str,
        catalogue: &'static Catalogue,
    ) -> Result<Loaded, FileError> {
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
        let mut ignored = Vec::new();
        // Each parameter once, however it is written (P303, P0303, p303): of two keys of one
        // parameter the file would mean the one TOML read last, whichever that is.
        let mut keys: BTreeMap<u16, &str> = BTreeMap::new();
        for (key, saved) in &file.param {
            let at = line_of(text, key);
            let param = named_once(&mut keys, key, at, &fail)?;
            let info = catalogue.param(param.pnu.get()).ok_or_else(|| {
                fail(
                    at,
                    format!("{key}: not a parameter of {}", catalogue.family),
                )
            })?;
            if info.is_writable() && !info.action && !info.is_setting() && param.index.is_none() {
                // P0010, P0004 (older backups hold them): the drive's state, not a setting.
                ignored.push(info.id.to_string());
                continue;
            }
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
            entries.extend(elements(key, saved, info).map_err(|m| fail(at, m))?);
        }
        entries.extend(described_entries(&file, text, catalogue, &mut keys, &fail)?);
        entries.sort_by_key(|e| (e.param.pnu, e.param.index));
        Ok(Loaded {
            file,
            entries,
            ignored,
        })
    }

    /// Whether the file may go to a drive whose firmware reads `now` (its r0018, as
    /// [`Bus::firmware`] reads it): the same firmware, or a file or drive that does not say.
    /// Another firmware may number, range or mean its parameters otherwise (STARTER refuses
    /// it); `other_firmware` is the caller's deliberate decision to restore all the same.
    ///
    /// # Errors
    /// [`ParamError::Value`] naming both versions.
    pub fn check_firmware(
        &self,
        now: Option<Number>,
        other_firmware: bool,
    ) -> Result<(), ParamError> {
        match (self.firmware, now) {
            (Some(theirs), Some(ours)) if theirs != ours && !other_firmware => {
                Err(ParamError::Value {
                    param: "firmware".to_owned(),
                    problem: format!(
                        "the backup was taken from firmware {} and the drive has {}: its \
                         parameters may be numbered, limited or meant otherwise; restore it \
                         deliberately to another firmware (nothing was written)",
                        theirs.text(),
                        ours.text()
                    ),
                })
            }
            _ => Ok(()),
        }
    }

    /// The file as TOML, with a header that says what it is.
    pub fn to_text(&self) -> String {
        let body = toml::to_string(self).unwrap_or_default();
        format!(
            "# uss-rt parameter backup (format {FORMAT}): the settings of drive {} on bus {}: each \
             setting of its family's catalogue, with every element the drive said it has (a \
             list: its data sets or array){}.\n# Restore: ussctl param restore DRIVE FILE; compare: \
             ussctl param diff DRIVE FILE.\n{body}",
            self.drive,
            self.bus,
            if self.described.is_empty() {
                ""
            } else {
                "; under [described], settings the catalogue does not list, typed as the drive \
                 described them"
            }
        )
    }
}

impl From<FileError> for ParamError {
    fn from(e: FileError) -> Self {
        Self::Value {
            param: e.origin.clone() + &e.line.map(|l| format!(":{l}")).unwrap_or_default(),
            problem: e.message,
        }
    }
}

/// The elements one key of a file sets, each checked against `info`: a list for an array, as
/// many values as it has; one value or (a drive with data sets, as the drive said when the
/// backup was taken) a list for any other. The error is the message, without its line.
fn elements(key: &str, saved: &Saved, info: &'static Param) -> Result<Vec<Entry>, String> {
    let listed = matches!(saved, Saved::Many(_));
    let values = match saved {
        Saved::One(n) if info.array == 0 => vec![*n],
        Saved::Many(list) if info.array > 0 && list.len() == usize::from(info.array) => {
            list.clone()
        }
        Saved::Many(list) if info.array == 0 && (1..=255).contains(&list.len()) => list.clone(),
        _ => {
            let wanted = if info.array == 0 {
                "one value".to_owned()
            } else {
                format!("a list of {} values", info.array)
            };
            return Err(format!("{key}: {} takes {wanted}", info.id));
        }
    };
    let mut out = Vec::with_capacity(values.len());
    for (i, n) in values.into_iter().enumerate() {
        if let (Some(step), Number::Int(steps)) = (info.scale, n) {
            // Backups before the unit held the steps as a whole number: P303 = 1000 was 10 s.
            return Err(format!(
                "{key}: {steps} has no decimal point; {} is saved in {unit} with one (older \
                 backups held its steps of {step} {unit}: {steps} steps are {:.*} {unit})",
                info.id,
                uss_catalogue::step_decimals(step),
                steps as f64 * step,
                unit = info.unit,
            ));
        }
        let value = info.parse(&n.text()).map_err(|e| format!("{key}: {e}"))?;
        if !info.within_limits(value) {
            return Err(format!(
                "{key}: {} is outside the drive's limits {}..={}",
                n.text(),
                info.min.unwrap_or(f64::NAN),
                info.max.unwrap_or(f64::NAN)
            ));
        }
        let param = ParamRef {
            prefix: Prefix::P,
            ..info.id
        };
        let param = if listed {
            let index = u8::try_from(i)
                .ok()
                .and_then(|i| Subindex::new(i).ok())
                .ok_or_else(|| format!("{key}: too many elements"))?;
            param.at(index)
        } else {
            param
        };
        out.push(Entry { param, info, value });
    }
    Ok(out)
}

/// The elements a file's `[described]` settings set, each checked: a number the catalogue
/// lists belongs under `[param]`, a type is one uss-rt reads, a parameter is named once
/// (`keys`, shared with `[param]`).
fn described_entries<'f>(
    file: &'f BackupFile,
    text: &str,
    catalogue: &'static Catalogue,
    keys: &mut BTreeMap<u16, &'f str>,
    fail: &dyn Fn(Option<usize>, String) -> FileError,
) -> Result<Vec<Entry>, FileError> {
    let mut entries = Vec::new();
    for (key, d) in &file.described {
        let at = line_of(text, key)
            .or_else(|| line_of_table(text, key))
            .or_else(|| line_of(text, &format!("{key}.value")))
            .or_else(|| line_of(text, &format!("{key}.type")));
        let param = named_once(keys, key, at, fail)?;
        let pnu = param.pnu.get();
        let why = if param.index.is_some() {
            Some("write an array as a list, e.g. value = [1, 2, 3]".to_owned())
        } else if catalogue.param(pnu).is_some() {
            Some(format!(
                "the catalogue of {} lists it: it belongs under [param]",
                catalogue.family
            ))
        } else {
            Catalogue::not_from_description(pnu)
        };
        if let Some(why) = why {
            return Err(fail(at, format!("{key}: {why}")));
        }
        let data_type = DataType::named(&d.data_type).ok_or_else(|| {
            fail(
                at,
                format!(
                    "{key}: type = \"{}\" is not a type uss-rt reads (U16, I16, U32, \
                         I32, Float)",
                    d.data_type
                ),
            )
        })?;
        let array = match &d.value {
            Saved::One(_) => 0,
            Saved::Many(list) => u16::try_from(list.len()).unwrap_or(u16::MAX),
        };
        let info = uss_catalogue::described(param, data_type, array);
        entries.extend(elements(key, &d.value, info).map_err(|m| fail(at, m))?);
    }
    Ok(entries)
}

/// Parameter `key` of a file, which names it first: of two keys of one parameter (P303,
/// P0303, p303) the file would mean the one TOML read last, whichever that is.
fn named_once<'f>(
    keys: &mut BTreeMap<u16, &'f str>,
    key: &'f str,
    at: Option<usize>,
    fail: &dyn Fn(Option<usize>, String) -> FileError,
) -> Result<ParamRef, FileError> {
    let param: ParamRef = key.parse().map_err(|e| fail(at, format!("{key}: {e}")))?;
    if let Some(first) = keys.insert(param.pnu.get(), key) {
        return Err(fail(
            at,
            format!(
                "{key}: {first} names the same parameter: keep one of them (nothing was \
                 restored or compared)"
            ),
        ));
    }
    Ok(param)
}

/// The line of a table `[described.key]` in `text`.
fn line_of_table(text: &str, key: &str) -> Option<usize> {
    text.lines()
        .position(|l| {
            let l = l.trim();
            l == format!("[described.{key}]") || l == format!("[described.\"{key}\"]")
        })
        .map(|i| i + 1)
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

/// A settable parameter's name as the family's manuals write it (`P0701`; `P303` on SIMOREG).
fn name_of(pnu: u16, catalogue: &Catalogue) -> String {
    catalogue.notation(ParamRef {
        prefix: Prefix::P,
        pnu: Pnu::from_u16(pnu),
        index: None,
    })
}

/// Reads per request (the PROFIdrive multi-parameter limit).
const PER_REQUEST: usize = 39;

/// One element of a drive's settings as it was read: the element, its catalogue entry and its
/// value.
pub type Setting = (ParamRef, &'static Param, Value);

/// A drive's settings ([`Bus::upload`]): the file, and how many values it holds.
#[derive(Debug, Clone)]
pub struct Upload {
    pub file: BackupFile,
    /// Elements read (an array's or data set's each).
    pub values: usize,
    /// With [`UploadOptions::discover`]: how many numbers of the range the drive was asked
    /// for (those no catalogue says anything of).
    pub asked: usize,
}

/// One element that differs ([`Bus::diff_file`], [`Bus::diff_drives`]): the drive's value and
/// the other's (the file's, or the second drive's); `None` where that side does not have it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Difference {
    pub param: ParamRef,
    pub info: &'static Param,
    pub drive: Option<Value>,
    pub other: Option<Value>,
}

/// A comparison: the elements that are the same, and each that differs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Diff {
    pub same: usize,
    pub differ: Vec<Difference>,
    /// What a file holds that is not compared (the drive's state: P0010, P0004).
    pub ignored: Vec<String>,
}

/// Whether a read failed because the drive does not have the parameter.
pub const fn not_on_drive(e: &ParamError) -> bool {
    matches!(
        e,
        ParamError::Drive(DriveError::Refused(ErrorNumber::IllegalPnu))
    )
}

/// The catalogue whose settings a drive of `family` has (`catalogue/data/<family>.toml`).
///
/// # Errors
/// [`ParamError::NotOnFamily`] for a generic slave: uss-rt has no catalogue of its settings to
/// back up, restore or compare.
pub fn settings_catalogue(
    address: Address,
    family: DriveFamily,
) -> Result<&'static Catalogue, ParamError> {
    Catalogue::of(family)
        .filter(|c| !c.param.is_empty())
        .ok_or(ParamError::NotOnFamily {
            address: address.get(),
            family: family.name(),
            what: "uss-rt has no catalogue of its settings to back up, restore or compare \
                   (read and write its parameters by number)",
        })
}

/// A backup goes to, and is compared with, a drive of its own family only: the same number
/// means another thing in another family (MM4 P1082 in Hz, a G120's p1082 in rpm). `theirs`:
/// the family the file or the other drive is of; `what`: how the refusal starts ("the backup
/// is of a"); `done`: what is not done ("restored (nothing was written)", "compared").
///
/// # Errors
/// [`ParamError::Value`] naming both families.
pub fn check_family(
    family: DriveFamily,
    theirs: Option<&str>,
    what: &str,
    done: &str,
) -> Result<(), ParamError> {
    match theirs {
        Some(theirs) if theirs != family.name() => Err(ParamError::Value {
            param: "family".to_owned(),
            problem: format!(
                "{what} {theirs} drive, this drive is configured as {}: values of another \
                 family are not {done}",
                family.name()
            ),
        }),
        _ => Ok(()),
    }
}

impl Bus {
    /// The firmware of drive `address` as its r0018 reads it (MICROMASTER 4: a float, 2.09;
    /// G120: its number); none where its family's catalogue has no r0018 or the drive refuses
    /// it (it does not have it).
    ///
    /// # Errors
    /// A failure of the path: the firmware is not known, which is not "none" (a backup and a
    /// restore are checked by it).
    pub fn firmware(&self, address: Address) -> Result<Option<Number>, ParamError> {
        let Some(r0018) = Catalogue::of(self.family(address)).and_then(|c| c.param(18)) else {
            return Ok(None);
        };
        let v = match self.read(address, r0018.id) {
            Ok(v) => v,
            Err(ParamError::Drive(_)) => return Ok(None),
            Err(e) => return Err(e),
        };
        Ok(Some(match r0018.data_type {
            DataType::Float => Number::of(DataType::Float, v),
            t => Number::Int(t.decode(v).as_f64() as i64),
        }))
    }

    /// Reads `params` of drive `address` in requests of up to 39; one result each, in order.
    /// `progress` is told (done, of) after each request.
    pub fn read_entries(
        &self,
        address: Address,
        params: &[ParamRef],
        progress: &mut dyn FnMut(usize, usize),
    ) -> Vec<Result<Value, ParamError>> {
        let tasks: Vec<ParamTask> = params
            .iter()
            .map(|p| ParamTask::read(p.pnu, p.index))
            .collect();
        self.batch_all(address, &tasks, progress)
    }

    /// Runs `tasks` on drive `address` in requests of up to 39; one result each, in order.
    /// `progress` is told (done, of) after each request.
    fn batch_all(
        &self,
        address: Address,
        tasks: &[ParamTask],
        progress: &mut dyn FnMut(usize, usize),
    ) -> Vec<Result<Value, ParamError>> {
        let mut out = Vec::with_capacity(tasks.len());
        for chunk in tasks.chunks(PER_REQUEST) {
            out.extend(self.batch(address, chunk));
            progress(out.len(), tasks.len());
        }
        out
    }

    /// How many elements each of `params` has on drive `address`, as the drive describes it
    /// (descriptive element 2, AK 4: 0 for a plain parameter): one per parameter, in order; 0
    /// where the drive refuses the description (a parameter it does not have is found by its
    /// read).
    ///
    /// # Errors
    /// A failure of the path (offline, ussd gone).
    fn described_elements(
        &self,
        address: Address,
        params: &[&'static Param],
    ) -> Result<Vec<u16>, ParamError> {
        let element = Subindex::new(2).map_err(|e| ParamError::Unexpected(e.to_string()))?;
        let tasks: Vec<ParamTask> = params
            .iter()
            .map(|p| ParamTask::ReadDescription {
                pnu: Pnu::from_u16(p.number()),
                element,
            })
            .collect();
        self.batch_all(address, &tasks, &mut |_, _| {})
            .into_iter()
            .map(|r| match r {
                Ok(v) => Ok(u16::try_from(v.as_u32()).unwrap_or(0).min(255)),
                Err(ParamError::Drive(_)) => Ok(0),
                Err(e) => Err(e),
            })
            .collect()
    }

    /// The settings of drive `address` by `catalogue` (each [`Param::is_setting`]): every
    /// element the catalogue lists for an array, and for any other parameter every element the
    /// drive says it has (its data sets) or the plain value; and the parameters the drive does
    /// not have. `progress` is told (done, of) as the reads go.
    ///
    /// # Errors
    /// A failure of the path (offline, ussd gone) fails it all.
    pub fn settings(
        &self,
        address: Address,
        catalogue: &'static Catalogue,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<(Vec<Setting>, Vec<String>), ParamError> {
        let params: Vec<&'static Param> =
            catalogue.param.iter().filter(|p| p.is_setting()).collect();
        let plain: Vec<&'static Param> = params.iter().copied().filter(|p| p.array == 0).collect();
        let described = self.described_elements(address, &plain)?;
        let mut elements = plain.iter().map(|p| p.number()).zip(described);
        let mut all: Vec<(ParamRef, &'static Param)> = Vec::new();
        for p in params {
            let id = ParamRef {
                prefix: Prefix::P,
                ..p.id
            };
            let count = if p.array > 0 {
                p.array
            } else {
                elements
                    .find(|(n, _)| *n == p.number())
                    .map_or(0, |(_, c)| c)
            };
            if count == 0 {
                all.push((id, p));
            }
            for i in 0..count {
                if let Some(i) = u8::try_from(i).ok().and_then(|i| Subindex::new(i).ok()) {
                    all.push((id.at(i), p));
                }
            }
        }
        let refs: Vec<ParamRef> = all.iter().map(|(r, _)| *r).collect();
        let results = self.read_entries(address, &refs, progress);
        let mut values = Vec::new();
        let mut missing = Vec::new();
        for ((param, info), r) in all.into_iter().zip(results) {
            match r {
                Ok(v) => values.push((param, info, v)),
                Err(e) if not_on_drive(&e) => {
                    let id = info.id.to_string();
                    if missing.last() != Some(&id) {
                        missing.push(id);
                    }
                }
                Err(e) => return Err(e),
            }
        }
        Ok((values, missing))
    }

    /// Uploads every setting of drive `address` as STARTER does: each setting of its family's
    /// catalogue with every element the drive has (its data sets and arrays), its firmware
    /// (r0018) and family, into a [`BackupFile`] taken now. The drive's state (P0010, P0004)
    /// and commands (P0970, P3900) are not settings and are left out.
    ///
    /// # Errors
    /// [`ParamError::NotOnFamily`] for a generic slave; a failure of the path otherwise.
    pub fn upload(
        &self,
        address: Address,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Upload, ParamError> {
        self.upload_with(address, &UploadOptions::default(), progress)
    }

    /// [`Bus::upload`], and with [`UploadOptions::discover`] the settable parameters of the
    /// range that the catalogue does not list, as the drive describes them (`described`).
    ///
    /// # Errors
    /// [`ParamError::Value`] for a discovery range whose first number is above its last
    /// (before the bus); [`ParamError::NotOnFamily`] for a generic slave; a failure of the
    /// path otherwise.
    pub fn upload_with(
        &self,
        address: Address,
        options: &UploadOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Upload, ParamError> {
        if let Some(range) = &options.discover
            && range.is_empty()
        {
            return Err(ParamError::Value {
                param: format!("discover {}-{}", range.start(), range.end()),
                problem: "the first parameter number is above the last".to_owned(),
            });
        }
        let family = self.family(address);
        let catalogue = settings_catalogue(address, family)?;
        let firmware = self.firmware(address)?;
        let (values, missing) = self.settings(address, catalogue, progress)?;
        let found = match &options.discover {
            Some(range) => self.discover(address, catalogue, range.clone(), progress)?,
            None => Discovered::default(),
        };
        let described_values: usize = found.settings.values().map(|d| d.value.len()).sum();
        let mut param: BTreeMap<String, Saved> = BTreeMap::new();
        for (r, info, v) in &values {
            let n = Number::of_param(info, *v);
            let key = info.id.to_string();
            if r.index.is_some() {
                match param.entry(key).or_insert_with(|| Saved::Many(Vec::new())) {
                    Saved::Many(list) => list.push(n),
                    Saved::One(_) => {}
                }
            } else {
                param.insert(key, Saved::One(n));
            }
        }
        Ok(Upload {
            file: BackupFile {
                format: FORMAT,
                family: catalogue.family.clone(),
                drive_family: Some(family.name().to_owned()),
                bus: self.name().to_owned(),
                drive: address.get(),
                firmware,
                taken: now_utc(),
                not_on_drive: missing,
                param,
                described: found.settings,
                not_read: found.unread,
            },
            values: values.len() + described_values,
            asked: found.asked,
        })
    }

    /// The parameters of `numbers` drive `address` has, with the data type each describes
    /// (descriptive element `e1`); a number it refuses it does not have, a type uss-rt does
    /// not read is left out.
    ///
    /// # Errors
    /// A failure of the path.
    fn described_types(
        &self,
        address: Address,
        numbers: &[u16],
        e1: Subindex,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Vec<(u16, DataType)>, ParamError> {
        let tasks: Vec<ParamTask> = numbers
            .iter()
            .map(|&n| ParamTask::ReadDescription {
                pnu: Pnu::from_u16(n),
                element: e1,
            })
            .collect();
        let mut found = Vec::new();
        for (&n, r) in numbers
            .iter()
            .zip(self.batch_all(address, &tasks, progress))
        {
            match r {
                Ok(code) => {
                    if let Some(t) = u16::try_from(code.as_u32())
                        .ok()
                        .and_then(DataType::from_code)
                    {
                        found.push((n, t));
                    }
                }
                // Not on the drive (error 0), or not described to this link.
                Err(ParamError::Drive(_)) => {}
                Err(e) => return Err(e),
            }
        }
        Ok(found)
    }

    /// The settable parameters of drive `address` numbered in `range` that `catalogue` does
    /// not list, as the drive describes them: each number asked for its data type
    /// (descriptive element 1; refused: the drive does not have it), those it has for their
    /// elements (2) and whether they are read-only (4), and the settable ones read, every
    /// element. A parameter whose type uss-rt does not read, or that the drive does not say is
    /// writable, is left out. Returns them by name and how many values they hold.
    ///
    /// # Errors
    /// A failure of the path.
    fn discover(
        &self,
        address: Address,
        catalogue: &'static Catalogue,
        range: core::ops::RangeInclusive<u16>,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Discovered, ParamError> {
        let element = |e: u8| Subindex::new(e).map_err(|e| ParamError::Unexpected(e.to_string()));
        let (e1, e2, e4) = (element(1)?, element(2)?, element(4)?);
        let numbers: Vec<u16> = range
            .filter(|&n| {
                !catalogue.knows(n)
                    && Catalogue::not_from_description(n).is_none()
                    && Pnu::new(u32::from(n)).is_ok()
            })
            .collect();
        let found = self.described_types(address, &numbers, e1, progress)?;
        let tasks: Vec<ParamTask> = found
            .iter()
            .flat_map(|&(n, _)| {
                [e2, e4].map(|element| ParamTask::ReadDescription {
                    pnu: Pnu::from_u16(n),
                    element,
                })
            })
            .collect();
        let answers = self.batch_all(address, &tasks, &mut |_, _| {});
        let mut settable: Vec<(u16, DataType, u16)> = Vec::new();
        for (&(n, t), pair) in found.iter().zip(answers.chunks(2)) {
            let word = |r: &Result<Value, ParamError>| match r {
                Ok(v) => Ok(Some(v.as_u32())),
                Err(ParamError::Drive(_)) => Ok(None),
                Err(e) => Err(e.clone()),
            };
            let (elements, read_only) = (word(&pair[0])?, word(&pair[1])?);
            if read_only == Some(0) {
                let elements = elements.map_or(0, |c| u16::try_from(c).unwrap_or(0).min(255));
                settable.push((n, t, elements));
            }
        }
        let mut refs: Vec<(usize, ParamRef)> = Vec::new();
        for (i, &(n, _, elements)) in settable.iter().enumerate() {
            let id = ParamRef {
                prefix: Prefix::P,
                pnu: Pnu::from_u16(n),
                index: None,
            };
            if elements == 0 {
                refs.push((i, id));
            }
            for k in 0..elements {
                if let Some(k) = u8::try_from(k).ok().and_then(|k| Subindex::new(k).ok()) {
                    refs.push((i, id.at(k)));
                }
            }
        }
        let plain: Vec<ParamRef> = refs.iter().map(|(_, r)| *r).collect();
        let read = self.read_entries(address, &plain, &mut |_, _| {});
        let mut out: BTreeMap<String, DescribedSetting> = BTreeMap::new();
        let mut unread: Vec<String> = Vec::new();
        for ((i, r), v) in refs.iter().zip(read) {
            let (n, t, _) = settable[*i];
            let name = name_of(n, catalogue);
            if unread.contains(&name) {
                continue;
            }
            let v = match v {
                Ok(v) => v,
                // Described, but an element of it is refused: not saved at all (a part would
                // restore as the whole), and named so.
                Err(ParamError::Drive(_)) => {
                    out.remove(&name);
                    unread.push(name);
                    continue;
                }
                Err(e) => return Err(e),
            };
            let number = Number::of(t, v);
            let entry = out.entry(name).or_insert_with(|| DescribedSetting {
                data_type: t.name().to_owned(),
                value: if r.index.is_some() {
                    Saved::Many(Vec::new())
                } else {
                    Saved::One(number)
                },
            });
            if let Saved::Many(list) = &mut entry.value {
                list.push(number);
            }
        }
        Ok(Discovered {
            settings: out,
            unread,
            asked: numbers.len(),
        })
    }

    /// The parameters of `entries` that the file took from a drive's own description (its
    /// `[described]`) and that drive `address` describes otherwise now: another type, another
    /// number of elements, read-only, or not at all. Each is refused by a restore, not written
    /// (its value would mean something else), and differs in a comparison.
    ///
    /// # Errors
    /// A failure of the path.
    pub(crate) fn described_differently(
        &self,
        address: Address,
        entries: &[Entry],
    ) -> Result<Vec<(Pnu, ParamError)>, ParamError> {
        let mut out = Vec::new();
        let mut asked = Vec::new();
        for e in entries.iter().filter(|e| e.info.is_described()) {
            if asked.contains(&e.param.pnu) {
                continue;
            }
            asked.push(e.param.pnu);
            let held = |n: u16| match n {
                0 => "one value".to_owned(),
                n => format!("{n} elements"),
            };
            let problem = match self.drive_description(address, e.param.pnu) {
                Ok(d) if d.data_type != e.info.data_type => format!(
                    "the backup's drive described it as {} and this drive as {}: not written",
                    e.info.data_type.name(),
                    d.data_type.name()
                ),
                Ok(d) if d.read_only == Some(true) => {
                    "this drive describes it as read-only: not written".to_owned()
                }
                Ok(d) if d.elements.unwrap_or(0) != e.info.array => format!(
                    "the backup holds {} and this drive describes {}: not written",
                    held(e.info.array),
                    held(d.elements.unwrap_or(0))
                ),
                Ok(_) => continue,
                Err(ParamError::Drive(d)) => {
                    format!("this drive does not describe it ({d}): not written")
                }
                Err(e) => return Err(e),
            };
            out.push((
                e.param.pnu,
                ParamError::Value {
                    param: e.info.id.to_string(),
                    problem,
                },
            ));
        }
        Ok(out)
    }

    /// Compares drive `address` with a backup file's `text` (`origin` names it in errors):
    /// every element the file sets, read from the drive.
    ///
    /// # Errors
    /// [`ParamError::Value`] for a file that does not pass its checks (with its line) or is of
    /// another family; [`ParamError::NotOnFamily`] for a generic slave; a failure of the path.
    pub fn diff_file(
        &self,
        address: Address,
        text: &str,
        origin: &str,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Diff, ParamError> {
        let catalogue = settings_catalogue(address, self.family(address))?;
        let loaded = BackupFile::parse(text, origin, catalogue)?;
        self.diff_loaded(address, &loaded, progress)
    }

    /// [`Bus::diff_file`] of a file already read and checked.
    ///
    /// # Errors
    /// [`ParamError::Value`] for a file of another family; a failure of the path.
    pub fn diff_loaded(
        &self,
        address: Address,
        loaded: &Loaded,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Diff, ParamError> {
        let family = self.family(address);
        check_family(
            family,
            loaded.file.drive_family.as_deref(),
            "the backup is of a",
            "compared",
        )?;
        let refs: Vec<ParamRef> = loaded.entries.iter().map(|e| e.param).collect();
        let now = self.read_entries(address, &refs, progress);
        let mut diff = Diff {
            ignored: loaded.ignored.clone(),
            ..Diff::default()
        };
        // What the file took from a drive's description and this drive describes otherwise
        // (another type or number of elements) is no setting of this drive: it differs.
        let otherwise = self.described_differently(address, &loaded.entries)?;
        for (e, current) in loaded.entries.iter().zip(now) {
            let differ = |drive| Difference {
                param: e.param,
                info: e.info,
                drive,
                other: Some(e.value),
            };
            if otherwise.iter().any(|(pnu, _)| *pnu == e.param.pnu) {
                diff.differ.push(differ(None));
                continue;
            }
            match current {
                Ok(v) if v == e.value => diff.same += 1,
                Ok(v) => diff.differ.push(differ(Some(v))),
                // The drive refused the read (e.g. it does not have the parameter).
                Err(ParamError::Drive(_)) => diff.differ.push(differ(None)),
                Err(e) => return Err(e),
            }
        }
        Ok(diff)
    }

    /// Compares the settings of drives `address` and `other`, of one family, each read with
    /// the elements it says it has.
    ///
    /// # Errors
    /// [`ParamError::Value`] for drives of two families; [`ParamError::NotOnFamily`] for a
    /// generic slave; a failure of the path.
    pub fn diff_drives(
        &self,
        address: Address,
        other: Address,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Diff, ParamError> {
        let family = self.family(address);
        let catalogue = settings_catalogue(address, family)?;
        check_family(
            family,
            Some(self.family(other).name()),
            &format!("drive {other} is a"),
            "compared",
        )?;
        let (a, _) = self.settings(address, catalogue, progress)?;
        let (b, _) = self.settings(other, catalogue, progress)?;
        let theirs: BTreeMap<_, _> = b.iter().map(|(r, _, v)| ((r.pnu, r.index), *v)).collect();
        let mut diff = Diff::default();
        for (r, info, v) in &a {
            match theirs.get(&(r.pnu, r.index)) {
                Some(w) if w == v => diff.same += 1,
                w => diff.differ.push(Difference {
                    param: *r,
                    info,
                    drive: Some(*v),
                    other: w.copied(),
                }),
            }
        }
        Ok(diff)
    }
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
            firmware: Some(Number::Float(2.09)),
            taken: now_utc(),
            not_on_drive: vec!["P0004".into()],
            param,
            described: BTreeMap::new(),
            not_read: Vec::new(),
        }
    }

    /// The sweep of issue 46: `P303 = 5.0` beside `P0303 = 10.0` was taken (the key TOML read
    /// last won) and the report said both written.
    #[test]
    fn a_setting_the_drive_described_is_read_back_typed_as_it_said_and_checked() {
        let mut f = file(BTreeMap::new());
        let described = |t: &str, value| DescribedSetting {
            data_type: t.to_owned(),
            value,
        };
        f.described
            .insert("P0701".into(), described("U16", Saved::One(Number::Int(9))));
        f.described.insert(
            "P1230".into(),
            described(
                "Float",
                Saved::Many(vec![Number::Float(1.5), Number::Float(-2.5)]),
            ),
        );
        let text = f.to_text();
        assert!(text.contains("under [described]"), "{text}");
        let loaded = BackupFile::parse(&text, "f", Catalogue::micromaster4()).unwrap();
        let got: Vec<_> = loaded
            .entries
            .iter()
            .map(|e| (e.param.to_string(), e.value, e.info.is_described()))
            .collect();
        assert_eq!(
            got,
            [
                ("P0701".to_owned(), Value::Word(9), true),
                ("P1230[0]".to_owned(), Value::from_f32(1.5), true),
                ("P1230[1]".to_owned(), Value::from_f32(-2.5), true),
            ]
        );
        assert_eq!(loaded.entries[1].info.data_type, DataType::Float);
        let mut g120 = f.clone();
        g120.family.clone_from(&Catalogue::g120().family);
        g120.described.clear();
        g120.described
            .insert("p1910".into(), described("U16", Saved::One(Number::Int(1))));
        let e = BackupFile::parse(&g120.to_text(), "f", Catalogue::g120()).unwrap_err();
        assert!(
            e.message
                .contains("a command in the catalogue of MICROMASTER 4"),
            "{e}"
        );
        // What the catalogue lists belongs under [param]; a type uss-rt does not read, a value
        // the type cannot hold and a name given twice are refused with their line.
        for (key, d, says) in [
            (
                "P1082",
                described("Float", Saved::One(Number::Float(5.0))),
                "under [param]",
            ),
            // A guarded parameter the catalogue lists only as a guard (P0840, ON/OFF1's
            // source), and a command of another family under the same number (MM4 P1910, a
            // motor identification, is not in the G120 catalogue): never from a description.
            (
                "P0840",
                described("U32", Saved::One(Number::Int(722))),
                "guarded",
            ),
            (
                "P0702",
                described("Octets", Saved::One(Number::Int(1))),
                "not a type",
            ),
            (
                "P0702",
                described("U16", Saved::One(Number::Int(-1))),
                "P0702",
            ),
            (
                "P701",
                described("U16", Saved::One(Number::Int(1))),
                "same parameter",
            ),
        ] {
            let mut bad = f.clone();
            bad.described.insert(key.into(), d);
            let e = BackupFile::parse(&bad.to_text(), "f", Catalogue::micromaster4()).unwrap_err();
            assert!(e.message.contains(says) && e.line.is_some(), "{key}: {e}");
        }
    }

    #[test]
    fn a_parameter_named_twice_is_refused_naming_both() {
        let mut param = BTreeMap::new();
        param.insert("P1082".into(), Saved::One(Number::Float(45.0)));
        param.insert("P01082".into(), Saved::One(Number::Float(50.0)));
        let text = file(param).to_text();
        let e = BackupFile::parse(&text, "f", Catalogue::micromaster4()).unwrap_err();
        assert!(
            e.message.contains("names the same parameter") && e.line.is_some(),
            "{e}"
        );
        let mut param = BTreeMap::new();
        param.insert("P0003".into(), Saved::One(Number::Int(1)));
        param.insert("P3".into(), Saved::One(Number::Int(3)));
        let text = file(param).to_text();
        assert!(BackupFile::parse(&text, "f", Catalogue::micromaster4()).is_err());
    }

    #[test]
    fn a_fixed_point_setting_is_saved_in_its_unit_and_a_whole_number_is_refused() {
        // SIMOREG P303 counts 0.01 s: saved as seconds, never as the bare steps.
        let simoreg = Catalogue::simoreg();
        let p303 = simoreg.param(303).unwrap();
        let n = Number::of_param(p303, Value::Word(7));
        assert_eq!(n, Number::Float(0.07));
        let mut param = BTreeMap::new();
        param.insert("P303".into(), Saved::One(n));
        let mut f = file(param);
        f.family.clone_from(&simoreg.family);
        let text = f.to_text();
        assert!(text.contains("P303 = 0.07"), "{text}");
        let loaded = BackupFile::parse(&text, "f", simoreg).unwrap();
        assert_eq!(loaded.entries[0].value, Value::Word(7));
        let old = text.replace("P303 = 0.07", "P303 = 1000");
        let e = BackupFile::parse(&old, "f", simoreg).unwrap_err();
        assert!(
            e.message.contains("no decimal point") && e.message.contains("10.00 s"),
            "{e}"
        );
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
        let Loaded {
            file: back,
            entries,
            ..
        } = BackupFile::parse(&text, "f", Catalogue::micromaster4()).unwrap();
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
            let loaded = BackupFile::parse(&text, "f", Catalogue::micromaster4()).unwrap();
            prop_assert_eq!(loaded.entries[0].value, Value::from_f32(f));
        }
    }
}
