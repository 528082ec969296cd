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
//! A stop of every drive goes out as one broadcast telegram (ADR bit 5, USS.md section 3: no
//! drive answers) per telegram shape of the drives that take broadcasts
//! ([`crate::DriveSetup::broadcast`]), right after the exchange in progress; then the drives
//! that did not hear it (S110, G120 firmware 4) get their own telegram, and then every drive
//! confirms the stop in its own exchange. A broadcast is left out when a drive that would hear
//! it gets a stronger stop now (it would be weakened): those drives get their own telegrams.
//!
//! A look also measures the engine's own continuity: the time since the previous look beyond
//! what one attempt and one idle step explain is a gap (ussd paused by SIGSTOP, a suspended
//! machine, a starved CPU), and a gap longer than a drive's watchdog time latches it
//! (`LatchReason::Paused`). An attempt whose start pause or reply wait took longer than one
//! attempt explains looks again at once (`engine::exchange`), so the telegram after a pause
//! carries the latch and the image of the exchange that straddled it says so.

use super::{
    Adr, Bridge, Clock, Duration, Engine, MAX_PKW_WORDS, MAX_PZD_WORDS, Transport, TransportError,
    encode,
};
use crate::control::Transition;
use uss_shm_types::StopCommand;
use uss_shm_types::pzd::stop_strength;

/// The longest an idle wait (a fixed cycle time, every drive offline) goes without a look.
pub const LOOK_STEP: Duration = Duration::from_millis(1);

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// Looks at every drive now: its newest sample and operator command, judged by its gate;
    /// marks the drives due out of turn.
    pub(super) fn look(&mut self) {
        if !self.cfg.safety_first {
            return;
        }
        let now = self.clock.now();
        let gap = self.continuity.look(now);
        for slot in 0..self.drives.len() {
            let change = self.observe(slot, now, gap);
            if self.drives[slot].setup.layout.pzd.get() == 0 {
                // No words: nothing to send sooner.
                continue;
            }
            let mut words = [0u16; MAX_PZD_WORDS];
            self.drives[slot].gate.words(&mut words);
            let stronger = stop_strength(words[0]) > stop_strength(self.drives[slot].sent[0]);
            let rearmed = matches!(change, Some(Transition::Rearmed { .. }));
            self.turns.looked(slot, stronger, rearmed);
        }
    }

    /// [`Engine::look`], then a stop of every drive asked for since, as broadcasts.
    pub(super) fn look_and_broadcast(&mut self) -> Result<(), TransportError> {
        self.look();
        self.broadcast_stop_all()
    }

    /// The strongest stop of every drive asked for since the last one sent, if any.
    fn take_stop_all(&mut self) -> Option<StopCommand> {
        self.shared.stop_all.take(&mut self.stop_all_seen)
    }

    /// Whether drive `slot` hears broadcasts that carry a stop word.
    fn hears_broadcasts(&self, slot: usize) -> bool {
        let setup = &self.drives[slot].setup;
        setup.broadcast && setup.layout.pzd.get() > 0
    }

    /// The strongest stop drive `slot` has now: in its last telegram or in its gate's words.
    fn stop_now(&self, slot: usize) -> u8 {
        let mut words = [0u16; MAX_PZD_WORDS];
        self.drives[slot].gate.words(&mut words);
        stop_strength(words[0]).max(stop_strength(self.drives[slot].sent[0]))
    }

    /// A stop of every drive: one broadcast per telegram shape (PKW request words, PZD words)
    /// of the drives that hear broadcasts, unless one of them has a stronger stop now.
    fn broadcast_stop_all(&mut self) -> Result<(), TransportError> {
        if !self.cfg.safety_first {
            return Ok(());
        }
        let Some(command) = self.take_stop_all() else {
            return Ok(());
        };
        let stw1 = command.stw1();
        let n = self.drives.len();
        let mut handled = 0u32;
        for first in 0..n {
            if handled & (1 << first) != 0 || !self.hears_broadcasts(first) {
                continue;
            }
            let shape = self.drives[first].setup.layout;
            let same = |s: &Self, slot: usize| {
                let l = s.drives[slot].setup.layout;
                s.hears_broadcasts(slot)
                    && l.pzd == shape.pzd
                    && l.pkw.request_words() == shape.pkw.request_words()
            };
            let mut group = 0u32;
            let mut weakens = false;
            for slot in first..n {
                if same(self, slot) {
                    group |= 1 << slot;
                    weakens |= self.stop_now(slot) > command.strength();
                }
            }
            handled |= group;
            if !weakens {
                self.send_broadcast(first, stw1)?;
                self.turns.heard(group);
            }
        }
        Ok(())
    }

    /// One broadcast telegram in the shape of drive `slot`'s: no PKW task, `stw1` and zeros as
    /// PZD. Nobody answers: the line is free when it is sent (and its echo read, on two wires).
    fn send_broadcast(&mut self, slot: usize, stw1: u16) -> Result<(), TransportError> {
        let setup = self.drives[slot].setup;
        let none = [0u16; MAX_PKW_WORDS];
        let mut pzd = [0u16; MAX_PZD_WORDS];
        pzd[0] = stw1;
        let adr = Adr::broadcast();
        let Ok(n) = encode(
            &mut self.tx,
            adr,
            &none[..setup.layout.pkw.request_words()],
            &pzd[..setup.layout.pzd.get()],
        ) else {
            return Ok(());
        };
        self.clock.sleep_until_precise(self.exchange.send_at());
        let send_at = self.clock.now();
        self.transport.flush_input(send_at)?;
        let end = self.transport.send(&self.tx[..n], send_at)?;
        // Nobody answers: nothing to wait for but the echo, on two wires.
        self.exchange
            .sent(end, self.cfg.response_timeout + self.cfg.rx_latency);
        let shown = crate::DriveSetup {
            address: adr.address,
            ..setup
        };
        self.capture
            .request(&shown, &self.tx[..n], false, (send_at, end));
        self.bus.broadcasts += 1;
        if self.cfg.echo {
            // Our own bytes back; a missing echo fails nothing here (no reply is due).
            let _ = self.discard_echo(n)?;
        }
        Ok(())
    }

    /// Looks at every drive, then polls each drive due out of turn but `except` (the drive whose
    /// poll is in progress: its next attempt carries its new words). Out-of-turn polls never
    /// nest.
    pub(super) fn serve_out_of_turn(
        &mut self,
        except: Option<usize>,
    ) -> Result<(), TransportError> {
        if self.turns.serving() {
            return Ok(());
        }
        self.look_and_broadcast()?;
        while let Some(slot) = self.turns.next(except) {
            self.poll_out_of_turn(slot)?;
            self.look_and_broadcast()?;
        }
        Ok(())
    }

    /// One poll of `slot` out of turn.
    pub(super) fn poll_out_of_turn(&mut self, slot: usize) -> Result<(), TransportError> {
        if !self.turns.begin_out_of_turn() {
            // Within one already: none nests (`serve_out_of_turn` never asks for it).
            return Ok(());
        }
        self.bus.out_of_turn += 1;
        let polled = self.poll_drive(slot, false);
        self.turns.end_out_of_turn();
        polled
    }
}
