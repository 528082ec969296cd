//! What a drive's parameters are, as the drives engineer knows them from the parameter list:
//! number and prefix (`P` settable, `r` read-only), name, PROFIdrive data type, unit, array size,
//! access level, when it can be changed; and the texts of fault and warning numbers.
//!
//! The catalogue is data: one TOML file per drive family (`data/*.toml`), compiled in and read at
//! first use. [`Values`] turns the words of the PKW channel into typed values and back, refusing
//! what does not fit the type before it reaches the bus.
//!
//! ```
//! use uss_catalogue::{Catalogue, DataType, Values as _};
//! use uss_protocol::Value;
//!
//! let p1082 = Catalogue::micromaster4().param(1082).unwrap();
//! assert_eq!((p1082.name.as_str(), p1082.data_type, p1082.unit.as_str()), ("Max. frequency", DataType::Float, "Hz"));
//! assert_eq!(p1082.show(Value::Dword(0x4248_0000)), "50.00 Hz");
//! assert_eq!(p1082.data_type.parse("45"), Ok(Value::from_f32(45.0)));
//! assert_eq!(Catalogue::micromaster4().fault(72), Some("USS (COM link) setpoint fault"));
//! ```

use core::fmt;
use serde::Deserialize;
use std::sync::LazyLock;
use uss_control::DriveFamily;
use uss_protocol::{ParamRef, Prefix, Value};

/// The PROFIdrive data types of the parameters (the codec's: its type codes are the value of
/// descriptive element 1, USS.md section 6); [`Values`] reads and writes values of them.
pub use uss_protocol::DataType;

/// A value of a parameter's own type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Typed {
    I16(i16),
    I32(i32),
    U16(u16),
    U32(u32),
    Float(f32),
}

/// A value serializes as the plain number (a float widened to f64 as it is, not re-rounded), so
/// every JSON report of a parameter value writes it the same way.
impl serde::Serialize for Typed {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match *self {
            Self::I16(n) => s.serialize_i16(n),
            Self::I32(n) => s.serialize_i32(n),
            Self::U16(n) => s.serialize_u16(n),
            Self::U32(n) => s.serialize_u32(n),
            Self::Float(f) => s.serialize_f64(f64::from(f)),
        }
    }
}

/// Text that is not a value of the parameter's type.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValueError {
    #[error("{text:?} is not a number")]
    NotANumber { text: String },
    #[error("{text} does not fit {data_type} ({range})")]
    OutOfRange {
        text: String,
        data_type: DataType,
        range: &'static str,
    },
    #[error("{text} is not a whole number, and {data_type} holds only whole numbers")]
    NotWhole { text: String, data_type: DataType },
    /// A fixed-point parameter holds whole steps only (SIMOREG P303: 0.01 s).
    #[error("{text} is not a whole number of steps of {step} {unit}")]
    NotAStep {
        text: String,
        /// The step as the catalogue writes it (`0.01`).
        step: String,
        unit: String,
    },
    #[error("{text} {unit} in steps of {step} {unit} does not fit {data_type}")]
    StepsOutOfRange {
        text: String,
        data_type: DataType,
        step: String,
        unit: String,
    },
}

/// Values of a [`DataType`]: what the PKW channel carried read as it, and text written as it.
pub trait Values {
    /// The value the PKW channel carried, read as this type (a word of a dword type, or a
    /// dword of a word type, is read from its low bits).
    fn decode(self, v: Value) -> Typed;

    /// A value written as text (`45`, `45.5`, `-3`, `0x1F`), as this type's word or double
    /// word; what does not fit the type is refused here, before the bus.
    fn parse(self, text: &str) -> Result<Value, ValueError>;
}

/// The values a type holds, as an error says them.
const fn range(t: DataType) -> &'static str {
    match t {
        DataType::I16 => "-32768..=32767",
        DataType::I32 => "-2147483648..=2147483647",
        DataType::U16 => "0..=65535",
        DataType::U32 => "0..=4294967295",
        DataType::Float => "a single-precision number: 0, or 1.4e-45 to 3.4e38 in size",
    }
}

impl Values for DataType {
    fn decode(self, v: Value) -> Typed {
        let raw = v.as_u32();
        match self {
            Self::I16 => Typed::I16(raw as u16 as i16),
            Self::I32 => Typed::I32(raw as i32),
            Self::U16 => Typed::U16(raw as u16),
            Self::U32 => Typed::U32(raw),
            Self::Float => Typed::Float(f32::from_bits(raw)),
        }
    }

