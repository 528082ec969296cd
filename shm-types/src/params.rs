//! Parameter access over `uss/<bus>/params` (iceoryx2 request-response): a PROFIdrive-style
//! multi-parameter request of up to 39 items for one drive, answered by exactly one response
//! with one result per item. ussd runs each item as one PKW task (USS.md section 6): one task
//! per drive on the wire at a time, FIFO, repeated until its matching reply.

use crate::codes::{UnknownCode, code_table};
use crate::names::Address;
use crate::{LAYOUT_VERSION, check_version};
#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;
use uss_protocol::ParamTask;

/// Most items in one request (the PROFIdrive parameter-access limit for multi-parameter
/// requests).
pub const MAX_PARAM_ITEMS: usize = 39;
/// Highest subindex (USS.md section 6: the IND low byte, 0..254).
pub const MAX_SUBINDEX: u16 = 254;
/// `error_item` of a response whose error concerns no single item.
pub const NO_ITEM: u8 = u8::MAX;

code_table! {
    /// What one item asks; the `task` byte of [`ParamItem`]. The AK sent depends on `storage`
    /// (USS.md section 6, task IDs). 0 is not a task, so a zeroed item is refused.
    pub enum TaskCode {
        /// AK 1: read a value (word or dword reply).
        Read = 1 => "read",
        /// AK 2 (RAM) / 14 (RAM + EEPROM): change a word; `value` <= 0xFFFF.
        WriteWord = 2 => "write word",
        /// AK 3 (RAM) / 13 (RAM + EEPROM): change a double word.
        WriteDword = 3 => "write dword",
        /// AK 6: read the array element `index`.
        ReadArray = 4 => "read array element",
        /// AK 7 (RAM) / 12 (RAM + EEPROM): change array word `index`; `value` <= 0xFFFF.
        WriteArrayWord = 5 => "write array word",
        /// AK 8 (RAM) / 11 (RAM + EEPROM): change array double word `index`.
        WriteArrayDword = 6 => "write array dword",
        /// AK 9: read the number of array elements.
        ReadElementCount = 7 => "read element count",
        /// AK 4: read descriptive element `index`.
        ReadDescription = 8 => "read description",
    }
}

/// Where a change is stored: the codec's type; its byte is the `storage` byte of
/// [`ParamItem`].
pub use uss_protocol::Storage;

