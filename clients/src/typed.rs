//! Parameters the way a drives engineer thinks of them: named in the manuals' notation
//! (`P1082`, `r0021`, `P0947[3]`, `r0947.3`), read as their own type with their unit
//! (`P1082 = 50.00 Hz`), and written from text converted to their own type, refused before the
//! bus when it does not fit. What a parameter is comes from the catalogue (`uss-catalogue`);
//! for a parameter the catalogue does not know, the drive is asked (descriptive element 1, its
//! PROFIdrive data type; USS.md section 6) once per drive and parameter.

use crate::{Bus, ParamError, WriteOptions};
use core::fmt;
use std::collections::HashMap;
use std::sync::{Mutex, PoisonError};
use uss_catalogue::{Catalogue, DataType, Param, Typed, Values as _};
use uss_protocol::{Address, ParamRef, ParamTask, Pnu, Subindex, Value};
use uss_shm_types::DriveFamily;

/// The catalogue a [`Bus`] was given ([`Bus::with_catalogue`]; none: each drive's family's
/// own), and the data types drives described, by (address, PNU), for parameters it does not
/// know.
#[derive(Debug, Default)]
pub(crate) struct Described {
    catalogue: Option<&'static Catalogue>,
    types: Mutex<HashMap<(u8, u16), DataType>>,
}

impl Described {
    fn get(&self, address: u8, pnu: u16) -> Option<DataType> {
        self.types
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .get(&(address, pnu))
            .copied()
    }

    fn insert(&self, address: u8, pnu: u16, t: DataType) {
        self.types
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .insert((address, pnu), t);
    }
}

/// A parameter value and what it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamValue {
    /// The parameter as the catalogue writes it (`r0021`, not `P21`), with the index asked for.
    pub param: ParamRef,
    /// The word or double word the drive sent.
    pub raw: Value,
    pub data_type: DataType,
    /// The catalogue's entry; `None`: the drive described the type itself.
    pub info: Option<&'static Param>,
    /// Digits of a parameter number as the family's manuals write it: 4 (`P1082`), 3 on
    /// SIMOREG (`P303`); [`ParamValue::id`].
    pub digits: u8,
}

/// What a drive says of one of its parameters ([`Bus::drive_description`]); `None` where it
/// does not say.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Description {
    pub data_type: DataType,
    /// Its elements (descriptive element 2): 0 for a plain parameter, its data sets or array
    /// otherwise.
    pub elements: Option<u16>,
    pub read_only: Option<bool>,
    /// Its limits, in its own unit (descriptive elements 7 and 8).
    pub min: Option<f64>,
    pub max: Option<f64>,
}

impl ParamValue {
    /// The parameter as the family's manuals write it: `P1082`, `r0947[2]`; `P303` on SIMOREG.
    pub fn id(&self) -> String {
        uss_catalogue::notation(self.param, self.digits)
    }

    /// The value in its own type.
    pub fn typed(&self) -> Typed {
        self.data_type.decode(self.raw)
    }

    /// The value in its unit, as a client is given it: [`ParamValue::typed`], but a fixed-point
    /// parameter's steps as a number of its unit (SIMOREG P303's raw 1000 is 10.0 s).
    pub fn value(&self) -> uss_catalogue::Quantity {
        let typed = self.typed();
        self.info
            .map_or_else(|| uss_catalogue::Quantity::of(typed), |p| p.quantity(typed))
    }

    /// The unit (`Hz`, `s`, ...), empty when it has none or is not known.
    pub fn unit(&self) -> &'static str {
        self.info.map_or("", |p| p.unit.as_str())
    }

    /// The catalogue's name of the parameter.
    pub fn name(&self) -> Option<&'static str> {
        self.info.map(|p| p.name.as_str())
    }

    /// The value as shown: `50.00 Hz`, `5`, `0xFB31` (a status or control word).
    pub fn shown(&self) -> String {
        self.shown_typed(self.typed())
    }

    /// [`ParamValue::shown`], the value already in its own type ([`ParamValue::typed`]).
    pub fn shown_typed(&self, typed: Typed) -> String {
        match self.info {
            Some(p) => p.show_typed(self.raw, typed),
            None => typed.to_string(),
        }
    }
}

impl fmt::Display for ParamValue {
    /// `P1082 = 50.00 Hz`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} = {}", self.id(), self.shown())
    }
}

