//! `param backup`, `param restore`, `param diff`: a drive's settings saved, put back, compared.
//!
//! A backup is the client library's upload (`Bus::upload`: every setting of the catalogue with
//! every element the drive has, its data sets included; the drive's state and commands such as
//! the factory reset left out). A restore reads the drive, writes only what differs, in a safe
//! order (the access level P0003 raised first when a parameter needs it; P0010 = 1 around
//! parameters that only quick commissioning may change; the file's P0003 last), checks each
//! written value against the drive's answer, and reports what the drive refused. Cut short
//! (drive offline, ussd gone, Ctrl-C), it says which values were written and which not; run
//! again, it completes the rest. A Ctrl-C first puts back quick commissioning and the access
//! level it raised, to what the drive had.

use crate::cli::{address, duration};
use crate::report::{DiffLine, DiffReport, RestoreReport};
use crate::{Failure, Output, catch_signals, signal_name, signals, stopped};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use uss_client::Address;
use uss_client::backup::{self, BackupFile, Diff as Compared, Entry, Loaded, not_on_drive};
use uss_client::uss_catalogue::{Catalogue, Change};
use uss_client::uss_protocol::ParamRef;
use uss_client::{Bus, DriveFamily, ParamError, Value, WriteOptions};

/// A library error of a backup, restore or diff of `drive`, as ussctl reports it: another
/// family or firmware (or none uss-rt knows) is said as such; anything else names `what`.
fn failed(drive: Address, what: &str) -> impl Fn(ParamError) -> Failure + '_ {
    move |e| match e {
        ParamError::NotOnFamily { family, what, .. } => Failure::Family {
            drive,
            problem: format!("it is a {family} drive: {what}"),
        },
        ParamError::Value { param, problem } if param == "family" || param == "firmware" => {
            Failure::Family { drive, problem }
        }
        source => Failure::Param {
            drive,
            param: what.to_owned(),
            source,
        },
    }
}

/// A progress callback for the library's reads: a bar on stderr while a terminal watches.
fn bar_of(bar: &ProgressBar) -> impl FnMut(usize, usize) + '_ {
    |done, of| {
        bar.set_length(of as u64);
        bar.set_position(done as u64);
    }
}

/// Reads `params` of `drive` in requests of up to 39; one result each, in order.
fn read_all(
    bus: &Bus,
    drive: Address,
    params: &[ParamRef],
    what: &str,
) -> Vec<Result<Value, ParamError>> {
    let bar = progress(params.len(), what);
    let out = bus.read_entries(drive, params, &mut bar_of(&bar));
    bar.finish_and_clear();
    out
}

/// A bar on stderr while a terminal watches (nothing otherwise).
fn progress(len: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len as u64).with_message(what.to_owned());
    if let Ok(style) = ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len}") {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

/// `param backup`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Backup {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
    /// Write the backup to FILE instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
}

impl Backup {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        backup(bus, out, self.drive, self.output.as_deref())
    }
}

/// `param diff`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Diff {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
    /// A backup file, or the address of another drive on the bus.
    other: String,
}

impl Diff {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        diff(bus, out, self.drive, &self.other)
    }
}

/// `param backup DRIVE [-o FILE]`.
fn backup(bus: &Bus, out: &Output, drive: Address, output: Option<&Path>) -> Result<(), Failure> {
    let start = Instant::now();
    let bar = progress(0, &format!("reading drive {drive}"));
    let upload = bus
        .upload(drive, &mut bar_of(&bar))
        .map_err(failed(drive, "backup"));
    bar.finish_and_clear();
    let upload = upload?;
    let file = &upload.file;
    let text = file.to_text();
    match output {
        None => {
            crate::write_out(&text)?;
        }
        Some(path) => {
            std::fs::write(path, &text).map_err(|source| Failure::File {
                path: path.display().to_string(),
                source,
            })?;
            out.note(&format!(
                "drive {drive}: {} parameters ({} values) saved to {} in {:.2} s{}",
                file.param.len(),
                upload.values,
                path.display(),
                start.elapsed().as_secs_f64(),
                if file.not_on_drive.is_empty() {
                    String::new()
                } else {
                    format!("; not on this drive: {}", file.not_on_drive.join(", "))
                }
            ));
        }
    }
    Ok(())
}

/// Reads and checks a backup file against the catalogue of the drive's family.
fn load(path: &Path, catalogue: &'static Catalogue) -> Result<Loaded, Failure> {
    let text = std::fs::read_to_string(path).map_err(|source| Failure::File {
        path: path.display().to_string(),
        source,
    })?;
    Ok(BackupFile::parse(
        &text,
        &path.display().to_string(),
        catalogue,
    )?)
}