code_table! {
    /// Why ussd refused a request or an item before it reached the bus; the `error` byte of
    /// [`ParamResponse`] (whole request) and the `refusal` byte of [`ParamResult`] (one item).
    pub enum RequestError {
        Ok = 0 => "ok",
        /// No drive with this address on this bus.
        UnknownDrive = 1 => "unknown drive",
        /// `count` is outside 1..=39.
        BadCount = 2 => "bad item count",
        /// The PNU cannot be addressed. Every u16 PNU fits the page scheme of USS.md section 6,
        /// so ussd does not return this today; it is reserved for drive-family limits.
        PnuOutOfRange = 3 => "PNU out of range",
        /// The value does not fit the task: a word write with `value` > 0xFFFF, or a read with
        /// a non-zero `value`.
        ValueType = 4 => "value does not match the task",
        /// Parameter writes are disabled for this drive (`params_writable = false`).
        WritesDisabled = 5 => "writes disabled",
        /// The drive's parameter queue has no room for every item of the request: nothing of
        /// it was queued (a request runs whole or not at all); retry after results arrived.
        Busy = 6 => "the drive's parameter queue has no room for the whole request",
        /// ussd is shutting down.
        Shutdown = 7 => "shut down",
        /// The request's `version` is not [`LAYOUT_VERSION`].
        Version = 8 => "layout version mismatch",
        /// `task` is not a [`TaskCode`].
        BadTask = 9 => "unknown task code",
        /// `storage` is not a [`Storage`] code, or not RAM with a read.
        BadStorage = 10 => "unknown storage code",
        /// `index` is above 254 (USS.md section 6), or given with a task that takes none.
        BadSubindex = 11 => "subindex out of range",
        /// The drive has no parameter channel (PKW length 0, USS.md section 3).
        NoParameterChannel = 12 => "no parameter channel",
        /// A double word does not fit the drive's 3-word parameter channel (USS.md section 6).
        DwordOverThreeWords = 13 => "dword over a 3-word channel",
        /// A write to a drive that another process controls, without [`REQUEST_FORCE`]; the
        /// response's `controller_pid` names that process.
        Controlled = 14 => "drive controlled by another process",
        /// `flags` has bits this layout does not define.
        BadFlags = 15 => "unknown flags",
        /// The bus line is down; ussd reopens it.
        LineDown = 16 => "bus line down",
        /// A write of a parameter that can take the drive away from ussd (the family's
        /// catalogue marks it), without [`REQUEST_UNSAFE`]; `item` names it.
        Guarded = 17 => "guarded parameter: takes the drive away from ussd",
        /// A write to a drive without a catalogue (`family = "generic"`), or to a parameter its
        /// `writable` list does not name, without [`REQUEST_UNSAFE`]; `item` names it.
        Unlisted = 18 => "not listed as writable",
        /// A value no parameter of its type holds (NaN or an infinity for a float), refused
        /// with [`REQUEST_UNSAFE`] too; `item` names it.
        ImpossibleValue = 19 => "no value of this parameter (NaN or an infinity)",
        /// An array parameter (the family's catalogue says so) named without its element: a
        /// drive would take element 0, rarely what was meant; `item` names it.
        IndexRequired = 20 => "array parameter without an index",
        /// A write to RAM and EEPROM (task codes 11..14) to a drive whose family has no such
        /// tasks (SINAMICS G120): write to RAM, then copy RAM to ROM (p0971); `item` names it.
        NoEepromTask = 21 => "the drive stores no single value in EEPROM",
    }
}

/// `flags` bit of a [`ParamRequest`]: write even though another process controls the drive
/// (a deliberate act, e.g. `ussctl param write --force`).
pub const REQUEST_FORCE: u8 = 0x01;
/// `flags` bit of a [`ParamRequest`]: write even a parameter that can take the drive away from
/// ussd (its command or setpoint source, its COM link, its telegram monitoring off, a factory
/// reset; the family's catalogue marks them), e.g. `ussctl param write --unsafe`. Logged.
pub const REQUEST_UNSAFE: u8 = 0x02;
/// `flags` bit of a [`ParamRequest`]: its last item is not run now. It is the write that puts
/// back what the items before it raise on the way (a restore's access level P0003 and quick
/// commissioning P0010, RAM only), which ussd runs itself should the requesting process die
/// before it writes that element again: a restore killed halfway leaves no drive in quick
/// commissioning at a raised access level. The response answers the items before it.
pub const REQUEST_PUT_BACK: u8 = 0x04;
/// Every `flags` bit this layout defines.
pub const REQUEST_FLAGS: u8 = REQUEST_FORCE | REQUEST_UNSAFE | REQUEST_PUT_BACK;

code_table! {
    /// How one item ended; the `outcome` byte of [`ParamResult`]. Every item of an accepted
    /// request ends in exactly one of these.
    pub enum Outcome {
        /// Not run: the request was refused as a whole, or the slot is beyond `count`.
        NotRun = 0 => "not run",
        /// The value read or, for a change, the value the drive now holds.
        Value = 1 => "value",
        /// The number of array elements (task 9, reply 6).
        ElementCount = 2 => "element count",
        /// A descriptive element (task 4, reply 3).
        Description = 3 => "description",
        /// Reply 7: the drive refused the task; its error number is in `drive_error`.
        DriveError = 4 => "drive error",
        /// Reply 8: no PKW change rights.
        NoChangeRights = 5 => "no change rights",
        /// No matching reply within the parameter timeout.
        Timeout = 6 => "timeout",
        /// The drive was or went offline before the item completed.
        DriveOffline = 7 => "drive offline",
        /// The drive's mailbox was full.
        MailboxFull = 8 => "mailbox full",
        /// ussd stopped before the item completed.
        Shutdown = 9 => "shut down",
        /// ussd refused the item before the bus; the reason is in `refusal`.
        Refused = 10 => "refused",
        /// The bus line failed (device unplugged, I/O error) before the item completed.
        LineDown = 11 => "bus line down",
        /// The client that asked died before the item reached the wire: it was never sent.
        Cancelled = 12 => "cancelled",
    }
}

