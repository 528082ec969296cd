//! The one conversion between the parameter items of the contract and the protocol's types,
//! both ways, and the one vocabulary for how an item ended, from the engine to the client API:
//! [`ItemOutcome`] = `Result<Result<Answer, DriveError>, PathError>`, keeping "the drive
//! refused" (reply 7 with its error number, reply 8) apart from "the path failed" (refused by
//! ussd, timeout, offline, cancelled, ...).
//!
//! - [`ParamTask`] <-> [`ParamItem`]: `ParamItem::from(&task)` and
//!   `ParamTask::try_from(&item)`, which is the one check of an item (task, storage, subindex,
//!   value width); a drive-specific check (PKW mode, writability) follows in the engine.
//! - [`ItemOutcome`] <-> [`ParamResult`]: [`ParamResult::of`] and [`ParamResult::outcome_of`].

use crate::codes::UnknownCode;
use crate::params::{
    MAX_SUBINDEX, Outcome, ParamItem, ParamResult, RequestError, Storage, TaskCode,
};

// The contract's index limit is the codec's: `Subindex::new` is its one check.
const _: () = assert!(MAX_SUBINDEX == Subindex::MAX as u16);
use uss_protocol::{ErrorNumber, ParamReply, ParamTask, Pnu, ReplyKind, Subindex, Value};

/// What the drive answered to a task it carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Answer {
    /// The value read or, for a change, the value the drive now holds.
    Value(Value),
    /// The number of array elements (task 9, reply 6).
    ElementCount(u16),
    /// A descriptive element (task 4, reply 3).
    Description(Value),
}

impl Answer {
    /// The answer as a value (an element count as a word).
    pub const fn value(self) -> Value {
        match self {
            Self::Value(v) | Self::Description(v) => v,
            Self::ElementCount(n) => Value::Word(n),
        }
    }

    /// What a matching reply says (USS.md section 6, reply IDs): an answer, or the drive's
    /// refusal. A value reply kind this master does not interpret counts as a drive error
    /// with the reply ID as its number.
    pub fn of_reply(reply: &ParamReply) -> Result<Self, DriveError> {
        match reply.kind {
            ReplyKind::Error(e) => Err(DriveError::Refused(e)),
            ReplyKind::NoChangeRights => Err(DriveError::NoChangeRights),
            ReplyKind::ElementCount(n) => Ok(Self::ElementCount(n)),
            ReplyKind::Description(v) => Ok(Self::Description(v)),
            other => other
                .value()
                .map(Self::Value)
                .ok_or(DriveError::Refused(ErrorNumber::Other(u16::from(
                    other.id(),
                )))),
        }
    }
}

/// The drive refused the task: it answered, and the answer is no.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
pub enum DriveError {
    /// Reply 7: the task cannot be executed, with the drive's error number.
    #[error("the drive refused the task with {0}")]
    Refused(ErrorNumber),
    /// Reply 8: no PKW change rights.
    #[error(
        "the drive grants no parameter change rights (reply 8): allow parameter changes over USS on the drive (MICROMASTER: P0927)"
    )]
    NoChangeRights,
}

/// The task did not get to the drive, or its answer did not come back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
pub enum PathError {
    /// ussd refused the item before the bus.
    #[error("ussd refused the item before the bus: {0}")]
    Refused(RequestError),
    /// No matching reply within ussd's parameter timeout.
    #[error(
        "no matching reply within ussd's parameter timeout: check the drive's PKW length (P2013); raise param_timeout_ms for slow EEPROM writes"
    )]
    Timeout,
    /// The drive was or went offline before the item completed.
    #[error("the drive is offline: check `ussctl status`, its wiring, address and baud rate")]
    DriveOffline,
    /// The drive's parameter queue in ussd was full. Not expected since a request is taken
    /// whole or refused whole ([`crate::RequestError::Busy`]); kept in the contract's codes.
    #[error("ussd's parameter queue for the drive is full: retry once earlier requests finished")]
    MailboxFull,
    /// ussd stopped before the item completed.
    #[error("ussd shut down before the task finished: retry once ussd runs again")]
    Shutdown,
    /// The bus line failed before the item completed.
    #[error(
        "the bus line went down before the task finished: ussd reopens it; check the adapter and cable (`ussctl status`), then retry"
    )]
    LineDown,
    /// The client that asked died before the item reached the wire: it was never sent.
    #[error("the task was cancelled before it reached the drive: its client process died")]
    Cancelled,
}