    fn parse(self, text: &str) -> Result<Value, ValueError> {
        let t = text.trim();
        let out_of_range = || ValueError::OutOfRange {
            text: t.to_owned(),
            data_type: self,
            range: range(self),
        };
        let not_a_number = || ValueError::NotANumber { text: t.to_owned() };
        // Hex is the bits of the type: `0xFFFF` is -1 for an I16, `0x41200000` 10.0 for a float.
        if let Some(hex) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
            let bits = u32::from_str_radix(hex, 16).map_err(|_| not_a_number())?;
            return match self {
                Self::I16 | Self::U16 => u16::try_from(bits)
                    .map(Value::Word)
                    .map_err(|_| out_of_range()),
                Self::I32 | Self::U32 => Ok(Value::Dword(bits)),
                Self::Float if f32::from_bits(bits).is_finite() => Ok(Value::Dword(bits)),
                Self::Float => Err(out_of_range()),
            };
        }
        if self == Self::Float {
            let f: f32 = t.parse().map_err(|_| not_a_number())?;
            // Too large is infinite; too small is 0 although the text is not: neither is what
            // was written.
            let lost = f == 0.0 && t.parse::<f64>().is_ok_and(|x| x != 0.0);
            return if f.is_finite() && !lost {
                Ok(Value::from_f32(f))
            } else {
                Err(out_of_range())
            };
        }
        // A whole number however it is written: `300`, `300.0`, `1e3`.
        let n = if let Ok(n) = t.parse::<i64>() {
            n
        } else {
            let f: f64 = t.parse().map_err(|_| not_a_number())?;
            if !f.is_finite() || f.fract() != 0.0 {
                return Err(ValueError::NotWhole {
                    text: t.to_owned(),
                    data_type: self,
                });
            }
            if f.abs() > 1e18 {
                return Err(out_of_range());
            }
            f as i64
        };
        match self {
            Self::I16 => i16::try_from(n).map(|v| Value::Word(v as u16)),
            Self::U16 => u16::try_from(n).map(Value::Word),
            Self::I32 => i32::try_from(n).map(|v| Value::Dword(v as u32)),
            Self::U32 | Self::Float => u32::try_from(n).map(Value::Dword),
        }
        .map_err(|_| out_of_range())
    }
}

/// A value as a client is given it, in the parameter's unit: a whole number, or a real one (a
/// float parameter's, widened as it is; a fixed-point parameter's in its unit). It serializes
/// as the plain number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Quantity {
    Whole(i64),
    Real(f64),
}

impl Quantity {
    /// The value of a parameter without a unit step: as its type holds it.
    pub fn of(typed: Typed) -> Self {
        match typed {
            Typed::Float(f) => Self::Real(f64::from(f)),
            t => Self::Whole(t.as_f64() as i64),
        }
    }

    /// As a number.
    pub fn as_f64(self) -> f64 {
        match self {
            Self::Whole(n) => n as f64,
            Self::Real(x) => x,
        }
    }
}

impl serde::Serialize for Quantity {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match *self {
            Self::Whole(n) => s.serialize_i64(n),
            Self::Real(x) => s.serialize_f64(x),
        }
    }
}

impl Typed {
    /// The value as a number (for JSON and comparisons).
    pub fn as_f64(self) -> f64 {
        match self {
            Self::I16(v) => f64::from(v),
            Self::I32(v) => f64::from(v),
            Self::U16(v) => f64::from(v),
            Self::U32(v) => f64::from(v),
            Self::Float(v) => f64::from(v),
        }
    }
}

impl fmt::Display for Typed {
    /// Integers as they are; floats with two decimals as the operator panels show them
    /// (`50.00`), or with as many as it takes to read back as the very value the drive holds
    /// (`0.001`, `12.345678`; `-0.00` keeps its sign).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::I16(v) => write!(f, "{v}"),
            Self::I32(v) => write!(f, "{v}"),
            Self::U16(v) => write!(f, "{v}"),
            Self::U32(v) => write!(f, "{v}"),
            Self::Float(v) => {
                let two = format!("{v:.2}");
                if two
                    .parse::<f32>()
                    .is_ok_and(|back| back.to_bits() == v.to_bits())
                {
                    f.write_str(&two)
                } else {
                    // The shortest text that reads back as `v` (Rust's `{}` of an f32).
                    write!(f, "{v}")
                }
            }
        }
    }
}

/// When a parameter can be changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Change {
    /// Any time, also while the motor runs.
    Always,
    /// Only while the motor does not run (S1..S3).
    NotRunning,
    /// Only in quick commissioning (P0010 = 1).
    Commissioning,
    /// Never: a monitoring (`r`) parameter.
    ReadOnly,
}

impl Change {
    /// The rule in words, as ussctl and the bindings say it ("not while running").
    pub const fn words(self) -> &'static str {
        match self {
            Self::Always => "any time",
            Self::NotRunning => "not while running",
            Self::Commissioning => "in quick commissioning (P0010 = 1)",
            Self::ReadOnly => "never (read-only)",
        }
    }
}

/// A control or status word whose bits have names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
pub enum Bits {
    /// Control word 1 (USS.md section 7).
    STW1,
    /// Status word 1 (USS.md section 7).
    ZSW1,
}

