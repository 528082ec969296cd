//! Control over the network, fail-safe.
//!
//! **Operator stops, always.** A query on `.../drive/<addr>/stop` (or `.../stop` for every drive)
//! with `off1` (the default), `off2` or `off3` as its payload is an operator's stop through ussd,
//! whoever controls the drive, exactly like `ussctl stop/coast/quick-stop`: a safe command is
//! sendable from anywhere, so this needs no `--allow-control`. The command goes to ussd as soon
//! as the query arrives; the reply comes once the drive's image shows it went out (or says it
//! was not confirmed), from a thread of its own, so one stop never waits for another.
//!
//! **Remote control, only with `--allow-control`.** A remote controller publishes samples on
//! `.../drive/<addr>/out` ([`Out`]). The bridge takes the drive's local exclusive controller and
//! passes each fresh sample on as one publish, and nothing else: it never refreshes on its own.
//! While a sender (`from`) controls the drive (its last sample passed on within the drive's
//! watchdog time) every other sender is refused. So ussd's watchdog sees the remote controller
//! itself: when its samples stop arriving within the drive's watchdog time (a partition, a dead
//! remote, a bridge crash), the drive gets its safe command, latched. A latched drive is
//! re-armed only by a stop (OFF1, OFF2, OFF3) that names the latch it acknowledges (`rearm` =
//! the image's `latch_id`), then an ON: a sample sent before the latch, delivered late after a
//! partition, or from a controller that never saw the latch, re-arms nothing
//! (docs/ARCHITECTURE.md, "Failure model"). A sample that is not passed on (unreadable, old,
//! from another sender, refused by the controller rules) is reported on `.../control` and not
//! sent, so a controller that speaks garbage trips the drive too. After [`RELEASE_AFTER`]
//! without a sample taken the bridge hands the drive back, so a local controller can take it.
//!
//! Samples reach the bridge through one subscriber whose callback never blocks Zenoh: it queues
//! them for a dispatcher, which hands each drive's samples to a thread of that drive (a re-arm
//! handshake of one drive never delays another's samples) and reports itself what it cannot
//! hand on (control not allowed, ussd not running, a drive ussd does not poll, a full queue).

use crate::gate::{Gate, Peer};
use crate::keys::{Keys, StopTarget};
use crate::payload::{ControlReport, Out, SampleError, StopReply, unix_ns};
use crate::policy::Right;
use crate::refusal::Refusal;
use core::time::Duration;
use crossbeam_channel::{Receiver, Sender, TrySendError};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use uss_client::{
    Address, Bus, ClientError, ControlOptions, Controller, DriveWatch, ErrorKind, PzdInput,
    StopCommand,
};
use zenoh::bytes::Encoding;
use zenoh::handlers::FifoChannelHandler;
use zenoh::query::{Query, Queryable};
use zenoh::sample::Sample;
use zenoh::{Session, Wait};

/// A remote controller silent this long loses the drive: the bridge releases its controller
/// (the drive tripped long before, at its watchdog time). Above Zenoh's default lease (10 s),
/// so a short partition keeps the drive's latch reason ("controller stale") for the operator.
pub const RELEASE_AFTER: Duration = Duration::from_secs(15);
/// How long a stop query waits at least for the drives' images to show the command; longer
/// when a drive's handshake time (its turn on a slow full line, its next probe while offline)
/// says so, up to [`STOP_TIMEOUT_MAX`].
const STOP_TIMEOUT: Duration = Duration::from_secs(3);
/// The longest a stop query waits, well inside a client's query timeout (10 s): a drive not
/// confirmed by then is marked unconfirmed (an offline drive probed every minute).
const STOP_TIMEOUT_MAX: Duration = Duration::from_secs(8);
/// How often the control report goes out besides on every change, while the bridge holds the
/// drive's controller.
const REPORT_EVERY: Duration = Duration::from_secs(1);
/// A sample as the dispatcher read it: parsed once, or why it could not be.
type Parsed = Result<Out, SampleError>;
/// A sample for a drive's thread: as parsed, and who sent it.
type FromPeer = (Parsed, Peer);

