//! Control over the network, fail-safe.
//!
//! **Operator stops, always.** A query on `.../drive/<addr>/stop` (or `.../stop` for every drive)
//! with `off1` (the default), `off2` or `off3` as its payload is an operator's stop through ussd,
//! whoever controls the drive, exactly like `ussctl stop/coast/quick-stop`: a safe command is
//! sendable from anywhere, so this needs no `--allow-control`. The reply comes once the drive's
//! image shows the command went out.
//!
//! **Remote control, only with `--allow-control`.** A remote controller publishes samples on
//! `.../drive/<addr>/out` ([`Out`]). The bridge takes the drive's local exclusive controller at
//! the first sample and passes each fresh sample on as one publish, and nothing else: it never
//! refreshes on its own. So ussd's watchdog sees the remote controller itself: when its samples
//! stop arriving within the drive's watchdog time (a partition, a dead remote, a bridge crash),
//! the drive gets its safe command, latched, and only an OFF1 then an ON of the remote
//! controller re-arm it (docs/ARCHITECTURE.md, "Failure model"). A sample that cannot be passed
//! on (unreadable, old, refused by the controller rules) is reported on `.../control` and not
//! sent, so a controller that speaks garbage trips the drive too. After [`RELEASE_AFTER`]
//! without samples the bridge hands the drive back, so a local controller can take it.

use crate::keys::Keys;
use crate::payload::{ControlReport, Out, StopReply, VERSION, unix_ns};
use core::time::Duration;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use uss_client::{Bus, ClientError, ControlOptions, Controller, Latch, StopCommand};
use zenoh::bytes::Encoding;
use zenoh::query::Query;
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

/// A remote controller silent this long loses the drive: the bridge releases its controller
/// (the drive tripped long before, at its watchdog time). Above Zenoh's default lease (10 s),
/// so a short partition keeps the drive's latch reason ("controller stale") for the operator.
pub const RELEASE_AFTER: Duration = Duration::from_secs(15);
/// How long a stop query waits for the drive's image to show the command: an offline drive is
/// probed only every `offline_probe_ms`.
const STOP_TIMEOUT: Duration = Duration::from_secs(3);
/// How often the control report goes out besides on every change, while the bridge holds the
/// drive's controller.
const REPORT_EVERY: Duration = Duration::from_secs(1);
/// How often a bus without ussd is tried again.
const RECONNECT: Duration = Duration::from_millis(250);

/// What a stop query's payload asks for.
fn stop_command(payload: Option<&str>) -> Result<StopCommand, String> {
    match payload.map(str::trim).unwrap_or_default() {
        "" | "off1" | "OFF1" => Ok(StopCommand::Off1),
        "off2" | "OFF2" => Ok(StopCommand::Off2),
        "off3" | "OFF3" => Ok(StopCommand::Off3),
        other => Err(format!(
            "{other:?} is not a stop command: send off1 (ramp down, the default), off2 (coast) or off3 (quick stop)"
        )),
    }
}

/// The answer to one stop query: the JSON of the drive's [`StopReply`] (an array of them for
/// every drive: replies on one key would be consolidated into one), or the error text.
fn stop(bus: &Bus, name: &str, keys: &Keys, query: &Query) -> Result<String, String> {
    let target = keys.stop_of(query.key_expr().as_str())?;
    let payload = query
        .payload()
        .map(|p| p.try_to_string().map(std::borrow::Cow::into_owned))
        .transpose()
        .map_err(|_| "the stop command is not text: send off1, off2 or off3".to_owned())?;
    let command = stop_command(payload.as_deref())?;
    let drives = match target {
        Some(drive) => bus
            .stop_drive(drive, command)
            .map(|()| vec![drive])
            .map_err(|e| e.to_string())?,
        None => bus.stop_all(command).map_err(|e| e.to_string())?,
    };
    let mut replies = Vec::new();
    for drive in drives {
        let last = bus
            .wait_stopped(drive, command, STOP_TIMEOUT)
            .map_err(|e| format!("drive {drive}: {} sent, not confirmed: {e}", command.name()))?;
        replies.push(StopReply::new(name, drive, command, &last));
    }
    let json = match (target, replies.as_slice()) {
        (Some(_), [one]) => serde_json::to_string(one),
        _ => serde_json::to_string(&replies),
    };
    json.map_err(|e| e.to_string())
}

