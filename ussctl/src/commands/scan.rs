//! `scan DEVICE`: which drives answer on a line ussd does not serve, at which baud rate, with
//! which PKW and PZD lengths (USS.md sections 2 and 3).
//!
//! For each baud rate and address a mirror telegram (ADR bit 6) asks whether a slave is there:
//! it comes back unchanged whatever the slave's telegram length. A slave that mirrors is then
//! asked with telegrams of each layout in turn (the common ones first) until it answers: a
//! slave answers only telegrams of its own length. Every probe's PZD carry the safe command OFF1
//! (STW1 0x047E, bit 10 set, setpoint 0), as every telegram of uss-rt does: a scan never switches
//! a drive on, and a drive USS controls gets OFF1. The PKW probe reads P0003 (a word): a 4-word
//! request answered with 3 words is the variable length (P2013 = 127). With a 4-word or
//! variable parameter channel, the family is asked for: a SINAMICS drive (G120) answers the
//! PROFIdrive device identification r0964[0] with 42 (Siemens), and its r0964[2] is the firmware
//! version; a MICROMASTER 4 or G110 has no r0964 but answers r0018, its firmware as a float
//! (which 3 words cannot carry). A slave that answers neither is left for the user to name
//! (`simoreg`, `generic`).

use super::common::firmware_version;
use crate::report::{ScanReport, ScannedDrive};
use crate::{Failure, Output, catch_signals, stopped};
use core::time::Duration;
use indicatif::ProgressBar;
use std::path::Path;
use std::time::Instant;
use uss_client::Value;
use uss_client::uss_protocol::telegram::{Layout, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, encode};
use uss_client::uss_protocol::{
    Address, Adr, Baud, Framer, FramerConfig, MAX_RESPONSE_DELAY, ParamReply, ReplyKind, Timing,
};
use uss_master::transports::serial::{SerialError, SerialOptions, SerialTransport};
use uss_master::{Clock, MonotonicClock, Transport};

/// The PZD of every probe: OFF1 (STW1 0x047E, bit 10 "control by PLC" set) with a zero setpoint
/// and zero further words, the first `pzd` of them.
const SAFE_PZD: [u16; 16] = {
    let mut words = [0; 16];
    words[0] = uss_client::StopCommand::Off1.stw1();
    words
};

/// Layouts tried on a slave that answered the mirror telegram, the common ones first.
fn layouts() -> Vec<(PkwMode, usize)> {
    let pzd_order = [2, 6, 4, 8, 0, 1, 3, 5, 7, 9, 10, 11, 12, 13, 14, 15, 16];
    let mut out = Vec::new();
    for pkw in [PkwMode::Four, PkwMode::Three, PkwMode::None] {
        for &pzd in &pzd_order {
            out.push((pkw, pzd));
        }
    }
    out
}

/// A line and the clock its bytes are stamped on.
struct Probe {
    line: SerialTransport,
    clock: MonotonicClock,
    timing: Timing,
    /// When the line last went quiet (our request's end, or a reply's last byte).
    free_at: Duration,
}

impl Probe {
    /// Sends a telegram and returns the reply's bytes, if one came within the response delay.
    fn exchange(&mut self, adr: Adr, pkw: &[u16], pzd: &[u16]) -> Result<Option<Vec<u8>>, Failure> {
        let mut buf = [0u8; MAX_TELEGRAM_BYTES];
        let n = encode(&mut buf, adr, pkw, pzd)
            .map_err(|e| Failure::Usage(format!("cannot build a probe telegram: {e}")))?;
        let io = |e: uss_master::TransportError| Failure::Usage(format!("the line failed: {e}"));
        // The start pause after whatever the line carried last (USS.md section 4).
        self.clock
            .sleep_until_precise(self.free_at + self.timing.start_pause());
        let now = self.clock.now();
        self.line.flush_input(now).map_err(io)?;
        let end = self.line.send(&buf[..n], now).map_err(io)?;
        self.free_at = end;
        let mut framer = Framer::new(FramerConfig::strict(self.timing));
        framer.line_busy_until(end);
        // The reply starts within the longest response delay (with margin for the adapter);
        // once it has started, its characters may take as long as the longest telegram.
        let mut deadline = end + MAX_RESPONSE_DELAY + Duration::from_millis(5);
        let longest = self.timing.telegram(MAX_TELEGRAM_BYTES.saturating_sub(4));
        while let Some(rx) = self.line.recv(deadline, &mut self.clock).map_err(io)? {
            deadline = deadline.max(rx.at + longest);
            self.free_at = rx.at;
            if let Some(done) = framer.push(rx.byte, rx.at) {
                return Ok(done.ok().map(|t| t.as_bytes().to_vec()));
            }
        }
        Ok(None)
    }
}