/// Samples waiting for the dispatcher, and for each drive's thread.
const QUEUE: usize = 1024;
/// Stop replies being confirmed at once; beyond, a stop is sent and its reply says it is not
/// confirmed.
const MAX_CONFIRMING: usize = 4;
const DRIVE_QUEUE: usize = 64;

/// What a remote controller's sample gets while the bridge does not allow remote control.
pub const CONTROL_REFUSED: &str =
    "remote control is refused: this uss-zenoh runs without --allow-control";

/// What a stop query's payload asks for.
fn stop_command(payload: Option<&str>) -> Result<StopCommand, Refusal> {
    match payload.map(str::trim).unwrap_or_default() {
        "" | "off1" | "OFF1" => Ok(StopCommand::Off1),
        "off2" | "OFF2" => Ok(StopCommand::Off2),
        "off3" | "OFF3" => Ok(StopCommand::Off3),
        other => Err(Refusal::invalid(format!(
            "{other:?} is not a stop command: send off1 (ramp down, the default), off2 (coast) or off3 (quick stop)"
        ))),
    }
}

/// What a stop query sent: the command, what it named (the drives it went to, and the keys
/// their replies go out under), and when it was sent (`CLOCK_MONOTONIC` ns: the latch that
/// confirms it began then or later).
type Sent = (StopCommand, StopTarget, Vec<Address>, u64);

/// Sends the stop a query asks for, or says why not.
fn send_stop(bus: &Bus, keys: &Keys, gate: &Gate, query: &Query) -> Result<Sent, Refusal> {
    let key = query.key_expr().as_str();
    let (name, keys) = keys
        .sender(key)
        .map_err(|e| Refusal::invalid(e.to_string()))?;
    let peer = gate.peer(name);
    let drives = if crate::keys::has_wildcards(key) {
        bus.drives()
    } else {
        Vec::new()
    };
    let target = keys
        .stops_named(key, &drives)
        .map_err(|e| Refusal::invalid(e.to_string()))?;
    match &target {
        StopTarget::Bus(_) => gate.check(&peer, Right::Stop, None)?,
        StopTarget::Drives(named) => {
            for (drive, _) in named {
                gate.check(&peer, Right::Stop, Some(*drive))?;
            }
        }
    }
    let payload = query
        .payload()
        .map(|p| p.try_to_string().map(std::borrow::Cow::into_owned))
        .transpose()
        .map_err(|_| Refusal::invalid("the stop command is not text: send off1, off2 or off3"))?;
    let command = stop_command(payload.as_deref())?;
    let sent_ns = uss_client::monotonic_ns();
    let drives = match &target {
        StopTarget::Drives(named) => {
            let mut sent = Vec::new();
            for (drive, _) in named {
                bus.stop_drive(*drive, command).map_err(Refusal::from)?;
                sent.push(*drive);
            }
            sent
        }
        StopTarget::Bus(_) => bus.stop_all(command).map_err(Refusal::from)?,
    };
    Ok((command, target, drives, sent_ns))
}

