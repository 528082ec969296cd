use super::*;
use proptest::prelude::*;
use uss_protocol::ParamReply;

/// The simulated MICROMASTER 4's parameter set.
fn mm4() -> &'static ParamSet {
    crate::family::param_set(uss_control::DriveFamily::Micromaster4)
}

const STOPPED: DriveContext = DriveContext { running: false };
const RUNNING: DriveContext = DriveContext { running: true };

fn pnu(n: u16) -> Pnu {
    Pnu::from_u16(n)
}

fn sub(i: u8) -> Subindex {
    Subindex::new(i).unwrap()
}

fn err(e: ErrorNumber) -> ReplyKind {
    ReplyKind::Error(e)
}

fn run(t: &mut ParamTable, task: ParamTask) -> ReplyKind {
    t.execute(&task, PkwMode::Four, STOPPED)
}

fn read(t: &mut ParamTable, n: u16) -> ReplyKind {
    run(t, ParamTask::Read { pnu: pnu(n) })
}

fn read_at(t: &mut ParamTable, n: u16, i: u8) -> ReplyKind {
    run(
        t,
        ParamTask::ReadArray {
            pnu: pnu(n),
            index: sub(i),
        },
    )
}

fn describe_task(n: u16, element: u8) -> ParamTask {
    ParamTask::ReadDescription {
        pnu: pnu(n),
        element: sub(element),
    }
}

fn write_task(n: u16, value: Value, storage: Storage) -> ParamTask {
    ParamTask::Write {
        pnu: pnu(n),
        value,
        storage,
    }
}

fn write_at_task(n: u16, i: u8, value: Value, storage: Storage) -> ParamTask {
    ParamTask::WriteArray {
        pnu: pnu(n),
        index: sub(i),
        value,
        storage,
    }
}

fn write(t: &mut ParamTable, n: u16, value: Value) -> ReplyKind {
    run(t, write_task(n, value, Storage::Ram))
}

fn write_eeprom(t: &mut ParamTable, n: u16, value: Value) -> ReplyKind {
    run(t, write_task(n, value, Storage::RamAndEeprom))
}

fn write_at(t: &mut ParamTable, n: u16, i: u8, value: Value) -> ReplyKind {
    run(t, write_at_task(n, i, value, Storage::Ram))
}

fn write_at_eeprom(t: &mut ParamTable, n: u16, i: u8, value: Value) -> ReplyKind {
    run(t, write_at_task(n, i, value, Storage::RamAndEeprom))
}

fn array_len(t: &mut ParamTable, n: u16) -> ReplyKind {
    run(t, ParamTask::ReadArrayLen { pnu: pnu(n) })
}

fn write_f32(t: &mut ParamTable, n: u16, value: f32) -> ReplyKind {
    write(t, n, Value::from_f32(value))
}

/// A table with P0003 = 3 (expert), so every parameter of the list is within reach.
fn expert() -> ParamTable {
    let mut t = ParamTable::new();
    assert_eq!(write(&mut t, P0003, Value::Word(3)), ReplyKind::Word(3));
    t
}

// --- The table itself ---

#[test]
fn definitions_are_sorted_unique_and_their_defaults_are_valid() {
    for pair in mm4().definitions().windows(2) {
        assert!(
            pair[0].pnu < pair[1].pnu,
            "{} before {}",
            pair[0].name,
            pair[1].name
        );
    }
    for def in mm4().definitions() {
        let number = &def.name[1..5];
        assert_eq!(number.parse::<u16>().unwrap(), def.pnu, "{}", def.name);
        let prefix = if def.is_read_only() { 'r' } else { 'P' };
        assert!(def.name.starts_with(prefix), "{}", def.name);
        assert!(def.min <= def.max, "{}", def.name);
        assert!((1..=4).contains(&def.level), "{}", def.name);
        assert_eq!(def.check_value(def.default), Ok(()), "{}", def.name);
        for &raw in def.allowed {
            assert_eq!(def.check_value(raw), Ok(()), "{} setting {raw}", def.name);
        }
    }
}

#[test]
fn new_table_holds_factory_defaults() {
    let t = ParamTable::new();
    assert_eq!(t.get(P0003, 0), Some(1));
    assert_eq!(t.get(P0010, 0), Some(0));
    assert_eq!(t.get(P0700, 0), Some(5));
    assert_eq!(t.get(P0927, 0), Some(15));
    assert_eq!(t.get(P1000, 0), Some(5));
    assert_eq!(t.get(P1082, 0), Some(0x4248_0000));
    assert_eq!(t.get(P2010, 0), Some(6));
    assert_eq!(t.get(P2010, 1), Some(6));
    assert_eq!(t.get(P2012, COM_LINK), Some(2));
    assert_eq!(t.get(P2013, COM_LINK), Some(127));
    assert_eq!(t.get(R0018, 0), Some(2.09f32.to_bits()));
    assert_eq!(t.get(R0947, 7), Some(0));
    assert_eq!(ParamTable::default(), t);
}

#[test]
fn definition_finds_defined_parameters_only() {
    let t = ParamTable::new();
    let def = t.definition(P1082).unwrap();
    assert_eq!(def.name, "P1082 Max. frequency");
    assert_eq!(def.ty, DataType::Float);
    assert_eq!(def.change, Change::NotRunning);
    assert_eq!(t.definition(R2031).unwrap().elements, 2);
    assert!(t.definition(1).is_none());
    assert!(t.definition(u16::MAX).is_none());
}

// --- Reads ---

#[test]
fn no_task_is_answered_with_no_task() {
    let mut t = ParamTable::new();
    for mode in [
        PkwMode::None,
        PkwMode::Three,
        PkwMode::Four,
        PkwMode::Variable,
    ] {
        assert_eq!(
            t.execute(&ParamTask::None, mode, STOPPED),
            ReplyKind::NotYet
        );
    }
}