impl TaskCode {
    pub const fn is_write(self) -> bool {
        matches!(
            self,
            Self::WriteWord | Self::WriteDword | Self::WriteArrayWord | Self::WriteArrayDword
        )
    }

    /// Whether the task writes a 16-bit value.
    pub const fn writes_word(self) -> bool {
        matches!(self, Self::WriteWord | Self::WriteArrayWord)
    }
}

/// One parameter access.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssParamItemV9"))]
pub struct ParamItem {
    /// A [`TaskCode`].
    pub task: u8,
    /// A [`Storage`] code (used by writes; 0 for reads).
    pub storage: u8,
    /// Parameter number 0..=65535 (ussd applies the IND page scheme, USS.md section 6).
    pub pnu: u16,
    /// Subindex 0..=254: array index or descriptive element number; 0 otherwise.
    pub index: u16,
    pub reserved: u16,
    /// The value to write (a float as its IEEE-754 bits); 0 for reads.
    pub value: u32,
}

/// A request for up to 39 parameter accesses on one drive.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssParamRequestV9"))]
pub struct ParamRequest {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// Drive address, 0..=31.
    pub address: u8,
    /// Items in use, 1..=39.
    pub count: u8,
    /// [`REQUEST_FORCE`] or 0.
    pub flags: u8,
    pub reserved: u8,
    pub items: [ParamItem; MAX_PARAM_ITEMS],
}

/// The result of one item.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssParamResultV9"))]
pub struct ParamResult {
    /// An [`Outcome`] code.
    pub outcome: u8,
    /// 1 when `value` is a double word (reply 2 or 5), 0 for a word.
    pub value_is_dword: u8,
    /// With [`Outcome::DriveError`]: the drive's error number with reply 7 (USS.md section 6,
    /// e.g. 0 illegal PNU, 2 limit exceeded); 0 otherwise.
    pub drive_error: u16,
    /// The value (value, element count or description outcomes).
    pub value: u32,
    /// Telegrams that carried the task (more than 1 with busy replies or retries).
    pub telegrams: u32,
    /// With [`Outcome::Refused`]: a [`RequestError`] code; 0 otherwise.
    pub refusal: u8,
    pub reserved: [u8; 3],
    /// From the first telegram carrying the task to its result, ns (0 if it never reached
    /// the wire).
    pub on_wire_ns: u64,
}

/// The one response to a [`ParamRequest`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssParamResponseV9"))]
pub struct ParamResponse {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// A [`RequestError`] code: 0 when the items ran (each has its own outcome); otherwise no
    /// item ran.
    pub error: u8,
    /// The item the error is about, or [`NO_ITEM`].
    pub error_item: u8,
    /// The request's drive address.
    pub address: u8,
    /// Results in use: the request's count, 0 when refused as a whole.
    pub count: u8,
    /// With [`RequestError::Controlled`]: the controlling process; 0 otherwise.
    pub controller_pid: u32,
    pub reserved: u32,
    pub results: [ParamResult; MAX_PARAM_ITEMS],
}

/// Why a whole request was refused, and which item it is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Refusal {
    pub error: RequestError,
    pub item: Option<u8>,
}

impl Refusal {
    const fn request(error: RequestError) -> Self {
        Self { error, item: None }
    }

    const fn item(error: RequestError, index: usize) -> Self {
        Self {
            error,
            item: Some(index as u8),
        }
    }
}

