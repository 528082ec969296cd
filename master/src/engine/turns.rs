//! Safety telegrams jump the queue (issue 21): a stop or a trip must not wait for its drive's
//! turn in the circulating list, which on 31 drives at 9600 baud comes every 1.3 s.
//!
//! Before every telegram (and every millisecond of an idle wait) the engine looks at every
//! drive ([`Engine::look`]): it takes the drive's newest sample and operator command and lets
//! the drive's gate judge them and the watchdog at this moment. A drive whose words became a
//! stronger stop than the last telegram it got carried (an operator's stop, a watchdog trip, a
//! release, a refused sample, the controller's own stop) is polled next, out of turn, after the
//! exchange in progress; so is a drive a re-arm made live, once between two of its regular
//! polls. Out-of-turn polls are ordinary polls (PKW job, retries, image) that do not move the
//! circulating list on.
//!
//! Bounds. A stop or a trip reaches its drive in the telegram after the one on the wire when it
//! came: one exchange, whatever the bus size (a drive that does not answer gets its retries
//! only after the drives due out of turn). Starvation: between two of its regular polls a
//! drive's words can only grow stronger (none, OFF1, OFF3, OFF2) a bounded number of times, and
//! weaken again only by a regular poll or its one out-of-turn re-arm; so each drive takes at
//! most a few polls out of turn per cycle, and a controller that flips its drive as fast as it
//! can (run, release, re-arm) takes at most one extra poll per regular poll: the other drives'
//! poll period at most doubles.
//!
//! A look also measures the engine's own continuity: the time since the previous look beyond
//! what one attempt and one idle step explain is a gap (ussd paused by SIGSTOP, a suspended
//! machine, a starved CPU), and a gap longer than a drive's watchdog time latches it
//! (`LatchReason::Paused`).

use super::{Bridge, Clock, Duration, Engine, MAX_PZD_WORDS, Transport, TransportError};
use crate::engine::control::Transition;
use uss_shm_types::pzd::stop_strength;

/// The longest an idle wait (a fixed cycle time, every drive offline) goes without a look.
pub const LOOK_STEP: Duration = Duration::from_millis(1);

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// Looks at every drive now: its newest sample and operator command, judged by its gate;
    /// marks the drives due out of turn.
    pub(super) fn look(&mut self) {
        let now = self.clock.now();
        let gap = now
            .saturating_sub(self.last_look)
            .saturating_sub(self.look_lag);
        self.last_look = now;
        for slot in 0..self.drives.len() {
            let change = self.observe(slot, now, gap);
            if self.drives[slot].setup.layout.pzd.get() == 0 {
                // No words: nothing to send sooner.
                continue;
            }
            let bit = 1u32 << slot;
            let mut words = [0u16; MAX_PZD_WORDS];
            self.drives[slot].gate.words(&mut words);
            if stop_strength(words[0]) > stop_strength(self.stats.drives[slot].sent[0]) {
                self.out_of_turn |= bit;
            }
            if matches!(change, Some(Transition::Rearmed { .. })) && self.rearm_spent & bit == 0 {
                self.out_of_turn |= bit;
                self.rearm_spent |= bit;
            }
        }
    }

    /// The drive to poll out of turn now, if any (the lowest slot first).
    pub(super) fn next_out_of_turn(&self, except: Option<usize>) -> Option<usize> {
        let mask = except.map_or(u32::MAX, |slot| !(1u32 << slot));
        let due = self.out_of_turn & mask;
        (due != 0).then(|| due.trailing_zeros() as usize)
    }

    /// Looks at every drive, then polls each drive due out of turn but `except` (the drive whose
    /// poll is in progress: its next attempt carries its new words). Out-of-turn polls never
    /// nest.
    pub(super) fn serve_out_of_turn(
        &mut self,
        except: Option<usize>,
    ) -> Result<(), TransportError> {
        if self.serving_out_of_turn {
            return Ok(());
        }
        self.look();
        while let Some(slot) = self.next_out_of_turn(except) {
            self.poll_out_of_turn(slot)?;
            self.look();
        }
        Ok(())
    }

    /// One poll of `slot` out of turn.
    pub(super) fn poll_out_of_turn(&mut self, slot: usize) -> Result<(), TransportError> {
        self.serving_out_of_turn = true;
        self.stats.bus.out_of_turn += 1;
        let polled = self.poll_drive(slot, false);
        self.serving_out_of_turn = false;
        polled
    }
}
