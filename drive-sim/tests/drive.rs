//! The drive model: PROFIdrive state machine, ramp, PKW handshake, telegram monitoring
//! (USS.md sections 5, 6 and 7), driven through real telegrams.
#![allow(clippy::unwrap_used, clippy::float_cmp)]

use std::time::Duration;
use uss_drive_sim::drive::FAULT_TELEGRAM_OFF;
use uss_drive_sim::params::COM_LINK;
use uss_drive_sim::{Drive, DriveConfig, State, Stop};
use uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, Telegram, encode};
use uss_protocol::{Address, Adr, ErrorNumber, ParamReply, ReplyKind, Zsw1};

const ADDR: u8 = 3;

fn layout(pkw: PkwMode, pzd: usize) -> Layout {
    Layout::new(pkw, PzdCount::new(pzd).unwrap())
}

fn drive(pkw: PkwMode) -> Drive {
    Drive::new(DriveConfig::new(
        Address::new(ADDR).unwrap(),
        layout(pkw, 2),
    ))
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// Sends one telegram and returns the reply's (PKW words, PZD words).
fn send(d: &mut Drive, pkw: &[u16], pzd: &[u16], now: Duration) -> Option<(Vec<u16>, Vec<u16>)> {
    let mut req = [0u8; MAX_TELEGRAM_BYTES];
    let n = encode(&mut req, Adr::to(Address::new(ADDR).unwrap()), pkw, pzd).unwrap();
    let telegram = Telegram::parse(&req[..n]).unwrap();
    let mut out = [0u8; MAX_TELEGRAM_BYTES];
    let len = d.receive(&telegram, now, &mut out)?;
    let reply = Telegram::parse(&out[..len]).unwrap();
    assert_eq!(reply.adr(), Adr::to(Address::new(ADDR).unwrap()));
    let words = reply.words(d.config().layout).unwrap();
    Some((words.pkw().to_vec(), words.pzd().to_vec()))
}

fn control(d: &mut Drive, stw: u16, hsw: u16, now: Duration) -> (Zsw1, u16) {
    let pkw = vec![0; d.config().layout.pkw.request_words()];
    let (_, pzd) = send(d, &pkw, &[stw, hsw], now).unwrap();
    (Zsw1::from_bits_retain(pzd[0]), pzd[1])
}

/// Runs the drive up to `hz` (with P2000 = 50 Hz) and returns the time reached.
fn run_to(d: &mut Drive, percent_word: u16, until: Duration) -> Duration {
    let mut t = Duration::ZERO;
    control(d, 0x047E, 0, t);
    while t < until {
        t += ms(10);
        control(d, 0x047F, percent_word, t);
    }
    t
}

fn param(d: &Drive, pnu: u16) -> f32 {
    d.params().get_f32(pnu, 0).unwrap()
}

#[test]
fn powers_up_in_s1_switching_on_inhibited() {
    let mut d = drive(PkwMode::Four);
    assert_eq!(d.state(), State::SwitchingOnInhibited);
    let (z, hiw) = control(&mut d, 0x0400, 0, ms(0));
    assert!(z.contains(Zsw1::SWITCHING_ON_INHIBITED | Zsw1::CONTROL_REQUESTED));
    assert!(!z.contains(Zsw1::READY_TO_SWITCH_ON));
    assert_eq!(hiw, 0);
}

#[test]
fn leaving_s1_needs_off1_first() {
    let mut d = drive(PkwMode::Four);
    control(&mut d, 0x047F, 0, ms(0));
    assert_eq!(
        d.state(),
        State::SwitchingOnInhibited,
        "ON while inhibited is ignored"
    );
    control(&mut d, 0x047E, 0, ms(10));
    assert_eq!(d.state(), State::ReadyToSwitchOn);
    let (z, _) = control(&mut d, 0x047F, 0, ms(20));
    assert_eq!(d.state(), State::OperationEnabled);
    assert!(z.contains(Zsw1::READY_TO_SWITCH_ON | Zsw1::READY_TO_RUN | Zsw1::OPERATION_ENABLED));
}

#[test]
fn mm420_start_up_words_step_through_s2_s3_s4() {
    // USS.md section 7: STW1 0x0476 -> S2, 0x0477 -> S3, 0x047F -> S4.
    let mut d = drive(PkwMode::Four);
    control(&mut d, 0x0476, 0, ms(0));
    assert_eq!(d.state(), State::ReadyToSwitchOn);
    let (z, _) = control(&mut d, 0x0477, 0, ms(10));
    assert_eq!(d.state(), State::ReadyForOperation);
    assert!(z.contains(Zsw1::READY_TO_RUN) && !z.contains(Zsw1::OPERATION_ENABLED));
    control(&mut d, 0x047F, 0, ms(20));
    assert_eq!(d.state(), State::OperationEnabled);
}

#[test]
fn ramp_follows_p1120_and_reports_at_setpoint() {
    // P1082 = 50 Hz, P1120 = 10 s: 5 Hz/s. Setpoint 0x2000 = 50 % of P2000 (50 Hz) = 25 Hz.
    let mut d = drive(PkwMode::Four);
    run_to(&mut d, 0x2000, ms(2000));
    assert!(
        (d.frequency_hz() - 10.0).abs() < 0.06,
        "{}",
        d.frequency_hz()
    );
    let (z, _) = control(&mut d, 0x047F, 0x2000, ms(2010));
    assert!(!z.contains(Zsw1::AT_SETPOINT));
    assert!(z.contains(Zsw1::RUNNING_RIGHT));
    let mut t = ms(2010);
    while t < ms(6000) {
        t += ms(10);
        control(&mut d, 0x047F, 0x2000, t);
    }
    let (z, hiw) = control(&mut d, 0x047F, 0x2000, t);
    assert_eq!(d.frequency_hz(), 25.0);
    assert!(z.contains(Zsw1::AT_SETPOINT));
    assert_eq!(hiw, 0x2000, "HIW scales like the setpoint");
    assert_eq!(param(&d, 21), 25.0, "r0021 mirrors the output frequency");
    assert_eq!(
        d.params().get(52, 0),
        Some(u32::from(z.bits())),
        "r0052 mirrors ZSW1"
    );
    assert_eq!(d.params().get(54, 0), Some(0x047F), "r0054 mirrors STW1");
}

#[test]
fn off1_ramps_down_with_p1121_then_ready_to_switch_on() {
    let mut d = drive(PkwMode::Four);
    let mut t = run_to(&mut d, 0x4000, ms(10_100));
    assert_eq!(d.frequency_hz(), 50.0);
    t += ms(10);
    control(&mut d, 0x047E, 0x4000, t);
    assert_eq!(d.state(), State::SwitchingOff(Stop::Off1));
    t += ms(5000);
    control(&mut d, 0x047E, 0x4000, t);
    assert!(
        (d.frequency_hz() - 25.0).abs() < 0.06,
        "{}",
        d.frequency_hz()
    );
    t += ms(5100);
    control(&mut d, 0x047E, 0x4000, t);
    assert_eq!(d.frequency_hz(), 0.0);
    assert_eq!(d.state(), State::ReadyToSwitchOn);
}

#[test]
fn off2_coasts_at_once_to_s1() {
    let mut d = drive(PkwMode::Four);
    let t = run_to(&mut d, 0x4000, ms(3000));
    assert!(d.frequency_hz() > 10.0);
    let (z, _) = control(&mut d, 0x047C, 0x4000, t + ms(10));
    assert_eq!(d.state(), State::SwitchingOnInhibited);
    assert_eq!(d.frequency_hz(), 0.0);
    assert!(!z.contains(Zsw1::NO_OFF2), "ZSW1 bit 4 shows OFF2 active");
}

#[test]
fn off3_quick_stops_with_p1135_then_s1() {
    // P1135 = 5 s from P1082: 10 Hz/s.
    let mut d = drive(PkwMode::Four);
    let mut t = run_to(&mut d, 0x4000, ms(10_100));
    t += ms(10);
    control(&mut d, 0x047A, 0x4000, t);
    assert_eq!(d.state(), State::SwitchingOff(Stop::Off3));
    t += ms(2500);
    control(&mut d, 0x047A, 0x4000, t);
    assert!(
        (d.frequency_hz() - 25.0).abs() < 0.06,
        "{}",
        d.frequency_hz()
    );
    t += ms(2600);
    let (z, _) = control(&mut d, 0x047A, 0x4000, t);
    assert_eq!(d.state(), State::SwitchingOnInhibited);
    assert!(!z.contains(Zsw1::NO_OFF3));
}

#[test]
fn reverse_runs_left_and_max_frequency_clamps() {
    let mut d = drive(PkwMode::Four);
    // 0x6000 = 150 % of 50 Hz = 75 Hz, clamped to P1082 = 50 Hz; bit 11 reverses.
    let mut t = Duration::ZERO;
    control(&mut d, 0x047E, 0, t);
    while t < ms(10_200) {
        t += ms(10);
        control(&mut d, 0x047F | 0x0800, 0x6000, t);
    }
    let (z, hiw) = control(&mut d, 0x047F | 0x0800, 0x6000, t);
    assert_eq!(d.frequency_hz(), -50.0);
    assert_eq!(hiw, 0xC000, "-100 %");
    assert!(!z.contains(Zsw1::RUNNING_RIGHT));
    assert!(z.contains(Zsw1::MAX_FREQUENCY_REACHED));
}

#[test]
fn fault_acknowledge_needs_a_rising_edge_of_bit_7() {
    let mut d = drive(PkwMode::Four);
    let t = run_to(&mut d, 0x2000, ms(500));
    control(&mut d, 0x04FF, 0x2000, t + ms(10));
    d.trip(7);
    assert_eq!(d.state(), State::Fault);
    assert_eq!(d.frequency_hz(), 0.0);
    let (z, _) = control(&mut d, 0x04FE, 0, t + ms(20));
    assert_eq!(d.state(), State::Fault, "bit 7 held high is no edge");
    assert!(z.contains(Zsw1::FAULT));
    control(&mut d, 0x047E, 0, t + ms(30));
    assert_eq!(d.state(), State::Fault);
    let (z, _) = control(&mut d, 0x04FE, 0, t + ms(40));
    assert_eq!(
        d.state(),
        State::ReadyToSwitchOn,
        "acknowledged, then OFF1 leaves S1"
    );
    assert!(!z.contains(Zsw1::FAULT));
    assert_eq!(d.params().get(947, 0), Some(7), "r0947 keeps the fault");
}

#[test]
fn fault_buffer_holds_four_trips_of_two_faults_with_their_times() {
    let mut d = drive(PkwMode::Four);
    let acknowledge = |d: &mut Drive, t: Duration| {
        control(d, 0x047E, 0, t);
        control(d, 0x04FE, 0, t + ms(10));
        control(d, 0x047E, 0, t + ms(20));
    };
    // Trip 1 at 61 s with two faults; trip 2 at 1 h 2 min 3 s with one.
    control(&mut d, 0x047E, 0, Duration::from_secs(61));
    d.trip_with_value(7, 11);
    d.trip_with_value(30, 12);
    d.trip_with_value(30, 13);
    acknowledge(&mut d, Duration::from_secs(62));
    control(&mut d, 0x047E, 0, Duration::from_secs(3723));
    d.trip_with_value(72, 14);
    let read = |pnu: u16| (0..12).map(|i| d.params().get(pnu, i)).collect::<Vec<_>>();
    let words = |v: &[u32]| v.iter().map(|&w| Some(w)).collect::<Vec<_>>();
    let mut codes = words(&[72, 0, 7, 30, 0, 0, 0, 0]);
    codes.extend([None; 4]);
    assert_eq!(read(947), codes, "newest trip first, two faults per trip");
    let mut values = words(&[14, 0, 11, 12, 0, 0, 0, 0]);
    values.extend([None; 4]);
    assert_eq!(read(949), values, "a fault value per fault");
    // seconds | minutes << 8, hours | days << 8, month | year << 8 (a clock never set).
    assert_eq!(
        read(948),
        words(&[3 | 2 << 8, 1, 0, 1 | 1 << 8, 0, 0, 0, 0, 0, 0, 0, 0]),
        "three time words per trip"
    );
}

#[test]
fn stw1_without_bit_10_is_ignored() {
    let mut d = drive(PkwMode::Four);
    let t = run_to(&mut d, 0x2000, ms(500));
    // 0x007C would coast (OFF2) if the drive took it; without bit 10 it must not.
    control(&mut d, 0x007C, 0, t + ms(10));
    assert_eq!(d.state(), State::OperationEnabled);
    assert_eq!(d.stw1().bits(), 0x047F);
}

#[test]
fn telegram_off_time_trips_f0072_and_needs_acknowledge() {
    let mut config = DriveConfig::new(Address::new(ADDR).unwrap(), layout(PkwMode::Four, 2));
    config.telegram_off_time_ms = 100;
    let mut d = Drive::new(config);
    assert_eq!(d.params().get(2014, COM_LINK), Some(100));
    control(&mut d, 0x047E, 0, ms(0));
    control(&mut d, 0x047F, 0x2000, ms(50));
    d.advance(ms(150));
    assert_eq!(
        d.state(),
        State::OperationEnabled,
        "exactly P2014 is still in time"
    );
    d.advance(ms(151));
    assert_eq!(d.state(), State::Fault);
    assert_eq!(d.fault(), Some(FAULT_TELEGRAM_OFF));
    assert_eq!(d.params().get(947, 0), Some(u32::from(FAULT_TELEGRAM_OFF)));
    control(&mut d, 0x047E, 0, ms(300));
    control(&mut d, 0x04FE, 0, ms(310));
    assert_eq!(d.state(), State::ReadyToSwitchOn);
    assert_eq!(d.fault(), None);
}

#[test]
fn telegrams_without_bit_10_count_as_missing_for_monitoring() {
    let mut config = DriveConfig::new(Address::new(ADDR).unwrap(), layout(PkwMode::Four, 2));
    config.telegram_off_time_ms = 100;
    let mut d = Drive::new(config);
    control(&mut d, 0x047E, 0, ms(0));
    for i in 1..=20 {
        control(&mut d, 0x007E, 0, ms(10 * i));
    }
    assert_eq!(d.fault(), Some(FAULT_TELEGRAM_OFF));
}

#[test]
fn telegram_monitoring_is_off_with_p2014_zero() {
    let mut d = drive(PkwMode::Four);
    control(&mut d, 0x047E, 0, ms(0));
    d.advance(Duration::from_secs(60));
    assert_eq!(d.state(), State::ReadyToSwitchOn);
}

#[test]
fn read_p1082_over_pkw4_is_50_hz_as_float() {
    let mut d = drive(PkwMode::Four);
    let (pkw, pzd) = send(&mut d, &[0x1000 | 1082, 0, 0, 0], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0x2000 | 1082, 0, 0x4248, 0x0000]);
    assert_eq!(
        pzd[0] & 0x0001,
        0x0001,
        "PZD comes with the parameter reply: S2"
    );
}

