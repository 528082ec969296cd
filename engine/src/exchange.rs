//! One drive's poll: the telegram with its PZD words and PKW task, the reply and its checks
//! (USS.md section 4: start pause, response delay, residual time, BCC, the right slave), retries,
//! the echo of a 2-wire adapter, and what a good or failed poll changes.

use super::{
    Address, Adr, Bridge, Clock, DriveSetup, Duration, Engine, Event, Heard, LOOK_STEP,
    LastFailure, MAX_NET_BYTES, MAX_PKW_WORDS, MAX_PZD_WORDS, Ordering, Outgoing, ParamReply,
    PathError, ReplyKind, Silence, Transport, TransportError, Words, encode,
};

/// How one attempt ended.
pub(super) enum Attempt {
    Reply { words: Words, timing: ReplyTiming },
    Failed(LastFailure),
}

/// When the parts of a good reply happened.
#[derive(Debug, Clone, Copy)]
pub(super) struct ReplyTiming {
    request_len: usize,
    request_end: Duration,
    stx_at: Duration,
    done: Duration,
    first_attempt: bool,
}

impl<T: Transport, C: Clock, B: Bridge> Engine<T, C, B> {
    /// Polls the drive in `slot`: at its turn in the circulating list (`regular`), or out of
    /// turn (`engine::turns`). Before a retry the drives due out of turn go first; every
    /// attempt carries the drive's words as they are then.
    pub(super) fn poll_drive(&mut self, slot: usize, regular: bool) -> Result<(), TransportError> {
        if regular {
            self.turns.regular_poll(slot);
        }
        let now = self.clock.now();
        if let Some(r) = self.drives[slot]
            .mailbox
            .expire(self.cfg.param_timeout, now)
        {
            self.deliver(r);
        }
        self.refresh_picture(slot);
        self.check_own_reads(slot);
        let mut last = LastFailure::NoResponse;
        for attempt in 0..=self.cfg.retries {
            if attempt > 0 {
                self.drives[slot].counters.retries += 1;
                self.serve_out_of_turn(Some(slot))?;
            }
            let begin = self.exchange.free_at();
            match self.attempt(slot, None, true)? {
                Attempt::Reply { words, mut timing } => {
                    timing.first_attempt = attempt == 0;
                    self.on_reply(slot, &words, begin, timing);
                    self.after_poll(slot);
                    return Ok(());
                }
                Attempt::Failed(f) => {
                    let d = &mut self.drives[slot];
                    d.attempt_failed(f);
                    d.link.last_failure = f;
                    last = f;
                    if attempt < self.cfg.retries {
                        self.emit(Event::Retry {
                            address: self.drives[slot].setup.address,
                            at: self.clock.now(),
                            attempt: attempt + 1,
                            failure: f,
                        });
                    }
                }
            }
        }
        self.on_failed_poll(slot, last);
        self.after_poll(slot);
        Ok(())
    }

    /// A good reply from the drive in `slot` (`begin`: when the line was free before its
    /// request): its link, what it said, its timing, its input image, then its parameter reply.
    pub(super) fn on_reply(
        &mut self,
        slot: usize,
        words: &Words,
        begin: Duration,
        timing: ReplyTiming,
    ) {
        self.bus.good += 1;
        let d = &mut self.drives[slot];
        d.counters.good += 1;
        let good = d.counters.good;
        // A whole poll that failed: the drive may have restarted in between.
        let missed = d.link.consecutive_failed_polls > 0;
        let (since_last, came_back) = d.link.good(timing.done);
        if let Some(period) = since_last {
            d.timing.update_period.record(period);
        }
        let said = d.heard(words.pzd(), good == 1);
        let address = d.setup.address;
        self.record_exchange(slot, words, begin, timing);
        for event in said.events(address, timing.done) {
            self.emit(event);
        }
        let image = &self.shared.drives[slot].images;
        image.input.write(
            words.pzd(),
            good,
            u64::try_from(timing.done.as_nanos()).unwrap_or(u64::MAX),
        );
        if came_back {
            image.online.store(true, Ordering::Release);
            self.emit(Event::DriveOnline {
                address,
                at: timing.done,
            });
            // A drive that comes online may have been replaced, reset or power-cycled: what
            // ussd knew of it is unknown until read again.
            self.forget_picture(slot, false);
        } else if missed {
            self.drives[slot].monitoring_due = true;
            self.drives[slot].reference_due = true;
        }
        self.last_reply_done = Some(timing.done);
        self.take_param_reply(slot, words.pkw(), timing.done);
    }