impl ParamItem {
    /// An unused slot (task 0, refused if counted).
    pub const EMPTY: Self = Self {
        task: 0,
        storage: 0,
        pnu: 0,
        index: 0,
        reserved: 0,
        value: 0,
    };

    pub const fn new(task: TaskCode, pnu: u16, index: u16, value: u32, storage: Storage) -> Self {
        Self {
            task: task.code(),
            storage: storage.code(),
            pnu,
            index,
            reserved: 0,
            value,
        }
    }

    /// Reads parameter `pnu`.
    pub const fn read(pnu: u16) -> Self {
        Self::new(TaskCode::Read, pnu, 0, 0, Storage::Ram)
    }

    pub fn task(&self) -> Result<TaskCode, UnknownCode> {
        TaskCode::try_from(self.task)
    }

    pub fn storage(&self) -> Result<Storage, UnknownCode> {
        Storage::of_code(self.storage).ok_or(UnknownCode {
            table: "Storage",
            code: self.storage,
        })
    }
}

impl ParamRequest {
    /// A request for `items` on drive `address`.
    pub fn new(address: Address, items: &[ParamItem]) -> Result<Self, Refusal> {
        Self::of(address, items, |item| *item)
    }

    /// A request of `tasks`, each put in its item's place by the one conversion
    /// ([`ParamItem::from`]), with no list of items between.
    pub fn of_tasks(address: Address, tasks: &[ParamTask]) -> Result<Self, Refusal> {
        Self::of(address, tasks, |task| ParamItem::from(task))
    }

    fn of<T>(
        address: Address,
        items: &[T],
        item: impl Fn(&T) -> ParamItem,
    ) -> Result<Self, Refusal> {
        if items.is_empty() || items.len() > MAX_PARAM_ITEMS {
            return Err(Refusal::request(RequestError::BadCount));
        }
        let mut all = [ParamItem::EMPTY; MAX_PARAM_ITEMS];
        for (slot, one) in all.iter_mut().zip(items) {
            *slot = item(one);
        }
        Ok(Self {
            version: LAYOUT_VERSION,
            address: address.get(),
            count: items.len() as u8,
            flags: 0,
            reserved: 0,
            items: all,
        })
    }

    /// Whether the request says its writes are deliberate ([`REQUEST_FORCE`]).
    pub const fn is_forced(&self) -> bool {
        self.flags & REQUEST_FORCE != 0
    }

    /// Whether the request may write guarded parameters ([`REQUEST_UNSAFE`]).
    pub const fn is_unsafe(&self) -> bool {
        self.flags & REQUEST_UNSAFE != 0
    }

    /// Checks everything ussd can check without the bus configuration (version, address
    /// range, count, every item) and returns the tasks the items ask for.
    pub fn validate(&self) -> Result<(Address, Vec<ParamTask>), Refusal> {
        check_version(self.version).map_err(|_| Refusal::request(RequestError::Version))?;
        if self.flags & !REQUEST_FLAGS != 0 {
            return Err(Refusal::request(RequestError::BadFlags));
        }
        let address =
            Address::new(self.address).map_err(|_| Refusal::request(RequestError::UnknownDrive))?;
        let count = usize::from(self.count);
        if !(1..=MAX_PARAM_ITEMS).contains(&count) {
            return Err(Refusal::request(RequestError::BadCount));
        }
        let tasks: Vec<ParamTask> = self.items[..count]
            .iter()
            .enumerate()
            .map(|(i, item)| ParamTask::try_from(item).map_err(|e| Refusal::item(e, i)))
            .collect::<Result<_, _>>()?;
        // A put-back follows what it puts back, and is a write.
        if self.flags & REQUEST_PUT_BACK != 0 && (count < 2 || !tasks[count - 1].is_write()) {
            return Err(Refusal::request(RequestError::BadFlags));
        }
        Ok((address, tasks))
    }
}

