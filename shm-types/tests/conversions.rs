//! The contract's one conversion per boundary, both ways, as properties: a protocol task
//! survives the trip through a request item, an item's outcome through a result item, and any
//! item or result ussd accepts reads back as itself.
#![allow(clippy::unwrap_used)]

use proptest::prelude::*;
use uss_protocol::{ErrorNumber, ParamTask, Pnu, Storage, Subindex, Value};
use uss_shm_types::{
    Answer, DriveError, ItemOutcome, Outcome, ParamItem, ParamResult, PathError, RequestError,
    ResultError,
};

fn value() -> impl Strategy<Value = Value> {
    prop_oneof![
        any::<u16>().prop_map(Value::Word),
        any::<u32>().prop_map(Value::Dword)
    ]
}

fn storage() -> impl Strategy<Value = Storage> {
    prop_oneof![Just(Storage::Ram), Just(Storage::RamAndEeprom)]
}

fn task() -> impl Strategy<Value = ParamTask> {
    let pnu = any::<u16>().prop_map(Pnu::from_u16);
    let index = (0u8..=254).prop_map(|i| Subindex::new(i).unwrap());
    prop_oneof![
        pnu.clone().prop_map(|pnu| ParamTask::Read { pnu }),
        (pnu.clone(), value(), storage()).prop_map(|(pnu, value, storage)| ParamTask::Write {
            pnu,
            value,
            storage
        }),
        (pnu.clone(), index.clone())
            .prop_map(|(pnu, element)| ParamTask::ReadDescription { pnu, element }),
        (pnu.clone(), index.clone()).prop_map(|(pnu, index)| ParamTask::ReadArray { pnu, index }),
        (pnu.clone(), index, value(), storage()).prop_map(|(pnu, index, value, storage)| {
            ParamTask::WriteArray {
                pnu,
                index,
                value,
                storage,
            }
        }),
        pnu.prop_map(|pnu| ParamTask::ReadArrayLen { pnu }),
    ]
}

fn outcome() -> impl Strategy<Value = ItemOutcome> {
    let refusal = (1u8..=16).prop_map(|c| RequestError::try_from(c).unwrap());
    prop_oneof![
        value().prop_map(|v| Ok(Ok(Answer::Value(v)))),
        any::<u16>().prop_map(|n| Ok(Ok(Answer::ElementCount(n)))),
        value().prop_map(|v| Ok(Ok(Answer::Description(v)))),
        // The drive's error number is what travels: every number reads as one error.
        any::<u16>().prop_map(|n| Ok(Err(DriveError::Refused(ErrorNumber::from_number(n))))),
        Just(Ok(Err(DriveError::NoChangeRights))),
        refusal.prop_map(|e| Err(PathError::Refused(e))),
        prop_oneof![
            Just(PathError::Timeout),
            Just(PathError::DriveOffline),
            Just(PathError::MailboxFull),
            Just(PathError::Shutdown),
            Just(PathError::LineDown),
            Just(PathError::Cancelled),
        ]
        .prop_map(Err),
    ]
}

fn item() -> impl Strategy<Value = ParamItem> {
    (
        0u8..=9,
        0u8..=2,
        any::<u16>(),
        0u16..=300,
        any::<u32>(),
        any::<bool>(),
    )
        .prop_map(|(task, storage, pnu, index, value, small)| ParamItem {
            task,
            storage,
            pnu,
            index,
            reserved: 0,
            value: if small { value & 0xFFFF } else { value },
        })
}

proptest! {
    #[test]
    fn a_task_survives_the_trip_through_a_request_item(t in task()) {
        prop_assert_eq!(ParamTask::try_from(&ParamItem::from(&t)), Ok(t));
    }

    #[test]
    fn an_accepted_item_reads_back_as_the_same_task(i in item()) {
        if let Ok(t) = ParamTask::try_from(&i) {
            prop_assert_eq!(ParamItem::from(&t), i);
        }
    }

    #[test]
    fn an_outcome_survives_the_trip_through_a_result_item(
        o in outcome(),
        telegrams in any::<u32>(),
        on_wire_ns in any::<u64>(),
    ) {
        let r = ParamResult::of(&o, telegrams, on_wire_ns);
        prop_assert_eq!(r.outcome_of(), Ok(o));
        prop_assert_eq!((r.telegrams, r.on_wire_ns), (telegrams, on_wire_ns));
        // The code alone, without the result around it, is the result's.
        prop_assert_eq!(uss_shm_types::Outcome::of(&o).code(), r.outcome);
    }

    #[test]
    fn any_result_item_reads_as_an_outcome_or_says_why_not(
        outcome in any::<u8>(),
        value_is_dword in 0u8..=1,
        drive_error in any::<u16>(),
        value in any::<u32>(),
        refusal in any::<u8>(),
    ) {
        let r = ParamResult {
            outcome,
            value_is_dword,
            drive_error,
            value,
            refusal,
            ..ParamResult::NOT_RUN
        };
        match r.outcome_of() {
            Ok(o) => prop_assert_eq!(ParamResult::of(&o, 0, 0).outcome_of(), Ok(o)),
            Err(ResultError::NotRun) => prop_assert_eq!(outcome, Outcome::NotRun.code()),
            Err(ResultError::Unknown(_)) => {
                prop_assert!(Outcome::try_from(outcome).is_err() || refusal > 16);
            }
        }
    }
}

#[test]
fn items_the_contract_refuses_name_what_is_wrong() {
    let read = ParamItem::read(1);
    let cases = [
        (ParamItem::EMPTY, RequestError::BadTask),
        (ParamItem { task: 9, ..read }, RequestError::BadTask),
        (ParamItem { storage: 2, ..read }, RequestError::BadStorage),
        (ParamItem { index: 255, ..read }, RequestError::BadSubindex),
        (ParamItem { value: 1, ..read }, RequestError::ValueType),
        // A subindex only with a task that takes one; storage only with a change.
        (ParamItem { index: 1, ..read }, RequestError::BadSubindex),
        (ParamItem { storage: 1, ..read }, RequestError::BadStorage),
        (
            ParamItem {
                task: 2,
                value: 0x1_0000,
                ..read
            },
            RequestError::ValueType,
        ),
    ];
    for (bad, error) in cases {
        assert_eq!(ParamTask::try_from(&bad), Err(error), "{bad:?}");
    }
    assert_eq!(ParamItem::from(&ParamTask::None), ParamItem::EMPTY);
}
