//! `scan`: the drives that answered.

use serde::Serialize;
use std::fmt::Write as _;
use uss_client::state_name;

/// One drive `scan` found.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ScannedDrive {
    pub baud: u32,
    pub address: u8,
    /// "0", "3", "4", "variable (127)", or "unknown" (it mirrored but answered no layout).
    pub pkw: String,
    pub pzd: usize,
    /// The ZSW1 it answered with.
    pub zsw1: Option<u16>,
    /// r0018, with a parameter channel.
    pub firmware: Option<f64>,
    /// The `family` to configure, where the answers tell it: a drive whose device
    /// identification r0964[0] is 42 (Siemens, PROFIdrive) is `g120`; one that has r0018 as a
    /// float (the MICROMASTER 4 firmware) is `micromaster4` (a G110 answers the same: `g110`).
    pub family: Option<&'static str>,
    /// Why the line may not be right (null: every part of it was confirmed: the layout by two
    /// replies to different tasks, the family by its identification): a layout seen in one
    /// reply only, a question not answered, a value that is no firmware version.
    pub unsure: Option<String>,
}

impl From<&uss_client::scan::Found> for ScannedDrive {
    fn from(found: &uss_client::scan::Found) -> Self {
        use uss_client::uss_protocol::telegram::PkwMode;
        Self {
            baud: found.baud.get(),
            address: found.address.get(),
            pkw: match found.pkw {
                None => "unknown".into(),
                Some(PkwMode::Variable) => "variable (127)".into(),
                Some(mode) => mode.p2013().to_string(),
            },
            pzd: found.pzd,
            zsw1: found.zsw1,
            firmware: found.firmware,
            family: found.family.map(uss_client::DriveFamily::name),
            unsure: found.unsure.clone(),
        }
    }
}

/// `scan`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ScanReport {
    pub device: String,
    pub bauds: Vec<u32>,
    pub addresses: usize,
    /// How often each question was asked before silence counted as its answer.
    pub tries: u32,
    pub drives: Vec<ScannedDrive>,
    /// Ctrl-C ended it early.
    pub cut_short: bool,
    pub seconds: f64,
}

impl ScanReport {
    pub fn new(
        device: &std::path::Path,
        bauds: &[uss_client::uss_protocol::Baud],
        addresses: usize,
        tries: u32,
    ) -> Self {
        Self {
            device: device.display().to_string(),
            bauds: bauds.iter().map(|b| b.get()).collect(),
            addresses,
            tries,
            drives: Vec::new(),
            cut_short: false,
            seconds: 0.0,
        }
    }

    /// The drives found as ussd's configuration takes them, ready to paste: a `[[bus]]` per
    /// rate with the drives that answered at it, each as a `[[bus.drive]]` with its layout and
    /// family; what the scan could not tell is a comment to fill in, and an UNSURE line says why.
    pub fn toml(&self) -> String {
        let mut out = format!(
            "# ussctl scan {}: {} found; check each entry, then `ussd --check-config FILE`\n",
            self.device,
            match self.drives.len() {
                1 => "1 drive".to_owned(),
                n => format!("{n} drives"),
            }
        );
        let mut rates: Vec<u32> = self.drives.iter().map(|d| d.baud).collect();
        rates.dedup();
        for (n, baud) in rates.iter().enumerate() {
            let _ = write!(
                out,
                "\n[[bus]]\nname = \"line{}\"\ndevice = \"{}\"\nbaud = {baud}\n",
                n + 1,
                self.device
            );
            for d in self.drives.iter().filter(|d| d.baud == *baud) {
                let _ = write!(out, "\n[[bus.drive]]\naddress = {}\n", d.address);
                match d.pkw.as_str() {
                    "variable (127)" => out.push_str("pkw = 127\n"),
                    "unknown" => {
                        out.push_str("# pkw = ?  the scan could not tell: 0, 3, 4 or 127\n");
                    }
                    n => {
                        let _ = writeln!(out, "pkw = {n}");
                    }
                }
                let _ = writeln!(out, "pzd = {}", d.pzd);
                match d.family {
                    Some(f @ "micromaster4") => {
                        let _ = writeln!(out, "family = \"{f}\"   # or \"g110\" for a G110");
                    }
                    Some(f) => {
                        let _ = writeln!(out, "family = \"{f}\"");
                    }
                    // Not told: the family that assumes nothing (read by value alone, no
                    // reference or monitoring read, no catalogue's guards), never ussd's
                    // default micromaster4 by omission.
                    None => out.push_str(
                        "family = \"generic\"   # not told by the drive: name its family \
                         (micromaster4, g110, g120, simoreg) to use its catalogue\n",
                    ),
                }
                if let Some(why) = &d.unsure {
                    let _ = writeln!(out, "# UNSURE: {why}");
                }
            }
        }
        out
    }

    pub fn human(&self) -> String {
        let mut out = String::new();
        for d in &self.drives {
            let _ = write!(
                out,
                "{:>6} baud  drive {:2}: PKW {}, PZD {}",
                d.baud, d.address, d.pkw, d.pzd
            );
            if let Some(z) = d.zsw1 {
                let _ = write!(out, ", ZSW1 {z:#06X} ({})", state_name(z));
            }
            if let Some(f) = d.firmware {
                let _ = write!(out, ", firmware {f:.2}");
            }
            match d.family {
                Some(f @ "micromaster4") => {
                    let _ = write!(out, ", family = \"{f}\" (or \"g110\" for a G110)");
                }
                Some(f) => {
                    let _ = write!(out, ", family = \"{f}\"");
                }
                None => {}
            }
            if let Some(why) = &d.unsure {
                let _ = write!(out, "; UNSURE: {why}");
            }
            out.push('\n');
        }
        let plural =
            |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
        let _ = writeln!(
            out,
            "{}: {} found, {} x {} in {:.2} s, each question asked up to {} times{}",
            self.device,
            plural(self.drives.len(), "drive", "drives"),
            plural(self.addresses, "address", "addresses"),
            plural(self.bauds.len(), "baud rate", "baud rates"),
            self.seconds,
            self.tries,
            if self.cut_short {
                " (cut short by Ctrl-C)"
            } else {
                ""
            }
        );
        out
    }
}
