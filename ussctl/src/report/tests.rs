use super::*;
use uss_client::{
    Address, BusStatus, DriveDiag, Monitoring, ParamValue, PzdInput, StopCommand, Value,
};
use uss_shm_types::DriveCounters;
use uss_shm_types::DriveInfo;
use uss_shm_types::diag::LastFailure;

fn diag() -> DriveDiag {
    DriveDiag {
        online: 1,
        known: 1,
        last_zsw1: 0xFB34,
        last_hiw: 0x2000,
        counters: DriveCounters {
            good: 10,
            rejected: 1,
            timeouts: 1,
            ..DriveCounters::default()
        },
        // 0x2000 = 50 % of this drive's P2000 as ussd's configuration gives it.
        info: DriveInfo {
            reference_hz: 60.0,
            pzd_words: 2,
            ..DriveInfo::UNKNOWN
        },
        last_failure: LastFailure::NoResponse.code(),
        latch_command: StopCommand::Off1.code(),
        ..DriveDiag::new(3)
    }
}

#[test]
fn status_json_has_one_object_per_drive_with_decoded_zsw1() {
    let report = StatusReport {
        bus: BusView::new("b0", &BusStatus::EMPTY),
        drives: vec![DriveView::new(&diag(), 0)],
    };
    let v = serde_json::to_value(&report).unwrap();
    assert_eq!(v["bus"]["bus"], "b0");
    assert_eq!(v["bus"]["efficiency"], serde_json::Value::Null);
    let d = &v["drives"][0];
    assert_eq!(d["address"], 3);
    assert_eq!(d["online"], true);
    assert_eq!(d["state"], "S4");
    assert_eq!(d["zsw1"], 0xFB34);
    assert_eq!(d["zsw1_hex"], "0xFB34");
    assert_eq!(
        d["flags"],
        serde_json::json!(["at-setpoint", "control-requested", "running-right"])
    );
    assert_eq!(d["actual_hz"], 30.0);
    assert_eq!(
        (d["good"].as_u64(), d["rejected"].as_u64()),
        (Some(10), Some(1))
    );
    assert_eq!(d["last_error"], "no response");
    assert_eq!(d["control"]["state"], "latched");
    assert_eq!(d["control"]["reason"], "ussd started");
    assert_eq!(d["monitoring"], "not read yet");
    let text = report.human();
    assert!(
        text.contains("   3  yes     S4         0xFB34      30.00"),
        "{text}"
    );
    assert!(text.contains("latched: ussd started, OFF1"), "{text}");
}

#[test]
fn a_drive_without_telegram_monitoring_is_warned_about() {
    let off = DriveView::new(
        &DriveDiag {
            monitoring: Monitoring::Off.code(),
            control: uss_client::ControlState::Live.code(),
            ..diag()
        },
        0,
    );
    let report = StatusReport {
        bus: BusView::new("b0", &BusStatus::EMPTY),
        drives: vec![off],
    };
    let text = report.human();
    assert!(
        text.contains("warning: drive 3: telegram monitoring is OFF: if ussd or its line dies, nothing stops this drive"),
        "{text}"
    );
    assert!(text.contains("  live  "), "{text}");
}

#[test]
fn a_drive_is_unknown_until_its_first_poll_decided() {
    let d = DriveView::new(
        &DriveDiag {
            known: 0,
            online: 0,
            ..diag()
        },
        0,
    );
    assert_eq!(d.state, "unknown");
}

#[test]
fn offline_drives_show_offline_not_a_stale_state() {
    let d = DriveView::new(
        &DriveDiag {
            online: 0,
            ..diag()
        },
        0,
    );
    assert_eq!((d.online, d.state), (false, "offline"));
}