/// One parameter of the catalogue.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Param {
    /// As the manual writes it: `P1082`, `r0021`.
    #[serde(rename = "id", deserialize_with = "param_id")]
    pub id: ParamRef,
    pub name: String,
    #[serde(rename = "type")]
    pub data_type: DataType,
    #[serde(default)]
    pub unit: String,
    /// A fixed-point value: the word counts steps of this many `unit` (SIMOREG P303 counts
    /// 0.01 s: 1000 is 10.00 s). Its limits and default are in `unit`; it is shown, written
    /// and saved in `unit` too.
    #[serde(default)]
    pub scale: Option<f64>,
    /// Elements of an indexed parameter; 0 = not indexed. Such a parameter is always named
    /// with its element (`P2014[0]`): without one a drive takes element 0, which may not be the
    /// one meant, so uss-rt refuses it.
    #[serde(default)]
    pub array: u16,
    /// What each element is (`COM link (RS485)`), where the elements differ in meaning; empty,
    /// or one per element.
    #[serde(default)]
    pub elements: Vec<String>,
    /// User access level (P0003) needed: 1 standard, 2 extended, 3 expert, 4 service.
    pub level: u8,
    pub change: Change,
    /// A change is kept over a power cycle (stored to EEPROM when asked).
    #[serde(default = "yes")]
    pub eeprom: bool,
    pub min: Option<f64>,
    pub max: Option<f64>,
    /// The factory setting, in the parameter's unit (every element of an array), where the
    /// list gives one the simulator plays.
    pub default: Option<f64>,
    /// The only settings the drive takes (an enumeration with gaps, P0700: 0, 1, 2, 4, 5, 6);
    /// empty: any value within the limits.
    #[serde(default)]
    pub values: Vec<u32>,
    pub bits: Option<Bits>,
    /// Writing it starts something (a factory reset, an identification run): a command, not a
    /// setting; never saved in or restored from a backup.
    #[serde(default)]
    pub action: bool,
    /// Elements by data set on the drives that have them (MICROMASTER 440: three command data
    /// sets for the command and setpoint sources, three drive data sets for limits and ramps;
    /// 0 = none). Unlike an array, the parameter is named without an element: a drive takes a
    /// plain task as element 0, the first data set, and a drive without data sets (an MM420 may
    /// have fewer) answers it alone. A backup asks each drive how many elements it has
    /// (descriptive element 2, AK 4) and saves them all.
    #[serde(default)]
    pub data_sets: u8,
    /// The stored page of the manufacturer's list this entry was checked against (list, issue,
    /// page); none: not checked against a stored copy yet.
    #[serde(default)]
    pub source: Option<String>,
}

/// The source of an entry a drive described itself ([`described`]).
pub const DESCRIBED: &str = "the drive's own description (AK 4), not uss-rt's catalogue";

/// A settable parameter that the family's catalogue does not list, as a drive described it
/// (AK 4: its data type, descriptive element 1, and its elements, element 2): what a backup
/// saves of it and a restore writes. Nothing else is known of it: no name, unit, limits (the
/// drive checks its own) or change rule; its access level is taken as 3, the expert level at
/// which STARTER sees and changes every user parameter (CU240S OI 07/2008 A5E00766042B AD,
/// 5.9 p.111: "for STARTER, only access levels 0 and 3 are relevant"). Each kind is made once
/// and kept for the process (a few per parameter a drive has).
pub fn described(id: ParamRef, data_type: DataType, array: u16) -> &'static Param {
    type Made = Vec<&'static Param>;
    static MADE: std::sync::Mutex<Made> = std::sync::Mutex::new(Vec::new());
    let id = ParamRef {
        prefix: Prefix::P,
        index: None,
        ..id
    };
    let mut made = MADE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(p) = made
        .iter()
        .find(|p| p.id == id && p.data_type == data_type && p.array == array)
    {
        return p;
    }
    let p: &'static Param = Box::leak(Box::new(Param {
        id,
        name: "described by the drive".to_owned(),
        data_type,
        unit: String::new(),
        scale: None,
        array,
        elements: Vec::new(),
        level: 3,
        change: Change::Always,
        eeprom: true,
        min: None,
        max: None,
        default: None,
        values: Vec::new(),
        bits: None,
        action: false,
        data_sets: 0,
        source: Some(DESCRIBED.to_owned()),
    }));
    made.push(p);
    p
}

const fn yes() -> bool {
    true
}

fn param_id<'de, D: serde::Deserializer<'de>>(d: D) -> Result<ParamRef, D::Error> {
    let text = String::deserialize(d)?;
    text.parse::<ParamRef>()
        .map_err(|e| serde::de::Error::custom(format_args!("{text:?}: {e}")))
}

fn families<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<DriveFamily>, D::Error> {
    Vec::<String>::deserialize(d)?
        .iter()
        .map(|name| {
            Catalogue::family_named(name)
                .filter(|&f| f != DriveFamily::Generic)
                .ok_or_else(|| {
                    serde::de::Error::custom(format!(
                        "families: {name:?} is no family of the contract's DriveFamily (add its \
                         line there first): {}",
                        Catalogue::family_names()
                    ))
                })
        })
        .collect()
}

fn some_param_id<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<ParamRef>, D::Error> {
    param_id(d).map(Some)
}

fn param_ids<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<ParamRef>, D::Error> {
    Vec::<String>::deserialize(d)?
        .into_iter()
        .map(|text| {
            text.parse::<ParamRef>()
                .map_err(|e| serde::de::Error::custom(format_args!("{text:?}: {e}")))
        })
        .collect()
}

impl Param {
    /// The parameter number.
    pub const fn number(&self) -> u16 {
        self.id.pnu.get()
    }

    /// Whether the parameter can be written at all.
    pub fn is_writable(&self) -> bool {
        self.change != Change::ReadOnly
    }

    /// Whether it is a setting a backup saves and a restore writes: changeable, not a command
    /// (`action`), and kept over a power cycle (`eeprom`): the commissioning parameter (P0010)
    /// and the parameter filter (P0004) are the drive's state, not settings, so a backup taken
    /// during quick commissioning does not put the drive back into it.
    pub fn is_setting(&self) -> bool {
        self.is_writable() && !self.action && self.eeprom
    }

    /// Whether it is an array: named with an element only.
    pub const fn is_array(&self) -> bool {
        self.array > 0
    }

    /// Whether this entry is not the catalogue's but a parameter a drive described itself
    /// ([`described`]).
    pub fn is_described(&self) -> bool {
        self.source.as_deref() == Some(DESCRIBED)
    }

