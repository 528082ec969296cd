use super::*;
use proptest::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use uss_drive_sim::serve::{Port, Pty, serve};
use uss_drive_sim::{DriveConfig, SimBus};
use uss_engine::{MonotonicClock, VirtualClock};
use uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, encode};
use uss_protocol::{Address, Adr, DriveState, Framer, FramerConfig, Zsw1};

const MS: Duration = Duration::from_millis(1);

fn baud() -> Baud {
    Baud::new(115_200).unwrap()
}

fn options(kernel_rs485: bool, low_latency: bool) -> SerialOptions {
    SerialOptions {
        baud: baud(),
        kernel_rs485,
        rs485_settings: Rs485Wanted::default(),
        low_latency,
        rx_latency: core::time::Duration::ZERO,
    }
}

fn open_pty() -> (Pty, SerialTransport) {
    let pty = Pty::open().unwrap();
    let (serial, _) = SerialTransport::open(pty.path(), &options(false, false)).unwrap();
    (pty, serial)
}

fn unmark_all(state: &mut Unmark, raw: &[u8], out: &mut Vec<(u8, Option<LineError>)>) {
    out.extend(raw.iter().filter_map(|&b| state.push(b)));
}

fn unmark(raw: &[u8]) -> Vec<(u8, Option<LineError>)> {
    let mut out = Vec::new();
    unmark_all(&mut Unmark::Plain, raw, &mut out);
    out
}

/// Receives until `count` characters came or 2 s passed.
fn recv_n(serial: &mut SerialTransport, clock: &mut MonotonicClock, count: usize) -> Vec<Rx> {
    let deadline = clock.now() + Duration::from_secs(2);
    let mut got = Vec::new();
    while got.len() < count {
        match serial.recv(deadline, clock).unwrap() {
            Some(rx) => got.push(rx),
            None => break,
        }
    }
    got
}

#[test]
fn unmarking_passes_plain_bytes_and_decodes_each_marking() {
    assert_eq!(
        unmark(&[0x02, 0x00, 0x7F]),
        [(2, None), (0, None), (0x7F, None)]
    );
    assert_eq!(unmark(&[0xFF, 0xFF]), [(0xFF, None)]);
    assert_eq!(
        unmark(&[0xFF, 0x00, 0x41]),
        [(0x41, Some(LineError::Parity))]
    );
    assert_eq!(
        unmark(&[0xFF, 0x00, 0xFF]),
        [(0xFF, Some(LineError::Parity))]
    );
    assert_eq!(
        unmark(&[0xFF, 0x00, 0x00]),
        [(0x00, Some(LineError::Framing))]
    );
    assert_eq!(unmark(&[0xFF, 0x41]), [(0x41, Some(LineError::Framing))]);
}

#[test]
fn marking_split_between_reads_decodes_the_same_at_every_position() {
    let raw = [
        0x02, 0xFF, 0xFF, 0x10, 0xFF, 0x00, 0x41, 0xFF, 0x00, 0x00, 0xFF, 0x00, 0xFF, 0x03,
    ];
    let whole = unmark(&raw);
    assert_eq!(
        whole,
        [
            (0x02, None),
            (0xFF, None),
            (0x10, None),
            (0x41, Some(LineError::Parity)),
            (0x00, Some(LineError::Framing)),
            (0xFF, Some(LineError::Parity)),
            (0x03, None),
        ]
    );
    for split in 0..=raw.len() {
        let mut state = Unmark::Plain;
        let mut out = Vec::new();
        unmark_all(&mut state, &raw[..split], &mut out);
        unmark_all(&mut state, &raw[split..], &mut out);
        assert_eq!(out, whole, "split at {split}");
        assert_eq!(state, Unmark::Plain);
    }
}

/// A character as the UART delivers it: fine, with bad parity, or a break.
#[derive(Debug, Clone, Copy)]
enum Arrival {
    Good(u8),
    BadParity(u8),
    Break,
}

/// Marks characters the way `n_tty` does with `PARMRK` and without `ISTRIP`.
fn mark(arrivals: &[Arrival]) -> Vec<u8> {
    let mut raw = Vec::new();
    for a in arrivals {
        match *a {
            Arrival::Good(MARK) => raw.extend([MARK, MARK]),
            Arrival::Good(b) => raw.push(b),
            Arrival::BadParity(b) => raw.extend([MARK, 0, b]),
            Arrival::Break => raw.extend([MARK, 0, 0]),
        }
    }
    raw
}

