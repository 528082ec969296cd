//! `param restore` and `param diff`.

use serde::Serialize;
use std::fmt::Write as _;
use uss_client::restore::{RestoreLine, Restored};
use uss_client::uss_catalogue::Param;
use uss_client::uss_protocol::ParamRef;
use uss_client::{Address, Value};

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
    /// The report of `done`, a restore of `file` to `drive` on `bus`.
    pub fn new(
        bus: &str,
        drive: Address,
        file: &std::path::Path,
        dry_run: bool,
        done: &Restored,
    ) -> Self {
        let left_raised = done
            .left_raised
            .iter()
            .map(|l| {
                let command = crate::cli::command_line(
                    bus,
                    &format!("param write {drive} {} {}", l.param, l.was),
                );
                format!(
                    "{} = {}: {}; put it back with `{command}`",
                    l.param, l.to, l.meaning
                )
            })
            .collect();
        Self {
            bus: bus.to_owned(),
            drive: drive.get(),
            file: file.display().to_string(),
            dry_run,
            equal: done.equal,
            written: done.written,
            refused: done.refused,
            unknown: done.unknown,
            kept: done.kept,
            cut_short: done.cut_short.clone(),
            left_raised,
            stored: done.stored.clone(),
            ignored: done.ignored.clone(),
            lines: done.lines.clone(),
            seconds: done.took.as_secs_f64(),
        }
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
            reference_hz: reset.picture.reference_hz,
            monitoring: reset.picture.monitoring.to_string(),
            monitoring_ms: reset.picture.monitoring_ms,
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
            reference_hz: done.picture.reference_hz,
            monitoring: done.picture.monitoring.to_string(),
            monitoring_ms: done.picture.monitoring_ms,
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