#[test]
fn read_p2000_uses_the_page_bit() {
    let mut d = drive(PkwMode::Four);
    let (pkw, _) = send(&mut d, &[0x1000, 0x8000, 0, 0], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0x2000, 0x8000, 0x4248, 0x0000]);
}

#[test]
fn variable_pkw_replies_3_words_for_a_word_and_4_for_a_dword() {
    let mut d = drive(PkwMode::Variable);
    let (pkw, _) = send(&mut d, &[0x1000 | 700, 0, 0, 0], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0x1000 | 700, 0, 5]);
    let (pkw, _) = send(&mut d, &[0x1000 | 1082, 0, 0, 0], &[0x047E, 0], ms(10)).unwrap();
    assert_eq!(pkw, vec![0x2000 | 1082, 0, 0x4248, 0]);
}

#[test]
fn no_task_is_answered_with_ak_0() {
    let mut d = drive(PkwMode::Four);
    let (pkw, _) = send(&mut d, &[0, 0, 0, 0], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0, 0, 0, 0]);
}

#[test]
fn eeprom_write_is_busy_then_answered_and_survives_power_cycle() {
    let mut d = drive(PkwMode::Four);
    // AK 13: change dword in RAM + EEPROM, P1120 = 3.0 s (0x4040_0000).
    let task = [0xD000 | 1120, 0, 0x4040, 0x0000];
    for i in 0..3 {
        let (pkw, _) = send(&mut d, &task, &[0x047E, 0], ms(10 * i)).unwrap();
        assert_eq!(pkw[0] >> 12, 0, "busy reply {i}");
        assert_eq!(pkw[0] & 0x7FF, 1120);
    }
    let (pkw, _) = send(&mut d, &task, &[0x047E, 0], ms(40)).unwrap();
    assert_eq!(pkw, vec![0x2000 | 1120, 0, 0x4040, 0x0000]);
    // AK 3: RAM only, P1121 = 4.0 s.
    let (pkw, _) = send(&mut d, &[0x3000 | 1121, 0, 0x4080, 0], &[0x047E, 0], ms(50)).unwrap();
    assert_eq!(
        pkw,
        vec![0x2000 | 1121, 0, 0x4080, 0x0000],
        "RAM writes answer at once"
    );
    assert_eq!(param(&d, 1121), 4.0);
    d.power_cycle();
    assert_eq!(d.state(), State::SwitchingOnInhibited);
    assert_eq!(param(&d, 1120), 3.0, "EEPROM value survives");
    assert_eq!(param(&d, 1121), 10.0, "RAM value is lost");
}

