//! Captured telegrams decoded at three levels (`ussctl capture --level`): `raw` (the bytes),
//! `frame` (STX, LGE, ADR, PKW and PZD words, BCC checked; USS.md section 3), `app` (the PKW
//! task or reply in the manuals' notation with the catalogue's type and unit, STW1/ZSW1 with
//! their bits named, setpoint and actual value in % and Hz; USS.md sections 6 and 7).

use clap::ValueEnum;
use core::fmt::Write as _;
use serde::Serialize;
use uss_client::uss_protocol::{
    Adr, Layout, ParamRef, ParamReply, PkwMode, Prefix, PzdCount, ReplyKind, Subindex, Telegram,
    bcc,
};
use uss_client::uss_shm_types::{Hex, TelegramRecord};
use uss_client::{Catalogue, ParamTask, Pnu, Setpoint, Value, state_name, zsw1_flags};

/// How much of a telegram `capture` shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Level {
    /// The bytes.
    Raw,
    /// STX, LGE, ADR, PKW and PZD words, BCC.
    Frame,
    /// Parameter tasks and replies, control and status words, setpoints and actual values.
    App,
}

/// One captured telegram, decoded.
#[derive(Debug, Clone, Serialize, schemars::JsonSchema)]
pub struct CaptureLine {
    pub sequence: u64,
    /// Seconds since the first telegram shown.
    pub t: f64,
    /// `CLOCK_MONOTONIC` ns of the first and last byte.
    pub start_ns: u64,
    pub end_ns: u64,
    /// "request" or "reply".
    pub direction: &'static str,
    pub drive: u8,
    /// A reply: "good" or what failed ("no response", "BCC error", ...); a request: "sent".
    pub outcome: &'static str,
    /// The bytes in hex, space-separated.
    pub bytes: String,
    pub truncated: bool,
    /// Present when the bytes are one whole telegram.
    pub frame: Option<Frame>,
    /// Present at `--level app` for a whole telegram.
    pub app: Option<App>,
    /// The level the line is shown at (not in `--json`).
    #[serde(skip)]
    pub level: Level,
}

/// A telegram's frame: STX, LGE, ADR, words, BCC.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, schemars::JsonSchema)]
pub struct Frame {
    pub stx: u8,
    pub lge: u8,
    pub adr: u8,
    pub pkw: Vec<u16>,
    pub pzd: Vec<u16>,
    pub bcc: u8,
    /// The BCC the bytes before it give (USS.md section 3).
    pub bcc_expected: u8,
}

/// A telegram's meaning.
#[derive(Debug, Clone, PartialEq, Serialize, schemars::JsonSchema)]
pub struct App {
    /// The parameter task or reply: `read P1082`, `P1082 = 50.00 Hz`, `no task`.
    pub pkw: Option<String>,
    /// "STW1" (request) or "ZSW1" (reply).
    pub word1_name: &'static str,
    /// STW1 (request) or ZSW1 (reply).
    pub word1: Option<u16>,
    /// Its set bits (STW1) or its state and flags (ZSW1), named.
    pub word1_bits: Vec<&'static str>,
    /// "setpoint" (request) or "actual" (reply).
    pub value2_name: &'static str,
    /// The setpoint (request) or actual value (reply), raw, in % and in Hz of the drive's
    /// reference frequency.
    pub value2: Option<u16>,
    pub percent: Option<f64>,
    pub hz: Option<f64>,
}

/// What a decoder needs besides the record: the catalogue of each drive's family for parameter
/// names and types, and each drive's reference frequency P2000 (both by address).
pub struct Decoder<'a> {
    pub catalogue: &'a dyn Fn(u8) -> Option<&'static Catalogue>,
    pub reference_hz: &'a dyn Fn(u8) -> Option<f32>,
    pub level: Level,
}