impl ParamResult {
    /// A slot that did not run.
    pub const NOT_RUN: Self = Self {
        outcome: Outcome::NotRun.code(),
        value_is_dword: 0,
        drive_error: 0,
        value: 0,
        telegrams: 0,
        refusal: 0,
        reserved: [0; 3],
        on_wire_ns: 0,
    };

    pub fn outcome(&self) -> Result<Outcome, UnknownCode> {
        Outcome::try_from(self.outcome)
    }

    /// An item refused before the bus.
    pub const fn refused(error: RequestError) -> Self {
        Self {
            outcome: Outcome::Refused.code(),
            refusal: error.code(),
            ..Self::NOT_RUN
        }
    }
}

impl ParamResponse {
    /// A response with no results yet (`count` 0, error 0) for drive `address`.
    pub const fn new(address: u8) -> Self {
        Self {
            version: LAYOUT_VERSION,
            error: RequestError::Ok.code(),
            error_item: NO_ITEM,
            address,
            count: 0,
            controller_pid: 0,
            reserved: 0,
            results: [ParamResult::NOT_RUN; MAX_PARAM_ITEMS],
        }
    }

    /// The response to a request refused as a whole.
    pub const fn refused(address: u8, refusal: Refusal) -> Self {
        let mut r = Self::new(address);
        r.error = refusal.error.code();
        r.error_item = match refusal.item {
            Some(i) => i,
            None => NO_ITEM,
        };
        r
    }

    pub fn error(&self) -> Result<RequestError, UnknownCode> {
        RequestError::try_from(self.error)
    }