#[test]
fn repeated_task_is_answered_without_executing_it_again() {
    let mut d = drive(PkwMode::Four);
    let task = [0x3000 | 1120, 0, 0x4040, 0x0000];
    send(&mut d, &task, &[0x047E, 0], ms(0)).unwrap();
    d.params_mut().set_internal(1120, 0, 4.0f32.to_bits());
    let (pkw, _) = send(&mut d, &task, &[0x047E, 0], ms(10)).unwrap();
    assert_eq!(
        pkw,
        vec![0x2000 | 1120, 0, 0x4040, 0x0000],
        "the stored reply"
    );
    assert_eq!(param(&d, 1120), 4.0, "not written again");
    // A changed task is a new task.
    let (pkw, _) = send(&mut d, &[0x1000 | 1120, 0, 0, 0], &[0x047E, 0], ms(20)).unwrap();
    assert_eq!(pkw, vec![0x2000 | 1120, 0, 0x4080, 0x0000]);
}

#[test]
fn busy_drive_answers_every_task_late() {
    let mut config = DriveConfig::new(Address::new(ADDR).unwrap(), layout(PkwMode::Four, 2));
    config.task_busy_telegrams = 2;
    let mut d = Drive::new(config);
    let read = [0x1000 | 700, 0, 0, 0];
    for i in 0..2 {
        let (pkw, _) = send(&mut d, &read, &[0x047E, 0], ms(i)).unwrap();
        assert_eq!(pkw, vec![700, 0, 0, 0]);
    }
    let (pkw, _) = send(&mut d, &read, &[0x047E, 0], ms(3)).unwrap();
    assert_eq!(pkw, vec![0x1000 | 700, 0, 0, 5]);
}