impl Bus {
    /// Consults `catalogue` for every drive of this bus, instead of each drive's family's own
    /// (`catalogue/data/<family>.toml`), generic slaves included; parameters it does not know
    /// are described by the drives.
    #[must_use]
    pub fn with_catalogue(mut self, catalogue: &'static Catalogue) -> Self {
        self.described = std::sync::Arc::new(Described {
            catalogue: Some(catalogue),
            types: Mutex::default(),
        });
        self
    }

    /// What kind of slave ussd says drive `address` is (its configured `family`); a drive
    /// ussd does not describe counts as a MICROMASTER 4 (ussd's default family), and a family
    /// code this build does not know (a newer ussd's) as generic, which assumes nothing
    /// ([`DriveFamily::of_code`]).
    pub fn family(&self, address: Address) -> DriveFamily {
        self.diag(address).map_or(DriveFamily::Micromaster4, |d| {
            DriveFamily::of_code(d.info.family)
        })
    }

    /// The catalogue that applies to a drive of `family`: the one given with
    /// [`Bus::with_catalogue`], or else the family's built-in one
    /// (`catalogue/data/<family>.toml`; a G110 shares the MICROMASTER 4's numbers; none for a
    /// `generic` slave). What a catalogue does not list, the drive describes itself.
    fn catalogue_of(&self, family: DriveFamily) -> Option<&'static Catalogue> {
        self.described.catalogue.or_else(|| Catalogue::of(family))
    }

    /// Digits of a parameter number as the manuals of drive `address`'s family write it: 4
    /// (`P1082`), 3 on SIMOREG (`P303`).
    pub fn param_digits(&self, address: Address) -> u8 {
        self.catalogue_of(self.family(address))
            .map_or(4, |c| c.param_digits)
    }

    /// `p` as the manuals of drive `address`'s family write it (`P303` on SIMOREG).
    pub fn notation(&self, address: Address, p: ParamRef) -> String {
        uss_catalogue::notation(p, self.param_digits(address))
    }

    /// What to do about a drive's refusal `e` of a write of `param` to drive `address`, in the
    /// words every front-end adds to the error's own (ussctl, Python, C, the bridge), where the
    /// number and the family's catalogue tell it; `None` for any other error. The numbers, as
    /// the MICROMASTER 4 lists them (PROFIBUS Optional Board OI 6SE6400-5AK00-0BP0, table 3-5,
    /// p. 27; the same in the CU240S/CU240E OI 03/2009, tables 5-73 and 5-81, pp. 158 and 180):
    /// 2 "minimum/maximum not reached/exceeded", 17 "request cannot be processed due to
    /// operating state", 200/201 the modified minimum/maximum, 204 "available access
    /// authorization does not cover modification of parameters" (a SINAMICS G120 gives them in
    /// hex: 0x02, 0x11, 0xC8/0xC9, 0xCC).
    pub fn refusal_hint(
        &self,
        address: Address,
        param: ParamRef,
        e: &ParamError,
    ) -> Option<String> {
        let ParamError::Drive(uss_shm_types::DriveError::Refused(number)) = e else {
            return None;
        };
        let catalogue = self.catalogue_of(self.family(address));
        let entry = catalogue.and_then(|c| c.param(param.pnu.get()));
        let id = self.notation(address, entry.map_or(param, |p| p.id));
        let limits = entry
            .filter(|p| p.min.is_some() || p.max.is_some())
            .map(|p| {
                let side = |v: Option<f64>| v.map_or_else(|| "?".to_owned(), |v| v.to_string());
                format!(
                    " (the catalogue: {}..={} {})",
                    side(p.min),
                    side(p.max),
                    p.unit
                )
            })
            .unwrap_or_default();
        let describe =
            format!("`ussctl param describe {address} {id}` asks the drive for its limits");
        match number.number() {
            2 => Some(format!(
                "the value is beyond {id}'s limits{limits}: {describe}"
            )),
            200 | 201 => Some(format!(
                "the value is beyond a limit another setting puts on {id} now (a maximum frequency \
                 bounds the minimum, ...): {describe}"
            )),
            204 => {
                let level = entry.map(|p| p.level)?;
                let raise = self.notation(address, catalogue.and_then(|c| c.access_level)?);
                Some(format!(
                    "{id} needs access level {level} ({raise} = {level}); the drive's is lower: \
                     write {raise} = {level} first (`ussctl param write {address} {raise} {level}`), \
                     and put it back after"
                ))
            }
            17 => {
                let entry = entry?;
                match entry.change {
                    uss_catalogue::Change::Commissioning => {
                        let p = self.notation(address, catalogue.and_then(|c| c.commissioning)?);
                        Some(format!(
                            "{id} can be changed in quick commissioning only ({p} = 1): \
                             `ussctl param quick-commission {address} --set {id}=VALUE --unsafe` \
                             enters it, writes and ends it"
                        ))
                    }
                    uss_catalogue::Change::NotRunning => Some(format!(
                        "{id} cannot be changed while the motor runs: stop the drive first"
                    )),
                    _ => None,
                }
            }
            _ => None,
        }
    }

    /// What parameter `pnu` of drive `address` is: the catalogue's entry, or the type the drive
    /// describes (asked once per drive and parameter). A `generic` slave is never asked: it
    /// may not know descriptions (some firmware stops answering), so this is refused.
    pub fn describe(
        &self,
        address: Address,
        pnu: Pnu,
    ) -> Result<(DataType, Option<&'static Param>), ParamError> {
        self.describe_as(address, pnu, self.family(address))
    }

    /// [`Bus::describe`] for a drive of `family`.
    fn describe_as(
        &self,
        address: Address,
        pnu: Pnu,
        family: DriveFamily,
    ) -> Result<(DataType, Option<&'static Param>), ParamError> {
        if let Some(p) = self.catalogue_of(family).and_then(|c| c.param(pnu.get())) {
            return Ok((p.data_type, Some(p)));
        }
        if family == DriveFamily::Generic {
            return Err(never_described(address, pnu));
        }
        if let Some(t) = self.described.get(address.get(), pnu.get()) {
            return Ok((t, None));
        }
        let t = self.ask_description(address, pnu)?;
        self.described.insert(address.get(), pnu.get(), t);
        Ok((t, None))
    }

    /// What drive `address` itself says parameter `pnu` is: its descriptive element 1, the
    /// PROFIdrive data type (AK 4), asked every time. A `generic` slave is not asked.
    pub fn drive_describes(&self, address: Address, pnu: Pnu) -> Result<DataType, ParamError> {
        if self.family(address) == DriveFamily::Generic {
            return Err(never_described(address, pnu));
        }
        self.ask_description(address, pnu)
    }

    /// What drive `address` says parameter `pnu` is, by the PROFIdrive descriptive elements
    /// (AK 4, USS.md section 6) in one request: 1 its data type, 2 its number of elements, 4
    /// whether it is read-only, 7 and 8 its limits (in its own type and unit: a fixed-point
    /// parameter's steps times its step, SIMOREG P303's 65000 is 650 s). An element the drive
    /// does not give (a limit over a 3-word channel is error 102) is `None`. A `generic`
    /// slave is not asked.
    ///
    /// # Errors
    /// The drive's refusal of element 1 (it does not have the parameter), or the path's.
    pub fn drive_description(&self, address: Address, pnu: Pnu) -> Result<Description, ParamError> {
        if self.family(address) == DriveFamily::Generic {
            return Err(never_described(address, pnu));
        }
        let tasks: Vec<ParamTask> = [1, 2, 4, 7, 8]
            .into_iter()
            .filter_map(|e| Subindex::new(e).ok())
            .map(|element| ParamTask::ReadDescription { pnu, element })
            .collect();
        let mut got = self.batch(address, &tasks).into_iter();
        let code = got
            .next()
            .unwrap_or_else(|| Err(ParamError::Unexpected("no result".into())))?;
        let data_type = DataType::from_code(code.as_u32() as u16).ok_or_else(|| {
            ParamError::Unexpected(format!(
                "drive {address} describes P{:04} with data type {}, which uss-rt does not read",
                pnu.get(),
                code.as_u32()
            ))
        })?;
        let mut next = || got.next().and_then(Result::ok).map(Value::as_u32);
        let elements = next().map(|n| u16::try_from(n).unwrap_or(u16::MAX));
        let read_only = next().map(|r| r != 0);
        let limit = |raw: u32| match data_type {
            DataType::Float => f64::from(f32::from_bits(raw)),
            DataType::I16 => f64::from(raw as u16 as i16),
            DataType::U16 => f64::from(raw as u16),
            DataType::I32 => f64::from(raw as i32),
            DataType::U32 => f64::from(raw),
        };
        // A fixed-point parameter's limits are steps to the drive: in its unit to a client.
        let step = self
            .catalogue_of(self.family(address))
            .and_then(|c| c.param(pnu.get()))
            .and_then(|p| p.scale)
            .unwrap_or(1.0);
        let limit = |raw: u32| limit(raw) * step;
        let (min, max) = (next().map(limit), next().map(limit));
        Ok(Description {
            data_type,
            elements,
            read_only,
            min,
            max,
        })
    }

    /// Asks the drive for descriptive element 1 of `pnu`, its data type.
    fn ask_description(&self, address: Address, pnu: Pnu) -> Result<DataType, ParamError> {
        let element = Subindex::new(1).map_err(|e| ParamError::Unexpected(e.to_string()))?;
        let task = ParamTask::ReadDescription { pnu, element };
        let code = self
            .batch(address, &[task])
            .pop()
            .unwrap_or_else(|| Err(ParamError::Unexpected("no result".into())))?;
        DataType::from_code(code.as_u32() as u16).ok_or_else(|| {
            ParamError::Unexpected(format!(
                "drive {address} describes P{:04} with data type {}, which uss-rt does not read",
                pnu.get(),
                code.as_u32()
            ))
        })
    }

    /// The type a caller names for parameter `param` of drive `address` (`ussctl --type`).
    /// Where the parameter's own type is known (its family's catalogue, or a description the
    /// drive gave this `Bus` before) that one applies, with its catalogue entry, to read with
    /// ([`Bus::read_elements_described`]) or write with ([`Bus::write_param_described`]), and a
    /// named type of another kind (a word for a float, a double word for a word) is refused
    /// ([`ParamError::Value`]): it would show or write other than what the drive holds. `None`:
    /// the type is not known here (a generic slave, a parameter no catalogue lists), so the
    /// named one applies; the drive is not asked (a caller that names the type sends one task).
    pub fn named_type(
        &self,
        address: Address,
        param: ParamRef,
        named: DataType,
    ) -> Result<Option<(DataType, Option<&'static Param>)>, ParamError> {
        let kind = |t: DataType| match t {
            DataType::I16 | DataType::U16 => "word",
            DataType::I32 | DataType::U32 => "double word",
            DataType::Float => "float",
        };
        let known = match self.catalogue_entry(address, param.pnu) {
            Some(p) => Some((p.data_type, Some(p))),
            None => self
                .described
                .get(address.get(), param.pnu.get())
                .map(|t| (t, None)),
        };
        match known {
            Some((own, info)) if kind(own) != kind(named) => Err(ParamError::Value {
                param: shown_as(param, info).to_string(),
                problem: format!(
                    "its type is {own:?} (a {}), not a {}: drop --type, it is read and written as its own",
                    kind(own),
                    kind(named)
                ),
            }),
            known => Ok(known),
        }
    }

    /// How many values [`Bus::read_elements`] gives for `param` of drive `address`: every
    /// element of an array parameter its catalogue knows, named without one; else 1.
    pub fn element_count(&self, address: Address, param: ParamRef) -> usize {
        whole_array(param, self.catalogue_entry(address, param.pnu))
            .map_or(1, |(_, count)| usize::from(count))
    }

    /// The catalogue entry for parameter `pnu` of drive `address`, where its family has one.
    pub fn catalogue_entry(&self, address: Address, pnu: Pnu) -> Option<&'static Param> {
        self.catalogue_of(self.family(address))
            .and_then(|c| c.param(pnu.get()))
    }

    /// Reads a parameter as its own type (`P1082 = 50.00 Hz`). A `generic` slave's value is
    /// typed by its reply alone: a word unsigned 16 bits, a double word unsigned 32. An array
    /// parameter is read by its element (`r0947[2]`); without one it is refused
    /// ([`ParamError::Value`], naming the elements): [`Bus::read_elements`] reads them all.
    pub fn read_param(&self, address: Address, param: ParamRef) -> Result<ParamValue, ParamError> {
        let family = self.family(address);
        if family == DriveFamily::Generic {
            return self.read_by_value(address, param);
        }
        let (data_type, info) = self.describe_as(address, param.pnu, family)?;
        self.read_described(address, param, data_type, info)
    }

    /// Reads a parameter whose type (and catalogue entry) the caller already found.
    fn read_described(
        &self,
        address: Address,
        param: ParamRef,
        data_type: DataType,
        info: Option<&'static Param>,
    ) -> Result<ParamValue, ParamError> {
        unindexed(param, info)?;
        let raw = self.read(address, param)?;
        Ok(ParamValue {
            param: shown_as(param, info),
            raw,
            data_type,
            info,
            digits: self.param_digits(address),
        })
    }

    /// Reads a parameter as its own type, every element of an array parameter named without
    /// one (up to 39 per request), or the one element or plain parameter named.
    pub fn read_elements(
        &self,
        address: Address,
        param: ParamRef,
    ) -> Result<Vec<ParamValue>, ParamError> {
        let family = self.family(address);
        if family == DriveFamily::Generic {
            return self.read_by_value(address, param).map(|v| vec![v]);
        }
        let described = self.describe_as(address, param.pnu, family)?;
        self.read_elements_described(address, param, described)
    }

    /// [`Bus::read_elements`] with the type and entry the caller found already
    /// ([`Bus::describe`], [`Bus::named_type`]): they are the ones read with, not looked up again.
    pub fn read_elements_described(
        &self,
        address: Address,
        param: ParamRef,
        (data_type, info): (DataType, Option<&'static Param>),
    ) -> Result<Vec<ParamValue>, ParamError> {
        let Some((p, count)) = whole_array(param, info) else {
            return self
                .read_described(address, param, data_type, info)
                .map(|v| vec![v]);
        };
        let whole = shown_as(param, Some(p));
        let elements: Vec<ParamRef> = (0..count)
            .map(|i| Subindex::new(i).map(|index| whole.at(index)))
            .collect::<Result<_, _>>()
            .map_err(|e| ParamError::Unexpected(e.to_string()))?;
        let mut values = Vec::with_capacity(elements.len());
        for chunk in elements.chunks(uss_shm_types::MAX_PARAM_ITEMS) {
            let tasks: Vec<ParamTask> = chunk
                .iter()
                .map(|e| ParamTask::read(e.pnu, e.index))
                .collect();
            for (&element, raw) in chunk.iter().zip(self.batch(address, &tasks)) {
                values.push(ParamValue {
                    param: element,
                    raw: raw?,
                    data_type,
                    info: Some(p),
                    digits: self.param_digits(address),
                });
            }
        }
        Ok(values)
    }

    /// A parameter read by its value alone, typed by the reply (a generic slave's).
    fn read_by_value(&self, address: Address, param: ParamRef) -> Result<ParamValue, ParamError> {
        let raw = self.read(address, param)?;
        Ok(ParamValue {
            param,
            raw,
            data_type: by_reply(raw),
            info: None,
            digits: self.param_digits(address),
        })
    }

    /// Writes `text` (`45`, `2.5`, `-3`, `0x1F`) to a parameter, converted to the parameter's
    /// own type; text that does not fit the type, or a read-only parameter, is refused before
    /// the bus ([`ParamError::Value`]). Returns the value the drive now holds.
    pub fn write_param(
        &self,
        address: Address,
        param: ParamRef,
        text: &str,
        options: WriteOptions,
    ) -> Result<ParamValue, ParamError> {
        let family = self.family(address);
        let described = if family == DriveFamily::Generic {
            // The width of what it holds now says what to write.
            (self.read_by_value(address, param)?.data_type, None)
        } else {
            self.describe_as(address, param.pnu, family)?
        };
        self.write_param_described(address, param, text, options, described)
    }

    /// [`Bus::write_param`] with the type and entry the caller found already
    /// ([`Bus::describe`], [`Bus::named_type`]): they are the ones written with.
    pub fn write_param_described(
        &self,
        address: Address,
        param: ParamRef,
        text: &str,
        options: WriteOptions,
        (data_type, info): (DataType, Option<&'static Param>),
    ) -> Result<ParamValue, ParamError> {
        let shown = shown_as(param, info);
        unindexed(param, info)?;
        if info.is_some_and(|p| !p.is_writable()) {
            return Err(ParamError::Value {
                param: self.notation(address, shown),
                problem: "read-only: a monitoring (r) parameter cannot be written".to_owned(),
            });
        }
        let value = info
            .map_or_else(|| data_type.parse(text), |p| p.parse_as(data_type, text))
            .map_err(|e| ParamError::Value {
                param: self.notation(address, shown),
                problem: e.to_string(),
            })?;
        let raw = self.write_with(address, param, value, options)?;
        Ok(ParamValue {
            param: shown,
            raw,
            data_type,
            info,
            digits: self.param_digits(address),
        })
    }
}

/// An array parameter named without its element is refused before the bus, naming its
/// elements: a drive would take element 0, rarely what was meant (ussd refuses it too).
fn unindexed(param: ParamRef, info: Option<&Param>) -> Result<(), ParamError> {
    match info {
        Some(p) if p.is_array() && param.index.is_none() => Err(ParamError::Value {
            param: p.id.to_string(),
            problem: format!(
                "an array of {} elements: name one, {}",
                p.array,
                p.elements_named()
            ),
        }),
        _ => Ok(()),
    }
}

/// Why a generic slave is not asked for a description.
fn never_described(address: Address, pnu: Pnu) -> ParamError {
    ParamError::Value {
        param: format!("P{}", pnu.get()),
        problem: format!(
            "drive {address} is a generic USS slave: uss-rt asks it for values alone, never for \
             descriptions (read the parameter: its reply says word or double word)"
        ),
    }
}

/// The type a reply's width gives a generic slave's value.
const fn by_reply(raw: Value) -> DataType {
    match raw {
        Value::Word(_) => DataType::U16,
        Value::Dword(_) => DataType::U32,
    }
}

/// `param` with the catalogue's prefix (`21` and `P0021` show as `r0021`).
fn shown_as(param: ParamRef, info: Option<&Param>) -> ParamRef {
    match info {
        Some(p) => ParamRef {
            prefix: p.id.prefix,
            ..param
        },
        None => param,
    }
}

/// When a trip happened, as r0948 holds it: three words in the format of the real-time clock
/// P2115, low byte first (seconds + minutes, hours + days, month + year). A drive stamps it
/// from the clock an operator panel set, or, with a clock never set, from its own count of
/// days and hours since power-up (month and year 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultTime {
    pub words: [u16; 3],
}