/// The reply to a stop that went out: each drive's image once it shows the command, within
/// [`STOP_TIMEOUT`] or the longest handshake time of the drives (at most
/// [`STOP_TIMEOUT_MAX`]) for all of them; a drive that does not show it in time is marked
/// unconfirmed ([`stop_json`]).
fn confirm_stop<'a>(
    name: &'a str,
    command: StopCommand,
    drives: &[Address],
    sent_ns: u64,
) -> Vec<StopReply<'a>> {
    let bus = Bus::open_as(name, "uss-zenoh-stop").ok();
    let wait = bus.as_ref().map_or(STOP_TIMEOUT, |b| {
        drives
            .iter()
            .filter_map(|&d| b.watch(d).ok().map(|w| w.handshake()))
            .fold(STOP_TIMEOUT, Duration::max)
            .min(STOP_TIMEOUT_MAX)
    });
    let deadline = Instant::now() + wait;
    let replies: Vec<StopReply<'_>> = drives
        .iter()
        .map(|&drive| {
            let left = deadline.saturating_duration_since(Instant::now());
            let shown = bus
                .as_ref()
                .ok_or_else(|| {
                    Refusal::new(
                        ErrorKind::NotRunning,
                        format!("ussd is not running on {name}"),
                    )
                })
                .and_then(|b| {
                    b.wait_stopped_since(drive, command, sent_ns, Some(left))
                        .map_err(Refusal::from)
                });
            StopReply::new(name, drive.get(), command, shown)
        })
        .collect();
    replies
}

/// Ends a stop query: for the bus, one reply (an array: replies on one key would be
/// consolidated into one) under `.../stop`; for drives, each drive's reply under its own key.
fn reply_stops(query: &Query, target: &StopTarget, replies: &[StopReply<'_>]) {
    match target {
        StopTarget::Bus(key) => {
            let json = serde_json::to_string(replies).unwrap_or_default();
            crate::params::reply_as(query, key, Ok(json));
        }
        StopTarget::Drives(named) => {
            for (reply, (_, key)) in replies.iter().zip(named) {
                let json = serde_json::to_string(reply).unwrap_or_default();
                crate::params::reply_as(query, key, Ok(json));
            }
        }
    }
}

/// Serves the operator stops of bus `name` until `stop_flag`: each stop goes to ussd as soon as
/// its query arrives; every query ends in exactly one answer (a reply, or an error reply).
pub fn serve_stops(
    queryable: &Queryable<FifoChannelHandler<Query>>,
    name: &str,
    keys: &Keys,
    gate: &Gate,
    stop_flag: &Arc<AtomicBool>,
) {
    let mut bus: Result<Bus, Refusal> = Err(Refusal::new(
        ErrorKind::NotRunning,
        format!("ussd is not running on {name}"),
    ));
    let confirming = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    while !stop_flag.load(Ordering::Relaxed) {
        let query = match queryable.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(q)) => q,
            Ok(None) => continue,
            Err(_) => break,
        };
        if bus.is_err() {
            bus = Bus::open_as(name, "uss-zenoh-stops").map_err(Refusal::from);
        }
        let sent = bus
            .as_ref()
            .map_err(Clone::clone)
            .and_then(|b| send_stop(b, keys, gate, &query));
        match sent {
            Ok((command, target, drives, sent_ns)) => {
                if confirming.load(Ordering::Relaxed) >= MAX_CONFIRMING {
                    // Each confirmation holds a reader of ussd's services: a flood of stops must
                    // not take them from ussctl and the controllers. The stop went out.
                    let replies: Vec<_> = drives
                        .iter()
                        .map(|&d| {
                            let why = Refusal::new(
                                ErrorKind::WaitTimeout,
                                format!(
                                    "sent; not confirmed: {MAX_CONFIRMING} stops are being \
                                     confirmed"
                                ),
                            );
                            StopReply::new(name, d.get(), command, Err(why))
                        })
                        .collect();
                    reply_stops(&query, &target, &replies);
                    continue;
                }
                confirming.fetch_add(1, Ordering::Relaxed);
                let (name, confirming) = (name.to_owned(), Arc::clone(&confirming));
                let confirmed = std::thread::Builder::new()
                    .name("stop-reply".to_owned())
                    .spawn(move || {
                        let replies = confirm_stop(&name, command, &drives, sent_ns);
                        reply_stops(&query, &target, &replies);
                        confirming.fetch_sub(1, Ordering::Relaxed);
                    });
                if let Err(e) = confirmed {
                    eprintln!("uss-zenoh: cannot start a thread for a stop's reply: {e}");
                }
            }
            Err(refusal) => crate::params::reply(&query, Err(refusal)),
        }
    }
}

