//! `uss-zenoh-client run`: a remote controller of one drive through a bridge that allows remote
//! control. OFF1 until the drive is re-armed, ON every period, OFF1 and a release at the end.
//! It gives up, sending nothing more, when the drive latches or its images stop coming: only a
//! new run re-arms the drive.

use core::time::Duration;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use zenoh::Wait;
use zenoh::bytes::Encoding;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::sample::Sample;

// Its progress lines ignore a reader of stdout that went away: the run goes on and winds the
// drive down at its end as always.
use super::{Failure, on, say};

/// No fresh image for this long and `run` gives up.
const BLIND_AFTER: Duration = Duration::from_secs(1);
/// How long the re-arm may take.
pub const ARM_TIMEOUT: Duration = Duration::from_secs(5);
/// How long the drive may take to ramp down at the end.
const STOP_TIMEOUT: Duration = Duration::from_secs(30);
const OFF1: &str = r#""stw1":1150,"hz":0.0"#;

/// The remote controller and what it sees of the drive: the latest image and the bridge's
/// latest control report.
struct Remote<'a> {
    drive: &'a str,
    /// Who sends: `<host>:<pid>`.
    from: String,
    publisher: Publisher<'a>,
    images: Subscriber<FifoChannelHandler<Sample>>,
    reports: Subscriber<FifoChannelHandler<Sample>>,
    seq: u64,
    period: Duration,
    image: Option<serde_json::Value>,
    seen_at: Instant,
    report: Option<serde_json::Value>,
}

impl Remote<'_> {
    fn send(&mut self, body: &str) -> Result<(), Failure> {
        self.seq += 1;
        self.publisher
            .put(format!(
                "{{\"v\":1,\"from\":{:?},\"seq\":{},{body}}}",
                self.from, self.seq
            ))
            .wait()
            .map_err(|error| Failure::Zenoh {
                key: format!("{}/out", self.drive),
                error,
            })
    }

    /// Sends `body`, waits a period, and takes in what arrived meanwhile.
    fn step(&mut self, body: &str) -> Result<(), Failure> {
        self.send(body)?;
        std::thread::sleep(self.period);
        self.look();
        Ok(())
    }

    fn look(&mut self) {
        while let Ok(Some(s)) = self.images.try_recv() {
            if let Ok(v) = serde_json::from_slice::<serde_json::Value>(&s.payload().to_bytes()) {
                if v["stale"] == false {
                    self.seen_at = Instant::now();
                }
                self.image = Some(v);
            }
        }
        while let Ok(Some(s)) = self.reports.try_recv() {
            self.report = serde_json::from_slice(&s.payload().to_bytes()).ok();
        }
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

    fn actual_hz(&self) -> f64 {
        self.image
            .as_ref()
            .and_then(|i| i["actual_hz"].as_f64())
            .unwrap_or_default()
    }

    /// The bridge's reason for refusing this client's last sample, if it refused it.
    fn refusal(&self) -> Option<String> {
        self.report
            .as_ref()
            .filter(|r| r["state"] == "refused" && r["sender"] == self.from.as_str())
            .map(|r| r["error"].as_str().unwrap_or("refused").to_owned())
    }

    /// Whether the bridge holds the drive for another remote controller.
    fn held_by_another(&self) -> bool {
        self.report
            .as_ref()
            .is_some_and(|r| r["holder"].is_string() && r["holder"] != self.from.as_str())
    }

    /// Whether the bridge holds the drive for this client.
    fn holds(&self) -> bool {
        self.report
            .as_ref()
            .is_some_and(|r| r["holder"] == self.from.as_str())
    }

    /// OFF1 until the drive is live (ussd took the OFF1). A latched drive's OFF1 names the
    /// latch its image shows: nothing is sent before an image was seen.
    fn arm(&mut self, stop: &AtomicBool) -> Result<(), Failure> {
        let deadline = Instant::now() + ARM_TIMEOUT;
        while self.image.is_none() {
            if Instant::now() >= deadline {
                return Err(Failure::NoImage {
                    drive: self.drive.to_owned(),
                });
            }
            std::thread::sleep(self.period);
            self.look();
        }
        loop {
            let latch = self
                .image
                .as_ref()
                .filter(|i| i["control"] == "latched")
                .and_then(|i| i["latch_id"].as_u64());
            match latch {
                Some(id) => self.step(&format!("{OFF1},\"rearm\":{id}"))?,
                None => self.step(OFF1)?,
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
        let on = format!(r#""stw1":1151,"hz":{hz}"#);
        loop {
            self.step(&on)?;
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
            if self.seen_at.elapsed() > BLIND_AFTER {
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
        let deadline = Instant::now() + STOP_TIMEOUT;
        while self.field("state") != "S2" && Instant::now() < deadline {
            self.step(OFF1)?;
            if !self.live() || self.seen_at.elapsed() > BLIND_AFTER {
                break;
            }
        }
        self.send(r#""release":true"#)?;
        // The bridge says when it handed the drive back.
        let deadline = Instant::now() + Duration::from_secs(2);
        loop {
            self.look();
            if self
                .report
                .as_ref()
                .is_some_and(|r| r["state"] == "released")
            {
                return Ok("released");
            }
            if Instant::now() >= deadline {
                return Ok("not confirmed released (its watchdog stops it all the same)");
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

/// Runs the drive whose key is `drive` (`uss/site/bus0/drive/1`) towards `hz`.
pub fn run(
    session: &zenoh::Session,
    drive: &str,
    hz: f32,
    duration: Option<Duration>,
    period_ms: u64,
) -> Result<(), Failure> {
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
    let mut remote = Remote {
        drive,
        from: format!("{}:{}", host.trim(), std::process::id()),
        publisher: session
            .declare_publisher(format!("{drive}/out"))
            .encoding(Encoding::APPLICATION_JSON)
            .express(true)
            .wait()
            .map_err(on(format!("{drive}/out")))?,
        images: subscribe("in")?,
        reports: subscribe("control")?,
        // A clock-based start: a later run's samples are newer than this run's.
        seq: u64::try_from(super::unix_ns()).unwrap_or(1),
        period: Duration::from_millis(period_ms.max(1)),
        image: None,
        seen_at: Instant::now(),
        report: None,
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
