//! ussd under a service manager: systemd's `Type=notify` protocol (`sd_notify(3)`, through the
//! `sd-notify` crate) and the check that every bus thread still makes progress.
//!
//! ussd says `READY=1` once every bus thread runs, `STOPPING=1` when it stops, and, when the
//! unit sets `WatchdogSec=`, `WATCHDOG=1` every half watchdog period, but only while no bus
//! thread hangs: a bus thread whose progress counter ([`uss_engine::EngineHandle::progress`])
//! has not moved for its [`stall_bound`] is hung (stuck in a system call of a wedged serial
//! driver, or a bug), and without keep-alives systemd kills and restarts ussd. The drives of a
//! hung bus are not polled: their own telegram monitoring (P2014) stops them meanwhile.
//! Without a service manager (no `NOTIFY_SOCKET`) nothing is sent, and a hung bus thread is
//! still logged.

use crate::config::BusConfig;
use core::time::Duration;
use sd_notify::NotifyState;
use std::time::Instant;
use uss_protocol::Timing;
use uss_protocol::telegram::MAX_NET_BYTES;

/// How long a bus thread may go without progress before it counts as hung: twice its longest
/// single step (one attempt: a request and a reply of the longest telegram, the response
/// timeout and its margin, two start pauses; on a serial line also the longest a write may wait
/// before it counts as a line failure, which the line thread then reopens), at least one
/// second. Idle waits are cut into steps of [`uss_engine::IDLE_STEP`], so they never come
/// near it.
pub fn stall_bound(bus: &BusConfig) -> Duration {
    let timing = Timing::new(bus.baud);
    let write_stall = bus.device.write_stall(timing);
    let attempt = timing.telegram(MAX_NET_BYTES) * 2
        + timing.start_pause() * 2
        + bus.response_timeout_ms.get()
        + bus.timeout_margin_ms.get()
        + write_stall;
    (attempt * 2).max(Duration::from_secs(1))
}

/// What the progress check found for one bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    /// Its thread made no progress for `for_`, past its bound: it hangs.
    Hung { bus: usize, for_: Duration },
    /// Its thread moves again after hanging for `for_`.
    Moving { bus: usize, for_: Duration },
    /// Its line has been down for `for_`, past its `line_down_limit_ms`.
    LineDownTooLong { bus: usize, for_: Duration },
}

/// The progress of every bus thread, as last seen.
#[derive(Debug)]
pub struct Progress {
    buses: Vec<Seen>,
}

#[derive(Debug)]
struct Seen {
    count: u64,
    since: Instant,
    bound: Duration,
    hung: bool,
    /// How long its line may stay down (`None`: for ever), and since when it is.
    line_limit: Option<Duration>,
    down_since: Option<Instant>,
    down_too_long: bool,
}

impl Progress {
    /// Starts watching buses whose stall bounds are `bounds` and line-down limits
    /// `line_limits`, their counters at `counts`.
    pub fn new(
        bounds: &[Duration],
        line_limits: &[Option<Duration>],
        counts: &[u64],
        now: Instant,
    ) -> Self {
        let buses = bounds
            .iter()
            .zip(line_limits)
            .zip(counts)
            .map(|((&bound, &line_limit), &count)| Seen {
                count,
                since: now,
                bound,
                hung: false,
                line_limit,
                down_since: None,
                down_too_long: false,
            })
            .collect();
        Self { buses }
    }

    /// Looks at the counters `counts` and whether each line is down (`down`, one per bus, in
    /// the order of [`Progress::new`]) at `now`; returns what changed since the last look.
    pub fn check(&mut self, counts: &[u64], down: &[bool], now: Instant) -> Vec<Change> {
        let mut changes = Vec::new();
        for (bus, (seen, &is_down)) in self.buses.iter_mut().zip(down).enumerate() {
            if !is_down {
                seen.down_since = None;
                seen.down_too_long = false;
                continue;
            }
            let since = *seen.down_since.get_or_insert(now);
            let for_ = now.saturating_duration_since(since);
            if !seen.down_too_long && seen.line_limit.is_some_and(|limit| for_ >= limit) {
                seen.down_too_long = true;
                changes.push(Change::LineDownTooLong { bus, for_ });
            }
        }
        for (bus, (seen, &count)) in self.buses.iter_mut().zip(counts).enumerate() {
            let for_ = now.saturating_duration_since(seen.since);
            if count != seen.count {
                if seen.hung {
                    changes.push(Change::Moving { bus, for_ });
                }
                seen.count = count;
                seen.since = now;
                seen.hung = false;
            } else if !seen.hung && for_ >= seen.bound {
                seen.hung = true;
                changes.push(Change::Hung { bus, for_ });
            }
        }
        changes
    }