#[test]
fn parameters_show_in_their_type_and_unit() {
    let info = uss_client::Catalogue::micromaster4().param(1082);
    let v = ParamValue {
        param: "P1082".parse().unwrap(),
        raw: Value::Dword(0x4248_0000),
        data_type: uss_client::DataType::Float,
        info,
        digits: 4,
    };
    let p = ParamReport::new("b0", Address::new(1).unwrap(), &v);
    assert_eq!(p.human(), "drive 1 P1082 = 50.00 Hz  (Max. frequency)");
    assert_eq!(
        serde_json::to_value(&p).unwrap(),
        serde_json::json!({"bus": "b0", "drive": 1, "param": "P1082", "pnu": 1082, "index": null,
                           "name": "Max. frequency", "type": "float", "unit": "Hz",
                           "raw": 1_112_014_848_u32, "hex": "0x42480000", "value": 50.0})
    );
    let zsw1 = ParamValue {
        param: "r0052".parse().unwrap(),
        raw: Value::Word(0xFB31),
        data_type: uss_client::DataType::U16,
        info: uss_client::Catalogue::micromaster4().param(52),
        digits: 4,
    };
    let mut p = ParamReport::new("b0", Address::new(1).unwrap(), &zsw1);
    assert!(
        p.human().starts_with(
            "drive 1 r0052 = 0xFB31  (CO/BO: Act. status word 1): at-setpoint, control-requested"
        ),
        "{}",
        p.human()
    );
    p.eeprom = Some(true);
    assert!(
        p.human()
            .starts_with("drive 1 r0052 := 0xFB31, RAM and EEPROM")
    );
    assert_eq!(
        stw1_bits(0x047E),
        [
            "no-OFF2",
            "no-OFF3",
            "pulses-enabled",
            "RFG-enabled",
            "RFG-start",
            "setpoint-enabled",
            "control-by-PLC"
        ]
    );
}

#[test]
fn faults_list_recorded_codes_with_texts_values_and_warnings() {
    let report = uss_client::FaultReport {
        codes: "r0947".parse().unwrap(),
        values: Some("r0949".parse().unwrap()),
        warnings_from: Some("r2110".parse().unwrap()),
        digits: 4,
        param_digits: 4,
        faults: vec![
            uss_client::Fault {
                slot: 0,
                number: 70,
                value: Some(3),
                time: Some(uss_client::FaultTime {
                    words: [5 | 31 << 8, 20 | 22 << 8, 11 | 26 << 8],
                }),
                received: None,
                text: Some("CB setpoint fault"),
            },
            uss_client::Fault {
                slot: 1,
                number: 999,
                value: None,
                time: None,
                received: None,
                text: None,
            },
        ],
        warnings: Some(vec![uss_client::Warning {
            number: 501,
            text: Some("Current limit"),
        }]),
    };
    let f = FaultsReport::new("b", Address::new(2).unwrap(), &report);
    assert_eq!(
        f.human(),
        "drive 2 fault buffer r0947, newest first:\n  0: F0070 CB setpoint fault (fault value r0949 = 3) at 2026-11-22 20:31:05\n  1: F0999\nactive warnings (r2110):\n  A0501 Current limit\n"
    );
    let v = serde_json::to_value(&f).unwrap();
    assert_eq!(
        v["faults"][0],
        serde_json::json!({"slot": 0, "number": 70, "code": "F0070", "value": 3, "time": "2026-11-22 20:31:05", "time_words": [7941, 5652, 6667], "text": "CB setpoint fault"})
    );
    assert_eq!(v["warnings"][0]["code"], "A0501");
    let none = FaultsReport::new(
        "b",
        Address::new(2).unwrap(),
        &uss_client::FaultReport {
            codes: "r0947".parse().unwrap(),
            values: None,
            warnings_from: None,
            digits: 4,
            param_digits: 4,
            faults: Vec::new(),
            warnings: None,
        },
    );
    assert_eq!(none.human(), "drive 2: no faults recorded (r0947 empty)\n");
}