/// The drives of one bus the bridge holds for a remote controller, with who holds each: its
/// `from`, and its certificate's name when Zenoh bound its key to it (an access policy that
/// lists it). ussd's rule "a controlled drive takes no writes from another process" sees one
/// process in the bridge, whichever peer asks; so the bridge applies it per peer
/// ([`crate::params`]): while it holds a drive, a parameter write to it is refused unless it
/// comes from the holder's own certificate (a peer it cannot tell apart from another is
/// refused).
#[derive(Debug, Default)]
pub struct Held {
    holders: Mutex<HashMap<Address, Holder>>,
}

/// Who the bridge holds a drive for.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Holder {
    /// The remote controller's `from`.
    pub from: String,
    /// Its certificate's name, when the bridge knows it for sure.
    pub verified: Option<String>,
}

impl Held {
    /// Who holds `drive`, if the bridge holds it.
    pub fn holder(&self, drive: Address) -> Option<Holder> {
        self.holders
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get(&drive)
            .cloned()
    }

    /// Who holds `drive` for a remote controller other than `peer`: a controller that named no
    /// verified identity, or another one than `peer`'s. Such a holder's drive takes no
    /// parameter write or commissioning from `peer`.
    pub fn held_from(&self, drive: Address, peer: &crate::gate::Peer) -> Option<Holder> {
        self.holder(drive)
            .filter(|h| h.verified.is_none() || h.verified.as_deref() != peer.verified_name())
    }

    fn set(&self, drive: Address, holder: Option<Holder>) {
        let mut holders = self
            .holders
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        match holder {
            Some(h) => holders.insert(drive, h),
            None => holders.remove(&drive),
        };
    }
}

/// Serves the remote controllers of bus `name` until `stop_flag`; without `allowed`, every
/// sample is refused (and the refusal reported), none is passed on. The drives it holds are
/// kept in `held`.
pub fn serve_control(
    session: &Session,
    name: &str,
    keys: &Keys,
    allowed: bool,
    gate: &Gate,
    held: &Arc<Held>,
    stop_flag: &Arc<AtomicBool>,
) {
    let (tx, rx) = crossbeam_channel::bounded::<Sample>(QUEUE);
    // Samples of peers that do not name themselves, and of those that do (.../as/<name>/...).
    let mut subscribers = Vec::new();
    for key in [keys.outputs(), keys.named().outputs()] {
        let tx = tx.clone();
        // The callback runs on Zenoh's own thread: it never blocks it (a full queue drops the
        // sample, and the drive's watchdog sees a missing sample as it sees a lost one).
        let subscriber = session
            .declare_subscriber(&key)
            .callback(move |sample| {
                let _ = tx.try_send(sample);
            })
            .wait();
        match subscriber {
            Ok(s) => subscribers.push(s),
            Err(e) => {
                eprintln!("uss-zenoh: cannot subscribe to {key}: {e}");
                return;
            }
        }
    }
    drop(tx);
    let mut d = Dispatcher {
        session,
        name,
        keys,
        allowed,
        gate,
        held,
        stop_flag,
        bus: None,
        next_open: Instant::now(),
        drives: HashMap::new(),
        refused: HashMap::new(),
    };
    while !stop_flag.load(Ordering::Relaxed) {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(sample) => d.dispatch(&sample),
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        }
    }
    for (_, (tx, thread)) in d.drives.drain() {
        drop(tx);
        let _ = thread.join();
    }
}

/// Hands each drive's samples to that drive's thread.
struct Dispatcher<'a> {
    session: &'a Session,
    name: &'a str,
    keys: &'a Keys,
    allowed: bool,
    gate: &'a Gate,
    held: &'a Arc<Held>,
    stop_flag: &'a Arc<AtomicBool>,
    bus: Option<Bus>,
    /// When ussd is tried again while it is not running.
    next_open: Instant,
    drives: HashMap<Address, (Sender<FromPeer>, std::thread::JoinHandle<()>)>,
    /// Samples this dispatcher refused, per drive.
    refused: HashMap<Address, u64>,
}

