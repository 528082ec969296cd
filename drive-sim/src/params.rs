//! The parameter table of the simulated drive on the parameter channel (USS.md section 6).
//!
//! A [`ParamSet`] is one family's list of parameters with their numbers, names, types, limits,
//! settings, factory settings and change rules, made from its family profile (`uss-catalogue`'s
//! data file, [`ParamSet::of_profile`]) once, before any drive runs, for every family with a
//! profile ([`crate::family::param_set`]). The simulator adds only what makes the unit (its firmware
//! version) and the parameters its table consults that the profile does not name ([`Own`]). [`ParamTable`] holds a RAM and an EEPROM value for every
//! element of every parameter of its set and executes PKW tasks against them. Storage is sized
//! at compile time ([`MAX_SLOTS`]), so the table never touches
//! the heap: [`ParamTable::execute`], [`ParamTable::get`], [`ParamTable::get_f32`] and
//! [`ParamTable::set_internal`] are safe to call from a real-time thread.
//!
//! A change task is checked in this order, and the first failing check answers:
//!
//! 1. existence: an unknown PNU is error 0;
//! 2. addressing: an array task on a plain parameter is error 4, an index beyond the array error 3
//!    (AK 2/3/13/14 on an array change element 0, as AK 1 reads it);
//! 3. read-only (`r` parameters): error 1;
//! 4. change rights: P0927 bit 3 (USS on COM link) clear gives reply 8, "no PKW change rights"
//!    (a family whose set names no change-rights parameter skips this);
//! 5. access level: a parameter above the level in P0003 is error 204 (likewise skipped without
//!    an access-level parameter);
//! 6. data type: a word for a dword type or the other way round is error 5;
//! 7. channel width: a dword over a 3-word channel is error 102;
//! 8. operating state: a "not while running" parameter while running, or a commissioning
//!    parameter outside its P0010 setting, is error 17;
//! 9. value: a NaN float is error 104, a value outside min..max error 2, a value not in the
//!    parameter's list of settings error 104.
//!
//! Read tasks (AK 1, 4, 6, 9) run steps 1, 2 and 7 only: reading needs no change rights and no
//! access level. Every refused task leaves the table as it was.

use uss_protocol::{ErrorNumber, ParamTask, PkwMode, Pnu, ReplyKind, Storage, Subindex, Value};

/// Data type of a parameter: the codec's; descriptive element 1 carries its PROFIdrive code
/// (USS.md section 6).
pub use uss_protocol::DataType;

/// How the table stores and compares values of a [`DataType`].
trait Raw {
    /// The bits a raw value of this type occupies; word types are stored zero-extended.
    fn mask(self) -> u32;
    /// A raw value as the number it stands for (exact for every type).
    fn number(self, raw: u32) -> f64;
    /// A limit as this type sees it: floats compare in single precision, integers exactly.
    fn limit(self, limit: f64) -> f64;
    /// A number encoded as a raw value of this type (saturating for integers).
    fn raw(self, number: f64) -> u32;
}

impl Raw for DataType {
    fn mask(self) -> u32 {
        if self.is_dword() { u32::MAX } else { 0xFFFF }
    }

    fn number(self, raw: u32) -> f64 {
        match self {
            Self::U16 => f64::from(raw as u16),
            Self::I16 => f64::from(raw as u16 as i16),
            Self::U32 => f64::from(raw),
            Self::I32 => f64::from(raw as i32),
            Self::Float => f64::from(f32::from_bits(raw)),
        }
    }

    fn limit(self, limit: f64) -> f64 {
        match self {
            Self::Float => f64::from(limit as f32),
            _ => limit,
        }
    }

    fn raw(self, number: f64) -> u32 {
        match self {
            Self::U16 => u32::from(number as u16),
            Self::I16 => u32::from(number as i16 as u16),
            Self::U32 => number as u32,
            Self::I32 => number as i32 as u32,
            Self::Float => (number as f32).to_bits(),
        }
    }
}

/// When a parameter may be changed (MM4 parameter lists: "C" commissioning, "U" run, "T" ready).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    /// An `r` parameter: actual values, status and diagnostics; error 1 on a change task.
    ReadOnly,
    /// "CUT": in every state.
    Always,
    /// "CT": not while the motor runs (error 17).
    NotRunning,
    /// "C": only in quick commissioning, P0010 = 1 (P0970: P0010 = 30); error 17 otherwise.
    Commissioning,
}

