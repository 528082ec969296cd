//! The parameter channel (PKW): tasks, replies, PNU paging and error numbers (USS.md section 6).
//!
//! Layout of the PKW words: `PKE` (AK in bits 12-15, SPM bit 11, PNU low part in bits 0-10),
//! `IND` (subindex in the low byte, page bits in the high byte), then one or two `PWE` words.
//! With 4 PKW words a word value sits in PWE2 (PWE1 = 0) and a dword is PWE1 high, PWE2 low; with
//! 3 words only a word fits, in PWE1. Replies are decoded by their actual length.

use crate::telegram::{MAX_PKW_WORDS, PkwMode};
use thiserror::Error;

/// A parameter number, 0..=65535. Numbers from 2000 up are carried as a page in IND.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Pnu(u16);

/// A parameter number that does not fit the PKW channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
#[error("parameter number {0} is out of range 0..=65535")]
pub struct PnuError(pub u32);

/// PNU bits carried in PKE (bits 0-10, 0..=1999).
const PNU_LOW_MASK: u16 = 0x07FF;
const PAGE_SIZE: u16 = 2000;
/// Where each bit of the page number goes in the IND high byte: page bit i -> IND bit `PAGE_BITS[i]`.
const PAGE_BITS: [u8; 6] = [7, 4, 5, 6, 2, 3];

impl Pnu {
    pub const fn new(pnu: u32) -> Result<Self, PnuError> {
        if pnu <= u16::MAX as u32 {
            Ok(Self(pnu as u16))
        } else {
            Err(PnuError(pnu))
        }
    }

    pub const fn from_u16(pnu: u16) -> Self {
        Self(pnu)
    }

    pub const fn get(self) -> u16 {
        self.0
    }

    /// The part carried in PKE: `PNU mod 2000`.
    pub const fn low(self) -> u16 {
        self.0 % PAGE_SIZE
    }

    /// The page: `PNU div 2000`.
    pub const fn page(self) -> u8 {
        (self.0 / PAGE_SIZE) as u8
    }

    /// The IND high byte for this PNU: page bits in the order of USS.md section 6.
    pub const fn ind_high(self) -> u8 {
        let page = self.page();
        let mut out = 0u8;
        let mut i = 0;
        while i < PAGE_BITS.len() {
            if page & (1 << i) != 0 {
                out |= 1 << PAGE_BITS[i];
            }
            i += 1;
        }
        out
    }

    /// Reassembles a PNU from the PKE low part and the IND high byte. Returns `None` for a PKE
    /// part of 2000..=2047 or a page beyond 65535.
    pub const fn from_parts(low: u16, ind_high: u8) -> Option<Self> {
        if low >= PAGE_SIZE {
            return None;
        }
        let mut page = 0u32;
        let mut i = 0;
        while i < PAGE_BITS.len() {
            if ind_high & (1 << PAGE_BITS[i]) != 0 {
                page |= 1 << i;
            }
            i += 1;
        }
        let pnu = page * PAGE_SIZE as u32 + low as u32;
        if pnu <= u16::MAX as u32 {
            Some(Self(pnu as u16))
        } else {
            None
        }
    }
}

impl core::fmt::Display for Pnu {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "P{}", self.0)
    }
}

/// An array index (IND low byte), 0..=254.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Subindex(u8);

impl Subindex {
    pub const MAX: u8 = 254;

    pub const fn new(index: u8) -> Result<Self, PkwError> {
        if index <= Self::MAX {
            Ok(Self(index))
        } else {
            Err(PkwError::Subindex(index))
        }
    }

    pub const fn get(self) -> u8 {
        self.0
    }
}

/// A parameter value: a word or a double word. Floats travel as the dword of their IEEE-754 bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Value {
    Word(u16),
    Dword(u32),
}

impl Value {
    /// A float as its IEEE-754 single precision bits (`50.0` -> `0x4248_0000`).
    pub fn from_f32(v: f32) -> Self {
        Self::Dword(v.to_bits())
    }