impl Dispatcher<'_> {
    fn dispatch(&mut self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        // A key with a wildcard for the name was published by nobody in particular: dropped.
        let Ok((name, keys)) = self.keys.sender(key) else {
            return;
        };
        let Some(drive) = keys.output_of(key) else {
            return;
        };
        let peer = self.gate.peer(name);
        let parsed = Out::parse(&sample.payload().to_bytes());
        let sender = parsed.as_ref().ok().map(|o| o.from.clone());
        let who = peer.to_string();
        if let Err(why) = self.hand_on(drive, parsed, peer) {
            let refused = self.refused.entry(drive).or_default();
            *refused += 1;
            let mut report = ControlReport::new(self.name, drive.get());
            report.state = "refused";
            report.sender = sender;
            report.peer = Some(who);
            report.set_error(Some(&why));
            report.refused = *refused;
            put_report(self.session, &self.keys.control(drive), &report);
        }
    }

    fn hand_on(&mut self, drive: Address, sample: Parsed, peer: Peer) -> Result<(), Refusal> {
        if !self.allowed {
            self.gate.count(&peer, Right::Control, CONTROL_REFUSED);
            return Err(Refusal::refused(CONTROL_REFUSED));
        }
        // A control report carries the refusal (the remote controller's report says why).
        self.gate.check(&peer, Right::Control, Some(drive))?;
        if self.bus.is_none() && Instant::now() >= self.next_open {
            self.next_open = Instant::now() + Duration::from_millis(250);
            self.bus = Bus::open_as(self.name, "uss-zenoh-control").ok();
        }
        let bus = self.bus.as_ref().ok_or_else(|| not_running(self.name))?;
        if !self.drives.contains_key(&drive) {
            let known = bus.drives();
            if !known.contains(&drive) {
                return Err(Refusal::new(
                    ErrorKind::UnknownDrive,
                    format!(
                        "drive {drive} is not on {} (ussd polls drives {known:?} there)",
                        self.name
                    ),
                ));
            }
            let (tx, rx) = crossbeam_channel::bounded(DRIVE_QUEUE);
            let (session, name, keys) = (
                self.session.clone(),
                self.name.to_owned(),
                self.keys.clone(),
            );
            let (stop_flag, held) = (Arc::clone(self.stop_flag), Arc::clone(self.held));
            let thread = std::thread::Builder::new()
                .name(format!("control-{drive}"))
                .spawn(move || {
                    control_drive(&session, &name, &keys, drive, &rx, &held, &stop_flag);
                })
                .map_err(|e| {
                    Refusal::new(
                        ErrorKind::Internal,
                        format!("cannot start the control thread of drive {drive}: {e}"),
                    )
                })?;
            self.drives.insert(drive, (tx, thread));
        }
        let Some((tx, _)) = self.drives.get(&drive) else {
            return Err(Refusal::new(ErrorKind::Internal, "no control thread"));
        };
        match tx.try_send((sample, peer)) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(_)) => Err(Refusal::refused(format!(
                "the bridge is {DRIVE_QUEUE} samples behind with drive {drive}: this one was dropped"
            ))),
            Err(TrySendError::Disconnected(_)) => {
                // The thread could not reach ussd: the next sample starts another.
                self.drives.remove(&drive);
                Err(not_running(self.name))
            }
        }
    }
}

fn put_report(session: &Session, key: &str, report: &ControlReport<'_>) {
    let mut report = report.clone();
    report.published_unix_ns = unix_ns();
    if let Ok(json) = serde_json::to_string(&report)
        && let Err(e) = session
            .put(key, json)
            .encoding(Encoding::APPLICATION_JSON)
            .wait()
    {
        eprintln!("uss-zenoh: put {key}: {e}");
    }
}

