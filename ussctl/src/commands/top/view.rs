//! Drawing one frame: status bar, drive table, detail pane, key line.

use super::App;
use super::detail::{COUNTERS, Detail};
use super::model::{Col, Screen, TopDrive};
use ratatui::Frame;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Cell, Paragraph, Row, Table, TableState, Wrap};
use uss_client::Health;

const RED: Style = Style::new().fg(Color::Red).add_modifier(Modifier::BOLD);
const YELLOW: Style = Style::new().fg(Color::Yellow);
const GREEN: Style = Style::new().fg(Color::Green);
const DIM: Style = Style::new().fg(Color::DarkGray);
/// A value that changed within the last two seconds.
const CHANGED: Style = Style::new().add_modifier(Modifier::REVERSED);

pub(super) fn draw(frame: &mut Frame<'_>, app: &App) {
    let screen = &app.screens[app.current];
    // The table as high as its drives (borders and header: 3 lines), the detail pane below.
    let rows = u16::try_from(screen.drives.len())
        .unwrap_or(u16::MAX)
        .max(1);
    let [bar, table, detail, keys] = Layout::vertical([
        Constraint::Length(4),
        Constraint::Max(rows.saturating_add(3)),
        Constraint::Min(9),
        Constraint::Length(2),
    ])
    .areas(frame.area());
    frame.render_widget(status_bar(app, screen), bar);
    draw_table(frame, screen, table);
    frame.render_widget(detail_pane(screen), detail);
    frame.render_widget(key_line(app, screen), keys);
}

/// Whether what the screen shows is not the bus as it is now.
fn stale(screen: &Screen) -> bool {
    !screen.serving() || screen.read_error.is_some()
}

fn status_bar<'a>(app: &App, screen: &'a Screen) -> Paragraph<'a> {
    let tabs: Vec<Span<'_>> = app
        .screens
        .iter()
        .enumerate()
        .flat_map(|(i, s)| {
            let style = if i == app.current {
                Style::new().add_modifier(Modifier::REVERSED | Modifier::BOLD)
            } else {
                Style::new()
            };
            [
                Span::styled(format!(" bus {} ", s.name), style),
                Span::raw(" "),
            ]
        })
        .collect();
    let mut lines = vec![Line::from(tabs)];
    lines.push(ussd_line(screen));
    if let Some(r) = screen.report.as_ref().filter(|_| screen.bus_open()) {
        let rt = if r.rt_cpu >= 0 {
            format!(
                "{} priority {} on CPU {}",
                r.rt_mode, r.rt_priority, r.rt_cpu
            )
        } else {
            r.rt_mode.to_owned()
        };
        let (per_s, cycle_ms) = screen.rates.unwrap_or((f64::NAN, f64::NAN));
        let line = match &r.line_error {
            _ if stale(screen) => Span::styled("line: not known now", DIM),
            None => Span::styled("line up", GREEN),
            Some(e) => Span::styled(format!("LINE DOWN: {e}"), RED),
        };
        let efficiency = r
            .efficiency
            .map_or_else(|| "not measured".to_owned(), |e| format!("{e:.2}"));
        let shown = if stale(screen) { DIM } else { Style::new() };
        lines.push(Line::from(vec![
            Span::styled(format!(
                "RT {rt} | cycle {cycle_ms:.1} ms | {per_s:.0} exchanges/s | mean exchange {:.0} us | efficiency {efficiency} of the wire floor | ",
                r.mean_exchange_us
            ), shown),
            line,
            Span::styled(format!(
                " | jobs {}/{} | overruns {}",
                r.jobs_finished, r.jobs_accepted, r.cycle_overruns
            ), shown),
        ]).style(shown));
    }
    Paragraph::new(lines)
}