#[test]
fn read_p1082_is_dword_50_hz() {
    let mut t = ParamTable::new();
    assert_eq!(read(&mut t, P1082), ReplyKind::Dword(0x4248_0000));
    let task = ParamTask::Read { pnu: pnu(P1082) };
    assert_eq!(
        t.execute(&task, PkwMode::Variable, RUNNING),
        ReplyKind::Dword(0x4248_0000)
    );
}

#[test]
fn read_word_parameter_is_word_reply_in_every_channel_width() {
    let mut t = ParamTable::new();
    let task = ParamTask::Read { pnu: pnu(P0700) };
    for mode in [PkwMode::Three, PkwMode::Four, PkwMode::Variable] {
        assert_eq!(t.execute(&task, mode, STOPPED), ReplyKind::Word(5));
    }
    assert_eq!(read(&mut t, P2000), ReplyKind::Dword(0x4248_0000));
    assert_eq!(read(&mut t, P1120), ReplyKind::Dword(0x4120_0000));
    assert_eq!(read(&mut t, R0018), ReplyKind::Dword(0x4005_C28F));
}

#[test]
fn dword_read_over_three_word_channel_is_error_102() {
    let mut t = ParamTable::new();
    let task = ParamTask::Read { pnu: pnu(P1082) };
    assert_eq!(
        t.execute(&task, PkwMode::Three, STOPPED),
        err(ErrorNumber::ChannelTooNarrow)
    );
}

#[test]
fn every_task_without_a_parameter_channel_is_error_102() {
    let mut t = ParamTable::new();
    let before = t.clone();
    for task in [
        ParamTask::Read { pnu: pnu(P0700) },
        ParamTask::ReadArrayLen { pnu: pnu(P2010) },
        write_task(P1120, Value::from_f32(2.0), Storage::Ram),
    ] {
        assert_eq!(
            t.execute(&task, PkwMode::None, STOPPED),
            err(ErrorNumber::ChannelTooNarrow),
            "{task:?}"
        );
    }
    assert_eq!(t, before);
}

#[test]
fn unknown_pnu_is_error_0() {
    let mut t = ParamTable::new();
    for task in [
        ParamTask::Read { pnu: pnu(1) },
        ParamTask::Read { pnu: pnu(65535) },
        ParamTask::ReadArray {
            pnu: pnu(2015),
            index: sub(0),
        },
        ParamTask::ReadArrayLen { pnu: pnu(950) },
        describe_task(1081, 1),
        write_task(1083, Value::Word(1), Storage::Ram),
        write_at_task(2032, 0, Value::Word(1), Storage::RamAndEeprom),
    ] {
        assert_eq!(run(&mut t, task), err(ErrorNumber::IllegalPnu), "{task:?}");
    }
}

#[test]
fn plain_read_of_an_array_reads_element_0() {
    let mut t = ParamTable::new();
    t.set_internal(R0947, 0, 0x0046);
    t.set_internal(R0947, 1, 0x0011);
    assert_eq!(read(&mut t, R0947), ReplyKind::Word(0x0046));
}

#[test]
fn array_elements_read_write_and_count() {
    let mut t = expert();
    assert_eq!(array_len(&mut t, R0947), ReplyKind::ElementCount(8));
    assert_eq!(array_len(&mut t, P2011), ReplyKind::ElementCount(2));
    assert_eq!(
        write_at(&mut t, P2011, COM_LINK, Value::Word(17)),
        ReplyKind::ArrayWord(17)
    );
    assert_eq!(read_at(&mut t, P2011, 0), ReplyKind::ArrayWord(17));
    assert_eq!(read_at(&mut t, P2011, 1), ReplyKind::ArrayWord(0));
    assert_eq!(t.get(P2011, 0), Some(17));
    t.set_internal(R0947, 7, 0x0055);
    assert_eq!(read_at(&mut t, R0947, 7), ReplyKind::ArrayWord(0x0055));
}

#[test]
fn array_index_beyond_the_elements_is_error_3() {
    let mut t = expert();
    assert_eq!(read_at(&mut t, R0947, 8), err(ErrorNumber::FaultySubindex));
    assert_eq!(
        read_at(&mut t, P2010, 254),
        err(ErrorNumber::FaultySubindex)
    );
    assert_eq!(
        write_at(&mut t, P2011, 2, Value::Word(3)),
        err(ErrorNumber::FaultySubindex)
    );
    assert_eq!(t, expert());
}

#[test]
fn array_task_on_a_plain_parameter_is_error_4() {
    let mut t = ParamTable::new();
    assert_eq!(read_at(&mut t, P0927, 0), err(ErrorNumber::NotAnArray));
    assert_eq!(array_len(&mut t, P2000), err(ErrorNumber::NotAnArray));
    assert_eq!(
        write_at(&mut t, P0927, 0, Value::Word(2)),
        err(ErrorNumber::NotAnArray)
    );
    assert_eq!(t.get(P0927, 0), Some(15));
    // A data-set parameter (P1120: one per drive data set) takes both: a plain task is its
    // element 0, the first data set.
    assert_eq!(array_len(&mut t, P1120), ReplyKind::ElementCount(3));
    assert_eq!(read(&mut t, P1120), ReplyKind::Dword(10.0f32.to_bits()));
    assert_eq!(
        read_at(&mut t, P1120, 0),
        ReplyKind::ArrayDword(10.0f32.to_bits())
    );
}

// --- Descriptive elements ---