impl FaultTime {
    /// `(seconds, minutes, hours, days, month, year)`, one per byte.
    const fn fields(self) -> [u8; 6] {
        let [a, b, c] = self.words;
        [
            (a & 0xFF) as u8,
            (a >> 8) as u8,
            (b & 0xFF) as u8,
            (b >> 8) as u8,
            (c & 0xFF) as u8,
            (c >> 8) as u8,
        ]
    }
}

/// `2026-11-22 20:31:05` (a set clock: year 2000 + the year byte), `day 3 04:05:06` (a clock
/// never set), or the three words in hex when they are neither.
impl core::fmt::Display for FaultTime {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let [sec, min, hour, day, month, year] = self.fields();
        let time_ok = sec < 60 && min < 60 && hour < 24;
        if time_ok && (1..=12).contains(&month) && (1..=31).contains(&day) && year < 100 {
            let year = 2000 + u16::from(year);
            write!(f, "{year}-{month:02}-{day:02} {hour:02}:{min:02}:{sec:02}")
        } else if time_ok && month == 0 && year == 0 {
            write!(f, "day {day} {hour:02}:{min:02}:{sec:02}")
        } else {
            let [a, b, c] = self.words;
            write!(f, "{a:#06X} {b:#06X} {c:#06X}")
        }
    }
}