/// How one parameter item ended: every accepted item ends in exactly one.
pub type ItemOutcome = Result<Result<Answer, DriveError>, PathError>;

/// A [`ParamResult`] that carries no outcome.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ResultError {
    #[error("an item was not run")]
    NotRun,
    #[error(transparent)]
    Unknown(#[from] UnknownCode),
}

impl From<&ParamTask> for ParamItem {
    /// The item that asks for `task`; [`ParamTask::None`] is the empty item (refused if sent).
    fn from(task: &ParamTask) -> Self {
        let change = |array: bool, value: Value| match (array, value.is_dword()) {
            (false, false) => TaskCode::WriteWord,
            (false, true) => TaskCode::WriteDword,
            (true, false) => TaskCode::WriteArrayWord,
            (true, true) => TaskCode::WriteArrayDword,
        };
        let (code, pnu, index, value, storage) = match *task {
            ParamTask::None => return Self::EMPTY,
            ParamTask::Read { pnu } => (TaskCode::Read, pnu, 0, 0, Storage::Ram),
            ParamTask::Write {
                pnu,
                value,
                storage: s,
            } => (change(false, value), pnu, 0, value.as_u32(), s),
            ParamTask::ReadDescription { pnu, element } => {
                let index = element.get();
                (TaskCode::ReadDescription, pnu, index, 0, Storage::Ram)
            }
            ParamTask::ReadArray { pnu, index } => {
                (TaskCode::ReadArray, pnu, index.get(), 0, Storage::Ram)
            }
            ParamTask::WriteArray {
                pnu,
                index,
                value,
                storage: s,
            } => (change(true, value), pnu, index.get(), value.as_u32(), s),
            ParamTask::ReadArrayLen { pnu } => {
                (TaskCode::ReadElementCount, pnu, 0, 0, Storage::Ram)
            }
        };
        Self::new(code, pnu.get(), u16::from(index), value, storage)
    }
}

impl TryFrom<&ParamItem> for ParamTask {
    type Error = RequestError;

    /// The task an item asks for: the one check of an item on its own (known task and
    /// storage, subindex 0..=254 and only with a task that takes one, a word write's value
    /// within 16 bits, no value and RAM storage with a read).
    fn try_from(item: &ParamItem) -> Result<Self, RequestError> {
        let code = item.task().map_err(|_| RequestError::BadTask)?;
        let storage = item.storage().map_err(|_| RequestError::BadStorage)?;
        let index = u8::try_from(item.index)
            .ok()
            .and_then(|i| Subindex::new(i).ok())
            .ok_or(RequestError::BadSubindex)?;
        let pnu = Pnu::from_u16(item.pnu);
        let word = || {
            u16::try_from(item.value)
                .map(Value::Word)
                .map_err(|_| RequestError::ValueType)
        };
        let dword = Value::Dword(item.value);
        if !code.is_write() && item.value != 0 {
            return Err(RequestError::ValueType);
        }
        if !code.is_write() && item.storage != Storage::Ram.code() {
            return Err(RequestError::BadStorage);
        }
        let takes_index = matches!(
            code,
            TaskCode::ReadArray
                | TaskCode::WriteArrayWord
                | TaskCode::WriteArrayDword
                | TaskCode::ReadDescription
        );
        if !takes_index && item.index != 0 {
            return Err(RequestError::BadSubindex);
        }
        Ok(match code {
            TaskCode::Read => Self::Read { pnu },
            TaskCode::WriteWord => Self::Write {
                pnu,
                value: word()?,
                storage,
            },
            TaskCode::WriteDword => Self::Write {
                pnu,
                value: dword,
                storage,
            },
            TaskCode::ReadArray => Self::ReadArray { pnu, index },
            TaskCode::WriteArrayWord => Self::WriteArray {
                pnu,
                index,
                value: word()?,
                storage,
            },
            TaskCode::WriteArrayDword => Self::WriteArray {
                pnu,
                index,
                value: dword,
                storage,
            },
            TaskCode::ReadElementCount => Self::ReadArrayLen { pnu },
            TaskCode::ReadDescription => Self::ReadDescription {
                pnu,
                element: index,
            },
        })
    }
}

