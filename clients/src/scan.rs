//! Which drives answer on a line ussd does not serve, at which baud rate, with which PKW and
//! PZD lengths and family (USS.md sections 2 and 3): what a service engineer runs first on a
//! machine nobody documented, as STARTER's "accessible nodes" does. In the client library so
//! every front-end scans the same way ([`scan`]: `ussctl scan`, `uss_rt.scan`, `ussrt_scan`).
//!
//! For each baud rate and address a mirror telegram (ADR bit 6) asks whether a slave is there:
//! it comes back unchanged whatever the slave's telegram length. A slave that mirrors is then
//! asked with telegrams of each layout in turn (the common ones first) until it answers: a
//! slave answers only telegrams of its own length. Every probe's PZD carry the safe command OFF1
//! (STW1 0x047E, bit 10 set, setpoint 0), as every telegram of uss-rt does: a scan never switches
//! a drive on, and a drive USS controls gets OFF1. The PKW probe reads P0003: a 4-word request
//! answered with 3 words is the variable length (P2013 = 127); a double word in the answer (reply
//! 2) is a 4-word channel, since a 3-word one carries words only (USS.md section 6). With a
//! 4-word or variable parameter channel, the family is asked for: a SINAMICS drive (G120)
//! answers the PROFIdrive device identification r0964[0] with 42 (Siemens), and its r0964[2] is
//! the firmware version; a MICROMASTER 4 or G110 has no r0964 but answers r0018, its firmware
//! as a float (which 3 words cannot carry). A slave that answers neither is left for the user
//! to name (`simoreg`, `generic`). What the answers do not make sure is said
//! ([`Found::unsure`]), never guessed quietly.

use crate::cancel::Cancel;
use crate::{DriveFamily, ParamTask, Value};
use core::time::Duration;
use std::path::{Path, PathBuf};
use std::time::Instant;
use uss_engine::{Clock, MonotonicClock, Transport};
use uss_protocol::exchange::{Exchange, Heard, Silence};
use uss_protocol::telegram::{
    Layout, MAX_PKW_WORDS, MAX_TELEGRAM_BYTES, PkwMode, PzdCount, encode,
};
use uss_protocol::{
    Address, Adr, Baud, FramerConfig, MAX_RESPONSE_DELAY, ParamReply, Pnu, ReplyKind, Subindex,
    Timing,
};
use uss_serial::{SerialError, SerialOptions, SerialTransport};

/// MICROMASTER's P2010 settings 4..=12: the rates a scan tries unless told (1200 to 115200).
pub const SCAN_BAUDS: [u32; 8] = [1200, 2400, 4800, 9600, 19200, 38400, 57600, 115_200];

/// What a scan asks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanOptions {
    /// The rates, in the order tried.
    pub bauds: Vec<Baud>,
    /// The addresses asked at each rate.
    pub addresses: Vec<Address>,
    /// How often each question is asked before silence counts as its answer (1..=20): an
    /// address silent to this many mirror telegrams counts as empty (raise it on a noisy line).
    pub tries: u32,
}

impl Default for ScanOptions {
    /// [`SCAN_BAUDS`], addresses 0..=31, 4 tries.
    fn default() -> Self {
        Self {
            bauds: SCAN_BAUDS
                .iter()
                .filter_map(|&b| Baud::new(b).ok())
                .collect(),
            addresses: (0..=31).filter_map(|a| Address::new(a).ok()).collect(),
            tries: 4,
        }
    }
}

/// A slave a scan found.
#[derive(Debug, Clone, PartialEq)]
pub struct Found {
    pub baud: Baud,
    pub address: Address,
    /// Its parameter channel (P2013: 0, 3, 4 or variable); `None`: it answered the mirror
    /// telegram but its layout is not known.
    pub pkw: Option<PkwMode>,
    /// Its PZD length (P2012).
    pub pzd: usize,
    /// The status word ZSW1 it answered with (with PZD).
    pub zsw1: Option<u16>,
    /// Its firmware (r0018 of a MICROMASTER 4, r0964[2] of a SINAMICS drive).
    pub firmware: Option<f64>,
    /// The family to configure, where the answers tell it: a drive whose device identification
    /// r0964[0] is 42 (Siemens, PROFIdrive) is G120; one that has r0018 as a float (the
    /// MICROMASTER 4 firmware) is MICROMASTER 4 (a G110 answers the same).
    pub family: Option<DriveFamily>,
    /// Why the line may not be right (`None`: every part of it was confirmed: the layout by two
    /// replies to different tasks, the family by its identification): a layout seen in one
    /// reply only or that its replies do not tell apart, a question not answered, a value that
    /// is no firmware version, replies heard only garbled.
    pub unsure: Option<String>,
}

