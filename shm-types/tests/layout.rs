//! Checks every contract type against the one expected-layout table in `uss_shm_types::layout`:
//! size, alignment, iceoryx2 type name, and each field's offset and size.

use core::mem::{align_of, offset_of, size_of, size_of_val};
use iceoryx2::prelude::ZeroCopySend;
use uss_shm_types::layout::{FieldLayout, LAYOUTS, TypeLayout};
use uss_shm_types::{
    BlackboardKey, BusStatus, DriveCounters, DriveDiag, DriveInfo, Generation, Heartbeat,
    LAYOUT_VERSION, MAX_PARAM_ITEMS, OperatorRequest, OperatorResponse, ParamItem, ParamRequest,
    ParamResponse, ParamResult, PzdInput, PzdOutput, StopCommand, TelegramRecord,
};

/// The layout the compiler gave a type, in the table's shape.
struct Actual {
    name: &'static str,
    type_name: &'static str,
    size: usize,
    align: usize,
    fields: Vec<FieldLayout>,
}

/// `actual!(Type = value, [field, ...])`: the real size, alignment, type name and field offsets.
macro_rules! actual {
    ($t:ident = $v:expr, [$($field:ident),+ $(,)?] $(,)?) => {{
        let v: $t = $v;
        Actual {
            name: stringify!($t),
            // SAFETY: `type_name` only returns the string the derive was given.
            type_name: unsafe { <$t as ZeroCopySend>::type_name() },
            size: size_of::<$t>(),
            align: align_of::<$t>(),
            fields: vec![$(FieldLayout {
                name: stringify!($field),
                offset: offset_of!($t, $field),
                size: size_of_val(&v.$field),
            }),+],
        }
    }};
}

/// Every contract type with every field, in memory order (a table: kept one type per row).
#[rustfmt::skip]
fn actual_layouts() -> Vec<Actual> {
    vec![
        actual!(BlackboardKey = BlackboardKey::IMAGE, [value]),
        actual!(PzdOutput = PzdOutput::EMPTY, [
            version, controller_pid, sequence, timestamp_ns, stw1, setpoint, extra, word_count,
            flags, reserved, latch_id,
        ]),
        actual!(PzdInput = PzdInput::EMPTY, [
            version, online, control, word_count, latch_reason, sequence, timestamp_ns,
            age_ns, zsw1, hiw, extra, sent_stw1, sent_setpoint, latches, latched_since_ns,
            latched_by_pid, latch_command, rejection, known, picture, taken_sequence, latch_id,
            period_ns, stale_after_ns,
        ]),
        actual!(DriveInfo = DriveInfo::UNKNOWN, [
            reference_hz, watchdog_ms, safe_command, params_writable, pkw_words, pzd_words,
            weight, family, pole_pairs, reserved,
        ]),
        actual!(DriveCounters = DriveCounters::default(), [
            requests, good, rejected, timeouts, retries, failed_polls, missing_stx, start_pause,
            bad_lge, bcc, residual, length, wrong_address, parity, framing, overrun, echo,
            pkw_busy, jobs_done, watchdog_trips, latches, rejected_outputs, releases, overrides,
            replacements,
        ]),
        actual!(DriveDiag = DriveDiag::new(0), [
            version, consecutive_failed_polls, last_zsw1, last_hiw, address, online, no_reply,
            control, last_failure, latch_reason, latch_command, rejection, monitoring, known,
            picture, reserved, monitoring_ms, controller_pid, since_ns, last_good_ns, latched_since_ns,
            info, counters, exchange_ns, response_delay_ns, period_ns, stale_after_ns,
            monitoring_min_ms, reserved3,
        ]),
        actual!(BusStatus = BusStatus::EMPTY, [
            version, rt_cpu, rt_mode, rt_priority, drive_count, running, efficiency_ppm,
            exchanges, good, cycles, cycle_overruns, events_dropped, results_lost, jobs_accepted,
            jobs_finished, mean_exchange_ns, bus_clock_ns, timestamp_ns, line_state, line_fault,
            reserved, line_errno, line_down_since_ns, line_downs, reopen_attempts, reserved2,
            jobs_cancelled, exchange_ns, response_delay_ns, turnaround_ns, exchange_count,
            exchange_sum_ns, exchange_le, out_of_turn,
            broadcasts, timed, untimed, timed_exchange_ns, timed_wire_floor_ns,
        ]),
        actual!(ParamItem = ParamItem::EMPTY, [task, storage, pnu, index, reserved, value]),
        actual!(ParamRequest = ParamRequest {
            version: LAYOUT_VERSION, address: 0, count: 0, flags: 0, reserved: 0,
            items: [ParamItem::EMPTY; MAX_PARAM_ITEMS],
        }, [version, address, count, flags, reserved, items]),
        actual!(ParamResult = ParamResult::NOT_RUN, [
            outcome, value_is_dword, drive_error, value, telegrams, refusal, reserved, on_wire_ns,
        ]),
        actual!(ParamResponse = ParamResponse::new(0), [
            version, error, error_item, address, count, controller_pid, reserved, results,
        ]),
        actual!(Heartbeat = Heartbeat::new(1, Generation(2)), [
            version, pid, generation, sequence, timestamp_ns, exchanges, line_down_since_ns, state,
            line_fault, reserved, line_errno,
        ]),
        actual!(OperatorRequest = OperatorRequest::new(1, StopCommand::Off1), [
            version, address, command, reserved,
        ]),
        actual!(OperatorResponse = OperatorResponse::done(StopCommand::Off1, 0), [
            version, error, command, reserved, drives,
        ]),
        actual!(TelegramRecord = TelegramRecord::EMPTY, [
            version, len, direction, outcome, address, pkw, pzd, flags, reserved, sequence,
            start_ns, end_ns, bytes,
        ]),
    ]
}

