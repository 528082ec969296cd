//! Parameter access (USS.md section 6) through ussd's `params` request-response service: one
//! request of up to 39 items for one drive, one response with one result per item. ussd runs
//! the items one PKW task at a time; PNUs from 2000 up are paged by ussd.

use crate::request::NoAnswer;
use crate::{Bus, ClientError, ParamError};
use uss_protocol::{ParamRef, ParamTask, Pnu, Storage, Subindex, Value};
use uss_shm_types::names;
use uss_shm_types::{
    Address, MAX_PARAM_ITEMS, ParamRequest, ParamResponse, ParamResult, PathError, RequestError,
};

/// How [`Bus::write_with`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WriteOptions {
    /// RAM and EEPROM (survives a power cycle) instead of RAM only.
    pub eeprom: bool,
    /// Write even while another process controls the drive.
    pub force: bool,
    /// Write even a parameter that can take the drive away from ussd (the family's catalogue
    /// marks them: command or setpoint source, COM link, telegram monitoring off, factory
    /// reset). ussd logs it; the value is read back and verified (when the read-back is answered).
    pub unsafe_write: bool,
}

impl WriteOptions {
    /// Where a write with these options is stored: RAM, or RAM and EEPROM.
    pub const fn storage(self) -> Storage {
        if self.eeprom {
            Storage::RamAndEeprom
        } else {
            Storage::Ram
        }
    }
}

/// The fault buffer: r0947, 8 elements, newest fault first (MICROMASTER).
pub const FAULT_BUFFER_PNU: u16 = 947;
/// Elements of [`FAULT_BUFFER_PNU`].
pub const FAULT_BUFFER_LEN: u8 = 8;

/// What one item delivered: a value (read or changed: the value the drive now holds), an
/// element count (as a word) or a descriptive element; or why not, in the contract's one
/// vocabulary (the drive refused, or the path failed).
pub fn item_result(result: &ParamResult) -> Result<Value, ParamError> {
    match result.outcome_of() {
        Ok(Ok(Ok(answer))) => Ok(answer.value()),
        Ok(Ok(Err(refused))) => Err(ParamError::Drive(refused)),
        Ok(Err(PathError::Refused(error))) => Err(ParamError::Refused { error, item: None }),
        Ok(Err(failed)) => Err(ParamError::Path(failed)),
        Err(e) => Err(ParamError::Unexpected(e.to_string())),
    }
}

/// The rule for a write that did not end with the drive's answer: when its task reached the
/// drive (`telegrams` > 0) and then the answer was lost (a timeout, the drive or the line
/// going down, ussd shutting down), the drive may hold the new value: that is
/// [`ParamError::MaybeApplied`], never "not done". A read, or a task that never left, stays as
/// it is.
pub fn write_outcome(
    task: &ParamTask,
    result: Result<Value, ParamError>,
    telegrams: u32,
) -> Result<Value, ParamError> {
    match result {
        Err(ParamError::Path(
            failure @ (PathError::Timeout
            | PathError::DriveOffline
            | PathError::LineDown
            | PathError::Shutdown),
        )) if task.is_write() && telegrams > 0 => {
            Err(ParamError::MaybeApplied { failure, telegrams })
        }
        other => other,
    }
}

/// The results of a whole response to a request of `count` items for drive `address`.
pub fn response_results(
    response: &ParamResponse,
    address: Address,
    count: usize,
) -> Result<Vec<Result<Value, ParamError>>, ParamError> {
    uss_shm_types::check_version(response.version).map_err(ClientError::from)?;
    match response.error() {
        Ok(RequestError::Ok) => {}
        Ok(RequestError::Controlled) => {
            return Err(ParamError::Controlled {
                address: address.get(),
                pid: response.controller_pid,
            });
        }
        Ok(error) => {
            let item = (response.error_item != uss_shm_types::params::NO_ITEM)
                .then_some(response.error_item);
            return Err(ParamError::Refused { error, item });
        }
        Err(e) => return Err(ParamError::Unexpected(e.to_string())),
    }
    if response.address != address.get() || usize::from(response.count) != count {
        return Err(ParamError::Unexpected(format!(
            "a response for drive {} with {} results to a request for drive {address} with {count} items",
            response.address, response.count
        )));
    }
    Ok(response.results().iter().map(item_result).collect())
}

impl Bus {
    /// Reads the parameter (or array element) `param` names (`P1082`, `r0947[2]`: parse the
    /// manuals' text, or [`ParamRef::new`]) from drive `address`.
    pub fn read(&self, address: Address, param: ParamRef) -> Result<Value, ParamError> {
        self.one(address, ParamTask::read(param.pnu, param.index))
    }

