//! `trace`: every input image of some drives at bus rate, optionally from a trigger on, to CSV
//! and a plot.
//!
//! ussd writes a drive's input image after every poll and notifies the bus's cycle event; the
//! trace wakes on it and records each image whose sequence (good replies), online or control
//! state changed. An image the trace was too late to see is counted in the next row's
//! `missed`, never invented.

use crate::cli::{Trigger, address, duration, trigger};
use crate::{Failure, Output, catch_signals, stopped};
use core::fmt::Write as _;
use core::time::Duration;
use serde::Serialize;
use std::collections::VecDeque;
use std::path::PathBuf;
use uss_client::uss_protocol::{Setpoint, Zsw1};
use uss_client::{Address, Bus, ClientError, DriveWatch, PzdInput, monotonic_ns, state_name};

/// `trace`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Trace {
    /// The drives to record (addresses 0..=31).
    #[arg(required = true, value_parser = address)]
    pub(crate) drives: Vec<Address>,
    /// How long to record (after the trigger, when there is one): 10, 10s, 2.5s or 500ms.
    #[arg(long = "for", value_name = "DURATION", default_value = "10s", value_parser = duration)]
    pub(crate) duration: Duration,
    /// Start recording when this becomes true on a traced drive: `fault` (ZSW1 bit 3),
    /// `zsw1-bit=N` (bit N set), `hz>F` or `hz<F` (actual frequency). A condition already
    /// true when the trace starts fires once it has been false.
    #[arg(long, value_name = "CONDITION", value_parser = trigger)]
    pub(crate) trigger: Option<Trigger>,
    /// Keep this much from before the trigger (time 0 is the trigger).
    #[arg(long, value_name = "DURATION", value_parser = duration, requires = "trigger")]
    pub(crate) pre: Option<Duration>,
    /// Give up when the trigger has not fired after this long (default: wait until Ctrl-C).
    #[arg(long, value_name = "DURATION", value_parser = duration, requires = "trigger")]
    pub(crate) wait: Option<Duration>,
    /// Write the CSV to FILE (default: stdout).
    #[arg(short = 'o', long = "output", value_name = "FILE")]
    pub(crate) output: Option<PathBuf>,
    /// Render the trace to FILE: .svg or .png.
    #[arg(long, value_name = "FILE")]
    pub(crate) plot: Option<PathBuf>,
}

/// The longest the trace sleeps without looking at the images (an exchange event may be
/// coalesced with the next, or ussd may be gone).
const WAIT_STEP: Duration = Duration::from_millis(20);

/// Which drive an image is of, its reference frequency, and when it was seen.
struct At {
    drive: u8,
    reference_hz: f32,
    ns: u64,
}

/// One recorded input image: a CSV row.
#[derive(Debug, Clone, Serialize, schemars::JsonSchema)]
pub(crate) struct Row {
    /// Seconds from the trigger (or the start of the trace).
    pub t_s: f64,
    pub drive: u8,
    /// Good replies of this ussd so far.
    pub sequence: u64,
    pub online: u8,
    /// `live` or `latched`.
    pub control: &'static str,
    /// S1..S5, fault, not ready.
    pub state: &'static str,
    pub zsw1: String,
    pub fault: u8,
    pub warning: u8,
    pub actual_hz: f32,
    /// The setpoint the poll sent.
    pub setpoint_hz: f32,
    /// The control word the poll sent.
    pub stw1: String,
    /// Time since the drive's previous good reply.
    pub age_ms: f64,
    /// Good replies between the previous row of this drive and this one that the trace did
    /// not see.
    pub missed: u64,
    /// Why the image is not live: `ussd gone`, `ussd stopped`, `line down`; empty when it is.
    pub note: &'static str,
    /// When, `CLOCK_MONOTONIC` ns (not written).
    #[serde(skip)]
    pub at_ns: u64,
    /// ZSW1 as a number (written as `zsw1`).
    #[serde(skip)]
    pub zsw1_bits: u16,
}

impl Row {
    fn new(at: &At, image: &PzdInput, missed: u64, note: &'static str) -> Self {
        let reference_hz = at.reference_hz;
        let z = Zsw1::from_bits_retain(image.zsw1);
        Self {
            t_s: 0.0,
            drive: at.drive,
            sequence: image.sequence,
            online: image.online,
            control: image.control_name(),
            state: state_name(image.zsw1),
            zsw1: format!("0x{:04X}", image.zsw1),
            fault: u8::from(z.contains(Zsw1::FAULT)),
            warning: u8::from(z.contains(Zsw1::WARNING)),
            actual_hz: Setpoint::from_word(image.hiw).hz(reference_hz),
            setpoint_hz: Setpoint::from_word(image.sent_setpoint).hz(reference_hz),
            stw1: format!("0x{:04X}", image.sent_stw1),
            age_ms: image.age_ns as f64 / 1e6,
            missed,
            note,
            at_ns: at.ns,
            zsw1_bits: image.zsw1,
        }
    }