impl Found {
    /// A slave at `address` whose layout is not known (yet).
    pub const fn unknown(baud: Baud, address: Address) -> Self {
        Self {
            baud,
            address,
            pkw: None,
            pzd: 0,
            zsw1: None,
            firmware: None,
            family: None,
            unsure: None,
        }
    }
}

/// What a scan found.
#[derive(Debug, Clone, PartialEq)]
pub struct Scanned {
    /// The slaves, by rate and then address.
    pub drives: Vec<Found>,
    /// The caller's [`Cancel`] ended it before the last address.
    pub cut_short: bool,
    pub took: Duration,
    /// The rates it asked at: the options', or one of them on a pseudo-terminal.
    pub bauds: Vec<Baud>,
}

/// Why a scan could not run. Every failure is of the line: the device named, what to do.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    /// Another process holds the line (ussd serving it, a terminal program).
    #[error(
        "{0}: is ussd serving this line? scan only a line nobody else uses (stop that bus first)"
    )]
    Busy(SerialError),
    /// The path is no serial device.
    #[error("cannot open {path}: {path} is not a serial device (not a tty)", path = .0.display())]
    NotATty(PathBuf),
    /// The device cannot be opened or set up (missing, permissions, the driver refused 8E1).
    #[error("{0}")]
    Open(SerialError),
    /// The line failed while the scan ran (an adapter unplugged).
    #[error("the line failed: {0}")]
    Line(uss_engine::TransportError),
    /// A probe that cannot be built: a defect of this library.
    #[error("cannot build a probe telegram: {0}")]
    Telegram(String),
    /// Options no scan can run with.
    #[error("{0}")]
    Options(String),
}

/// Scans `device` as `options` say: at each rate, each address is asked by a mirror telegram,
/// and each slave that mirrors is identified (its layout, its ZSW1, its family and firmware
/// where it tells them). `notice` hears what the caller should tell its user before the first
/// probe (every probe carries OFF1), `progress` (addresses asked, of all) after each address.
/// `cancel` asked ends it after the address under way, with [`Scanned::cut_short`].
pub fn scan(
    device: &Path,
    options: &ScanOptions,
    cancel: &dyn Cancel,
    progress: &mut dyn FnMut(usize, usize),
    notice: &mut dyn FnMut(&str),
) -> Result<Scanned, ScanError> {
    if !(1..=20).contains(&options.tries) {
        return Err(ScanError::Options(format!(
            "tries {}: each question is asked 1 to 20 times",
            options.tries
        )));
    }
    let start = Instant::now();
    let mut bauds = options.bauds.as_slice();
    if bauds.len() > 1 && is_pseudo_terminal(device) {
        // A pty (uss-sim --pty, a socat or ser2net line) takes any rate and a slave behind it
        // answers at each: every drive would be found at every rate, each after its timeouts.
        let at = bauds.iter().position(|b| b.get() == 19_200).unwrap_or(0);
        bauds = &bauds[at..=at];
        notice(&format!(
            "{} is a pseudo-terminal: it carries every baud rate alike (a slave behind it answers \
             at each), so the scan asks at {} baud only (--baud chooses the rate)",
            device.display(),
            bauds[0].get()
        ));
    }
    let total = bauds.len() * options.addresses.len();
    let mut done = 0;
    let mut found = Vec::new();
    let mut cut_short = false;
    'bauds: for (n, &baud) in bauds.iter().enumerate() {
        let line = open(device, baud)?;
        if n == 0 {
            // Said before the first probe: a drive that runs under USS control here stops.
            notice(&format!(
                "every probe carries OFF1 (STW1 0x047E, setpoint 0): a drive on {} that runs \
                 under USS control ramps down and stays off",
                device.display()
            ));
        }
        let timing = Timing::new(baud);
        // The line's receive latency as ussd derives it (an FTDI latency timer, a UART's FIFO):
        // the framer judges the timing rules on the wire, and a reply delivered that much later
        // is still in time.
        let latency = uss_serial::latency::detect(Path::new("/sys"), device, timing).latency;
        let mut probe = Probe {
            line,
            clock: MonotonicClock::new(),
            exchange: Exchange::new(FramerConfig::with_latency(timing, latency), Duration::ZERO),
            reply_within: MAX_RESPONSE_DELAY + latency + ADAPTER_MARGIN,
            tries: options.tries,
            garbled: 0,
        };
        for &address in &options.addresses {
            if cancel.asked() > 0 {
                cut_short = true;
                break 'bauds;
            }
            if let Some(drive) = ask_address(&mut probe, address)? {
                found.push(drive);
            }
            done += 1;
            progress(done, total);
        }
    }
    Ok(Scanned {
        drives: found,
        cut_short,
        took: start.elapsed(),
        bauds: bauds.to_vec(),
    })
}

