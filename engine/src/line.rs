//! The line failing and coming back: every job ends, every drive goes offline; on return
//! every drive latches ([`LatchReason::LineRestored`]) and is probed at once.

use super::{
    Bridge, Clock, Duration, Engine, Event, FramerConfig, LatchReason, LineFailure, Ordering,
    PathError, Transport, TransportError,
};

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// The line failed: every pending job ends with [`PathError::LineDown`] (the one on the wire
    /// included: its reply cannot come), every drive is offline, and new jobs are refused until
    /// the line is back. Nothing can be sent meanwhile: a running drive's own telegram
    /// monitoring (P2014) is what stops it.
    pub fn line_down(&mut self, error: &TransportError) {
        self.snapshot.take();
        let now = self.clock.now();
        let fault = LineFailure::of(error);
        self.shared.reopen_attempts.store(0, Ordering::Relaxed);
        self.shared.line_down.store(true, Ordering::Release);
        self.fail_all_jobs(Err(PathError::LineDown));
        for slot in 0..self.drives.len() {
            self.drives[slot].link.line_down(now);
            self.shared.drives[slot]
                .images
                .online
                .store(false, Ordering::Release);
            self.after_poll(slot);
        }
        self.line.down = Some((now, fault));
        self.line.downs += 1;
        self.emit(Event::LineDown { at: now, fault });
        self.publish();
    }

    /// The line is back on `transport`, whose device hands received bytes over up to
    /// `rx_latency` late (read again at every open: a replug may bring another adapter): every
    /// drive latches ([`LatchReason::LineRestored`]) and is probed at once, coming online with
    /// its first good reply. A drive that ran before runs again only when its controller
    /// re-arms it (OFF1, then ON).
    pub fn restore(&mut self, transport: T, rx_latency: Duration) {
        self.snapshot.take();
        let now = self.clock.now();
        self.transport = transport;
        let mut lag = self.continuity.lag();
        if rx_latency != self.cfg.rx_latency {
            self.cfg.rx_latency = rx_latency;
            let attempt = super::build::period_setup(&self.cfg).attempt;
            self.periods.set_attempt(attempt);
            // What one attempt explains of a gap between looks grows with it (build.rs).
            lag = attempt + super::LOOK_STEP * 2;
        }
        self.exchange.restart(
            FramerConfig::with_latency(self.cfg.timing, self.cfg.rx_latency),
            now,
        );
        // The line was down: no gap of the engine's, every drive latches below anyway.
        self.continuity.restart(now, lag);
        self.last_reply_done = None;
        self.last_reply_seen = None;
        for slot in 0..self.drives.len() {
            self.drives[slot].link.next_probe = now;
            self.latch_now(slot, LatchReason::LineRestored, now);
        }
        let down_for = self
            .line
            .down
            .take()
            .map_or(Duration::ZERO, |(since, _)| now.saturating_sub(since));
        self.shared.line_down.store(false, Ordering::Release);
        self.emit(Event::LineUp { at: now, down_for });
        self.publish();
    }
}
