//! The turn scheduling as pure state, tested as tables: which drive goes next out of turn
//! ([`Turns`]) and whether the engine ran without a gap between two looks ([`Continuity`]).
//! The engine's looks (`engine::turns`) feed them what they saw; nothing here reads a clock or
//! touches the line.
//!
//! The rules (`engine::turns` has the why): a drive whose words became a stronger stop than
//! its last telegram carried is due out of turn; so is a drive a re-arm made live, once between
//! two of its regular polls; a drive is no longer due once a telegram carries its words; the
//! drives that did not hear a broadcast stop go before those that did; the drive whose poll is
//! in progress is not picked (its next attempt carries its new words); out-of-turn polls never
//! nest.

use core::time::Duration;

/// Drives due a poll out of turn, a bit per slot (at most 32 drives on a line).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Turns {
    /// Due a poll out of turn.
    due: u32,
    /// Had their out-of-turn re-arm since their last regular poll.
    rearm_spent: u32,
    /// Heard a stop in a broadcast and are due their own poll to confirm it, after the drives
    /// that did not hear it.
    heard: u32,
    /// Within an out-of-turn poll.
    serving: bool,
}

const fn bit(slot: usize) -> u32 {
    if slot < 32 { 1 << slot } else { 0 }
}

impl Turns {
    /// Nobody due.
    pub const NONE: Self = Self {
        due: 0,
        rearm_spent: 0,
        heard: 0,
        serving: false,
    };

    /// What a look saw of drive `slot`: whether its words are now a stronger stop than its last
    /// telegram carried, and whether a re-arm made it live just now.
    pub fn looked(&mut self, slot: usize, stronger_stop: bool, rearmed: bool) {
        let b = bit(slot);
        if stronger_stop {
            self.due |= b;
        }
        if rearmed && self.rearm_spent & b == 0 {
            self.due |= b;
            self.rearm_spent |= b;
        }
    }

    /// A broadcast stop reached the drives of `group` (a bit per slot).
    pub fn heard(&mut self, group: u32) {
        self.heard |= group;
    }

    /// A telegram carries drive `slot`'s words now: it is no longer due.
    pub fn sent(&mut self, slot: usize) {
        self.due &= !bit(slot);
        self.heard &= !bit(slot);
    }

    /// Drive `slot`'s regular poll begins: a re-arm may take it out of turn once again.
    pub fn regular_poll(&mut self, slot: usize) {
        self.rearm_spent &= !bit(slot);
    }

    /// The drive to poll out of turn now, if any, but `except` (the drive whose poll is in
    /// progress): the drives that did not hear a broadcast stop first, the lowest slot first.
    pub fn next(&self, except: Option<usize>) -> Option<usize> {
        let due = self.due & !except.map_or(0, bit);
        let unheard = due & !self.heard;
        let pick = if unheard != 0 { unheard } else { due };
        (pick != 0).then(|| pick.trailing_zeros() as usize)
    }

    /// Whether drive `slot` is due out of turn.
    pub const fn is_due(&self, slot: usize) -> bool {
        self.due & bit(slot) != 0
    }

    /// Whether an out-of-turn poll is in progress.
    pub const fn serving(&self) -> bool {
        self.serving
    }

    /// An out-of-turn poll begins: `false` within one already (they never nest).
    pub fn begin_out_of_turn(&mut self) -> bool {
        !core::mem::replace(&mut self.serving, true)
    }

    /// The out-of-turn poll [`Turns::begin_out_of_turn`] began has ended.
    pub fn end_out_of_turn(&mut self) {
        self.serving = false;
    }
}

/// The engine's own continuity: the time between two looks beyond what the work between them
/// explains (one attempt at worst and one idle step, [`Continuity::lag`]) is a gap: ussd paused
/// by SIGSTOP, a suspended machine, a starved CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Continuity {
    last_look: Duration,
    lag: Duration,
    /// The gaps judged since [`Continuity::take_stall`].
    stall: Duration,
}