    /// A good reply's timing: the drive's response delay and the exchange, for the drive and
    /// the bus; a first attempt's exchange against its wire-time floor (USS.md section 4).
    fn record_exchange(&mut self, slot: usize, words: &Words, begin: Duration, t: ReplyTiming) {
        // The STX's arrival time is the end of its stop bit: its start was one tz earlier.
        let tz = self.cfg.timing.char_time();
        let response_delay = t.stx_at.saturating_sub(tz + t.request_end);
        let exchange = t.done.saturating_sub(begin);
        self.timing.response_delay.record(response_delay);
        self.timing.exchange.record(exchange);
        let d = &mut self.drives[slot].timing;
        d.response_delay.record(response_delay);
        d.exchange.record(exchange);
        if !t.first_attempt {
            return;
        }
        let reply_len = 4 + 2 * (words.pkw().len() + words.pzd().len());
        let chars = (t.request_len + reply_len) as u64;
        let floor = self.cfg.timing.start_pause() + self.cfg.timing.chars(chars) + response_delay;
        // An exchange shorter than its characters take at the baud rate was not timed by the
        // wire: the reply came out of a buffer faster than a line carries it (a pty, a stalled
        // sender's backlog). It says nothing of efficiency, which is at most 1 by definition.
        let bus = &mut self.bus;
        if exchange >= floor {
            bus.timed_exchange_ns += u64::try_from(exchange.as_nanos()).unwrap_or(u64::MAX);
            bus.timed_wire_floor_ns += u64::try_from(floor.as_nanos()).unwrap_or(u64::MAX);
            bus.timed += 1;
        } else {
            bus.untimed += 1;
        }
    }

    /// The PKW words of a good reply: the answer to the drive's job on the wire, if any.
    fn take_param_reply(&mut self, slot: usize, pkw: &[u16], at: Duration) {
        let d = &mut self.drives[slot];
        if pkw.is_empty() || d.mailbox.is_empty() {
            return;
        }
        let Ok(reply) = ParamReply::decode(pkw) else {
            return;
        };
        if reply.kind == ReplyKind::NotYet {
            d.counters.pkw_busy += 1;
        }
        if let Some(result) = d.mailbox.on_reply(&reply, at) {
            self.deliver(result);
        }
    }

    /// A poll of the drive in `slot` failed all its retries (the last with `failure`): it may
    /// go offline, and then its jobs end.
    pub(super) fn on_failed_poll(&mut self, slot: usize, failure: LastFailure) {
        let now = self.clock.now();
        let d = &mut self.drives[slot];
        d.counters.failed_polls += 1;
        if !d
            .link
            .failed(now, self.cfg.offline_after, self.cfg.offline_probe)
        {
            return;
        }
        let address = d.setup.address;
        self.shared.drives[slot]
            .images
            .online
            .store(false, Ordering::Release);
        self.emit(Event::DriveOffline {
            address,
            at: now,
            failure,
        });
        while let Some(r) = self.drives[slot]
            .mailbox
            .finish(Err(PathError::DriveOffline), now)
        {
            self.deliver(r);
        }
    }