    /// Reads a float parameter (a double word holding IEEE-754 bits; P1082 reads 50.0).
    pub fn read_f32(&self, address: Address, param: ParamRef) -> Result<f32, ParamError> {
        self.read(address, param).map(Value::as_f32)
    }

    /// Reads a parameter as an unsigned number (a word is widened).
    pub fn read_u32(&self, address: Address, param: ParamRef) -> Result<u32, ParamError> {
        self.read(address, param).map(Value::as_u32)
    }

    /// Reads a word parameter; a double word is [`ParamError::Unexpected`].
    pub fn read_u16(&self, address: Address, param: ParamRef) -> Result<u16, ParamError> {
        match self.read(address, param)? {
            Value::Word(w) => Ok(w),
            Value::Dword(d) => Err(ParamError::Unexpected(format!(
                "{param} is a double word ({d:#010X}), not a word"
            ))),
        }
    }

    /// Changes `param` to `value` in RAM, or RAM and EEPROM with `eeprom`; returns the value
    /// the drive now holds. A float goes as [`Value::from_f32`] (`Value::from_f32(2.0)` for
    /// P1120 = 2 s). While another process controls the drive the write is refused
    /// ([`ParamError::Controlled`]); see [`Bus::write_with`] to force it.
    pub fn write(
        &self,
        address: Address,
        param: ParamRef,
        value: Value,
        eeprom: bool,
    ) -> Result<Value, ParamError> {
        let options = WriteOptions {
            eeprom,
            ..WriteOptions::default()
        };
        self.write_with(address, param, value, options)
    }

    /// [`Bus::write`] with all its options: `force` writes even while another process controls
    /// the drive (a deliberate act, e.g. during commissioning; ussd logs nothing extra, the
    /// controller is not told); `unsafe_write` writes even a parameter that can take the drive
    /// away from ussd (ussd logs it), and reads it back: a drive that holds something else is
    /// [`ParamError::Unexpected`]. A command (the catalogue's `action`: a factory reset, the end
    /// of quick commissioning) is not read back: what it reads after is its progress, not a
    /// setting.
    pub fn write_with(
        &self,
        address: Address,
        param: ParamRef,
        value: Value,
        options: WriteOptions,
    ) -> Result<Value, ParamError> {
        self.write_putting_back(address, param, value, None, options)
    }

    /// [`Bus::write_with`], leaving ussd the write `param` := `back` (when there is one: the
    /// value and where it goes, RAM or RAM and EEPROM) to run should this process die before
    /// it writes `param` again
    /// ([`uss_shm_types::REQUEST_PUT_BACK`]): a restore's access level or quick commissioning,
    /// raised on the way, is not left raised by a process killed halfway. A ussd older than
    /// the put-back refuses it: the write then goes alone, put back by this process only.
    pub(crate) fn write_putting_back(
        &self,
        address: Address,
        param: ParamRef,
        value: Value,
        back: Option<(Value, Storage)>,
        options: WriteOptions,
    ) -> Result<Value, ParamError> {
        let task = |v, storage| ParamTask::write(param.pnu, param.index, v, storage);
        let mut flags = 0;
        if options.force {
            flags |= uss_shm_types::REQUEST_FORCE;
        }
        if options.unsafe_write {
            flags |= uss_shm_types::REQUEST_UNSAFE;
        }
        let mut tasks = vec![task(value, options.storage())];
        if let Some((back, storage)) = back {
            tasks.push(task(back, storage));
            flags |= uss_shm_types::REQUEST_PUT_BACK;
        }
        let written = match self.request_answered(address, &tasks, 1, flags) {
            Err(ParamError::Refused {
                error: RequestError::BadFlags,
                ..
            }) if back.is_some() => {
                return self.write_putting_back(address, param, value, None, options);
            }
            other => other?,
        }
        .pop()
        .unwrap_or_else(|| Err(ParamError::Unexpected("no result".into())))?;
        let command = self
            .catalogue_entry(address, param.pnu)
            .is_some_and(|p| p.action);
        if options.unsafe_write && !command {
            // The drive's answer confirmed the write: a read-back that does not come back
            // (the drive went offline meanwhile) does not make it undone.
            let Ok(held) = self.read(address, param) else {
                return Ok(written);
            };
            if held != written {
                return Err(ParamError::Unexpected(format!(
                    "{param} was written as {written:?} but the drive holds {held:?}"
                )));
            }
        }
        Ok(written)
    }

    /// Reads the number of elements of array `pnu`.
    pub fn read_array_len(&self, address: Address, pnu: Pnu) -> Result<u16, ParamError> {
        self.one(address, ParamTask::ReadArrayLen { pnu })
            .map(|v| v.as_u32() as u16)
    }

