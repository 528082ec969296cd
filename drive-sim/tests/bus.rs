//! The simulated bus and its fault injector: who answers, broadcast, mirror, special telegrams,
//! and every kind of injected fault (USS.md sections 1, 3, 4 and 9).
#![allow(clippy::unwrap_used)]

use std::time::Duration;
use uss_drive_sim::{BusError, DriveConfig, Fault, SimBus, State};
use uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, Telegram, encode};
use uss_protocol::{Address, Adr, DecodeError, FrameError};

fn addr(a: u8) -> Address {
    Address::new(a).unwrap()
}

fn bus(addresses: &[u8]) -> SimBus {
    let mut bus = SimBus::new(7);
    for &a in addresses {
        let layout = Layout::new(PkwMode::Four, PzdCount::new(2).unwrap());
        bus.add(DriveConfig::new(addr(a), layout)).unwrap();
    }
    bus
}

fn request(adr: Adr, stw: u16) -> ([u8; MAX_TELEGRAM_BYTES], usize) {
    let mut buf = [0u8; MAX_TELEGRAM_BYTES];
    let n = encode(&mut buf, adr, &[0, 0, 0, 0], &[stw, 0]).unwrap();
    (buf, n)
}

fn exchange(bus: &mut SimBus, adr: Adr, stw: u16, now: Duration) -> Option<uss_drive_sim::Reply> {
    let (buf, n) = request(adr, stw);
    bus.on_telegram(&Telegram::parse(&buf[..n]).unwrap(), now)
}

#[test]
fn only_the_addressed_drive_answers() {
    let mut b = bus(&[1, 2]);
    let reply = exchange(&mut b, Adr::to(addr(2)), 0x047E, Duration::ZERO).unwrap();
    let t = Telegram::parse(reply.bytes()).unwrap();
    assert_eq!(t.adr().address, addr(2));
    assert_eq!(b.drive(addr(2)).unwrap().state(), State::ReadyToSwitchOn);
    assert_eq!(
        b.drive(addr(1)).unwrap().state(),
        State::SwitchingOnInhibited
    );
    assert_eq!(reply.delay, Duration::from_millis(1));
    assert!(exchange(&mut b, Adr::to(addr(9)), 0x047E, Duration::ZERO).is_none());
    assert_eq!(b.unanswered, 1);
}

#[test]
fn broadcast_is_processed_by_all_and_answered_by_none() {
    let mut b = bus(&[1, 2]);
    let adr = Adr {
        broadcast: true,
        ..Adr::to(addr(0))
    };
    assert!(exchange(&mut b, adr, 0x047E, Duration::ZERO).is_none());
    for a in [1, 2] {
        assert_eq!(b.drive(addr(a)).unwrap().state(), State::ReadyToSwitchOn);
    }
}

#[test]
fn a_broadcast_pkw_task_is_ignored_and_a_drive_that_takes_no_broadcasts_ignores_it_all() {
    let layout = Layout::new(PkwMode::Four, PzdCount::new(2).unwrap());
    let mut b = SimBus::new(7);
    b.add(DriveConfig::new(addr(1), layout)).unwrap();
    b.add(DriveConfig {
        takes_broadcasts: false,
        ..DriveConfig::new(addr(2), layout)
    })
    .unwrap();
    // A write of P1082 = 10.0 (AK 3, PNU 1082, float 10.0) with STW1 OFF1, broadcast.
    let mut buf = [0u8; MAX_TELEGRAM_BYTES];
    let n = encode(
        &mut buf,
        Adr::broadcast(),
        &[0x3000 | 1082, 0, 0x4120, 0],
        &[0x047E, 0],
    )
    .unwrap();
    let t = Telegram::parse(&buf[..n]).unwrap();
    assert!(b.on_telegram(&t, Duration::ZERO).is_none());
    assert_eq!(b.drive(addr(1)).unwrap().state(), State::ReadyToSwitchOn);
    assert_eq!(
        b.drive(addr(2)).unwrap().state(),
        State::SwitchingOnInhibited,
        "drive 2 ignores broadcasts"
    );
    // The PKW write was not carried out: P1082 still reads 50.0 Hz.
    let (buf, n) = {
        let mut buf = [0u8; MAX_TELEGRAM_BYTES];
        let n = encode(
            &mut buf,
            Adr::to(addr(1)),
            &[0x1000 | 1082, 0, 0, 0],
            &[0x047E, 0],
        )
        .unwrap();
        (buf, n)
    };
    let reply = b
        .on_telegram(
            &Telegram::parse(&buf[..n]).unwrap(),
            Duration::from_millis(50),
        )
        .unwrap();
    let words = Telegram::parse(reply.bytes())
        .unwrap()
        .words(layout)
        .unwrap();
    assert_eq!(&words.pkw()[2..4], &[0x4248, 0], "P1082 is still 50.0");
}

