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
use crate::{Failure, Output, Signals, catch_signals};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use uss_client::Address;
use uss_client::backup::{self, BackupFile, Diff as Compared, Loaded, UploadOptions};
use uss_client::restore::RestoreOptions;
use uss_client::uss_catalogue::Catalogue;
use uss_client::{Bus, ParamError};

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
    /// Also ask the drive for every parameter number FROM-TO (e.g. 0-3999) that uss-rt's
    /// catalogue of its family does not list, and save the settable ones it has, typed as it
    /// describes them (one exchange per number; under [described] in the file).
    #[arg(long, value_name = "FROM-TO", value_parser = pnu_range)]
    discover: Option<core::ops::RangeInclusive<u16>>,
}

impl Backup {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        let options = UploadOptions {
            discover: self.discover.clone(),
        };
        backup(bus, out, self.drive, self.output.as_deref(), &options)
    }
}

/// `FROM-TO` (or one number) of parameter numbers.
fn pnu_range(text: &str) -> Result<core::ops::RangeInclusive<u16>, String> {
    backup::pnu_range(text).ok_or_else(|| {
        format!("'{text}' is not a range of parameter numbers FROM-TO (e.g. 0-3999)")
    })
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
fn backup(
    bus: &Bus,
    out: &Output,
    drive: Address,
    output: Option<&Path>,
    options: &UploadOptions,
) -> Result<(), Failure> {
    let start = Instant::now();
    let bar = progress(0, &format!("reading drive {drive}"));
    let upload = bus
        .upload_with(drive, options, &mut bar_of(&bar))
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
                "drive {drive}: {} parameters ({} values) saved to {} in {:.2} s{}{}{}",
                file.param.len() + file.described.len(),
                upload.values,
                path.display(),
                start.elapsed().as_secs_f64(),
                if file.not_on_drive.is_empty() {
                    String::new()
                } else {
                    format!("; not on this drive: {}", file.not_on_drive.join(", "))
                },
                match (&options.discover, file.described.is_empty()) {
                    (None, _) => String::new(),
                    (Some(_), true) => format!(
                        "; of the {} numbers asked beyond the catalogue the drive described no \
                         setting",
                        upload.asked
                    ),
                    (Some(_), false) => format!(
                        "; described by the drive, not in uss-rt's catalogue ({} numbers \
                         asked): {}",
                        upload.asked,
                        file.described
                            .keys()
                            .map(String::as_str)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                },
                if file.not_read.is_empty() {
                    String::new()
                } else {
                    format!(
                        "; described but refused to read (not saved): {}",
                        file.not_read.join(", ")
                    )
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
    /// What the flags ask of the library's restore.
    const fn options(&self) -> RestoreOptions {
        RestoreOptions {
            eeprom: self.eeprom,
            dry_run: self.dry_run,
            force: self.force,
            unsafe_write: self.unsafe_write,
            other_firmware: self.other_firmware,
            put_back_within: self.put_back_within,
        }
    }

    /// `param restore DRIVE FILE [--eeprom] [--dry-run] [--force] [--unsafe]`.
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        restore(bus, out, self)
    }
}

fn restore(bus: &Bus, out: &Output, r: &Restore) -> Result<(), Failure> {
    let drive = r.drive;
    let catalogue =
        backup::settings_catalogue(drive, bus.family(drive)).map_err(failed(drive, "restore"))?;
    let loaded = load(&r.file, catalogue)?;
    if !r.dry_run {
        // Ctrl-C cuts the restore between two writes and puts back what it raised.
        catch_signals()?;
    }
    let bar = progress(0, &format!("restoring drive {drive}"));
    let done = bus.restore(
        drive,
        &loaded,
        r.options(),
        &Signals,
        &mut bar_of(&bar),
        &mut |notice| {
            bar.suspend(|| {
                for line in notice.lines() {
                    eprintln!("ussctl: {line}");
                }
            });
        },
    );
    bar.finish_and_clear();
    let done = done.map_err(|e| match e {
        ParamError::Guarded { params, why } => Failure::Guarded { drive, params, why },
        e => failed(drive, "restore")(e),
    })?;
    let report = RestoreReport::new(bus.name(), drive, &r.file, r.dry_run, &done);
    out.show(&report, RestoreReport::human)?;
    if r.dry_run || done.is_complete() {
        Ok(())
    } else {
        Err(Failure::Incomplete { drive })
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