    /// The drive's fault buffer r0947 (8 fault codes, newest first, 0 = empty), read in one
    /// request of 8 array reads.
    pub fn faults(&self, address: Address) -> Result<Vec<u16>, ParamError> {
        let items: Vec<_> = (0..FAULT_BUFFER_LEN)
            .filter_map(|i| Subindex::new(i).ok())
            .map(|i| ParamTask::read(Pnu::from_u16(FAULT_BUFFER_PNU), Some(i)))
            .collect();
        self.batch(address, &items)
            .into_iter()
            .map(|r| r.map(|v| v.as_u32() as u16))
            .collect()
    }

    /// Runs up to 39 tasks on drive `address` in one request, one after the other with no
    /// other client's task between them; one result per task, in order. A request runs whole
    /// or not at all: ussd refuses it as a whole when the drive's queue has no room for every
    /// task ([`uss_shm_types::RequestError::Busy`]), or for an item it cannot take (named). A
    /// failure of the request as a whole (ussd refused it, did not answer, is not running) is
    /// reported for every task.
    pub fn batch(&self, address: Address, items: &[ParamTask]) -> Vec<Result<Value, ParamError>> {
        self.batch_with(address, items, false)
    }

    /// [`Bus::batch`], its writes forced with `force` (see [`Bus::write_with`]).
    pub fn batch_with(
        &self,
        address: Address,
        items: &[ParamTask],
        force: bool,
    ) -> Vec<Result<Value, ParamError>> {
        match self.try_batch(address, items, force) {
            Ok(results) => results,
            Err(e) => vec![Err(e); items.len()],
        }
    }

    /// [`Bus::batch_with`] that tells a failure of the request as a whole (ussd refused it,
    /// did not answer, is not running: `Err`) from the items' own results (`Ok`, one per task,
    /// in order): for front-ends that report the two apart (Python's and C's batch).
    pub fn try_batch(
        &self,
        address: Address,
        items: &[ParamTask],
        force: bool,
    ) -> Result<Vec<Result<Value, ParamError>>, ParamError> {
        let flags = if force {
            uss_shm_types::REQUEST_FORCE
        } else {
            0
        };
        self.request(address, items, flags)
    }

    fn one(&self, address: Address, item: ParamTask) -> Result<Value, ParamError> {
        self.request(address, &[item], 0)?
            .pop()
            .unwrap_or_else(|| Err(ParamError::Unexpected("no result".into())))
    }

    /// Sends one request and waits for its one response.
    fn request(
        &self,
        address: Address,
        tasks: &[ParamTask],
        flags: u8,
    ) -> Result<Vec<Result<Value, ParamError>>, ParamError> {
        self.request_answered(address, tasks, tasks.len(), flags)
    }

    /// [`Bus::request`] whose response answers the first `answered` of `tasks` (the rest
    /// wait in ussd: [`uss_shm_types::REQUEST_PUT_BACK`]).
    fn request_answered(
        &self,
        address: Address,
        tasks: &[ParamTask],
        answered: usize,
        flags: u8,
    ) -> Result<Vec<Result<Value, ParamError>>, ParamError> {
        // The one conversion from the protocol's tasks to the contract's items.
        let mut request =
            ParamRequest::of_tasks(address, tasks).map_err(|r| ParamError::Refused {
                error: r.error,
                item: r.item,
            })?;
        request.flags |= flags;
        let response = self.send_request(&request)?;
        let results = match response_results(&response, address, answered) {
            // Every front-end hears it as the drive unknown, with the drives ussd serves.
            Err(ParamError::Refused {
                error: RequestError::UnknownDrive,
                ..
            }) => return Err(self.unknown_drive(address).into()),
            other => other?,
        };
        Ok(results
            .into_iter()
            .zip(tasks)
            .zip(response.results())
            .map(|((result, task), raw)| write_outcome(task, result, raw.telegrams))
            .collect())
    }

