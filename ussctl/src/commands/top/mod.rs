//! `top`: a live monitor of one or more buses (ratatui on crossterm). A status bar per bus (ussd
//! and its heartbeat, real-time mode obtained, cycle time, exchanges/s, efficiency, line), a
//! table of drives that marks what changed and what is wrong, a detail pane for the selected
//! drive (ussd's counters and timing, the drive's own USS counters r2024..r2031 and its fault
//! buffer), and keys for the safe operator stops, each confirmed first.
//!
//! It never shows a picture that is not true: while ussd is gone or stopped the last picture is
//! shown marked STALE; while no ussd serves a bus it says so and keeps trying to connect.

mod detail;
mod model;
mod view;

use crate::{Failure, catch_signals, stopped};
use core::time::Duration;
use model::Screen;
use ratatui::crossterm::event::{self, Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use std::io::IsTerminal as _;
use std::time::Instant;
use uss_client::{Address, StopCommand};

/// How often the screen's data is read.
const REFRESH: Duration = Duration::from_millis(200);
/// The longest the loop waits for a key.
const KEY_WAIT: Duration = Duration::from_millis(50);

/// A stop that waits for the operator's `y`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Pending {
    pub command: StopCommand,
    /// None: every drive of the bus.
    pub drive: Option<Address>,
}

impl Pending {
    /// The question asked before the stop is sent.
    pub(crate) fn question(self, bus: &str) -> String {
        let what = match self.command {
            StopCommand::Off1 => "Stop (OFF1, along the ramp)",
            StopCommand::Off2 => "Coast (OFF2, pulses off at once)",
            StopCommand::Off3 => "Quick-stop (OFF3, along the OFF3 ramp)",
        };
        let whom = self.drive.map_or_else(
            || format!("EVERY drive of bus {bus}"),
            |d| format!("drive {d}"),
        );
        format!(
            "{what} {whom}? It stays latched until its controller re-arms it.  y: yes, any other key: no"
        )
    }
}

/// What the monitor shows and remembers between frames.
pub(crate) struct App {
    pub screens: Vec<Screen>,
    /// The screen shown.
    pub current: usize,
    pub pending: Option<Pending>,
    /// The last action's outcome, and when.
    pub message: Option<(String, bool, Instant)>,
    pub details: detail::Reader,
}

impl App {
    fn screen(&mut self) -> &mut Screen {
        &mut self.screens[self.current]
    }

    /// Handles a key; false to quit.
    fn key(&mut self, key: KeyEvent) -> bool {
        if key.kind != KeyEventKind::Press {
            return true;
        }
        let ctrl_c =
            key.modifiers.contains(KeyModifiers::CONTROL) && key.code == KeyCode::Char('c');
        if ctrl_c {
            return false;
        }
        if let Some(pending) = self.pending.take() {
            if key.code == KeyCode::Char('y') {
                self.send(pending);
            } else {
                self.message = Some((
                    "cancelled: nothing was sent".to_owned(),
                    false,
                    Instant::now(),
                ));
            }
            return true;
        }
        let selected = self.screens[self.current].selected_drive();
        let ask = |command, all: bool| {
            Some(Pending {
                command,
                drive: if all { None } else { selected },
            })
            .filter(|p| p.drive.is_some() || all)
        };
        match key.code {
            KeyCode::Char('q') | KeyCode::Esc => return false,
            KeyCode::Up | KeyCode::Char('k') => self.screen().select(-1),
            KeyCode::Down | KeyCode::Char('j') => self.screen().select(1),
            KeyCode::Tab => self.current = (self.current + 1) % self.screens.len(),
            KeyCode::BackTab => {
                self.current = (self.current + self.screens.len() - 1) % self.screens.len();
            }
            KeyCode::Char('s') => self.pending = ask(StopCommand::Off1, false),
            KeyCode::Char('c') => self.pending = ask(StopCommand::Off2, false),
            KeyCode::Char('x') => self.pending = ask(StopCommand::Off3, false),
            KeyCode::Char('S') => self.pending = ask(StopCommand::Off1, true),
            KeyCode::Char('C') => self.pending = ask(StopCommand::Off2, true),
            KeyCode::Char('X') => self.pending = ask(StopCommand::Off3, true),
            _ => {}
        }
        true
    }

    /// Sends a confirmed stop through ussd's stop socket.
    fn send(&mut self, p: Pending) {
        let screen = &self.screens[self.current];
        let outcome = screen.stop(p);
        self.message = Some(match outcome {
            Ok(text) => (text, false, Instant::now()),
            Err(e) => (format!("NOT sent: {e}"), true, Instant::now()),
        });
    }
}

/// `top`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Top {
    /// More buses to monitor beside --bus; tab switches between them.
    buses: Vec<String>,
}

impl Top {
    /// Monitors `bus` (`--bus`) and the others named.
    pub(crate) fn run(&self, bus: &str) -> Result<(), Failure> {
        let mut all = vec![bus.to_owned()];
        all.extend(self.buses.iter().filter(|b| *b != bus).cloned());
        top(&all)
    }
}

