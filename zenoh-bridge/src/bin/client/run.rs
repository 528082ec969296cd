//! `uss-zenoh-client run`: a remote controller of one drive through a bridge that allows remote
//! control. OFF1 until the drive is re-armed, ON every period, OFF1 and a release at the end.
//! What it sends is decided by the client rules every controller runs on
//! (`uss_control::session`), fed with the drive's images as the bridge publishes them: every
//! sample names the latch this client acknowledged (`rearm`). It gives up, sending nothing more,
//! when the drive latches, its own loop stalled past the drive's watchdog time, or the images
//! stop coming: only a new run re-arms the drive.

use core::time::Duration;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use uss_client::uss_shm_types::{LatchView, Session, SessionError, SessionSetup, Step};
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::sample::Sample;

// Its progress lines ignore a reader of stdout that went away: the run goes on and winds the
// drive down at its end as always.
use super::{Failure, on, say};

/// No fresh image for this long, or the drive's handshake time as its image says when that is
/// longer (a full slow line polls a drive only every second or so), and `run` gives up.
const BLIND_AFTER: Duration = Duration::from_secs(1);
/// How long the re-arm may take at least; two handshake times of the drive when longer.
pub const ARM_TIMEOUT: Duration = Duration::from_secs(5);
/// How long the drive may take to ramp down at the end.
const STOP_TIMEOUT: Duration = Duration::from_secs(30);
/// How long the bridge may take to confirm the hand-over, beyond the drive's handshake time: a
/// bridge on a starved CPU or paused for a moment still takes it when it resumes.
const RELEASE_TIMEOUT: Duration = Duration::from_secs(8);
/// How often the release goes out again until the bridge confirms it: one that was lost or
/// came while the bridge was busy is not the last word (a second one is harmless).
const RELEASE_AGAIN: Duration = Duration::from_millis(250);
/// STW1 of the run: ON with everything enabled.
const RUN: u16 = 0x047F;
/// STW1 of OFF1: the re-arming stop, and the stop at the end.
const OFF1: u16 = uss_client::StopCommand::Off1.stw1();
/// The drive's watchdog when its image does not say.
const DEFAULT_WATCHDOG_MS: u64 = 100;

/// The remote controller and what it sees of the drive: the latest image and the bridge's
/// latest control report.
struct Remote<'a> {
    drive: &'a str,
    /// Who sends: `<host>:<pid>`.
    from: String,
    /// How the bridge names this client in its reports (`peer`, `holder_peer`): the name it
    /// sends under and what vouches for it, or that it names none. Every peer reads `from` in
    /// the reports, so a report is this client's only when both match.
    peer: String,
    publisher: Publisher<'a>,
    images: Subscriber<FifoChannelHandler<Sample>>,
    reports: Subscriber<FifoChannelHandler<Sample>>,
    seq: u64,
    period: Duration,
    image: Option<serde_json::Value>,
    seen_at: Instant,
    report: Option<serde_json::Value>,
    /// Whether a report said the bridge handed the drive back on this client's release (seen
    /// as it arrived: a later report of another sender does not hide it).
    released: bool,
    /// The client rules, once the first image said the drive's PZD length and watchdog.
    session: Option<Session>,
    hz: f32,
    /// When this run was asked for: its process's start, on this host's `CLOCK_MONOTONIC`.
    asked_ns: u64,
    /// The image whose `monotonic_ns` (the bridge's clock, that of the latch ids) was furthest
    /// ahead of this host's clock when it arrived: that stamp and when (each image took time
    /// to arrive, so each errs low, and the furthest ahead is the closest).
    bridge_clock: Option<(u64, u64)>,
}

/// The part of an image the client rules look at: live or latched, and which latch (the image
/// names no latch's stop: this client's re-arm sends OFF1).
fn input_of(image: &serde_json::Value) -> LatchView {
    if image["control"] == "live" {
        LatchView::LIVE
    } else {
        LatchView {
            latch: Some(image["latch_id"].as_u64().unwrap_or(0)),
            stop: None,
        }
    }
}