#[test]
fn dword_over_three_word_pkw_is_error_5_or_configured_103() {
    let mut d = Drive::new(DriveConfig::new(
        Address::new(ADDR).unwrap(),
        layout(PkwMode::Three, 2),
    ));
    let (pkw, _) = send(&mut d, &[0x3000 | 1120, 0, 0x4040], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0x7000 | 1120, 0, 5]);
    let mut config = DriveConfig::new(Address::new(ADDR).unwrap(), layout(PkwMode::Three, 2));
    config.dword_over_three_words = ErrorNumber::DwordOverThreeWords;
    let mut d = Drive::new(config);
    let (pkw, _) = send(&mut d, &[0x3000 | 1120, 0, 0x4040], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0x7000 | 1120, 0, 103]);
}

#[test]
fn unsupported_task_ids_are_error_106() {
    let mut d = drive(PkwMode::Four);
    for ak in [5u16, 10, 15] {
        let (pkw, _) = send(
            &mut d,
            &[(ak << 12) | 1082, 0, 0, 0],
            &[0x047E, 0],
            ms(u64::from(ak)),
        )
        .unwrap();
        let reply = ParamReply::decode(&pkw).unwrap();
        assert_eq!(
            reply.kind,
            ReplyKind::Error(ErrorNumber::TaskNotImplemented),
            "AK {ak}"
        );
    }
}