/// Serves the operator stops of bus `name` until `stop_flag`: every query ends in exactly one
/// answer (a reply, or an error reply).
pub fn serve_stops(session: &Session, name: &str, keys: &Keys, stop_flag: &Arc<AtomicBool>) {
    let key = keys.stops();
    let queryable = match session.declare_queryable(&key).wait() {
        Ok(q) => q,
        Err(e) => {
            eprintln!("uss-zenoh: cannot declare the queryable {key}: {e}");
            return;
        }
    };
    let mut bus: Result<Bus, String> = Err(format!("ussd is not running on {name}"));
    while !stop_flag.load(Ordering::Relaxed) {
        let query = match queryable.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(q)) => q,
            Ok(None) => continue,
            Err(_) => break,
        };
        if bus.is_err() {
            bus = Bus::open_as(name, "uss-zenoh-stops").map_err(|e| e.to_string());
        }
        let answer = bus
            .as_ref()
            .map_err(Clone::clone)
            .and_then(|b| stop(b, name, keys, &query));
        crate::params::reply(&query, answer);
    }
}

/// What a remote controller's sample gets while the bridge does not allow remote control.
pub const CONTROL_REFUSED: &str =
    "remote control is refused: this uss-zenoh runs without --allow-control";

/// Serves the remote controllers of every drive of bus `name` (one thread per drive, so a
/// re-arm handshake of one drive never delays another's samples) until `stop_flag`; without
/// `allowed`, every sample is refused (and the refusal reported), none is passed on.
pub fn serve_control(
    session: &Session,
    name: &str,
    keys: &Keys,
    allowed: bool,
    stop_flag: &Arc<AtomicBool>,
) {
    let bus = loop {
        if stop_flag.load(Ordering::Relaxed) {
            return;
        }
        match Bus::open_as(name, "uss-zenoh-control") {
            Ok(bus) => break bus,
            Err(_) => std::thread::sleep(RECONNECT),
        }
    };
    // A thread for each drive of the ussd serving the bus, and for each drive a restarted ussd
    // adds (a drive it no longer runs refuses the samples: not on the bus).
    let mut threads = Vec::new();
    let mut served: Vec<u8> = Vec::new();
    while !stop_flag.load(Ordering::Relaxed) {
        for drive in bus.drives() {
            if served.contains(&drive) {
                continue;
            }
            served.push(drive);
            let (session, name, keys) = (session.clone(), name.to_owned(), keys.clone());
            let stop_flag = Arc::clone(stop_flag);
            let spawned = std::thread::Builder::new()
                .name(format!("control-{drive}"))
                .spawn(move || {
                    control_drive(&session, &name, &keys, (drive, allowed), &stop_flag);
                });
            match spawned {
                Ok(t) => threads.push(t),
                Err(e) => {
                    eprintln!("uss-zenoh: cannot start the control thread of drive {drive}: {e}");
                }
            }
        }
        std::thread::sleep(Duration::from_secs(1));
    }
    for t in threads {
        let _ = t.join();
    }
}

/// One drive under remote control.
struct Remote<'a> {
    session: &'a Session,
    bus: Bus,
    name: &'a str,
    drive: u8,
    allowed: bool,
    report_key: String,
    controller: Option<Controller>,
    /// The sequence number of the last sample passed on (reset when the drive is handed back).
    last_seq: Option<u64>,
    last_sample: Option<Instant>,
    report: ControlReport<'a>,
    reported: Option<ControlReport<'a>>,
    next_report: Instant,
}