impl Remote<'_> {
    /// Sends a sample the session made: its STW1, the run's Hz (0 for a stop) and the latch it
    /// names.
    fn send_sample(&mut self, sample: &uss_client::uss_shm_types::Sample) -> Result<(), Failure> {
        let stw1 = sample.stw1();
        let hz = if stw1 == RUN { self.hz } else { 0.0 };
        // A sample naming a latch says when its re-arm was asked for; the session names one
        // only once the bridge's clock is known (`arm`).
        let body = match (sample.latch_id, self.asked_on_bridge()) {
            (id, Some(asked)) if id != 0 => {
                format!("\"stw1\":{stw1},\"hz\":{hz:?},\"rearm\":{id},\"asked_ns\":{asked}")
            }
            _ => format!("\"stw1\":{stw1},\"hz\":{hz:?}"),
        };
        self.send(&body)
    }

    /// When this run was asked for, on the bridge's clock, erring early (an image's transit
    /// makes the offset look smaller than it is): a latch that began after the run started is
    /// never taken for one before it.
    fn asked_on_bridge(&self) -> Option<u64> {
        let (theirs, at) = self.bridge_clock?;
        Some(uss_client::uss_shm_types::on_latch_clock(
            self.asked_ns,
            theirs,
            at,
        ))
    }

    fn send(&mut self, body: &str) -> Result<(), Failure> {
        self.seq += 1;
        self.publisher
            .put(format!(
                "{{\"v\":1,\"from\":{:?},\"seq\":{},{body}}}",
                self.from, self.seq
            ))
            .wait()
            .map_err(|error| Failure::Zenoh {
                key: self.publisher.key_expr().to_string(),
                error,
            })
    }

    /// One call of this controller: the session's decision on `stw1` for the drive as its
    /// latest image shows it; a sample it makes is sent; then a period's wait and what arrived
    /// meanwhile. An ON while the re-arming stop is out sends the stop again.
    fn step(&mut self, stw1: u16) -> Result<(), SessionError> {
        let image = self.image.as_ref().map_or(LatchView::LIVE, input_of);
        let now = uss_client::monotonic_ns();
        let Some(session) = self.session.as_mut() else {
            return Ok(());
        };
        let sample = match session.publish(now, &image, |w| w.words[0] = stw1)? {
            Step::Publish(sample) => Some(sample),
            Step::AwaitRearm => match session.publish(now, &image, |_| {})? {
                Step::Publish(stop) => Some(stop),
                Step::AwaitRearm => None,
            },
        };
        if let Some(sample) = sample
            && let Err(e) = self.send_sample(&sample)
        {
            let _ = say(&format!("{}: {e}", self.drive));
        }
        std::thread::sleep(self.every());
        self.look();
        Ok(())
    }

    /// The period between samples: `--period`, or the session's refresh period when the
    /// drive's watchdog is short enough to need it sooner.
    fn every(&self) -> Duration {
        self.session.as_ref().map_or(self.period, |s| {
            self.period.min(Duration::from_nanos(s.refresh_ns()))
        })
    }

    /// The session, made from the first image: the drive's PZD length and watchdog time.
    fn start_session(&mut self) {
        let Some(image) = self.image.as_ref() else {
            return;
        };
        let pzd = 2 + image["words"].as_array().map_or(0, Vec::len);
        let watchdog_ms = image["watchdog_ms"].as_u64().unwrap_or(DEFAULT_WATCHDOG_MS);
        let setup = SessionSetup {
            pzd,
            pid: std::process::id(),
            watchdog_ns: watchdog_ms.saturating_mul(1_000_000),
            first_sequence: 0,
        };
        self.session = Some(Session::new(setup));
    }

    /// The failure a session's refusal ends the run with.
    fn failure(&self, e: SessionError, since: Instant) -> Failure {
        match e {
            SessionError::Stalled { gap_ns, .. } => Failure::Stalled {
                drive: self.drive.to_owned(),
                seconds: gap_ns as f64 / 1e9,
            },
            _ => Failure::Latched {
                drive: self.drive.to_owned(),
                seconds: since.elapsed().as_secs_f64(),
                reason: self.field("latch_reason").to_owned(),
            },
        }
    }

    fn look(&mut self) {
        while let Ok(Some(s)) = self.images.try_recv() {
            if let Ok(v) = serde_json::from_slice::<serde_json::Value>(&s.payload().to_bytes()) {
                if v["stale"] == false {
                    self.seen_at = Instant::now();
                }
                if let Some(theirs) = v["monotonic_ns"].as_u64() {
                    let at = uss_client::monotonic_ns();
                    let ahead = |(t, a): (u64, u64)| i128::from(t) - i128::from(a);
                    if self
                        .bridge_clock
                        .is_none_or(|b| ahead((theirs, at)) > ahead(b))
                    {
                        self.bridge_clock = Some((theirs, at));
                    }
                }
                self.image = Some(v);
            }
        }
        while let Ok(Some(s)) = self.reports.try_recv() {
            self.report = serde_json::from_slice(&s.payload().to_bytes()).ok();
            self.released |= self
                .report
                .as_ref()
                .is_some_and(|r| r["state"] == "released" && self.is_me(r, "sender", "peer"));
        }
    }

    /// The drive's handshake time as its latest image says (at least 1 s).
    fn handshake(&self) -> Duration {
        self.image
            .as_ref()
            .and_then(|i| i["handshake_ms"].as_f64())
            .and_then(|ms| Duration::try_from_secs_f64(ms / 1e3).ok())
            .unwrap_or_default()
            .max(BLIND_AFTER)
    }

    /// No fresh image for longer than the drive's handshake time.
    fn blind(&self) -> bool {
        self.seen_at.elapsed() > self.handshake()
    }

    fn field(&self, name: &str) -> &str {
        self.image
            .as_ref()
            .and_then(|i| i[name].as_str())
            .unwrap_or_default()
    }

    fn live(&self) -> bool {
        self.image
            .as_ref()
            .is_some_and(|i| i["control"] == "live" && i["stale"] == false && i["online"] == true)
    }

    /// HIW in Hz; NaN while ussd reads the drive's reference again (the image says null).
    fn actual_hz(&self) -> f64 {
        self.image
            .as_ref()
            .and_then(|i| i["actual_hz"].as_f64())
            .unwrap_or(f64::NAN)
    }

    /// Whether the image says what the drive's reference is (Hz can be scaled): not while ussd
    /// reads it again after the drive came online, was reset or commissioned.
    fn reference_known(&self) -> bool {
        self.image
            .as_ref()
            .is_some_and(|i| i["actual_hz"].is_number())
    }

    /// [`Failure::Faulted`] while the drive's image shows a fault (ZSW1 bit 3).
    fn not_faulted(&self) -> Result<(), Failure> {
        if self.field("state") != "fault" {
            return Ok(());
        }
        let zsw1 = self
            .image
            .as_ref()
            .and_then(|i| i["zsw1"].as_u64())
            .and_then(|z| u16::try_from(z).ok())
            .unwrap_or_default();
        Err(Failure::Faulted {
            drive: self.drive.to_owned(),
            address: self.drive.rsplit('/').next().unwrap_or_default().to_owned(),
            zsw1,
        })
    }

    /// The bridge's reason for refusing this client's last sample, if it refused it.
    fn refusal(&self) -> Option<String> {
        self.report
            .as_ref()
            .filter(|r| r["state"] == "refused" && self.is_me(r, "sender", "peer"))
            .map(|r| r["error"].as_str().unwrap_or("refused").to_owned())
    }

    /// Whether the bridge holds the drive for another remote controller.
    fn held_by_another(&self) -> bool {
        self.report
            .as_ref()
            .is_some_and(|r| r["holder"].is_string() && !self.is_me(r, "holder", "holder_peer"))
    }

    /// Whether report `r`'s `sender_field` (and its `peer_field`) is this client.
    fn is_me(&self, r: &serde_json::Value, sender_field: &str, peer_field: &str) -> bool {
        r[sender_field] == self.from.as_str()
            && r[peer_field]
                .as_str()
                .is_some_and(|p| p.starts_with(self.peer.as_str()))
    }

    /// Whether the bridge holds the drive for this client.
    fn holds(&self) -> bool {
        self.report
            .as_ref()
            .is_some_and(|r| self.is_me(r, "holder", "holder_peer"))
    }

    /// OFF1 until the drive is live (ussd took the OFF1). A latched drive's OFF1 names the
    /// latch its image shows (the session's re-arm): nothing is sent before an image was seen,
    /// and a latch that comes during the re-arm ends it.
    fn arm(&mut self, stop: &AtomicBool) -> Result<(), Failure> {
        let start = Instant::now();
        let mut deadline = start + ARM_TIMEOUT;
        while self.image.is_none() {
            if Instant::now() >= deadline {
                return Err(Failure::NoImage {
                    drive: self.drive.to_owned(),
                });
            }
            std::thread::sleep(self.every());
            self.look();
        }
        // A drive in fault does not run whatever it is sent: say so, and send nothing.
        self.not_faulted()?;
        self.start_session();
        deadline = deadline.max(start + self.handshake() * 2);
        let image = self.image.as_ref().map_or(LatchView::LIVE, input_of);
        // The re-arm was asked for when this run started: a stop that came since (an operator's
        // coast while it connected) is news it does not clear.
        let asked = self.asked_on_bridge().ok_or_else(|| {
            Failure::ArmRefused(
                "the bridge's images carry no clock (monotonic_ns: an older uss-zenoh), so no \
                 re-arm can say when it was asked for: nothing was re-armed"
                    .to_owned(),
            )
        })?;
        if let Some(session) = self.session.as_mut() {
            let sample = session
                .rearm(uss_client::monotonic_ns(), &image, asked)
                .map_err(|e| match e {
                    SessionError::Tripped { .. } => Failure::StoppedWhileStarting {
                        drive: self.drive.to_owned(),
                        reason: self.field("latch_reason").to_owned(),
                    },
                    e => Failure::ArmRefused(e.to_string()),
                })?;
            self.send_sample(&sample)?;
        }
        loop {
            std::thread::sleep(self.every());
            self.look();
            let image = self.image.as_ref().map_or(LatchView::LIVE, input_of);
            // A new latch during the re-arm (an operator's stop) ends it: the drive latched.
            let rearmed = self.session.as_mut().map(|s| s.rearmed(&image));
            if let Some(Err(e)) = rearmed {
                return Err(self.failure(e, start));
            }
            let refused = self.refusal();
            if let Some(why) = refused.as_ref().filter(|_| !self.held_by_another()) {
                return Err(Failure::ArmRefused(why.clone()));
            }
            // Live by this client's own re-arm, not by someone else's.
            if self.live() && self.holds() {
                return Ok(());
            }
            if Instant::now() >= deadline || stop.load(Ordering::Relaxed) {
                // Another remote controller may be falling silent (the bridge lets go of it
                // when its drive shows the trip): that refusal is final only now.
                if let Some(why) = refused {
                    return Err(Failure::ArmRefused(why));
                }
                return Err(Failure::NotArmed {
                    drive: self.drive.to_owned(),
                    control: self.field("control").to_owned(),
                    latch: self.field("latch_reason").to_owned(),
                });
            }
            // The re-arming stop again, until the bridge holds the drive for this client.
            self.step(OFF1).map_err(|e| self.failure(e, start))?;
        }
    }

    /// ON towards `hz` until `duration` or `stop`; fails when the drive latches, the bridge
    /// refuses a sample, or the images stop coming.
    fn run(
        &mut self,
        hz: f32,
        duration: Option<Duration>,
        stop: &AtomicBool,
    ) -> Result<(), Failure> {
        let start = Instant::now();
        let mut last_note = start;
        // A drive that just came online, was reset or commissioned has its reference read
        // again: the bridge scales no Hz until then, so the re-arming stop goes on meanwhile
        // (its two own reads take up to four of the drive's handshake times, as
        // `DriveWatch::reference_wait` says).
        let deadline = start + self.handshake() * 4;
        while !self.reference_known() && Instant::now() < deadline {
            self.step(OFF1).map_err(|e| self.failure(e, start))?;
        }
        self.hz = hz;
        loop {
            self.step(RUN).map_err(|e| self.failure(e, start))?;
            self.not_faulted()?;
            if !self.live() && self.field("control") == "latched" {
                return Err(Failure::Latched {
                    drive: self.drive.to_owned(),
                    seconds: start.elapsed().as_secs_f64(),
                    reason: self.field("latch_reason").to_owned(),
                });
            }
            if let Some(why) = self.refusal() {
                return Err(Failure::SampleRefused(why));
            }
            if self.blind() {
                return Err(Failure::Blind {
                    drive: self.drive.to_owned(),
                    seconds: self.seen_at.elapsed().as_secs_f64(),
                });
            }
            if stop.load(Ordering::Relaxed) || duration.is_some_and(|d| start.elapsed() >= d) {
                return Ok(());
            }
            if last_note.elapsed() >= Duration::from_millis(500) {
                let _ = say(&format!(
                    "  {:6.1} s  {:8.2} Hz",
                    start.elapsed().as_secs_f64(),
                    self.actual_hz()
                ));
                last_note = Instant::now();
            }
        }
    }

    /// OFF1 along the ramp until the drive is back in S2, then the release; how it ended.
    fn wind_down(&mut self) -> Result<&'static str, Failure> {
        let start = Instant::now();
        let deadline = start + STOP_TIMEOUT;
        while self.field("state") != "S2" && Instant::now() < deadline {
            self.step(OFF1).map_err(|e| self.failure(e, start))?;
            if !self.live() || self.blind() {
                break;
            }
        }
        if let Some(session) = self.session.as_mut() {
            session.release(uss_client::monotonic_ns());
        }
        // The bridge says when it handed the drive back; until then the release goes out again.
        let deadline = Instant::now() + self.handshake() + RELEASE_TIMEOUT;
        let mut sent = None::<Instant>;
        loop {
            if sent.is_none_or(|at| at.elapsed() >= RELEASE_AGAIN) {
                self.send(r#""release":true"#)?;
                sent = Some(Instant::now());
            }
            std::thread::sleep(Duration::from_millis(5));
            self.look();
            if self.released {
                return Ok("released");
            }
            if Instant::now() >= deadline {
                return Ok("not confirmed released (its watchdog stops it all the same)");
            }
        }
    }
}

