//! The session's rules as a table: a state, a call, what is published or which error.
#![allow(clippy::unwrap_used)]

use super::*;

const READY: u16 = 0x047E;
const RUN: u16 = 0x047F;
const COAST: u16 = 0x047C;
const MS: u64 = 1_000_000;
const WATCHDOG: u64 = 100 * MS;
/// The start-up latch, an operator's coast after it, and one more.
const L1: u64 = 1_000;
const L2: u64 = 2_000;
const L3: u64 = 3_000;

fn live() -> LatchView {
    LatchView::LIVE
}

/// Latched by an operator's OFF1.
fn latched(id: u64) -> LatchView {
    LatchView::latched(id, StopCommand::Off1)
}

/// A session and the image and time it sees.
struct Play {
    s: Session,
    image: LatchView,
    now: u64,
}

/// What a call came to, in the table's terms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Out {
    /// Published: STW1 and the latch it names.
    Sent(u16, u64),
    Await,
    Nothing,
    Err(SessionError),
}

fn out(r: Result<Step, SessionError>) -> Out {
    match r {
        Ok(Step::Publish(s)) => Out::Sent(s.stw1(), s.latch_id),
        Ok(Step::AwaitRearm) => Out::Await,
        Err(e) => Out::Err(e),
    }
}

impl Play {
    /// A controller that opened the drive latched at start (L1, at 1 us) at t = 1 ms: it
    /// acknowledged nothing.
    fn opened() -> Self {
        let setup = SessionSetup {
            pzd: 2,
            pid: 7,
            watchdog_ns: WATCHDOG,
            first_sequence: 500,
        };
        Self {
            s: Session::new(setup),
            image: latched(L1),
            now: MS,
        }
    }

    /// Re-armed (its OFF1 taken, the image live) and running: ON at 10 ms.
    fn running() -> Self {
        let mut p = Self::opened();
        assert_eq!(p.rearm(), Out::Sent(READY, L1));
        p.image = live();
        p.at(10);
        assert_eq!(p.run(), Out::Sent(RUN, L1));
        p
    }

    fn at(&mut self, ms: u64) -> &mut Self {
        self.now = ms * MS;
        self
    }

    fn show(&mut self, image: LatchView) -> &mut Self {
        self.image = image;
        self
    }

    fn call(&mut self, change: impl FnOnce(&mut Words)) -> Out {
        out(self.s.publish(self.now, &self.image, change))
    }

    fn stw1(&mut self, stw1: u16) -> Out {
        self.call(|w| w.words[0] = stw1)
    }

    fn run(&mut self) -> Out {
        self.call(|w| {
            w.words[0] = RUN;
            w.words[1] = 0x2000;
        })
    }

    fn refresh(&mut self) -> Out {
        self.s
            .refresh(self.now, &self.image)
            .map_or(Out::Nothing, |s| Out::Sent(s.stw1(), s.latch_id))
    }

    /// The program's re-arm, asked for at the moment of the call.
    fn rearm(&mut self) -> Out {
        self.s
            .rearm(self.now, &self.image, self.now)
            .map_or_else(Out::Err, |s| Out::Sent(s.stw1(), s.latch_id))
    }
}

/// Running, then the controller's own OFF1 at 20 ms, then an operator's coast (L2) shown at
/// 30 ms: issue 20's sequence.
fn stopped_then_coasted() -> Play {
    let mut p = Play::running();
    p.at(20);
    assert_eq!(p.stw1(READY), Out::Sent(READY, L1));
    p.at(30).show(latched(L2));
    p
}

fn tripped(latch_id: u64) -> Out {
    Out::Err(SessionError::Tripped { latch_id })
}

fn stalled(gap_ms: u64) -> Out {
    Out::Err(SessionError::Stalled {
        gap_ns: gap_ms * MS,
        watchdog_ns: WATCHDOG,
    })
}