/// Guarded parameters (command or setpoint source, COM link, ...) are restored only with
/// --unsafe, and then before anything is written: never a restore cut short half way.
fn refuse_guarded(
    drive: Address,
    family: DriveFamily,
    differing: &[(Entry, Option<Value>)],
) -> Result<(), Failure> {
    let Some(catalogue) = Catalogue::of(family) else {
        return Ok(());
    };
    let guarded: Vec<(&Entry, &str)> = differing
        .iter()
        .filter_map(|(e, _)| {
            catalogue
                .guard(e.param.pnu.get(), e.value)
                .map(|why| (e, why))
        })
        .collect();
    match guarded.first() {
        Some((_, why)) => Err(Failure::Guarded {
            drive,
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

/// `param restore`'s arguments.
#[derive(Debug, clap::Args)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "four independent switches of the command line"
)]
pub struct Restore {
    /// The drive's address on the bus, 0..=31.
    #[arg(value_parser = address)]
    drive: Address,
    /// The backup file (written by `param backup`).
    file: PathBuf,
    /// Make the drive's settings permanent once the file's values are in RAM: every setting
    /// is copied from RAM to ROM (P0971, p0971), so the EEPROM holds the file's values whatever
    /// it held before; the access level and quick commissioning raised on the way are put back
    /// first and stay as they were.
    #[arg(long)]
    eeprom: bool,
    /// Show what would be written; write nothing.
    #[arg(long)]
    dry_run: bool,
    /// Write even though another process controls the drive (a deliberate act).
    #[arg(long)]
    force: bool,
    /// Restore a backup taken from another firmware (r0018) all the same: without it such a
    /// restore is refused before anything is written, naming both.
    #[arg(long)]
    other_firmware: bool,
    /// Write guarded parameters too (command or setpoint source, COM link, ...): without
    /// it a restore that would change one is refused before anything is written, naming
    /// them. ussd logs each.
    #[arg(long = "unsafe")]
    unsafe_write: bool,
    /// A restore cut short (Ctrl-C, the drive offline, ussd gone) puts back the access
    /// level and quick commissioning it raised on the way, waiting up to this long for
    /// the drive to answer again; what it cannot put back it names, with the command that
    /// does it.
    #[arg(long, value_name = "DURATION", default_value = "30s", value_parser = duration)]
    put_back_within: Duration,
}

impl Restore {
    /// Forced, guarded parameters too (`--force`, `--unsafe`). Every write goes to RAM: with
    /// `--eeprom` the copy of RAM to ROM at the end stores them, and only them with what the
    /// drive held, never a raise of the way.
    const fn options(&self) -> WriteOptions {
        WriteOptions {
            eeprom: false,
            force: self.force,
            unsafe_write: self.unsafe_write,
        }
    }

    /// `param restore DRIVE FILE [--eeprom] [--dry-run] [--force] [--unsafe]`.
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        restore(bus, out, self)
    }
}

fn restore(bus: &Bus, out: &Output, r: &Restore) -> Result<(), Failure> {
    let drive = r.drive;
    let family = bus.family(drive);
    let catalogue = backup::settings_catalogue(drive, family).map_err(failed(drive, "restore"))?;
    let Loaded {
        file,
        entries,
        ignored,
    } = load(&r.file, catalogue)?;
    backup::check_family(
        family,
        file.drive_family.as_deref(),
        "the backup is of a",
        "restored (nothing was written)",
    )
    .and_then(|()| file.check_firmware(bus.firmware(drive), r.other_firmware))
    .map_err(failed(drive, "restore"))?;
    let start = Instant::now();
    let refs: Vec<ParamRef> = entries.iter().map(|e| e.param).collect();
    let now = read_all(bus, drive, &refs, &format!("reading drive {drive}"));
    let mut report = RestoreReport::new(bus.name(), drive, &r.file, r.dry_run);
    report.ignored = ignored;
    let mut differing = Vec::new();
    for (e, current) in entries.iter().zip(&now) {
        match current {
            Ok(v) if *v == e.value => report.equal += 1,
            // The line ussd talks over: writing another drive's address or baud rate there
            // would cut the drive off the bus in the middle of the restore.
            Ok(v) if catalogue.is_link(e.param) => report.keep_link(e, *v),
            Ok(v) => differing.push((*e, Some(*v))),
            Err(err) if not_on_drive(err) => report.refuse(e, err),
            Err(source) => {
                return Err(Failure::Param {
                    drive,
                    param: e.param.to_string(),
                    source: source.clone(),
                });
            }
        }
    }
    for (e, was) in &differing {
        report.plan(e, *was);
    }
    if r.dry_run {
        report.seconds = start.elapsed().as_secs_f64();
        return out.show(&report, RestoreReport::human);
    }
    if differing.is_empty() {
        // RAM is as the file says; the EEPROM may not be (a value written there since).
        if r.eeprom {
            catch_signals()?;
            store(bus, drive, &mut report);
        }
        report.seconds = start.elapsed().as_secs_f64();
        let complete = report.is_complete();
        out.show(&report, RestoreReport::human)?;
        return if complete {
            Ok(())
        } else {
            Err(Failure::Incomplete { drive })
        };
    }
    if !r.unsafe_write {
        refuse_guarded(drive, family, &differing)?;
    }
    catch_signals()?;
    let options = r.options();
    let steps = order(bus, drive, catalogue, &differing);
    let (took, cut) = write_steps(bus, drive, &steps, options, &mut report)?;
    // However it ended (cut short, or a write back the drive did not confirm), the drive is
    // not left in quick commissioning or at a raised access level.
    let raised: Vec<_> = still_raised(&steps, &took).collect();
    if !raised.is_empty() {
        let why = cut.unwrap_or(if took.contains(&Took::Maybe) {
            "an unanswered write"
        } else {
            "a refused write"
        });
        put_back(bus, drive, catalogue, &raised, r, why, &mut report);
    }
    if r.eeprom {
        if report.is_complete() {
            store(bus, drive, &mut report);
        } else {
            report.stored = Some(
                "not stored: the restore did not complete, so the EEPROM keeps what it held"
                    .to_owned(),
            );
        }
    }
    report.seconds = start.elapsed().as_secs_f64();
    let complete = report.is_complete();
    out.show(&report, RestoreReport::human)?;
    if complete {
        Ok(())
    } else {
        Err(Failure::Incomplete { drive })
    }
}

/// Makes what RAM holds permanent after a restore: the copy of RAM to ROM, said in the report.
fn store(bus: &Bus, drive: Address, report: &mut RestoreReport) {
    report.stored = Some(match bus.save_to_rom(drive) {
        Ok(saved) => format!(
            "copied RAM to ROM ({} := 1): every setting survives a power cycle",
            saved.param
        ),
        Err(e) => format!("not stored: {e}"),
    });
}

/// Writes the steps of a restore in order, each reported. Returns what the drive did with each
/// step written and, when the restore was cut short, why (for the report's "put back after").
fn write_steps(
    bus: &Bus,
    drive: Address,
    steps: &[Step],
    options: WriteOptions,
    report: &mut RestoreReport,
) -> Result<(Vec<Took>, Option<&'static str>), Failure> {
    let bar = progress(steps.len(), &format!("writing drive {drive}"));
    // What the drive did with each step so far.
    let mut took = Vec::with_capacity(steps.len());
    let mut cut = None;
    for (i, step) in steps.iter().enumerate() {
        if stopped() {
            report.cut_short(signal_name(), &steps[i..]);
            cut = Some(signal_name());
            break;
        }
        let (param, value) = step.target();
        let result = bus.write_with(drive, param, value, options);
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
            Err(ParamError::Controlled { address, pid }) if i == 0 => {
                bar.finish_and_clear();
                return Err(Failure::Param {
                    drive,
                    param: "restore".into(),
                    source: ParamError::Controlled { address, pid },
                });
            }
            Err(e @ ParamError::Drive(_)) => report.refuse_step(step, &e),
            // The task went out and its answer was lost: the drive may hold the value. The
            // next write finds out whether the drive is still there.
            Err(e @ ParamError::MaybeApplied { .. }) => report.unknown(step, &e),
            Err(e) => {
                // A signal that came while the write waited is why the restore ends.
                let signal = stopped().then(signal_name);
                let why = signal.map_or_else(|| e.to_string(), str::to_owned);
                if e.may_be_applied() {
                    report.unknown(step, &e);
                    report.cut_short(&why, &steps[i + 1..]);
                } else {
                    report.cut_short(&why, &steps[i..]);
                }
                cut = Some(signal.unwrap_or("the cut"));
                break;
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok((took, cut))
}

/// What the drive did with a step of a restore.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Took {
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
pub(crate) fn still_raised<'a>(
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

/// Puts back what a restore cut short (by `why`) had `raised`, last raised first: each is
/// written until the drive takes it, or (its answer lost) a read shows the drive holds it, or
/// the drive refuses it, or `r.put_back_within` has passed since the cut (a drive offline or a
/// ussd gone may come back meanwhile), or a signal says to leave it (a second one when a
/// signal cut the restore, even one that came while a write waited). The report names what
/// is left raised and the command that puts it back.
fn put_back(
    bus: &Bus,
    drive: Address,
    catalogue: &Catalogue,
    raised: &[(ParamRef, u16, u16)],
    r: &Restore,
    why: &str,
    report: &mut RestoreReport,
) {
    let deadline = Instant::now() + r.put_back_within;
    // Signals up to here cut the restore; the next one (at most the second) leaves.
    let leave_at = (signals() + 1).min(2);
    let mut said = false;
    for &(param, to, was) in raised {
        let mut read_back = false;
        let result = loop {
            let error = match bus.write_with(drive, param, Value::Word(was), r.options()) {
                Ok(_) => break Ok(()),
                Err(e @ ParamError::Drive(_)) => break Err(e.to_string()),
                Err(e) => e,
            };
            // The answer lost: what does the drive hold?
            if bus.read(drive, param) == Ok(Value::Word(was)) {
                read_back = true;
                break Ok(());
            }
            if signals() >= leave_at {
                break Err(format!(
                    "{error} ({}{}: not waited for)",
                    if leave_at == 2 { "a second " } else { "" },
                    signal_name()
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
                eprintln!(
                    "ussctl: drive {drive}: {error}\nussctl: putting back what the restore raised ({}) once the drive answers again (up to {:.0} s; Ctrl-C to leave it)",
                    what.join(", "),
                    r.put_back_within.as_secs_f64()
                );
            }
            std::thread::sleep(Duration::from_millis(200));
        };
        let result = result.map(|()| read_back);
        let meaning = if catalogue.commissioning.map(|p| p.pnu) == Some(param.pnu) {
            "the drive stays in quick commissioning and will not run"
        } else {
            "the access level stays raised"
        };
        report.put_back(param, to, was, why, result, meaning);
    }
}

/// The writes of a restore, in a safe order: access level first, quick commissioning around
/// what needs it, the file's P0010 and then P0003 last (where the family has them: its
/// catalogue's `access_level` and `commissioning`).
fn order(
    bus: &Bus,
    drive: Address,
    catalogue: &Catalogue,
    differing: &[(Entry, Option<Value>)],
) -> Vec<Step> {
    // What the drive has now; `None` where the family has no such parameter or the read failed:
    // what it could not read, the restore does not raise (what needs it is refused, and said).
    let now = |p: Option<ParamRef>| {
        let p = p?;
        let v = bus.read(drive, ParamRef { index: None, ..p }).ok()?;
        Some(v.as_u32() as u16)
    };
    let (access, commissioning_param) = (catalogue.access_level, catalogue.commissioning);
    let (level_now, commissioning_now) = (now(access), now(commissioning_param));
    let needed = differing.iter().map(|(e, _)| u16::from(e.info.level)).max();
    let raise = match (access, level_now, needed) {
        (Some(p), Some(level), Some(n)) if n > level => Some((p, n, level)),
        _ => None,
    };
    // Quick commissioning (P0010 = 1) around what only it may change, unless the drive is in it.
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

/// One write of a restore.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Step {
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

    pub(crate) fn name(&self) -> String {
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

/// `param diff DRIVE (FILE | DRIVE)`.
/// Exits nonzero ([`Failure::Differ`]) when there are differences, as `diff(1)` does.
fn diff(bus: &Bus, out: &Output, drive: Address, other: &str) -> Result<(), Failure> {
    let mut report = DiffReport::new(bus.name(), drive, other);
    let bar = progress(0, &format!("reading drive {drive}"));
    let compared = if let Ok(second) = other.parse::<u8>() {
        // A number names a drive (a file named so is written ./17).
        let second = Address::new(second).map_err(|e| Failure::Usage(e.to_string()))?;
        bus.diff_drives(drive, second, &mut bar_of(&bar))
    } else {
        let catalogue =
            backup::settings_catalogue(drive, bus.family(drive)).map_err(failed(drive, "diff"))?;
        let loaded = load(Path::new(other), catalogue)?;
        bus.diff_loaded(drive, &loaded, &mut bar_of(&bar))
    };
    bar.finish_and_clear();
    let Compared {
        same,
        differ,
        ignored,
    } = compared.map_err(failed(drive, "diff"))?;
    report.same = same;
    report.ignored = ignored;
    report.lines = differ
        .iter()
        .map(|d| DiffLine::new(d.param, d.info, d.drive, d.other))
        .collect();
    out.show(&report, DiffReport::human)?;
    match report.lines.len() {
        0 => Ok(()),
        differ => Err(Failure::Differ { drive, differ }),
    }
}

#[cfg(test)]
mod tests {
    use super::{Step, Took, still_raised};
    use uss_client::uss_protocol::ParamRef;

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