/// What the heartbeat says of ussd.
fn ussd_line(screen: &Screen) -> Line<'_> {
    if let Some(e) = &screen.open_error {
        return Line::from(Span::styled(
            format!("NO USSD: {e}; trying again every second"),
            RED,
        ));
    }
    let now = uss_client::monotonic_ns();
    let ago = |ns: u64| now.saturating_sub(ns) as f64 / 1e9;
    match &screen.health {
        Some(Health::Running { pid }) => {
            let mut spans = vec![Span::styled(
                format!("ussd {pid} running, heartbeat fresh"),
                GREEN,
            )];
            if let Some(s) = &screen.status {
                spans.push(Span::raw(format!(
                    " | status {:.2} s old | {} drives",
                    ago(s.timestamp_ns),
                    s.drive_count
                )));
            }
            Line::from(spans)
        }
        Some(Health::LineDown { pid, since_ns, .. }) => Line::from(Span::styled(
            format!(
                "ussd {pid} running, its LINE is DOWN for {:.1} s: every drive offline",
                ago(*since_ns)
            ),
            RED,
        )),
        Some(Health::Stopped { pid, at_ns }) => Line::from(Span::styled(
            format!(
                "ussd {pid} STOPPED {:.1} s ago: the picture below is STALE (waiting for a new ussd)",
                ago(*at_ns)
            ),
            RED,
        )),
        Some(Health::Gone { pid, last_ns }) => Line::from(Span::styled(
            format!(
                "ussd {pid} GONE: no heartbeat for {:.1} s: the picture below is STALE (waiting for a new ussd)",
                ago(*last_ns)
            ),
            RED,
        )),
        None => Line::from(Span::styled("connecting...", DIM)),
    }
}

/// The style of a marked value: reversed while changed, else `normal`.
fn marked(screen: &Screen, drive: u8, col: Col, normal: Style) -> Style {
    if screen.changed(drive, col) {
        normal.patch(CHANGED)
    } else {
        normal
    }
}

/// Drive `d`'s row, its cells of the columns `shown`.
fn drive_row<'a>(screen: &Screen, d: &'a TopDrive, shown: &[usize]) -> Row<'a> {
    let r = &d.row;
    let a = r.address;
    let state_style = match r.state {
        "offline" | "fault" => RED,
        "unknown" | "not ready" => DIM,
        "S4" => GREEN,
        _ => Style::new(),
    };
    let control_style = if d.control.state == "latched" {
        YELLOW
    } else {
        GREEN
    };
    let count_style = |n: u64| if n > 0 { YELLOW } else { Style::new() };
    let cells = vec![
        Cell::from(format!("{a:>4}")),
        Cell::from(if r.online { "yes" } else { "NO" }).style(marked(
            screen,
            a,
            Col::Online,
            if r.online { Style::new() } else { RED },
        )),
        Cell::from(d.control.human()).style(marked(screen, a, Col::Control, control_style)),
        Cell::from(r.state).style(marked(screen, a, Col::State, state_style)),
        Cell::from(r.zsw1_hex.clone()).style(marked(screen, a, Col::Zsw1, Style::new())),
        Cell::from(r.flags.join(",")),
        Cell::from(format!("{:8.2}", r.actual_hz)),
        Cell::from(d.set_hz.map_or_else(String::new, |hz| format!("{hz:8.2}"))),
        Cell::from(format!("{:>10}", r.good)),
        Cell::from(format!("{:>8}", r.rejected)).style(marked(
            screen,
            a,
            Col::Rejected,
            count_style(r.rejected),
        )),
        Cell::from(format!("{:>8}", r.timeouts)).style(marked(
            screen,
            a,
            Col::Timeouts,
            count_style(r.timeouts),
        )),
        Cell::from(r.last_error).style(marked(
            screen,
            a,
            Col::LastError,
            if r.last_error == "none" {
                Style::new()
            } else {
                YELLOW
            },
        )),
        Cell::from(match d.diag.info.watchdog_ms {
            0 => "off".to_owned(),
            ms => format!("{ms} ms"),
        }),
        // The process whose words go out: none while the drive is latched (its last
        // controller may have released it, died or been stopped).
        Cell::from(
            r.controller_pid
                .filter(|_| r.control.state == "live")
                .map_or_else(String::new, |p| p.to_string()),
        ),
    ];
    Row::new(
        cells
            .into_iter()
            .enumerate()
            .filter(|(c, _)| shown.contains(c))
            .map(|(_, cell)| cell),
    )
}

/// The table's columns in the order shown: title and width (0: the flags, which get what the
/// others leave).
const COLUMNS: [(&str, u16); 14] = [
    ("addr", 4),
    ("online", 6),
    ("control", 30),
    ("state", 9),
    ("ZSW1", 6),
    ("flags", 0),
    ("actual Hz", 9),
    ("set Hz", 8),
    ("good", 10),
    ("rejected", 8),
    ("timeouts", 8),
    ("last error", 17),
    ("watchdog", 8),
    ("controller", 10),
];

/// The order columns get room in, as a narrow terminal shows them (top and htop fit 80
/// columns the same way): which drive, whether it answers and what it does first, the
/// counters after; the flags take only what is left.
const ROOM_ORDER: [usize; 14] = [0, 1, 3, 2, 6, 7, 4, 8, 10, 9, 11, 13, 12, 5];