fn arrival() -> impl Strategy<Value = Arrival> {
    prop_oneof![
        8 => any::<u8>().prop_map(Arrival::Good),
        2 => Just(Arrival::Good(MARK)),
        1 => (1..=u8::MAX).prop_map(Arrival::BadParity),
        1 => Just(Arrival::Break),
    ]
}

proptest! {
    #[test]
    fn any_marked_stream_read_in_any_chunks_decodes_to_what_arrived(
        arrivals in proptest::collection::vec(arrival(), 0..200),
        cuts in proptest::collection::vec(any::<prop::sample::Index>(), 0..8),
    ) {
        let raw = mark(&arrivals);
        let mut cuts: Vec<usize> = cuts.iter().map(|c| c.index(raw.len() + 1)).collect();
        cuts.sort_unstable();
        let mut state = Unmark::Plain;
        let mut out = Vec::new();
        let mut from = 0;
        for cut in cuts.into_iter().chain([raw.len()]) {
            unmark_all(&mut state, &raw[from..cut], &mut out);
            from = cut;
        }
        let expected: Vec<_> = arrivals
            .iter()
            .map(|a| match *a {
                Arrival::Good(b) => (b, None),
                Arrival::BadParity(b) => (b, Some(LineError::Parity)),
                Arrival::Break => (0, Some(LineError::Framing)),
            })
            .collect();
        prop_assert_eq!(out, expected);
        prop_assert_eq!(state, Unmark::Plain);
    }

    #[test]
    fn unmarking_never_yields_more_characters_than_bytes(raw in proptest::collection::vec(any::<u8>(), 0..300)) {
        prop_assert!(unmark(&raw).len() <= raw.len());
    }
}

#[test]
fn only_8e1_counts_as_even_parity() {
    let e1 = ControlFlags::CS8 | ControlFlags::PARENB | ControlFlags::CREAD;
    assert!(is_8e1(e1));
    assert!(!is_8e1(ControlFlags::CS8 | ControlFlags::CREAD));
    assert!(!is_8e1(e1 | ControlFlags::PARODD));
    assert!(!is_8e1(e1 | ControlFlags::CMSPAR));
    assert!(!is_8e1(e1 | ControlFlags::CSTOPB));
    assert!(!is_8e1((e1 & !ControlFlags::CSIZE) | ControlFlags::CS7));
}

#[test]
fn missing_device_is_a_typed_error_naming_the_path() {
    let err = SerialTransport::open(Path::new("/nonexistent/ttyUSS9"), &options(false, true))
        .unwrap_err();
    assert!(matches!(err, SerialError::NotFound { .. }), "{err:?}");
    assert_eq!(
        err.to_string(),
        "cannot open /nonexistent/ttyUSS9: No such file or directory"
    );
}

#[test]
fn second_open_of_an_open_device_is_refused_as_busy() {
    let (pty, _serial) = open_pty();
    let err = SerialTransport::open(pty.path(), &options(false, false)).unwrap_err();
    assert!(matches!(err, SerialError::Busy { .. }), "{err:?}");
    assert_eq!(
        err.to_string(),
        format!(
            "cannot open {}: device is busy (opened exclusively by another process)",
            pty.path().display()
        )
    );
}

#[test]
fn device_opens_again_after_the_transport_is_dropped() {
    let (pty, serial) = open_pty();
    drop(serial);
    let (mut serial, _) = SerialTransport::open(pty.path(), &options(false, false)).unwrap();
    assert_eq!(serial.send(&[0x55], MS).unwrap(), MS);
}

#[test]
fn pseudo_terminal_opens_and_the_report_says_what_it_lacks() {
    let pty = Pty::open().unwrap();
    let (_serial, report) = SerialTransport::open(pty.path(), &options(true, true)).unwrap();
    assert_eq!(
        report,
        OpenReport {
            pseudo_terminal: true,
            parity: ParityState::NotOnPseudoTerminal,
            rs485: Setting::Unsupported(Errno::ENOTTY),
            rs485_kept: None,
            low_latency: Setting::Unsupported(Errno::ENOTTY),
        }
    );
    assert_eq!(
        report.to_string(),
        "pty=true parity=none-on-pty rs485=unsupported(ENOTTY) low_latency=unsupported(ENOTTY)"
    );
    let pty = Pty::open().unwrap();
    let (_serial, report) = SerialTransport::open(pty.path(), &options(false, false)).unwrap();
    assert_eq!(
        report.to_string(),
        "pty=true parity=none-on-pty rs485=not-requested low_latency=not-requested"
    );
}