#[test]
fn descriptive_elements_give_type_elements_access_and_limits() {
    let mut t = ParamTable::new();
    let d = |t: &mut ParamTable, n, e| run(t, describe_task(n, e));
    let word = |w| ReplyKind::Description(Value::Word(w));
    let dword = |d| ReplyKind::Description(Value::Dword(d));
    assert_eq!(d(&mut t, P1082, 1), word(8));
    assert_eq!(d(&mut t, P1082, 2), word(3), "one per drive data set");
    assert_eq!(d(&mut t, P2000, 2), word(0), "not indexed");
    assert_eq!(d(&mut t, P1082, 4), word(0));
    assert_eq!(d(&mut t, P1082, 7), dword(0x0000_0000));
    assert_eq!(d(&mut t, P1082, 8), dword(0x4422_8000)); // 650.0
    assert_eq!(d(&mut t, P2000, 7), dword(0x3F80_0000)); // 1.0
    assert_eq!(d(&mut t, P2010, 1), word(6));
    assert_eq!(d(&mut t, P2010, 2), word(2));
    assert_eq!(d(&mut t, P2010, 7), dword(3));
    assert_eq!(d(&mut t, P2010, 8), dword(12));
    assert_eq!(d(&mut t, R0947, 2), word(8));
    assert_eq!(d(&mut t, R0947, 4), word(1));
    // An r parameter whose list gives no limits describes its type's whole range.
    assert_eq!(d(&mut t, R0021, 7), dword((-f32::MAX).to_bits()));
}

#[test]
fn descriptive_element_not_kept_is_error_3() {
    let mut t = ParamTable::new();
    for element in [0, 3, 5, 6, 9, 254] {
        assert_eq!(
            run(&mut t, describe_task(P1082, element)),
            err(ErrorNumber::FaultySubindex),
            "element {element}"
        );
    }
}

#[test]
fn limit_descriptions_over_three_word_channel_are_error_102() {
    let mut t = ParamTable::new();
    let three =
        |t: &mut ParamTable, e| t.execute(&describe_task(P0700, e), PkwMode::Three, STOPPED);
    assert_eq!(three(&mut t, 1), ReplyKind::Description(Value::Word(6)));
    assert_eq!(three(&mut t, 7), err(ErrorNumber::ChannelTooNarrow));
    assert_eq!(three(&mut t, 8), err(ErrorNumber::ChannelTooNarrow));
}

#[test]
fn integer_limits_are_encoded_in_the_parameters_type() {
    assert_eq!(DataType::U16.raw(65535.0), 0xFFFF);
    assert_eq!(DataType::I16.raw(-1.0), 0xFFFF);
    assert_eq!(DataType::I32.raw(-2.0), 0xFFFF_FFFE);
    assert_eq!(DataType::U32.raw(4_000_000_000.0), 4_000_000_000);
    assert_eq!(DataType::Float.raw(50.0), 0x4248_0000);
    assert_eq!(
        [
            DataType::U16,
            DataType::I16,
            DataType::U32,
            DataType::I32,
            DataType::Float
        ]
        .map(DataType::code),
        [6, 3, 7, 4, 8]
    );
}

// --- Writes ---

#[test]
fn write_echoes_the_stored_value() {
    let mut t = ParamTable::new();
    assert_eq!(write_f32(&mut t, P1120, 2.5), ReplyKind::Dword(0x4020_0000));
    assert_eq!(t.get(P1120, 0), Some(0x4020_0000));
    assert_eq!(write(&mut t, P0700, Value::Word(2)), ReplyKind::Word(2));
    assert_eq!(read(&mut t, P0700), ReplyKind::Word(2));
    let task = write_task(P1082, Value::from_f32(60.0), Storage::Ram);
    assert_eq!(
        t.execute(&task, PkwMode::Variable, STOPPED),
        ReplyKind::Dword(0x4270_0000)
    );
}

#[test]
fn plain_write_to_an_array_changes_element_0() {
    let mut t = expert();
    assert_eq!(write(&mut t, P2012, Value::Word(4)), ReplyKind::Word(4));
    assert_eq!(t.get(P2012, 0), Some(4));
    assert_eq!(t.get(P2012, 1), Some(2));
}

#[test]
fn write_to_read_only_parameter_is_error_1() {
    let mut t = expert();
    assert_eq!(
        write_f32(&mut t, R0021, 10.0),
        err(ErrorNumber::ValueNotChangeable)
    );
    assert_eq!(
        write_at_eeprom(&mut t, R2024, 1, Value::Word(0)),
        err(ErrorNumber::ValueNotChangeable)
    );
    assert_eq!(t, expert());
}

#[test]
fn value_outside_the_limits_is_error_2() {
    let mut t = expert();
    assert_eq!(
        write_f32(&mut t, P1082, 650.5),
        err(ErrorNumber::LimitExceeded)
    );
    assert_eq!(
        write_f32(&mut t, P1082, -0.5),
        err(ErrorNumber::LimitExceeded)
    );
    assert_eq!(
        write_f32(&mut t, P2000, 0.5),
        err(ErrorNumber::LimitExceeded)
    );
    assert_eq!(
        write_f32(&mut t, P1120, f32::INFINITY),
        err(ErrorNumber::LimitExceeded)
    );
    assert_eq!(
        write(&mut t, P0003, Value::Word(5)),
        err(ErrorNumber::LimitExceeded)
    );
    assert_eq!(
        write_at(&mut t, P2011, 1, Value::Word(32)),
        err(ErrorNumber::LimitExceeded)
    );
    // Below the lowest setting counts as a limit, a gap between settings as illegal.
    assert_eq!(
        write_at(&mut t, P2010, 1, Value::Word(2)),
        err(ErrorNumber::LimitExceeded)
    );
    assert_eq!(t, expert());
    assert_eq!(
        write_f32(&mut t, P1082, 650.0),
        ReplyKind::Dword(0x4422_8000)
    );
    assert_eq!(write_f32(&mut t, P2000, 1.0), ReplyKind::Dword(0x3F80_0000));
}