/// One drive under remote control.
struct Remote<'a> {
    session: &'a Session,
    /// The drives the bridge holds, for the parameter server's write rule.
    held: &'a Held,
    bus: Bus,
    /// The drive's inputs, for the latch the report shows.
    watch: Option<DriveWatch>,
    name: &'a str,
    drive: Address,
    report_key: String,
    controller: Option<Controller>,
    /// The sequence number of the last sample passed on (forgotten when the drive is handed
    /// back, and after a silence longer than the drive's watchdog time).
    last_seq: Option<u64>,
    /// When the last sample was passed on.
    last_taken: Option<Instant>,
    /// When the controller was taken or a sample last passed on: the drive is handed back
    /// [`RELEASE_AFTER`] after it (refused samples do not keep it).
    active: Option<Instant>,
    report: ControlReport<'a>,
    /// The certificate name of the holder, when the bridge knows it for sure.
    holder_verified: Option<String>,
    reported: Option<ControlReport<'a>>,
    next_report: Instant,
}

impl Remote<'_> {
    /// Passes one sample on, or says why not.
    fn take(&mut self, (sample, peer): FromPeer) -> Result<(), Refusal> {
        let out = sample.map_err(|e| Refusal::new(e.kind(), e.to_string()))?;
        self.report.sender = Some(out.from.clone());
        self.report.peer = Some(peer.to_string());
        // Only a verified name controls (the bridge starts with --allow-control only under a
        // policy that grants `control` by name, and its gate let this peer through for that).
        let Some(verified) = peer.verified_name().map(str::to_owned) else {
            return Err(Refusal::refused(format!(
                "refused: {peer} is no verified name: remote control rests on certificates (or users) the policy names"
            )));
        };
        // The holder is its certificate and its `from` (one process of it): another
        // certificate's sample, or another process of the same one, is another sender.
        let holds = self.report.holder.as_ref() == Some(&out.from)
            && self.holder_verified.as_deref() == Some(verified.as_str());
        if let Some(holder) = self.report.holder.as_ref().filter(|_| !holds) {
            return Err(Refusal::new(
                ErrorKind::Controlled,
                format!(
                    "drive {} is controlled remotely by {holder:?} until it releases it or falls \
                     silent: nothing of {:?} was sent",
                    self.drive, out.from
                ),
            ));
        }
        if let Some(last) = self.last_seq.filter(|&last| out.seq <= last) {
            return Err(Refusal::new(
                ErrorKind::InvalidSample,
                format!(
                    "old sample: seq {} is not above {last}, the last one taken",
                    out.seq
                ),
            ));
        }
        if out.release {
            self.release();
            // Said to this sender even when the bridge held nothing for it (a restarted bridge,
            // a release sent again): the drive is not held for it.
            self.report.state = "released";
            return Ok(());
        }
        // From here on the drive is held, before any call that may wait (the controller's
        // opening, a re-arm's handshake): no peer's write slips in, this sender's neither until
        // its sample is taken (no verified holder: every write is refused meanwhile).
        self.held.set(
            self.drive,
            Some(Holder {
                from: out.from.clone(),
                verified: None,
            }),
        );
        if self.controller.is_none() {
            // A session acknowledges no latch by opening the drive: only a remote controller's
            // stop that names the latch re-arms it.
            let c = self.bus.control(self.drive, ControlOptions::default())?;
            self.controller = Some(c);
            self.active = Some(Instant::now());
        }
        let Some(c) = &self.controller else {
            return Err(Refusal::new(ErrorKind::Internal, "no controller"));
        };
        let info = c.inputs().info();
        let words = out
            .pzd(usize::from(info.pzd_words), info.reference_hz)
            .map_err(|e| Refusal::new(e.kind(), e.to_string()))?;
        let image = c.inputs().latest();
        if image.is_live() && !holds {
            // Live without this sender having re-armed it: its holder fell silent and ussd has
            // not shown the trip yet. Only a named re-arm of that latch takes it over.
            return Err(Refusal::new(
                ErrorKind::Controlled,
                format!(
                    "drive {} is live under an earlier remote controller's words: wait for its \
                     latch and re-arm it by name",
                    self.drive
                ),
            ));
        }
        // A latched drive takes from the network only a sample that names its latch: one sent
        // before the latch, or by a controller that never saw it, is reported and not passed on
        // (a remote stop that must reach the drive anyway is the `.../stop` query's).
        if image.latch().is_some_and(|id| out.rearm != Some(id)) {
            return Err(latched(ErrorKind::Tripped, self.name, self.drive, &image));
        }
        // The remote controller acknowledges the latch it names (the session checks that the
        // drive shows it); then its stop re-arms the drive and its ON runs it, as the session
        // decides for every controller.
        let named = self.named_rearm(&out, &image)?;
        let sent = named
            .map_or(Ok(()), |(id, asked)| c.acknowledge_latch(id, asked))
            .and_then(|()| c.set_words(&words));
        match sent {
            Ok(()) => {
                self.last_seq = Some(out.seq);
                self.last_taken = Some(Instant::now());
                self.active = self.last_taken;
                self.report.seq = Some(out.seq);
                self.report.holder = Some(out.from);
                self.report.holder_peer = self.report.peer.clone();
                self.holder_verified = Some(verified);
                Ok(())
            }
            Err(
                e @ (ClientError::Tripped { .. }
                | ClientError::NotArmed { .. }
                | ClientError::NotTheLatch { .. }),
            ) => Err(latched(
                e.kind(),
                self.name,
                self.drive,
                &c.inputs().latest(),
            )),
            Err(e) => Err(Refusal::from(e)),
        }
    }

    /// The latch a sample names to re-arm and when that was asked for, if it names one of the
    /// latched drive's. A re-arm carries when it was asked for: a latch that began after it is
    /// not its to clear (an operator's stop that came while the remote started).
    fn named_rearm(&self, out: &Out, image: &PzdInput) -> Result<Option<(u64, u64)>, Refusal> {
        let named = out.rearm.filter(|&id| id != 0 && !image.is_live());
        match (named, out.asked_ns) {
            (Some(_), None) => Err(Refusal::new(
                ErrorKind::InvalidSample,
                format!(
                    "drive {} on {}: a re-arm (rearm) carries asked_ns, when it was asked for on \
                     this bridge's clock (the images' monotonic_ns): nothing was re-armed",
                    self.drive, self.name
                ),
            )),
            (named, asked) => Ok(named.zip(asked)),
        }
    }

    /// No sender holds the drive any more.
    fn forget_holder(&mut self) {
        self.report.holder = None;
        self.report.holder_peer = None;
        self.holder_verified = None;
    }

    /// Hands the drive back (ussd sends its safe command, latched as "released").
    fn release(&mut self) {
        if let Some(c) = self.controller.take() {
            let _ = c.release();
            self.report.state = "released";
            self.report.set_error(None);
        }
        self.forget_holder();
        self.last_seq = None;
        self.last_taken = None;
        self.active = None;
    }

    /// Publishes the report (with the drive's latch as ussd shows it) when it changed or, while
    /// the bridge holds the drive, when it is due.
    fn publish_report(&mut self) {
        if let Some(watch) = &self.watch {
            let image = watch.latest();
            self.report.control = image.control_name();
            self.report.latch_reason = image.latch_reason_name();
            self.report.latch_id = image.latch_id;
        }
        let changed = self.reported.as_ref() != Some(&self.report);
        let due = self.controller.is_some() && Instant::now() >= self.next_report;
        if !changed && !due {
            return;
        }
        put_report(self.session, &self.report_key, &self.report);
        self.reported = Some(self.report.clone());
        self.next_report = Instant::now() + REPORT_EVERY;
    }
}