/// One parameter of the MM4 parameter list.
#[derive(Debug, Clone, Copy)]
pub struct ParamDef {
    pub pnu: u16,
    pub name: &'static str,
    pub ty: DataType,
    /// 0 = a plain parameter; n > 0 = an array of n elements.
    pub elements: u8,
    pub min: f64,
    pub max: f64,
    /// If non-empty, only these raw values are allowed (error 104 otherwise).
    pub allowed: &'static [u32],
    /// Raw default (floats as their IEEE-754 bits), same for every element.
    pub default: u32,
    pub change: Change,
    /// User access level needed to change it (P0003: 1 standard, 2 extended, 3 expert, 4 service).
    /// For read-only parameters: the level at which the MM4 lists them.
    pub level: u8,
}

impl ParamDef {
    pub const fn is_array(&self) -> bool {
        self.elements > 0
    }

    pub const fn is_read_only(&self) -> bool {
        matches!(self.change, Change::ReadOnly)
    }

    /// Values stored for this parameter: 1 for a plain parameter.
    pub(crate) const fn slots(&self) -> usize {
        if self.elements == 0 {
            1
        } else {
            self.elements as usize
        }
    }

    /// Whether a raw value may be stored (USS.md section 6: errors 104 and 2).
    fn check_value(&self, raw: u32) -> Result<(), ErrorNumber> {
        let number = self.ty.number(raw);
        if number.is_nan() {
            return Err(ErrorNumber::IllegalValue);
        }
        if number < self.ty.limit(self.min) || number > self.ty.limit(self.max) {
            return Err(ErrorNumber::LimitExceeded);
        }
        if !self.allowed.is_empty() && !self.allowed.contains(&raw) {
            return Err(ErrorNumber::IllegalValue);
        }
        Ok(())
    }

    #[cfg(test)]
    pub(crate) const fn new(
        pnu: u16,
        name: &'static str,
        ty: DataType,
        change: Change,
        level: u8,
    ) -> Self {
        Self {
            pnu,
            name,
            ty,
            elements: 0,
            min: 0.0,
            max: 0.0,
            allowed: &[],
            default: 0,
            change,
            level,
        }
    }

    #[cfg(test)]
    pub(crate) const fn limits(mut self, min: f64, max: f64) -> Self {
        self.min = min;
        self.max = max;
        self
    }
}

pub const R0018: u16 = 18;
pub const R0021: u16 = 21;
/// Drive state (MM4).
pub const R0002: u16 = 2;
/// DC-link voltage (MM4).
pub const R0026: u16 = 26;
/// Rated inverter voltage (MM4).
pub const R0208: u16 = 208;
pub const R0052: u16 = 52;
pub const R0054: u16 = 54;
pub const P0003: u16 = 3;
pub const P0010: u16 = 10;
pub const P0310: u16 = 310;
pub const P0700: u16 = 700;
pub const P0719: u16 = 719;
pub const P0927: u16 = 927;
pub const R0947: u16 = 947;
pub const R0948: u16 = 948;
pub const R0949: u16 = 949;
pub const P0970: u16 = 970;
pub const P0971: u16 = 971;
pub const P1000: u16 = 1000;
pub const P1058: u16 = 1058;
pub const P1080: u16 = 1080;
pub const P1082: u16 = 1082;
pub const P1120: u16 = 1120;
pub const P1121: u16 = 1121;
pub const P1135: u16 = 1135;
pub const P2000: u16 = 2000;
pub const P2010: u16 = 2010;
pub const P2011: u16 = 2011;
pub const P2012: u16 = 2012;
pub const P2013: u16 = 2013;
pub const P2014: u16 = 2014;
pub const R2024: u16 = 2024;
pub const R2025: u16 = 2025;
pub const R2026: u16 = 2026;
pub const R2027: u16 = 2027;
pub const R2028: u16 = 2028;
pub const R2029: u16 = 2029;
pub const R2030: u16 = 2030;
pub const R2031: u16 = 2031;
pub const R2110: u16 = 2110;

/// P0927 bit 3: parameters may be changed over USS on the COM link.
pub const P0927_USS_COM: u32 = 1 << 3;

/// Array index of the COM link in the USS settings P2010..P2014 and diagnostics r2024..r2031
/// (index 1 is the BOP link: MM420 Parameter List 04/02 p.84, P2012).
pub const COM_LINK: u8 = 0;

/// The whole range of a data type: the limits of a parameter whose profile gives none.
fn type_range(ty: DataType) -> (f64, f64) {
    match ty {
        DataType::U16 => (0.0, 65535.0),
        DataType::I16 => (-32768.0, 32767.0),
        DataType::U32 => (0.0, 4_294_967_295.0),
        DataType::I32 => (-2_147_483_648.0, 2_147_483_647.0),
        DataType::Float => (-f64::from(f32::MAX), f64::from(f32::MAX)),
    }
}