impl Decoder<'_> {
    pub fn decode(&self, r: &TelegramRecord, t: f64) -> CaptureLine {
        let request = r.is_request();
        let bytes = r.bytes();
        let frame = frame(bytes, layout(r));
        let app = match (&frame, self.level) {
            (Some(f), Level::App) => Some(self.app(r, f, request)),
            _ => None,
        };
        CaptureLine {
            sequence: r.sequence,
            t,
            start_ns: r.start_ns,
            end_ns: r.end_ns,
            direction: if request { "request" } else { "reply" },
            drive: r.address,
            outcome: r.outcome_name(),
            bytes: Hex(bytes).to_string(),
            truncated: r.flags & uss_client::uss_shm_types::CAPTURE_TRUNCATED != 0,
            frame,
            app,
            level: self.level,
        }
    }

    fn app(&self, r: &TelegramRecord, f: &Frame, request: bool) -> App {
        let pkw = match f.pkw.len() {
            0 => None,
            _ if request => Some(match ParamTask::decode(&f.pkw) {
                Ok(task) => Params((self.catalogue)(r.address)).task(task),
                Err(e) => format!("PKW not understood: {e}"),
            }),
            _ => Some(match ParamReply::decode(&f.pkw) {
                Ok(reply) => Params((self.catalogue)(r.address)).reply(&reply),
                Err(e) => format!("PKW not understood: {e}"),
            }),
        };
        let word1 = f.pzd.first().copied();
        let word1_bits = match word1 {
            Some(w) if request => crate::report::stw1_bits(w),
            Some(w) => {
                let state = state_name(w);
                let mut bits = vec![state];
                // The fault bit is the state "fault" already.
                bits.extend(zsw1_flags(w).into_iter().filter(|&f| f != state));
                bits
            }
            None => Vec::new(),
        };
        let value2 = f.pzd.get(1).copied();
        let percent = value2.map(|v| f64::from(Setpoint::from_raw(v as i16).percent()));
        let hz = percent.and_then(|p| {
            (self.reference_hz)(r.address).map(|reference| p / 100.0 * f64::from(reference))
        });
        App {
            pkw,
            word1_name: if request { "STW1" } else { "ZSW1" },
            word1,
            word1_bits,
            value2_name: if request { "setpoint" } else { "actual" },
            value2,
            percent,
            hz,
        }
    }
}

/// A drive's parameters as its family's catalogue names and shows them (none: as numbers).
struct Params(Option<&'static Catalogue>);

impl Params {
    /// `P1082` or `r0947[2]`, with the catalogue's prefix.
    fn name(&self, pnu: Pnu, index: Option<u8>) -> String {
        let prefix = self
            .0
            .and_then(|c| c.param(pnu.get()))
            .map_or(Prefix::P, |p| p.id.prefix);
        ParamRef {
            pnu,
            index: index.and_then(|i| Subindex::new(i).ok()),
            prefix,
        }
        .to_string()
    }

    /// A value of parameter `pnu` as the catalogue shows it: `50.00 Hz`, `5`, `0xFB31`.
    fn value(&self, pnu: Pnu, v: Value) -> String {
        match self.0.and_then(|c| c.param(pnu.get())) {
            Some(p) => p.show(v),
            None => match v {
                Value::Word(w) => format!("{w} ({w:#06X})"),
                Value::Dword(d) => format!("{d} ({d:#010X})"),
            },
        }
    }

    fn task(&self, task: ParamTask) -> String {
        match task {
            ParamTask::None => "no task".into(),
            ParamTask::Read { pnu } => format!("read {}", self.name(pnu, None)),
            ParamTask::ReadArray { pnu, index } => {
                format!("read {}", self.name(pnu, Some(index.get())))
            }
            ParamTask::ReadArrayLen { pnu } => {
                format!("read the element count of {}", self.name(pnu, None))
            }
            ParamTask::ReadDescription { pnu, element } => format!(
                "read descriptive element {} of {}",
                element.get(),
                self.name(pnu, None)
            ),
            ParamTask::Write {
                pnu,
                value,
                storage,
            } => format!(
                "write {} := {}{}",
                self.name(pnu, None),
                self.value(pnu, value),
                storage_text(storage)
            ),
            ParamTask::WriteArray {
                pnu,
                index,
                value,
                storage,
            } => format!(
                "write {} := {}{}",
                self.name(pnu, Some(index.get())),
                self.value(pnu, value),
                storage_text(storage)
            ),
        }
    }

    fn reply(&self, r: &ParamReply) -> String {
        let indexed = || self.name(r.pnu, Some(r.subindex));
        match r.kind {
            ReplyKind::NotYet => "no reply yet".into(),
            ReplyKind::Word(w) => format!(
                "{} = {}",
                self.name(r.pnu, None),
                self.value(r.pnu, Value::Word(w))
            ),
            ReplyKind::Dword(d) => format!(
                "{} = {}",
                self.name(r.pnu, None),
                self.value(r.pnu, Value::Dword(d))
            ),
            ReplyKind::ArrayWord(w) => {
                format!("{} = {}", indexed(), self.value(r.pnu, Value::Word(w)))
            }
            ReplyKind::ArrayDword(d) => {
                format!("{} = {}", indexed(), self.value(r.pnu, Value::Dword(d)))
            }
            ReplyKind::ElementCount(n) => {
                format!("{} has {n} elements", self.name(r.pnu, None))
            }
            ReplyKind::Description(v) => format!(
                "descriptive element {} of {} = {}",
                r.subindex,
                self.name(r.pnu, None),
                v.as_u32()
            ),
            ReplyKind::Error(e) => format!("{} refused: {e}", self.name(r.pnu, None)),
            ReplyKind::NoChangeRights => {
                format!("{}: no change rights (AK 8)", self.name(r.pnu, None))
            }
            ReplyKind::ChangeReport { id, value } | ReplyKind::Other { id, value } => format!(
                "{}: reply ID {id}, value {}",
                self.name(r.pnu, None),
                value.as_u32()
            ),
        }
    }
}

const fn storage_text(storage: uss_client::uss_protocol::Storage) -> &'static str {
    match storage {
        uss_client::uss_protocol::Storage::Ram => " (RAM)",
        uss_client::uss_protocol::Storage::RamAndEeprom => " (RAM and EEPROM)",
    }
}