fn expected(name: &str) -> &'static TypeLayout {
    LAYOUTS
        .iter()
        .find(|t| t.name == name)
        .unwrap_or_else(|| panic!("{name} is missing from layout::LAYOUTS"))
}

#[test]
fn every_type_matches_the_layout_table() {
    let actual = actual_layouts();
    assert_eq!(
        actual.len(),
        LAYOUTS.len(),
        "a type is missing here or in the table"
    );
    for a in &actual {
        let e = expected(a.name);
        assert_eq!(a.type_name, e.type_name, "{}: type name", a.name);
        assert_eq!(a.size, e.size, "{}: size", a.name);
        assert_eq!(a.align, e.align, "{}: alignment", a.name);
        assert_eq!(a.fields.as_slice(), e.fields, "{}: fields", a.name);
    }
}

#[test]
fn the_table_leaves_no_implicit_padding() {
    for t in LAYOUTS {
        let mut end = 0;
        for field in t.fields {
            assert_eq!(
                field.offset, end,
                "{}.{}: gap before it",
                t.name, field.name
            );
            end = field.offset + field.size;
        }
        assert_eq!(end, t.size, "{}: gap at the end", t.name);
    }
}

#[test]
fn payloads_start_with_the_version_and_name_it_in_their_type_name() {
    let suffix = format!("V{LAYOUT_VERSION}");
    // The key, the array elements and the nested records are not payloads of their own.
    let not_payloads = [
        "BlackboardKey",
        "ParamItem",
        "ParamResult",
        "DriveInfo",
        "DriveCounters",
    ];
    for t in LAYOUTS {
        if t.name != "BlackboardKey" {
            assert!(
                t.type_name.ends_with(&suffix),
                "{}: {}",
                t.name,
                t.type_name
            );
        }
        if !not_payloads.contains(&t.name) {
            assert_eq!(
                t.fields[0],
                FieldLayout {
                    name: "version",
                    offset: 0,
                    size: 4
                }
            );
        }
    }
}

#[test]
fn constructors_write_the_current_version() {
    assert_eq!(PzdOutput::default().version, LAYOUT_VERSION);
    assert_eq!(PzdInput::default().version, LAYOUT_VERSION);
    assert_eq!(DriveDiag::new(1).version, LAYOUT_VERSION);
    assert_eq!(BusStatus::default().version, LAYOUT_VERSION);
    assert_eq!(ParamResponse::new(1).version, LAYOUT_VERSION);
    assert_eq!(
        OperatorRequest::new(1, StopCommand::Off2).version,
        LAYOUT_VERSION
    );
}