/// The control column's index in [`COLUMNS`].
const CONTROL: usize = 2;

/// The control column's narrowest: "latched" and a space. Below its full width it is cut at
/// the end, its state word first (`latched: ...`): a latched drive never looks like one that
/// runs (issue 47's sweep: under 57 columns the column was dropped for narrower ones).
const CONTROL_MIN: u16 = 8;

/// The columns that fit `width` (the table's inside: borders and the selection mark off), in
/// the order shown, each with its width: each value whole but the control's text, which is
/// narrowed rather than left out.
fn fitting(width: u16) -> Vec<(usize, u16)> {
    let mut left = width;
    let mut shown = Vec::new();
    for &c in &ROOM_ORDER {
        let full = COLUMNS[c].1;
        if full == 0 || full < left {
            left = left.saturating_sub(full + 1);
            shown.push((c, full));
        } else if c == CONTROL && left > CONTROL_MIN {
            shown.push((c, left - 1));
            left = 0;
        }
    }
    shown.sort_unstable();
    shown
}

fn draw_table(frame: &mut Frame<'_>, screen: &Screen, area: Rect) {
    // Borders and the selection mark ("> ").
    let fit = fitting(area.width.saturating_sub(4));
    let shown: Vec<usize> = fit.iter().map(|&(c, _)| c).collect();
    let header = Row::new(shown.iter().map(|&c| COLUMNS[c].0))
        .style(Style::new().add_modifier(Modifier::BOLD | Modifier::UNDERLINED));
    let widths: Vec<Constraint> = fit
        .iter()
        .map(|&(_, w)| match w {
            0 => Constraint::Fill(1),
            w => Constraint::Length(w),
        })
        .collect();
    let mut title = format!(" drives of bus {} ", screen.name);
    let mut style = Style::new();
    if stale(screen) {
        title.push_str("- STALE: the last picture ussd gave, not the bus now ");
        style = DIM;
    }
    let rows = screen.drives.iter().map(|d| drive_row(screen, d, &shown));
    let table = Table::new(rows, widths)
        .header(header)
        .style(style)
        .block(Block::bordered().title(title))
        .row_highlight_style(Style::new().add_modifier(Modifier::BOLD))
        .highlight_symbol("> ");
    let mut state = TableState::default().with_selected(Some(screen.selected));
    frame.render_stateful_widget(table, area, &mut state);
}

fn detail_pane(screen: &Screen) -> Paragraph<'_> {
    let Some(d) = screen.drives.get(screen.selected) else {
        return Paragraph::new("no drive").block(Block::bordered().title(" detail "));
    };
    let diag = &d.diag;
    let c = &diag.counters;
    let us = |n: u64| n as f64 / 1e3;
    let q = |v: [u64; 4]| {
        format!(
            "p50 {:.0} p99 {:.0} p99.9 {:.0} max {:.0} us",
            us(v[0]),
            us(v[1]),
            us(v[2]),
            us(v[3])
        )
    };
    let mut lines = vec![
        Line::from(format!(
            "ussd: sent {} good {} rejected {} | timeouts {} retries {} failed polls {} | BCC {} length {} STX {} residual {} wrong address {} parity {} framing {} overrun {} echo {}",
            c.requests,
            c.good,
            c.rejected,
            c.timeouts,
            c.retries,
            c.failed_polls,
            c.bcc,
            c.length,
            c.missing_stx,
            c.residual,
            c.wrong_address,
            c.parity,
            c.framing,
            c.overrun,
            c.echo
        )),
        Line::from(format!(
            "      parameter jobs {} busy {} | watchdog trips {} latches {} releases {} overrides {} refused samples {}",
            c.jobs_done,
            c.pkw_busy,
            c.watchdog_trips,
            c.latches,
            c.releases,
            c.overrides,
            c.rejected_outputs
        )),
        Line::from(format!(
            "timing: exchange {} | response delay {}",
            q(diag.exchange_ns),
            q(diag.response_delay_ns)
        )),
    ];
    lines.extend(own_view(screen, diag.address));
    let title = format!(
        " drive {} - {} ",
        diag.address,
        crate::report::InfoReport::of(&diag.info).human()
    );
    Paragraph::new(lines)
        .wrap(Wrap { trim: true })
        .block(Block::bordered().title(title))
}