    /// The value read as a float; a word is widened first.
    pub fn as_f32(self) -> f32 {
        match self {
            Self::Word(w) => f32::from(w),
            Self::Dword(d) => f32::from_bits(d),
        }
    }

    /// The value as an unsigned 32-bit number.
    pub const fn as_u32(self) -> u32 {
        match self {
            Self::Word(w) => w as u32,
            Self::Dword(d) => d,
        }
    }

    pub const fn is_dword(self) -> bool {
        matches!(self, Self::Dword(_))
    }

    /// A raw value as a front-end's caller gives one: a double word (`dword`), or a word;
    /// `None` for a word above 0xFFFF.
    pub const fn from_raw(raw: u32, dword: bool) -> Option<Self> {
        if dword {
            Some(Self::Dword(raw))
        } else if raw <= u16::MAX as u32 {
            Some(Self::Word(raw as u16))
        } else {
            None
        }
    }
}

/// Where a change is stored (USS.md section 6: the write tasks' RAM and RAM + EEPROM codes).
/// Its byte, [`Storage::code`], is the `storage` byte of the shared-memory contract's items.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(u8)]
pub enum Storage {
    /// RAM only: lost at the next power cycle.
    #[default]
    Ram = 0,
    /// RAM and EEPROM: survives a power cycle; the drive takes longer (busy replies).
    RamAndEeprom = 1,
}

impl Storage {
    /// Both, in code order.
    pub const ALL: &[Self] = &[Self::Ram, Self::RamAndEeprom];

    /// Its byte.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The storage of byte `code`, if it is one.
    pub const fn of_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Self::Ram),
            1 => Some(Self::RamAndEeprom),
            _ => None,
        }
    }
}

impl From<Storage> for u8 {
    fn from(storage: Storage) -> Self {
        storage.code()
    }
}

/// A task the master puts into the PKW channel (USS.md section 6, task IDs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ParamTask {
    /// AK 0.
    None,
    /// AK 1: read a value.
    Read { pnu: Pnu },
    /// AK 2/3 (RAM) or 14/13 (RAM + EEPROM): change a word or dword.
    Write {
        pnu: Pnu,
        value: Value,
        storage: Storage,
    },
    /// AK 4: read a descriptive element (element number in IND).
    ReadDescription { pnu: Pnu, element: Subindex },
    /// AK 6: read an array element.
    ReadArray { pnu: Pnu, index: Subindex },
    /// AK 7/8 (RAM) or 12/11 (RAM + EEPROM): change an array word or dword.
    WriteArray {
        pnu: Pnu,
        index: Subindex,
        value: Value,
        storage: Storage,
    },
    /// AK 9: read the number of array elements.
    ReadArrayLen { pnu: Pnu },
}

/// Why PKW words could not be built or understood.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum PkwError {
    #[error("subindex {0} is out of range 0..=254")]
    Subindex(u8),
    #[error("the slave has no parameter channel (PKW mode 0)")]
    NoChannel,
    #[error("a double word does not fit a 3-word parameter channel")]
    DwordOverThreeWords,
    #[error("{0} PKW words: the parameter channel has 3 or 4")]
    Words(usize),
    #[error("task ID {0} is not supported")]
    UnsupportedTask(u8),
    #[error("PKE carries PNU part {0}, beyond 1999")]
    PnuPart(u16),
}

const fn pke(id: u8, pnu: Pnu) -> u16 {
    ((id as u16) << 12) | pnu.low()
}

const fn ind(pnu: Pnu, sub: u8) -> u16 {
    ((pnu.ind_high() as u16) << 8) | sub as u16
}

/// Writes PWE words for `value` into `out[2..]` and returns the PKW word count used.
fn put_value(
    out: &mut [u16; MAX_PKW_WORDS],
    words: usize,
    value: Option<Value>,
) -> Result<usize, PkwError> {
    match (words, value) {
        (3, None) => out[2] = 0,
        (3, Some(Value::Word(w))) => out[2] = w,
        (3, Some(Value::Dword(_))) => return Err(PkwError::DwordOverThreeWords),
        (4, None) => (out[2], out[3]) = (0, 0),
        (4, Some(Value::Word(w))) => (out[2], out[3]) = (0, w),
        (4, Some(Value::Dword(d))) => (out[2], out[3]) = ((d >> 16) as u16, d as u16),
        (n, _) => return Err(PkwError::Words(n)),
    }
    Ok(words)
}