#[test]
fn rs485_keeps_the_ports_polarity_and_delays_unless_configured() {
    // A board whose device tree wires RTS active-low with delays and receive during send.
    let tree = SerialRs485 {
        flags: SER_RS485_RTS_AFTER_SEND | SER_RS485_RX_DURING_TX,
        delay_rts_before_send: 2,
        delay_rts_after_send: 3,
        ..SerialRs485::default()
    };
    let kept = rs485_settings(tree, Rs485Wanted::default());
    assert_eq!(
        kept,
        SerialRs485 {
            flags: SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND | SER_RS485_RX_DURING_TX,
            ..tree
        }
    );
    // Configured: polarity and one delay change, the rest stays.
    let set = rs485_settings(
        tree,
        Rs485Wanted {
            rts_high_while_sending: Some(true),
            delay_before_ms: None,
            delay_after_ms: Some(0),
        },
    );
    assert_eq!(
        set.flags,
        SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND | SER_RS485_RX_DURING_TX
    );
    assert_eq!(
        (set.delay_rts_before_send, set.delay_rts_after_send),
        (2, 0)
    );
    // A port with no polarity at all gets RTS high while sending.
    let bare = rs485_settings(SerialRs485::default(), Rs485Wanted::default());
    assert_eq!(bare.flags, SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND);
    assert_eq!(
        Rs485Kept {
            rts_high_while_sending: false,
            delay_before_ms: 2,
            delay_after_ms: 3
        }
        .to_string(),
        "RTS low while sending, delays 2/3 ms"
    );
}

#[test]
fn refused_rs485_error_says_what_to_do() {
    let err = SerialError::Rs485Refused {
        path: PathBuf::from("/dev/ttyS1"),
        errno: Errno::ENOTTY,
    };
    assert_eq!(
        err.to_string(),
        "cannot open /dev/ttyS1: kernel RS485 mode requested but the driver refused \
         TIOCSRS485 (ENOTTY): use rs485 = \"auto\" for adapters that switch direction themselves"
    );
}

#[test]
fn sent_bytes_reach_the_far_side_at_once_on_a_pty() {
    let (mut pty, mut serial) = open_pty();
    let bytes = [0x02, 0x0E, 0x03, 0xFF, 0x00, 0x41];
    // A pty moves bytes at once: the request has left when write returns. (On a UART the
    // end is `now` plus the characters' wire time.)
    let end = serial.send(&bytes, 5 * MS).unwrap();
    assert_eq!(end, 5 * MS);
    let mut buf = [0u8; 16];
    let mut got = Vec::new();
    while got.len() < bytes.len() {
        let n = pty.read_some(&mut buf, 500 * MS).unwrap();
        assert!(n > 0, "only {got:02X?} arrived");
        got.extend_from_slice(&buf[..n]);
    }
    assert_eq!(got, bytes);
}

#[test]
fn received_bytes_come_in_order_stamped_with_their_arrival() {
    let (mut pty, mut serial) = open_pty();
    let mut clock = MonotonicClock::new();
    let before = clock.now();
    pty.write_all(&[0x02, 0x06, 0x05, 0x00]).unwrap();
    let got = recv_n(&mut serial, &mut clock, 4);
    let after = clock.now();
    assert_eq!(
        got.iter().map(|rx| (rx.byte, rx.error)).collect::<Vec<_>>(),
        [(0x02, None), (0x06, None), (0x05, None), (0x00, None)]
    );
    for rx in &got {
        assert!(before <= rx.at && rx.at <= after, "{rx:?}");
    }
    assert!(got.windows(2).all(|w| w[0].at <= w[1].at));
}

#[test]
fn bytes_read_together_behind_an_adapter_are_dated_back_by_their_character_times() {
    let pty = Pty::open().unwrap();
    let with_latency = SerialOptions {
        rx_latency: 16 * MS,
        ..options(false, false)
    };
    let (mut serial, _) = SerialTransport::open(pty.path(), &with_latency).unwrap();
    let mut pty = pty;
    let mut clock = MonotonicClock::new();
    // Sleep first, so the first read holds every byte: one packet of an adapter, a
    // marked 0xFF among them (two raw bytes, one character).
    pty.write_all(&[0x02, 0xFF, 0x05, 0x00]).unwrap();
    std::thread::sleep(20 * MS);
    let got = recv_n(&mut serial, &mut clock, 4);
    let c = Timing::new(baud()).chars(1);
    assert_eq!(got.len(), 4, "{got:?}");
    let read_at = got[3].at;
    for (i, rx) in got.iter().enumerate() {
        assert_eq!(
            Some(rx.at),
            read_at.checked_sub(c * (3 - i as u32)),
            "{got:?}"
        );
    }
}