/// Whether `device` is the slave side of a pseudo-terminal (Unix98: character device majors
/// 136 to 143, Documentation/admin-guide/devices.txt).
fn is_pseudo_terminal(device: &Path) -> bool {
    use std::os::unix::fs::{FileTypeExt as _, MetadataExt as _};
    std::fs::metadata(device).is_ok_and(|m| {
        m.file_type().is_char_device() && (136..=143).contains(&nix::sys::stat::major(m.rdev()))
    })
}

/// The line at `baud`, opened for a scan: every failure said with what to do.
fn open(device: &Path, baud: Baud) -> Result<SerialTransport, ScanError> {
    let options = SerialOptions {
        baud,
        kernel_rs485: false,
        rs485_settings: uss_serial::Rs485Wanted::default(),
        low_latency: true,
        rx_latency: Duration::ZERO,
    };
    SerialTransport::open(device, &options)
        .map(|(line, _)| line)
        .map_err(|e| match e {
            SerialError::Busy { .. } => ScanError::Busy(e),
            SerialError::Open { .. } if !is_tty(device) => ScanError::NotATty(device.to_owned()),
            e => ScanError::Open(e),
        })
}

/// Whether `path` is a character device.
fn is_tty(path: &Path) -> bool {
    use std::os::unix::fs::FileTypeExt as _;
    std::fs::metadata(path).is_ok_and(|m| m.file_type().is_char_device())
}

/// Asks `address` by a mirror telegram, and identifies what answers it.
fn ask_address(probe: &mut Probe, address: Address) -> Result<Option<Found>, ScanError> {
    let mirror = Adr {
        mirror: true,
        ..Adr::to(address)
    };
    probe.heard_garbled();
    if probe.ask(mirror, &[], &SAFE_PZD[..2])?.is_none() {
        // Something answered, never intact: not an empty address.
        let garbled = probe.heard_garbled();
        return Ok((garbled > 0).then(|| Found {
            unsure: Some(format!(
                "something answered at this address, but never intact ({garbled} of {} \
                 mirror telegrams answered garbled: a bad BCC, noise, or a slave at another \
                 baud rate)",
                probe.tries
            )),
            ..Found::unknown(probe.exchange.timing().baud(), address)
        }));
    }
    identify(probe, address).map(Some)
}

/// The firmware version r0018 as the drive shows it, to two decimals (2.09, not 2.0899999).
fn firmware_version(r0018: f32) -> f64 {
    (f64::from(r0018) * 100.0).round() / 100.0
}

/// The PZD of every probe: OFF1 (STW1 0x047E, bit 10 "control by PLC" set) with a zero setpoint
/// and zero further words, the first `pzd` of them.
const SAFE_PZD: [u16; 16] = {
    let mut words = [0; 16];
    words[0] = crate::StopCommand::Off1.stw1();
    words
};