    /// Whether `trigger` holds for this image (never for an image that is not live).
    fn satisfies(&self, trigger: Trigger) -> bool {
        if self.online == 0 || !self.note.is_empty() {
            return false;
        }
        match trigger {
            Trigger::Fault => self.fault != 0,
            Trigger::Zsw1Bit(n) => self.zsw1_bits & (1 << n) != 0,
            Trigger::HzAbove(hz) => self.actual_hz > hz,
            Trigger::HzBelow(hz) => self.actual_hz < hz,
        }
    }
}

/// The short reason a client error gives for an image that is not live.
fn note_of(e: &ClientError) -> &'static str {
    match e {
        ClientError::UssdGone { .. } => "ussd gone",
        ClientError::UssdStopped { .. } => "ussd stopped",
        ClientError::LineDown { .. } => "line down",
        _ => "not served",
    }
}

/// One traced drive: its watch and what the trace saw last.
struct Traced {
    watch: DriveWatch,
    last: Option<(PzdInput, &'static str)>,
    /// Whether the trigger's condition held on the last row (None before the first).
    armed: Option<bool>,
}

impl Traced {
    /// The row for the drive's current image, if it differs from the last one seen.
    fn look(&mut self) -> Option<Row> {
        let look = self.watch.snapshot();
        let (image, note) = (look.image, look.problem.as_ref().map_or("", note_of));
        let changed = self
            .last
            .is_none_or(|(last, last_note)| !last.same_picture(&image) || last_note != note);
        if !changed {
            return None;
        }
        // A restarted ussd counts its sequence from 0 again: nothing missed across it.
        let missed = match self.last {
            Some((last, _)) if image.sequence > last.sequence => image.sequence - last.sequence - 1,
            _ => 0,
        };
        let fresh = self.last.is_none_or(|(l, _)| l.sequence != image.sequence);
        let at_ns = if fresh && image.timestamp_ns != 0 && note.is_empty() {
            image.timestamp_ns
        } else {
            monotonic_ns()
        };
        self.last = Some((image, note));
        let at = At {
            drive: self.watch.address().get(),
            reference_hz: look.info.reference_hz,
            ns: at_ns,
        };
        Some(Row::new(&at, &image, missed, note))
    }
}

/// What a trace recorded.
pub(crate) struct Recording {
    pub rows: Vec<Row>,
    /// Whether Ctrl-C ended it early.
    pub interrupted: bool,
}

/// Records until `duration` after the trigger (or the start), or Ctrl-C.
fn record(bus: &Bus, out: &Output, o: &Trace) -> Result<Recording, Failure> {
    let mut traced = o
        .drives
        .iter()
        .map(|&a| {
            Ok(Traced {
                watch: bus.watch(a)?,
                last: None,
                armed: None,
            })
        })
        .collect::<Result<Vec<_>, Failure>>()?;
    let cycle = bus.cycle_listener()?;
    catch_signals()?;
    if let Some(trigger) = o.trigger {
        let note = format!("waiting for the trigger {trigger} (Ctrl-C gives up)");
        if o.output.is_some() {
            out.note(&note);
        } else {
            eprintln!("{note}");
        }
    }
    let start = monotonic_ns();
    let nanos = |d: Duration| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
    let mut fired: Option<u64> = o.trigger.is_none().then_some(start);
    let mut rows: VecDeque<Row> = VecDeque::new();
    loop {
        let now = monotonic_ns();
        if let Some(t0) = fired {
            if now >= t0.saturating_add(nanos(o.duration)) {
                break;
            }
        } else if let Some(wait) = o.wait
            && now >= start.saturating_add(nanos(wait))
        {
            return Err(Failure::NotTriggered {
                trigger: o.trigger.map(|t| t.to_string()).unwrap_or_default(),
                why: format!("did not fire within {:.1} s", wait.as_secs_f64()),
            });
        }
        if stopped() {
            if fired.is_none() {
                return Err(Failure::NotTriggered {
                    trigger: o.trigger.map(|t| t.to_string()).unwrap_or_default(),
                    why: "had not fired when the trace was stopped".to_owned(),
                });
            }
            return Ok(finish(rows, fired, true));
        }
        // ussd gone, stopped or its line down: the rows say so; keep looking (it may return).
        if cycle.wait(WAIT_STEP, |_| {}).is_err() {
            std::thread::sleep(WAIT_STEP);
        }
        for t in &mut traced {
            let Some(row) = t.look() else { continue };
            if let (Some(trigger), None) = (o.trigger, fired) {
                let holds = row.satisfies(trigger);
                if t.armed == Some(false) && holds {
                    fired = Some(row.at_ns);
                }
                t.armed = Some(holds);
            }
            rows.push_back(row);
        }
        if fired.is_none() {
            // Before the trigger only --pre is kept.
            let keep_from = monotonic_ns().saturating_sub(nanos(o.pre.unwrap_or_default()));
            while rows.front().is_some_and(|r| r.at_ns < keep_from) {
                rows.pop_front();
            }
        }
    }
    Ok(finish(rows, fired, false))
}

fn finish(rows: VecDeque<Row>, fired: Option<u64>, interrupted: bool) -> Recording {
    // Time 0: the trigger, or the start.
    let origin_ns = fired.unwrap_or(0);
    let mut rows: Vec<Row> = rows.into();
    // Rows of different drives are appended in the order they were seen; order them by time.
    rows.sort_by_key(|r| r.at_ns);
    for r in &mut rows {
        r.t_s = (i128::from(r.at_ns) - i128::from(origin_ns)) as f64 / 1e9;
    }
    Recording { rows, interrupted }
}

/// What `trace` reports when done.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub(crate) struct Summary {
    drives: Vec<u8>,
    rows: usize,
    seconds: f64,
    missed: u64,
    trigger: Option<String>,
    interrupted: bool,
    csv: Option<String>,
    plot: Option<String>,
}

