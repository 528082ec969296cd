//! The virtual wire: real character timing, response delay, echo, and the drives' own receive
//! rules (start pause, residual time) applied to what the master sends (USS.md section 4).
#![allow(clippy::unwrap_used)]

use std::time::Duration;
use uss_drive_sim::{DriveConfig, Fault, RxByte, SimBus, VirtualWire};
use uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, encode};
use uss_protocol::{Address, Adr, Baud, Framer, FramerConfig, LineError, Telegram, Timing};

const BAUD: u32 = 19200;

fn timing() -> Timing {
    Timing::new(Baud::new(BAUD).unwrap())
}

fn wire(delay_ms: u64) -> VirtualWire {
    wire_at(timing(), delay_ms)
}

fn wire_at(timing: Timing, delay_ms: u64) -> VirtualWire {
    let mut bus = SimBus::new(1);
    let mut config = DriveConfig::new(
        Address::new(1).unwrap(),
        Layout::new(PkwMode::Four, PzdCount::new(2).unwrap()),
    );
    config.response_delay = Duration::from_millis(delay_ms);
    bus.add(config).unwrap();
    VirtualWire::new(bus, timing)
}

fn request(stw: u16) -> Vec<u8> {
    let mut buf = [0u8; MAX_TELEGRAM_BYTES];
    let n = encode(
        &mut buf,
        Adr::to(Address::new(1).unwrap()),
        &[0x1000 | 1082, 0, 0, 0],
        &[stw, 0],
    )
    .unwrap();
    buf[..n].to_vec()
}

fn drain(w: &mut VirtualWire) -> Vec<RxByte> {
    std::iter::from_fn(|| w.receive(Duration::MAX)).collect()
}

#[test]
fn bytes_take_their_wire_time_and_the_reply_follows_the_response_delay() {
    let mut w = wire(2);
    let tz = timing().char_time();
    let t0 = Duration::from_millis(10);
    let req = request(0x047E);
    let end = w.transmit(&req, t0);
    assert_eq!(end, t0 + tz * 16, "16 characters of 11 bits at 19200 baud");
    let first = w.next_arrival().unwrap();
    assert_eq!(
        first,
        end + Duration::from_millis(2) + tz,
        "STX complete one tz after the delay"
    );
    assert_eq!(
        w.receive(first.saturating_sub(Duration::from_nanos(1))),
        None,
        "not before it arrives"
    );
    let rx = drain(&mut w);
    assert_eq!(rx.len(), 16);
    for (i, b) in rx.iter().enumerate() {
        assert_eq!(b.at, first + tz * i as u32);
        assert_eq!(b.error, None);
    }
    let bytes: Vec<u8> = rx.iter().map(|b| b.byte).collect();
    let reply = Telegram::parse(&bytes).unwrap();
    assert_eq!(
        &reply.net()[..8],
        &[0x24, 0x3A, 0, 0, 0x42, 0x48, 0, 0],
        "P1082 = 50.0 Hz"
    );
}

#[test]
fn echo_returns_the_masters_own_bytes_first() {
    let mut w = wire(1).with_echo(true);
    let req = request(0x047E);
    w.transmit(&req, Duration::ZERO);
    let rx: Vec<u8> = drain(&mut w).iter().map(|b| b.byte).collect();
    assert_eq!(&rx[..req.len()], &req[..]);
    assert!(Telegram::parse(&rx[req.len()..]).is_ok());
}

#[test]
fn request_without_start_pause_after_the_reply_is_not_answered() {
    let mut w = wire(1);
    let end = w.transmit(&request(0x047E), Duration::ZERO);
    let rx = drain(&mut w);
    let reply_end = rx.last().unwrap().at;
    assert!(reply_end > end);
    // Its STX completes one tz after the reply's BCC: less than the 2 tz start pause.
    w.transmit(&request(0x047E), reply_end);
    assert!(drain(&mut w).is_empty());
    assert_eq!(
        w.bus()
            .drive(Address::new(1).unwrap())
            .unwrap()
            .counters()
            .start,
        1
    );
    // With the pause the next request is answered.
    let later = reply_end + Duration::from_millis(50);
    w.transmit(&request(0x047E), later);
    assert_eq!(drain(&mut w).len(), 16);
}

#[test]
fn request_slower_than_the_residual_time_is_dropped_by_the_drive() {
    let mut w = wire(1);
    let req = request(0x047E);
    let t = timing();
    let end = w.transmit(&req[..5], Duration::ZERO);
    // The rest arrives after 1.5 x (n+3) tz from the STX.
    let late = t.char_time() + t.max_residual(12) + Duration::from_micros(1);
    assert!(late > end);
    w.transmit(&req[5..], late);
    assert!(drain(&mut w).is_empty());
    assert_eq!(
        w.bus()
            .drive(Address::new(1).unwrap())
            .unwrap()
            .counters()
            .length,
        1
    );
}

#[test]
fn corrupted_byte_arrives_flagged_with_a_parity_error() {
    let mut w = wire(1);
    w.bus_mut()
        .faults_mut(Address::new(1).unwrap())
        .unwrap()
        .script([Some(Fault::CorruptByte)]);
    w.transmit(&request(0x047E), Duration::ZERO);
    let rx = drain(&mut w);
    assert_eq!(
        rx.iter()
            .filter(|b| b.error == Some(LineError::Parity))
            .count(),
        1
    );
}

#[test]
fn late_reply_overlapping_the_next_request_arrives_in_time_order() {
    let mut w = wire(1).with_echo(true);
    w.bus_mut()
        .faults_mut(Address::new(1).unwrap())
        .unwrap()
        .script([Some(Fault::Late)]);
    let end = w.transmit(&request(0x047E), Duration::ZERO);
    // The master gives up at 20 ms and sends again while the late reply is still coming.
    w.flush_input(end);
    w.transmit(&request(0x047E), end + Duration::from_millis(20));
    let rx = drain(&mut w);
    assert!(rx.windows(2).all(|p| p[0].at <= p[1].at));
}

#[test]
fn flush_input_drops_only_what_has_arrived() {
    let mut w = wire(1);
    let end = w.transmit(&request(0x047E), Duration::ZERO);
    let first = w.next_arrival().unwrap();
    w.flush_input(first + timing().char_time() * 3);
    assert_eq!(drain(&mut w).len(), 12);
    assert!(first > end);
}

/// A slave keeps the start pause before its reply too (USS.md section 4): even a drive set to
/// answer at once starts its reply no sooner than the start pause plus one character time, at
/// every baud rate, so a strict master takes every reply.
#[test]
fn a_reply_never_starts_before_the_start_pause_at_any_baud() {
    for baud in Baud::STANDARD {
        let timing = Timing::new(Baud::new(baud).unwrap());
        for delay_ms in [0, 1] {
            let mut w = wire_at(timing, delay_ms);
            let end = w.transmit(&request(0x047E), Duration::ZERO);
            let rx = drain(&mut w);
            let stx_done = rx.first().unwrap().at;
            let delay = Duration::from_millis(delay_ms).max(timing.earliest_reply());
            assert_eq!(stx_done, end + delay + timing.char_time(), "{baud} baud");
            assert!(stx_done >= end + timing.start_pause() + timing.char_time());
            let mut master = Framer::new(FramerConfig::strict(timing));
            master.line_busy_until(end);
            let mut complete = false;
            for b in &rx {
                if let Some(got) = master.push(b.byte, b.at) {
                    assert!(got.is_ok(), "{baud} baud, delay {delay_ms}: {got:?}");
                    complete = true;
                }
            }
            assert!(complete, "{baud} baud, delay {delay_ms}: no telegram");
        }
    }
}
