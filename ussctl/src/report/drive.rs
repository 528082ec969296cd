//! One drive: `watch` lines, parameters, faults, operator stops, `run` and `ack`.

use super::shown_state;
use super::status::ControlView;
use serde::Serialize;
use std::fmt::Write as _;
use uss_client::uss_catalogue::Bits;
use uss_client::uss_protocol::Subindex;
use uss_client::{
    Address, FaultReport, ParamValue, PzdInput, Quantity, Setpoint, StopCommand, Value, zsw1_flags,
};

/// One drive in one round of `watch`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct WatchLine {
    /// Seconds since `watch` started.
    pub t: f64,
    pub drive: u8,
    pub online: bool,
    pub state: &'static str,
    pub zsw1: u16,
    pub hiw: u16,
    pub actual_hz: f32,
    /// Good replies so far.
    pub sequence: u64,
    /// The drive's update period (time between its last two good replies), ms.
    pub period_ms: f64,
    pub control: ControlView,
    /// STW1 of the telegram that brought this reply.
    pub sent_stw1: u16,
    /// PZD3.. as the drive sent them.
    pub extra: Vec<u16>,
}

impl WatchLine {
    pub fn new(t: f64, drive: Address, i: &PzdInput, reference_hz: f32) -> Self {
        let online = i.online != 0;
        let extra_words = usize::from(i.word_count)
            .saturating_sub(2)
            .min(i.extra.len());
        Self {
            t,
            drive: drive.get(),
            online,
            state: shown_state(i.known, i.online, i.zsw1),
            zsw1: i.zsw1,
            hiw: i.hiw,
            // No Hz while ussd reads the reference again (0): NaN, not a speed of 0.
            actual_hz: if reference_hz > 0.0 {
                Setpoint::from_word(i.hiw).hz(reference_hz)
            } else {
                f32::NAN
            },
            sequence: i.sequence,
            period_ms: i.age_ns as f64 / 1e6,
            control: ControlView::of_input(i),
            sent_stw1: i.sent_stw1,
            extra: i.extra[..extra_words].to_vec(),
        }
    }

    pub fn human(&self) -> String {
        let mut out = format!(
            "{:8.3}s  drive {:>2}  {:<9}  ZSW1 {:#06X}  {:>8.2} Hz  replies {:>8}  period {:>6.2} ms",
            self.t,
            self.drive,
            self.state,
            self.zsw1,
            self.actual_hz,
            self.sequence,
            self.period_ms
        );
        if !self.extra.is_empty() {
            let words: Vec<_> = self.extra.iter().map(|w| format!("{w:#06X}")).collect();
            let _ = write!(out, "  PZD3.. {}", words.join(" "));
        }
        if self.control.state != "live" {
            let _ = write!(out, "  [{}]", self.control.human());
        }
        out
    }
}

/// `param read` / `param write`: the value in the parameter's own type and unit.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ParamReport {
    pub bus: String,
    pub drive: u8,
    /// As the manuals write it: `P1082`, `r0947[3]`.
    pub param: String,
    pub pnu: u16,
    pub index: Option<u8>,
    /// The catalogue's name; null for a parameter it does not know.
    pub name: Option<&'static str>,
    /// The data type: "float", "U16", "I16", "U32", "I32".
    #[serde(rename = "type")]
    pub data_type: String,
    /// "Hz", "s", ...; empty when none or not known.
    pub unit: &'static str,
    pub raw: u32,
    pub hex: String,
    /// The value in its type and unit: a float for float and for a fixed-point parameter in
    /// its unit (SIMOREG P303: raw 1000 is 10.0 s), an integer otherwise.
    #[schemars(with = "f64")]
    pub value: Quantity,
    /// A status or control word's set bits by name (r0052, r0054).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub bits: Vec<&'static str>,
    /// Set for a write: whether it went to EEPROM too.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eeprom: Option<bool>,
    /// The value as shown to people: `50.00 Hz`.
    #[serde(skip)]
    shown: String,
}

impl ParamReport {
    pub fn new(bus: &str, drive: Address, v: &ParamValue) -> Self {
        let typed = v.typed();
        let bits = match v.info.and_then(|p| p.bits) {
            Some(Bits::ZSW1) => zsw1_flags(v.raw.as_u32() as u16),
            Some(Bits::STW1) => stw1_bits(v.raw.as_u32() as u16),
            None => Vec::new(),
        };
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            param: v.id(),
            pnu: v.param.pnu.get(),
            index: v.param.index.map(Subindex::get),
            name: v.name(),
            data_type: v.data_type.to_string(),
            unit: v.unit(),
            raw: v.raw.as_u32(),
            hex: match v.raw {
                Value::Word(w) => format!("{w:#06X}"),
                Value::Dword(d) => format!("{d:#010X}"),
            },
            value: v.value(),
            bits,
            eeprom: None,
            shown: v.shown_typed(typed),
        }
    }

    pub fn human(&self) -> String {
        let mut out = match self.eeprom {
            None => format!("drive {} {} = {}", self.drive, self.param, self.shown),
            Some(eeprom) => format!(
                "drive {} {} := {}{}",
                self.drive,
                self.param,
                self.shown,
                if eeprom { ", RAM and EEPROM" } else { ", RAM" }
            ),
        };
        if let Some(name) = self.name {
            let _ = write!(out, "  ({name})");
        }
        if !self.bits.is_empty() {
            let _ = write!(out, ": {}", self.bits.join(", "));
        }
        out
    }
}

