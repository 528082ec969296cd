//! How often ussd expects to poll each drive now, and after how long a drive's image is stale:
//! the times every client waits by (one poll for a re-arm, a stop's confirmation) instead of
//! fixed ones. A full line at the drives' factory baud rate (31 drives at 9600 baud) polls each
//! drive only every 1.3 s; a client that waited a fixed second could not control any of them.
//!
//! The period of a drive is the circulating list's cycle time (measured, smoothed; before the
//! first cycle the worst case of the list at the bus's baud rate) over the drive's entries in
//! the list, doubled with `param_priority` (an extra poll may follow each regular one); an
//! offline drive's is its probe interval. Its image is stale once it is older than two periods
//! and the time one poll may take with all its retries (at least 100 ms).

use core::time::Duration;

/// The least age at which an image is stale: a fast bus's own limit (a few ms) would call a
/// scheduling hiccup of a machine without real-time priority a stale drive.
pub const MIN_STALE_AFTER: Duration = Duration::from_millis(100);

/// The poll periods of a bus's drives. No allocation after construction.
#[derive(Debug, Clone)]
pub struct Periods {
    /// The smoothed cycle time.
    cycle: Duration,
    /// Whether a cycle was measured yet.
    measured: bool,
    /// Entries of each drive (by slot) in the circulating list.
    entries: Vec<u32>,
    /// 2 with `param_priority`, else 1.
    factor: u32,
    /// The longest one poll takes: every attempt timing out.
    poll: Duration,
    /// How often an offline drive is probed.
    probe: Duration,
    /// A fixed cycle time, when configured: no cycle is shorter.
    fixed: Option<Duration>,
    /// The worst case of one attempt.
    attempt: Duration,
    /// Entries in the circulating list.
    list_len: u32,
}

/// What [`Periods`] needs of a bus.
#[derive(Debug, Clone, Copy)]
pub struct PeriodSetup {
    /// The worst case of one attempt at the bus's baud rate (USS.md section 4).
    pub attempt: Duration,
    pub retries: u8,
    pub probe: Duration,
    pub param_priority: bool,
    pub fixed_cycle: Option<Duration>,
}

impl Periods {
    /// The periods of the drives of circulating list `list` (slots), `drives` of them.
    pub fn new(list: &[u8], drives: usize, setup: PeriodSetup) -> Self {
        let mut entries = vec![0u32; drives];
        for &slot in list {
            if let Some(e) = entries.get_mut(usize::from(slot)) {
                *e += 1;
            }
        }
        let poll = setup.attempt * (u32::from(setup.retries) + 1);
        let guess = setup.attempt * u32::try_from(list.len()).unwrap_or(u32::MAX);
        Self {
            cycle: setup.fixed_cycle.map_or(guess, |f| f.max(guess)),
            measured: false,
            entries,
            factor: if setup.param_priority { 2 } else { 1 },
            poll,
            probe: setup.probe,
            fixed: setup.fixed_cycle,
            attempt: setup.attempt,
            list_len: u32::try_from(list.len()).unwrap_or(u32::MAX),
        }
    }

    /// A new worst case of one attempt (the line came back on a device with another receive
    /// latency).
    pub fn set_attempt(&mut self, attempt: Duration) {
        let tries = (self.poll.as_nanos() / self.attempt.as_nanos().max(1)).max(1);
        self.poll = attempt * u32::try_from(tries).unwrap_or(1);
        self.attempt = attempt;
        if !self.measured {
            // Still the guess from the worst attempt (no cycle measured yet).
            let guess = attempt * self.list_len;
            self.cycle = self.fixed.map_or(guess, |f| f.max(guess));
        }
    }

    /// The shortest telegram-off time (P2014) that does not trip drive `slot` between two of
    /// its polls: the longest time between them with every exchange of the circulating list at
    /// its worst case (doubled by `param_priority`, at least a fixed cycle time); rounded up to
    /// 10 ms. Failed attempts (retries) stretch it further: then the drive's trip is its
    /// monitoring doing its work.
    pub fn shortest_monitoring(&self, slot: usize) -> Duration {
        let entries = self.entries.get(slot).copied().unwrap_or(1).max(1);
        let cycle = (self.attempt * self.list_len).max(self.fixed.unwrap_or_default());
        let worst = cycle * self.factor / entries;
        let step = Duration::from_millis(10);
        let steps = worst.as_nanos().div_ceil(step.as_nanos());
        step * u32::try_from(steps).unwrap_or(u32::MAX)
    }

