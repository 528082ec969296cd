//! `param restore` and `param diff`.

use crate::commands::backup::Step;
use serde::Serialize;
use std::fmt::Write as _;
use uss_client::backup::Entry;
use uss_client::uss_catalogue::Param;
use uss_client::uss_protocol::ParamRef;
use uss_client::{Address, ParamError, Value};

/// One value of a restore: what the drive had, what the file says, what happened.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct RestoreLine {
    pub param: String,
    pub was: Option<String>,
    pub wanted: String,
    /// "planned", "written", "refused: ...", "unknown: ..." (the write reached the drive and
    /// its answer was lost: the drive may hold the value), "not written"; for the access level
    /// and quick commissioning a restore cut short had raised: "put back after Ctrl-C" or "put
    /// back after the cut" (`was` the raised value, `wanted` the drive's before the restore),
    /// or "LEFT RAISED: ..." with why and the command that puts it back.
    pub result: String,
}

/// `param restore`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct RestoreReport {
    pub bus: String,
    pub drive: u8,
    pub file: String,
    pub dry_run: bool,
    /// Values the drive already held.
    pub equal: usize,
    pub written: usize,
    pub refused: usize,
    /// Writes that reached the drive whose answer was lost: the drive may hold the value.
    pub unknown: usize,
    /// COM-link settings that differ but are kept (baud rate, address, PZD/PKW length).
    pub kept: usize,
    /// Why the restore stopped early (null: it ran to the end).
    pub cut_short: Option<String>,
    /// What a restore cut short raised on the way and could not put back, each with what it
    /// means and the command that puts it back (empty: nothing is left raised).
    pub left_raised: Vec<String>,
    /// With `--eeprom`: how the values were made permanent once all were in RAM ("copied RAM
    /// to ROM (P0971)"), or why not ("not stored: ..."); null without `--eeprom`.
    pub stored: Option<String>,
    /// What the file holds that is the drive's state, not a setting (P0010, P0004, in backups
    /// taken before uss-rt left them out): not restored.
    pub ignored: Vec<String>,
    pub lines: Vec<RestoreLine>,
    pub seconds: f64,
}