#[test]
fn parameters_changeable_only_when_stopped_refuse_while_running() {
    let mut d = drive(PkwMode::Four);
    let t = run_to(&mut d, 0x2000, ms(100));
    // P1082 (max frequency) is not changeable while running: error 17.
    let (pkw, _) = send(
        &mut d,
        &[0x3000 | 1082, 0, 0x4270, 0],
        &[0x047F, 0x2000],
        t + ms(10),
    )
    .unwrap();
    assert_eq!(pkw, vec![0x7000 | 1082, 0, 0, 17]);
    send(&mut d, &[0, 0, 0, 0], &[0x047F, 0x2000], t + ms(20)).unwrap();
    // PZD is processed first: a telegram with OFF2 stops the drive, so its write succeeds.
    let (pkw, _) = send(
        &mut d,
        &[0x3000 | 1082, 0, 0x4270, 0],
        &[0x047C, 0],
        t + ms(30),
    )
    .unwrap();
    assert_eq!(pkw, vec![0x2000 | 1082, 0, 0x4270, 0]);
}

#[test]
fn telegram_of_wrong_length_is_rejected_silently_and_counted() {
    let mut d = drive(PkwMode::Four);
    // PKW 3 + PZD 2 to a PKW 4 drive.
    assert!(send(&mut d, &[0x1000, 0, 0], &[0x047E, 0], ms(0)).is_none());
    let c = d.counters();
    assert_eq!((c.good, c.rejected, c.length), (0, 1, 1));
    assert_eq!(
        d.params().get(2031, COM_LINK),
        Some(1),
        "r2031 length errors"
    );
    assert_eq!(d.params().get(2025, COM_LINK), Some(1), "r2025 rejected");
    send(&mut d, &[0, 0, 0, 0], &[0x047E, 0], ms(10)).unwrap();
    assert_eq!(d.params().get(2024, COM_LINK), Some(1), "r2024 good");
}