impl ParamResult {
    /// The result of an item that ended in `outcome`, carried by `telegrams` telegrams over
    /// `on_wire_ns` (0 if it never reached the wire).
    pub fn of(outcome: &ItemOutcome, telegrams: u32, on_wire_ns: u64) -> Self {
        let (code, value, drive_error, refusal) = parts(outcome);
        Self {
            outcome: code.code(),
            value_is_dword: u8::from(value.is_some_and(Value::is_dword)),
            drive_error,
            value: value.map_or(0, Value::as_u32),
            telegrams,
            refusal: refusal.code(),
            on_wire_ns,
            ..Self::NOT_RUN
        }
    }

    /// How the item ended; an item that did not run, or a code this layout does not define,
    /// is a [`ResultError`].
    pub fn outcome_of(&self) -> Result<ItemOutcome, ResultError> {
        let value = if self.value_is_dword != 0 {
            Value::Dword(self.value)
        } else {
            Value::Word(self.value as u16)
        };
        Ok(match self.outcome()? {
            Outcome::NotRun => return Err(ResultError::NotRun),
            Outcome::Value => Ok(Ok(Answer::Value(value))),
            Outcome::ElementCount => Ok(Ok(Answer::ElementCount(self.value as u16))),
            Outcome::Description => Ok(Ok(Answer::Description(value))),
            Outcome::DriveError => Ok(Err(DriveError::Refused(ErrorNumber::from_number(
                self.drive_error,
            )))),
            Outcome::NoChangeRights => Ok(Err(DriveError::NoChangeRights)),
            Outcome::Refused => Err(PathError::Refused(RequestError::try_from(self.refusal)?)),
            Outcome::Timeout => Err(PathError::Timeout),
            Outcome::DriveOffline => Err(PathError::DriveOffline),
            Outcome::MailboxFull => Err(PathError::MailboxFull),
            Outcome::Shutdown => Err(PathError::Shutdown),
            Outcome::LineDown => Err(PathError::LineDown),
            Outcome::Cancelled => Err(PathError::Cancelled),
        })
    }
}

/// An item's end in the result's terms: its outcome code, the value it carries, the drive's
/// error number and ussd's refusal.
fn parts(outcome: &ItemOutcome) -> (Outcome, Option<Value>, u16, RequestError) {
    match *outcome {
        Ok(Ok(Answer::Value(v))) => (Outcome::Value, Some(v), 0, RequestError::Ok),
        Ok(Ok(Answer::ElementCount(n))) => (
            Outcome::ElementCount,
            Some(Value::Word(n)),
            0,
            RequestError::Ok,
        ),
        Ok(Ok(Answer::Description(v))) => (Outcome::Description, Some(v), 0, RequestError::Ok),
        Ok(Err(DriveError::Refused(e))) => {
            (Outcome::DriveError, None, e.number(), RequestError::Ok)
        }
        Ok(Err(DriveError::NoChangeRights)) => (Outcome::NoChangeRights, None, 0, RequestError::Ok),
        Err(PathError::Refused(e)) => (Outcome::Refused, None, 0, e),
        Err(PathError::Timeout) => (Outcome::Timeout, None, 0, RequestError::Ok),
        Err(PathError::DriveOffline) => (Outcome::DriveOffline, None, 0, RequestError::Ok),
        Err(PathError::MailboxFull) => (Outcome::MailboxFull, None, 0, RequestError::Ok),
        Err(PathError::Shutdown) => (Outcome::Shutdown, None, 0, RequestError::Ok),
        Err(PathError::LineDown) => (Outcome::LineDown, None, 0, RequestError::Ok),
        Err(PathError::Cancelled) => (Outcome::Cancelled, None, 0, RequestError::Ok),
    }
}

impl Outcome {
    /// How an item that ended so is coded ([`ParamResult::of`] without the result around it).
    pub fn of(outcome: &ItemOutcome) -> Self {
        parts(outcome).0
    }
}