/// What one slave answered: its layout, whether the PKW length is variable, its firmware.
fn identify(probe: &mut Probe, address: Address) -> Result<Option<ScannedDrive>, Failure> {
    let baud = probe.timing.baud().get();
    for (pkw, pzd) in layouts() {
        let Ok(count) = PzdCount::new(pzd) else {
            continue;
        };
        let layout = Layout::new(pkw, count);
        // Read P0003 (a word) with the PKW channel; the PZD carry OFF1.
        let task = [0x1000 | 3, 0, 0, 0];
        let pkw_words = &task[..pkw.request_words()];
        // Twice: one lost reply must not hide the layout.
        let mut answer = None;
        for _ in 0..2 {
            answer = probe.exchange(Adr::to(address), pkw_words, &SAFE_PZD[..pzd])?;
            if answer.is_some() {
                break;
            }
        }
        let Some(bytes) = answer else {
            continue;
        };
        let Ok(reply) = uss_client::uss_protocol::Telegram::parse(&bytes) else {
            continue;
        };
        if reply.adr().address != address {
            continue;
        }
        // A 4-word request answered with 3 PKW words: the variable length (P2013 = 127).
        let variable = Layout::new(PkwMode::Variable, count);
        let (layout, words) = match reply.words(layout) {
            Ok(w) => (layout, w),
            Err(_) if pkw == PkwMode::Four => match reply.words(variable) {
                Ok(w) => (variable, w),
                Err(_) => continue,
            },
            Err(_) => continue,
        };
        let variable = layout.pkw == PkwMode::Variable;
        // A 3-word channel with one more PZD word has the same length as a 4-word channel: a
        // word reply in 4 words has its high word 0, in 3 words that place holds the value.
        let word_reply = words.pkw().first().is_some_and(|w| w >> 12 == 1);
        if layout.pkw == PkwMode::Four && word_reply && words.pkw().get(2) != Some(&0) {
            continue;
        }
        // The other way round a 4-word slave seen through 3 words shows the value's high word
        // (0) there: a double word (r0018, a float) tells them apart, as a 3-word slave
        // refuses it (error 5 or 103) while a 4-word one answers it (AK 2).
        if layout.pkw == PkwMode::Three
            && words.pkw().get(2) == Some(&0)
            && answers_a_dword(probe, address, layout)?
        {
            continue;
        }
        let mut drive = ScannedDrive {
            baud,
            address: address.get(),
            pkw: if variable {
                "variable (127)".to_owned()
            } else {
                pkw.p2013().to_string()
            },
            pzd,
            zsw1: words.pzd().first().copied(),
            firmware: None,
            family: None,
        };
        if matches!(layout.pkw, PkwMode::Four | PkwMode::Variable) {
            let identification = |probe: &mut Probe, element: u16| {
                read_value(probe, address, layout, [0x6000 | R0964, element, 0, 0])
            };
            if identification(probe, 0)?.map(Value::as_u32) == Some(PROFIDRIVE_SIEMENS) {
                drive.family = Some("g120");
                drive.firmware = identification(probe, 2)?.map(|v| f64::from(v.as_u32()) / 100.0);
            } else {
                drive.firmware = read_value(probe, address, layout, [0x1000 | 18, 0, 0, 0])?
                    .map(|v| firmware_version(v.as_f32()));
                drive.family = drive.firmware.map(|_| "micromaster4");
            }
        }
        return Ok(Some(drive));
    }
    Ok(None)
}

/// Whether a slave asked for r0018 (a double word) through `layout` answers with a double
/// word (AK 2), which a 3-word channel cannot carry.
fn answers_a_dword(probe: &mut Probe, address: Address, layout: Layout) -> Result<bool, Failure> {
    let task = [0x1000 | 18, 0, 0];
    let answer = probe.exchange(Adr::to(address), &task, &SAFE_PZD[..layout.pzd.get()])?;
    Ok(answer
        .and_then(|b| {
            uss_client::uss_protocol::Telegram::parse(&b)
                .ok()
                .map(|t| t.net().first().copied())
        })
        .flatten()
        .is_some_and(|pke_high| pke_high >> 4 == 2))
}