    /// Its elements as a user names them: `P2014[0] (COM link, RS485) or P2014[1] (BOP link,
    /// RS232)`, or `r0947[0] .. r0947[7]` where they are alike.
    pub fn elements_named(&self) -> String {
        let at = |i: u16| format!("{}[{i}]", self.id);
        if self.elements.is_empty() {
            return format!("{} .. {}", at(0), at(self.array.saturating_sub(1)));
        }
        self.elements
            .iter()
            .zip(0..)
            .map(|(what, i)| format!("{} ({what})", at(i)))
            .collect::<Vec<_>>()
            .join(" or ")
    }

    /// The value as it is shown: `50.00 Hz`, `5`, `0xFB31`, `10.00 s` (a fixed-point value).
    pub fn show(&self, v: Value) -> String {
        self.show_typed(v, self.data_type.decode(v))
    }

    /// [`Param::show`] of `v` already decoded as `typed` (its [`Values::decode`]).
    pub fn show_typed(&self, v: Value, typed: Typed) -> String {
        let shown = if self.bits.is_some() {
            format!("{:#06X}", v.as_u32() as u16)
        } else if let Some(step) = self.scale {
            format!("{:.*}", step_decimals(step), typed.as_f64() * step)
        } else {
            typed.to_string()
        };
        if self.unit.is_empty() {
            shown
        } else {
            format!("{shown} {}", self.unit)
        }
    }

    /// Whether `v` lies within the drive's limits the catalogue knows (none known: it does).
    pub fn within_limits(&self, v: Value) -> bool {
        let x = self.in_unit(self.data_type.decode(v));
        self.min.is_none_or(|m| x >= m - 1e-9) && self.max.is_none_or(|m| x <= m + 1e-9)
    }

    /// The value in the parameter's unit: its type's number, times the step of a fixed-point
    /// parameter (SIMOREG P303's raw 1000 is 10.0 s).
    pub fn in_unit(&self, typed: Typed) -> f64 {
        typed.as_f64() * self.scale.unwrap_or(1.0)
    }

    /// The value in the parameter's unit as a client is given it: a fixed-point parameter's
    /// steps as a number of its unit (`10.0` for P303's 1000, `0.07` for 7, exactly to the
    /// step's digits), every other value as its type holds it.
    pub fn quantity(&self, typed: Typed) -> Quantity {
        match self.scale {
            Some(step) => {
                let x = self.in_unit(typed);
                Quantity::Real(format!("{x:.*}", step_decimals(step)).parse().unwrap_or(x))
            }
            None => Quantity::of(typed),
        }
    }

    /// A value written as text in the parameter's unit, as `data_type` (the drive's type of
    /// it, where it described one) holds it: a fixed-point parameter takes whole steps
    /// (`5.5` s is 550 of P303's 0.01 s; `5.555` is refused); hex is the raw word either way.
    pub fn parse_as(&self, data_type: DataType, text: &str) -> Result<Value, ValueError> {
        let t = text.trim();
        let Some(step) = self
            .scale
            .filter(|_| !t.starts_with("0x") && !t.starts_with("0X"))
        else {
            return data_type.parse(t);
        };
        let x: f64 = t
            .parse()
            .map_err(|_| ValueError::NotANumber { text: t.to_owned() })?;
        let steps = (x / step).round();
        if !x.is_finite() || (steps * step - x).abs() > step * 1e-6 {
            return Err(ValueError::NotAStep {
                text: t.to_owned(),
                step: step.to_string(),
                unit: self.unit.clone(),
            });
        }
        data_type
            .parse(&format!("{steps}"))
            .map_err(|_| ValueError::StepsOutOfRange {
                text: t.to_owned(),
                data_type,
                step: step.to_string(),
                unit: self.unit.clone(),
            })
    }

    /// [`Param::parse_as`] as the catalogue types the parameter.
    pub fn parse(&self, text: &str) -> Result<Value, ValueError> {
        self.parse_as(self.data_type, text)
    }
}

/// Decimals that show a step exactly: 2 for 0.01, 1 for 0.5, 0 for 1.
pub fn step_decimals(step: f64) -> usize {
    (0..6)
        .find(|&d| {
            let x = step * 10f64.powi(d as i32);
            (x - x.round()).abs() < 1e-9
        })
        .unwrap_or(6)
}

/// A fault or warning number with its text.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Message {
    pub number: u16,
    pub text: String,
}

/// A parameter whose change can take the drive away from ussd: its command or setpoint
/// source, its COM link, the access that hides these, its telegram monitoring switched off, a
/// factory reset. ussd refuses to write it unless the request is marked unsafe.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Guard {
    #[serde(deserialize_with = "param_id")]
    pub id: ParamRef,
    /// What a change does, in a few words (for the refusal and the log).
    pub why: String,
    /// Only a change to 0 (or below: no time at all) is guarded (switching telegram
    /// monitoring off).
    #[serde(default)]
    pub zero_only: bool,
    /// Only changes to these values are guarded (P0010 = 30, the factory setting mode); empty:
    /// every value.
    #[serde(default)]
    pub values: Vec<u32>,
    /// Where the entry comes from: the manual (title, order number, edition, section or page)
    /// that says what the parameter does.
    pub source: String,
}

impl Guard {
    /// Whether a change to `value` (as the parameter's type reads it) is guarded.
    // Exact: 0 and the listed values are whole numbers a drive holds exactly.
    #[allow(clippy::float_cmp)]
    fn covers(&self, value: f64) -> bool {
        (!self.zero_only || value <= 0.0)
            && (self.values.is_empty() || self.values.iter().any(|v| f64::from(*v) == value))
    }
}