    /// Sends a request as it is (no checks on this side) and returns ussd's one response:
    /// for tools that build requests themselves. [`response_results`] reads it. Fails when
    /// ussd does not answer within the answer timeout ([`Bus::set_answer_timeout`]).
    pub fn send_request(&self, request: &ParamRequest) -> Result<ParamResponse, ParamError> {
        let services = self.link().check()?;
        let client = crate::request::client(self.link(), &services, &services.params, || {
            names::params(&services.instance)
        })?;
        let timeout = self.answer_timeout(usize::from(request.count).min(MAX_PARAM_ITEMS));
        match crate::request::round_trip(client, *request, timeout)? {
            Ok(response) => Ok(response),
            Err(NoAnswer::NotRunning) => {
                Err(ClientError::not_running(self.name().to_owned()).into())
            }
            Err(NoAnswer::Dropped) => Err(ParamError::Dropped),
            Err(NoAnswer::Timeout) => Err(ParamError::NoAnswer(timeout)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use uss_shm_types::{DriveError, Outcome, ParamItem};

    fn result(outcome: Outcome, value: u32, dword: bool) -> ParamResult {
        ParamResult {
            outcome: outcome.code(),
            value,
            value_is_dword: u8::from(dword),
            ..ParamResult::NOT_RUN
        }
    }

    #[test]
    fn tasks_go_out_as_the_items_the_contract_checks() {
        let p = Pnu::from_u16;
        let tasks = [
            ParamTask::read(p(947), Subindex::new(7).ok()),
            ParamTask::read(p(1082), None),
            ParamTask::write(p(1120), None, Value::from_f32(2.0), Storage::Ram),
            ParamTask::write(
                p(2010),
                Subindex::new(3).ok(),
                Value::Word(7),
                Storage::RamAndEeprom,
            ),
            ParamTask::ReadArrayLen { pnu: p(947) },
        ];
        for t in tasks {
            assert_eq!(ParamTask::try_from(&ParamItem::from(&t)), Ok(t));
        }
        assert_eq!(ParamItem::from(&tasks[1]), ParamItem::read(1082));
    }

    #[test]
    fn results_map_to_values_and_typed_errors() {
        assert_eq!(
            item_result(&result(Outcome::Value, 0x4248_0000, true)),
            Ok(Value::Dword(0x4248_0000))
        );
        assert_eq!(
            item_result(&result(Outcome::Value, 0x4248_0000, true)).map(Value::as_f32),
            Ok(50.0)
        );
        assert_eq!(
            item_result(&result(Outcome::Value, 6, false)),
            Ok(Value::Word(6))
        );
        assert_eq!(
            item_result(&result(Outcome::ElementCount, 8, false)),
            Ok(Value::Word(8))
        );
        let drive_error = ParamResult {
            drive_error: 2,
            ..result(Outcome::DriveError, 0, false)
        };
        assert_eq!(
            item_result(&drive_error),
            Err(ParamError::Drive(DriveError::Refused(
                uss_protocol::ErrorNumber::LimitExceeded
            )))
        );
        assert_eq!(
            item_result(&result(Outcome::NoChangeRights, 0, false)),
            Err(ParamError::Drive(DriveError::NoChangeRights))
        );
        assert_eq!(
            item_result(&result(Outcome::Timeout, 0, false)),
            Err(ParamError::Path(PathError::Timeout))
        );
        assert_eq!(
            item_result(&result(Outcome::DriveOffline, 0, false)),
            Err(ParamError::Path(PathError::DriveOffline))
        );
        assert_eq!(
            item_result(&result(Outcome::Shutdown, 0, false)),
            Err(ParamError::Path(PathError::Shutdown))
        );
        assert_eq!(
            item_result(&ParamResult::refused(RequestError::WritesDisabled)),
            Err(ParamError::Refused {
                error: RequestError::WritesDisabled,
                item: None
            })
        );
        assert!(matches!(
            item_result(&ParamResult {
                outcome: 200,
                ..ParamResult::NOT_RUN
            }),
            Err(ParamError::Unexpected(_))
        ));
    }

    #[test]
    fn refused_responses_name_the_error_and_item() {
        let r = ParamResponse::refused(
            9,
            uss_shm_types::Refusal {
                error: RequestError::UnknownDrive,
                item: None,
            },
        );
        assert_eq!(
            response_results(&r, Address::new(9).unwrap(), 1),
            Err(ParamError::Refused {
                error: RequestError::UnknownDrive,
                item: None
            })
        );
        let r = ParamResponse::refused(
            3,
            uss_shm_types::Refusal {
                error: RequestError::BadSubindex,
                item: Some(2),
            },
        );
        assert_eq!(
            response_results(&r, Address::new(3).unwrap(), 4),
            Err(ParamError::Refused {
                error: RequestError::BadSubindex,
                item: Some(2)
            })
        );
    }

    #[test]
    fn responses_for_another_request_are_unexpected() {
        let mut r = ParamResponse::new(3);
        r.count = 1;
        r.results[0] = result(Outcome::Value, 1, false);
        assert_eq!(
            response_results(&r, Address::new(3).unwrap(), 1),
            Ok(vec![Ok(Value::Word(1))])
        );
        assert!(matches!(
            response_results(&r, Address::new(4).unwrap(), 1),
            Err(ParamError::Unexpected(_))
        ));
        assert!(matches!(
            response_results(&r, Address::new(3).unwrap(), 2),
            Err(ParamError::Unexpected(_))
        ));
    }
}