impl RestoreReport {
    pub fn new(bus: &str, drive: Address, file: &std::path::Path, dry_run: bool) -> Self {
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            file: file.display().to_string(),
            dry_run,
            equal: 0,
            written: 0,
            refused: 0,
            unknown: 0,
            kept: 0,
            cut_short: None,
            left_raised: Vec::new(),
            stored: None,
            ignored: Vec::new(),
            lines: Vec::new(),
            seconds: 0.0,
        }
    }

    fn line(&mut self, e: &Entry) -> &mut RestoreLine {
        let name = e.param.to_string();
        if let Some(i) = self.lines.iter().position(|l| l.param == name) {
            return &mut self.lines[i];
        }
        self.lines.push(RestoreLine {
            param: name,
            was: None,
            wanted: e.info.show(e.value),
            result: "not written".into(),
        });
        let last = self.lines.len() - 1;
        &mut self.lines[last]
    }

    /// A differing value, to be written.
    pub fn plan(&mut self, e: &Entry, was: Option<Value>) {
        let line = self.line(e);
        line.was = was.map(|v| e.info.show(v));
        line.result = "planned".into();
    }

    /// A setting of the line ussd talks over that differs: kept.
    pub fn keep_link(&mut self, e: &Entry, held: Value) {
        let line = self.line(e);
        line.was = Some(e.info.show(held));
        line.result = "kept: the COM link ussd talks over (change it at the drive)".into();
        self.kept += 1;
    }

    /// Written; the drive holds `held` now (checked against the file's value).
    pub fn written(&mut self, e: &Entry, held: Value) {
        let ok = held == e.value;
        let line = self.line(e);
        line.result = if ok {
            "written".into()
        } else {
            format!("written, but the drive holds {}", e.info.show(held))
        };
        if ok {
            self.written += 1;
        } else {
            self.refused += 1;
        }
    }

    /// The drive refused the value (or does not have the parameter).
    pub fn refuse(&mut self, e: &Entry, error: &ParamError) {
        self.line(e).result = format!("refused: {error}");
        self.refused += 1;
    }

    /// The drive refused a step's value.
    pub fn refuse_step(&mut self, step: &Step, error: &ParamError) {
        self.step_result(
            step,
            format!("refused: {error}"),
            format!("refused on the way: {error}"),
        );
        self.refused += 1;
    }

    /// A step's write reached the drive and its answer was lost: the drive may hold it.
    pub fn unknown(&mut self, step: &Step, error: &ParamError) {
        self.step_result(
            step,
            format!("unknown: {error}"),
            format!("unknown: {error} (on the way)"),
        );
        self.unknown += 1;
    }

    /// What became of `step`: a value of the file gets `of_file` on its line, a value set on
    /// the way (access level, quick commissioning) a line of its own saying `on_the_way`.
    fn step_result(&mut self, step: &Step, of_file: String, on_the_way: String) {
        match step {
            Step::Restore(e) => self.line(e).result = of_file,
            Step::Helper(param, value)
            | Step::Raise {
                param, to: value, ..
            } => self.lines.push(RestoreLine {
                param: param.to_string(),
                was: None,
                wanted: value.to_string(),
                result: on_the_way,
            }),
        }
    }

    /// `param`, raised to `to` on the way, written back to `was` (the drive's value before the
    /// restore) after the restore was cut short by `why`: `Ok(read_back)` (whether a read
    /// showed it, the write's answer lost), or not (`Err`; `meaning`: what being left raised
    /// means for the drive).
    pub fn put_back(
        &mut self,
        param: ParamRef,
        to: u16,
        was: u16,
        why: &str,
        result: Result<bool, String>,
        meaning: &str,
    ) {
        let command = crate::cli::command_line(
            &self.bus,
            &format!("param write {} {param} {was}", self.drive),
        );
        let result = match result {
            Ok(false) => format!("put back after {why}"),
            Ok(true) => format!("put back (read back) after {why}"),
            Err(e) => {
                self.left_raised.push(format!(
                    "{param} = {to}: {meaning}; put it back with `{command}`"
                ));
                format!("LEFT RAISED: {e}")
            }
        };
        self.lines.push(RestoreLine {
            param: param.to_string(),
            was: Some(to.to_string()),
            wanted: was.to_string(),
            result,
        });
    }

    /// Stopped before `rest` was written.
    pub fn cut_short(&mut self, why: &str, rest: &[Step]) {
        for step in rest {
            if let Step::Restore(e) = step {
                self.line(e).result = "not written".into();
            }
        }
        self.cut_short = Some(format!(
            "{why}; not written: {}",
            rest.iter().map(Step::name).collect::<Vec<_>>().join(", ")
        ));
    }

    pub fn is_complete(&self) -> bool {
        self.refused == 0
            && self.unknown == 0
            && self.cut_short.is_none()
            && self
                .stored
                .as_ref()
                .is_none_or(|s| !s.starts_with("not stored"))
    }

    pub fn human(&self) -> String {
        let mut out = String::new();
        for l in &self.lines {
            let _ = writeln!(
                out,
                "  {:<10} {} -> {}: {}",
                l.param,
                l.was.as_deref().unwrap_or("-"),
                l.wanted,
                l.result
            );
        }
        let what = if self.dry_run {
            format!("would write {}", self.lines.len() - self.kept)
        } else {
            format!(
                "wrote {}, refused {}{}",
                self.written,
                self.refused,
                if self.unknown == 0 {
                    String::new()
                } else {
                    format!(", {} unknown (read them back)", self.unknown)
                }
            )
        };
        let _ = writeln!(
            out,
            "drive {} from {}: {what}; {} already as in the file{} ({:.2} s)",
            self.drive,
            self.file,
            self.equal,
            if self.kept == 0 {
                String::new()
            } else {
                format!(", {} COM-link settings kept", self.kept)
            },
            self.seconds
        );
        if let Some(why) = &self.cut_short {
            let _ = writeln!(out, "cut short: {why}");
        }
        for left in &self.left_raised {
            let _ = writeln!(out, "left raised: {left}");
        }
        if let Some(stored) = &self.stored {
            let _ = writeln!(out, "EEPROM: {stored}");
        }
        out.push_str(&ignored_line(&self.ignored, "restored"));
        out
    }
}