/// The record's drive layout, if its codes are valid.
fn layout(r: &TelegramRecord) -> Option<Layout> {
    let pkw = PkwMode::from_p2013(u16::from(r.pkw))?;
    let pzd = PzdCount::new(usize::from(r.pzd)).ok()?;
    Some(Layout::new(pkw, pzd))
}

/// The frame of `bytes` when they are one telegram of the right length (its BCC may be
/// wrong: that is shown, not hidden).
fn frame(bytes: &[u8], layout: Option<Layout>) -> Option<Frame> {
    let (&stx, rest) = bytes.split_first()?;
    let (&lge, _) = rest.split_first()?;
    if bytes.len() != usize::from(lge) + 2 || bytes.len() < 4 {
        return None;
    }
    let (body, last) = bytes.split_at(bytes.len() - 1);
    let words: Vec<u16> = bytes[3..bytes.len() - 1]
        .chunks_exact(2)
        .map(|p| u16::from_be_bytes([p[0], p[1]]))
        .collect();
    // With a good BCC the protocol's own split (PKW length from LGE); otherwise by layout.
    let split = Telegram::parse(bytes)
        .ok()
        .zip(layout)
        .and_then(|(t, l)| t.words(l).ok())
        .map(|w| w.pkw().len())
        .or_else(|| {
            let pzd = layout?.pzd.get();
            words.len().checked_sub(pzd)
        })
        .unwrap_or(0)
        .min(words.len());
    Some(Frame {
        stx,
        lge,
        adr: bytes[2],
        pkw: words[..split].to_vec(),
        pzd: words[split..].to_vec(),
        bcc: last[0],
        bcc_expected: bcc(body),
    })
}