    /// A pass through the circulating list took `took` (before any fixed-cycle wait).
    pub fn cycle_done(&mut self, took: Duration) {
        let took = self.fixed.map_or(took, |f| took.max(f));
        self.cycle = if self.measured {
            // A quarter of each new cycle: smooth, yet a slower bus shows within a few cycles.
            (self.cycle * 3 + took) / 4
        } else {
            took
        };
        self.measured = true;
    }

    /// How often drive `slot` is polled now (`online`: in the circulating list; offline: probed).
    pub fn period(&self, slot: usize, online: bool) -> Duration {
        if !online {
            return self.probe.max(self.cycle);
        }
        let entries = self.entries.get(slot).copied().unwrap_or(1).max(1);
        self.cycle * self.factor / entries
    }

    /// After how long drive `slot`'s image is stale: two periods and one poll with its retries,
    /// at least [`MIN_STALE_AFTER`].
    pub fn stale_after(&self, slot: usize, online: bool) -> Duration {
        (self.period(slot, online) * 2 + self.poll).max(MIN_STALE_AFTER)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn setup() -> PeriodSetup {
        PeriodSetup {
            attempt: ms(60),
            retries: 2,
            probe: ms(500),
            param_priority: false,
            fixed_cycle: None,
        }
    }

    #[test]
    fn a_drive_twice_in_the_list_is_polled_twice_as_often() {
        // Drive 0 weight 2, drives 1 and 2 weight 1: list 0 1 0 2.
        let mut p = Periods::new(&[0, 1, 0, 2], 3, setup());
        assert_eq!(
            p.period(1, true),
            ms(240),
            "before a cycle: the worst case of 4 attempts"
        );
        p.cycle_done(ms(100));
        assert_eq!((p.period(0, true), p.period(1, true)), (ms(50), ms(100)));
        assert_eq!(p.stale_after(1, true), ms(200 + 180));
        assert_eq!(p.period(1, false), ms(500), "offline: its probes");
    }

    #[test]
    fn the_cycle_is_smoothed_and_never_below_a_fixed_cycle_time() {
        let mut p = Periods::new(&[0, 1], 2, setup());
        p.cycle_done(ms(100));
        p.cycle_done(ms(200));
        assert_eq!(p.period(0, true), ms(125));
        let mut fixed = Periods::new(
            &[0, 1],
            2,
            PeriodSetup {
                fixed_cycle: Some(ms(300)),
                param_priority: true,
                ..setup()
            },
        );
        fixed.cycle_done(ms(100));
        assert_eq!(
            fixed.period(0, true),
            ms(600),
            "300 ms cycles, doubled by param_priority"
        );
    }

    #[test]
    fn the_shortest_safe_telegram_off_time_covers_the_worst_cycle_and_a_poll() {
        let list: Vec<u8> = (0..31).collect();
        let p = Periods::new(&list, 31, setup());
        // 31 attempts of 60 ms.
        assert_eq!(p.shortest_monitoring(5), ms(1860));
        let weighted = Periods::new(&[0, 1, 0, 2], 3, setup());
        assert_eq!(weighted.shortest_monitoring(0), ms(120));
        assert_eq!(weighted.shortest_monitoring(1), ms(240));
    }

    #[test]
    fn thirty_one_drives_at_9600_baud_are_polled_every_1_3_s() {
        // 42.6 ms per exchange (PKW 4 + PZD 2 at 9600 baud, as measured on such a line).
        let list: Vec<u8> = (0..31).collect();
        let mut p = Periods::new(&list, 31, setup());
        p.cycle_done(Duration::from_micros(42_600 * 31));
        let period = p.period(19, true);
        assert!(period > ms(1300) && period < ms(1330), "{period:?}");
    }
}