#[test]
fn mirror_telegram_comes_back_unchanged() {
    let mut b = bus(&[4]);
    let adr = Adr {
        mirror: true,
        ..Adr::to(addr(4))
    };
    let (buf, n) = request(adr, 0x047F);
    let reply = b
        .on_telegram(&Telegram::parse(&buf[..n]).unwrap(), Duration::ZERO)
        .unwrap();
    assert_eq!(reply.bytes(), &buf[..n]);
    assert_eq!(reply.bytes()[2], 0x44, "ADR bit 6 still set");
    assert_eq!(
        b.drive(addr(4)).unwrap().state(),
        State::SwitchingOnInhibited,
        "not processed"
    );
}

#[test]
fn special_telegram_is_rejected_without_reply() {
    let mut b = bus(&[4]);
    let adr = Adr {
        special: true,
        ..Adr::to(addr(4))
    };
    assert!(exchange(&mut b, adr, 0x047E, Duration::ZERO).is_none());
    assert_eq!(b.drive(addr(4)).unwrap().counters().rejected, 1);
}

#[test]
fn duplicate_address_is_refused() {
    let mut b = bus(&[4]);
    let layout = Layout::new(PkwMode::Four, PzdCount::new(2).unwrap());
    assert_eq!(
        b.add(DriveConfig::new(addr(4), layout)),
        Err(BusError::DuplicateAddress(addr(4)))
    );
}

#[test]
fn receive_errors_are_counted_by_every_drive() {
    let mut b = bus(&[1, 2]);
    b.on_error(
        &FrameError::Bcc {
            expected: 1,
            actual: 2,
        },
        Duration::ZERO,
    );
    b.on_error(&FrameError::MissingStx(0x55), Duration::ZERO);
    for a in [1, 2] {
        let c = b.drive(addr(a)).unwrap().counters();
        assert_eq!((c.bcc, c.start, c.rejected), (1, 1, 2));
    }
}

fn scripted(fault: Fault) -> (uss_drive_sim::Reply, Vec<u8>) {
    let mut clean = bus(&[5]);
    let good = exchange(&mut clean, Adr::to(addr(5)), 0x047E, Duration::ZERO).unwrap();
    let mut b = bus(&[5]);
    b.faults_mut(addr(5)).unwrap().script([Some(fault)]);
    let reply = exchange(&mut b, Adr::to(addr(5)), 0x047E, Duration::ZERO).unwrap();
    assert_eq!(reply.fault, Some(fault));
    assert_eq!(b.slot(addr(5)).unwrap().faults.injected(fault), 1);
    // The script is used up: the next reply is clean.
    let next = exchange(&mut b, Adr::to(addr(5)), 0x047E, Duration::from_millis(10)).unwrap();
    assert_eq!(next.fault, None);
    (reply, good.bytes().to_vec())
}