impl ParamDef {
    /// The definition a family profile (`uss-catalogue`) gives: number, name as the manual writes
    /// it (`P1082 Max. frequency`), type, array size, change rule, access level, limits (the
    /// type's whole range where the profile gives none), settings and factory setting. Without
    /// a factory setting in the profile the parameter starts at the value nearest 0 its limits
    /// and settings allow: the simulator's start, not a claim about the drive. Made once per
    /// family, before any drive runs (its texts live as long as the program).
    pub fn of_profile(p: &uss_catalogue::Param) -> Self {
        let ty = p.data_type;
        let (lo, hi) = type_range(ty);
        // A fixed-point parameter's limits and default are in its unit; the drive holds steps.
        let steps = |x: f64| p.scale.map_or(x, |step| (x / step).round());
        let (min, max) = (p.min.map_or(lo, steps), p.max.map_or(hi, steps));
        let allowed: &'static [u32] = Box::leak(p.values.clone().into_boxed_slice());
        let mut default = ty.raw(p.default.map_or(0.0, steps).clamp(min, max));
        if !allowed.is_empty() && !allowed.contains(&default) {
            default = allowed[0];
        }
        let change = match p.change {
            uss_catalogue::Change::ReadOnly => Change::ReadOnly,
            uss_catalogue::Change::Always => Change::Always,
            uss_catalogue::Change::NotRunning => Change::NotRunning,
            uss_catalogue::Change::Commissioning => Change::Commissioning,
        };
        Self {
            pnu: p.number(),
            name: Box::leak(format!("{} {}", p.id, p.name).into_boxed_str()),
            ty,
            // A data-set parameter is an array to the drive that has the data sets.
            elements: u8::try_from(p.array).unwrap_or(u8::MAX).max(p.data_sets),
            min,
            max,
            allowed,
            default,
            change,
            level: p.level,
        }
    }
}

/// What a family's simulated drive adds to its profile: the parameters its table consults that
/// the profile does not name (change rights, factory reset), and the values that make it this
/// unit (its firmware version).
#[derive(Debug, Clone, Copy)]
pub struct Own {
    pub change_rights: Option<(u16, u32)>,
    pub factory_reset: Option<u16>,
    /// The transfer of every setting from RAM to EEPROM (P0971).
    pub save: Option<u16>,
    /// (PNU, raw value): start values of this unit that its profile does not give.
    pub start: &'static [(u16, u32)],
}

impl ParamSet {
    /// The set a family's profile lists, with what the simulator adds (`own`). Made once per
    /// family (the sets are statics), before a drive runs.
    ///
    /// # Panics
    /// If the profile lists more than [`MAX_DEFS`] parameters or [`MAX_SLOTS`] values, or lacks
    /// a parameter the table consults (the built-in profiles are tested).
    pub fn of_profile(family: &'static str, profile: &uss_catalogue::Catalogue, own: Own) -> Self {
        let mut defs: Vec<ParamDef> = profile.param.iter().map(ParamDef::of_profile).collect();
        for &(pnu, raw) in own.start {
            if let Some(def) = defs.iter_mut().find(|d| d.pnu == pnu) {
                def.default = raw;
            }
        }
        let consulted = Consulted {
            access_level: profile.access_level.map(|p| p.pnu.get()),
            commissioning: profile.commissioning.map(|p| p.pnu.get()),
            change_rights: own.change_rights,
            factory_reset: own.factory_reset,
            save: profile.save.map(|p| p.pnu.get()).or(own.save),
            quick_end: profile.quick_commissioning.map(|p| p.pnu.get()),
            link: Vec::leak(
                profile
                    .link
                    .iter()
                    .map(|p| (p.pnu.get(), p.index.map_or(0, Subindex::get)))
                    .collect(),
            ),
            eeprom_tasks: profile.eeprom_tasks,
        };
        Self::new(family, Vec::leak(defs), consulted)
    }
}

/// Most parameters one family's set lists.
pub const MAX_DEFS: usize = 96;
/// Most values (one per plain parameter, one per array element) one family's set stores.
pub const MAX_SLOTS: usize = 512;