/// One difference of `param diff`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DiffLine {
    pub param: String,
    pub name: &'static str,
    /// The drive's value; null: the drive does not have it.
    pub drive: Option<String>,
    /// The other drive's or the file's value; null: it has none.
    pub other: Option<String>,
}

impl DiffLine {
    pub fn new(
        param: ParamRef,
        info: &'static Param,
        drive: Option<Value>,
        other: Option<Value>,
    ) -> Self {
        Self {
            param: param.to_string(),
            name: info.name.as_str(),
            drive: drive.map(|v| info.show(v)),
            other: other.map(|v| info.show(v)),
        }
    }
}

/// `param diff`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct DiffReport {
    pub bus: String,
    pub drive: u8,
    /// The file or the other drive's address.
    pub other: String,
    /// Values that are the same.
    pub same: usize,
    /// What the file holds that is the drive's state, not a setting (P0010, P0004): not
    /// compared.
    pub ignored: Vec<String>,
    pub lines: Vec<DiffLine>,
}

impl DiffReport {
    pub fn new(bus: &str, drive: Address, other: &str) -> Self {
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            other: other.to_owned(),
            same: 0,
            ignored: Vec::new(),
            lines: Vec::new(),
        }
    }

    pub fn human(&self) -> String {
        let other = if self.other.parse::<u8>().is_ok() {
            format!("drive {}", self.other)
        } else {
            self.other.clone()
        };
        let ignored = ignored_line(&self.ignored, "compared");
        if self.lines.is_empty() {
            return format!(
                "drive {} and {other}: no differences ({} values compared)\n{ignored}",
                self.drive, self.same
            );
        }
        let mut out = String::new();
        for l in &self.lines {
            let _ = writeln!(
                out,
                "  {:<10} drive {}: {:<14} {other}: {:<14} ({})",
                l.param,
                self.drive,
                l.drive.as_deref().unwrap_or("(none)"),
                l.other.as_deref().unwrap_or("(none)"),
                l.name
            );
        }
        let _ = writeln!(
            out,
            "drive {} and {other}: {} difference{}, {} value{} the same",
            self.drive,
            self.lines.len(),
            if self.lines.len() == 1 { "" } else { "s" },
            self.same,
            if self.same == 1 { "" } else { "s" },
        );
        out.push_str(&ignored);
        out
    }
}

/// The line that names what a file holds that is not a setting, and what is not `done` with
/// it; empty when there is none.
fn ignored_line(ignored: &[String], done: &str) -> String {
    if ignored.is_empty() {
        return String::new();
    }
    format!(
        "not {done}: {} (the drive's state, not a setting: a backup no longer holds it)\n",
        ignored.join(", ")
    )
}

/// `param save`: the copy of RAM to ROM.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct SaveReport {
    pub bus: String,
    pub drive: u8,
    /// The parameter that made the copy ("P0971", "p0971").
    pub param: String,
    /// The access level raised for the copy and put back, RAM and EEPROM alike
    /// ("P0003 3 -> 1"); null when none was needed.
    pub raised: Option<String>,
}

impl SaveReport {
    pub fn new(bus: &str, drive: Address, saved: &uss_client::Saved) -> Self {
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            param: saved.param.to_string(),
            raised: saved.raised_text(),
        }
    }

    pub fn human(&self) -> String {
        let raised = self
            .raised
            .as_ref()
            .map(|r| format!("; access level raised for it and put back ({r})"))
            .unwrap_or_default();
        format!(
            "drive {}: copied RAM to ROM ({} := 1): every setting survives a power cycle{raised}\n",
            self.drive, self.param
        )
    }
}