/// Runs the drive whose key is `drive` (`uss/site/bus0/drive/1`) towards `hz`, sending its
/// samples on `out` (`<drive>/out`, or under this client's name `.../as/<name>/drive/1/out`).
pub fn run(
    session: &zenoh::Session,
    drive: &str,
    out: &str,
    hz: f32,
    duration: Option<Duration>,
    period_ms: u64,
) -> Result<(), Failure> {
    let asked_ns = uss_client::process_start_ns().map_err(Failure::StartTime)?;
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))
            .map_err(|source| Failure::Signal { signal, source })?;
    }
    let drive = drive.trim_end_matches('/');
    let subscribe = |what: &str| {
        session
            .declare_subscriber(format!("{drive}/{what}"))
            .wait()
            .map_err(on(format!("{drive}/{what}")))
    };
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    // The bridge shows a named sender as `"<name>" (...)`, one without a name as this.
    let peer = out.split_once("/as/").map_or_else(
        || "a peer that did not name itself".to_owned(),
        |(_, rest)| format!("{:?}", rest.split('/').next().unwrap_or_default()),
    );
    let mut remote = Remote {
        drive,
        from: format!("{}:{}", host.trim(), std::process::id()),
        peer,
        publisher: session
            .declare_publisher(out.to_owned())
            .encoding(Encoding::APPLICATION_JSON)
            .express(true)
            .wait()
            .map_err(on(out))?,
        images: subscribe("in")?,
        reports: subscribe("control")?,
        // A clock-based start: a later run's samples are newer than this run's.
        seq: u64::try_from(super::unix_ns()).unwrap_or(1),
        period: Duration::from_millis(period_ms.max(1)),
        image: None,
        seen_at: Instant::now(),
        report: None,
        released: false,
        session: None,
        hz: 0.0,
        asked_ns,
        bridge_clock: None,
    };
    remote.arm(&stop)?;
    let _ = say(&format!(
        "{drive}: re-armed; running towards {hz} Hz; {}",
        match duration {
            Some(d) => format!("stopping after {d:?}"),
            None => "Ctrl-C stops it".to_owned(),
        }
    ));
    remote.run(hz, duration, &stop)?;
    let released = remote.wind_down()?;
    let _ = say(&format!(
        "{drive}: stopped (OFF1, {}, {:.2} Hz) and {released}",
        remote.field("state"),
        remote.actual_hz()
    ));
    Ok(())
}