#[test]
// The probes have the type of the injection point.
#[allow(clippy::unnecessary_wraps)]
fn a_rate_the_port_cannot_make_is_refused_naming_what_it_made() {
    // A CP2102 behind the pty: asked for 187500, it reads back 230400.
    fn cp2102(_: BorrowedFd<'_>, _: bool) -> Result<Option<ReadBack>, Errno> {
        Ok(Some(ReadBack {
            termios: 230_400,
            baud_base: None,
        }))
    }
    fn uart_16550(_: BorrowedFd<'_>, _: bool) -> Result<Option<ReadBack>, Errno> {
        Ok(Some(ReadBack {
            termios: 187_500,
            baud_base: Some(921_600),
        }))
    }
    let pty = Pty::open().unwrap();
    let fast = SerialOptions {
        baud: Baud::new(187_500).unwrap(),
        ..options(false, false)
    };
    let err = SerialTransport::open_with(pty.path(), &fast, cp2102).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "cannot use {}: the port runs 230400 baud for the 187500 asked (+22.9 %, more \
             than 2 % off: the drives would not answer)",
            pty.path().display()
        )
    );
    // The device was let go: a 16550 on a 14.7456 MHz crystal makes it (184320).
    assert!(SerialTransport::open_with(pty.path(), &fast, uart_16550).is_ok());
    // And a pseudo-terminal itself has no rate to check.
}

#[test]
// The probe has the type of the injection point.
#[allow(clippy::unnecessary_wraps)]
fn characters_lost_to_an_overrun_flag_the_next_one_received() {
    use std::sync::atomic::AtomicU64;
    static COUNT: AtomicU64 = AtomicU64::new(0);
    fn counted(_: BorrowedFd<'_>) -> Result<u64, Errno> {
        Ok(COUNT.load(Ordering::Relaxed))
    }
    let (mut pty, mut serial) = open_pty();
    serial.overruns = Some(counted);
    let mut clock = MonotonicClock::new();
    pty.write_all(&[1, 2]).unwrap();
    let clean = recv_n(&mut serial, &mut clock, 2);
    assert!(clean.iter().all(|rx| rx.error.is_none()), "{clean:?}");
    // The UART lost characters before the next read: its first character carries it.
    COUNT.store(3, Ordering::Relaxed);
    pty.write_all(&[3, 4]).unwrap();
    let got = recv_n(&mut serial, &mut clock, 2);
    assert_eq!(
        got.iter().map(|rx| (rx.byte, rx.error)).collect::<Vec<_>>(),
        [(3, Some(LineError::Overrun)), (4, None)]
    );
    // A pseudo-terminal keeps no count: not asked.
    assert!(open_pty().1.overruns.is_none());
}

#[test]
fn byte_already_read_is_returned_even_after_the_deadline() {
    let (mut pty, mut serial) = open_pty();
    let mut clock = MonotonicClock::new();
    pty.write_all(&[0x11, 0x22, 0x33]).unwrap();
    assert_eq!(recv_n(&mut serial, &mut clock, 1)[0].byte, 0x11);
    let past = Duration::ZERO;
    assert_eq!(serial.recv(past, &mut clock).unwrap().unwrap().byte, 0x22);
    assert_eq!(serial.recv(past, &mut clock).unwrap().unwrap().byte, 0x33);
    assert_eq!(serial.recv(past, &mut clock).unwrap(), None);
}

#[test]
fn silence_returns_none_once_the_deadline_has_passed() {
    let (_pty, mut serial) = open_pty();
    let mut clock = MonotonicClock::new();
    let deadline = clock.now() + 20 * MS;
    assert_eq!(serial.recv(deadline, &mut clock).unwrap(), None);
    assert!(clock.now() >= deadline);
}

#[test]
fn endless_deadline_waits_until_a_byte_arrives() {
    let (mut pty, mut serial) = open_pty();
    let mut clock = MonotonicClock::new();
    let got = std::thread::scope(|s| {
        s.spawn(|| {
            std::thread::sleep(20 * MS);
            pty.write_all(&[0x5A]).unwrap();
        });
        serial.recv(Duration::MAX, &mut clock).unwrap()
    });
    assert_eq!(got.map(|rx| rx.byte), Some(0x5A));
}