#[test]
fn watch_lines_carry_the_extra_words_in_use() {
    let mut i = PzdInput::from_words(&[0xFB31, 0, 5, 6], 9, 0, 2_000_000).unwrap();
    (i.online, i.known) = (1, 1);
    let w = WatchLine::new(0.5, Address::new(4).unwrap(), &i, 50.0);
    assert_eq!(
        (w.state, w.extra.as_slice(), w.period_ms),
        ("S2", &[5, 6][..], 2.0)
    );
    assert!(w.human().contains("PZD3.. 0x0005 0x0006"), "{}", w.human());
}

/// An OFF3 asked of a drive that coasts (OFF2) keeps its OFF2: the line says the OFF2 it sends
/// and what that does, not "it stops quickly" (issue 35: read in the guide's quick-stop --all).
#[test]
fn a_stop_report_says_what_the_stop_it_sent_does() {
    let coasting = PzdInput {
        online: 1,
        known: 1,
        zsw1: 0xBB60,
        sent_stw1: 0x047C,
        latch_reason: uss_client::LatchReason::Override.code(),
        latch_command: StopCommand::Off2.code(),
        ..PzdInput::EMPTY
    };
    let ramping = PzdInput {
        latch_command: StopCommand::Off3.code(),
        sent_stw1: 0x047A,
        zsw1: 0xBB50,
        ..coasting
    };
    let mut report = StopReport::new("bus0", StopCommand::Off3);
    report.push(Address::new(1).unwrap(), &coasting);
    report.push(Address::new(2).unwrap(), &ramping);
    let said = report.human();
    assert!(
        said.contains(
            "drive 1: OFF2 sent (STW1 0x047C) on bus0, it coasts: its OFF2 stays, stronger than the OFF3 asked; now S1"
        ),
        "{said}"
    );
    assert!(
        said.contains("drive 2: OFF3 sent (STW1 0x047A) on bus0, it stops quickly; now S1"),
        "{said}"
    );
}

/// Rule 3: diagnostics older than ussd's own limit for them (a ussd that was paused and has not
/// polled since it resumed, a stalled bus thread) are not the drive as it is: the row says
/// stale, not online, and not the state it last saw (the adversarial run saw `status` show the
/// pre-pause "online, S4" right after ussd resumed).
#[test]
fn a_drive_whose_poll_is_overdue_shows_stale_not_online() {
    let overdue = DriveDiag {
        last_good_ns: 1,
        stale_after_ns: 50_000_000,
        ..diag()
    };
    let report = StatusReport {
        bus: BusView::new("b0", &BusStatus::EMPTY),
        drives: vec![DriveView::new(&overdue, 1_000_000_000)],
    };
    let v = serde_json::to_value(&report).unwrap();
    let d = &v["drives"][0];
    assert_eq!(
        (&d["online"], &d["stale"], &d["state"]),
        (
            &serde_json::json!(false),
            &serde_json::json!(true),
            &serde_json::json!("stale")
        ),
        "{d}"
    );
    let text = report.human();
    assert!(text.contains("   3  no      stale "), "{text}");
    let stats = serde_json::to_value(DriveStats::new(&overdue, 1_000_000_000)).unwrap();
    assert_eq!(
        (&stats["online"], &stats["stale"]),
        (&serde_json::json!(false), &serde_json::json!(true)),
        "{stats}"
    );
}

/// `run`'s last line never shows a peak below the frequency it shows as "now" (it said "now
/// 18.22 Hz, peak 17.84 Hz": the drive went on ramping between the last reading of the loop and
/// the stop's confirmation).
#[test]
fn a_runs_peak_is_at_least_its_last_frequency() {
    let last = PzdInput {
        online: 1,
        known: 1,
        zsw1: 0xBB37,
        hiw: 0x2000,
        ..PzdInput::default()
    };
    let report =
        DriveReport::new("b0", "run", &last, Address::new(1).unwrap(), 50.0).with_peak(17.84);
    assert_eq!((report.actual_hz, report.peak_hz), (25.0, Some(25.0)));
    let report =
        DriveReport::new("b0", "run", &last, Address::new(1).unwrap(), 50.0).with_peak(-30.0);
    assert_eq!(report.peak_hz, Some(-30.0));
}