#[rustfmt::skip]
#[test]
fn decision_table() {
    type Case = (&'static str, fn() -> Play, fn(&mut Play) -> Out, Out);
    let cases: &[Case] = &[
        // Opened while latched at ussd's start (L1): only the explicit re-arm acknowledges it.
        ("opened: a keepalive goes out naming no latch (no re-arm)", Play::opened, |p| p.call(|_| {}), Out::Sent(READY, 0)),
        ("opened: OFF1 goes out naming no latch (no re-arm)", Play::opened, |p| p.stw1(READY), Out::Sent(READY, 0)),
        ("opened: OFF2 goes out naming no latch", Play::opened, |p| p.stw1(COAST), Out::Sent(COAST, 0)),
        ("opened: ON is news", Play::opened, Play::run, tripped(L1)),
        ("opened: keepalives, then ON: still news", Play::opened, |p| { p.call(|_| {}); p.at(20).call(|_| {}); p.at(40).run() }, tripped(L1)),
        ("opened: OFF1, then ON: still news", Play::opened, |p| { p.stw1(READY); p.at(20).run() }, tripped(L1)),
        ("opened: jog is news", Play::opened, |p| p.stw1(READY | 0x0100), tripped(L1)),
        ("opened: the refresher does not repeat a stop over news", Play::opened, |p| { p.stw1(READY); p.at(20).refresh() }, Out::Nothing),
        ("opened: the re-arm names the latch it sees", Play::opened, Play::rearm, Out::Sent(READY, L1)),
        ("opened: ON after the re-arm, before ussd took it, waits", Play::opened, |p| { p.rearm(); p.run() }, Out::Await),
        ("opened: ON once the image is live goes out", Play::opened, |p| { p.rearm(); p.show(live()).run() }, Out::Sent(RUN, L1)),
        ("opened: a new latch before the re-arm is taken is news", Play::opened, |p| { p.rearm(); p.show(latched(L2)).run() }, tripped(L2)),
        ("opened: after the re-arm, OFF1 names the latch too", Play::opened, |p| { p.rearm(); p.stw1(READY) }, Out::Sent(READY, L1)),
        ("opened: bit 10 clear is refused before the wire", Play::opened, |p| p.stw1(0x007E), Out::Err(SessionError::Invalid(Rejection::NoPlcControl))),
        ("opened: three words for two are refused", Play::opened, |p| p.call(|w| w.count = 3), Out::Err(SessionError::Invalid(Rejection::WordCount))),
        ("opened: no refresh before the program's first call", Play::opened, Play::refresh, Out::Nothing),
        ("opened: the refresher repeats the re-arming OFF1", Play::opened, |p| { p.rearm(); p.at(20).refresh() }, Out::Sent(READY, L1)),
        ("opened live (an earlier controller's drive): ON goes out, ussd judges whose it is", Play::opened, |p| p.show(live()).run(), Out::Sent(RUN, 0)),
        // Live and running.
        ("running: ON again", Play::running, |p| p.at(30).run(), Out::Sent(RUN, L1)),
        ("running: a refresh 90 ms after the last call", Play::running, |p| p.at(100).refresh(), Out::Sent(RUN, L1)),
        ("running: no refresh 101 ms after the last call (the program stalled)", Play::running, |p| p.at(111).refresh(), Out::Nothing),
        ("running: a call 150 ms after the last is a trip", Play::running, |p| p.at(160).run(), stalled(150)),
        ("running: after a gap, a stop still goes out", Play::running, |p| p.at(160).stw1(READY), Out::Sent(READY, L1)),
        ("running: after a gap, ON fails until a re-arm", Play::running, |p| { p.at(160).stw1(READY); p.at(170).run() }, stalled(150)),
        ("running: after a gap the refresher sends nothing", Play::running, |p| { p.at(160).stw1(READY); p.at(170).refresh() }, Out::Nothing),
        ("running: after a gap, re-armed, ON goes out", Play::running, |p| { p.at(160).run(); p.at(170).rearm(); p.at(180).run() }, Out::Sent(RUN, L1)),
        ("running: an operator's coast (L2) is news for ON", Play::running, |p| p.at(20).show(latched(L2)).run(), tripped(L2)),
        ("running: ... not for a stop, which goes out naming the old latch (no re-arm)", Play::running, |p| p.at(20).show(latched(L2)).stw1(READY), Out::Sent(READY, L1)),
        ("running: ... a coast goes out too", Play::running, |p| p.at(20).show(latched(L2)).stw1(COAST), Out::Sent(COAST, L1)),
        ("running: ... and ON after that stop is still news", Play::running, |p| { p.at(20).show(latched(L2)).stw1(READY); p.at(30).run() }, tripped(L2)),
        ("running: ... and the refresher sends nothing", Play::running, |p| p.at(20).show(latched(L2)).refresh(), Out::Nothing),
        ("running: re-arm names the new latch", Play::running, |p| p.at(20).show(latched(L2)).rearm(), Out::Sent(READY, L2)),
        ("running: released, a call fails", Play::running, |p| { p.s.release(p.now); p.run() }, Out::Err(SessionError::Released)),
        ("running: released, nothing is refreshed", Play::running, |p| { p.s.release(p.now); p.refresh() }, Out::Nothing),
        ("running: released, no re-arm", Play::running, |p| { p.s.release(p.now); p.rearm() }, Out::Err(SessionError::Released)),
        // Issue 20: the controller's own OFF1, then an operator's coast.
        ("own OFF1 then a coast: the refresher does not re-arm it", stopped_then_coasted, Play::refresh, Out::Nothing),
        ("own OFF1 then a coast: ON is news", stopped_then_coasted, Play::run, tripped(L2)),
        ("own OFF1 then a coast: re-armed, ON waits for ussd", stopped_then_coasted, |p| { p.rearm(); p.run() }, Out::Await),
        ("own OFF1 then a coast: re-armed and live, ON goes out", stopped_then_coasted, |p| { p.rearm(); p.show(live()).run() }, Out::Sent(RUN, L2)),
        ("own OFF1 then a coast, then a third latch during the re-arm: news", stopped_then_coasted, |p| { p.rearm(); p.show(latched(L3)).refresh() }, Out::Nothing),
    ];
    for (name, start, event, expected) in cases {
        let mut p = start();
        assert_eq!(event(&mut p), *expected, "{name}");
    }
}

#[test]
fn a_relay_re_arms_only_the_latch_the_drive_shows() {
    let mut p = Play::running();
    p.at(20).show(latched(L2));
    // The remote controller names L1 (the latch it saw before): not the drive's latch now.
    assert_eq!(
        p.s.acknowledge(p.now, &p.image, L1, p.now),
        Err(SessionError::NotTheLatch {
            named: L1,
            shown: L2
        })
    );
    assert_eq!(p.run(), tripped(L2));
    // Naming L2 acknowledges it; the relay's stop then re-arms, naming L2.
    assert_eq!(p.s.acknowledge(p.now, &p.image, L2, p.now), Ok(()));
    assert_eq!(p.stw1(READY), Out::Sent(READY, L2));
    // Naming a latch while the drive is live acknowledges nothing.
    p.show(live());
    assert_eq!(
        p.s.acknowledge(p.now, &p.image, L2, p.now),
        Err(SessionError::NotTheLatch {
            named: L2,
            shown: 0
        })
    );
}

#[test]
fn a_relay_re_arms_only_after_its_remote_controller_names_the_latch() {
    let setup = SessionSetup {
        pzd: 2,
        pid: 7,
        watchdog_ns: WATCHDOG,
        first_sequence: 0,
    };
    let mut p = Play {
        s: Session::new(setup),
        image: latched(L1),
        now: MS,
    };
    // A remote stop that names no latch goes out and re-arms nothing.
    assert_eq!(p.stw1(READY), Out::Sent(READY, 0));
    assert_eq!(p.refresh(), Out::Nothing);
    assert_eq!(p.run(), tripped(L1));
    assert_eq!(p.s.acknowledge(p.now, &p.image, L1, p.now), Ok(()));
    assert_eq!(p.stw1(READY), Out::Sent(READY, L1));
}

#[test]
fn a_relays_named_re_arm_after_a_silence_is_a_fresh_call() {
    // The remote controller fell silent (the drive tripped: L2), then a new run names L2 0.6 s
    // later: its stop re-arms and its ON runs, the silence before is not held against it.
    let mut p = Play::running();
    p.at(650).show(latched(L2));
    assert_eq!(p.s.acknowledge(p.now, &p.image, L2, p.now), Ok(()));
    assert_eq!(p.stw1(READY), Out::Sent(READY, L2));
    p.at(670).show(live());
    assert_eq!(p.run(), Out::Sent(RUN, L2));
}

#[test]
fn rearmed_follows_the_image() {
    let mut p = Play::running();
    p.at(20).show(latched(L2));
    p.rearm();
    assert_eq!(p.s.rearmed(&p.image), Ok(false));
    assert_eq!(
        p.s.rearmed(&latched(L3)),
        Err(SessionError::Tripped { latch_id: L3 })
    );
    assert_eq!(p.s.rearmed(&live()), Ok(true));
}

#[test]
fn check_reports_news_and_a_stall_without_counting_as_a_call() {
    let mut p = Play::running();
    assert_eq!(p.s.check(50 * MS, &p.image), Ok(()));
    assert_eq!(
        p.s.check(50 * MS, &latched(L2)),
        Err(SessionError::Tripped { latch_id: L2 })
    );
    // 150 ms without a call: check says so, and it did not feed the watchdog.
    assert!(matches!(
        p.s.check(160 * MS, &p.image),
        Err(SessionError::Stalled { .. })
    ));
    assert_eq!(p.at(160).refresh(), Out::Nothing);
}

#[test]
fn every_sample_has_a_new_sequence_the_pid_and_the_time() {
    let mut p = Play::opened();
    let first = p.s.rearm(3, &p.image, MS).unwrap();
    let refreshed = p.s.refresh(4, &p.image).unwrap();
    let release = p.s.release(5);
    assert_eq!(
        (first.sequence, refreshed.sequence, release.sequence),
        (501, 502, 503)
    );
    assert_eq!(
        (first.timestamp_ns, refreshed.timestamp_ns, first.pid),
        (3, 4, 7)
    );
    assert!(release.is_release());
    assert_eq!(release.latch_id, L1);
    // A session that never re-armed acknowledged no latch.
    let mut p = Play::opened();
    p.call(|_| {});
    assert_eq!(p.s.release(6).latch_id, 0);
    // The sequence wraps past 0, which ussd reads as "never written".
    let setup = SessionSetup {
        pzd: 2,
        pid: 7,
        watchdog_ns: WATCHDOG,
        first_sequence: u64::MAX,
    };
    let mut s = Session::new(setup);
    let Ok(Step::Publish(w)) = s.publish(1, &latched(L1), |_| {}) else {
        panic!()
    };
    assert_eq!(w.sequence, 1);
}

#[test]
fn a_re_arm_sends_off1_with_every_other_word_zero() {
    let mut p = Play::running();
    p.at(20).call(|w| w.words[1] = 0x1234);
    p.show(latched(L2));
    let sample = p.s.rearm(p.now, &p.image, p.now).unwrap();
    let words = sample.words().unwrap();
    assert_eq!((words.stw1(), words.words[1], words.count), (READY, 0, 2));
}

#[test]
fn a_controller_refreshes_every_quarter_watchdog_at_most_every_20_ms() {
    let cases = [
        // (watchdog, refresh)
        (100 * MS, 20 * MS),
        (60_000 * MS, 20 * MS),
        (80 * MS, 20 * MS),
        (40 * MS, 10 * MS),
        (15 * MS, 3_750_000),
        (MS, 250_000),
        (3, 1),
        (0, 1),
    ];
    for (watchdog_ns, refresh) in cases {
        assert_eq!(super::refresh_ns(watchdog_ns), refresh, "{watchdog_ns} ns");
    }
    // The session's own: its drive's watchdog is 100 ms.
    assert_eq!(Play::running().s.refresh_ns(), 20 * MS);
}

/// A re-arm asked for before a latch began does not acknowledge it (an operator's stop while a
/// program was starting): it is news, nothing is sent; one asked for after it re-arms.
#[test]
fn a_rearm_asked_before_a_latch_does_not_acknowledge_it() {
    let mut s = Session::new(SessionSetup {
        pzd: 2,
        pid: 7,
        watchdog_ns: WATCHDOG,
        first_sequence: 500,
    });
    let latched_at = 5_000_000_000;
    let image = latched(latched_at);
    assert_eq!(
        s.rearm(latched_at + 10, &image, latched_at - 1),
        Err(SessionError::Tripped {
            latch_id: latched_at
        })
    );
    assert_eq!(s.stops(), 0, "nothing was sent");
    let out = s.rearm(latched_at + 20, &image, latched_at + 1).unwrap();
    assert_eq!(
        out.latch_id, latched_at,
        "the stop names the latch it re-arms"
    );
}

/// A re-arm that keeps the stop sends the latch's own command naming it: OFF2 for a coast,
/// OFF3 for a quick stop, OFF1 otherwise; a plain re-arm sends OFF1.
#[test]
fn a_rearm_keeping_the_stop_sends_the_latchs_own_command() {
    let latched_at = 5_000_000_000;
    for (command, stw1) in [
        (StopCommand::Off2, 0x047C),
        (StopCommand::Off3, 0x047A),
        (StopCommand::Off1, 0x047E),
    ] {
        let mut s = Session::new(SessionSetup {
            pzd: 2,
            pid: 7,
            watchdog_ns: WATCHDOG,
            first_sequence: 500,
        });
        let image = LatchView::latched(latched_at, command);
        assert_eq!(
            s.rearm_keeping_stop(latched_at + 10, &image, latched_at - 1),
            Err(SessionError::Tripped {
                latch_id: latched_at
            }),
            "{command:?}: a latch after the ask"
        );
        let out = s
            .rearm_keeping_stop(latched_at + 10, &image, latched_at)
            .unwrap();
        assert_eq!(
            (out.stw1(), out.latch_id),
            (stw1, latched_at),
            "{command:?}"
        );
        let plain = s.rearm(latched_at + 20, &image, latched_at).unwrap();
        assert_eq!(plain.stw1(), 0x047E, "{command:?}");
    }
}

/// A relay acknowledges a latch its remote names only when the remote's command was asked
/// after the latch began: a remote that started, then saw an operator's coast in its first
/// image, re-arms nothing (issue 45, the Zenoh client).
#[test]
fn a_relay_acknowledges_no_latch_that_began_after_its_remotes_command() {
    let mut p = Play::running();
    p.at(20).show(latched(L2));
    assert_eq!(
        p.s.acknowledge(p.now, &p.image, L2, L2 - 1),
        Err(SessionError::Tripped { latch_id: L2 })
    );
    assert_eq!(p.run(), tripped(L2), "nothing was acknowledged");
    assert_eq!(p.s.acknowledge(p.now, &p.image, L2, L2), Ok(()));
    assert_eq!(p.stw1(READY), Out::Sent(READY, L2));
}

/// A program's moment moved onto the latches' clock errs early, whichever clock runs ahead.
#[test]
fn an_ask_on_another_clock_is_moved_onto_the_latches_clock_erring_early() {
    // Same clock: a stamp 3 ms old makes the ask 3 ms earlier.
    assert_eq!(super::on_latch_clock(100 * MS, 97 * MS, 100 * MS), 97 * MS);
    // This program's clock 80 ms ahead of ussd's (a time namespace): its ask of 180 ms is
    // ussd's 100 ms, less the stamp's age (2 ms).
    assert_eq!(super::on_latch_clock(180 * MS, 98 * MS, 180 * MS), 98 * MS);
    // 80 ms behind.
    assert_eq!(super::on_latch_clock(20 * MS, 98 * MS, 20 * MS), 98 * MS);
    // Never below 0, never wrapped.
    assert_eq!(super::on_latch_clock(MS, 0, 5 * MS), 0);
    assert_eq!(super::on_latch_clock(u64::MAX, u64::MAX, 0), u64::MAX);
    // A coast ussd latched at its 101 ms, after a program 80 ms ahead asked at its 180 ms
    // (ussd's 100 ms): refused; taken on the program's own clock it would have passed.
    let mut p = Play::running();
    p.show(latched(101 * MS));
    assert_eq!(
        p.s.rearm(
            p.now,
            &p.image,
            super::on_latch_clock(180 * MS, 98 * MS, 180 * MS)
        ),
        Err(SessionError::Tripped { latch_id: 101 * MS })
    );
    assert!(
        p.s.rearm(p.now, &p.image, 180 * MS).is_ok(),
        "on its own clock"
    );
}