/// The parameters a family's table consults itself; `None` where the family has none (its
/// check is then skipped).
#[derive(Debug, Clone, Copy)]
pub struct Consulted {
    /// The user access level (P0003): a change above it is error 204.
    pub access_level: Option<u16>,
    /// The commissioning parameter (P0010): "C" parameters only at 1, the reset only at 30.
    pub commissioning: Option<u16>,
    /// Which interfaces may change parameters (P0927), and the bit of this USS link.
    pub change_rights: Option<(u16, u32)>,
    /// The factory reset (P0970): writing 1 puts every setting back to its default.
    pub factory_reset: Option<u16>,
    /// The transfer to EEPROM (P0971): writing 1 stores every setting's RAM value in EEPROM;
    /// the parameter then reads 0 again (the transfer is done).
    pub save: Option<u16>,
    /// The end of quick commissioning (P3900): 1..=3 written at P0010 = 1 ends it (see
    /// `ParamTable::end_quick_commissioning`).
    pub quick_end: Option<u16>,
    /// The settings of the link the drive answers on (its profile's `link`: baud rate,
    /// address, PZD and PKW length), as (PNU, element): kept by a reset (see
    /// `ParamTable::factory_reset`).
    pub link: &'static [(u16, u8)],
    /// Whether it takes the task codes that store one value in RAM and EEPROM (11..14); a
    /// G120 refuses them (error 106, task not implemented).
    pub eeprom_tasks: bool,
}

/// One family's parameter list, laid out once: where each parameter's values sit,
/// their defaults, and the slots of the parameters the table consults.
#[derive(Debug)]
pub struct ParamSet {
    /// The family as the simulator's `family=` names it.
    pub family: &'static str,
    defs: &'static [ParamDef],
    offsets: [usize; MAX_DEFS],
    defaults: [u32; MAX_SLOTS],
    access_level: Option<usize>,
    commissioning: Option<usize>,
    change_rights: Option<(usize, u32)>,
    factory_reset: Option<usize>,
    save: Option<usize>,
    quick_end: Option<usize>,
    link: &'static [(u16, u8)],
    eeprom_tasks: bool,
    consulted: Consulted,
}

/// The slot of a plain parameter of `defs`. A PNU missing from the list panics when the set is
/// made (each built-in set is made by the tests).
const fn slot_of(defs: &[ParamDef], offsets: &[usize; MAX_DEFS], pnu: u16) -> usize {
    let mut i = 0;
    while i < defs.len() {
        if defs[i].pnu == pnu {
            return offsets[i];
        }
        i += 1;
    }
    panic!("a parameter the table consults is missing from its set")
}

const fn slot_of_opt(
    defs: &[ParamDef],
    offsets: &[usize; MAX_DEFS],
    pnu: Option<u16>,
) -> Option<usize> {
    match pnu {
        Some(pnu) => Some(slot_of(defs, offsets, pnu)),
        None => None,
    }
}

impl ParamSet {
    /// Lays `defs` out (sorted by PNU, checked) and finds what it consults.
    pub const fn new(
        family: &'static str,
        defs: &'static [ParamDef],
        consulted: Consulted,
    ) -> Self {
        assert!(
            !defs.is_empty() && defs.len() <= MAX_DEFS,
            "a set has 1..=MAX_DEFS parameters"
        );
        let mut offsets = [0; MAX_DEFS];
        let mut i = 1;
        while i < defs.len() {
            assert!(
                defs[i - 1].pnu < defs[i].pnu,
                "a set is sorted by PNU, each once"
            );
            offsets[i] = offsets[i - 1] + defs[i - 1].slots();
            i += 1;
        }
        let slots = offsets[defs.len() - 1] + defs[defs.len() - 1].slots();
        assert!(slots <= MAX_SLOTS, "a set stores at most MAX_SLOTS values");
        let mut defaults = [0; MAX_SLOTS];
        let mut i = 0;
        while i < defs.len() {
            let mut k = 0;
            while k < defs[i].slots() {
                defaults[offsets[i] + k] = defs[i].default;
                k += 1;
            }
            i += 1;
        }
        let change_rights = match consulted.change_rights {
            Some((pnu, bit)) => Some((slot_of(defs, &offsets, pnu), bit)),
            None => None,
        };
        Self {
            family,
            defs,
            offsets,
            defaults,
            access_level: slot_of_opt(defs, &offsets, consulted.access_level),
            commissioning: slot_of_opt(defs, &offsets, consulted.commissioning),
            change_rights,
            factory_reset: slot_of_opt(defs, &offsets, consulted.factory_reset),
            save: slot_of_opt(defs, &offsets, consulted.save),
            quick_end: slot_of_opt(defs, &offsets, consulted.quick_end),
            link: consulted.link,
            eeprom_tasks: consulted.eeprom_tasks,
            consulted,
        }
    }