/// The PROFIdrive device identification (SINAMICS): element 0 the manufacturer, 2 the firmware
/// version (470 = 4.70).
const R0964: u16 = 964;
/// r0964[0] of a Siemens device.
const PROFIDRIVE_SIEMENS: u32 = 42;

/// A read task's value over the drive's own layout, repeated while it answers "not yet";
/// `None` when the drive refuses it (it does not have the parameter) or does not answer.
fn read_value(
    probe: &mut Probe,
    address: Address,
    layout: Layout,
    task: [u16; 4],
) -> Result<Option<Value>, Failure> {
    for _ in 0..5 {
        let pkw = &task[..layout.pkw.request_words()];
        let Some(bytes) = probe.exchange(Adr::to(address), pkw, &SAFE_PZD[..layout.pzd.get()])?
        else {
            return Ok(None);
        };
        let words = uss_client::uss_protocol::Telegram::parse(&bytes)
            .ok()
            .and_then(|t| t.words(layout).ok());
        let Some(words) = words else {
            return Ok(None);
        };
        match ParamReply::decode(words.pkw()).map(|r| r.kind) {
            Ok(ReplyKind::NotYet) => {}
            Ok(kind) => return Ok(kind.value()),
            Err(_) => return Ok(None),
        }
    }
    Ok(None)
}

/// Whether `path` is a character device.
fn is_tty(path: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt as _;
    std::fs::metadata(path).is_ok_and(|m| m.file_type().is_char_device())
}

/// What `scan` was asked to do.
pub(crate) struct Scan<'a> {
    pub device: &'a Path,
    pub bauds: Vec<Baud>,
    pub addresses: Vec<Address>,
}

/// `scan DEVICE [--baud LIST|all] [--addresses FROM-TO]`.
pub(crate) fn scan(out: &Output, s: &Scan<'_>) -> Result<(), Failure> {
    catch_signals()?;
    let start = Instant::now();
    let mut report = ScanReport::new(s.device, &s.bauds, s.addresses.len());
    let bar = ProgressBar::new((s.bauds.len() * s.addresses.len()) as u64);
    'bauds: for &baud in &s.bauds {
        let options = SerialOptions {
            baud,
            kernel_rs485: false,
            rs485_settings: uss_master::transports::serial::Rs485Wanted::default(),
            low_latency: true,
            rx_latency: core::time::Duration::ZERO,
        };
        let (line, _) = SerialTransport::open(s.device, &options).map_err(|e| {
            Failure::Usage(match e {
                SerialError::Busy { .. } => format!(
                    "{e}: is ussd serving this line? scan only a line nobody else uses (stop \
                     that bus first)"
                ),
                SerialError::Open { .. } if !is_tty(s.device) => format!(
                    "cannot open {0}: {0} is not a serial device (not a tty)",
                    s.device.display()
                ),
                e => e.to_string(),
            })
        })?;
        let mut probe = Probe {
            line,
            clock: MonotonicClock::new(),
            timing: Timing::new(baud),
            free_at: Duration::ZERO,
        };
        for &address in &s.addresses {
            if stopped() {
                report.cut_short = true;
                break 'bauds;
            }
            bar.inc(1);
            let mirror = Adr {
                mirror: true,
                ..Adr::to(address)
            };
            let Some(echo) = probe.exchange(mirror, &[], &SAFE_PZD[..2])? else {
                continue;
            };
            let answered = uss_client::uss_protocol::Telegram::parse(&echo)
                .is_ok_and(|t| t.adr().address == address);
            if !answered {
                continue;
            }
            match identify(&mut probe, address)? {
                Some(drive) => report.drives.push(drive),
                None => report.drives.push(ScannedDrive {
                    baud: baud.get(),
                    address: address.get(),
                    pkw: "unknown".into(),
                    pzd: 0,
                    zsw1: None,
                    firmware: None,
                    family: None,
                }),
            }
        }
    }
    bar.finish_and_clear();
    report.seconds = start.elapsed().as_secs_f64();
    out.show(&report, ScanReport::human)
}