/// Where a family keeps its faults and warnings: what a fault report reads.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultBuffers {
    /// The fault numbers, newest first (MM4 r0947, G120 r0945, SIMOREG r947).
    #[serde(deserialize_with = "param_id")]
    pub codes: ParamRef,
    /// One fault value per element of `codes` (r0949).
    #[serde(default, deserialize_with = "some_param_id")]
    pub values: Option<ParamRef>,
    /// The trips' times in the MICROMASTER 4's format: three words per trip of `per_trip`
    /// faults (r0948).
    #[serde(default, deserialize_with = "some_param_id")]
    pub times: Option<ParamRef>,
    /// When each fault came, as the SINAMICS system runtime r2114: its milliseconds of the
    /// day (r0948) and its days (r2130), one element per element of `codes`.
    #[serde(default, deserialize_with = "some_param_id")]
    pub received_ms: Option<ParamRef>,
    #[serde(default, deserialize_with = "some_param_id")]
    pub received_days: Option<ParamRef>,
    /// Elements of `codes` (and `values`) a report reads.
    pub len: u8,
    /// Faults per trip (fault case), for the times.
    pub per_trip: u8,
    /// The active warnings (MM4 r2110, G120 r2122's current alarms).
    #[serde(default, deserialize_with = "some_param_id")]
    pub warnings: Option<ParamRef>,
    /// Elements of `warnings` a report reads.
    #[serde(default)]
    pub warnings_len: u8,
    /// Digits of a fault or warning number as the family's manuals write it: F0072 (4, the
    /// default), SINAMICS F01910 (5).
    #[serde(default = "four")]
    pub digits: u8,
}

const fn four() -> u8 {
    4
}

/// `p` as manuals that write `digits` digits write it: its letter, its number with at least
/// `digits` digits, its element (`P303`, `r947[2]` with 3; `P1082`, `r0947[2]` with 4, as
/// [`ParamRef`]'s own text).
pub fn notation(p: ParamRef, digits: u8) -> String {
    let text = p.to_string();
    let width = usize::from(digits);
    if width >= 4 {
        return text;
    }
    // The letter, the four digits the protocol writes, the rest (`[2]`).
    let (letter, rest) = text.split_at(1);
    let count = rest.chars().take_while(char::is_ascii_digit).count();
    let (number, tail) = rest.split_at(count);
    let trimmed = number.trim_start_matches('0');
    format!("{letter}{trimmed:0>width$}{tail}")
}

