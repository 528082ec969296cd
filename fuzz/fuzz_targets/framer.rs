//! Feeds the receive framer (USS.md section 4) arbitrary bytes with arbitrary gaps, line errors,
//! polls, resets and clock jumps, forwards and back. The framer must never panic, and every
//! telegram it yields must be one that `Telegram::parse` accepts and whose words can be split for
//! any layout.
//!
//! Input: two bytes of baud rate and one of configuration, then steps of two bytes `[op, data]`.
#![no_main]

use core::time::Duration;
use libfuzzer_sys::fuzz_target;
use uss_protocol::{
    Baud, FrameError, Framer, FramerConfig, Layout, LineError, PkwMode, PzdCount, Telegram, Timing,
};

/// A standard rate when the top bit is clear, else any rate up to about 12 Mbaud.
fn baud(code: u16) -> Baud {
    let rate = if code & 0x8000 == 0 {
        Baud::STANDARD[usize::from(code) % Baud::STANDARD.len()]
    } else {
        300 + u32::from(code & 0x7FFF) * 366
    };
    Baud::new(rate).expect("300..=11_992_722 is in range")
}

/// Bit 0 set relaxes the start pause; bits 1-7 give up to 31.75 ms of residual slack.
fn config(timing: Timing, code: u8) -> FramerConfig {
    FramerConfig {
        timing,
        require_start_pause: code & 1 == 0,
        residual_slack: Duration::from_micros(u64::from(code >> 1) * 250),
    }
}

const LINE_ERRORS: [LineError; 3] = [LineError::Parity, LineError::Framing, LineError::Overrun];

fn check_telegram(t: Telegram<'_>) {
    let bytes = t.as_bytes();
    assert!(bytes.len() <= 256, "{} bytes", bytes.len());
    assert_eq!(Telegram::parse(bytes), Ok(t));
    for pkw in [
        PkwMode::None,
        PkwMode::Three,
        PkwMode::Four,
        PkwMode::Variable,
    ] {
        for pzd in 0..=16 {
            let layout = Layout::new(pkw, PzdCount::new(pzd).expect("0..=16 PZD words"));
            if let Ok(words) = t.words(layout) {
                assert_eq!(2 * (words.pkw().len() + words.pzd().len()), t.net().len());
            }
        }
    }
}

fuzz_target!(|input: &[u8]| {
    let Some((&[baud_hi, baud_lo, config_code], steps)) = input.split_first_chunk::<3>() else {
        return;
    };
    let timing = Timing::new(baud(u16::from_be_bytes([baud_hi, baud_lo])));
    let mut framer = Framer::new(config(timing, config_code));
    let tz = timing.char_time();
    let mut now = Duration::ZERO;
    for step in steps.chunks_exact(2) {
        let (op, data) = (step[0], step[1]);
        let low = u32::from(op & 0x1F);
        match op >> 5 {
            // A byte after up to 8 tz, in sixteenths of tz: around the start pause.
            0..=3 => {
                now = now.saturating_add(tz * u32::from(op) / 16);
                if let Some(Ok(t)) = framer.push(data, now) {
                    check_telegram(t);
                }
            }
            // A byte after up to 992 tz: beyond any residual time.
            4 => {
                now = now.saturating_add(tz * low * 32);
                if let Some(Ok(t)) = framer.push(data, now) {
                    check_telegram(t);
                }
            }
            // The residual timer fires.
            5 => {
                now = now.saturating_add(tz * low * 32);
                let deadline = framer.deadline();
                let error = framer.poll(now);
                assert_eq!(error.is_some(), deadline.is_some_and(|d| now > d));
                assert!(!framer.is_receiving() || error.is_none());
            }
            // A broken character.
            6 => {
                now = now.saturating_add(tz * low / 8);
                let error = LINE_ERRORS[usize::from(data) % LINE_ERRORS.len()];
                assert_eq!(framer.push_line_error(error, now), FrameError::Line(error));
                assert!(!framer.is_receiving());
            }
            _ => match low {
                0 => framer.reset(),
                1 => framer.line_busy_until(now.saturating_add(tz * u32::from(data))),
                // The clock steps back, or jumps to the far ends of time.
                2 => now = now.saturating_sub(tz * u32::from(data)),
                3 => now = Duration::MAX.saturating_sub(tz * u32::from(data)),
                4 => now = Duration::from_nanos(u64::from(data) << 56),
                // A byte in the same chunk as the one before: no time passes.
                _ => {
                    if let Some(Ok(t)) = framer.push(data, now) {
                        check_telegram(t);
                    }
                }
            },
        }
        assert_eq!(framer.is_receiving(), framer.deadline().is_some());
    }
});