fn words(w: &[u16]) -> String {
    w.iter()
        .map(|w| format!("{w:04X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

impl CaptureLine {
    /// One line: time, direction and drive, then the chosen level.
    pub fn human(&self) -> String {
        let arrow = if self.direction == "request" {
            "->"
        } else {
            "<-"
        };
        let head = format!("{:>10.6}  {arrow} {:>2}  ", self.t, self.drive);
        let failed = self.outcome != "good" && self.outcome != "sent";
        let mut body = match (self.level, &self.frame) {
            (_, _) if self.bytes.is_empty() => String::new(),
            (Level::Raw, _) | (_, None) => self.bytes.clone(),
            (Level::Frame, Some(f)) => frame_text(f),
            (Level::App, Some(f)) => self.app.as_ref().map_or_else(|| frame_text(f), app_text),
        };
        if failed {
            body = if body.is_empty() {
                self.outcome.to_owned()
            } else {
                format!("{}: {body}", self.outcome)
            };
        }
        if self.truncated {
            body.push_str(" (more bytes came than a record holds)");
        }
        head + &body
    }
}

fn frame_text(f: &Frame) -> String {
    let adr = Adr::from_byte(f.adr);
    let mut text = format!(
        "STX {:02X} LGE {} ADR {:02X} (drive {})",
        f.stx,
        f.lge,
        f.adr,
        adr.address.get()
    );
    if !f.pkw.is_empty() {
        let _ = write!(text, " PKW {}", words(&f.pkw));
    }
    if !f.pzd.is_empty() {
        let _ = write!(text, " PZD {}", words(&f.pzd));
    }
    if f.bcc == f.bcc_expected {
        let _ = write!(text, " BCC {:02X} ok", f.bcc);
    } else {
        let _ = write!(text, " BCC {:02X} (expected {:02X})", f.bcc, f.bcc_expected);
    }
    text
}

fn app_text(a: &App) -> String {
    let mut parts = Vec::new();
    if let Some(pkw) = &a.pkw {
        parts.push(pkw.clone());
    }
    if let Some(w) = a.word1 {
        parts.push(format!(
            "{} {w:#06X} {}",
            a.word1_name,
            a.word1_bits.join(" ")
        ));
    }
    if let (Some(v), Some(p)) = (a.value2, a.percent) {
        let mut text = format!("{} {v:#06X} = {p:.1} %", a.value2_name);
        if let Some(hz) = a.hz {
            let _ = write!(text, " = {hz:.2} Hz");
        }
        parts.push(text);
    }
    parts.join(" | ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use uss_client::uss_protocol::{Address, encode};
    use uss_client::uss_shm_types::{CAPTURE_BYTES, Direction, LastFailure};

    fn record(direction: Direction, outcome: LastFailure, bytes: &[u8]) -> TelegramRecord {
        let mut r = TelegramRecord {
            direction: direction.code(),
            outcome: outcome.code(),
            address: 1,
            pkw: 4,
            pzd: 2,
            len: bytes.len() as u16,
            ..TelegramRecord::EMPTY
        };
        r.bytes[..bytes.len()].copy_from_slice(bytes);
        r
    }

    fn telegram(pkw: &[u16], pzd: &[u16]) -> Vec<u8> {
        let mut out = [0u8; 64];
        let n = encode(&mut out, Adr::to(Address::new(1).unwrap()), pkw, pzd).unwrap();
        out[..n].to_vec()
    }

    fn line(level: Level, r: &TelegramRecord) -> String {
        let hz = |_| Some(50.0);
        Decoder {
            catalogue: &|_| Some(Catalogue::micromaster4()),
            reference_hz: &hz,
            level,
        }
        .decode(r, 0.25)
        .human()
    }

    /// A faulted drive's ZSW1 says "fault" once: the state, not the state and its bit again
    /// (the capture showed 0xBB38 as "fault fault").
    #[test]
    fn a_fault_is_named_once() {
        let reply = record(
            Direction::Reply,
            LastFailure::None,
            &telegram(&[0, 0, 0, 0], &[0xBB38, 0]),
        );
        let shown = line(Level::App, &reply);
        assert!(shown.contains("ZSW1 0xBB38 fault "), "{shown}");
        assert_eq!(shown.matches("fault").count(), 1, "{shown}");
    }

    #[test]
    fn a_drive_of_another_family_is_shown_with_its_own_catalogue() {
        // p1082 of a G120 is a speed in rpm; of a generic slave, a number.
        let reply = record(
            Direction::Reply,
            LastFailure::None,
            &telegram(&[0x243A, 0, 0x44BB, 0x8000], &[0xBB37, 0x2000]),
        );
        let hz = |_| None;
        let shown = |catalogue: Option<&'static Catalogue>| {
            Decoder {
                catalogue: &move |_| catalogue,
                reference_hz: &hz,
                level: Level::App,
            }
            .decode(&reply, 0.25)
            .human()
        };
        let g120 = shown(Catalogue::of(uss_client::DriveFamily::G120));
        assert!(g120.contains("p1082 = 1500.00 rpm |"), "{g120}");
        let generic = shown(None);
        assert!(
            generic.contains("P1082 = 1153138688 (0x44BB8000) |"),
            "{generic}"
        );
    }

    #[test]
    fn each_level_shows_a_parameter_read_and_its_reply() {
        let request = record(
            Direction::Request,
            LastFailure::None,
            &telegram(&[0x143A, 0, 0, 0], &[0x047F, 0x2000]),
        );
        assert_eq!(
            line(Level::Raw, &request),
            "  0.250000  ->  1  02 0E 01 14 3A 00 00 00 00 00 00 04 7F 20 00 78"
        );
        assert_eq!(
            line(Level::Frame, &request),
            "  0.250000  ->  1  STX 02 LGE 14 ADR 01 (drive 1) PKW 143A 0000 0000 0000 PZD 047F 2000 BCC 78 ok"
        );
        assert_eq!(
            line(Level::App, &request),
            "  0.250000  ->  1  read P1082 | STW1 0x047F ON no-OFF2 no-OFF3 pulses-enabled RFG-enabled RFG-start setpoint-enabled control-by-PLC | setpoint 0x2000 = 50.0 % = 25.00 Hz"
        );
        let reply = record(
            Direction::Reply,
            LastFailure::None,
            &telegram(&[0x243A, 0, 0x4248, 0], &[0xBB37, 0x2000]),
        );
        assert_eq!(
            line(Level::App, &reply),
            "  0.250000  <-  1  P1082 = 50.00 Hz | ZSW1 0xBB37 S4 at-setpoint control-requested | actual 0x2000 = 50.0 % = 25.00 Hz"
        );
        let refused = record(
            Direction::Reply,
            LastFailure::None,
            &telegram(&[0x7000 | 1082, 0, 0, 5], &[0xBB31, 0]),
        );
        assert!(
            line(Level::App, &refused).contains("P1082 refused: error 5: wrong data type |"),
            "{}",
            line(Level::App, &refused)
        );
    }

    #[test]
    fn failed_replies_say_what_failed_and_show_what_came() {
        let none = record(Direction::Reply, LastFailure::NoResponse, &[]);
        assert_eq!(line(Level::App, &none), "  0.250000  <-  1  no response");
        let mut broken = telegram(&[0, 0, 0, 0], &[0xBB31, 0]);
        let last = broken.len() - 1;
        broken[last] ^= 0xFF;
        let bcc = record(Direction::Reply, LastFailure::Bcc, &broken);
        let shown = line(Level::Frame, &bcc);
        assert!(
            shown.starts_with("  0.250000  <-  1  BCC error: STX 02 LGE 14"),
            "{shown}"
        );
        assert!(shown.ends_with(&format!(
            "BCC {:02X} (expected {:02X})",
            broken[last],
            broken[last] ^ 0xFF
        )));
        let garbage = record(
            Direction::Reply,
            LastFailure::MissingStx,
            &[0xFF, 0x00, 0x13],
        );
        assert_eq!(
            line(Level::App, &garbage),
            "  0.250000  <-  1  missing STX: FF 00 13"
        );
    }

    proptest! {
        /// Any bytes, any codes: the decoder shows them and never panics.
        #[test]
        fn any_record_decodes(
            bytes in proptest::collection::vec(any::<u8>(), 0..CAPTURE_BYTES),
            direction in 0u8..3,
            outcome in 0u8..16,
            pkw in any::<u8>(),
            pzd in any::<u8>(),
        ) {
            let mut r = record(Direction::Request, LastFailure::None, &bytes);
            (r.direction, r.outcome, r.pkw, r.pzd) = (direction, outcome, pkw, pzd);
            for level in [Level::Raw, Level::Frame, Level::App] {
                let _ = line(level, &r);
            }
        }

        /// A telegram as the master encodes it comes back as its words.
        #[test]
        fn frames_give_back_the_words(
            pkw in proptest::collection::vec(any::<u16>(), 4..=4),
            pzd in proptest::collection::vec(any::<u16>(), 2..=2),
        ) {
            let bytes = telegram(&pkw, &pzd);
            let f = frame(&bytes, Some(Layout::new(PkwMode::Four, PzdCount::new(2).unwrap())))
                .unwrap();
            prop_assert_eq!(f.pkw, pkw);
            prop_assert_eq!(f.pzd, pzd);
            prop_assert_eq!(f.bcc, f.bcc_expected);
        }
    }
}
