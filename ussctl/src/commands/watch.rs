//! `watch`: the drives' images, one line per drive and round, until Ctrl-C or a count.

use crate::cli::address;
use crate::report::WatchLine;
use crate::{Failure, Output, catch_signals, stopped};
use core::time::Duration;
use std::time::Instant;
use uss_client::{Address, Bus, ClientError};

/// `watch`'s arguments.
#[derive(Debug, clap::Args)]
pub struct Watch {
    /// Only these drives (default: all).
    #[arg(value_parser = address)]
    drives: Vec<Address>,
    /// Milliseconds between rounds.
    #[arg(long, default_value_t = 500, value_name = "MS")]
    interval: u64,
    /// Stop after this many rounds.
    #[arg(long, value_name = "N")]
    count: Option<u64>,
}

impl Watch {
    pub(crate) fn run(&self, bus: &Bus, out: &Output) -> Result<(), Failure> {
        watch(bus, out, &self.drives, self.interval, self.count)
    }
}

fn watch(
    bus: &Bus,
    out: &Output,
    only: &[Address],
    interval_ms: u64,
    count: Option<u64>,
) -> Result<(), Failure> {
    let addresses = if only.is_empty() {
        bus.drives()
    } else {
        only.to_vec()
    };
    let watches = addresses
        .iter()
        .map(|&a| bus.watch(a))
        .collect::<Result<Vec<_>, _>>()?;
    catch_signals()?;
    let start = Instant::now();
    let interval = Duration::from_millis(interval_ms.max(1));
    let mut round = 0;
    // What keeps the bus from being watched now (ussd gone, stopped, its line down), said once
    // when it begins: watch goes on, as top does, and follows a restarted ussd.
    let mut away: Option<String> = None;
    while !stopped() && count.is_none_or(|n| round < n) {
        if round > 0 {
            sleep_unless_stopped(interval);
            if stopped() {
                break;
            }
        }
        let t = start.elapsed().as_secs_f64();
        let mut now_away = None;
        for w in &watches {
            // A stale picture is never shown as fresh: a drive whose poll is overdue (a stalled
            // bus thread) shows as stale; with ussd gone, stopped or its line down, every drive
            // shows offline with why, until ussd serves the bus again.
            let (image, state) = match w.read() {
                Ok(image) => (image, None),
                Err(ClientError::Stale { .. }) => (w.latest(), Some("stale")),
                Err(e @ ClientError::UssdGone { .. }) => {
                    now_away = Some(e.to_string());
                    (w.latest(), Some("ussd gone"))
                }
                Err(e @ ClientError::UssdStopped { .. }) => {
                    now_away = Some(e.to_string());
                    (w.latest(), Some("ussd stopped"))
                }
                Err(e @ ClientError::LineDown { .. }) => {
                    now_away = Some(e.to_string());
                    (w.latest(), Some("line down"))
                }
                Err(e) => return Err(e.into()),
            };
            let mut line = WatchLine::new(t, w.address(), &image, w.info().reference_hz);
            if let Some(state) = state {
                line.state = state;
                line.online &= state == "stale";
            }
            out.show(&line, WatchLine::human)?;
        }
        match (&away, now_away) {
            (None, Some(why)) => {
                eprintln!("ussctl: {why}: watching on until ussd serves the bus again");
                away = Some(why);
            }
            (Some(_), None) => {
                eprintln!("ussctl: ussd serves bus {} again", bus.name());
                away = None;
            }
            _ => {}
        }
        round += 1;
    }
    Ok(())
}

/// Sleeps `d` in small steps so Ctrl-C is noticed quickly.
fn sleep_unless_stopped(d: Duration) {
    let end = Instant::now() + d;
    while !stopped() {
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return;
        }
        std::thread::sleep(left.min(Duration::from_millis(20)));
    }
}