/// When a SINAMICS fault came: the drive's system runtime r2114 then, in days (r2130) and
/// milliseconds of the day (r0948).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Runtime {
    pub days: u16,
    pub ms: u32,
}

/// `day 3 04:05:06.789`: the runtime's day count and the time of that day.
impl core::fmt::Display for Runtime {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let ms = self.ms;
        let (h, m, s, milli) = (ms / 3_600_000, ms / 60_000 % 60, ms / 1000 % 60, ms % 1000);
        write!(f, "day {} {h:02}:{m:02}:{s:02}.{milli:03}", self.days)
    }
}

/// One recorded fault: where it sits in the fault buffer, its number, its fault value and text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fault {
    /// Element of the fault buffer (r0947 on MICROMASTER 4): 0 is the newest.
    pub slot: u8,
    /// F0072 -> 72.
    pub number: u16,
    /// The fault value (r0949) of the same element, its 32 bits as the drive sent them (a
    /// G120's is signed: `as i32`); `None` when the drive has none.
    pub value: Option<u32>,
    /// r0948 of its trip (MICROMASTER 4); `None` when the drive has no such r0948 or left
    /// it 0.
    pub time: Option<FaultTime>,
    /// The runtime it came at (SINAMICS r2130/r0948); `None` where the family has none.
    pub received: Option<Runtime>,
    /// The catalogue's text.
    pub text: Option<&'static str>,
}