/// The drive's own counters and fault buffer, as last read for this drive.
fn own_view(screen: &Screen, drive: u8) -> Vec<Line<'static>> {
    let Some(d) = screen
        .detail
        .as_ref()
        .filter(|d: &&Detail| d.drive.get() == drive)
    else {
        return vec![Line::styled(
            "drive's own counters (r2024..r2031) and fault buffer: reading...",
            DIM,
        )];
    };
    let ago = d.at.elapsed().as_secs_f64();
    let counters: Vec<String> = COUNTERS
        .iter()
        .zip(&d.counters)
        .map(|(&(pnu, name), v)| match v {
            Ok(n) => format!("r{pnu} {name} {n}"),
            Err(_) => format!("r{pnu} {name} -"),
        })
        .collect();
    let mut lines = vec![Line::from(format!(
        "drive's own USS counters, COM link (read {ago:.1} s ago): {}",
        counters.join(", ")
    ))];
    lines.push(match &d.faults {
        None => Line::styled("fault buffer: reading...", DIM),
        Some(Ok(report)) => {
            let faults: Vec<String> = report
                .faults
                .iter()
                .take(4)
                .map(|f| {
                    let time = f.when().map_or_else(String::new, |t| format!(" at {t}"));
                    let digits = usize::from(report.digits);
                    format!("F{:0digits$} {}{time}", f.number, f.text.unwrap_or(""))
                })
                .collect();
            let warnings = report.warnings.as_ref().map_or_else(
                || "unknown".to_owned(),
                |w| {
                    if w.is_empty() {
                        "none".to_owned()
                    } else {
                        w.iter()
                            .map(|w| format!("A{:04} {}", w.number, w.text.unwrap_or("")))
                            .collect::<Vec<_>>()
                            .join(", ")
                    }
                },
            );
            let style = if faults.is_empty() {
                Style::new()
            } else {
                YELLOW
            };
            Line::styled(
                format!(
                    "fault buffer: {} | warnings: {warnings}",
                    if faults.is_empty() {
                        "empty".to_owned()
                    } else {
                        faults.join("; ")
                    }
                ),
                style,
            )
        }
        Some(Err(e)) => Line::styled(format!("fault buffer: not read: {e}"), DIM),
    });
    lines
}

fn key_line<'a>(app: &'a App, screen: &Screen) -> Paragraph<'a> {
    let mut lines = Vec::new();
    if let Some(p) = app.pending {
        lines.push(Line::styled(
            p.question(&screen.name),
            Style::new()
                .fg(Color::Black)
                .bg(Color::Yellow)
                .add_modifier(Modifier::BOLD),
        ));
    } else if let Some((text, error, at)) = &app.message
        && at.elapsed().as_secs() < 10
    {
        lines.push(Line::styled(text.clone(), if *error { RED } else { GREEN }));
    } else {
        lines.push(Line::raw(""));
    }
    lines.push(Line::styled(
        "up/down select | s stop (OFF1)  c coast (OFF2)  x quick stop (OFF3): the selected drive, S C X: every drive | tab next bus | q quit",
        DIM,
    ));
    Paragraph::new(lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 47, item 5: at 80 columns the table dropped the address and state columns and
    /// clipped numbers. Columns get room in order of need, each whole.
    #[test]
    fn a_narrow_terminal_keeps_the_drive_its_state_and_control_whole() {
        let names = |w: u16| {
            fitting(w)
                .iter()
                .map(|&(c, _)| COLUMNS[c].0)
                .collect::<Vec<_>>()
        };
        // 80 columns less the borders and the selection mark.
        assert_eq!(
            names(76),
            [
                "addr",
                "online",
                "control",
                "state",
                "flags",
                "actual Hz",
                "set Hz"
            ]
        );
        let all: u16 = COLUMNS.iter().map(|c| c.1 + 1).sum();
        assert_eq!(names(all).len(), COLUMNS.len());
        assert_eq!(names(0), ["flags"]);
        // Narrower than the control's full width (issue 47's sweep: below 57 columns it was
        // dropped, a latched drive then showed nothing of its latch): narrowed, never dropped.
        for inside in [52, 40, 36, 31] {
            let fit = fitting(inside);
            let control = fit.iter().find(|&&(c, _)| c == CONTROL);
            assert!(
                control.is_some_and(|&(_, w)| w >= CONTROL_MIN),
                "{inside}: {fit:?}"
            );
            let used: u16 = fit.iter().map(|&(_, w)| w + 1).sum();
            assert!(used <= inside + 1, "{inside}: {fit:?}");
        }
    }
}