impl Summary {
    fn human(&self) -> String {
        let drives: Vec<String> = self.drives.iter().map(u8::to_string).collect();
        let mut text = format!(
            "trace: drive{} {}: {} images in {:.2} s, {} missed",
            if self.drives.len() == 1 { "" } else { "s" },
            drives.join(", "),
            self.rows,
            self.seconds,
            self.missed
        );
        if let Some(t) = &self.trigger {
            let _ = write!(text, ", from trigger {t} (time 0)");
        }
        if self.interrupted {
            text += ", cut short by Ctrl-C";
        }
        for file in [&self.csv, &self.plot].into_iter().flatten() {
            let _ = write!(text, "\nwrote {file}");
        }
        text
    }
}

impl Trace {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        trace(bus, out, self)
    }
}

fn trace(bus: &Bus, out: &Output, o: &Trace) -> Result<(), Failure> {
    if let Some(plot) = o.plot.as_deref() {
        crate::plot::Format::of(plot)?;
    }
    let recording = record(bus, out, o)?;
    let rows = &recording.rows;
    let mut csv = Vec::new();
    {
        let mut writer = csv::Writer::from_writer(&mut csv);
        for row in rows {
            writer.serialize(row).map_err(Failure::Csv)?;
        }
        writer
            .flush()
            .map_err(|e| Failure::Csv(csv::Error::from(e)))?;
    }
    if let Some(path) = o.output.as_deref() {
        std::fs::write(path, &csv).map_err(|source| Failure::File {
            path: path.display().to_string(),
            source,
        })?;
    } else {
        crate::write_out(&String::from_utf8_lossy(&csv))?;
    }
    if let Some(path) = o.plot.as_deref() {
        let title = format!(
            "bus {}: drive{} {}",
            bus.name(),
            if o.drives.len() == 1 { "" } else { "s" },
            o.drives
                .iter()
                .map(Address::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        );
        crate::plot::render(path, &title, rows, o.trigger.is_some())?;
    }
    let seconds = match (rows.first(), rows.last()) {
        (Some(a), Some(b)) => b.t_s - a.t_s,
        _ => 0.0,
    };
    let summary = Summary {
        drives: o.drives.iter().map(|a| a.get()).collect(),
        rows: rows.len(),
        seconds,
        missed: rows.iter().map(|r| r.missed).sum(),
        trigger: o.trigger.map(|t| t.to_string()),
        interrupted: recording.interrupted,
        csv: o.output.as_ref().map(|p| p.display().to_string()),
        plot: o.plot.as_ref().map(|p| p.display().to_string()),
    };
    if o.output.is_some() {
        out.show(&summary, Summary::human)
    } else {
        // The CSV went to stdout: the summary goes beside it.
        eprintln!("{}", summary.human());
        Ok(())
    }
}