/// Reads the PNU from PKE and IND.
fn pnu_of(words: &[u16]) -> Result<Pnu, PkwError> {
    let low = words[0] & PNU_LOW_MASK;
    Pnu::from_parts(low, (words[1] >> 8) as u8).ok_or(PkwError::PnuPart(low))
}

impl ParamTask {
    /// A read of `pnu` (AK 1), or of its array element `index` (AK 6).
    pub const fn read(pnu: Pnu, index: Option<Subindex>) -> Self {
        match index {
            None => Self::Read { pnu },
            Some(index) => Self::ReadArray { pnu, index },
        }
    }

    /// A change of `pnu` (or of its array element `index`) to `value`, a word or a double
    /// word (a float as its IEEE-754 bits), stored as `storage` says.
    pub const fn write(pnu: Pnu, index: Option<Subindex>, value: Value, storage: Storage) -> Self {
        match index {
            None => Self::Write {
                pnu,
                value,
                storage,
            },
            Some(index) => Self::WriteArray {
                pnu,
                index,
                value,
                storage,
            },
        }
    }

    /// The task ID (AK).
    pub const fn id(&self) -> u8 {
        match *self {
            Self::None => 0,
            Self::Read { .. } => 1,
            Self::Write { value, storage, .. } => match (value, storage) {
                (Value::Word(_), Storage::Ram) => 2,
                (Value::Dword(_), Storage::Ram) => 3,
                (Value::Dword(_), Storage::RamAndEeprom) => 13,
                (Value::Word(_), Storage::RamAndEeprom) => 14,
            },
            Self::ReadDescription { .. } => 4,
            Self::ReadArray { .. } => 6,
            Self::WriteArray { value, storage, .. } => match (value, storage) {
                (Value::Word(_), Storage::Ram) => 7,
                (Value::Dword(_), Storage::Ram) => 8,
                (Value::Dword(_), Storage::RamAndEeprom) => 11,
                (Value::Word(_), Storage::RamAndEeprom) => 12,
            },
            Self::ReadArrayLen { .. } => 9,
        }
    }

    /// The parameter the task addresses (`None` for AK 0).
    pub const fn pnu(&self) -> Option<Pnu> {
        match *self {
            Self::None => None,
            Self::Read { pnu }
            | Self::Write { pnu, .. }
            | Self::ReadDescription { pnu, .. }
            | Self::ReadArray { pnu, .. }
            | Self::WriteArray { pnu, .. }
            | Self::ReadArrayLen { pnu } => Some(pnu),
        }
    }

    /// The IND low byte: the array index or descriptive element, 0 otherwise.
    pub const fn subindex(&self) -> u8 {
        match *self {
            Self::ReadDescription { element: i, .. }
            | Self::ReadArray { index: i, .. }
            | Self::WriteArray { index: i, .. } => i.0,
            _ => 0,
        }
    }

    /// Whether the task changes a parameter.
    pub const fn is_write(&self) -> bool {
        matches!(self, Self::Write { .. } | Self::WriteArray { .. })
    }

    /// Encodes the task for a slave with the given PKW mode; returns how many words of `out` the
    /// request carries (3 or 4). A dword over a 3-word channel is refused here, before it reaches
    /// the wire (USS.md section 6; MICROMASTER answers error 5, section 9).
    pub fn encode(&self, mode: PkwMode, out: &mut [u16; MAX_PKW_WORDS]) -> Result<usize, PkwError> {
        let words = match mode {
            PkwMode::None => return Err(PkwError::NoChannel),
            m => m.request_words(),
        };
        let value = match *self {
            Self::Write { value, .. } | Self::WriteArray { value, .. } => Some(value),
            _ => None,
        };
        (out[0], out[1]) = match self.pnu() {
            Some(pnu) => (pke(self.id(), pnu), ind(pnu, self.subindex())),
            None => (0, 0),
        };
        put_value(out, words, value)
    }