#[test]
fn silence_on_a_virtual_clock_ends_exactly_at_the_deadline() {
    let (_pty, mut serial) = open_pty();
    let mut clock = VirtualClock::new();
    assert_eq!(serial.recv(3 * MS, &mut clock).unwrap(), None);
    assert_eq!(clock.now(), 3 * MS);
}

#[test]
fn flush_input_drops_bytes_read_and_bytes_waiting_in_the_kernel() {
    let (mut pty, mut serial) = open_pty();
    let mut clock = MonotonicClock::new();
    pty.write_all(&[1, 2, 3]).unwrap();
    assert_eq!(recv_n(&mut serial, &mut clock, 1)[0].byte, 1);
    pty.write_all(&[4, 5]).unwrap();
    std::thread::sleep(20 * MS);
    serial.flush_input(clock.now()).unwrap();
    let deadline = clock.now() + 20 * MS;
    assert_eq!(serial.recv(deadline, &mut clock).unwrap(), None);
    pty.write_all(&[6]).unwrap();
    assert_eq!(recv_n(&mut serial, &mut clock, 1)[0].byte, 6);
}

#[test]
fn literal_ff_arrives_as_one_ff() {
    let (mut pty, mut serial) = open_pty();
    let mut clock = MonotonicClock::new();
    pty.write_all(&[0xFF, 0x00, 0xFF, 0xFF, 0x41]).unwrap();
    let got = recv_n(&mut serial, &mut clock, 5);
    assert_eq!(
        got.iter().map(|rx| (rx.byte, rx.error)).collect::<Vec<_>>(),
        [
            (0xFF, None),
            (0x00, None),
            (0xFF, None),
            (0xFF, None),
            (0x41, None)
        ]
    );
}

#[test]
fn closed_far_side_reads_as_closed() {
    let (pty, mut serial) = open_pty();
    drop(pty);
    let mut clock = MonotonicClock::new();
    let deadline = clock.now() + Duration::from_secs(2);
    assert!(matches!(
        serial.recv(deadline, &mut clock),
        Err(TransportError::Closed)
    ));
}

#[test]
fn simulated_drive_answers_a_telegram_over_a_pty_with_the_exact_reply() {
    let mut pty = Pty::open().unwrap();
    let path = pty.path().to_owned();
    let timing = Timing::new(baud());
    let address = Address::new(3).unwrap();
    let layout = Layout::new(PkwMode::Four, PzdCount::new(2).unwrap());
    let mut bus = SimBus::new(1);
    bus.add(DriveConfig::new(address, layout)).unwrap();
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let sim = s.spawn(|| serve(&mut pty, &mut bus, timing, Instant::now(), &stop));
        let (mut serial, _) = SerialTransport::open(&path, &options(false, true)).unwrap();
        let mut clock = MonotonicClock::new();
        let mut framer = Framer::new(FramerConfig::strict(timing));
        let mut request = [0u8; MAX_TELEGRAM_BYTES];
        let n = encode(&mut request, Adr::to(address), &[0, 0, 0, 0], &[0x047E, 0]).unwrap();
        serial.flush_input(clock.now()).unwrap();
        serial.send(&request[..n], clock.now()).unwrap();
        let deadline = clock.now() + Duration::from_secs(2);
        let mut reply = None;
        while reply.is_none() {
            let Some(rx) = serial.recv(deadline, &mut clock).unwrap() else {
                break;
            };
            assert_eq!(rx.error, None);
            reply = framer
                .push(rx.byte, rx.at)
                .map(|t| t.unwrap().as_bytes().to_vec());
        }
        stop.store(true, Ordering::Relaxed);
        sim.join().unwrap().unwrap();

        // STW1 0x047E takes the drive from S1 to S2: PKW zeros, ZSW1 0xBB31, HIW 0.
        assert_eq!(
            reply.unwrap(),
            [
                0x02, 0x0E, 0x03, 0, 0, 0, 0, 0, 0, 0, 0, 0xBB, 0x31, 0, 0, 0x85
            ]
        );
        assert_eq!(
            DriveState::from_zsw1(Zsw1::from_bits_retain(0xBB31)),
            DriveState::ReadyToSwitchOn
        );
    });
}