/// Request lengths (net words) tried on a slave that answered the mirror telegram, the common
/// layouts' first: 4 PKW words with 2, 6, 4, 8, 0, 1, 3, ... 16 PZD words, then a 3-word
/// channel without PZD (3), then no channel with 1 or 2 PZD words. A slave answers only
/// requests of its own length (a variable channel: its PZD length plus 3 or 4).
fn lengths() -> Vec<usize> {
    let pzd_order = [2, 6, 4, 8, 0, 1, 3, 5, 7, 9, 10, 11, 12, 13, 14, 15, 16];
    let mut out: Vec<usize> = pzd_order.iter().map(|p| 4 + p).collect();
    out.extend([3, 2, 1]);
    out
}

/// What a probe's reply may take beyond the longest response delay and the receive latency
/// sysfs tells of: an adapter sysfs does not describe (a device server, a converter of its own).
const ADAPTER_MARGIN: Duration = Duration::from_millis(5);

/// The PNU whose read the probes carry: P0003 (the access level, a word on every Siemens
/// family), and P0010 to confirm with a task the drive has not answered yet.
const PROBE_PNU: u16 = 3;
const CONFIRM_PNU: u16 = 10;

/// A line and the clock its bytes are stamped on.
struct Probe {
    line: SerialTransport,
    clock: MonotonicClock,
    /// The exchange's rules (start pause, reply deadline, framer): those ussd's engine keeps.
    exchange: Exchange,
    /// How long after a request its reply may start: the longest response delay, the line's
    /// receive latency and [`ADAPTER_MARGIN`].
    reply_within: Duration,
    /// How often a question is asked before silence counts as the answer.
    tries: u32,
    /// Exchanges since [`Probe::heard_garbled`] was last taken that brought bytes but no
    /// intact telegram (a bad BCC, a garbled or cut reply).
    garbled: u32,
}

impl Probe {
    /// Sends a telegram and returns the reply's bytes, if an intact one came within the
    /// response delay. A reply broken or cut short, or garbage with no intact reply after it,
    /// counts as garbled; garbage before an intact reply does not.
    fn exchange(
        &mut self,
        adr: Adr,
        pkw: &[u16],
        pzd: &[u16],
    ) -> Result<Option<Vec<u8>>, ScanError> {
        let mut buf = [0u8; MAX_TELEGRAM_BYTES];
        let n = encode(&mut buf, adr, pkw, pzd).map_err(|e| ScanError::Telegram(e.to_string()))?;
        let io = ScanError::Line;
        // The start pause after whatever the line carried last (USS.md section 4).
        self.clock.sleep_until_precise(self.exchange.send_at());
        let now = self.clock.now();
        self.line.flush_input(now).map_err(io)?;
        let end = self.line.send(&buf[..n], now).map_err(io)?;
        self.exchange.sent(end, self.reply_within);
        loop {
            let deadline = self.exchange.deadline();
            let Some(rx) = self.line.recv(deadline, &mut self.clock).map_err(io)? else {
                if self.exchange.silence() != Silence::NoReply(None) {
                    self.garbled += 1;
                }
                return Ok(None);
            };
            match self.exchange.heard(rx.byte, rx.error, rx.at) {
                Heard::More => {}
                Heard::Telegram { telegram, .. } => return Ok(Some(telegram.as_bytes().to_vec())),
                Heard::Broken(_) => {
                    self.garbled += 1;
                    return Ok(None);
                }
            }
        }
    }

    /// How many exchanges brought bytes but no intact telegram since the last call.
    fn heard_garbled(&mut self) -> u32 {
        core::mem::take(&mut self.garbled)
    }

    /// Asks `address` up to [`Probe::tries`] times: the net words of the first intact reply from
    /// it, or `None` when it stayed silent (a reply lost, spoilt or from another address is
    /// asked again).
    fn ask(&mut self, adr: Adr, pkw: &[u16], pzd: &[u16]) -> Result<Option<Vec<u16>>, ScanError> {
        for _ in 0..self.tries {
            let Some(bytes) = self.exchange(adr, pkw, pzd)? else {
                continue;
            };
            let Ok(reply) = uss_protocol::Telegram::parse(&bytes) else {
                continue;
            };
            let net = reply.net();
            if reply.adr().address != adr.address || !net.len().is_multiple_of(2) {
                continue;
            }
            return Ok(Some(
                net.chunks_exact(2)
                    .map(|p| u16::from_be_bytes([p[0], p[1]]))
                    .collect(),
            ));
        }
        Ok(None)
    }
}