/// One active warning.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Warning {
    /// A0501 -> 501.
    pub number: u16,
    pub text: Option<&'static str>,
}

impl Fault {
    /// When it came, as the drive keeps it: a MICROMASTER 4's trip time, a SINAMICS runtime.
    pub fn when(&self) -> Option<String> {
        self.time
            .map(|t| t.to_string())
            .or_else(|| self.received.map(|r| r.to_string()))
    }
}

impl FaultReport {
    /// `p` as the family's manuals write it (`r947` on SIMOREG, `r0947` on MICROMASTER 4).
    pub fn notation(&self, p: ParamRef) -> String {
        uss_catalogue::notation(p, self.param_digits)
    }
}

/// The drive's fault buffer and active warnings, read in one request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FaultReport {
    /// Where they were read: the fault codes (MM4 r0947, G120 r0945), the fault values
    /// (r0949), the warnings (MM4 r2110, G120 r2122).
    pub codes: ParamRef,
    pub values: Option<ParamRef>,
    pub warnings_from: Option<ParamRef>,
    /// Digits of a fault or warning number as the family's manuals write it: 4 (F0072), 5 on
    /// SINAMICS (F01910).
    pub digits: u8,
    /// Digits of a parameter number as the family's manuals write it (`r947` on SIMOREG):
    /// [`FaultReport::notation`].
    pub param_digits: u8,
    /// Recorded faults, newest first (empty slots left out).
    pub faults: Vec<Fault>,
    /// Active warnings; `None` when the drive (or its family) has none.
    pub warnings: Option<Vec<Warning>>,
}

