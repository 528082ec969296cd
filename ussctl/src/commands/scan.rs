//! `scan DEVICE`: which drives answer on a line ussd does not serve (the library's
//! [`uss_client::scan`]), rendered.

use crate::cli::{AddressList, BaudList, address_list, baud_list};
use crate::report::{ScanReport, ScannedDrive};
use crate::{Failure, Output, Signals, catch_signals};
use indicatif::ProgressBar;
use std::path::PathBuf;
use uss_client::scan::{ScanOptions, scan};

/// `scan`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Scan {
    /// The serial device, e.g. /dev/ttyUSB0.
    device: PathBuf,
    /// Baud rates: a list (9600,19200), or `all` (the 13 of USS.md section 2); default the
    /// eight of MICROMASTER's P2010 (1200 to 115200).
    #[arg(long, value_name = "LIST|all", value_parser = baud_list)]
    baud: Option<BaudList>,
    /// Addresses: a range (0-31) or a list (1,3,5).
    #[arg(long, value_name = "RANGE", default_value = "0-31", value_parser = address_list)]
    addresses: AddressList,
    /// How often each question is asked before silence counts as its answer: an address
    /// silent to this many mirror telegrams counts as empty (raise it on a noisy line).
    #[arg(long, value_name = "N", default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..=20))]
    tries: u32,
    /// Print the drives found as ussd's configuration takes them (`[[bus]]`, `[[bus.drive]]`),
    /// ready to paste into ussd.toml.
    #[arg(long, conflicts_with = "json")]
    toml: bool,
}

impl Scan {
    /// `scan DEVICE [--baud LIST|all] [--addresses FROM-TO] [--tries N]`: no bus, no ussd.
    pub(crate) fn run(&self, out: &Output) -> Result<(), Failure> {
        let mut options = ScanOptions {
            addresses: self.addresses.0.clone(),
            tries: self.tries,
            ..ScanOptions::default()
        };
        if let Some(list) = &self.baud {
            options.bauds.clone_from(&list.0);
        }
        catch_signals()?;
        let bar = ProgressBar::new((options.bauds.len() * options.addresses.len()) as u64);
        let scanned = scan(
            &self.device,
            &options,
            &Signals,
            &mut |done, total| {
                // One rate only on a pseudo-terminal: the library says how many there are.
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            },
            &mut |notice| eprintln!("ussctl: {notice}"),
        )?;
        bar.finish_and_clear();
        let mut report = ScanReport::new(
            &self.device,
            &scanned.bauds,
            options.addresses.len(),
            self.tries,
        );
        report.drives = scanned.drives.iter().map(ScannedDrive::from).collect();
        report.cut_short = scanned.cut_short;
        report.seconds = scanned.took.as_secs_f64();
        if self.toml {
            print!("{}", report.toml());
            return Ok(());
        }
        out.show(&report, ScanReport::human)
    }
}