    /// Decodes the PKW words of a request (the slave's side). The value width of a change task is
    /// given by its task ID; a dword task over 3 words is [`PkwError::DwordOverThreeWords`].
    pub fn decode(words: &[u16]) -> Result<Self, PkwError> {
        if !matches!(words.len(), 3 | 4) {
            return Err(PkwError::Words(words.len()));
        }
        let id = (words[0] >> 12) as u8;
        if id == 0 {
            return Ok(Self::None);
        }
        let pnu = pnu_of(words)?;
        let sub = Subindex::new((words[1] & 0xFF) as u8)?;
        let word = || Value::Word(words[words.len() - 1]);
        let dword = || {
            if words.len() == 4 {
                Ok(Value::Dword(
                    (u32::from(words[2]) << 16) | u32::from(words[3]),
                ))
            } else {
                Err(PkwError::DwordOverThreeWords)
            }
        };
        let write = |value, storage| Self::Write {
            pnu,
            value,
            storage,
        };
        let write_array = |value, storage| Self::WriteArray {
            pnu,
            index: sub,
            value,
            storage,
        };
        Ok(match id {
            1 => Self::Read { pnu },
            2 => write(word(), Storage::Ram),
            3 => write(dword()?, Storage::Ram),
            4 => Self::ReadDescription { pnu, element: sub },
            6 => Self::ReadArray { pnu, index: sub },
            7 => write_array(word(), Storage::Ram),
            8 => write_array(dword()?, Storage::Ram),
            9 => Self::ReadArrayLen { pnu },
            11 => write_array(dword()?, Storage::RamAndEeprom),
            12 => write_array(word(), Storage::RamAndEeprom),
            13 => write(dword()?, Storage::RamAndEeprom),
            14 => write(word(), Storage::RamAndEeprom),
            other => return Err(PkwError::UnsupportedTask(other)),
        })
    }
}

/// An error number carried by reply ID 7 "task cannot be executed" (USS.md section 6). Numbers
/// this list does not name are kept in [`ErrorNumber::Other`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ErrorNumber {
    IllegalPnu,
    ValueNotChangeable,
    LimitExceeded,
    FaultySubindex,
    NotAnArray,
    WrongDataType,
    SettingNotAllowed,
    DescriptionNotChangeable,
    NoMasterControl,
    KeywordMissing,
    NotInThisState,
    PnuDeactivated,
    ChannelTooNarrow,
    DwordOverThreeWords,
    IllegalValue,
    TaskNotImplemented,
    ModifiedMinExceeded,
    ModifiedMaxExceeded,
    AccessLevelTooLow,
    Other(u16),
}

impl ErrorNumber {
    const NAMED: [(u16, ErrorNumber); 19] = [
        (0, Self::IllegalPnu),
        (1, Self::ValueNotChangeable),
        (2, Self::LimitExceeded),
        (3, Self::FaultySubindex),
        (4, Self::NotAnArray),
        (5, Self::WrongDataType),
        (6, Self::SettingNotAllowed),
        (7, Self::DescriptionNotChangeable),
        (11, Self::NoMasterControl),
        (12, Self::KeywordMissing),
        (17, Self::NotInThisState),
        (101, Self::PnuDeactivated),
        (102, Self::ChannelTooNarrow),
        (103, Self::DwordOverThreeWords),
        (104, Self::IllegalValue),
        (106, Self::TaskNotImplemented),
        (200, Self::ModifiedMinExceeded),
        (201, Self::ModifiedMaxExceeded),
        (204, Self::AccessLevelTooLow),
    ];

    pub fn from_number(n: u16) -> Self {
        Self::NAMED
            .iter()
            .find(|(k, _)| *k == n)
            .map_or(Self::Other(n), |&(_, e)| e)
    }