impl Bus {
    /// The fault buffer with its values, the trips' times and texts, and the active warnings,
    /// in one request, where the drive's family keeps them (its catalogue's `faults`: MM4
    /// r0947/r0949/r0948/r2110, G120 r0945/r0949/r2122, SIMOREG r947/r949). A drive without
    /// the values, times or warnings (error 0) still gets its fault codes; a `generic` slave
    /// has no buffer uss-rt knows, and is refused.
    pub fn fault_report(&self, address: Address) -> Result<FaultReport, ParamError> {
        let family = self.family(address);
        let catalogue = self.catalogue_of(family);
        let Some(b) = catalogue.and_then(|c| c.faults.as_ref()) else {
            return Err(ParamError::Value {
                param: "fault buffer".to_owned(),
                problem: format!(
                    "drive {address} is a {} slave: it has no fault buffer uss-rt knows \
                     (read its own fault parameters by number)",
                    family.name()
                ),
            });
        };
        let element =
            |p: ParamRef, i: u8| Subindex::new(i).map(|i| ParamTask::read(p.pnu, Some(i)));
        let times_len = b.len / b.per_trip.max(1) * 3;
        let parts = [
            (Some(b.codes), b.len),
            (b.values, b.len),
            (b.warnings, b.warnings_len),
            (b.times, times_len),
            (b.received_ms, b.len),
            (b.received_days, b.len),
        ];
        let mut tasks = Vec::new();
        let mut counts = [0usize; 6];
        for (k, (param, n)) in parts.into_iter().enumerate() {
            if let Some(p) = param {
                let before = tasks.len();
                tasks.extend((0..n).filter_map(|i| element(p, i).ok()));
                counts[k] = tasks.len() - before;
            }
        }
        // Up to 40 elements (a G120's codes, values, alarms and two time parameters): more
        // than one request carries.
        let results: Vec<_> = tasks
            .chunks(uss_shm_types::MAX_PARAM_ITEMS)
            .flat_map(|chunk| self.batch(address, chunk))
            .collect();
        let (codes, rest) = results.split_at(counts[0].min(results.len()));
        let (values, rest) = rest.split_at(counts[1].min(rest.len()));
        let (warnings, rest) = rest.split_at(counts[2].min(rest.len()));
        let (times, rest) = rest.split_at(counts[3].min(rest.len()));
        let (received_ms, received_days) = rest.split_at(counts[4].min(rest.len()));
        let received = |slot: usize| {
            let ms = received_ms.get(slot)?.as_ref().ok()?.as_u32();
            let days = received_days.get(slot)?.as_ref().ok()?.as_u32() as u16;
            Some(Runtime { days, ms })
        };
        let word = |r: &Result<Value, ParamError>| r.clone().map(|v| v.as_u32() as u16);
        let mut faults = Vec::new();
        for (slot, code) in codes.iter().enumerate() {
            let number = word(code)?;
            if number != 0 {
                // `per_trip` faults per trip, three time words per trip.
                let trip = &times[(slot / usize::from(b.per_trip.max(1)) * 3).min(times.len())..];
                let time = trip
                    .iter()
                    .take(3)
                    .map(|r| word(r).ok())
                    .collect::<Option<Vec<u16>>>()
                    .and_then(|w| <[u16; 3]>::try_from(w).ok())
                    .filter(|w| *w != [0; 3])
                    .map(|words| FaultTime { words });
                faults.push(Fault {
                    slot: slot as u8,
                    number,
                    value: values
                        .get(slot)
                        .and_then(|r| r.as_ref().ok())
                        .map(|v| v.as_u32()),
                    time,
                    received: received(slot),
                    text: catalogue.and_then(|c| c.fault(number)),
                });
            }
        }
        let warnings = (b.warnings.is_some() && !warnings.is_empty())
            .then(|| {
                warnings
                    .iter()
                    .map(|r| word(r).ok())
                    .collect::<Option<Vec<u16>>>()
            })
            .flatten()
            .map(|numbers| {
                numbers
                    .into_iter()
                    .filter(|&n| n != 0)
                    .map(|number| Warning {
                        number,
                        text: catalogue.and_then(|c| c.warning(number)),
                    })
                    .collect()
            });
        Ok(FaultReport {
            codes: b.codes,
            values: b.values,
            warnings_from: b.warnings,
            digits: b.digits,
            param_digits: self.param_digits(address),
            faults,
            warnings,
        })
    }
}