#[test]
fn signed_and_float_limits_compare_as_their_type() {
    let signed =
        ParamDef::new(1, "P0001 test", DataType::I16, Change::Always, 1).limits(-100.0, 100.0);
    assert_eq!(signed.check_value(u32::from(-100i16 as u16)), Ok(()));
    assert_eq!(
        signed.check_value(u32::from(-101i16 as u16)),
        Err(ErrorNumber::LimitExceeded)
    );
    assert_eq!(
        signed.check_value(0xFFFF_FF9C),
        Ok(()),
        "only the low word counts"
    );
    let wide =
        ParamDef::new(1, "P0001 test", DataType::I32, Change::Always, 1).limits(-70_000.0, 0.0);
    assert_eq!(wide.check_value(-70_000i32 as u32), Ok(()));
    assert_eq!(wide.check_value(1), Err(ErrorNumber::LimitExceeded));
    let float =
        ParamDef::new(1, "P0001 test", DataType::Float, Change::Always, 1).limits(0.0, 2.09);
    assert_eq!(float.check_value(2.09f32.to_bits()), Ok(()));
}

#[test]
fn word_for_a_float_or_dword_for_a_word_is_error_5() {
    let mut t = expert();
    assert_eq!(
        write(&mut t, P1120, Value::Word(10)),
        err(ErrorNumber::WrongDataType)
    );
    assert_eq!(
        write(&mut t, P0700, Value::Dword(2)),
        err(ErrorNumber::WrongDataType)
    );
    assert_eq!(
        write_at(&mut t, P2011, 0, Value::Dword(3)),
        err(ErrorNumber::WrongDataType)
    );
    assert_eq!(t, expert());
}

#[test]
fn dword_write_over_three_word_channel_is_error_102() {
    let mut t = ParamTable::new();
    let task = write_task(P1120, Value::from_f32(3.0), Storage::Ram);
    assert_eq!(
        t.execute(&task, PkwMode::Three, STOPPED),
        err(ErrorNumber::ChannelTooNarrow)
    );
    assert_eq!(t, ParamTable::new());
    let word = write_task(P0700, Value::Word(2), Storage::Ram);
    assert_eq!(
        t.execute(&word, PkwMode::Three, STOPPED),
        ReplyKind::Word(2)
    );
}

#[test]
fn not_running_parameter_written_while_running_is_error_17() {
    let mut t = ParamTable::new();
    let task = write_task(P1082, Value::from_f32(60.0), Storage::Ram);
    assert_eq!(
        t.execute(&task, PkwMode::Four, RUNNING),
        err(ErrorNumber::NotInThisState)
    );
    let p0010 = write_task(P0010, Value::Word(1), Storage::Ram);
    assert_eq!(
        t.execute(&p0010, PkwMode::Four, RUNNING),
        err(ErrorNumber::NotInThisState)
    );
    assert_eq!(t, ParamTable::new());
    let ramp = write_task(P1120, Value::from_f32(3.0), Storage::Ram);
    assert_eq!(
        t.execute(&ramp, PkwMode::Four, RUNNING),
        ReplyKind::Dword(0x4040_0000),
        "Always parameters change while running"
    );
}