    /// This set with `extra` parameters besides its profile's: a drive whose own list is longer
    /// than uss-rt's catalogue of its family, as a real drive's is (uss-sim's `extra=` keys).
    /// Made once per drive kind and kept for the process.
    ///
    /// # Errors
    /// A PNU the set has already, or more than [`MAX_DEFS`] parameters or [`MAX_SLOTS`]
    /// values in all.
    pub fn with_extra(&self, extra: &[ParamDef]) -> Result<&'static Self, String> {
        let mut defs: Vec<ParamDef> = self.defs.to_vec();
        for def in extra {
            if defs.iter().any(|d| d.pnu == def.pnu) {
                return Err(format!(
                    "extra parameter {}: the {} profile has it already",
                    def.pnu, self.family
                ));
            }
            defs.push(*def);
        }
        defs.sort_by_key(|d| d.pnu);
        let slots: usize = defs.iter().map(ParamDef::slots).sum();
        if defs.len() > MAX_DEFS || slots > MAX_SLOTS {
            return Err(format!(
                "{} parameters with {slots} values in all: a simulated drive has at most \
                 {MAX_DEFS} and {MAX_SLOTS}",
                defs.len()
            ));
        }
        Ok(Box::leak(Box::new(Self::new(
            self.family,
            Vec::leak(defs),
            self.consulted,
        ))))
    }

    /// The definitions, sorted by PNU.
    pub const fn definitions(&self) -> &'static [ParamDef] {
        self.defs
    }

    /// The index of a parameter in the list.
    fn find(&self, pnu: u16) -> Option<usize> {
        self.defs.binary_search_by_key(&pnu, |d| d.pnu).ok()
    }

    /// The definition and value slot a task addresses. `index` is `None` for the plain tasks
    /// (AK 1, 2/3, 13/14), which address element 0, and the IND subindex for array tasks
    /// (USS.md section 6).
    fn locate(
        &self,
        pnu: Pnu,
        index: Option<Subindex>,
    ) -> Result<(&'static ParamDef, usize), ReplyKind> {
        let n = self
            .find(pnu.get())
            .ok_or(refuse(ErrorNumber::IllegalPnu))?;
        let def = &self.defs[n];
        let Some(index) = index else {
            return Ok((def, self.offsets[n]));
        };
        if !def.is_array() {
            return Err(refuse(ErrorNumber::NotAnArray));
        }
        if index.get() >= def.elements {
            return Err(refuse(ErrorNumber::FaultySubindex));
        }
        Ok((def, self.offsets[n] + usize::from(index.get())))
    }

    /// The definition and slot of an element, for the accessors of [`ParamTable`].
    fn slot(&self, pnu: u16, index: u8) -> Option<(&'static ParamDef, usize)> {
        let n = self.find(pnu)?;
        let def = &self.defs[n];
        (usize::from(index) < def.slots()).then(|| (def, self.offsets[n] + usize::from(index)))
    }
}

/// Two sets are the same when they are the same static.
impl PartialEq for ParamSet {
    fn eq(&self, other: &Self) -> bool {
        core::ptr::eq(self, other)
    }
}

impl Eq for ParamSet {}

/// What a MICROMASTER 4's table (and a G110's, which shares its numbers) consults besides its
/// profile's access level and commissioning parameter: P0927 bit 3, the P0970 reset.
pub(crate) const MM4_OWN: Own = Own {
    change_rights: Some((P0927, P0927_USS_COM)),
    factory_reset: Some(P0970),
    save: Some(P0971),
    start: &[],
};

/// P0010 settings: quick commissioning, factory setting.
const P0010_QUICK_COMMISSIONING: u32 = 1;
const P0010_FACTORY_SETTING: u32 = 30;

/// What the drive model tells the table about its state when a task is executed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DriveContext {
    pub running: bool,
}

/// RAM and EEPROM values of every parameter element, sized at compile time.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamTable {
    set: &'static ParamSet,
    ram: [u32; MAX_SLOTS],
    /// Only [`ParamTable::execute`] (with [`Storage::RamAndEeprom`]) and
    /// [`ParamTable::set_commissioned`] write it, and both leave read-only parameters alone, so
    /// read-only parameters always hold their defaults here.
    eeprom: [u32; MAX_SLOTS],
}

impl Default for ParamTable {
    fn default() -> Self {
        Self::new()
    }
}

fn refuse(error: ErrorNumber) -> ReplyKind {
    ReplyKind::Error(error)
}

/// A dword value needs PWE1 and PWE2: a 3-word channel is too narrow (USS.md section 6).
fn dword_fits(pkw: PkwMode) -> Result<(), ReplyKind> {
    match pkw {
        PkwMode::Three | PkwMode::None => Err(refuse(ErrorNumber::ChannelTooNarrow)),
        PkwMode::Four | PkwMode::Variable => Ok(()),
    }
}