/// A latch in words a remote controller can act on.
/// ussd is not running on `bus`: a sample was not passed on.
fn not_running(bus: &str) -> Refusal {
    Refusal::new(
        ErrorKind::NotRunning,
        format!("ussd is not running on {bus}: nothing was sent"),
    )
}

/// A latched drive's refusal of a sample (of `kind`: tripped, not armed, ...), with how to
/// re-arm it.
fn latched(kind: ErrorKind, bus: &str, drive: Address, image: &PzdInput) -> Refusal {
    let latch = uss_client::Latch::of(image);
    let text = format!(
        "drive {drive} on {bus} is latched ({latch}) and gets {}: nothing was sent; re-arm it \
         with a stop naming the latch and when it was asked for \
         ({{\"stw1\":1150,\"rearm\":{},\"asked_ns\":...}}), then ON",
        latch.command_name(),
        image.latch_id
    );
    Refusal::new(kind, text)
}

/// Serves the remote controller of one drive until `stop_flag` or the dispatcher goes; hands
/// the drive back on the way out.
fn control_drive(
    session: &Session,
    name: &str,
    keys: &Keys,
    drive: Address,
    samples: &Receiver<FromPeer>,
    held: &Held,
    stop_flag: &AtomicBool,
) {
    let Ok(bus) = Bus::open_as(name, "uss-zenoh-control") else {
        let mut report = ControlReport::new(name, drive.get());
        report.state = "refused";
        report.sender = samples
            .try_iter()
            .filter_map(|(parsed, _)| parsed.ok())
            .last()
            .map(|o| o.from);
        report.set_error(Some(&not_running(name)));
        put_report(session, &keys.control(drive), &report);
        return;
    };
    let watchdog = bus.diag(drive).map_or(Duration::from_millis(100), |d| {
        Duration::from_millis(u64::from(d.info.watchdog_ms))
    });
    let mut remote = Remote {
        session,
        held,
        watch: bus.watch(drive).ok(),
        bus,
        name,
        drive,
        report_key: keys.control(drive),
        controller: None,
        last_seq: None,
        last_taken: None,
        active: None,
        report: ControlReport::new(name, drive.get()),
        holder_verified: None,
        reported: None,
        next_report: Instant::now(),
    };
    while !stop_flag.load(Ordering::Relaxed) {
        // Only the newest of the samples waiting is taken: older ones (queued during a re-arm
        // handshake or a stall) would refresh the watchdog with words already superseded.
        let newest = samples
            .recv_timeout(Duration::from_millis(200))
            .map(|first| samples.try_iter().last().unwrap_or(first));
        // Looked at before the sample is: the first sample of a new sender after its
        // predecessor fell silent finds the drive free.
        let shows_latch = remote.watch.as_ref().is_some_and(|w| !w.latest().is_live());
        if shows_latch && remote.last_taken.is_some_and(|t| t.elapsed() > watchdog) {
            // The holder fell silent and the drive tripped: another sender (or the same one
            // restarted, with an older sequence number) may take it, re-arming it by its latch.
            remote.last_seq = None;
            remote.forget_holder();
        }
        match newest {
            Ok(sample) => match remote.take(sample) {
                Ok(()) => {
                    remote.report.taken += 1;
                    remote.report.set_error(None);
                    if remote.controller.is_some() {
                        remote.report.state = "controlling";
                    }
                }
                Err(e) => {
                    remote.report.refused += 1;
                    remote.report.state = "refused";
                    remote.report.set_error(Some(&e));
                }
            },
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {}
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
        }
        if remote.active.is_some_and(|t| t.elapsed() > RELEASE_AFTER) {
            remote.release();
        }
        held.set(
            drive,
            remote.controller.as_ref().map(|_| Holder {
                from: remote.report.holder.clone().unwrap_or_default(),
                verified: remote.holder_verified.clone(),
            }),
        );
        remote.publish_report();
    }
    remote.release();
    held.set(drive, None);
    remote.publish_report();
}