#[test]
fn a_ramp_time_too_short_to_matter_ends_the_ramp_at_once_and_never_gives_nan() {
    let mut d = drive(PkwMode::Four);
    // AK 3: P1120 = 1.2e-38 s (the smallest normal floats), accepted by the drive's limits.
    let tiny = 1.2e-38f32.to_bits();
    let task = [0x3000 | 1120, 0, (tiny >> 16) as u16, tiny as u16];
    let (pkw, _) = send(&mut d, &task, &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw[0] >> 12, 2, "changed: {pkw:04X?}");
    let t = run_to(&mut d, 0x2000, ms(30));
    // Same instant again (a zero time step), then later: always 25 Hz, never NaN.
    for at in [t, t, t + ms(1), t + ms(10)] {
        let (_, hiw) = control(&mut d, 0x047F, 0x2000, at);
        assert!(d.frequency_hz().is_finite(), "{}", d.frequency_hz());
        assert_eq!(d.frequency_hz(), 25.0);
        assert_eq!(hiw, 0x2000);
    }
}

#[test]
fn states_print_as_the_manuals_name_them() {
    assert_eq!(State::OperationEnabled.to_string(), "S4 operation enabled");
    assert_eq!(
        State::SwitchingOff(Stop::Off3).to_string(),
        "S5 OFF3 quick stop"
    );
    assert_eq!(
        State::SwitchingOnInhibited.to_string(),
        "S1 switching on inhibited"
    );
}

#[test]
fn a_generic_slave_answers_its_own_parameters_and_a_fragile_one_dies_of_any_other() {
    use uss_drive_sim::drive::Personality;
    let generic = |fragile| {
        Drive::new(DriveConfig {
            personality: Personality::Generic { fragile },
            ..DriveConfig::new(Address::new(ADDR).unwrap(), layout(PkwMode::Four, 2))
        })
    };
    let mut d = generic(false);
    // P1 a word (AK 1), P3 a double word (AK 2), P2 written.
    let (pkw, _) = send(&mut d, &[0x1000 | 1, 0, 0, 0], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0x1000 | 1, 0, 0, 0x0A51]);
    let (pkw, _) = send(&mut d, &[0x1000 | 3, 0, 0, 0], &[0x047E, 0], ms(10)).unwrap();
    assert_eq!(pkw, vec![0x2000 | 3, 0, 0, 12_345]);
    let (pkw, _) = send(&mut d, &[0x2000 | 2, 0, 0, 700], &[0x047E, 0], ms(20)).unwrap();
    assert_eq!(pkw, vec![0x1000 | 2, 0, 0, 700]);
    // P2014 index 0 (an array read) and P1's description are unknown here: error 0.
    // (P2014 is PNU part 14 with the page bit in IND.)
    let (pkw, _) = send(&mut d, &[0x6000 | 14, 0x8001, 0, 0], &[0x047E, 0], ms(30)).unwrap();
    assert_eq!(pkw, vec![0x7000 | 14, 0x8001, 0, 0]);
    // The fragile one answers nothing from then on.
    let mut d = generic(true);
    assert!(send(&mut d, &[0x1000 | 1, 0, 0, 0], &[0x047E, 0], ms(0)).is_some());
    assert!(send(&mut d, &[0x4000 | 1, 0, 0, 0], &[0x047E, 0], ms(10)).is_none());
    assert!(d.is_dead());
    assert!(send(&mut d, &[0, 0, 0, 0], &[0x047E, 0], ms(20)).is_none());
}