/// The PKW words of a request that reads `pnu` (element `index`) in a channel of `mode`
/// (none without a channel; 4 words for a variable one).
fn read_words(mode: PkwMode, pnu: u16, index: Option<u8>) -> Vec<u16> {
    let task = ParamTask::read(
        Pnu::from_u16(pnu),
        index.and_then(|i| Subindex::new(i).ok()),
    );
    let mut out = [0u16; MAX_PKW_WORDS];
    let n = task.encode(mode, &mut out).unwrap_or(0);
    out[..n].to_vec()
}

/// The channel a probe of `length` words carries a read in: 4 words where they fit, 3 for a
/// request of 3, none below; the rest are PZD (OFF1).
const fn probe_mode(length: usize) -> PkwMode {
    match length {
        0..=2 => PkwMode::None,
        3 => PkwMode::Three,
        _ => PkwMode::Four,
    }
}

/// What a reply says about the slave's layout, for a request of `length` words whose PKW
/// channel (4 words, or 3 for a request of 3) read `pnu`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Seen {
    /// A layout: its PKW mode and PZD length.
    Layout(PkwMode, usize),
    /// A 3-word channel at this length: a fixed one, or a variable one whose PZD length is one
    /// more than the request's (which then answers a request one word longer too).
    ThreeWords(usize),
    /// The reply does not tell (a status word that looks like a parameter answer, a length no
    /// layout gives).
    Unclear,
}

/// Whether `pke` (a reply's first word) answers a read of `pnu`: the same PNU (its low 11
/// bits) with a reply ID a read gets (1, 2, 4, 5, 6, error 7, no rights 8; "not yet" 0).
fn answers(pke: u16, pnu: u16) -> bool {
    pke & 0x07FF == pnu && matches!(pke >> 12, 0..=2 | 4..=8)
}

/// Whether a reply's value is a double word (reply ID 2 or 5), which only a 4-word channel
/// carries.
fn is_dword(reply: &[u16]) -> bool {
    reply.first().is_some_and(|&pke| matches!(pke >> 12, 2 | 5))
}

/// What a reply of `reply` words to a request of `length` words (PKW channel first, reading
/// `pnu`) says about the slave's layout.
fn seen(reply: &[u16], length: usize, pnu: u16) -> Seen {
    let pkw_request = probe_mode(length).request_words();
    let answered = reply.first().is_some_and(|&w| answers(w, pnu));
    if !answered {
        // No parameter answer in front: the slave has no channel, all its words are PZD.
        return if reply.len() == length && length <= 16 {
            Seen::Layout(PkwMode::None, length)
        } else {
            Seen::Unclear
        };
    }
    match (pkw_request, reply.len()) {
        // A 4-word request answered with one word less: the variable length (P2013 = 127).
        (4, n) if n + 1 == length => Seen::Layout(PkwMode::Variable, length - 4),
        // Its own length. A double word (reply 2 or 5) is a 4-word channel: a 3-word one
        // carries words only (USS.md section 6; a generic slave's P0003 may be one). A 4-word
        // channel sends a word value in its 4th word (the 3rd is 0); a 3-word channel sends it
        // in its 3rd word, and its status word ZSW1 (bits in the high byte) follows. A value 0
        // with a small word after it is a 4-word channel.
        (4, n) if n == length => {
            if is_dword(reply) || (reply[2] == 0 && reply[3] < 0x0100) {
                Seen::Layout(PkwMode::Four, length - 4)
            } else {
                Seen::ThreeWords(length - 3)
            }
        }
        (3, 3) => Seen::Layout(PkwMode::Three, 0),
        _ => Seen::Unclear,
    }
}