    pub fn number(self) -> u16 {
        match self {
            Self::Other(n) => n,
            named => Self::NAMED
                .iter()
                .find(|(_, e)| *e == named)
                .map_or(u16::MAX, |&(k, _)| k),
        }
    }

    /// What the number means, in the words of USS.md section 6.
    pub fn description(self) -> &'static str {
        match self {
            Self::IllegalPnu => "illegal parameter number",
            Self::ValueNotChangeable => "value cannot be changed",
            Self::LimitExceeded => "limit exceeded",
            Self::FaultySubindex => "faulty subindex",
            Self::NotAnArray => "not an array",
            Self::WrongDataType => "wrong data type",
            Self::SettingNotAllowed => "setting not allowed",
            Self::DescriptionNotChangeable => "descriptive element cannot be changed",
            Self::NoMasterControl => "no master control",
            Self::KeywordMissing => "keyword missing",
            Self::NotInThisState => "not possible in this operating state",
            Self::PnuDeactivated => "parameter deactivated",
            Self::ChannelTooNarrow => "channel too narrow",
            Self::DwordOverThreeWords => "double word over a 3-word parameter channel",
            Self::IllegalValue => "illegal value",
            Self::TaskNotImplemented => "task not implemented",
            Self::ModifiedMinExceeded => "modified minimum exceeded",
            Self::ModifiedMaxExceeded => "modified maximum exceeded",
            Self::AccessLevelTooLow => "access level too low",
            Self::Other(_) => "unknown error number",
        }
    }
}

impl core::fmt::Display for ErrorNumber {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "error {}: {}", self.number(), self.description())
    }
}

/// What a reply says, by reply ID (USS.md section 6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ReplyKind {
    /// 0: no reply yet; the master resends its task.
    NotYet,
    /// 1: a word value (read or changed).
    Word(u16),
    /// 2: a dword value (read or changed).
    Dword(u32),
    /// 3: a descriptive element.
    Description(Value),
    /// 4: an array word.
    ArrayWord(u16),
    /// 5: an array dword.
    ArrayDword(u32),
    /// 6: the number of array elements.
    ElementCount(u16),
    /// 7: the task cannot be executed.
    Error(ErrorNumber),
    /// 8: no PKW change rights (no master control authority).
    NoChangeRights,
    /// 9-12: change reports (not on MM4).
    ChangeReport { id: u8, value: Value },
    /// 13-15: IDs this master does not interpret (15 is text).
    Other { id: u8, value: Value },
}

impl ReplyKind {
    /// The reply ID (AK).
    pub const fn id(&self) -> u8 {
        match *self {
            Self::NotYet => 0,
            Self::Word(_) => 1,
            Self::Dword(_) => 2,
            Self::Description(_) => 3,
            Self::ArrayWord(_) => 4,
            Self::ArrayDword(_) => 5,
            Self::ElementCount(_) => 6,
            Self::Error(_) => 7,
            Self::NoChangeRights => 8,
            Self::ChangeReport { id, .. } | Self::Other { id, .. } => id,
        }
    }

    /// The value the reply carries, if any.
    pub const fn value(&self) -> Option<Value> {
        match *self {
            Self::Word(w) | Self::ArrayWord(w) | Self::ElementCount(w) => Some(Value::Word(w)),
            Self::Dword(d) | Self::ArrayDword(d) => Some(Value::Dword(d)),
            Self::Description(v)
            | Self::ChangeReport { value: v, .. }
            | Self::Other { value: v, .. } => Some(v),
            Self::NotYet | Self::Error(_) | Self::NoChangeRights => None,
        }
    }
}

/// A reply in the PKW channel: which parameter it is about and what it says.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ParamReply {
    pub pnu: Pnu,
    /// IND low byte as the slave returned it.
    pub subindex: u8,
    pub kind: ReplyKind,
}

impl ParamReply {
    /// The reply to "no task": AK 0, PNU 0.
    pub const NOT_YET: Self = Self {
        pnu: Pnu(0),
        subindex: 0,
        kind: ReplyKind::NotYet,
    };

