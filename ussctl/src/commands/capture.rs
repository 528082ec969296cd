//! `capture`: every telegram of the bus, decoded, until Ctrl-C, a time or a count; optionally
//! written to a pcapng file.

use crate::cli::address;
use crate::decode::{Decoder, Level};
use crate::{Failure, Output, catch_signals, stopped};
use core::time::Duration;
use std::path::{Path, PathBuf};
use std::time::Instant;
use uss_client::{Address, Bus, Catalogue};

/// `capture`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Capture {
    /// Only this drive's telegrams.
    #[arg(long, value_name = "ADDRESS", value_parser = address)]
    drive: Option<Address>,
    /// raw: the bytes; frame: STX, LGE, ADR, PKW, PZD, BCC; app: parameter tasks and
    /// replies, control and status words, setpoints and actual values.
    #[arg(long, value_enum, default_value = "app")]
    level: Level,
    /// Capture this many seconds (default: until Ctrl-C).
    #[arg(long = "for", value_name = "SECONDS")]
    duration: Option<f64>,
    /// Stop after this many telegrams.
    #[arg(long, value_name = "N")]
    count: Option<u64>,
    /// Also write the telegrams to this pcapng file.
    #[arg(short = 'o', long = "output", value_name = "FILE")]
    output: Option<PathBuf>,
}

/// How often the capture looks for new records.
const POLL: Duration = Duration::from_millis(10);

/// What the decoder shows each drive's telegrams with: its reference frequency (setpoints and
/// actual values in Hz) and its family's catalogue (parameter names and units).
struct DriveFacts {
    drives: Vec<(Address, Option<f32>, Option<&'static Catalogue>)>,
}

impl DriveFacts {
    fn of(bus: &Bus) -> Self {
        let drives = bus
            .drives()
            .into_iter()
            .map(|a| {
                let reference = bus.watch(a).ok().map(|w| w.info().reference_hz);
                (a, reference, Catalogue::of(bus.family(a)))
            })
            .collect();
        Self { drives }
    }

    fn reference_hz(&self, address: u8) -> Option<f32> {
        self.drives
            .iter()
            .find(|d| d.0.get() == address)
            .and_then(|d| d.1)
    }

    /// A drive ussd does not poll (a stray reply) is shown as a MICROMASTER 4.
    fn catalogue(&self, address: u8) -> Option<&'static Catalogue> {
        self.drives
            .iter()
            .find(|d| d.0.get() == address)
            .map_or(Some(Catalogue::micromaster4()), |d| d.2)
    }
}

impl Capture {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        capture(bus, out, self)
    }
}

fn capture(bus: &Bus, out: &Output, o: &Capture) -> Result<(), Failure> {
    let duration = o
        .duration
        .map(|s| {
            Duration::try_from_secs_f64(s)
                .map_err(|_| Failure::Usage(format!("--for {s}: give a number of seconds")))
        })
        .transpose()?;
    if let Some(a) = o.drive {
        bus.watch(a)?;
    }
    let facts = DriveFacts::of(bus);
    let reference_hz = |a: u8| facts.reference_hz(a);
    let catalogue = |a: u8| facts.catalogue(a);
    let decoder = Decoder {
        catalogue: &catalogue,
        reference_hz: &reference_hz,
        level: o.level,
    };
    let mut capture = bus.capture()?;
    let mut pcap = match o.output.as_deref() {
        Some(path) => {
            let file = std::fs::File::create(path).map_err(|source| Failure::File {
                path: path.display().to_string(),
                source,
            })?;
            let writer = crate::pcapng::Writer::new(
                std::io::BufWriter::new(file),
                crate::pcapng::wall_offset_ns(),
            )
            .map_err(|e| pcap_failure(path, &e))?;
            Some((path, writer))
        }
        None => None,
    };
    catch_signals()?;
    let start = Instant::now();
    let mut first_ns = None;
    let mut shown = 0u64;
    let done = |shown: u64| {
        stopped()
            || o.count.is_some_and(|n| shown >= n)
            || duration.is_some_and(|d| start.elapsed() >= d)
    };
    let mut outcome = Ok(());
    while !done(shown) {
        let records = match capture.take() {
            Ok(r) => r,
            Err(e) => {
                outcome = Err(e.into());
                break;
            }
        };
        if records.is_empty() {
            std::thread::sleep(POLL);
            continue;
        }
        for r in records
            .iter()
            .filter(|r| o.drive.is_none_or(|a| r.address == a.get()))
        {
            if done(shown) {
                break;
            }
            let first = *first_ns.get_or_insert(r.start_ns);
            let t = r.start_ns.saturating_sub(first) as f64 / 1e9;
            if let Some((path, writer)) = &mut pcap {
                writer.write(r).map_err(|e| pcap_failure(path, &e))?;
            }
            let line = decoder.decode(r, t);
            out.show(&line, crate::decode::CaptureLine::human)?;
            shown += 1;
        }
    }
    if let Some((path, writer)) = pcap {
        use std::io::Write as _;
        writer
            .into_inner()
            .flush()
            .map_err(|source| Failure::File {
                path: path.display().to_string(),
                source,
            })?;
    }
    if capture.lost() > 0 {
        out.note(&format!(
            "{} telegrams were lost: this capture did not keep up",
            capture.lost()
        ));
    }
    outcome
}

fn pcap_failure(path: &Path, e: &pcap_file::PcapError) -> Failure {
    Failure::File {
        path: path.display().to_string(),
        source: std::io::Error::other(e.to_string()),
    }
}