/// `entry` and its element count (at most 255, an IND subindex) when `param` names an array
/// parameter whole: [`Bus::read_elements`] reads its every element.
fn whole_array(param: ParamRef, entry: Option<&'static Param>) -> Option<(&'static Param, u8)> {
    entry
        .filter(|p| param.index.is_none() && p.is_array())
        .map(|p| (p, u8::try_from(p.array).unwrap_or(u8::MAX)))
}

#[cfg(test)]
mod tests {
    use super::{FaultTime, Runtime};

    #[test]
    fn a_sinamics_fault_time_is_its_runtime_day_and_time_of_day() {
        let shown = |days, ms| Runtime { days, ms }.to_string();
        assert_eq!(shown(0, 0), "day 0 00:00:00.000");
        assert_eq!(shown(3, 14_706_789), "day 3 04:05:06.789");
        assert_eq!(shown(65_535, 86_399_999), "day 65535 23:59:59.999");
    }

    #[test]
    fn fault_times_show_a_set_clock_a_clock_never_set_or_their_words() {
        let shown = |words| FaultTime { words }.to_string();
        // 20:31:05 on the 22nd of November 2026.
        assert_eq!(
            shown([5 | 31 << 8, 20 | 22 << 8, 11 | 26 << 8]),
            "2026-11-22 20:31:05"
        );
        // A drive clock never set: days since power-up, no month or year.
        assert_eq!(shown([3 | 2 << 8, 1 | 4 << 8, 0]), "day 4 01:02:03");
        // Neither (e.g. a run-time counter in seconds): shown as read.
        assert_eq!(shown([0x0001, 0x5180, 0]), "0x0001 0x5180 0x0000");
        assert_eq!(shown([60, 0, 1 | 1 << 8]), "0x003C 0x0000 0x0101");
    }
}