/// The catalogue of one drive family.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Catalogue {
    pub family: String,
    /// The families this profile is for, as the configuration names them (`micromaster4`,
    /// `g110`): the contract's codes it serves.
    #[serde(default, deserialize_with = "families")]
    pub families: Vec<DriveFamily>,
    /// The user access level a change may need raised (P0003), if the family has one.
    #[serde(default, deserialize_with = "some_param_id")]
    pub access_level: Option<ParamRef>,
    /// The commissioning parameter (P0010: 1 for "commissioning" parameters), if any.
    #[serde(default, deserialize_with = "some_param_id")]
    pub commissioning: Option<ParamRef>,
    /// The settings of the line ussd talks to the drive over (baud rate, address, PZD and PKW
    /// length of the USS link): a restore keeps the drive's own values.
    #[serde(default, deserialize_with = "param_ids")]
    pub link: Vec<ParamRef>,
    /// The parameters whose write may change any setting of the drive, its reference and its
    /// telegram monitoring included (MM4 P0010, P0970, P3900): after a write of one, ussd reads
    /// what it knows of the drive again and uses none of it until then. At most four.
    #[serde(default, deserialize_with = "param_ids")]
    pub rereads_after: Vec<ParamRef>,
    /// The "copy RAM to ROM" of the family (MM4 P0971, G120 p0971): 1 stores every setting's
    /// RAM value in EEPROM, and it reads 0 again when done; none: not known.
    #[serde(default, deserialize_with = "some_param_id")]
    pub save: Option<ParamRef>,
    /// Whether the drive takes the task codes that store one value in RAM and EEPROM (11..14,
    /// MICROMASTER 4 OI 10/06 table 3-19; CU240S OI 11/2006 table 8-10). SINAMICS G120 with a
    /// CU2x0-2 lists only 0..9 (Fieldbus Function Manual 06/2012 6SL3097-4AB10-0BP4, table
    /// 9-45): it stores settings permanently only by `save`.
    #[serde(default = "takes_eeprom_tasks")]
    pub eeprom_tasks: bool,
    /// The factory reset (MM4 P0970, G120 p0970): 1 puts every setting back to its factory
    /// value, once the commissioning parameter is at `factory_setting`; it reads 0 when done.
    #[serde(default, deserialize_with = "some_param_id")]
    pub factory_reset: Option<ParamRef>,
    /// The commissioning parameter's value that unlocks the factory reset (30 on MM4 and G120).
    #[serde(default)]
    pub factory_setting: Option<u16>,
    /// The end of quick commissioning (MM4 P3900, G120 p3900): written while the commissioning
    /// parameter is 1, it calculates the motor model from the motor data written before, takes
    /// the drive out of quick commissioning, and reads 0 when done (the commissioning parameter
    /// too). Its values: 1 also puts every setting outside quick commissioning back to its
    /// factory value (MICROMASTER 440 Parameter List 6SE6400-5BB00-0BP0, P3900: it "performs
    /// the calculations ... and resets all other parameters not included in the quick
    /// commissioning to factory settings"), 2 those of the I/O, 3 only calculates (2 and 3 not
    /// reached in a stored copy of the list: as the MM4 lists are known to give them).
    #[serde(default, deserialize_with = "some_param_id")]
    pub quick_commissioning: Option<ParamRef>,
    /// The fault buffer and warnings; none: uss-rt knows no fault buffer of the family.
    pub faults: Option<FaultBuffers>,
    /// Digits of a parameter number as the family's manuals write it: 4 (`P0003`, `r0947`) on
    /// MICROMASTER and SINAMICS, 3 on SIMOREG (`P303`, `r947`: OI 6RX1700-0AD76, "No
    /// parameterization enable (P927)", "Key parameter P051 incorrect" p. 7-23, "was > P151"
    /// p. 12-8). See [`Catalogue::notation`].
    #[serde(default = "four")]
    pub param_digits: u8,
    /// The drive's telegram-off time in ms on the USS link ussd talks over (MM4 P2014[0], G120
    /// p2040): ussd reads it when the drive comes online and checks it; none: not known, the
    /// configuration names it (`monitoring_param`).
    #[serde(default, deserialize_with = "some_param_id")]
    pub monitoring: Option<ParamRef>,
    /// The number of PZD words of the USS link ussd talks over (MM4 P2012[0], G120 p2022): its
    /// maximum is the most a drive of the family takes ([`Catalogue::max_pzd`]).
    #[serde(default, deserialize_with = "some_param_id")]
    pub pzd_length: Option<ParamRef>,
    /// The fault a telegram-off trip records (F0072 on MM4, F01910 on G120).
    #[serde(default)]
    pub telegram_off_fault: Option<u16>,
    /// The command source and its setting that takes commands from the USS link ussd talks over
    /// (MM4 P0700 = 5, G120 p0700 = 6): a drive whose ZSW1 bit 9 says it does not take them is
    /// told to set it.
    #[serde(default, deserialize_with = "some_param_id")]
    pub command_source: Option<ParamRef>,
    #[serde(default)]
    pub command_source_uss: Option<u32>,
    /// The behaviour the simulator plays a drive of this profile with (`micromaster4`, `g120`,
    /// `simoreg`: the ramp, link and fault-buffer parameters its model uses beyond the roles
    /// named here, `uss_drive_sim::family::Behaviour`); none: a MICROMASTER 4's.
    #[serde(default)]
    pub simulator: Option<String>,
    /// The reference frequency in Hz that 0x4000 of the setpoint stands for (MM4 P2000).
    #[serde(default, deserialize_with = "some_param_id")]
    pub reference: Option<ParamRef>,
    /// The reference speed in rpm that 0x4000 stands for, where the reference is a speed (G120
    /// p2000): read when the motor's pole pairs are configured.
    #[serde(default, deserialize_with = "some_param_id")]
    pub reference_speed: Option<ParamRef>,
    #[serde(default)]
    pub param: Vec<Param>,
    #[serde(default)]
    pub fault: Vec<Message>,
    #[serde(default)]
    pub warning: Vec<Message>,
    #[serde(default)]
    pub guard: Vec<Guard>,
}

/// A family takes the EEPROM task codes unless its profile says otherwise.
const fn takes_eeprom_tasks() -> bool {
    true
}

/// What a write of one value to one parameter means to ussd ([`Catalogue::judge_write`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WriteJudgement<'a> {
    /// The parameter's entry, where the catalogue lists it.
    pub entry: Option<&'a Param>,
    /// No setting of the parameter at all (NaN or an infinity for a float).
    pub impossible: bool,
    /// Why it can take the drive away from ussd, if it can.
    pub guard: Option<&'a str>,
}

/// A catalogue file that cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{origin}: {message}")]
pub struct CatalogueError {
    pub origin: String,
    pub message: String,
}

include!(concat!(env!("OUT_DIR"), "/profiles.rs"));

/// Every built-in profile (`catalogue/data/*.toml`, compiled in by `build.rs`), read at first use.
static PROFILES: LazyLock<Vec<Catalogue>> = LazyLock::new(|| {
    PROFILE_FILES
        .iter()
        .map(|(origin, text)| {
            Catalogue::parse(text, origin)
                .unwrap_or_else(|e| unreachable!("the built-in catalogue is valid (tested): {e}"))
        })
        .collect()
});

/// The built-in profile of `family`, which a family with a profile has (tested).
fn built_in(family: DriveFamily) -> &'static Catalogue {
    Catalogue::of(family)
        .unwrap_or_else(|| unreachable!("{} has a built-in profile (tested)", family.name()))
}