    /// One telegram to the drive in `slot` and its reply: its PZD words `pzd`, or (`None`) the
    /// words its gate decides ([`Engine::output`]). `with_task` puts the pending PKW task in (not
    /// for the shutdown telegrams).
    pub(super) fn attempt(
        &mut self,
        slot: usize,
        pzd: Option<&[u16]>,
        with_task: bool,
    ) -> Result<Attempt, TransportError> {
        self.shared.progress.fetch_add(1, Ordering::Relaxed);
        let setup = self.drives[slot].setup;
        // The task's words were encoded once when it was accepted; without a task (or before
        // one, to make it new to the drive) the channel carries zeros ("no task").
        if with_task {
            self.drop_jobs_of_the_dead(slot);
        }
        let outgoing = if with_task {
            self.drives[slot].mailbox.outgoing()
        } else {
            Outgoing::Idle
        };
        let pkw_len = setup.layout.pkw.request_words();
        let mut pkw = [0u16; MAX_PKW_WORDS];
        let carries_task = match outgoing {
            Outgoing::Task(words) => {
                pkw[..pkw_len].copy_from_slice(words);
                true
            }
            Outgoing::Idle | Outgoing::Separator => false,
        };
        let len = setup.layout.pzd.get();
        let mut words = [0u16; MAX_PZD_WORDS];
        match pzd {
            Some(w) => words[..w.len()].copy_from_slice(w),
            None => self.output(slot, self.clock.now(), &mut words),
        }
        let pzd_len = pzd.map_or(len, <[u16]>::len);
        let (pkw, words_now) = (&pkw[..pkw_len], words);
        let Some(mut n) = self.encode_request(setup, pkw, &words_now[..pzd_len]) else {
            return Ok(Attempt::Failed(LastFailure::Length));
        };
        if let Some(seen) = self.last_reply_seen.take() {
            let ready = self.clock.now();
            self.timing.work.record(ready.saturating_sub(seen));
        }
        // The start pause, then a clean input buffer, then our telegram (USS.md section 4).
        let planned = self.exchange.send_at();
        let wake = planned.max(self.clock.now());
        self.clock.sleep_until_precise(planned);
        let send_at = self.clock.now();
        if pzd.is_none() && send_at.saturating_sub(wake) > LOOK_STEP {
            // ussd did not run while it waited (SIGSTOP, a suspended machine, a starved CPU): what
            // was decided before is decided again now, with the gap seen, before it leaves.
            self.look();
            self.output(slot, send_at, &mut words);
            let Some(again) = self.encode_request(setup, pkw, &words[..pzd_len]) else {
                return Ok(Attempt::Failed(LastFailure::Length));
            };
            n = again;
        }
        if let Some(done) = self.last_reply_done.take() {
            self.timing.turnaround.record(send_at.saturating_sub(done));
        }
        self.transport.flush_input(send_at)?;
        let request_end = self.transport.send(&self.tx[..n], send_at)?;
        self.exchange
            .sent(request_end, self.cfg.response_timeout + self.cfg.rx_latency);
        self.capture
            .request(&setup, &self.tx[..n], carries_task, (send_at, request_end));
        self.drives[slot]
            .mailbox
            .on_sent(pkw_len, carries_task, send_at);
        self.drives[slot].counters.requests += 1;
        self.bus.exchanges += 1;
        let attempt = if self.cfg.echo
            && let Some(f) = self.discard_echo(n)?
        {
            Attempt::Failed(f)
        } else {
            self.receive_reply(setup, slot, n, request_end)?
        };
        self.drives[slot].sent_before.keep(&self.tx[..n]);
        if pzd.is_none() && self.continuity.overdue(self.clock.now()) {
            // ussd did not run while it waited for the reply (SIGSTOP, a suspended machine, a
            // starved CPU): the gap is judged now, so the image this exchange makes already
            // says what it means (rule 3), not one exchange later.
            self.look();
        }
        let outcome = match &attempt {
            Attempt::Reply { .. } => LastFailure::None,
            Attempt::Failed(f) => *f,
        };
        self.drives[slot]
            .mailbox
            .answered(outcome == LastFailure::None);
        self.capture.reply_end(&setup, outcome, self.clock.now());
        Ok(attempt)
    }

    /// Encodes a request to the drive of `setup` into the transmit buffer: its length, `None`
    /// when it does not fit.
    fn encode_request(&mut self, setup: DriveSetup, pkw: &[u16], pzd: &[u16]) -> Option<usize> {
        encode(&mut self.tx, Adr::to(setup.address), pkw, pzd).ok()
    }