impl Remote<'_> {
    /// Passes one sample on, or says why not.
    fn take(&mut self, sample: &Sample) -> Result<(), String> {
        self.last_sample = Some(Instant::now());
        if !self.allowed {
            return Err(CONTROL_REFUSED.to_owned());
        }
        let out = Out::parse(&sample.payload().to_bytes())?;
        if let Some(last) = self.last_seq.filter(|&last| out.seq <= last) {
            return Err(format!(
                "old sample: seq {} is not above {last}, the last one taken",
                out.seq
            ));
        }
        if out.release {
            self.release();
            self.last_seq = Some(out.seq);
            return Ok(());
        }
        if self.controller.is_none() {
            let c = self
                .bus
                .control(self.drive, ControlOptions::default())
                .map_err(|e| e.to_string())?;
            self.controller = Some(c);
        }
        let Some(c) = &self.controller else {
            return Err("no controller".to_owned());
        };
        let info = c.inputs().info();
        let words = out.pzd(usize::from(info.pzd_words), info.reference_hz)?;
        let off1 = words
            .first()
            .is_some_and(|w| w & uss_client::uss_shm_types::pzd::STW1_ON == 0);
        let sent = match c.set_words(&words) {
            // The remote controller's OFF1 after a trip is its acknowledgment: re-arm (OFF1,
            // until ussd took it), then its words.
            Err(ClientError::Tripped { .. }) if off1 => c.rearm().and_then(|_| c.set_words(&words)),
            other => other,
        };
        match sent {
            Ok(()) => {
                self.last_seq = Some(out.seq);
                self.report.seq = Some(out.seq);
                Ok(())
            }
            Err(ClientError::Tripped { latch, .. } | ClientError::NotArmed { latch, .. }) => {
                Err(latched(self.name, self.drive, &latch))
            }
            Err(e) => Err(e.to_string()),
        }
    }

    /// Hands the drive back (ussd sends its safe command, latched as "released").
    fn release(&mut self) {
        if let Some(c) = self.controller.take() {
            let _ = c.release();
            self.report.state = "released";
            self.report.error = None;
        }
        self.last_seq = None;
    }

    /// Publishes the report when it changed or is due.
    fn publish_report(&mut self) {
        let changed = self.reported.as_ref() != Some(&self.report);
        let due = self.controller.is_some() && Instant::now() >= self.next_report;
        if !changed && !due {
            return;
        }
        self.report.published_unix_ns = unix_ns();
        if let Ok(json) = serde_json::to_string(&self.report)
            && let Err(e) = self
                .session
                .put(&self.report_key, json)
                .encoding(Encoding::APPLICATION_JSON)
                .wait()
        {
            eprintln!("uss-zenoh: put {}: {e}", self.report_key);
        }
        self.report.published_unix_ns = 0;
        self.reported = Some(self.report.clone());
        self.next_report = Instant::now() + REPORT_EVERY;
    }
}

/// A latch in words a remote controller can act on.
fn latched(bus: &str, drive: u8, latch: &Latch) -> String {
    format!(
        "drive {drive} on {bus} is latched ({latch}) and gets {}: nothing was sent; re-arm it \
         with OFF1 (stw1 1150 = 0x047E), then ON",
        latch.command
    )
}

/// Serves the remote controller of one drive until `stop_flag`; hands the drive back on the
/// way out.
fn control_drive(
    session: &Session,
    name: &str,
    keys: &Keys,
    (drive, allowed): (u8, bool),
    stop_flag: &AtomicBool,
) {
    let key = keys.output(drive);
    let subscriber = match session.declare_subscriber(&key).wait() {
        Ok(s) => s,
        Err(e) => {
            eprintln!("uss-zenoh: cannot subscribe to {key}: {e}");
            return;
        }
    };
    let bus = loop {
        if stop_flag.load(Ordering::Relaxed) {
            return;
        }
        match Bus::open_as(name, "uss-zenoh-control") {
            Ok(bus) => break bus,
            Err(_) => std::thread::sleep(RECONNECT),
        }
    };
    let mut remote = Remote {
        session,
        bus,
        name,
        drive,
        allowed,
        report_key: keys.control(drive),
        controller: None,
        last_seq: None,
        last_sample: None,
        report: ControlReport {
            v: VERSION,
            bus: name,
            drive,
            state: "idle",
            seq: None,
            error: None,
            taken: 0,
            refused: 0,
            published_unix_ns: 0,
        },
        reported: None,
        next_report: Instant::now(),
    };
    while !stop_flag.load(Ordering::Relaxed) {
        if let Ok(Some(sample)) = subscriber.recv_timeout(Duration::from_millis(200)) {
            match remote.take(&sample) {
                Ok(()) => {
                    remote.report.taken += 1;
                    remote.report.error = None;
                    if remote.controller.is_some() {
                        remote.report.state = "controlling";
                    }
                }
                Err(e) => {
                    remote.report.refused += 1;
                    remote.report.state = "refused";
                    remote.report.error = Some(e);
                }
            }
        }
        if remote.controller.is_some()
            && remote
                .last_sample
                .is_some_and(|t| t.elapsed() > RELEASE_AFTER)
        {
            remote.release();
        }
        remote.publish_report();
    }
    remote.release();
}