/// A reversal (+20 Hz to -20 Hz, P1120 = 2 s, P1121 = 10 s, P1082 = 50 Hz) ramps down with
/// P1121 (5 Hz/s) while |f| falls towards zero, and up with P1120 (25 Hz/s) on the other side,
/// as a MICROMASTER's ramp-function generator does.
#[test]
fn a_reversal_ramps_down_with_p1121_until_zero_then_up_with_p1120() {
    let mut d = drive(PkwMode::Four);
    d.params_mut().set_internal(1120, 0, 2.0f32.to_bits());
    d.params_mut().set_internal(1121, 0, 10.0f32.to_bits());
    // 0x199A = 40 % of P2000 (50 Hz) = 20 Hz, reached at 25 Hz/s after 0.8 s.
    let mut t = run_to(&mut d, 0x199A, ms(1000));
    assert!(
        (d.frequency_hz() - 20.0).abs() < 0.01,
        "{}",
        d.frequency_hz()
    );
    let minus = (-0x199A_i16) as u16;
    for _ in 0..100 {
        t += ms(10);
        control(&mut d, 0x047F, minus, t);
    }
    // 1 s down at 5 Hz/s: 15 Hz (with P1120's 25 Hz/s it would be past zero at -5 Hz).
    assert!(
        (d.frequency_hz() - 15.0).abs() < 0.1,
        "{}",
        d.frequency_hz()
    );
    for _ in 0..400 {
        t += ms(10);
        control(&mut d, 0x047F, minus, t);
    }
    // 3 s more reach zero at 5 Hz/s, and -20 Hz 0.8 s after zero at 25 Hz/s (4 s in all).
    assert!(
        (d.frequency_hz() + 20.0).abs() < 0.01,
        "{}",
        d.frequency_hz()
    );
}

/// A refused task whose PNU field holds 2000..2047 without the page bit (PKE 0x27DD: AK 2,
/// P2013 written as it is not encoded) is answered with its PNU bits echoed, as every reply
/// does (USS.md section 6): PKE 0x77DD, error 0 (illegal PNU).
#[test]
fn a_refused_task_echoes_its_pnu_bits_even_when_they_name_no_parameter() {
    let mut d = drive(PkwMode::Four);
    let (pkw, _) = send(&mut d, &[0x27DD, 0x0000, 0, 5], &[0x047E, 0], ms(0)).unwrap();
    assert_eq!(pkw, vec![0x77DD, 0x0000, 0, 0]);
}

/// A drive being commissioned (P0010 = 1) does not switch on (`ParamTable::in_commissioning`):
/// it stays ready to switch on until P0010 is 0 again, here by the end of quick commissioning
/// (P3900 = 3), which also sets P3900 back to 0.
#[test]
fn a_drive_in_quick_commissioning_does_not_switch_on_until_p3900_ends_it() {
    let mut d = drive(PkwMode::Four);
    d.params_mut().set_internal(10, 0, 1);
    run_to(&mut d, 0x2000, ms(500));
    assert_eq!(d.state(), State::ReadyToSwitchOn);
    assert_eq!(d.frequency_hz(), 0.0);
    // The end of quick commissioning, as the PKW channel writes it (a word, RAM).
    let task = uss_protocol::ParamTask::Write {
        pnu: uss_protocol::Pnu::new(3900).unwrap(),
        value: uss_protocol::Value::Word(3),
        storage: uss_protocol::Storage::Ram,
    };
    let outcome = d.params_mut().execute(
        &task,
        PkwMode::Four,
        uss_drive_sim::params::DriveContext::default(),
    );
    assert_eq!(outcome, ReplyKind::Word(3), "taken");
    assert_eq!(d.params().get(10, 0), Some(0), "out of quick commissioning");
    assert_eq!(d.params().get(3900, 0), Some(0), "the calculation is done");
    run_to(&mut d, 0x2000, ms(500));
    assert!(d.state().is_running(), "{:?}", d.state());
}