/// The set bits of a control word 1 by name (USS.md section 7).
pub(crate) fn stw1_bits(stw1: u16) -> Vec<&'static str> {
    const NAMES: [&str; 16] = [
        "ON",
        "no-OFF2",
        "no-OFF3",
        "pulses-enabled",
        "RFG-enabled",
        "RFG-start",
        "setpoint-enabled",
        "fault-ack",
        "jog-right",
        "jog-left",
        "control-by-PLC",
        "reverse",
        "bit12",
        "motor-pot-up",
        "motor-pot-down",
        "local-remote",
    ];
    NAMES
        .iter()
        .enumerate()
        .filter(|&(i, _)| stw1 & (1 << i) != 0)
        .map(|(_, &n)| n)
        .collect()
}

/// `faults`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct FaultsReport {
    pub bus: String,
    pub drive: u8,
    /// Where the faults were read: the fault codes (`r0947` on MICROMASTER 4, `r0945` on
    /// G120), their values (`r0949`), the warnings (`r2110`, `r2122`).
    pub codes_param: String,
    pub values_param: Option<String>,
    pub warnings_param: Option<String>,
    /// The fault codes with their values, newest first; empty slots left out.
    pub faults: Vec<FaultEntry>,
    /// The active warnings; null when the drive has none uss-rt reads.
    pub warnings: Option<Vec<WarningEntry>>,
}

#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct FaultEntry {
    /// Element of the fault buffer: 0 is the newest.
    pub slot: u8,
    pub number: u16,
    /// `F0072`.
    pub code: String,
    /// The fault value (r0949, its 32 bits unsigned); null when the drive has none.
    pub value: Option<u32>,
    /// When it came as shown: a MICROMASTER 4's r0948 of its trip (`2026-11-22 20:31:05`, or
    /// `day 3 04:05:06` from a drive clock never set), a SINAMICS runtime r2130/r0948 (`day 3
    /// 04:05:06.789`); null when the drive has none or left it empty.
    pub time: Option<String>,
    /// A MICROMASTER 4's r0948: its three words as read.
    pub time_words: Option<[u16; 3]>,
    pub text: Option<&'static str>,
}

#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct WarningEntry {
    pub number: u16,
    /// `A0501`.
    pub code: String,
    pub text: Option<&'static str>,
}

impl FaultsReport {
    pub fn new(bus: &str, drive: Address, r: &FaultReport) -> Self {
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            codes_param: r.notation(r.codes),
            values_param: r.values.map(|p| r.notation(p)),
            warnings_param: r.warnings_from.map(|p| r.notation(p)),
            faults: r
                .faults
                .iter()
                .map(|f| FaultEntry {
                    slot: f.slot,
                    number: f.number,
                    code: format!("F{:0w$}", f.number, w = usize::from(r.digits)),
                    value: f.value,
                    time: f.when(),
                    time_words: f.time.map(|t| t.words),
                    text: f.text,
                })
                .collect(),
            warnings: r.warnings.as_ref().map(|w| {
                w.iter()
                    .map(|w| WarningEntry {
                        number: w.number,
                        code: format!("A{:0w$}", w.number, w = usize::from(r.digits)),
                        text: w.text,
                    })
                    .collect()
            }),
        }
    }

    pub fn human(&self) -> String {
        let codes = &self.codes_param;
        let mut out = if self.faults.is_empty() {
            format!("drive {}: no faults recorded ({codes} empty)\n", self.drive)
        } else {
            format!("drive {} fault buffer {codes}, newest first:\n", self.drive)
        };
        for f in &self.faults {
            let _ = write!(out, "  {}: {}", f.slot, f.code);
            if let Some(text) = f.text {
                let _ = write!(out, " {text}");
            }
            if let (Some(v), Some(p)) = (f.value, &self.values_param) {
                let _ = write!(out, " (fault value {p} = {v})");
            }
            if let Some(t) = &f.time {
                let _ = write!(out, " at {t}");
            }
            out.push('\n');
        }
        let from = self.warnings_param.as_deref().unwrap_or("warnings");
        match &self.warnings {
            None => {}
            Some(w) if w.is_empty() => {
                let _ = writeln!(out, "active warnings ({from}): none");
            }
            Some(w) => {
                let _ = writeln!(out, "active warnings ({from}):");
                for w in w {
                    let _ = writeln!(out, "  {} {}", w.code, w.text.unwrap_or("(no text known)"));
                }
            }
        }
        out
    }
}