    /// The results in use (at most 39, whatever `count` says).
    pub fn results(&self) -> &[ParamResult] {
        &self.results[..usize::from(self.count).min(MAX_PARAM_ITEMS)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drive(a: u8) -> Address {
        Address::new(a).unwrap()
    }

    #[test]
    fn a_valid_request_yields_its_items() {
        let items = [
            ParamItem::read(1082),
            ParamItem::new(TaskCode::WriteWord, 2000, 0, 0xFFFF, Storage::RamAndEeprom),
            ParamItem::new(TaskCode::ReadArray, 2010, 254, 0, Storage::Ram),
            ParamItem::new(TaskCode::WriteDword, 1082, 0, 0x4248_0000, Storage::Ram),
        ];
        let req = ParamRequest::new(drive(3), &items).unwrap();
        let (address, got) = req.validate().unwrap();
        assert_eq!(address.get(), 3);
        let back: Vec<ParamItem> = got.iter().map(ParamItem::from).collect();
        assert_eq!(back, items);
        assert_eq!(items[1].task(), Ok(TaskCode::WriteWord));
        assert_eq!(items[1].storage(), Ok(Storage::RamAndEeprom));
    }

    #[test]
    fn a_put_back_is_a_write_after_what_it_puts_back() {
        let raise = ParamItem::new(TaskCode::WriteWord, 3, 0, 3, Storage::Ram);
        let back = ParamItem::new(TaskCode::WriteWord, 3, 0, 1, Storage::Ram);
        let with = |items: &[ParamItem]| {
            let mut r = ParamRequest::new(drive(1), items).unwrap();
            r.flags = REQUEST_PUT_BACK;
            r.validate().map(|(_, tasks)| tasks.len())
        };
        assert_eq!(with(&[raise, back]), Ok(2));
        let refused = Err(Refusal::request(RequestError::BadFlags));
        assert_eq!(with(&[raise]), refused, "nothing to put back");
        assert_eq!(
            with(&[raise, ParamItem::read(3)]),
            refused,
            "a read puts nothing back"
        );
    }

    #[test]
    fn counts_outside_1_to_39_are_refused() {
        assert_eq!(
            ParamRequest::new(drive(1), &[]),
            Err(Refusal::request(RequestError::BadCount))
        );
        assert_eq!(
            ParamRequest::new(drive(1), &[ParamItem::read(1); 40]),
            Err(Refusal::request(RequestError::BadCount))
        );
        let mut req = ParamRequest::new(drive(1), &[ParamItem::read(1); 39]).unwrap();
        assert!(req.validate().is_ok());
        req.count = 40;
        assert_eq!(
            req.validate(),
            Err(Refusal::request(RequestError::BadCount))
        );
    }

    #[test]
    fn bad_items_are_refused_naming_the_item() {
        let cases = [
            (ParamItem::EMPTY, RequestError::BadTask),
            (
                ParamItem {
                    task: 9,
                    ..ParamItem::EMPTY
                },
                RequestError::BadTask,
            ),
            (
                ParamItem {
                    storage: 2,
                    ..ParamItem::read(1)
                },
                RequestError::BadStorage,
            ),
            (
                ParamItem::new(TaskCode::ReadArray, 1, 255, 0, Storage::Ram),
                RequestError::BadSubindex,
            ),
            (
                ParamItem::new(TaskCode::WriteArrayWord, 1, 0, 0x1_0000, Storage::Ram),
                RequestError::ValueType,
            ),
            (
                ParamItem {
                    value: 1,
                    ..ParamItem::read(1)
                },
                RequestError::ValueType,
            ),
        ];
        for (bad, error) in cases {
            let req = ParamRequest::new(drive(1), &[ParamItem::read(1), bad]).unwrap();
            assert_eq!(
                req.validate(),
                Err(Refusal {
                    error,
                    item: Some(1)
                }),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn foreign_version_and_address_are_refused() {
        let mut req = ParamRequest::new(drive(1), &[ParamItem::read(1)]).unwrap();
        req.address = 32;
        assert_eq!(
            req.validate(),
            Err(Refusal::request(RequestError::UnknownDrive))
        );
        req.address = 1;
        req.flags = 0x04;
        assert_eq!(
            req.validate(),
            Err(Refusal::request(RequestError::BadFlags))
        );
        req.flags = REQUEST_FORCE;
        assert!(req.validate().is_ok() && req.is_forced() && !req.is_unsafe());
        req.flags = REQUEST_FORCE | REQUEST_UNSAFE;
        assert!(req.validate().is_ok() && req.is_unsafe());
        req.version = 0;
        assert_eq!(req.validate(), Err(Refusal::request(RequestError::Version)));
    }

    #[test]
    fn refused_response_has_no_results_and_names_the_item() {
        let r = ParamResponse::refused(4, Refusal::item(RequestError::BadSubindex, 2));
        assert_eq!(r.error(), Ok(RequestError::BadSubindex));
        assert_eq!((r.error_item, r.address, r.results().len()), (2, 4, 0));
        let r = ParamResponse::refused(4, Refusal::request(RequestError::Busy));
        assert_eq!(r.error_item, NO_ITEM);
    }

    #[test]
    fn results_are_clamped_to_39_and_refusals_carry_their_reason() {
        let mut r = ParamResponse::new(1);
        r.count = 200;
        assert_eq!(r.results().len(), MAX_PARAM_ITEMS);
        let x = ParamResult::refused(RequestError::WritesDisabled);
        assert_eq!(x.outcome(), Ok(Outcome::Refused));
        assert_eq!(
            RequestError::try_from(x.refusal),
            Ok(RequestError::WritesDisabled)
        );
    }

    #[test]
    fn code_tables_are_dense_from_their_first_code() {
        let dense = |codes: &[u8]| codes.windows(2).all(|w| w[1] == w[0] + 1);
        assert!(dense(
            &TaskCode::ALL.iter().map(|c| c.code()).collect::<Vec<_>>()
        ));
        assert!(dense(
            &Outcome::ALL.iter().map(|c| c.code()).collect::<Vec<_>>()
        ));
        assert!(dense(
            &RequestError::ALL
                .iter()
                .map(|c| c.code())
                .collect::<Vec<_>>()
        ));
        assert_eq!(TaskCode::try_from(0).map_err(|e| e.table), Err("TaskCode"));
    }
}
