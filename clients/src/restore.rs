//! A backup written back to a drive as STARTER downloads it (issue 46), in the client library
//! so that every front-end restores the same way ([`Bus::restore`]): the drive is read, only
//! what differs is written, in a safe order (the access level raised first when a parameter
//! needs it; the commissioning parameter at 1 around what only quick commissioning may change;
//! the file's access level last), each written value is checked against the drive's answer,
//! and what the drive refused is reported. The settings of the link ussd talks over are kept. A
//! restore cut short (the caller's [`Cancel`], the drive offline, ussd gone) says which values
//! were written and which not, and first puts back the access level and quick commissioning it
//! raised, to what the drive had. With [`RestoreOptions::eeprom`] the values are made
//! permanent by the copy of RAM to ROM once all are in RAM: the EEPROM then holds the file, and
//! never a raise of the way.

use crate::backup::{Entry, Loaded, check_family, not_on_drive, settings_catalogue};
use crate::{Bus, ParamError, WriteOptions};
use core::time::Duration;
use std::time::Instant;
use uss_catalogue::{Catalogue, Change};
use uss_protocol::{ParamRef, Value};
use uss_shm_types::Address;

pub use crate::cancel::{Cancel, CancelHandle, NeverCancelled};

/// How a restore goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "five independent choices of the caller, as ussctl's flags"
)]
pub struct RestoreOptions {
    /// Make the values permanent once all are in RAM: the copy of RAM to ROM (P0971, p0971).
    pub eeprom: bool,
    /// Say what would be written; write nothing.
    pub dry_run: bool,
    /// Write even though another process controls the drive (a deliberate act).
    pub force: bool,
    /// Write guarded parameters too (command or setpoint source, ...); without it a restore
    /// that would change one is refused before anything is written ([`ParamError::Guarded`]).
    pub unsafe_write: bool,
    /// Restore a backup of other firmware all the same
    /// ([`crate::backup::BackupFile::check_firmware`]).
    pub other_firmware: bool,
    /// A restore cut short waits this long for the drive to answer again to put back what it
    /// raised.
    pub put_back_within: Duration,
}

impl Default for RestoreOptions {
    fn default() -> Self {
        Self {
            eeprom: false,
            dry_run: false,
            force: false,
            unsafe_write: false,
            other_firmware: false,
            put_back_within: Duration::from_secs(30),
        }
    }
}

impl RestoreOptions {
    /// Every write goes to RAM: with `eeprom` the copy of RAM to ROM at the end stores them.
    const fn writes(&self) -> WriteOptions {
        WriteOptions {
            eeprom: false,
            force: self.force,
            unsafe_write: self.unsafe_write,
        }
    }
}

/// One value of a restore: what the drive had, what the file says, what happened.
// With `view`, the report line of every front-end (`ussctl --json`, the Zenoh bridge).
#[derive(Debug, Clone, PartialEq, Eq)]
#[cfg_attr(feature = "view", derive(serde::Serialize, schemars::JsonSchema))]
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

/// What a restore cut short raised on the way and could not put back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LeftRaised {
    pub param: ParamRef,
    /// The value it was raised to, and the drive's before the restore.
    pub to: u16,
    pub was: u16,
    /// What being left raised means for the drive.
    pub meaning: &'static str,
}

/// What a restore did ([`Bus::restore`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Restored {
    /// Values the drive already held.
    pub equal: usize,
    pub written: usize,
    pub refused: usize,
    /// Writes that reached the drive whose answer was lost: the drive may hold the value.
    pub unknown: usize,
    /// Link settings that differ but are kept (baud rate, address, PZD/PKW length).
    pub kept: usize,
    /// Why the restore stopped early (none: it ran to the end).
    pub cut_short: Option<String>,
    pub left_raised: Vec<LeftRaised>,
    /// With `eeprom`: how the values were made permanent ("copied RAM to ROM (P0971 := 1):
    /// ..."), or why not ("not stored: ...").
    pub stored: Option<String>,
    /// What the file holds that is the drive's state, not a setting: not restored.
    pub ignored: Vec<String>,
    pub lines: Vec<RestoreLine>,
    pub took: Duration,
}