#[test]
fn injected_drop_sends_nothing() {
    let mut b = bus(&[5]);
    b.faults_mut(addr(5))
        .unwrap()
        .script([Some(Fault::DropReply), None]);
    assert!(exchange(&mut b, Adr::to(addr(5)), 0x047E, Duration::ZERO).is_none());
    assert!(exchange(&mut b, Adr::to(addr(5)), 0x047E, Duration::from_millis(5)).is_some());
}

#[test]
fn injected_bcc_error_keeps_parity_and_fails_the_bcc() {
    let (reply, good) = scripted(Fault::CorruptBcc);
    let n = good.len();
    assert_eq!(&reply.bytes()[..n - 1], &good[..n - 1]);
    assert_eq!(reply.bytes()[n - 1], good[n - 1] ^ 0x81);
    assert_eq!(reply.parity_error_at, None);
    assert!(matches!(
        Telegram::parse(reply.bytes()),
        Err(DecodeError::Bcc { .. })
    ));
}

#[test]
fn injected_byte_error_flips_one_bit_and_flags_parity() {
    let (reply, good) = scripted(Fault::CorruptByte);
    let at = reply.parity_error_at.unwrap();
    let diff: Vec<usize> = (0..good.len())
        .filter(|&i| reply.bytes()[i] != good[i])
        .collect();
    assert_eq!(diff, vec![at]);
    assert_eq!((reply.bytes()[at] ^ good[at]).count_ones(), 1);
}

#[test]
fn injected_truncation_cuts_the_reply() {
    let (reply, good) = scripted(Fault::Truncate);
    assert!(reply.bytes().len() < good.len() && !reply.bytes().is_empty());
    assert_eq!(reply.bytes(), &good[..reply.bytes().len()]);
}

#[test]
fn injected_late_reply_comes_after_20_ms() {
    let (reply, _) = scripted(Fault::Late);
    assert_eq!(reply.delay, Duration::from_millis(25));
    assert!(Telegram::parse(reply.bytes()).is_ok());
}

#[test]
fn injected_wrong_address_is_a_valid_telegram_from_the_next_address() {
    let (reply, _) = scripted(Fault::WrongAddress);
    let t = Telegram::parse(reply.bytes()).unwrap();
    assert_eq!(t.adr().address, addr(6));
}

#[test]
fn injected_noise_precedes_the_stx() {
    let (reply, good) = scripted(Fault::Noise);
    let noise = reply.bytes().len() - good.len();
    assert!((1..=8).contains(&noise));
    assert_eq!(&reply.bytes()[noise..], &good[..]);
}

#[test]
fn fault_probabilities_apply_at_their_rate() {
    let mut b = bus(&[5]);
    b.faults_mut(addr(5))
        .unwrap()
        .set_probability(Fault::DropReply, 0.25);
    let answered = (0..4000u64)
        .filter(|i| exchange(&mut b, Adr::to(addr(5)), 0x047E, Duration::from_millis(*i)).is_some())
        .count();
    let dropped = b.slot(addr(5)).unwrap().faults.injected(Fault::DropReply);
    assert_eq!(answered as u64 + dropped, 4000);
    assert!(
        (900..1100).contains(&dropped),
        "{dropped} of 4000 at p = 0.25"
    );
}

#[test]
fn unplugged_drive_neither_hears_nor_answers_until_plugged_back() {
    let mut b = bus(&[5]);
    b.faults_mut(addr(5))
        .unwrap()
        .unplug(Duration::from_millis(100), Some(Duration::from_millis(50)));
    let at = |ms| Duration::from_millis(ms);
    assert!(exchange(&mut b, Adr::to(addr(5)), 0x047E, at(99)).is_some());
    assert!(exchange(&mut b, Adr::to(addr(5)), 0x047F, at(100)).is_none());
    assert!(exchange(&mut b, Adr::to(addr(5)), 0x047F, at(149)).is_none());
    assert_eq!(
        b.drive(addr(5)).unwrap().state(),
        State::ReadyToSwitchOn,
        "did not hear the ON"
    );
    assert!(exchange(&mut b, Adr::to(addr(5)), 0x047E, at(150)).is_some());
}
