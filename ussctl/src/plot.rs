//! The picture of a trace (plotters): actual frequency against the setpoint sent over time,
//! one colour per drive, with state changes, faults, latches and gaps marked; below it, each
//! drive's state as a step line. SVG or PNG, by the file's extension.
//!
//! Text is laid out with `DejaVu` Sans, built in (the `dejavu` crate), so the picture is the same
//! on a machine without fonts.

use crate::Failure;
use crate::commands::trace::Row;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

/// The picture's size in pixels.
const SIZE: (u32, u32) = (1200, 800);
/// The font family text is drawn with.
const FONT: &str = "sans-serif";

/// A plot file's format, by its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Svg,
    Png,
}

impl Format {
    pub(crate) fn of(path: &Path) -> Result<Self, Failure> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("svg") => Ok(Self::Svg),
            Some("png") => Ok(Self::Png),
            _ => Err(Failure::Plot {
                path: path.display().to_string(),
                reason: "name the file .svg or .png".to_owned(),
            }),
        }
    }
}

/// Renders `rows` to `path`; `triggered` marks time 0 as the trigger.
pub(crate) fn render(
    path: &Path,
    title: &str,
    rows: &[Row],
    triggered: bool,
) -> Result<(), Failure> {
    static FONTS: Once = Once::new();
    FONTS.call_once(|| {
        // The built-in font is valid; a failure would only leave text out.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
    });
    let failed = |reason: String| Failure::Plot {
        path: path.display().to_string(),
        reason,
    };
    match Format::of(path)? {
        Format::Svg => {
            let root = SVGBackend::new(path, SIZE).into_drawing_area();
            draw(&root, title, rows, triggered).map_err(|e| failed(e.to_string()))?;
            root.present().map_err(|e| failed(e.to_string()))
        }
        Format::Png => {
            let root = BitMapBackend::new(path, SIZE).into_drawing_area();
            draw(&root, title, rows, triggered).map_err(|e| failed(e.to_string()))?;
            root.present().map_err(|e| failed(e.to_string()))
        }
    }
}

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// The drives of `rows`, in address order.
fn drives(rows: &[Row]) -> Vec<u8> {
    let mut drives: Vec<u8> = rows.iter().map(|r| r.drive).collect();
    drives.sort_unstable();
    drives.dedup();
    drives
}

/// The time axis: the rows' span (at least a second).
fn time_range(rows: &[Row]) -> core::ops::Range<f64> {
    let (lo, hi) = rows
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
            (lo.min(r.t_s), hi.max(r.t_s))
        });
    if lo.is_finite() && hi - lo >= 1.0 {
        lo..hi
    } else if lo.is_finite() {
        lo..lo + 1.0
    } else {
        0.0..1.0
    }
}

/// The frequency axis: 0 and every value, with a margin.
fn hz_range(rows: &[Row]) -> core::ops::Range<f64> {
    let (lo, hi) = rows.iter().fold((0.0_f64, 0.0_f64), |(lo, hi), r| {
        let (a, s) = (f64::from(r.actual_hz), f64::from(r.setpoint_hz));
        (lo.min(a).min(s), hi.max(a).max(s))
    });
    let margin = ((hi - lo) * 0.08).max(1.0);
    (lo - if lo < 0.0 { margin } else { 0.0 })..(hi + margin)
}

/// A drive's state as a height on the state lane.
fn level(state: &str) -> f64 {
    match state {
        "S1" => 1.0,
        "S2" => 2.0,
        "S3" => 3.0,
        "S5" => 3.5,
        "S4" => 4.0,
        "not ready" => 0.5,
        _ => 0.0,
    }
}

fn level_name(y: f64) -> String {
    match y.round() as i64 {
        0 => "fault".to_owned(),
        n @ 1..=4 => format!("S{n}"),
        _ => String::new(),
    }
}

/// Whether a row shows the drive as it is (online, ussd serving).
fn live(r: &Row) -> bool {
    r.online != 0 && r.note.is_empty()
}

/// The runs of consecutive live rows of one drive.
fn live_runs<'a>(rows: &[&'a Row]) -> Vec<Vec<&'a Row>> {
    let mut runs: Vec<Vec<&Row>> = Vec::new();
    let mut current = Vec::new();
    for &r in rows {
        if live(r) {
            current.push(r);
        } else if !current.is_empty() {
            runs.push(core::mem::take(&mut current));
        }
    }
    if !current.is_empty() {
        runs.push(current);
    }
    runs
}

/// A mark on the time axis: where, what, in which colour.
struct Mark {
    t: f64,
    text: String,
    color: RGBColor,
}