/// `param factory-reset`: the reset, and what ussd read of the drive after it.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ResetReport {
    pub bus: String,
    pub drive: u8,
    /// The writes, in order ("P0010 := 30", "P0970 := 1").
    pub writes: Vec<String>,
    /// From the first write until the drive said it was done.
    pub seconds: f64,
    /// The reference frequency ussd scales Hz by now, read again; null when ussd had not read
    /// it yet.
    pub reference_hz: Option<f32>,
    /// The telegram monitoring ussd read again: "on", "off", "too long", ...
    pub monitoring: String,
    pub monitoring_ms: u32,
}

impl ResetReport {
    pub fn new(bus: &str, drive: Address, reset: &uss_client::Reset) -> Self {
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            writes: reset.writes(),
            seconds: reset.took.as_secs_f64(),
            reference_hz: reset.reference_hz,
            monitoring: reset.monitoring.to_string(),
            monitoring_ms: reset.monitoring_ms,
        }
    }

    pub fn human(&self) -> String {
        format!(
            "drive {}: factory reset ({}) done in {:.2} s; every setting is its factory value (in RAM; `param save` stores it)\n  ussd read it again: {}\n",
            self.drive,
            self.writes.join(", "),
            self.seconds,
            read_again(self.reference_hz, &self.monitoring, self.monitoring_ms)
        )
    }
}

/// What ussd read of a drive again after a reset or a quick commissioning, as a reader acts on
/// it: "reference 50 Hz, telegram monitoring on (500 ms)".
fn read_again(reference_hz: Option<f32>, monitoring: &str, monitoring_ms: u32) -> String {
    let reference = reference_hz.map_or_else(
        || "its reference is still being read (Hz are refused until then)".to_owned(),
        |hz| format!("reference {hz} Hz"),
    );
    let monitoring = match monitoring {
        "off" => "telegram monitoring OFF: if ussd or its line dies, nothing stops this drive; set it before running it (USS.md section 5)".to_owned(),
        "on" => format!("telegram monitoring on ({monitoring_ms} ms)"),
        other => format!("telegram monitoring {other} ({monitoring_ms} ms)"),
    };
    format!("{reference}, {monitoring}")
}

/// `param quick-commission`: the writes in order, and what ussd read of the drive after them.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct QuickReport {
    pub bus: String,
    pub drive: u8,
    /// The writes, in order ("P0010 := 1", "P0304 := 400 V", ..., "P3900 := 3").
    pub writes: Vec<String>,
    /// The access level raised for it and put back in RAM ("P0003 1 -> 3 -> 1"); null when
    /// none was needed.
    pub raised: Option<String>,
    /// From the first write until the drive said it was done.
    pub seconds: f64,
    /// The reference frequency ussd scales Hz by now, read again; null when ussd had not read
    /// it yet.
    pub reference_hz: Option<f32>,
    /// The telegram monitoring ussd read again: "on", "off", "too long", ...
    pub monitoring: String,
    pub monitoring_ms: u32,
}

impl QuickReport {
    pub fn new(bus: &str, drive: Address, done: &uss_client::Commissioned) -> Self {
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            writes: done.writes(),
            raised: done.raised_text(),
            seconds: done.took.as_secs_f64(),
            reference_hz: done.reference_hz,
            monitoring: done.monitoring.to_string(),
            monitoring_ms: done.monitoring_ms,
        }
    }

    pub fn human(&self) -> String {
        let raised = self
            .raised
            .as_ref()
            .map(|r| format!("; access level raised for it and put back ({r})"))
            .unwrap_or_default();
        format!(
            "drive {}: quick commissioning done in {:.2} s ({}){raised}; the drive is out of quick commissioning (in RAM; `param save` stores it)\n  ussd read it again: {}\n",
            self.drive,
            self.seconds,
            self.writes.join(", "),
            read_again(self.reference_hz, &self.monitoring, self.monitoring_ms)
        )
    }
}