fn top(buses: &[String]) -> Result<(), Failure> {
    if !std::io::stdout().is_terminal() {
        return Err(Failure::Usage(
            "top draws on a terminal; for a script use `ussctl status` or `ussctl --json status`"
                .to_owned(),
        ));
    }
    catch_signals()?;
    let mut app = App {
        screens: buses.iter().map(|b| Screen::new(b)).collect(),
        current: 0,
        pending: None,
        message: None,
        details: detail::Reader::start(),
    };
    let mut terminal = ratatui::try_init().map_err(Failure::Output)?;
    let outcome = run(&mut terminal, &mut app);
    ratatui::restore();
    outcome
}

/// What came on the terminal within a wait.
enum Keys {
    /// A key (or more) to read.
    Ready,
    /// Nothing, or a signal (the loop looks at it).
    Nothing,
    /// The terminal went away (hang-up: its window closed, its ssh connection lost).
    Gone,
}

/// Waits up to `wait` for input on the terminal `tty` with poll(2): crossterm's own wait spins
/// on a hung-up terminal and never returns, so `top` would outlive its terminal, deaf to
/// SIGTERM.
fn keys(tty: std::os::fd::BorrowedFd<'_>, wait: Duration) -> Keys {
    use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
    let ms = u16::try_from(wait.as_millis()).unwrap_or(u16::MAX);
    let mut fds = [PollFd::new(tty, PollFlags::POLLIN)];
    match poll(&mut fds, PollTimeout::from(ms)) {
        Ok(0) | Err(nix::errno::Errno::EINTR) => Keys::Nothing,
        Err(_) => Keys::Gone,
        Ok(_) => {
            let seen = fds[0].revents().unwrap_or(PollFlags::empty());
            if seen.intersects(PollFlags::POLLHUP | PollFlags::POLLERR | PollFlags::POLLNVAL) {
                Keys::Gone
            } else {
                Keys::Ready
            }
        }
    }
}

fn run(terminal: &mut ratatui::DefaultTerminal, app: &mut App) -> Result<(), Failure> {
    use std::os::fd::AsFd as _;
    // The terminal crossterm reads keys from: standard input where it is one, else /dev/tty.
    let dev_tty;
    let stdin = std::io::stdin();
    let tty = if stdin.is_terminal() {
        stdin.as_fd()
    } else {
        dev_tty = std::fs::File::open("/dev/tty").map_err(Failure::Output)?;
        dev_tty.as_fd()
    };
    let mut next_refresh = Instant::now();
    while !stopped() {
        if Instant::now() >= next_refresh {
            for (i, screen) in app.screens.iter_mut().enumerate() {
                // Only the screen shown asks the drive for its own counters.
                screen.refresh(&app.details, i == app.current);
            }
            next_refresh = Instant::now() + REFRESH;
        }
        terminal
            .draw(|frame| view::draw(frame, app))
            .map_err(Failure::Output)?;
        let ready = match keys(tty, KEY_WAIT) {
            Keys::Gone => break,
            Keys::Nothing => false,
            Keys::Ready => event::poll(Duration::ZERO).map_err(Failure::Output)?,
        };
        if ready {
            // A resize needs nothing but the next frame, drawn at once.
            if let Event::Key(key) = event::read().map_err(Failure::Output)?
                && !app.key(key)
            {
                break;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn press(app: &mut App, c: KeyCode) -> bool {
        app.key(KeyEvent::new(c, KeyModifiers::NONE))
    }

    #[test]
    fn a_stop_is_sent_only_after_y_and_never_without_a_drive() {
        let mut app = App {
            screens: vec![Screen::new("top-unit-a"), Screen::new("top-unit-b")],
            current: 0,
            pending: None,
            message: None,
            details: detail::Reader::start(),
        };
        // No drive shown yet: a stop of "the selected drive" is not even asked.
        assert!(press(&mut app, KeyCode::Char('s')));
        assert_eq!(app.pending, None);
        // Every drive can always be asked for.
        assert!(press(&mut app, KeyCode::Char('X')));
        let pending = app.pending.unwrap();
        assert_eq!((pending.command, pending.drive), (StopCommand::Off3, None));
        assert!(
            pending.question("top-unit-a").starts_with(
                "Quick-stop (OFF3, along the OFF3 ramp) EVERY drive of bus top-unit-a?"
            )
        );
        // Any key but y cancels, and is not taken as a command of its own.
        assert!(press(&mut app, KeyCode::Char('q')));
        assert_eq!(app.pending, None);
        assert_eq!(
            app.message.as_ref().unwrap().0,
            "cancelled: nothing was sent"
        );
        // y sends: with no ussd, it says it was not sent.
        press(&mut app, KeyCode::Char('S'));
        press(&mut app, KeyCode::Char('y'));
        let (text, error, _) = app.message.as_ref().unwrap();
        assert!(*error);
        assert_eq!(text, "NOT sent: no ussd serves bus top-unit-a");
        // Tab goes round the buses; q and Ctrl-C quit.
        press(&mut app, KeyCode::Tab);
        assert_eq!(app.current, 1);
        press(&mut app, KeyCode::Tab);
        assert_eq!(app.current, 0);
        press(&mut app, KeyCode::BackTab);
        assert_eq!(app.current, 1);
        assert!(!press(&mut app, KeyCode::Char('q')));
        assert!(!app.key(KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL)));
    }
}