/// The reply carrying a value of the parameter's type: `word` for U16/I16, `dword` otherwise.
fn value_reply(
    def: &ParamDef,
    raw: u32,
    pkw: PkwMode,
    word: fn(u16) -> ReplyKind,
    dword: fn(u32) -> ReplyKind,
) -> Result<ReplyKind, ReplyKind> {
    if def.ty.is_dword() {
        dword_fits(pkw)?;
        Ok(dword(raw))
    } else {
        Ok(word(raw as u16))
    }
}

/// Descriptive elements (AK 4, USS.md section 6): 1 data type, 2 elements, 4 read-only,
/// 7 lower and 8 upper limit. The limits are dwords in the parameter's own encoding (float bits,
/// or the integer zero-extended from its width), so over a 3-word channel they are error 102 even
/// for a word parameter.
fn describe(def: &ParamDef, element: Subindex, pkw: PkwMode) -> Result<ReplyKind, ReplyKind> {
    let value = match element.get() {
        1 => Value::Word(def.ty.code()),
        2 => Value::Word(u16::from(def.elements)),
        4 => Value::Word(u16::from(def.is_read_only())),
        7 => Value::Dword(def.ty.raw(def.min)),
        8 => Value::Dword(def.ty.raw(def.max)),
        _ => return Err(refuse(ErrorNumber::FaultySubindex)),
    };
    if value.is_dword() {
        dword_fits(pkw)?;
    }
    Ok(ReplyKind::Description(value))
}

impl ParamTable {
    /// A MICROMASTER 4 with factory defaults in RAM and EEPROM.
    pub fn new() -> Self {
        Self::of(crate::family::param_set(
            uss_control::DriveFamily::Micromaster4,
        ))
    }

    /// A drive of `set`'s family with factory defaults in RAM and EEPROM.
    pub const fn of(set: &'static ParamSet) -> Self {
        Self {
            set,
            ram: set.defaults,
            eeprom: set.defaults,
        }
    }