    /// Whether every bus thread makes progress (none hangs).
    pub fn all_moving(&self) -> bool {
        self.buses.iter().all(|b| !b.hung)
    }

    /// Whether ussd is healthy: every bus thread makes progress and no line has been down past
    /// its limit. An unhealthy ussd withholds systemd's watchdog keep-alive, so systemd
    /// restarts it.
    pub fn healthy(&self) -> bool {
        self.buses.iter().all(|b| !b.hung && !b.down_too_long)
    }
}

/// The service manager's side: `READY`, `STATUS`, watchdog keep-alives, `STOPPING`. Does
/// nothing without `NOTIFY_SOCKET`.
#[derive(Debug)]
pub struct Notifier {
    /// Half the watchdog period systemd asked for (`WATCHDOG_USEC`), if it did.
    keep_alive_every: Option<Duration>,
    next_keep_alive: Instant,
    keep_alives: u64,
}

impl Notifier {
    /// Reads what the service manager asked for from the environment.
    pub fn from_env(now: Instant) -> Self {
        Self {
            keep_alive_every: sd_notify::watchdog_enabled().map(|d| d / 2),
            next_keep_alive: now,
            keep_alives: 0,
        }
    }

    /// The watchdog period systemd asked for, if any.
    pub fn watchdog(&self) -> Option<Duration> {
        self.keep_alive_every.map(|d| d * 2)
    }

    /// Every bus thread runs: `READY=1` with a status line.
    pub fn ready(&self, status: &str) {
        send(&[NotifyState::Ready, NotifyState::Status(status)]);
    }

    /// A new status line (`systemctl status` shows it).
    pub fn status(&self, status: &str) {
        send(&[NotifyState::Status(status)]);
    }

    /// Sends `WATCHDOG=1` when one is due and `healthy`; an unhealthy ussd sends none, so
    /// systemd restarts it after `WatchdogSec`.
    pub fn keep_alive(&mut self, now: Instant, healthy: bool) {
        let Some(every) = self.keep_alive_every else {
            return;
        };
        if !healthy || now < self.next_keep_alive {
            return;
        }
        send(&[NotifyState::Watchdog]);
        self.keep_alives += 1;
        self.next_keep_alive = now + every;
    }

    /// `STOPPING=1` with a status line.
    pub fn stopping(&self, status: &str) {
        send(&[NotifyState::Stopping, NotifyState::Status(status)]);
    }
}