/// The request length a slave answers, its first reply there, and what that reply says of
/// its layout (a 3-word channel told fixed or variable by a request one word longer).
fn find_length(probe: &mut Probe, adr: Adr) -> Result<Option<(usize, Vec<u16>, Seen)>, ScanError> {
    let mut found = None;
    for length in lengths() {
        let pkw = read_words(probe_mode(length), PROBE_PNU, None);
        let pzd = length - pkw.len();
        if let Some(reply) = probe.ask(adr, &pkw, &SAFE_PZD[..pzd])? {
            found = Some((length, reply));
            break;
        }
    }
    let Some((length, first)) = found else {
        return Ok(None);
    };
    let mut layout = seen(&first, length, PROBE_PNU);
    // A 3-word channel: a variable one answers a 4-word request one word longer too. Asked
    // again even when that length was silent before: its replies may have been lost then.
    if let Seen::ThreeWords(pzd) = layout {
        let variable = length < 20 && {
            let pkw = read_words(PkwMode::Four, PROBE_PNU, None);
            probe.ask(adr, &pkw, &SAFE_PZD[..pzd])?.is_some_and(|r| {
                r.len() == length && r.first().is_some_and(|&w| answers(w, PROBE_PNU))
            })
        };
        let mode = if variable {
            PkwMode::Variable
        } else {
            PkwMode::Three
        };
        layout = Seen::Layout(mode, pzd);
    }
    Ok(Some((length, first, layout)))
}

/// A slave that answered the mirror telegram: its layout and family, as sure as the answers
/// make them.
fn identify(probe: &mut Probe, address: Address) -> Result<Found, ScanError> {
    let baud = probe.exchange.timing().baud();
    let adr = Adr::to(address);
    let mut drive = Found::unknown(baud, address);
    let Some((length, first, layout)) = find_length(probe, adr)? else {
        drive.unsure = Some(format!(
            "it answered the mirror telegram but no request of 1 to 20 words ({} tries each)",
            probe.tries
        ));
        return Ok(drive);
    };
    let mut unsure = Vec::new();
    let Seen::Layout(mode, pzd_words) = layout else {
        drive.unsure = Some(format!(
            "it answered requests of {length} words, but its reply does not tell the layout"
        ));
        return Ok(drive);
    };
    // A second reply, to another task, must say the same: in the layout's own shape (OFF1 in
    // the slave's STW1), and its status word is the drive's. Without a channel, the task goes
    // in front as before, and must again not be answered; then OFF1 in its own shape.
    let shape = if mode == PkwMode::None {
        probe_mode(length)
    } else {
        mode
    };
    let pkw = read_words(shape, CONFIRM_PNU, None);
    let pzd = if mode == PkwMode::None {
        length - pkw.len()
    } else {
        pzd_words
    };
    let mut second = probe.ask(adr, &pkw, &SAFE_PZD[..pzd])?;
    let confirmed = second.as_deref().map(|r| {
        let answered = r.first().is_some_and(|&w| answers(w, CONFIRM_PNU));
        match mode {
            PkwMode::None => r.len() == pzd_words && !answered,
            PkwMode::Four => answered && r.len() == 4 + pzd_words && r[2] == 0,
            PkwMode::Three | PkwMode::Variable => {
                answered && r.len() == 3 + pzd_words && !is_dword(r)
            }
        }
    });
    match confirmed {
        Some(true) => {}
        Some(false) => unsure.push("a second reply told another layout".to_owned()),
        None => unsure.push("the layout was seen in one reply only".to_owned()),
    }
    if mode == PkwMode::None && confirmed == Some(true) {
        second = probe
            .ask(adr, &[], &SAFE_PZD[..pzd_words])?
            .filter(|r| r.len() == pzd_words);
    }
    let reply_pkw = |r: &[u16]| r.len().saturating_sub(pzd_words);
    drive.pkw = Some(mode);
    drive.pzd = pzd_words;
    if pzd_words > 0 {
        drive.zsw1 = match &second {
            Some(r) if confirmed == Some(true) => r.get(reply_pkw(r)).copied(),
            _ => None,
        };
        if drive.zsw1.is_none() {
            unsure.push("ZSW1 from a reply not confirmed".to_owned());
            drive.zsw1 = first.get(first.len().saturating_sub(pzd_words)).copied();
        }
    }
    if matches!(mode, PkwMode::Four | PkwMode::Variable)
        && let Ok(count) = PzdCount::new(pzd_words)
    {
        let layout = Layout::new(mode, count);
        family(probe, address, layout, &mut drive, &mut unsure)?;
    }
    if !unsure.is_empty() {
        drive.unsure = Some(unsure.join("; "));
    }
    Ok(drive)
}