impl Catalogue {
    /// MICROMASTER 420/430/440 and SINAMICS G110.
    pub fn micromaster4() -> &'static Self {
        built_in(DriveFamily::Micromaster4)
    }

    /// SINAMICS G120 with a CU240 over USS.
    pub fn g120() -> &'static Self {
        built_in(DriveFamily::G120)
    }

    /// SIMOREG DC-Master 6RA70.
    pub fn simoreg() -> &'static Self {
        built_in(DriveFamily::Simoreg)
    }

    /// The built-in catalogue of a family: the profile whose `families` name it; `None` for a
    /// `generic` slave.
    pub fn of(family: DriveFamily) -> Option<&'static Self> {
        PROFILES.iter().find(|c| c.families.contains(&family))
    }

    /// The family named `name` as the configuration writes it (`micromaster4`, `g110`,
    /// `g120`, `simoreg`, `generic`).
    pub fn family_named(name: &str) -> Option<DriveFamily> {
        DriveFamily::ALL.iter().copied().find(|f| f.name() == name)
    }

    /// Every family's name as the configuration writes it, for a message: "micromaster4, g110,
    /// g120, simoreg, generic".
    pub fn family_names() -> String {
        let names: Vec<&str> = DriveFamily::ALL.iter().map(|f| f.name()).collect();
        names.join(", ")
    }

    /// Whether `pnu` is one of the catalogue's guarded parameters or roles.
    fn guarded_or_role(&self, pnu: u16) -> bool {
        self.guard.iter().any(|g| g.id.pnu.get() == pnu) || self.role_of(pnu)
    }

    /// Whether `pnu` is one of the profile's roles (the link, the reset, the monitoring, ...).
    fn role_of(&self, pnu: u16) -> bool {
        let roles = [
            self.access_level,
            self.commissioning,
            self.save,
            self.factory_reset,
            self.quick_commissioning,
            self.monitoring,
            self.pzd_length,
            self.command_source,
            self.reference,
            self.reference_speed,
        ];
        self.link
            .iter()
            .chain(&self.rereads_after)
            .chain(roles.iter().flatten())
            .any(|p| p.pnu.get() == pnu)
    }

    /// Whether this catalogue says anything of parameter number `pnu`: an entry, a guard, or
    /// one of the profile's roles (the link, the commissioning and access-level parameters,
    /// the reset, the copy to ROM, the end of quick commissioning, the reference, the
    /// monitoring, the command source). A drive's own description of such a number is never
    /// taken in its place.
    pub fn knows(&self, pnu: u16) -> bool {
        self.param(pnu).is_some() || self.guarded_or_role(pnu)
    }

    /// Why parameter number `pnu`, where a drive describes it but its own family's catalogue
    /// does not list it, is still not a setting to save and write from that description: under
    /// the same number another family's catalogue of these Siemens lists has a command (a
    /// factory reset, a motor identification: MM4 P1910 = 1 starts one, and a G120's p1910
    /// is the same selection), a guarded parameter or a role. The numbers of MICROMASTER 4
    /// and SINAMICS lists mean the same for these (P0010, P0970, P0971, P1910, P3900), so
    /// such a number is left to the catalogue and to a deliberate write. `None`: no catalogue
    /// says anything of it.
    pub fn not_from_description(pnu: u16) -> Option<String> {
        // A plain setting of another family is only that: the drive's description of it holds.
        let objects = |c: &&Self| {
            c.knows(pnu)
                && c.param(pnu)
                    .is_none_or(|p| p.action || !p.is_setting() || c.guarded_or_role(pnu))
        };
        PROFILES.iter().find(objects).map(|c| {
            let id = c.notation(ParamRef {
                prefix: Prefix::P,
                pnu: uss_protocol::Pnu::from_u16(pnu),
                index: None,
            });
            let what = match c.param(pnu) {
                Some(p) if p.action => "a command",
                Some(p) if !p.is_setting() => "the drive's state, not a setting",
                _ => "a guarded parameter or one of ussd's own",
            };
            format!(
                "{id} is {what} in the catalogue of {}: never saved or restored from a drive's \
                 description (write it deliberately)",
                c.family
            )
        })
    }

    /// Fault `number` as the family's manuals write it: F0072 (MM4), F01910 (SINAMICS).
    pub fn fault_name(&self, number: u16) -> String {
        let digits = self.faults.as_ref().map_or(4, |f| f.digits);
        format!("F{number:0w$}", w = usize::from(digits))
    }

    /// What a drive of this family says to set its telegram-off time: "P2014[0]", and the
    /// fault its expiry records where known: "P2014[0] (F0072)"; `None` when uss-rt does not
    /// know the family's parameter.
    pub fn monitoring_name(&self) -> Option<String> {
        let param = self.monitoring?;
        Some(match self.telegram_off_fault_name() {
            Some(fault) => format!("{param} ({fault})"),
            None => param.to_string(),
        })
    }

    /// The fault a telegram-off trip records, as the family's manuals write it ("F0072"),
    /// where known.
    pub fn telegram_off_fault_name(&self) -> Option<String> {
        self.telegram_off_fault.map(|f| self.fault_name(f))
    }

    /// The setting that makes a drive of this family take its commands from the USS link:
    /// "P0700 = 5"; `None` when uss-rt does not know it.
    pub fn command_source_setting(&self) -> Option<String> {
        Some(format!(
            "{} = {}",
            self.command_source?, self.command_source_uss?
        ))
    }

    /// Whether `param` (number and index) is a setting of the line ussd talks over.
    pub fn is_link(&self, param: ParamRef) -> bool {
        self.link
            .iter()
            .any(|l| l.pnu == param.pnu && l.index == param.index)
    }

    /// Why writing `value` (the raw word or double word of the task) to parameter `pnu` can
    /// take the drive away from ussd, if it can ([`Catalogue::judge_write`]).
    pub fn guard(&self, pnu: u16, value: Value) -> Option<&str> {
        self.judge_write(pnu, value).guard
    }

    /// What writing `value` (the raw word or double word of the task) to parameter `pnu` means
    /// to ussd, the parameter looked up once: whether it can be no setting at all (NaN or an
    /// infinity for a float parameter: refused, `--unsafe` or not), and why it can take the
    /// drive away from ussd, if it can. The value is compared as the parameter's type reads
    /// it: a float's -0.0 is 0, so it switches monitoring off like 0 does.
    pub fn judge_write(&self, pnu: u16, value: Value) -> WriteJudgement<'_> {
        let entry = self.param(pnu);
        // As the parameter holds it: decoded by its type where the catalogue knows it, the
        // raw number otherwise.
        let decoded = entry.map_or(f64::from(value.as_u32()), |p| {
            match p.data_type.decode(value) {
                // A subnormal float is no setting a drive keeps: it reads as 0 (flushed).
                Typed::Float(f) if f.is_subnormal() => 0.0,
                typed => typed.as_f64(),
            }
        });
        WriteJudgement {
            entry,
            impossible: entry.is_some_and(|p| {
                p.data_type == DataType::Float && !f32::from_bits(value.as_u32()).is_finite()
            }),
            guard: self
                .guard
                .iter()
                .find(|g| g.id.pnu.get() == pnu && g.covers(decoded))
                .map(|g| g.why.as_str()),
        }
    }

    /// Reads a catalogue file: every entry checked, numbers unique and sorted.
    pub fn parse(text: &str, origin: &str) -> Result<Self, CatalogueError> {
        let error = |message: String| CatalogueError {
            origin: origin.to_owned(),
            message,
        };
        let c: Self = toml::from_str(text).map_err(|e| error(e.to_string()))?;
        let sorted = |numbers: Vec<u16>, what: &str| {
            numbers
                .windows(2)
                .find(|w| w[0] >= w[1])
                .map_or(Ok(()), |w| {
                    Err(error(format!(
                        "{what} {} follows {}: keep them unique and sorted by number",
                        w[1], w[0]
                    )))
                })
        };
        sorted(c.param.iter().map(Param::number).collect(), "parameter")?;
        sorted(c.fault.iter().map(|m| m.number).collect(), "fault")?;
        sorted(c.warning.iter().map(|m| m.number).collect(), "warning")?;
        if let Some(r) = c.pzd_length
            && c.param(r.pnu.get()).and_then(|p| p.max).is_none()
        {
            return Err(error(format!(
                "pzd_length names {r}, which has no entry with a max: the most PZD words a \
                 drive of the family takes is its max"
            )));
        }
        for p in &c.param {
            let settable = p.id.prefix != Prefix::R;
            if settable != p.is_writable() {
                return Err(error(format!(
                    "{}: an r parameter is read-only and a P parameter is not",
                    p.id
                )));
            }
            if let Some(step) = p.scale
                && (step.is_nan()
                    || step <= 0.0
                    || p.data_type == DataType::Float
                    || p.bits.is_some())
            {
                return Err(error(format!(
                    "{}: scale {step}: a fixed-point parameter is a word or double word of whole \
                     steps greater than 0",
                    p.id
                )));
            }
            let within = |x: f64| p.min.is_none_or(|m| x >= m) && p.max.is_none_or(|m| x <= m);
            if let Some(x) = p.default.filter(|&x| !within(x)) {
                return Err(error(format!(
                    "{}: default {x} lies outside its limits",
                    p.id
                )));
            }
            if let Some(x) = p.values.iter().find(|&&x| !within(f64::from(x))) {
                return Err(error(format!(
                    "{}: setting {x} lies outside its limits",
                    p.id
                )));
            }
            if !p.values.is_empty()
                && (p.data_type == DataType::Float || p.values.windows(2).any(|w| w[0] >= w[1]))
            {
                return Err(error(format!(
                    "{}: settings are whole numbers, unique and sorted",
                    p.id
                )));
            }
            if !p.elements.is_empty() && p.elements.len() != usize::from(p.array) {
                return Err(error(format!(
                    "{}: {} elements named for an array of {}",
                    p.id,
                    p.elements.len(),
                    p.array
                )));
            }
        }
        Ok(c)
    }

    /// The most PZD words a drive of the family takes on the USS link ussd talks over: the
    /// maximum of its PZD length parameter; `None` where the profile names none (the protocol's
    /// 16 then).
    pub fn max_pzd(&self) -> Option<(ParamRef, usize)> {
        let r = self.pzd_length?;
        let max = self.param(r.pnu.get())?.max?;
        Some((r, max as usize))
    }

    /// The parameter with number `pnu`.
    /// `p` as the family's manuals write it ([`notation`] with [`Catalogue::param_digits`]).
    pub fn notation(&self, p: ParamRef) -> String {
        notation(p, self.param_digits)
    }

    pub fn param(&self, pnu: u16) -> Option<&Param> {
        self.param
            .binary_search_by_key(&pnu, Param::number)
            .ok()
            .map(|i| &self.param[i])
    }

    /// The text of fault `number` (F0072 -> 72).
    pub fn fault(&self, number: u16) -> Option<&str> {
        find(&self.fault, number)
    }

    /// The text of warning `number` (A0501 -> 501).
    pub fn warning(&self, number: u16) -> Option<&str> {
        find(&self.warning, number)
    }
}

fn find(list: &[Message], number: u16) -> Option<&str> {
    list.binary_search_by_key(&number, |m| m.number)
        .ok()
        .map(|i| list[i].text.as_str())
}

#[cfg(test)]
mod tests;
