//! After `open` (or `connect`), the line allocates nothing per exchange (it runs in the
//! real-time thread): 1000 exchanges with a simulated drive over a pseudo-terminal, and 1000
//! through a device server's TCP port, counting allocations made by the master's thread only
//! (the simulator and the server run in their own).
#![allow(clippy::unwrap_used)]

mod common;

use common::allocations;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use uss_drive_sim::serve::{Pty, serve};
use uss_drive_sim::{DriveConfig, SimBus};
use uss_engine::clock::{Clock, MonotonicClock};
use uss_engine::transport::Transport;
use uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, encode};
use uss_protocol::{Address, Adr, Baud, Framer, FramerConfig, Timing};
use uss_serial::{SerialOptions, SerialTransport};

/// The simulator enforces the start pause; a pty moves bytes instantly, so wait generously.
const PAUSE: Duration = Duration::from_millis(1);

/// Exchanges with the drive at `address` on `line` (a request with PKW 4 and PZD 2, its reply
/// framed): 5 to warm up, then 1000 counted; the replies and this thread's allocations.
fn thousand_exchanges(
    line: &mut impl Transport,
    framer: &mut Framer,
    address: Address,
    check: impl Fn(&uss_protocol::Telegram<'_>),
) -> (usize, u64) {
    let mut clock = MonotonicClock::new();
    let mut request = [0u8; MAX_TELEGRAM_BYTES];
    let mut exchange = |i: u16| -> bool {
        clock.sleep_until(clock.now() + PAUSE);
        line.flush_input(clock.now()).unwrap();
        framer.reset();
        let stw = if i.is_multiple_of(2) { 0x047E } else { 0x047F };
        let n = encode(&mut request, Adr::to(address), &[0, 0, 0, 0], &[stw, i]).unwrap();
        line.send(&request[..n], clock.now()).unwrap();
        let deadline = clock.now() + Duration::from_millis(500);
        while let Some(rx) = line.recv(deadline, &mut clock).unwrap() {
            assert_eq!(rx.error, None);
            if let Some(telegram) = framer.push(rx.byte, rx.at) {
                let telegram = telegram.unwrap();
                assert_eq!(telegram.adr(), Adr::to(address));
                check(&telegram);
                return true;
            }
        }
        false
    };
    for i in 0..5 {
        assert!(exchange(i), "warm-up exchange {i} got no reply");
    }
    let before = allocations();
    let answered = (0..1000).filter(|&i| exchange(i)).count();
    (answered, allocations() - before)
}

#[test]
fn a_thousand_exchanges_over_a_pty_allocate_nothing() {
    let timing = Timing::new(Baud::new(115_200).unwrap());
    let address = Address::new(1).unwrap();
    let mut config = DriveConfig::new(
        address,
        Layout::new(PkwMode::Four, PzdCount::new(2).unwrap()),
    );
    config.response_delay = Duration::ZERO;
    let mut bus = SimBus::new(1);
    bus.add(config).unwrap();
    let mut pty = Pty::open().unwrap();
    let path = pty.path().to_owned();
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let sim = s.spawn(|| serve(&mut pty, &mut bus, timing, Instant::now(), &stop));
        let options = SerialOptions {
            baud: timing.baud(),
            kernel_rs485: false,
            rs485_settings: uss_serial::Rs485Wanted::default(),
            low_latency: true,
            rx_latency: core::time::Duration::ZERO,
        };
        let before_open = allocations();
        let (mut serial, _) = SerialTransport::open(&path, &options).unwrap();
        assert!(
            allocations() > before_open,
            "the counter sees this thread's allocations"
        );
        let mut framer = Framer::new(FramerConfig::strict(timing));
        let (answered, allocated) = thousand_exchanges(&mut serial, &mut framer, address, |t| {
            assert_eq!(t.lge(), 14);
        });
        stop.store(true, Ordering::Relaxed);
        sim.join().unwrap().unwrap();
        assert_eq!(answered, 1000);
        assert_eq!(allocated, 0, "allocations during 1000 exchanges");
    });
}

/// The same for a serial device server's port over TCP: a thread of this test plays the server
/// with a drive behind it (each request answered with a status reply).
#[test]
fn a_thousand_exchanges_through_a_device_server_allocate_nothing() {
    use std::io::{Read as _, Write as _};
    let timing = Timing::new(Baud::new(115_200).unwrap());
    let address = Address::new(1).unwrap();
    let mut request = [0u8; MAX_TELEGRAM_BYTES];
    let request_len = encode(&mut request, Adr::to(address), &[0, 0, 0, 0], &[0x047E, 0]).unwrap();
    let mut reply = [0u8; MAX_TELEGRAM_BYTES];
    let reply_len = encode(&mut reply, Adr::to(address), &[0, 0, 0, 0], &[0xBB31, 0]).unwrap();
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let server_address = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || {
        let (mut port, _) = listener.accept().unwrap();
        let mut got = vec![0u8; request_len];
        while port.read_exact(&mut got).is_ok() {
            if port.write_all(&reply[..reply_len]).is_err() {
                break;
            }
        }
    });
    let options = uss_serial::TcpOptions {
        baud: timing.baud(),
        rx_latency: Duration::from_millis(1),
    };
    let (mut line, _) = uss_serial::TcpTransport::connect(&server_address, &options).unwrap();
    let mut framer = Framer::new(FramerConfig::with_latency(timing, options.rx_latency));
    let (answered, allocated) = thousand_exchanges(&mut line, &mut framer, address, |_| {});
    drop(line);
    server.join().unwrap();
    assert_eq!(answered, 1000);
    assert_eq!(allocated, 0, "allocations during 1000 exchanges");
}