/// The family where the answers tell it: a SINAMICS drive (G120) answers the PROFIdrive
/// device identification r0964[0] with 42 (Siemens), its r0964[2] the firmware (470 = 4.70); a
/// MICROMASTER 4 or G110 has no r0964 but r0018, its firmware as a float. A value that is no
/// firmware version, or a question not answered, leaves the family open and says so.
fn family(
    probe: &mut Probe,
    address: Address,
    layout: Layout,
    drive: &mut Found,
    unsure: &mut Vec<String>,
) -> Result<(), ScanError> {
    match read_value(probe, address, layout, R0964, Some(0))? {
        Read::Value(v) if v.as_u32() == PROFIDRIVE_SIEMENS => {
            drive.family = Some(DriveFamily::G120);
            match read_value(probe, address, layout, R0964, Some(2))? {
                Read::Value(v) if (100..=9999).contains(&v.as_u32()) => {
                    drive.firmware = Some(f64::from(v.as_u32()) / 100.0);
                }
                Read::Value(v) => unsure.push(format!(
                    "r0964[2] = {} is not a firmware version",
                    v.as_u32()
                )),
                Read::Refused => unsure.push("r0964[2] was refused".to_owned()),
                Read::Silent => unsure.push("r0964[2] was not answered".to_owned()),
            }
        }
        // Another manufacturer's device identification: not a family uss-rt names.
        Read::Value(_) => {}
        Read::Silent => unsure.push("r0964 was not answered: the family is open".to_owned()),
        Read::Refused => match read_value(probe, address, layout, 18, None)? {
            Read::Value(v) => {
                let f = v.as_f32();
                if f.is_finite() && (0.01..100.0).contains(&f) {
                    drive.firmware = Some(firmware_version(f));
                    drive.family = Some(DriveFamily::Micromaster4);
                } else {
                    unsure.push(format!(
                        "r0018 = {:#010X} is not a firmware version: the family is open",
                        v.as_u32()
                    ));
                }
            }
            // A slave without r0018 (SIMOREG, others): left for the user to name.
            Read::Refused => {}
            Read::Silent => unsure.push("r0018 was not answered: the family is open".to_owned()),
        },
    }
    Ok(())
}

/// The PROFIdrive device identification (SINAMICS): element 0 the manufacturer, 2 the firmware
/// version (470 = 4.70).
const R0964: u16 = 964;
/// r0964[0] of a Siemens device.
const PROFIDRIVE_SIEMENS: u32 = 42;

/// What a read got.
enum Read {
    Value(Value),
    /// The drive refused it (it does not have the parameter).
    Refused,
    /// No answer to it within the tries.
    Silent,
}

/// A read of `pnu` (element `index`) over the drive's own layout, asked again while it answers
/// "not yet" or with a reply to another task.
fn read_value(
    probe: &mut Probe,
    address: Address,
    layout: Layout,
    pnu: u16,
    index: Option<u8>,
) -> Result<Read, ScanError> {
    let task = ParamTask::read(
        Pnu::from_u16(pnu),
        index.and_then(|i| Subindex::new(i).ok()),
    );
    let pkw = read_words(layout.pkw, pnu, index);
    for _ in 0..5 {
        let Some(reply) = probe.ask(Adr::to(address), &pkw, &SAFE_PZD[..layout.pzd.get()])? else {
            return Ok(Read::Silent);
        };
        let pkw_len = reply.len().saturating_sub(layout.pzd.get());
        if !layout.pkw.accepts_reply_words(pkw_len) {
            continue;
        }
        let Ok(answer) = ParamReply::decode(&reply[..pkw_len]) else {
            continue;
        };
        if !answer.answers(&task) {
            continue;
        }
        return Ok(match answer.kind {
            ReplyKind::Error(_) | ReplyKind::NoChangeRights => Read::Refused,
            kind => kind.value().map_or(Read::Refused, Read::Value),
        });
    }
    Ok(Read::Silent)
}
