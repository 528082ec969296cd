//! The simulator's families: each runs its own parameter set through the same drive model
//! (ramp, reference, telegram monitoring, fault buffer, command source), driven through real
//! telegrams.
#![allow(clippy::unwrap_used, clippy::float_cmp)]

use std::time::Duration;
use uss_drive_sim::drive::Personality;
use uss_drive_sim::{Drive, DriveConfig, State};
use uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, Telegram, encode};
use uss_protocol::{Address, Adr, ParamReply, ParamTask, Pnu, ReplyKind, Storage, Value, Zsw1};

const ADDR: u8 = 2;

fn drive(personality: Personality, p2014: u16) -> Drive {
    let mut config = DriveConfig::new(
        Address::new(ADDR).unwrap(),
        Layout::new(PkwMode::Four, PzdCount::new(2).unwrap()),
    );
    config.personality = personality;
    config.telegram_off_time_ms = p2014;
    let mut options = uss_drive_sim::SimOptions {
        family: Some(
            match personality {
                Personality::G110 => "g110",
                Personality::G120 => "g120",
                Personality::SIMOREG => "simoreg",
                _ => "micromaster4",
            }
            .to_owned(),
        ),
        ..Default::default()
    };
    options.p2014 = Some(p2014);
    options
        .apply(&mut config, &mut uss_drive_sim::FaultPlan::new())
        .unwrap();
    Drive::new(config)
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// One telegram with a PKW task; the reply's kind and ZSW1.
fn send(d: &mut Drive, task: ParamTask, stw: u16, hsw: u16, now: Duration) -> (ReplyKind, Zsw1) {
    let mut pkw = [0u16; 4];
    task.encode(PkwMode::Four, &mut pkw).unwrap();
    let mut req = [0u8; MAX_TELEGRAM_BYTES];
    let n = encode(
        &mut req,
        Adr::to(Address::new(ADDR).unwrap()),
        &pkw,
        &[stw, hsw],
    )
    .unwrap();
    let mut out = [0u8; MAX_TELEGRAM_BYTES];
    let len = d
        .receive(&Telegram::parse(&req[..n]).unwrap(), now, &mut out)
        .unwrap();
    let reply = Telegram::parse(&out[..len]).unwrap();
    let words = reply.words(d.config().layout).unwrap();
    let kind = ParamReply::decode(words.pkw()).unwrap().kind;
    (kind, Zsw1::from_bits_retain(words.pzd()[0]))
}

fn read(d: &mut Drive, pnu: u16, index: Option<u8>, now: Duration) -> ReplyKind {
    let index = index.map(|i| uss_protocol::Subindex::new(i).unwrap());
    send(
        d,
        ParamTask::read(Pnu::from_u16(pnu), index),
        0x047E,
        0,
        now,
    )
    .0
}

/// Runs to 50 % of the reference for `secs` and returns the time reached.
fn run(d: &mut Drive, secs: u64) -> Duration {
    let mut t = Duration::ZERO;
    send(d, ParamTask::None, 0x047E, 0, t);
    while t < ms(secs * 1000) {
        t += ms(10);
        send(d, ParamTask::None, 0x047F, 0x2000, t);
    }
    t
}

#[test]
fn a_g120_runs_in_rpm_and_keeps_its_faults_in_r0945_and_r0949() {
    let mut d = drive(Personality::G120, 0);
    // p2000 = 1500 rpm, p1120 = 10 s from 0 to p1082 = 1500 rpm: 750 rpm after 5 s.
    let t = run(&mut d, 5);
    assert_eq!(d.state(), State::OperationEnabled);
    assert!(
        (d.frequency_hz() - 750.0).abs() < 2.0,
        "{}",
        d.frequency_hz()
    );
    assert!(
        matches!(read(&mut d, 21, None, t), ReplyKind::Dword(v) if (f32::from_bits(v) - 750.0).abs() < 2.0)
    );
    // The MICROMASTER 4's numbers are not there.
    assert!(matches!(
        read(&mut d, 2014, Some(1), t),
        ReplyKind::Error(_)
    ));
    d.trip_with_value(7011, 3);
    assert_eq!(read(&mut d, 945, Some(0), t), ReplyKind::ArrayWord(7011));
    assert_eq!(read(&mut d, 949, Some(0), t), ReplyKind::ArrayDword(3));
    // The device identification: Siemens.
    assert_eq!(read(&mut d, 964, Some(0), t), ReplyKind::ArrayWord(42));
}

#[test]
fn a_g120_watches_its_fieldbus_with_p2040_in_ms() {
    let mut d = drive(Personality::G120, 100);
    assert_eq!(
        read(&mut d, 2040, None, ms(0)),
        ReplyKind::Dword(100f32.to_bits())
    );
    let t = run(&mut d, 1);
    d.advance(t + ms(150));
    assert_eq!(d.fault(), Some(1910), "F01910 fieldbus setpoint timeout");
}

#[test]
fn a_g120_with_its_commands_elsewhere_says_so_in_zsw1_bit_9() {
    let mut d = drive(Personality::G120, 0);
    let (_, z) = send(&mut d, ParamTask::None, 0x047E, 0, ms(0));
    assert!(z.contains(Zsw1::CONTROL_REQUESTED));
    let write = ParamTask::write(Pnu::from_u16(700), None, Value::Word(2), Storage::Ram);
    assert_eq!(send(&mut d, write, 0x047E, 0, ms(10)).0, ReplyKind::Word(2));
    let (_, z) = send(&mut d, ParamTask::None, 0x047F, 0x2000, ms(20));
    assert!(!z.contains(Zsw1::CONTROL_REQUESTED));
    assert_ne!(d.state(), State::OperationEnabled);
}

#[test]
fn a_simoreg_ramps_with_p303_in_10_ms_and_keeps_its_faults_in_r947() {
    let mut d = drive(Personality::SIMOREG, 0);
    // P303 = 1000 x 10 ms = 10 s from 0 to 100 %: 50 % (the setpoint) after 5 s.
    let t = run(&mut d, 5);
    assert!(
        (d.frequency_hz() - 50.0).abs() < 0.5,
        "{}",
        d.frequency_hz()
    );
    let write = ParamTask::write(Pnu::from_u16(303), None, Value::Word(200), Storage::Ram);
    assert_eq!(
        send(&mut d, write, 0x047F, 0x2000, t).0,
        ReplyKind::Word(200)
    );
    d.trip_with_value(30, 4);
    assert_eq!(read(&mut d, 947, Some(0), t), ReplyKind::ArrayWord(30));
    assert_eq!(read(&mut d, 949, Some(0), t), ReplyKind::ArrayWord(4));
    assert!(matches!(read(&mut d, 700, None, t), ReplyKind::Error(_)));
}

#[test]
fn a_g110_has_the_micromaster_numbers_and_its_own_firmware() {
    let mut d = drive(Personality::G110, 0);
    assert_eq!(
        read(&mut d, 18, None, ms(0)),
        ReplyKind::Dword(1.18f32.to_bits())
    );
    assert_eq!(read(&mut d, 2014, Some(1), ms(0)), ReplyKind::ArrayWord(0));
    d.trip(2);
    assert_eq!(read(&mut d, 947, Some(0), ms(0)), ReplyKind::ArrayWord(2));
}

/// Issue 46, item 6: the simulator read P2010/p2020 as 9600 baud on a 19200 line. A drive is
/// commissioned for the line it is on: MM4's P2010[0] (USS.md section 2: 7 = 19200) and a G120's
/// p2020 (CU230P-2 OI 01/2011 p.120: 12 = 115200) name the line's rate, across a power cycle;
/// where its list names no value for the rate, the setting stays its default.
#[test]
fn a_drive_commissioned_for_its_line_names_the_lines_baud_rate() {
    let baud = |b| uss_protocol::Baud::new(b).unwrap();
    let mut mm4 = drive(Personality::MICROMASTER4, 0);
    mm4.commission_line(baud(19200));
    assert_eq!(mm4.params().get(2010, 0), Some(7));
    mm4.power_cycle();
    assert_eq!(mm4.params().get(2010, 0), Some(7), "kept in EEPROM");
    let mut g120 = drive(Personality::G120, 0);
    g120.commission_line(baud(115_200));
    assert_eq!(g120.params().get(2020, 0), Some(12));
    let mut fast = drive(Personality::MICROMASTER4, 0);
    fast.commission_line(baud(115_200));
    assert_eq!(
        fast.params().get(2010, 0),
        Some(6),
        "no MM4 value for 115200: the default"
    );
}

/// Issue 46, item 6: the simulator read r0002 = 0 (commissioning mode) and r0026 = 0 V on a
/// powered drive. r0002 says the state (0 commissioning, 1 ready, 2 fault, 4 running, 5
/// stopping), r0026 the DC link of a powered 400 V unit (sqrt(2) x r0208).
#[test]
fn a_micromaster_says_its_drive_state_and_dc_link_voltage() {
    let mut d = drive(Personality::MICROMASTER4, 0);
    let state = |d: &mut Drive, t| read(d, 2, None, t);
    assert_eq!(state(&mut d, ms(0)), ReplyKind::Word(1), "ready");
    assert_eq!(read(&mut d, 208, None, ms(0)), ReplyKind::Dword(400));
    assert!(
        matches!(read(&mut d, 26, None, ms(0)), ReplyKind::Dword(v) if (f32::from_bits(v) - 565.7).abs() < 0.1),
        "{:?}",
        read(&mut d, 26, None, ms(0))
    );
    let t = run(&mut d, 1);
    let r0002 = ParamTask::read(Pnu::from_u16(2), None);
    // Read while ON is still sent (`read` sends OFF1).
    assert_eq!(
        send(&mut d, r0002, 0x047F, 0x2000, t).0,
        ReplyKind::Word(4),
        "running"
    );
    // OFF1. A task repeated telegram after telegram is one task to a USS slave, answered as
    // first: a telegram without a task in between makes the next read a new one.
    send(&mut d, ParamTask::None, 0x047E, 0, t + ms(10));
    assert_eq!(state(&mut d, t + ms(20)), ReplyKind::Word(5), "stopping");
    send(&mut d, ParamTask::None, 0x047E, 0, t + ms(25));
    d.trip(2);
    assert_eq!(state(&mut d, t + ms(30)), ReplyKind::Word(2), "fault");
    let mut d = drive(Personality::MICROMASTER4, 0);
    let level = ParamTask::write(Pnu::from_u16(3), None, Value::Word(3), Storage::Ram);
    assert_eq!(send(&mut d, level, 0x047E, 0, ms(0)).0, ReplyKind::Word(3));
    let quick = ParamTask::write(Pnu::from_u16(10), None, Value::Word(1), Storage::Ram);
    assert_eq!(send(&mut d, quick, 0x047E, 0, ms(10)).0, ReplyKind::Word(1));
    assert_eq!(
        state(&mut d, ms(20)),
        ReplyKind::Word(0),
        "commissioning mode"
    );
    let mut g110 = drive(Personality::G110, 0);
    assert_eq!(read(&mut g110, 208, None, ms(0)), ReplyKind::Dword(230));
}