/// Sends to the service manager; a failure is logged once per process, not fatal (ussd polls
/// on without one).
fn send(states: &[NotifyState<'_>]) {
    static WARNED: std::sync::Once = std::sync::Once::new();
    if let Err(e) = sd_notify::notify(states) {
        WARNED.call_once(|| {
            tracing::warn!("cannot notify the service manager (NOTIFY_SOCKET): {e}");
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Device;

    const MS: Duration = Duration::from_millis(1);

    #[test]
    fn a_counter_that_stops_past_its_bound_is_hung_and_reported_once_until_it_moves() {
        let t0 = Instant::now();
        let bounds = [1000 * MS, 2000 * MS];
        let mut p = Progress::new(&bounds, &[None, None], &[5, 7], t0);
        let check = |p: &mut Progress, counts: &[u64], at| p.check(counts, &[false, false], at);
        assert_eq!(check(&mut p, &[6, 7], t0 + 900 * MS), []);
        assert!(p.all_moving());
        // Bus 1 has not moved since t0: hung at its 2 s bound, not before.
        assert_eq!(check(&mut p, &[7, 7], t0 + 1900 * MS), []);
        assert_eq!(
            check(&mut p, &[8, 7], t0 + 2000 * MS),
            [Change::Hung {
                bus: 1,
                for_: 2000 * MS
            }]
        );
        assert!(!p.all_moving());
        assert_eq!(check(&mut p, &[9, 7], t0 + 5000 * MS), [], "reported once");
        assert!(!p.all_moving());
        assert_eq!(
            check(&mut p, &[10, 8], t0 + 5500 * MS),
            [Change::Moving {
                bus: 1,
                for_: 5500 * MS
            }]
        );
        assert!(p.all_moving());
        // Bus 0 last moved at t0 + 5.5 s: hung 1 s later.
        assert_eq!(check(&mut p, &[10, 9], t0 + 6400 * MS), []);
        assert_eq!(
            check(&mut p, &[10, 10], t0 + 6500 * MS),
            [Change::Hung {
                bus: 0,
                for_: 1000 * MS
            }]
        );
    }

    #[test]
    fn a_line_down_past_its_limit_makes_ussd_unhealthy_until_it_is_back() {
        let t0 = Instant::now();
        let limits = [Some(30_000 * MS), None];
        let mut p = Progress::new(&[1000 * MS, 1000 * MS], &limits, &[0, 0], t0);
        // Both lines go down at t0 + 1 s; the threads keep moving (they wait for the reopen).
        assert_eq!(p.check(&[1, 1], &[true, true], t0 + 1000 * MS), []);
        assert_eq!(p.check(&[2, 2], &[true, true], t0 + 30_900 * MS), []);
        assert!(p.healthy());
        assert_eq!(
            p.check(&[3, 3], &[true, true], t0 + 31_000 * MS),
            [Change::LineDownTooLong {
                bus: 0,
                for_: 30_000 * MS
            }]
        );
        assert!(!p.healthy());
        assert!(p.all_moving(), "not a hang");
        assert_eq!(
            p.check(&[4, 4], &[true, true], t0 + 90_000 * MS),
            [],
            "once"
        );
        // Bus 1 has no limit: down for ever is never unhealthy. Bus 0 back: healthy again, and
        // a new outage counts from its own start.
        assert_eq!(p.check(&[5, 5], &[false, true], t0 + 91_000 * MS), []);
        assert!(p.healthy());
        assert_eq!(p.check(&[6, 6], &[true, true], t0 + 92_000 * MS), []);
        assert_eq!(p.check(&[7, 7], &[true, true], t0 + 121_000 * MS), []);
        assert!(p.healthy());
    }

    #[test]
    fn the_stall_bound_covers_the_longest_attempt_and_is_at_least_a_second() {
        let bus = |baud: u32| {
            let toml = format!(
                "[[bus]]\nname = \"b\"\ndevice = \"/dev/ttyUSB0\"\nbaud = {baud}\n\n[[bus.drive]]\naddress = 1\n"
            );
            let bus = crate::config::Config::parse(&toml, "test")
                .unwrap()
                .buses
                .remove(0);
            BusConfig {
                device: Device::Sim,
                ..bus
            }
        };
        assert_eq!(stall_bound(&bus(115_200)), Duration::from_secs(1));
        // At 1200 baud one telegram of 252 net characters takes 2.3 s on the wire.
        let slow = bus(1200);
        let timing = Timing::new(slow.baud);
        assert!(stall_bound(&slow) > timing.telegram(MAX_NET_BYTES) * 4);
        // On a serial line a write stuck for its whole allowance is a line failure, not a
        // hang: the bound covers it.
        let serial = BusConfig {
            device: Device::Serial("/dev/ttyUSB0".into()),
            ..bus(9600)
        };
        let write_stall = uss_serial::write_stall(Timing::new(serial.baud));
        assert!(stall_bound(&serial) > write_stall * 2, "{write_stall:?}");
    }

    #[test]
    fn without_a_service_manager_nothing_is_due() {
        let n = Notifier {
            keep_alive_every: None,
            next_keep_alive: Instant::now(),
            keep_alives: 0,
        };
        assert_eq!(n.watchdog(), None);
    }
}