impl Restored {
    /// Whether everything was written (and stored, where asked): run again, an incomplete
    /// restore completes what can be.
    pub fn is_complete(&self) -> bool {
        self.refused == 0
            && self.unknown == 0
            && self.cut_short.is_none()
            && self
                .stored
                .as_ref()
                .is_none_or(|s| !s.starts_with("not stored"))
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
    fn plan(&mut self, e: &Entry, was: Option<Value>) {
        let line = self.line(e);
        line.was = was.map(|v| e.info.show(v));
        line.result = "planned".into();
    }

    /// A setting of the line ussd talks over that differs: kept.
    fn keep_link(&mut self, e: &Entry, held: Value) {
        let line = self.line(e);
        line.was = Some(e.info.show(held));
        line.result = "kept: the COM link ussd talks over (change it at the drive)".into();
        self.kept += 1;
    }

    /// Written; the drive holds `held` now (checked against the file's value).
    fn written(&mut self, e: &Entry, held: Value) {
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
    fn refuse(&mut self, e: &Entry, error: &ParamError) {
        self.line(e).result = format!("refused: {error}");
        self.refused += 1;
    }

    /// The drive refused a step's value.
    fn refuse_step(&mut self, step: &Step, error: &ParamError) {
        self.step_result(
            step,
            format!("refused: {error}"),
            format!("refused on the way: {error}"),
        );
        self.refused += 1;
    }

    /// A step's write reached the drive and its answer was lost: the drive may hold it.
    fn unknown(&mut self, step: &Step, error: &ParamError) {
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
    fn put_back(
        &mut self,
        (param, to, was): (ParamRef, u16, u16),
        why: &str,
        result: Result<bool, String>,
        meaning: &'static str,
    ) {
        let result = match result {
            Ok(false) => format!("put back after {why}"),
            Ok(true) => format!("put back (read back) after {why}"),
            Err(e) => {
                self.left_raised.push(LeftRaised {
                    param,
                    to,
                    was,
                    meaning,
                });
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
    fn cut_short(&mut self, why: &str, rest: &[Step]) {
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
}

impl Bus {
    /// Writes the backup `loaded` to drive `address` as STARTER downloads it (see the module):
    /// checked first (the drive's family, the file's firmware, guarded parameters without
    /// `unsafe_write`: nothing is written when one fails), then only what differs, in a safe
    /// order, each value checked against the drive's answer. `cancel` cuts it short;
    /// `progress` is told (done, of) as it reads and writes; `notice` gets what a caller
    /// watching should know at once (a put-back waiting for the drive to answer again).
    ///
    /// A restore that did not write everything is not an error: [`Restored::is_complete`]
    /// says so, and its lines say which.
    ///
    /// # Errors
    /// [`ParamError::NotOnFamily`] for a generic slave, [`ParamError::Value`] for a backup of
    /// another family or firmware, [`ParamError::Guarded`], [`ParamError::Controlled`] (another
    /// process controls the drive, without `force`); a failure of the path while the drive is
    /// read. Nothing is written in each case.
    pub fn restore(
        &self,
        address: Address,
        loaded: &Loaded,
        options: RestoreOptions,
        cancel: &dyn Cancel,
        progress: &mut dyn FnMut(usize, usize),
        notice: &mut dyn FnMut(&str),
    ) -> Result<Restored, ParamError> {
        let family = self.family(address);
        let catalogue = settings_catalogue(address, family)?;
        let Loaded {
            file,
            entries,
            ignored,
        } = loaded;
        check_family(
            family,
            file.drive_family.as_deref(),
            "the backup is of a",
            "restored (nothing was written)",
        )?;
        file.check_firmware(self.firmware(address)?, options.other_firmware)?;
        let start = Instant::now();
        let refs: Vec<ParamRef> = entries.iter().map(|e| e.param).collect();
        let now = self.read_entries(address, &refs, progress);
        let mut report = Restored {
            ignored: ignored.clone(),
            ..Restored::default()
        };
        let mismatch = self.described_differently(address, entries)?;
        let mut differing = Vec::new();
        for (e, current) in entries.iter().zip(now) {
            if let Some(why) = mismatch.iter().find(|(pnu, _)| *pnu == e.param.pnu) {
                report.refuse(e, &why.1);
                continue;
            }
            match current {
                Ok(v) if v == e.value => report.equal += 1,
                // The line ussd talks over: writing another drive's address or baud rate there
                // would cut the drive off the bus in the middle of the restore.
                Ok(v) if catalogue.is_link(e.param) => report.keep_link(e, v),
                Ok(v) => differing.push((*e, Some(v))),
                // A parameter the drive does not have, or a data set it does not have (a
                // MICROMASTER 440's backup on a drive with fewer): refused, said, the rest goes on.
                Err(err) if not_on_drive(&err) || no_such_element(e, &err) => {
                    report.refuse(e, &err);
                }
                Err(err) => return Err(err),
            }
        }
        for (e, was) in &differing {
            report.plan(e, *was);
        }
        if options.dry_run {
            report.took = start.elapsed();
            return Ok(report);
        }
        if differing.is_empty() {
            // RAM is as the file says; the EEPROM may not be (a value written there since).
            if options.eeprom {
                self.store(address, &mut report);
            }
            report.took = start.elapsed();
            return Ok(report);
        }
        if !options.unsafe_write {
            refuse_guarded(catalogue, &differing)?;
        }
        let steps = self.order(address, catalogue, &differing);
        let (took, cut) =
            self.write_steps(address, &steps, options, cancel, progress, &mut report)?;
        // However it ended (cut short, or a write back the drive did not confirm), the drive is
        // not left in quick commissioning or at a raised access level.
        let raised: Vec<_> = still_raised(&steps, &took).collect();
        if !raised.is_empty() {
            let why = cut.unwrap_or(if took.contains(&Took::Maybe) {
                "an unanswered write"
            } else {
                "a refused write"
            });
            let put = PutBack {
                address,
                catalogue,
                options,
                cancel,
                why,
            };
            self.put_back(&put, &raised, notice, &mut report);
        }
        if options.eeprom {
            if report.is_complete() {
                self.store(address, &mut report);
            } else {
                report.stored = Some(
                    "not stored: the restore did not complete, so the EEPROM keeps what it held"
                        .to_owned(),
                );
            }
        }
        report.took = start.elapsed();
        Ok(report)
    }

    /// Makes what RAM holds permanent after a restore: the copy of RAM to ROM, said in the
    /// report.
    fn store(&self, address: Address, report: &mut Restored) {
        report.stored = Some(match self.save_to_rom(address) {
            Ok(saved) => format!(
                "copied RAM to ROM ({} := 1): every setting survives a power cycle",
                saved.param
            ),
            Err(e) => format!("not stored: {e}"),
        });
    }

    /// Writes the steps of a restore in order, each reported. Returns what the drive did with
    /// each step written and, when the restore was cut short, why (for the report's "put back
    /// after").
    fn write_steps(
        &self,
        address: Address,
        steps: &[Step],
        options: RestoreOptions,
        cancel: &dyn Cancel,
        progress: &mut dyn FnMut(usize, usize),
        report: &mut Restored,
    ) -> Result<(Vec<Took>, Option<&'static str>), ParamError> {
        // What the drive did with each step so far.
        let mut took = Vec::with_capacity(steps.len());
        let mut cut = None;
        for (i, step) in steps.iter().enumerate() {
            if cancel.asked() > 0 {
                report.cut_short(cancel.why(), &steps[i..]);
                cut = Some(cancel.why());
                break;
            }
            let (param, value) = step.target();
            let result = match *step {
                // ussd puts a raise back should this process die before it does.
                Step::Raise { was, .. } => self.write_putting_back(
                    address,
                    param,
                    value,
                    Some((Value::Word(was), options.writes().storage())),
                    options.writes(),
                ),
                _ => self.write_with(address, param, value, options.writes()),
            };
            took.push(match &result {
                Ok(_) => Took::Yes,
                Err(e) if e.may_be_applied() => Took::Maybe,
                Err(_) => Took::No,
            });
            match result {
                Ok(held) => {
                    if let Step::Restore(e) = step {
                        report.written(e, held);
                    }
                }
                Err(e @ ParamError::Controlled { .. }) if i == 0 => return Err(e),
                Err(e @ ParamError::Drive(_)) => report.refuse_step(step, &e),
                // The task went out and its answer was lost: the drive may hold the value. The
                // next write finds out whether the drive is still there.
                Err(e @ ParamError::MaybeApplied { .. }) => report.unknown(step, &e),
                Err(e) => {
                    // A cancel that came while the write waited is why the restore ends.
                    let asked = (cancel.asked() > 0).then(|| cancel.why());
                    let why = asked.map_or_else(|| e.to_string(), str::to_owned);
                    if e.may_be_applied() {
                        report.unknown(step, &e);
                        report.cut_short(&why, &steps[i + 1..]);
                    } else {
                        report.cut_short(&why, &steps[i..]);
                    }
                    cut = Some(asked.unwrap_or("the cut"));
                    break;
                }
            }
            progress(i + 1, steps.len());
        }
        Ok((took, cut))
    }

    /// Puts back what a restore cut short (by `put.why`) had `raised`, last raised first: each
    /// is written until the drive takes it, or (its answer lost) a read shows the drive holds
    /// it, or the drive refuses it, or `put_back_within` has passed since the cut (a drive
    /// offline or a ussd gone may come back meanwhile), or the caller asks to leave it (once
    /// more than it asked when the restore was cut). The report names what is left raised.
    fn put_back(
        &self,
        put: &PutBack<'_>,
        raised: &[(ParamRef, u16, u16)],
        notice: &mut dyn FnMut(&str),
        report: &mut Restored,
    ) {
        let deadline = Instant::now() + put.options.put_back_within;
        // Asks up to here cut the restore; the next one (at most the second) leaves.
        let leave_at = (put.cancel.asked() + 1).min(2);
        let mut said = false;
        for &(param, to, was) in raised {
            let mut read_back = false;
            let result = loop {
                // The drive's own value back, whoever took control meanwhile (forced), and
                // as unsafe (P0010 = 30 is a guarded value of its own; ussd logs it).
                let back = WriteOptions {
                    eeprom: false,
                    force: true,
                    unsafe_write: true,
                };
                let error = match self.write_with(put.address, param, Value::Word(was), back) {
                    Ok(_) => break Ok(()),
                    Err(e @ ParamError::Drive(_)) => break Err(e.to_string()),
                    Err(e) => e,
                };
                // The answer lost: what does the drive hold?
                if self.read(put.address, param) == Ok(Value::Word(was)) {
                    read_back = true;
                    break Ok(());
                }
                if put.cancel.asked() >= leave_at {
                    break Err(format!(
                        "{error} ({}{}: not waited for)",
                        if leave_at == 2 { "a second " } else { "" },
                        put.cancel.why()
                    ));
                }
                if Instant::now() >= deadline {
                    break Err(error.to_string());
                }
                if !said {
                    said = true;
                    let what: Vec<String> = raised
                        .iter()
                        .map(|(p, _, was)| format!("{p} := {was}"))
                        .collect();
                    notice(&format!(
                        "drive {}: {error}\nputting back what the restore raised ({}) once the drive answers again (up to {:.0} s; {} to leave it)",
                        put.address,
                        what.join(", "),
                        put.options.put_back_within.as_secs_f64(),
                        put.cancel.why()
                    ));
                }
                std::thread::sleep(Duration::from_millis(200));
            };
            let result = result.map(|()| read_back);
            let meaning = if put.catalogue.commissioning.map(|p| p.pnu) == Some(param.pnu) {
                "the drive stays in quick commissioning and will not run"
            } else {
                "the access level stays raised"
            };
            report.put_back((param, to, was), put.why, result, meaning);
        }
    }

    /// The writes of a restore, in a safe order: access level first, quick commissioning
    /// around what needs it, the file's commissioning and access level last (where the family
    /// has them: its catalogue's `access_level` and `commissioning`).
    fn order(
        &self,
        address: Address,
        catalogue: &Catalogue,
        differing: &[(Entry, Option<Value>)],
    ) -> Vec<Step> {
        // What the drive has now; `None` where the family has no such parameter or the read
        // failed: what it could not read, the restore does not raise (what needs it is
        // refused, and said).
        let now = |p: Option<ParamRef>| {
            let p = p?;
            let v = self.read(address, ParamRef { index: None, ..p }).ok()?;
            Some(v.as_u32() as u16)
        };
        let (access, commissioning_param) = (catalogue.access_level, catalogue.commissioning);
        let (level_now, commissioning_now) = (now(access), now(commissioning_param));
        let needed = differing.iter().map(|(e, _)| u16::from(e.info.level)).max();
        let raise = match (access, level_now, needed) {
            (Some(p), Some(level), Some(n)) if n > level => Some((p, n, level)),
            _ => None,
        };
        // Quick commissioning (P0010 = 1) around what only it may change, unless the drive is
        // in it.
        let commissioning = match (commissioning_param, commissioning_now) {
            (Some(p), Some(was)) if was != 1 => differing
                .iter()
                .any(|(e, _)| e.info.change == Change::Commissioning)
                .then_some((p, was)),
            _ => None,
        };
        let number = |p: Option<ParamRef>| p.map(|p| p.pnu.get());
        let (p0003, p0010) = (number(access), number(commissioning_param));
        let (last, body): (Vec<_>, Vec<_>) = differing
            .iter()
            .partition(|(e, _)| [p0003, p0010].contains(&Some(e.param.pnu.get())));
        let (p0010_in_file, p0003_in_file) = (
            last.iter().any(|(e, _)| Some(e.param.pnu.get()) == p0010),
            last.iter().any(|(e, _)| Some(e.param.pnu.get()) == p0003),
        );
        let whole = |p: ParamRef| ParamRef { index: None, ..p };
        let mut steps: Vec<Step> = Vec::new();
        if let Some((p, n, level)) = raise {
            steps.push(Step::Raise {
                param: whole(p),
                to: n,
                was: level,
            });
        }
        if let Some((p, was)) = commissioning {
            steps.push(Step::Raise {
                param: whole(p),
                to: 1,
                was,
            });
        }
        steps.extend(body.iter().map(|(e, _)| Step::Restore(*e)));
        // Quick commissioning left and the access level put back: to the file's values (P0010
        // before P0003, which leaving commissioning may need), or to what the drive had.
        if let (Some((p, was)), false) = (commissioning, p0010_in_file) {
            steps.push(Step::Helper(p, was));
        }
        let mut last = last;
        last.sort_by_key(|(e, _)| std::cmp::Reverse(e.param.pnu));
        steps.extend(last.iter().map(|(e, _)| Step::Restore(*e)));
        if let (Some((p, _, level)), false) = (raise, p0003_in_file) {
            steps.push(Step::Helper(p, level));
        }
        steps
    }
}

/// Whether reading element `e` failed because the drive has no such element (error 3 faulty
/// subindex, 4 not an array) where it is a later data set or array element.
fn no_such_element(e: &Entry, err: &ParamError) -> bool {
    use uss_protocol::ErrorNumber;
    e.param.index.is_some_and(|i| i.get() > 0)
        && matches!(
            err,
            ParamError::Drive(crate::DriveError::Refused(
                ErrorNumber::FaultySubindex | ErrorNumber::NotAnArray
            ))
        )
}

/// What a put-back needs of its restore.
struct PutBack<'a> {
    address: Address,
    catalogue: &'a Catalogue,
    options: RestoreOptions,
    cancel: &'a dyn Cancel,
    why: &'a str,
}

/// Guarded parameters (command or setpoint source, COM link, ...) are restored only as
/// unsafe, and then before anything is written: never a restore cut short half way.
fn refuse_guarded(
    catalogue: &Catalogue,
    differing: &[(Entry, Option<Value>)],
) -> Result<(), ParamError> {
    let guarded: Vec<(&Entry, &str)> = differing
        .iter()
        .filter_map(|(e, _)| {
            catalogue
                .guard(e.param.pnu.get(), e.value)
                .map(|why| (e, why))
        })
        .collect();
    match guarded.first() {
        Some((_, why)) => Err(ParamError::Guarded {
            params: guarded
                .iter()
                .map(|(e, _)| e.param.to_string())
                .collect::<Vec<_>>()
                .join(", "),
            why: (*why).to_owned(),
        }),
        None => Ok(()),
    }
}

/// What the drive did with a step of a restore.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Took {
    /// It answered that it holds the value.
    Yes,
    /// It refused it, or the write never reached it.
    No,
    /// The write reached it and the answer was lost ([`ParamError::may_be_applied`]).
    Maybe,
}

/// What a restore cut short after the first `took.len()` steps puts back, last raised first:
/// each [`Step::Raise`] the drive took, or may have taken, whose parameter it did not
/// (certainly) take set again after, as (parameter, raised to, value before). Putting back a
/// value the drive may already hold again is harmless.
fn still_raised<'a>(
    steps: &'a [Step],
    took: &'a [Took],
) -> impl Iterator<Item = (ParamRef, u16, u16)> + 'a {
    let done = move || steps.iter().zip(took);
    done()
        .enumerate()
        .rev()
        .filter_map(move |(at, (step, &t))| {
            let Step::Raise { param, to, was } = *step else {
                return None;
            };
            let set_again = done()
                .skip(at + 1)
                .any(|(s, &w)| w == Took::Yes && s.target().0.pnu == param.pnu);
            (t != Took::No && !set_again).then_some((param, to, was))
        })
}

/// One write of a restore.
#[derive(Debug, Clone, Copy)]
enum Step {
    /// A value of the file.
    Restore(Entry),
    /// P0003 or P0010 set on the way back (access level, quick commissioning).
    Helper(ParamRef, u16),
    /// P0003 or P0010 raised on the way to `to`, from `was`: put back however the restore is
    /// cut short.
    Raise { param: ParamRef, to: u16, was: u16 },
}

impl Step {
    fn target(&self) -> (ParamRef, Value) {
        match self {
            Self::Restore(e) => (e.param, e.value),
            Self::Helper(p, v)
            | Self::Raise {
                param: p, to: v, ..
            } => (ParamRef { index: None, ..*p }, Value::Word(*v)),
        }
    }

    fn name(&self) -> String {
        match self {
            Self::Restore(e) => e.param.to_string(),
            Self::Helper(p, v)
            | Self::Raise {
                param: p, to: v, ..
            } => {
                format!("{p} := {v} (on the way)")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Step, Took, still_raised};
    use uss_protocol::ParamRef;

    /// Cut short after `i` steps of "P0003 := 3, P0010 := 1, P0010 := 0, P0003 := 1", a Ctrl-C
    /// puts back what the drive took raised and did not take set again, last raised first.
    #[test]
    fn a_cut_puts_back_what_was_raised_and_not_set_again() {
        let (p3, p10) = (ParamRef::p(3), ParamRef::p(10));
        let steps = [
            Step::Raise {
                param: p3,
                to: 3,
                was: 1,
            },
            Step::Raise {
                param: p10,
                to: 1,
                was: 0,
            },
            Step::Helper(p10, 0),
            Step::Helper(p3, 1),
        ];
        let put_back = |took: &[Took]| -> Vec<(u16, u16, u16)> {
            still_raised(&steps, took)
                .map(|(p, to, was)| (p.pnu.get(), to, was))
                .collect()
        };
        let (yes, no, maybe) = (Took::Yes, Took::No, Took::Maybe);
        let all = [yes; 4];
        let expected: [&[(u16, u16, u16)]; 5] = [
            &[],
            &[(3, 3, 1)],
            &[(10, 1, 0), (3, 3, 1)],
            &[(3, 3, 1)],
            &[],
        ];
        for (i, want) in expected.iter().enumerate() {
            assert_eq!(put_back(&all[..i]), *want, "cut after {i} steps");
        }
        // What the drive refused to raise is not put back; what it refused to set again is.
        assert_eq!(put_back(&[no, yes]), [(10, 1, 0)]);
        assert_eq!(put_back(&[yes, yes, no]), [(10, 1, 0), (3, 3, 1)]);
        assert_eq!(put_back(&[yes, yes, yes, no]), [(3, 3, 1)]);
        // What may have been raised is put back; what may have been set again is put back too.
        assert_eq!(put_back(&[yes, maybe]), [(10, 1, 0), (3, 3, 1)]);
        assert_eq!(put_back(&[yes, yes, maybe]), [(10, 1, 0), (3, 3, 1)]);
        assert_eq!(put_back(&[yes, yes, yes, maybe]), [(3, 3, 1)]);
    }
}