/// Where a drive's state, fault, control or liveness changed.
fn marks(rows: &[&Row]) -> Vec<Mark> {
    let mut marks = Vec::new();
    for pair in rows.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let (t, drive) = (b.t_s, b.drive);
        if live(a) && !live(b) {
            let why = if b.note.is_empty() { "offline" } else { b.note };
            marks.push(Mark {
                t,
                text: format!("{drive}: {why}"),
                color: RGBColor(120, 120, 120),
            });
        } else if b.fault != 0 && a.fault == 0 {
            marks.push(Mark {
                t,
                text: format!("{drive}: fault"),
                color: RED,
            });
        } else if b.control != a.control {
            marks.push(Mark {
                t,
                text: format!("{drive}: {}", b.control),
                color: RGBColor(230, 120, 0),
            });
        } else if b.state != a.state && live(b) {
            marks.push(Mark {
                t,
                text: format!("{drive}: {}", b.state),
                color: RGBColor(90, 90, 200),
            });
        }
    }
    marks
}

/// The most marks that get a text (more would be unreadable; all get their line).
const LABELLED_MARKS: usize = 40;

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    rows: &[Row],
    triggered: bool,
) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let root = root.titled(title, (FONT, 24))?;
    let (upper, lower) = root.split_vertically(root.dim_in_pixel().1 * 7 / 10);
    let time = time_range(rows);
    let hz = hz_range(rows);
    let mut speed = ChartBuilder::on(&upper)
        .caption(
            "actual frequency (solid) and setpoint sent (dashed)",
            (FONT, 16),
        )
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(time.clone(), hz.clone())?;
    speed
        .configure_mesh()
        .x_desc("time [s]")
        .y_desc("Hz")
        .label_style((FONT, 13))
        .draw()?;
    let mut states = ChartBuilder::on(&lower)
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(60)
        .build_cartesian_2d(time, -0.5..4.5)?;
    states
        .configure_mesh()
        .x_desc("time [s]")
        .y_desc("state")
        .y_labels(6)
        .y_label_formatter(&|y| level_name(*y))
        .label_style((FONT, 13))
        .draw()?;
    let mut labelled = 0;
    for (i, drive) in drives(rows).into_iter().enumerate() {
        let own: Vec<&Row> = rows.iter().filter(|r| r.drive == drive).collect();
        let color = Palette99::pick(i).to_rgba();
        draw_drive(&mut speed, &mut states, &own, color, &mut labelled)?;
    }
    if triggered {
        let line = [(0.0, hz.start), (0.0, hz.end)];
        speed.draw_series(std::iter::once(PathElement::new(
            line,
            BLACK.stroke_width(2),
        )))?;
        speed.draw_series(std::iter::once(Text::new(
            "trigger",
            (0.0, hz.start + (hz.end - hz.start) * 0.03),
            (FONT, 14),
        )))?;
    }
    speed
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .label_font((FONT, 13))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

type Chart<'a, DB> = ChartContext<
    'a,
    DB,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// One drive's lines, state steps and marks; `labelled` counts the marks with a text so far.
fn draw_drive<DB: DrawingBackend>(
    speed: &mut Chart<'_, DB>,
    states: &mut Chart<'_, DB>,
    own: &[&Row],
    color: RGBAColor,
    labelled: &mut usize,
) -> DrawResult<DB> {
    let drive = own.first().map_or(0, |r| r.drive);
    let hz = speed.y_range();
    for (n, run) in live_runs(own).into_iter().enumerate() {
        let actual = speed.draw_series(LineSeries::new(
            run.iter().map(|r| (r.t_s, f64::from(r.actual_hz))),
            color.stroke_width(2),
        ))?;
        if n == 0 {
            actual
                .label(format!("drive {drive} actual"))
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        let set = speed.draw_series(DashedLineSeries::new(
            run.iter().map(|r| (r.t_s, f64::from(r.setpoint_hz))),
            8,
            5,
            color.stroke_width(1),
        ))?;
        if n == 0 {
            set.label(format!("drive {drive} set"))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color));
        }
    }
    // The state lane: a step line, grey where the drive is not live.
    let mut steps = Vec::with_capacity(own.len() * 2);
    for pair in own.windows(2) {
        let y = if live(pair[0]) {
            level(pair[0].state)
        } else {
            -0.25
        };
        steps.push((pair[0].t_s, y));
        steps.push((pair[1].t_s, y));
    }
    states.draw_series(LineSeries::new(steps, color.stroke_width(2)))?;
    for mark in marks(own) {
        let line = [(mark.t, hz.start), (mark.t, hz.end)];
        speed.draw_series(std::iter::once(PathElement::new(line, mark.color)))?;
        if *labelled < LABELLED_MARKS {
            let y = hz.end - (hz.end - hz.start) * (0.04 + 0.05 * (*labelled % 6) as f64);
            speed.draw_series(std::iter::once(Text::new(
                mark.text,
                (mark.t, y),
                (FONT, 13).into_font().color(&mark.color),
            )))?;
            *labelled += 1;
        }
    }
    Ok(())
}