/// `stop`, `coast`, `quick-stop`: the drives that got the command and what they show now.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct StopReport {
    pub bus: String,
    /// "OFF1", "OFF2" or "OFF3".
    pub command: &'static str,
    pub drives: Vec<StoppedDrive>,
}

/// One drive after an operator's stop command.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct StoppedDrive {
    pub drive: u8,
    pub online: bool,
    pub state: &'static str,
    pub zsw1: u16,
    /// STW1 of the telegram the image came with: the command that went out.
    pub sent_stw1: u16,
    pub control: ControlView,
    /// Whether the drive's image showed the command; when not, why this process could not
    /// read it (the command stands: ussd took it).
    pub confirmed: bool,
    pub unconfirmed_because: Option<String>,
}

impl StopReport {
    pub fn new(bus: &str, command: StopCommand) -> Self {
        Self {
            bus: bus.to_owned(),
            command: command.name(),
            drives: Vec::new(),
        }
    }

    pub fn push(&mut self, drive: Address, i: &PzdInput) {
        let online = i.online != 0;
        self.drives.push(StoppedDrive {
            drive: drive.get(),
            online,
            state: shown_state(i.known, i.online, i.zsw1),
            zsw1: i.zsw1,
            sent_stw1: i.sent_stw1,
            control: ControlView::of_input(i),
            confirmed: true,
            unconfirmed_because: None,
        });
    }

    /// Drives ussd took the command for whose images this process cannot read (`why`).
    pub fn unconfirmed(&mut self, drives: &[Address], why: &uss_client::ClientError) {
        for &drive in drives {
            self.drives.push(StoppedDrive {
                drive: drive.get(),
                online: false,
                state: "not read",
                zsw1: 0,
                sent_stw1: 0,
                control: ControlView::of_input(&PzdInput::EMPTY),
                confirmed: false,
                unconfirmed_because: Some(why.to_string()),
            });
        }
    }

    pub fn human(&self) -> String {
        let mut out = String::new();
        for d in &self.drives {
            if let Some(why) = &d.unconfirmed_because {
                let _ = writeln!(
                    out,
                    "drive {}: {} taken by ussd on {}, sent in its next telegram, latched until its controller re-arms it; not confirmed here: {why}",
                    d.drive, self.command, self.bus
                );
                continue;
            }
            // What the drive gets: a stronger stop it had stays (OFF2 over OFF3 over OFF1).
            let sent = d.control.command.unwrap_or(self.command);
            let what = match sent {
                "OFF2" => "it coasts",
                "OFF3" => "it stops quickly",
                _ => "it ramps down",
            };
            let kept = if sent == self.command {
                String::new()
            } else {
                format!(
                    ": its {sent} stays, stronger than the {} asked",
                    self.command
                )
            };
            let _ = writeln!(
                out,
                "drive {}: {sent} sent (STW1 {:#06X}) on {}, {what}{kept}; now {} (ZSW1 {:#06X}); {} until a controller re-arms it (its explicit rearm, `ussctl run`)",
                d.drive, d.sent_stw1, self.bus, d.state, d.zsw1, d.control.state,
            );
        }
        out
    }
}

/// The end of `run` or `ack`: what the drive shows now.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DriveReport {
    pub bus: String,
    pub drive: u8,
    /// What ussctl did: "run", "stop", "ack".
    pub action: &'static str,
    pub online: bool,
    pub state: &'static str,
    pub zsw1: u16,
    pub actual_hz: f32,
    /// `run`: the highest actual frequency seen.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peak_hz: Option<f32>,
}

impl DriveReport {
    pub fn new(bus: &str, action: &'static str, i: &PzdInput, drive: Address, ref_hz: f32) -> Self {
        let online = i.online != 0;
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            action,
            online,
            state: shown_state(i.known, i.online, i.zsw1),
            zsw1: i.zsw1,
            actual_hz: if ref_hz > 0.0 {
                Setpoint::from_word(i.hiw).hz(ref_hz)
            } else {
                f32::NAN
            },
            peak_hz: None,
        }
    }

    /// `run`'s report with the highest frequency seen while it ran (`peak`), or the one it
    /// ends at where that is higher: the drive ramps on until it gets the stop.
    #[must_use]
    pub fn with_peak(mut self, peak: f32) -> Self {
        self.peak_hz = Some(if self.actual_hz.abs() > peak.abs() {
            self.actual_hz
        } else {
            peak
        });
        self
    }

    pub fn human(&self) -> String {
        let what = match self.action {
            "run" => "ran; OFF1 sent, it ramps down",
            _ => "fault acknowledge sent",
        };
        let mut out = format!(
            "drive {}: {what}; now {} (ZSW1 {:#06X}), {:.2} Hz",
            self.drive, self.state, self.zsw1, self.actual_hz
        );
        if let Some(p) = self.peak_hz {
            let _ = write!(out, ", peak {p:.2} Hz");
        }
        out
    }
}