    /// The family's parameter set.
    pub const fn set(&self) -> &'static ParamSet {
        self.set
    }

    /// Executes one task and returns the reply kind the drive sends (USS.md section 6). Writes
    /// change RAM, and with [`Storage::RamAndEeprom`] also EEPROM. A refused task changes
    /// nothing; the checks run in the order the module documentation gives. A slave without a
    /// parameter channel ([`PkwMode::None`]) has no room for any reply: every task is error 102.
    /// Never panics, whatever the task.
    pub fn execute(&mut self, task: &ParamTask, pkw: PkwMode, ctx: DriveContext) -> ReplyKind {
        match self.run(task, pkw, ctx) {
            Ok(reply) | Err(reply) => reply,
        }
    }

    fn run(
        &mut self,
        task: &ParamTask,
        pkw: PkwMode,
        ctx: DriveContext,
    ) -> Result<ReplyKind, ReplyKind> {
        if pkw == PkwMode::None && *task != ParamTask::None {
            return Err(refuse(ErrorNumber::ChannelTooNarrow));
        }
        // A family without the EEPROM task codes (a G120's CU2x0-2: 0..9 only) does not know
        // them: task not implemented.
        if !self.set.eeprom_tasks
            && matches!(
                *task,
                ParamTask::Write {
                    storage: Storage::RamAndEeprom,
                    ..
                } | ParamTask::WriteArray {
                    storage: Storage::RamAndEeprom,
                    ..
                }
            )
        {
            return Err(refuse(ErrorNumber::TaskNotImplemented));
        }
        match *task {
            ParamTask::None => Ok(ReplyKind::NotYet),
            ParamTask::Read { pnu } => {
                let (def, at) = self.set.locate(pnu, None)?;
                value_reply(def, self.ram[at], pkw, ReplyKind::Word, ReplyKind::Dword)
            }
            ParamTask::ReadArray { pnu, index } => {
                let (def, at) = self.set.locate(pnu, Some(index))?;
                let raw = self.ram[at];
                value_reply(def, raw, pkw, ReplyKind::ArrayWord, ReplyKind::ArrayDword)
            }
            ParamTask::ReadArrayLen { pnu } => {
                let (def, _) = self.set.locate(pnu, None)?;
                if def.is_array() {
                    Ok(ReplyKind::ElementCount(u16::from(def.elements)))
                } else {
                    Err(refuse(ErrorNumber::NotAnArray))
                }
            }
            ParamTask::ReadDescription { pnu, element } => {
                let (def, _) = self.set.locate(pnu, None)?;
                describe(def, element, pkw)
            }
            ParamTask::Write {
                pnu,
                value,
                storage,
            } => {
                let (def, at) = self.set.locate(pnu, None)?;
                let raw = self.write(def, at, value, storage, pkw, ctx)?;
                value_reply(def, raw, pkw, ReplyKind::Word, ReplyKind::Dword)
            }
            ParamTask::WriteArray {
                pnu,
                index,
                value,
                storage,
            } => {
                let (def, at) = self.set.locate(pnu, Some(index))?;
                let raw = self.write(def, at, value, storage, pkw, ctx)?;
                value_reply(def, raw, pkw, ReplyKind::ArrayWord, ReplyKind::ArrayDword)
            }
        }
    }

    /// Checks and stores a change (steps 3-9 of the module documentation); returns the value
    /// now stored, which the positive reply echoes.
    fn write(
        &mut self,
        def: &ParamDef,
        at: usize,
        value: Value,
        storage: Storage,
        pkw: PkwMode,
        ctx: DriveContext,
    ) -> Result<u32, ReplyKind> {
        if def.is_read_only() {
            return Err(refuse(ErrorNumber::ValueNotChangeable));
        }
        if let Some((at, bit)) = self.set.change_rights
            && self.ram[at] & bit == 0
        {
            return Err(ReplyKind::NoChangeRights);
        }
        if let Some(level) = self.set.access_level
            && u32::from(def.level) > self.ram[level]
        {
            return Err(refuse(ErrorNumber::AccessLevelTooLow));
        }
        if value.is_dword() != def.ty.is_dword() {
            return Err(refuse(ErrorNumber::WrongDataType));
        }
        if value.is_dword() {
            dword_fits(pkw)?;
        }
        self.check_state(def, at, ctx)?;
        let raw = value.as_u32();
        def.check_value(raw).map_err(refuse)?;
        self.ram[at] = raw;
        if storage == Storage::RamAndEeprom {
            self.eeprom[at] = raw;
        }
        if Some(at) == self.set.factory_reset && raw == 1 {
            self.factory_reset(storage);
        }
        if Some(at) == self.set.save && raw == 1 {
            self.save_all();
            return Ok(raw);
        }
        if Some(at) == self.set.quick_end && raw != 0 {
            self.end_quick_commissioning(raw, storage);
            return Ok(raw);
        }
        Ok(self.ram[at])
    }

    /// Whether the drive's state allows the change (error 17, USS.md section 6).
    fn check_state(&self, def: &ParamDef, at: usize, ctx: DriveContext) -> Result<(), ReplyKind> {
        let allowed = match def.change {
            Change::ReadOnly => false,
            Change::Always => true,
            Change::NotRunning => !ctx.running,
            Change::Commissioning => {
                let needed = if Some(at) == self.set.factory_reset {
                    P0010_FACTORY_SETTING
                } else {
                    P0010_QUICK_COMMISSIONING
                };
                self.set
                    .commissioning
                    .is_none_or(|p0010| self.ram[p0010] == needed)
            }
        };
        if allowed {
            Ok(())
        } else {
            Err(refuse(ErrorNumber::NotInThisState))
        }
    }

    /// P0970 = 1: every changeable parameter back to its default, in RAM and, when the task
    /// stored to EEPROM, in EEPROM. That includes P0970 and P0010 themselves (both default 0).
    /// Read-only parameters are actual values and diagnostics, not settings: they are kept.
    /// So are the settings of the link the drive answers on (`Consulted::link`): a simulated
    /// drive goes on answering at its address with its telegram, and shows the settings it
    /// answers with. Whether a real drive keeps them is the simulator's choice, not a manual's:
    /// no stored page says.
    fn factory_reset(&mut self, storage: Storage) {
        self.reset_to_defaults(storage, |_| false);
    }

    /// Every changeable parameter but those `kept` back to its default, in RAM and, with
    /// `storage` RAM and EEPROM, in EEPROM; the settings of the link the drive answers on
    /// (`Consulted::link`) are kept, element by element.
    fn reset_to_defaults(&mut self, storage: Storage, kept: impl Fn(&ParamDef) -> bool) {
        let set = self.set;
        for (n, def) in set.defs.iter().enumerate() {
            if def.is_read_only() || kept(def) {
                continue;
            }
            for k in 0..def.slots() {
                let index = u8::try_from(k).unwrap_or(u8::MAX);
                if set.link.contains(&(def.pnu, index)) {
                    continue;
                }
                let at = set.offsets[n] + k;
                self.ram[at] = set.defaults[at];
                if storage == Storage::RamAndEeprom {
                    self.eeprom[at] = set.defaults[at];
                }
            }
        }
    }

    /// P3900 = 1, 2 or 3 at P0010 = 1 (MICROMASTER 440 Parameter List 6SE6400-5BB00-0BP0,
    /// P3900: it "performs the calculations ... and resets all other parameters not included
    /// in the quick commissioning to factory settings"): with 1, every changeable parameter
    /// outside quick commissioning (not "C") goes back to its default; 2 and 3 keep them (the
    /// simulator has no I/O for 2 to reset). The motor model is not calculated: the simulated
    /// drive has none. Then P0010 and P3900 read 0 again: quick commissioning is over (the
    /// reply goes out when the calculation is done).
    fn end_quick_commissioning(&mut self, end: u32, storage: Storage) {
        if end == 1 {
            self.reset_to_defaults(storage, |def| def.change == Change::Commissioning);
        }
        let set = self.set;
        for at in [set.commissioning, set.quick_end].into_iter().flatten() {
            self.ram[at] = 0;
        }
    }

    /// P0971 = 1: every changeable parameter's RAM value into EEPROM, and P0971 back to 0 (the
    /// transfer is done when the reply goes out).
    fn save_all(&mut self) {
        let set = self.set;
        for (n, def) in set.defs.iter().enumerate() {
            if def.is_read_only() {
                continue;
            }
            let range = set.offsets[n]..set.offsets[n] + def.slots();
            self.eeprom[range.clone()].copy_from_slice(&self.ram[range]);
        }
        if let Some(at) = set.save {
            self.ram[at] = set.defaults[at];
            self.eeprom[at] = set.defaults[at];
        }
    }

    /// Whether the commissioning parameter (P0010) is set: a drive being commissioned or reset
    /// does not switch on. Inferred, not reached in a stored copy of the lists: P0010 itself
    /// "can only be changed in quick commissioning "C" or ready "T" but not in operation "U""
    /// (CU240S OI Compact 04/2006 A5E00766042B AA p.2-5), and a drive whose motor data are
    /// being written has no motor model to run with.
    pub fn in_commissioning(&self) -> bool {
        self.set.commissioning.is_some_and(|at| self.ram[at] != 0)
    }

    /// Raw value of an element as stored in RAM (None for an unknown PNU or index out of range).
    /// Index 0 is the value of a plain parameter.
    pub fn get(&self, pnu: u16, index: u8) -> Option<u32> {
        self.set.slot(pnu, index).map(|(_, at)| self.ram[at])
    }

    /// An element's RAM value as a number: integer types converted, floats from their bits.
    pub fn get_f32(&self, pnu: u16, index: u8) -> Option<f32> {
        self.set
            .slot(pnu, index)
            .map(|(def, at)| def.ty.number(self.ram[at]) as f32)
    }

    /// Sets a value from inside the drive (actual values, status words, diagnostics, fault
    /// buffer), bypassing every check; ignored for an unknown PNU/index. Writes RAM only. A word
    /// type keeps the low 16 bits, so `-5i16 as u32` and `0xFFFB` store the same.
    pub fn set_internal(&mut self, pnu: u16, index: u8, raw: u32) {
        if let Some((def, at)) = self.set.slot(pnu, index) {
            self.ram[at] = raw & def.ty.mask();
        }
    }

    /// Sets a changeable parameter in RAM and EEPROM, bypassing every check: how a simulated
    /// drive leaves the factory commissioned (address, baud rate, PZD length) so that the setting
    /// survives [`ParamTable::power_cycle`]. Ignored for read-only parameters and for an unknown
    /// PNU/index; word types keep the low 16 bits.
    pub fn set_commissioned(&mut self, pnu: u16, index: u8, raw: u32) {
        match self.set.slot(pnu, index) {
            Some((def, at)) if !def.is_read_only() => {
                self.ram[at] = raw & def.ty.mask();
                self.eeprom[at] = self.ram[at];
            }
            _ => {}
        }
    }

    /// A simulated power cycle: RAM takes the EEPROM values again; read-only (r) parameters go
    /// back to their defaults (EEPROM holds exactly those for them).
    pub fn power_cycle(&mut self) {
        self.ram = self.eeprom;
    }

    /// Whether a parameter is defined.
    pub fn definition(&self, pnu: u16) -> Option<&'static ParamDef> {
        self.set.find(pnu).map(|n| &self.set.defs[n])
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // the values asserted are exactly representable
mod tests;