    /// Decodes 3 or 4 reply words. The value's width is taken from the word count: with 3 words
    /// the value is PWE1; with 4 a word is PWE2 and a dword is PWE1:PWE2. An error number is the
    /// last word either way.
    pub fn decode(words: &[u16]) -> Result<Self, PkwError> {
        if !matches!(words.len(), 3 | 4) {
            return Err(PkwError::Words(words.len()));
        }
        let id = (words[0] >> 12) as u8;
        let last = words[words.len() - 1];
        let value = if words.len() == 4 && words[2] != 0 {
            Value::Dword((u32::from(words[2]) << 16) | u32::from(last))
        } else {
            Value::Word(last)
        };
        let dword =
            (u32::from(if words.len() == 4 { words[2] } else { 0 }) << 16) | u32::from(last);
        let kind = match id {
            0 => ReplyKind::NotYet,
            1 => ReplyKind::Word(last),
            2 => ReplyKind::Dword(dword),
            3 => ReplyKind::Description(value),
            4 => ReplyKind::ArrayWord(last),
            5 => ReplyKind::ArrayDword(dword),
            6 => ReplyKind::ElementCount(last),
            7 => ReplyKind::Error(ErrorNumber::from_number(last)),
            8 => ReplyKind::NoChangeRights,
            9..=12 => ReplyKind::ChangeReport { id, value },
            _ => ReplyKind::Other { id, value },
        };
        Ok(Self {
            pnu: pnu_of(words)?,
            subindex: (words[1] & 0xFF) as u8,
            kind,
        })
    }

    /// Encodes the reply for a slave with the given PKW mode (the simulator's side); returns the
    /// number of words used. In variable mode word replies take 3 words and dword replies 4.
    pub fn encode(&self, mode: PkwMode, out: &mut [u16; MAX_PKW_WORDS]) -> Result<usize, PkwError> {
        let value = match self.kind {
            ReplyKind::Error(e) => Some(Value::Word(e.number())),
            ref k => k.value(),
        };
        let words = match (mode, value) {
            (PkwMode::None, _) => return Err(PkwError::NoChannel),
            (PkwMode::Variable, Some(Value::Dword(_))) => 4,
            (PkwMode::Variable, _) => 3,
            (m, _) => m.request_words(),
        };
        out[0] = pke(self.kind.id(), self.pnu);
        out[1] = ind(self.pnu, self.subindex);
        put_value(out, words, value)
    }

    /// Whether this reply completes `task` (USS.md section 6, handshake): the reply ID belongs to
    /// the task's family (or is a negative reply, 7 or 8), and PNU and, for array and descriptive
    /// tasks, the index match. AK 0 never completes a task: it means "busy, resend".
    ///
    /// G120/S110 handle AK 1/2/3 as 6/7/8, so the array reply IDs are accepted for plain tasks too.
    pub fn answers(&self, task: &ParamTask) -> bool {
        let Some(pnu) = task.pnu() else {
            return false;
        };
        if self.pnu != pnu {
            return false;
        }
        let index_matters = matches!(
            task,
            ParamTask::ReadArray { .. }
                | ParamTask::WriteArray { .. }
                | ParamTask::ReadDescription { .. }
        );
        if index_matters && self.subindex != task.subindex() {
            return false;
        }
        let id = self.kind.id();
        if matches!(id, 7 | 8) {
            return true;
        }
        match task {
            ParamTask::None => false,
            ParamTask::Read { .. } | ParamTask::ReadArray { .. } => matches!(id, 1 | 2 | 4 | 5),
            ParamTask::Write { value, .. } | ParamTask::WriteArray { value, .. } => {
                if value.is_dword() {
                    matches!(id, 2 | 5)
                } else {
                    matches!(id, 1 | 4)
                }
            }
            ParamTask::ReadDescription { .. } => id == 3,
            ParamTask::ReadArrayLen { .. } => id == 6,
        }
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // the values asserted are exactly representable
mod tests;