    /// Receives until a valid reply from the right drive, or a failure (the exchange's rules:
    /// `uss_protocol::exchange`).
    pub(super) fn receive_reply(
        &mut self,
        setup: DriveSetup,
        slot: usize,
        request_len: usize,
        request_end: Duration,
    ) -> Result<Attempt, TransportError> {
        loop {
            let deadline = self.exchange.deadline();
            let Some(rx) = self.transport.recv(deadline, &mut self.clock)? else {
                // recv returns at the deadline.
                return Ok(Attempt::Failed(match self.exchange.silence() {
                    Silence::Incomplete => {
                        // The telegram did not complete in time.
                        self.drain()?;
                        LastFailure::Residual
                    }
                    Silence::NoReply(garbage) => {
                        // A reply that started too late on the wire may still be on its way
                        // through the adapter: the next telegram waits it out (and flushes
                        // it), so it is not taken for the answer to the retry.
                        self.exchange
                            .busy_until(self.clock.now() + self.cfg.rx_latency);
                        garbage.map_or(LastFailure::NoResponse, |e| LastFailure::from(&e))
                    }
                }));
            };
            self.capture.byte(rx.byte, rx.at);
            let (adr, words, stx_at, garbage, own) =
                match self.exchange.heard(rx.byte, rx.error, rx.at) {
                    Heard::More => continue,
                    Heard::Broken(e) => {
                        self.drain()?;
                        return Ok(Attempt::Failed(LastFailure::from(&e)));
                    }
                    Heard::Telegram {
                        telegram,
                        stx_at,
                        after_garbage,
                        ..
                    } => (
                        telegram.adr(),
                        telegram.words(setup.layout),
                        stx_at,
                        after_garbage,
                        // Our own request, byte for byte: a line that sends it back (a 2-wire
                        // adapter without `echo = true`, a device server that echoes), now or
                        // one exchange late (the request before it). A drive's reply differs
                        // (ZSW1 for STW1, a PKW reply for the task).
                        telegram.as_bytes() == &self.tx[..request_len]
                            || self.drives[slot].sent_before.is(telegram.as_bytes()),
                    ),
                };
            let failure = if own {
                LastFailure::Echo
            } else if adr == Adr::to(setup.address) {
                match words {
                    Ok(words) => {
                        if let Some(g) = garbage {
                            let slot = self.slot(setup.address);
                            self.drives[slot].counters.count(LastFailure::from(&g));
                        }
                        self.last_reply_seen = Some(self.clock.now());
                        let timing = ReplyTiming {
                            request_len,
                            request_end,
                            stx_at,
                            done: rx.at,
                            first_attempt: true,
                        };
                        return Ok(Attempt::Reply { words, timing });
                    }
                    Err(_) => LastFailure::Length,
                }
            } else {
                LastFailure::WrongAddress
            };
            self.drain()?;
            return Ok(Attempt::Failed(failure));
        }
    }

    pub(super) fn slot(&self, address: Address) -> usize {
        self.shared.slot_of[address.get() as usize].map_or(0, usize::from)
    }

    /// Reads our own request back from a 2-wire adapter and checks it byte for byte.
    pub(super) fn discard_echo(&mut self, n: usize) -> Result<Option<LastFailure>, TransportError> {
        // The reply's start deadline (`Exchange::sent`): the echo comes before it.
        let deadline = self.exchange.deadline();
        let mut last_echo = None;
        for i in 0..n {
            let Some(rx) = self.transport.recv(deadline, &mut self.clock)? else {
                // Part of it came, at most: the next request waits after what came.
                if let Some(last) = last_echo {
                    self.exchange.busy_until(last);
                }
                return Ok(Some(LastFailure::Echo));
            };
            last_echo = Some(rx.at);
            self.capture.byte(rx.byte, rx.at);
            if rx.byte != self.tx[i] || rx.error.is_some() {
                self.exchange.busy_until(rx.at);
                self.drain()?;
                return Ok(Some(LastFailure::Echo));
            }
        }
        // The echo is our own request: the line was busy until the request's computed end
        // (`Exchange::sent`), not until the echo was delivered (an adapter hands the echo's
        // tail and the reply's start over together; their spacing is the adapter's, not the
        // wire's). Our own bytes: the reply starts after them.
        self.capture.reply_begin();
        Ok(None)
    }

    /// After a broken reply, waits until the line has been quiet for a start pause, so the rest
    /// of it is not taken for the next reply. Bounded by the longest telegram's residual time.
    pub(super) fn drain(&mut self) -> Result<(), TransportError> {
        let pause = self.cfg.timing.start_pause();
        let limit = self.clock.now() + self.cfg.timing.max_residual(MAX_NET_BYTES);
        loop {
            let quiet = (self.exchange.free_at() + pause).min(limit);
            match self.transport.recv(quiet, &mut self.clock)? {
                Some(rx) if self.clock.now() < limit => {
                    self.exchange.busy_until(rx.at);
                    self.capture.byte(rx.byte, rx.at);
                }
                _ => break,
            }
        }
        self.exchange.quiet();
        Ok(())
    }
}