#[test]
fn commissioning_parameter_outside_quick_commissioning_is_error_17() {
    let mut t = ParamTable::new();
    assert_eq!(
        write_f32(&mut t, P0310, 60.0),
        err(ErrorNumber::NotInThisState)
    );
    assert_eq!(write(&mut t, P0010, Value::Word(30)), ReplyKind::Word(30));
    assert_eq!(
        write_f32(&mut t, P0310, 60.0),
        err(ErrorNumber::NotInThisState)
    );
    assert_eq!(write(&mut t, P0010, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(
        write_f32(&mut t, P0310, 60.0),
        ReplyKind::Dword(0x4270_0000)
    );
}

#[test]
fn factory_reset_without_p0010_30_is_error_17() {
    let mut t = ParamTable::new();
    assert_eq!(
        write(&mut t, P0970, Value::Word(1)),
        err(ErrorNumber::NotInThisState)
    );
    assert_eq!(write(&mut t, P0010, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(
        write(&mut t, P0970, Value::Word(1)),
        err(ErrorNumber::NotInThisState)
    );
}

#[test]
fn nan_float_is_error_104() {
    let mut t = ParamTable::new();
    assert_eq!(
        write(&mut t, P1120, Value::Dword(0x7FC0_0000)),
        err(ErrorNumber::IllegalValue)
    );
    assert_eq!(
        write(&mut t, P1120, Value::Dword(0xFFFF_FFFF)),
        err(ErrorNumber::IllegalValue)
    );
    assert_eq!(t, ParamTable::new());
}

#[test]
fn value_not_among_the_settings_is_error_104() {
    let mut t = expert();
    assert_eq!(
        write(&mut t, P0700, Value::Word(3)),
        err(ErrorNumber::IllegalValue)
    );
    // P0010 takes what the MM420 list names: 0, 1, 2, 29, 30.
    assert_eq!(
        write(&mut t, P0010, Value::Word(3)),
        err(ErrorNumber::IllegalValue)
    );
    for setting in [2, 29, 0] {
        assert_eq!(
            write(&mut t, P0010, Value::Word(setting)),
            ReplyKind::Word(setting)
        );
    }
    assert_eq!(
        write(&mut t, P1000, Value::Word(4)),
        err(ErrorNumber::IllegalValue)
    );
    assert_eq!(
        write_at(&mut t, P2010, 1, Value::Word(10)),
        err(ErrorNumber::IllegalValue)
    );
    assert_eq!(
        write_at(&mut t, P2013, 1, Value::Word(5)),
        err(ErrorNumber::IllegalValue)
    );
    assert_eq!(t, expert());
    assert_eq!(
        write_at(&mut t, P2010, 1, Value::Word(12)),
        ReplyKind::ArrayWord(12)
    );
    assert_eq!(write(&mut t, P1000, Value::Word(77)), ReplyKind::Word(77));
}

#[test]
fn parameter_above_the_access_level_is_error_204() {
    let mut t = ParamTable::new();
    // P0003 = 1 (standard): P1058 needs 2, P2012 and P0719 need 3.
    assert_eq!(
        write_f32(&mut t, P1058, 6.0),
        err(ErrorNumber::AccessLevelTooLow)
    );
    assert_eq!(
        write_at(&mut t, P2012, 1, Value::Word(4)),
        err(ErrorNumber::AccessLevelTooLow)
    );
    assert_eq!(write(&mut t, P0003, Value::Word(2)), ReplyKind::Word(2));
    assert_eq!(write_f32(&mut t, P1058, 6.0), ReplyKind::Dword(0x40C0_0000));
    assert_eq!(
        write(&mut t, P0719, Value::Word(11)),
        err(ErrorNumber::AccessLevelTooLow)
    );
    assert_eq!(write(&mut t, P0003, Value::Word(3)), ReplyKind::Word(3));
    assert_eq!(write(&mut t, P0719, Value::Word(11)), ReplyKind::Word(11));
    // Reading needs no level.
    assert_eq!(read_at(&mut t, P2014, 1), ReplyKind::ArrayWord(0));
}

#[test]
fn p0927_without_uss_bit_gives_no_change_rights() {
    let mut t = expert();
    assert_eq!(
        write(&mut t, P0927, Value::Word(0b0111)),
        ReplyKind::Word(7)
    );
    let before = t.clone();
    assert_eq!(write_f32(&mut t, P1120, 3.0), ReplyKind::NoChangeRights);
    assert_eq!(
        write_at_eeprom(&mut t, P2011, 1, Value::Word(3)),
        ReplyKind::NoChangeRights
    );
    assert_eq!(
        write(&mut t, P0927, Value::Word(15)),
        ReplyKind::NoChangeRights,
        "the lock covers P0927 itself"
    );
    assert_eq!(t, before);
    // Reads still work.
    assert_eq!(read(&mut t, P1120), ReplyKind::Dword(0x4120_0000));
    // The lock was written to RAM only: a power cycle lifts it.
    t.power_cycle();
    assert_eq!(write_f32(&mut t, P1120, 3.0), ReplyKind::Dword(0x4040_0000));
}

#[test]
fn checks_run_in_the_documented_order() {
    let mut t = ParamTable::new();
    t.set_internal(P0927, 0, 0); // no change rights
    t.set_internal(P0003, 0, 0); // below every level
    // An index beyond the array comes before read-only.
    assert_eq!(
        write_at(&mut t, R0947, 9, Value::Dword(1)),
        err(ErrorNumber::FaultySubindex)
    );
    // Read-only comes before change rights.
    assert_eq!(
        write(&mut t, R0052, Value::Dword(1)),
        err(ErrorNumber::ValueNotChangeable)
    );
    // Change rights come before the access level.
    assert_eq!(
        write(&mut t, P0719, Value::Dword(1)),
        ReplyKind::NoChangeRights
    );
    t.set_internal(P0927, 0, 15);
    // The access level comes before the data type.
    assert_eq!(
        write(&mut t, P0719, Value::Dword(1)),
        err(ErrorNumber::AccessLevelTooLow)
    );
    t.set_internal(P0003, 0, 3);
    // The data type comes before the operating state.
    let wrong_type = write_task(P1082, Value::Word(1), Storage::Ram);
    assert_eq!(
        t.execute(&wrong_type, PkwMode::Four, RUNNING),
        err(ErrorNumber::WrongDataType)
    );
    // The channel width comes before the operating state.
    let nan = write_task(P1082, Value::Dword(0x7FC0_0000), Storage::Ram);
    assert_eq!(
        t.execute(&nan, PkwMode::Three, RUNNING),
        err(ErrorNumber::ChannelTooNarrow)
    );
    // The operating state comes before the value.
    assert_eq!(
        t.execute(&nan, PkwMode::Four, RUNNING),
        err(ErrorNumber::NotInThisState)
    );
    assert_eq!(
        t.execute(&nan, PkwMode::Four, STOPPED),
        err(ErrorNumber::IllegalValue)
    );
}

// --- RAM, EEPROM, power cycle, factory reset ---

#[test]
fn ram_write_is_lost_and_eeprom_write_kept_across_power_cycle() {
    let mut t = ParamTable::new();
    assert_eq!(write_f32(&mut t, P1120, 2.0), ReplyKind::Dword(0x4000_0000));
    assert_eq!(
        write_eeprom(&mut t, P1121, Value::from_f32(3.0)),
        ReplyKind::Dword(0x4040_0000)
    );
    assert_eq!(
        write_eeprom(&mut t, P0003, Value::Word(3)),
        ReplyKind::Word(3)
    );
    assert_eq!(
        write_at_eeprom(&mut t, P2011, 1, Value::Word(7)),
        ReplyKind::ArrayWord(7)
    );
    assert_eq!(
        write_at(&mut t, P2011, 0, Value::Word(9)),
        ReplyKind::ArrayWord(9)
    );
    t.power_cycle();
    assert_eq!(t.get(P1120, 0), Some(0x4120_0000), "RAM write lost");
    assert_eq!(t.get(P1121, 0), Some(0x4040_0000), "EEPROM write kept");
    assert_eq!(t.get(P0003, 0), Some(3));
    assert_eq!(t.get(P2011, 1), Some(7));
    assert_eq!(t.get(P2011, 0), Some(0));
}

#[test]
fn power_cycle_brings_read_only_values_back_to_defaults() {
    let mut t = ParamTable::new();
    t.set_internal(R0021, 0, 25.0f32.to_bits());
    t.set_internal(R0947, 3, 0x0046);
    t.set_internal(R2024, 1, 1234);
    t.set_internal(R0018, 0, 0);
    t.power_cycle();
    assert_eq!(t, ParamTable::new());
    assert_eq!(t.get(R0018, 0), Some(0x4005_C28F));
}

#[test]
fn factory_reset_via_p0010_30_and_p0970_1() {
    let mut t = expert();
    assert_eq!(
        write_eeprom(&mut t, P1082, Value::from_f32(60.0)),
        ReplyKind::Dword(0x4270_0000)
    );
    assert_eq!(
        write_at_eeprom(&mut t, P2011, 1, Value::Word(12)),
        ReplyKind::ArrayWord(12)
    );
    // The COM link's address (index 0) is the link the drive answers on: kept by the reset;
    // the BOP link's (index 1) is not.
    assert_eq!(
        write_at_eeprom(&mut t, P2011, 0, Value::Word(7)),
        ReplyKind::ArrayWord(7)
    );
    t.set_internal(R0947, 0, 0x0046);
    assert_eq!(write(&mut t, P0010, Value::Word(30)), ReplyKind::Word(30));
    // A RAM-only reset: the factory values now, the stored ones after a power cycle.
    assert_eq!(write(&mut t, P0970, Value::Word(1)), ReplyKind::Word(0));
    assert_eq!(t.get(P0970, 0), Some(0));
    assert_eq!(t.get(P0010, 0), Some(0));
    assert_eq!(t.get(P0003, 0), Some(1));
    assert_eq!(t.get(P1082, 0), Some(0x4248_0000));
    assert_eq!(t.get(P2011, 1), Some(0));
    assert_eq!(t.get(P2011, 0), Some(7), "the link it answers on is kept");
    assert_eq!(
        t.get(R0947, 0),
        Some(0x0046),
        "fault history is not a setting"
    );
    t.power_cycle();
    assert_eq!(t.get(P1082, 0), Some(0x4270_0000));
    assert_eq!(t.get(P2011, 1), Some(12));
    // A reset stored to EEPROM as well survives the power cycle.
    assert_eq!(write(&mut t, P0010, Value::Word(30)), ReplyKind::Word(30));
    assert_eq!(
        write_eeprom(&mut t, P0970, Value::Word(1)),
        ReplyKind::Word(0)
    );
    t.power_cycle();
    assert_eq!(t.get(P2011, 0), Some(7), "kept in EEPROM too");
    t.set_commissioned(P2011, 0, 0);
    assert_eq!(t, ParamTable::new());
}

#[test]
fn p0970_0_is_accepted_and_resets_nothing() {
    let mut t = ParamTable::new();
    assert_eq!(write_f32(&mut t, P1120, 2.0), ReplyKind::Dword(0x4000_0000));
    assert_eq!(write(&mut t, P0010, Value::Word(30)), ReplyKind::Word(30));
    assert_eq!(write(&mut t, P0970, Value::Word(0)), ReplyKind::Word(0));
    assert_eq!(t.get(P1120, 0), Some(0x4000_0000));
    assert_eq!(t.get(P0010, 0), Some(30));
}

// --- Accessors for the drive model ---

#[test]
fn get_f32_decodes_by_type() {
    let mut t = ParamTable::new();
    assert_eq!(t.get_f32(P1082, 0), Some(50.0));
    assert_eq!(t.get_f32(P0927, 0), Some(15.0));
    assert_eq!(t.get_f32(P2013, 1), Some(127.0));
    t.set_internal(R0021, 0, (-12.5f32).to_bits());
    assert_eq!(t.get_f32(R0021, 0), Some(-12.5));
    t.set_internal(R0052, 0, 0xFB34);
    assert_eq!(t.get_f32(R0052, 0), Some(64_308.0));
    assert_eq!(t.get_f32(P2000, 1), None);
    assert_eq!(t.get_f32(5, 0), None);
}

#[test]
fn get_is_none_for_unknown_pnu_or_index() {
    let t = ParamTable::new();
    assert_eq!(t.get(5, 0), None);
    assert_eq!(t.get(P0700, 3), None);
    assert_eq!(t.get(P2010, 2), None);
    assert_eq!(t.get(R0947, 8), None);
    assert_eq!(t.get(R0947, 255), None);
}

#[test]
fn set_internal_bypasses_every_check_in_ram_only() {
    let mut t = ParamTable::new();
    t.set_internal(P0927, 0, 0);
    t.set_internal(R0052, 0, 0xFB34);
    t.set_internal(R2024, COM_LINK, 42);
    t.set_internal(P1082, 0, 700.0f32.to_bits()); // beyond the limit: no check
    t.set_internal(P0700, 0, 0x0001_0003); // word type keeps the low word
    assert_eq!(read(&mut t, R0052), ReplyKind::Word(0xFB34));
    assert_eq!(read_at(&mut t, R2024, COM_LINK), ReplyKind::ArrayWord(42));
    assert_eq!(read(&mut t, P1082), ReplyKind::Dword(0x442F_0000));
    assert_eq!(t.get(P0700, 0), Some(3));
    assert_eq!(
        write(&mut t, P0700, Value::Word(2)),
        ReplyKind::NoChangeRights
    );
    // Ignored silently for what does not exist.
    let before = t.clone();
    t.set_internal(5, 0, 1);
    t.set_internal(R0947, 8, 1);
    assert_eq!(t, before);
    t.power_cycle();
    assert_eq!(t, ParamTable::new());
}

#[test]
fn set_commissioned_survives_power_cycle_but_not_for_read_only() {
    let mut t = ParamTable::new();
    t.set_commissioned(P2011, COM_LINK, 5);
    t.set_commissioned(P2010, COM_LINK, 0x0001_0008);
    t.set_commissioned(R2025, COM_LINK, 9);
    t.set_commissioned(4, 0, 9);
    assert_eq!(t.get(R2025, COM_LINK), Some(0));
    t.power_cycle();
    assert_eq!(t.get(P2011, COM_LINK), Some(5));
    assert_eq!(t.get(P2010, COM_LINK), Some(8));
    assert_eq!(t.get(R2025, COM_LINK), Some(0));
}

// --- Robustness ---

fn any_task() -> impl Strategy<Value = ParamTask> {
    let pnus = prop_oneof![
        4 => (0..mm4().definitions().len()).prop_map(|n| mm4().definitions()[n].pnu),
        1 => any::<u16>(),
    ];
    let index = prop_oneof![3 => 0u8..9, 1 => 0u8..=Subindex::MAX];
    let value = prop_oneof![
        (0u16..=40).prop_map(Value::Word),
        any::<u16>().prop_map(Value::Word),
        (-10.0f32..700.0).prop_map(Value::from_f32),
        any::<u32>().prop_map(Value::Dword),
    ];
    let storage = prop_oneof![Just(Storage::Ram), Just(Storage::RamAndEeprom)];
    (0u8..7, pnus, index, value, storage).prop_map(|(kind, n, i, value, storage)| {
        let pnu = Pnu::from_u16(n);
        let index = Subindex::new(i).unwrap();
        match kind {
            0 => ParamTask::None,
            1 => ParamTask::Read { pnu },
            2 => ParamTask::Write {
                pnu,
                value,
                storage,
            },
            3 => ParamTask::ReadDescription {
                pnu,
                element: index,
            },
            4 => ParamTask::ReadArray { pnu, index },
            5 => ParamTask::WriteArray {
                pnu,
                index,
                value,
                storage,
            },
            _ => ParamTask::ReadArrayLen { pnu },
        }
    })
}

fn any_mode() -> impl Strategy<Value = PkwMode> {
    prop_oneof![
        Just(PkwMode::None),
        Just(PkwMode::Three),
        Just(PkwMode::Four),
        Just(PkwMode::Variable),
    ]
}

proptest! {
    /// Whatever the tasks: no panic, a refused task changes nothing, every reply fits the
    /// channel it goes out on, a change echoes what is stored, and every changeable
    /// parameter holds a value its definition allows.
    #[test]
    fn any_task_sequence_keeps_the_table_consistent(
        steps in proptest::collection::vec((any_task(), any_mode(), any::<bool>()), 1..40)
    ) {
        let mut t = ParamTable::new();
        for (task, mode, running) in steps {
            let before = t.clone();
            let reply = t.execute(&task, mode, DriveContext { running });
            if matches!(reply, ReplyKind::Error(_) | ReplyKind::NoChangeRights) {
                prop_assert_eq!(&t, &before);
            }
            let Some(p) = task.pnu() else { continue };
            if mode != PkwMode::None {
                let out = ParamReply { pnu: p, subindex: task.subindex(), kind: reply };
                prop_assert!(out.encode(mode, &mut [0; 4]).is_ok(), "{:?} in {:?}", reply, mode);
            }
            if let (true, Some(echo)) = (task.is_write(), reply.value()) {
                let index = if matches!(task, ParamTask::WriteArray { .. }) { task.subindex() } else { 0 };
                prop_assert_eq!(t.get(p.get(), index), Some(echo.as_u32()));
            }
            for def in mm4().definitions().iter().filter(|d| !d.is_read_only()) {
                for i in 0..def.slots() as u8 {
                    let raw = t.get(def.pnu, i).unwrap();
                    prop_assert_eq!(def.check_value(raw), Ok(()), "{} = {:#x}", def.name, raw);
                }
            }
        }
    }
}

/// A commissioning master's quick commissioning of an MM420 (parameter list 6SE6400-5BA00-0BP0,
/// typed in here, not read from the profile): P0010 = 1 opens the "C" motor data P0100, P0304,
/// P0305, P0307, P0310, P0311; P1300 is "CT"; r0025, r0026, r0027 are the output voltage, the
/// DC-link voltage and the output current (floats); P0971 = 1 stores RAM in EEPROM and reads 0
/// again.
#[test]
fn a_quick_commissioning_writes_the_motor_data_and_saves_it() {
    let mut t = expert();
    assert_eq!(
        write(&mut t, 304, Value::Word(400)),
        err(ErrorNumber::NotInThisState),
        "P0304 outside quick commissioning"
    );
    assert_eq!(write(&mut t, P0010, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(write(&mut t, 100, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(write(&mut t, 304, Value::Word(400)), ReplyKind::Word(400));
    assert_eq!(
        write(&mut t, 304, Value::Word(9)),
        err(ErrorNumber::LimitExceeded),
        "P0304 10..2000 V"
    );
    for (pnu, value) in [(305, 1.9f32), (307, 0.75), (310, 50.0)] {
        assert_eq!(
            write_f32(&mut t, pnu, value),
            ReplyKind::Dword(value.to_bits()),
            "P{pnu:04}"
        );
    }
    assert_eq!(write(&mut t, 311, Value::Word(1395)), ReplyKind::Word(1395));
    assert_eq!(write(&mut t, 1300, Value::Word(2)), ReplyKind::Word(2));
    assert_eq!(write(&mut t, P0010, Value::Word(0)), ReplyKind::Word(0));
    for r in [25, 26, 27] {
        assert_eq!(read(&mut t, r), ReplyKind::Dword(0), "r{r:04} is a float");
    }
    // Kept only in RAM until P0971 = 1.
    assert_eq!(write(&mut t, P0971, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(read(&mut t, P0971), ReplyKind::Word(0));
    t.power_cycle();
    assert_eq!(t.get(304, 0), Some(400));
    assert_eq!(t.get(311, 0), Some(1395));
    assert_eq!(t.get(1300, 0), Some(2));
    assert_eq!(t.get_f32(305, 0), Some(1.9));
}

/// The rest of an MM4's quick commissioning (parameter list 6SE6400-5BA00-0BP0, typed in here,
/// not read from the profile): P0308 rated motor cosPhi (float 0.000..1.000, "C"), P0335 motor
/// cooling ("CT"), P0340 calculation of the motor parameters ("T"), P0640 motor overload factor
/// (float 10.0..400.0 %, factory setting 150.0, changeable at any time).
#[test]
fn the_motor_data_of_quick_commissioning_are_all_there() {
    let mut t = expert();
    assert_eq!(
        write_f32(&mut t, 308, 0.8),
        err(ErrorNumber::NotInThisState),
        "P0308 outside quick commissioning"
    );
    assert_eq!(t.get_f32(640, 0), Some(150.0), "P0640's factory setting");
    assert_eq!(write(&mut t, P0010, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(
        write_f32(&mut t, 308, 0.82),
        ReplyKind::Dword(0.82f32.to_bits())
    );
    assert_eq!(
        write_f32(&mut t, 308, 1.5),
        err(ErrorNumber::LimitExceeded),
        "P0308 0.000..1.000"
    );
    assert_eq!(write(&mut t, 335, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(write(&mut t, P0010, Value::Word(0)), ReplyKind::Word(0));
    assert_eq!(write(&mut t, 340, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(
        write_f32(&mut t, 640, 5.0),
        err(ErrorNumber::LimitExceeded),
        "P0640 10.0..400.0 %"
    );
    assert_eq!(
        write_f32(&mut t, 640, 120.0),
        ReplyKind::Dword(120f32.to_bits())
    );
}

/// A G120 (CU2x0-2) has no task codes that store one value in EEPROM (Fieldbus Function Manual
/// 06/2012, table 9-45: 0..8): it refuses them, task not implemented (error 106), and changes
/// nothing. Its settings become permanent by p0971 = 1, which reads 0 again once done; a
/// power cycle then keeps them (issue 46: the simulator took what the drive refuses).
#[test]
fn a_g120_refuses_eeprom_tasks_and_saves_every_setting_by_p0971() {
    let g120 = crate::family::param_set(uss_control::DriveFamily::G120);
    let mut t = ParamTable::of(g120);
    let before = t.get(P1120, 0);
    assert_eq!(
        write_eeprom(&mut t, P1120, Value::from_f32(9.0)),
        err(ErrorNumber::TaskNotImplemented)
    );
    assert_eq!(t.get(P1120, 0), before, "nothing changed");
    assert_eq!(
        write_f32(&mut t, P1120, 9.0),
        ReplyKind::Dword(9.0f32.to_bits())
    );
    assert_eq!(write(&mut t, 971, Value::Word(1)), ReplyKind::Word(1));
    assert_eq!(read(&mut t, 971), ReplyKind::Word(0), "the save is done");
    t.power_cycle();
    assert_eq!(t.get(P1120, 0), Some(9.0f32.to_bits()), "kept by p0971");
    // A MICROMASTER 4 takes them.
    let mut mm = ParamTable::new();
    assert_eq!(
        write_eeprom(&mut mm, P1121, Value::from_f32(3.0)),
        ReplyKind::Dword(3.0f32.to_bits())
    );
}

// --- Parameters besides the profile (uss-sim's extra=) ---

#[test]
fn a_drive_with_extra_parameters_describes_keeps_and_resets_them_as_its_own() {
    use crate::drive::{Extra, Personality};
    let extra = Extra {
        words: Some((701, 702)),
        floats: Some((1230, 1230)),
        read_only: Some((760, 760)),
    };
    let set = extra.param_set(Personality::MICROMASTER4).unwrap();
    assert!(std::ptr::eq(
        set,
        extra.param_set(Personality::MICROMASTER4).unwrap()
    ));
    let mut t = ParamTable::of(set);
    let d = |t: &mut ParamTable, n, e| run(t, describe_task(n, e));
    let word = |w| ReplyKind::Description(Value::Word(w));
    assert_eq!((d(&mut t, 701, 1), d(&mut t, 701, 2)), (word(6), word(0)));
    assert_eq!((d(&mut t, 701, 4), d(&mut t, 760, 4)), (word(0), word(1)));
    assert_eq!((d(&mut t, 1230, 1), d(&mut t, 1230, 2)), (word(8), word(3)));
    assert_eq!(d(&mut t, 703, 1), err(ErrorNumber::IllegalPnu));
    assert_eq!(read(&mut t, 702), ReplyKind::Word(702));
    assert_eq!(
        write(&mut t, 760, Value::Word(1)),
        err(ErrorNumber::ValueNotChangeable)
    );
    assert_eq!(
        write_eeprom(&mut t, 701, Value::Word(9)),
        ReplyKind::Word(9)
    );
    assert_eq!(
        write_at(&mut t, 1230, 2, Value::from_f32(-4.0)),
        ReplyKind::ArrayDword((-4.0f32).to_bits())
    );
    t.power_cycle();
    assert_eq!((t.get(701, 0), t.get_f32(1230, 2)), (Some(9), Some(1.5)));
    // A factory reset puts them back as every other setting.
    assert_eq!(write(&mut t, P0010, Value::Word(30)), ReplyKind::Word(30));
    assert_eq!(write(&mut t, P0970, Value::Word(1)), ReplyKind::Word(0));
    assert_eq!(t.get(701, 0), Some(701));
    // The profile's own numbers are not extras.
    let clash = Extra {
        words: Some((700, 701)),
        ..Extra::default()
    };
    let e = clash.param_set(Personality::MICROMASTER4).unwrap_err();
    assert!(e.contains("700"), "{e}");
}