impl Continuity {
    /// Looks begin at `now`; two looks up to `lag` apart are no gap.
    pub const fn new(now: Duration, lag: Duration) -> Self {
        Self {
            last_look: now,
            lag,
            stall: Duration::ZERO,
        }
    }

    /// A look at `now`: the gap since the one before (zero when none).
    pub fn look(&mut self, now: Duration) -> Duration {
        let gap = now.saturating_sub(self.last_look).saturating_sub(self.lag);
        self.last_look = now;
        self.stall += gap;
        gap
    }

    /// Whether a look at `now` would find a gap (a reply wait that straddled a pause: looked at
    /// at once, so the exchange's image says so).
    pub fn overdue(&self, now: Duration) -> bool {
        now.saturating_sub(self.last_look) > self.lag
    }

    /// Looks start again at `now`, with `lag` (a line back, whose latency may differ): the time
    /// it was down is no gap of the engine's.
    pub fn restart(&mut self, now: Duration, lag: Duration) {
        self.last_look = now;
        self.lag = lag;
    }

    /// What two looks may be apart.
    pub const fn lag(&self) -> Duration {
        self.lag
    }

    /// The gaps judged since the last call (left out of the cycle time the poll periods learn
    /// from, so a pause does not stretch every drive's freshness limit).
    pub fn take_stall(&mut self) -> Duration {
        core::mem::take(&mut self.stall)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// One thing that happens to the schedule.
    #[derive(Debug, Clone, Copy)]
    enum Step {
        /// A look at a drive: stronger stop, re-armed.
        Looked(usize, bool, bool),
        Heard(u32),
        Sent(usize),
        Regular(usize),
    }
    use Step::{Heard, Looked, Regular, Sent};

    /// Each row: the steps from nothing due, then `next(None)`, `next(Some(0))`.
    #[test]
    fn the_next_drive_out_of_turn_as_a_table() {
        let rows: &[(&[Step], Option<usize>, Option<usize>)] = &[
            (&[], None, None),
            // A stronger stop is due; the drive in progress is not picked.
            (&[Looked(0, true, false)], Some(0), None),
            (&[Looked(3, true, false)], Some(3), Some(3)),
            // The lowest slot first.
            (
                &[Looked(5, true, false), Looked(2, true, false)],
                Some(2),
                Some(2),
            ),
            // Sent: no longer due.
            (&[Looked(2, true, false), Sent(2)], None, None),
            // A look that sees no stronger stop keeps what was due.
            (
                &[Looked(2, true, false), Looked(2, false, false)],
                Some(2),
                Some(2),
            ),
            // A re-arm once between two regular polls ...
            (&[Looked(1, false, true)], Some(1), Some(1)),
            (
                &[Looked(1, false, true), Sent(1), Looked(1, false, true)],
                None,
                None,
            ),
            // ... and again after its regular poll.
            (
                &[
                    Looked(1, false, true),
                    Sent(1),
                    Regular(1),
                    Looked(1, false, true),
                ],
                Some(1),
                Some(1),
            ),
            // A stronger stop is due however often (stops only grow stronger between polls).
            (
                &[Looked(1, false, true), Sent(1), Looked(1, true, false)],
                Some(1),
                Some(1),
            ),
            // The drives that did not hear a broadcast stop go first.
            (
                &[
                    Heard(0b0011),
                    Looked(0, true, false),
                    Looked(1, true, false),
                    Looked(4, true, false),
                ],
                Some(4),
                Some(4),
            ),
            (
                &[
                    Heard(0b0011),
                    Looked(0, true, false),
                    Looked(1, true, false),
                    Looked(4, true, false),
                    Sent(4),
                ],
                Some(0),
                Some(1),
            ),
            // Heard and then sent: heard no more.
            (
                &[
                    Heard(0b0001),
                    Sent(0),
                    Looked(0, true, false),
                    Looked(2, true, false),
                ],
                Some(0),
                Some(2),
            ),
            // A slot beyond a line's 32 is nobody.
            (&[Looked(40, true, true)], None, None),
        ];
        for (steps, next, but_0) in rows {
            let mut t = Turns::NONE;
            for &s in *steps {
                apply(&mut t, s);
            }
            assert_eq!(
                (t.next(None), t.next(Some(0))),
                (*next, *but_0),
                "{steps:?}"
            );
        }
    }

    fn apply(t: &mut Turns, s: Step) {
        match s {
            Looked(slot, stronger, rearmed) => t.looked(slot, stronger, rearmed),
            Heard(group) => t.heard(group),
            Sent(slot) => t.sent(slot),
            Regular(slot) => t.regular_poll(slot),
        }
    }

    #[test]
    fn out_of_turn_polls_never_nest() {
        let mut t = Turns::NONE;
        assert!(!t.serving() && t.begin_out_of_turn() && t.serving());
        assert!(!t.begin_out_of_turn());
        t.end_out_of_turn();
        assert!(!t.serving() && t.begin_out_of_turn());
    }

    /// Each row: looks at these times (lag 10), then the gaps they found and the stall taken.
    #[test]
    fn gaps_between_looks_as_a_table() {
        let ms = Duration::from_millis;
        let rows: &[(&[u64], &[u64], u64)] = &[
            (&[], &[], 0),
            (&[5, 15, 25], &[0, 0, 0], 0),
            (&[10], &[0], 0),
            (&[11], &[1], 1),
            (&[30, 35, 100], &[20, 0, 55], 75),
            // A look back in time (a clock that cannot run back) is no gap.
            (&[30, 20], &[20, 0], 20),
        ];
        for (looks, gaps, stall) in rows {
            let mut c = Continuity::new(Duration::ZERO, ms(10));
            let found: Vec<u64> = looks
                .iter()
                .map(|&t| u64::try_from(c.look(ms(t)).as_millis()).unwrap_or(u64::MAX))
                .collect();
            assert_eq!(
                (found.as_slice(), c.take_stall()),
                (*gaps, ms(*stall)),
                "{looks:?}"
            );
            assert_eq!(c.take_stall(), Duration::ZERO);
        }
        let mut c = Continuity::new(Duration::ZERO, ms(10));
        assert!(!c.overdue(ms(10)) && c.overdue(ms(11)));
        // A line back: the time it was down is no gap, and the new lag counts.
        c.restart(ms(500), ms(40));
        assert_eq!(
            (c.look(ms(540)), c.look(ms(581)), c.lag()),
            (ms(0), ms(1), ms(40))
        );
    }

    fn step() -> impl Strategy<Value = Step> {
        prop_oneof![
            (0usize..6, any::<bool>(), any::<bool>()).prop_map(|(s, a, b)| Looked(s, a, b)),
            (0u32..64).prop_map(Heard),
            (0usize..6).prop_map(Sent),
            (0usize..6).prop_map(Regular),
        ]
    }

    proptest! {
        /// Whatever happens: the drive picked is due and not the one excepted; a due drive stays
        /// due until a telegram carries its words; a re-arm takes a drive out of turn at most
        /// once between two of its regular polls (the bound on what a flipping controller
        /// costs the others).
        #[test]
        fn the_schedule_keeps_its_rules(steps in proptest::collection::vec(step(), 0..60)) {
            let mut t = Turns::NONE;
            let mut rearms = [0u32; 6];
            for s in steps {
                let before = t;
                apply(&mut t, s);
                for slot in 0..6 {
                    let kept = !before.is_due(slot) || t.is_due(slot);
                    prop_assert!(kept || matches!(s, Sent(x) if x == slot), "{s:?} {slot}");
                }
                match s {
                    Looked(slot, false, true) if !before.is_due(slot) && t.is_due(slot) => {
                        rearms[slot] += 1;
                    }
                    Regular(slot) => rearms[slot] = 0,
                    _ => {}
                }
                prop_assert!(rearms.iter().all(|&n| n <= 1), "{rearms:?}");
                for except in [None, Some(0), Some(3)] {
                    if let Some(slot) = t.next(except) {
                        prop_assert!(t.is_due(slot) && Some(slot) != except);
                    } else {
                        prop_assert!((0..6).all(|s| !t.is_due(s) || Some(s) == except));
                    }
                }
            }
        }
    }
}
