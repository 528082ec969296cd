//! [`Controller`]: the one handle that writes a drive's output image (STW1, setpoint, further
//! PZD words), with helpers that follow the PROFIdrive state machine (USS.md section 7), and
//! the client rules of `uss_control::session` surfaced as typed errors.

use crate::link::{Link, Services};
use crate::open::{Ipc, layout_verifier, opened, unknown_drive};
use crate::{Bus, ClientError, DriveWatch};
use core::time::Duration;
use iceoryx2::node::NodeView;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::prelude::{CallbackProgression, Node, NodeState, PortFactory as _};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSub;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::thread::JoinHandle;
use std::time::Instant;
use uss_protocol::{DriveState, Setpoint, Stw1};
use uss_shm_types::names;
use uss_shm_types::{
    Address, Generation, MAX_PZD_WORDS, PzdInput, PzdOutput, Sample, Session, SessionError,
    SessionSetup, Step, Words,
};

/// The longest refresh period: 20 ms, which suits ussd's default watchdog of 100 ms
/// (`watchdog_ms`). A controller of a drive with a shorter watchdog refreshes more often
/// ([`Controller::refresh_period`]).
pub const DEFAULT_REFRESH: Duration = Duration::from_nanos(uss_shm_types::MAX_REFRESH_NS);
/// The least a call waits for ussd to take an OFF1 before passing an ON ([`Controller::rearm`],
/// or an ON right after [`Controller::enable`]), and for a release on drop. The wait is the
/// drive's own ([`DriveWatch::handshake`]): ussd's freshness limit for it, which on a full slow
/// line (31 drives at 9600 baud) is seconds.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_nanos(uss_shm_types::MIN_HANDSHAKE_NS);

/// How a [`Controller`] starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct ControlOptions {
    /// PZD words to send, STW1 and setpoint included. `None`: the drive's PZD length as ussd
    /// is configured (P2012), which every sample must carry anyway; a different number is
    /// refused here before it could be refused by ussd.
    pub words: Option<usize>,
}

impl ControlOptions {
    /// Sends exactly `words` PZD words.
    pub fn words(words: usize) -> Self {
        Self {
            words: Some(words),
            ..Self::default()
        }
    }
}

/// Jogging direction (STW1 bits 8 and 9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Jog {
    Right,
    Left,
}

/// The publisher on the `out` service of one ussd generation.
struct Port {
    generation: Generation,
    publisher: Publisher<Ipc, PzdOutput, ()>,
}

/// The controller's own state, shared with a [`Refresher`] thread: its publisher and the
/// [`Session`] that decides what it publishes (`uss_control::session`, the one place of the
/// client rules).
struct State {
    port: Port,
    session: Session,
}

/// Shared with a [`Refresher`] thread.
struct Shared {
    link: Arc<Link>,
    state: Mutex<State>,
    watch: DriveWatch,
    bus: String,
    address: Address,
}

impl Shared {
    fn state(&self) -> MutexGuard<'_, State> {
        // Plain data, valid whatever a panicking holder left behind.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// A session's refusal in this controller's words, with the latch `input` shows.
    fn error(&self, e: SessionError, input: &PzdInput) -> ClientError {
        let (bus, address) = (self.bus.clone(), self.address.get());
        match e {
            SessionError::Tripped { .. } => ClientError::latched(&bus, address, input, true),
            SessionError::NotArmed { .. } => ClientError::latched(&bus, address, input, false),
            SessionError::Stalled {
                gap_ns,
                watchdog_ns,
            } => ClientError::Stalled {
                bus,
                address,
                gap: Duration::from_nanos(gap_ns),
                watchdog: Duration::from_nanos(watchdog_ns),
                // The stop ussd sends a drive whose controller went stale.
                command: self.watch.info().safe_command().ok(),
            },
            SessionError::Invalid(rejection) => ClientError::InvalidSample {
                bus,
                address,
                rejection,
            },
            SessionError::NotTheLatch { named, shown } => ClientError::NotTheLatch {
                bus,
                address,
                named,
                shown,
            },
            SessionError::Released => ClientError::Released { bus, address },
        }
    }

    /// A call of the program that changes the words with `change` (or only refreshes them), as
    /// the session decides. An ON right after a re-arming stop waits (at most the drive's
    /// handshake time, repeating the stop) until ussd took the stop and the drive is live.
    ///
    /// A stop goes out whatever ussd's heartbeat says: a ussd paused, starved or late with its
    /// heartbeat takes it when it looks again, and the controller's words are that stop from
    /// now on, so no later keepalive repeats the ON before it (docs/SAFETY.md, STOP-ANYWHERE).
    /// The call still fails with what the heartbeat says. An ON that waits for the re-arm is
    /// dropped ([`ClientError::Superseded`]) when another thread's stop comes meanwhile: that
    /// stop is the program's later word.
    fn publish(&self, change: impl Fn(&mut Words)) -> Result<(), ClientError> {
        let start = Instant::now();
        let mut stops_seen = None;
        loop {
            let link = self.link.check();
            let mut state = self.state();
            let stops = state.session.stops_with(&change);
            if stops_seen.is_some_and(|n| n != state.session.stops()) {
                return Err(ClientError::Superseded {
                    bus: self.bus.clone(),
                    address: self.address.get(),
                });
            }
            let unsure = match link {
                Ok(services) => {
                    self.follow(&mut state, &services)?;
                    None
                }
                Err(e) if stops => Some(e),
                Err(e) => return Err(e),
            };
            let input = self.watch.latest();
            let step = state
                .session
                .publish(monotonic_ns(), &input, &change)
                .map_err(|e| self.error(e, &input))?;
            let sample = match step {
                Step::Publish(sample) => {
                    Self::send(&mut state, sample)?;
                    return unsure.map_or(Ok(()), Err);
                }
                Step::AwaitRearm if start.elapsed() < handshake(&input) => {
                    // The program waits inside its call: the stop goes on being refreshed
                    // (a stop of this call's own, not another thread's).
                    let repeated = match state.session.publish(monotonic_ns(), &input, |_| {}) {
                        Ok(Step::Publish(repeated)) => repeated,
                        Ok(Step::AwaitRearm) => continue,
                        Err(e) => return Err(self.error(e, &input)),
                    };
                    stops_seen = Some(state.session.stops());
                    repeated
                }
                Step::AwaitRearm => {
                    return Err(ClientError::latched(
                        &self.bus,
                        self.address.get(),
                        &input,
                        false,
                    ));
                }
            };
            Self::send(&mut state, sample)?;
            drop(state);
            std::thread::sleep(crate::watch::POLL);
        }
    }

    /// After a restart of ussd, publishes on the new generation's `out` service.
    fn follow(&self, state: &mut State, services: &Services) -> Result<(), ClientError> {
        if state.port.generation != services.generation() {
            state.port = open_port(&self.link, services, self.address)?;
        }
        Ok(())
    }

    fn send(state: &mut State, sample: Sample) -> Result<(), ClientError> {
        state
            .port
            .publisher
            .send_copy(PzdOutput::from(sample))
            .map(|_| ())
            .map_err(|e| ClientError::ipc("publishing the output image", e))
    }

    /// What a background refresher publishes now, if the session allows it.
    fn refresh_in_background(&self) -> Result<(), ClientError> {
        let Ok(services) = self.link.check() else {
            // The owner learns of ussd's absence at its next call.
            return Ok(());
        };
        let mut state = self.state();
        self.follow(&mut state, &services)?;
        let input = self.watch.latest();
        match state.session.refresh(monotonic_ns(), &input) {
            Some(sample) => Self::send(&mut state, sample),
            None => Ok(()),
        }
    }

    /// Publishes a release and waits (at most the drive's handshake time) until ussd took it,
    /// so the publisher can go: iceoryx2 drops samples not yet received with their publisher.
    /// Once released, nothing more is published: a second call returns at once.
    /// Sent whatever ussd's heartbeat says, like a stop: a ussd paused or starved takes it
    /// when it looks again (the call then fails with what the heartbeat says).
    fn release(&self) -> Result<PzdInput, ClientError> {
        let mut state = self.state();
        if state.session.is_released() {
            return Ok(self.watch.latest());
        }
        let link = self.link.check();
        if let Ok(services) = &link {
            self.follow(&mut state, services)?;
        }
        let sample = state.session.release(monotonic_ns());
        state
            .port
            .publisher
            .send_copy(PzdOutput::from(sample))
            .map_err(|e| ClientError::ipc("publishing the release", e))?;
        drop(state);
        link?;
        self.watch
            .wait_polled("release taken", |i| i.taken_sequence == sample.sequence)
    }
}

use crate::link::monotonic_ns;

/// How long to wait for what the drive's next poll brings, as its image `input` states it.
fn handshake(input: &PzdInput) -> Duration {
    Duration::from_nanos(input.handshake_ns())
}

/// This process's publisher on drive `address`'s `out` service of the generation `services`
/// belong to; [`ClientError::Controlled`] while another process holds it.
fn open_port(link: &Link, services: &Services, address: Address) -> Result<Port, ClientError> {
    let bus = link.name.as_str();
    let name = names::drive_out(&services.instance, address);
    let service = opened(
        link.node
            .service_builder(&name)
            .publish_subscribe::<PzdOutput>()
            .open_with_attributes(&layout_verifier()?),
        bus,
        &name,
        unknown_drive(bus, address.get()),
    )?;
    let publisher = match service.publisher_builder().create() {
        Ok(p) => p,
        Err(PublisherCreateError::ExceedsMaxSupportedPublishers) => {
            let (pid, node) = holder(&link.node, &service).unzip();
            return Err(ClientError::Controlled {
                bus: bus.to_owned(),
                address: address.get(),
                pid,
                node,
            });
        }
        Err(e) => {
            return Err(ClientError::ipc(
                format!("publishing on {}", name.as_str()),
                e,
            ));
        }
    };
    Ok(Port {
        generation: services.generation(),
        publisher,
    })
}

/// Exclusive control of one drive: the only writer of its output image. Obtained from
/// [`Bus::control`]; a second controller for the same drive is refused while this one lives.
/// What it publishes is decided by a [`Session`] (`uss_control::session`): the client rules,
/// written once for every language.
///
/// **Latched until re-armed.** ussd passes this controller's words to the drive only while the
/// drive is *live*. It starts *latched* (ussd's start), and latches again when this
/// controller stops publishing within the drive's watchdog time (100 ms by default: it froze,
/// hung or died), when another controller takes its place without a release in between, when a
/// sample would be misread by the drive, when an operator stops the drive from another process
/// (`ussctl stop/coast/quick-stop`), or when the bus line comes back. A latched drive gets its
/// safe command (OFF1 unless configured otherwise) until a controller re-arms it the PROFIdrive
/// way: a stop that names the latch, then ON.
///
/// - **Only [`Controller::rearm`] re-arms.** Opening acknowledges no latch: the latch the drive
///   shows then (ussd's start, an operator's stop, an earlier controller's trip or release) is
///   news like any later one. Opening, reconnecting, [`Controller::keepalive`],
///   [`Controller::enable`] and a refresher never re-arm; the program's explicit
///   [`Controller::rearm`] is the one deliberate act, then [`Controller::run_hz`] and friends.
/// - A latch this controller has not acknowledged fails every ON with
///   [`ClientError::Tripped`] (when and why) until [`Controller::rearm`] acknowledges it. A
///   frozen controller that resumes, or its refresher, never restarts the motor by itself.
/// - A stop ([`Controller::stop`], [`Controller::coast`], [`Controller::quick_stop`]) always goes
///   out, latched or not; it re-arms nothing this controller did not acknowledge.
///
/// **Watchdog: the program's own calls.** Every setter publishes; between changes call
/// [`Controller::keepalive`] at least once per watchdog time (every
/// [`Controller::refresh_period`] suits any) from the control loop itself. A call after a
/// longer gap (the process was paused, the loop blocked) fails with [`ClientError::Stalled`]
/// and every ON does until [`Controller::rearm`]: a gap is a trip, not a fresh start.
/// [`Controller::spawn_refresher`] fills shorter gaps from a thread for tools, but stops
/// refreshing once the program has not called for longer than the watchdog time. Dropping the
/// controller (or [`Controller::release`]) hands the drive back cleanly: ussd sends the safe
/// command and shows the drive "released", which is not a watchdog trip.
///
/// Every sample keeps STW1 bit 10 ("control by PLC") set, carries exactly the drive's PZD
/// length, this process's id, a `CLOCK_MONOTONIC` time stamp, a new sequence number and the
/// latch it acknowledges; a sample ussd would refuse is refused here first
/// ([`ClientError::InvalidSample`]).
pub struct Controller {
    shared: Arc<Shared>,
}

impl core::fmt::Debug for Controller {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Controller")
            .field("bus", &self.shared.bus)
            .field("address", &self.shared.address)
            .field("words", &self.words())
            .finish_non_exhaustive()
    }
}

impl Controller {
    pub(crate) fn open(
        bus: &Bus,
        address: Address,
        options: ControlOptions,
    ) -> Result<Self, ClientError> {
        let diag = bus.diag(address)?;
        let pzd = usize::from(diag.info.pzd_words);
        if pzd == 0 {
            return Err(ClientError::NoProcessData {
                bus: bus.name().to_owned(),
                address: address.get(),
            });
        }
        if let Some(n) = options.words.filter(|&n| n != pzd) {
            return Err(ClientError::PzdWords {
                bus: bus.name().to_owned(),
                address: address.get(),
                given: n,
                expected: pzd,
            });
        }
        let services = bus.services()?;
        let port = open_port(bus.link(), &services, address).map_err(|e| match e {
            ClientError::UnknownDrive { .. } => bus.unknown_drive(address),
            other => other,
        })?;
        let watch = DriveWatch::open(bus, address)?;
        let setup = SessionSetup {
            pzd,
            pid: std::process::id(),
            watchdog_ns: u64::from(diag.info.watchdog_ms).saturating_mul(1_000_000),
            // A clock-based start: the first sample of a new controller never repeats its
            // predecessor's last sequence number.
            first_sequence: monotonic_ns(),
        };
        let session = Session::new(setup);
        Ok(Self {
            shared: Arc::new(Shared {
                link: Arc::clone(bus.link()),
                state: Mutex::new(State { port, session }),
                watch,
                bus: bus.name().to_owned(),
                address,
            }),
        })
    }

    /// The drive's address.
    pub fn address(&self) -> Address {
        self.shared.address
    }

    /// The drive's inputs, read while controlling it.
    pub fn inputs(&self) -> &DriveWatch {
        &self.shared.watch
    }

    /// The words this controller sends (STW1 first).
    pub fn words(&self) -> Vec<u16> {
        self.shared.state().session.words().as_slice().to_vec()
    }

    /// The current STW1.
    pub fn stw1(&self) -> Stw1 {
        Stw1::from_bits_retain(self.shared.state().session.words().stw1())
    }

    /// The sequence number of the last publish.
    pub fn sequence(&self) -> u64 {
        self.shared.state().session.sequence()
    }

    /// The latest input image, or [`ClientError::Tripped`] when the drive latched since this
    /// controller last acknowledged a latch ([`ClientError::Stalled`] after a gap in the
    /// program's calls). For control loops that read more than they write: it is no call that
    /// refreshes the drive ([`Controller::keepalive`] is).
    pub fn check(&self) -> Result<PzdInput, ClientError> {
        self.shared.link.check()?;
        let state = self.shared.state();
        let input = self.shared.watch.latest();
        match state.session.check(monotonic_ns(), &input) {
            Ok(()) => Ok(input),
            Err(e) => Err(self.shared.error(e, &input)),
        }
    }

    /// Re-publishes the current words with a new sequence number: the program's watchdog
    /// refresh, once per watchdog time at least.
    pub fn keepalive(&self) -> Result<(), ClientError> {
        self.shared.publish(|_| {})
    }

    /// The same as [`Controller::keepalive`].
    pub fn refresh(&self) -> Result<(), ClientError> {
        self.keepalive()
    }

    /// Acknowledges the drive's latch (a trip, an override, ussd's start, a gap in the
    /// program's calls) and re-arms it the PROFIdrive way: sends OFF1 naming the latch (STW1
    /// 0x047E, setpoint and every further word 0) and waits until ussd has taken it and the
    /// drive is live again. Then an ON ([`Controller::run_hz`], ...) reaches the drive. The
    /// drive itself may need [`Controller::acknowledge_fault`] too.
    ///
    /// `asked_ns` (`CLOCK_MONOTONIC`) is when the deliberate act that asked for the re-arm
    /// happened: [`crate::process_start_ns`] for a program that re-arms once it is set up,
    /// the moment an operator pressed a button or a pin rose, [`crate::monotonic_ns`] taken when
    /// the program decided to re-arm. A latch that began after that moment (an operator's stop
    /// while the program was starting) is not re-armed, the drive stays stopped, and the error
    /// is [`ClientError::Tripped`] naming it (docs/SAFETY.md, REARM).
    pub fn rearm(&self, asked_ns: u64) -> Result<PzdInput, ClientError> {
        self.rearm_by(asked_ns, Session::rearm)
    }

    /// Like [`Controller::rearm`], with the stop the drive is latched with as the re-arming
    /// words (`Session::rearm_keeping_stop`): a coast or quick stop stays on the wire, so a
    /// program that only acknowledges a fault and lets go (`ussctl ack`) never weakens it, even
    /// when it dies halfway. An ON from S1 needs [`Controller::stop`] (OFF1) first.
    pub fn rearm_keeping_stop(&self, asked_ns: u64) -> Result<PzdInput, ClientError> {
        self.rearm_by(asked_ns, Session::rearm_keeping_stop)
    }

    /// A re-arm by `rearm` for `asked_ns`, a moment of this process's clock, moved onto
    /// ussd's (the clock of the latch ids) by the freshest time stamp of ussd's seen (the
    /// drive's image, the heartbeat): a program in a time namespace of its own, whose clock
    /// runs ahead, re-arms no stop that came after its ask either.
    fn rearm_by(
        &self,
        asked_ns: u64,
        rearm: impl FnOnce(&mut Session, u64, &PzdInput, u64) -> Result<Sample, SessionError>,
    ) -> Result<PzdInput, ClientError> {
        {
            let services = self.shared.link.check()?;
            let (beat_ns, beat_read_ns) = self.shared.link.ussd_clock();
            let mut state = self.shared.state();
            self.shared.follow(&mut state, &services)?;
            let input = self.shared.watch.latest();
            let now = monotonic_ns();
            // Each errs early (the image was read just now, the heartbeat when the link last
            // looked): the later of the two is the closer.
            let asked = uss_shm_types::on_latch_clock(asked_ns, input.timestamp_ns, now).max(
                uss_shm_types::on_latch_clock(asked_ns, beat_ns, beat_read_ns),
            );
            let sample = rearm(&mut state.session, now, &input, asked)
                .map_err(|e| self.shared.error(e, &input))?;
            Shared::send(&mut state, sample)?;
        }
        let live = self.wait_polled("re-armed (live)", PzdInput::is_live);
        match live {
            Ok(input) => Ok(input),
            Err(ClientError::WaitTimeout { .. } | ClientError::Stale { .. }) => {
                Err(ClientError::latched(
                    &self.shared.bus,
                    self.shared.address.get(),
                    &self.inputs().latest(),
                    false,
                ))
            }
            Err(e) => Err(e),
        }
    }

    /// STW1 0x047E (OFF1, everything else enabled): S1 -> S2 (ready to switch on). Also
    /// stops a running drive along its ramp, like [`Controller::stop`]. It re-arms nothing by
    /// itself: a latched drive needs [`Controller::rearm`].
    pub fn enable(&self) -> Result<(), ClientError> {
        self.command(Stw1::READY)
    }

    /// STW1 0x047F with a setpoint in % of the reference (0x4000 = 100 %, -200..+199.99 %):
    /// S2 -> S3 -> S4, running. A negative setpoint runs the other way (signed HSW, USS.md
    /// section 7); a drive may block negative setpoints by its own parameters.
    /// A setpoint beyond that range, or not a finite number, is refused with
    /// [`ClientError::InvalidSetpoint`], never sent as full scale.
    pub fn run_percent(&self, percent: f32) -> Result<(), ClientError> {
        self.run_setpoint(self.setpoint(percent, 100.0, "%")?)
    }

    /// Like [`Controller::run_percent`], in Hz: scaled by the drive's reference frequency
    /// P2000 as ussd publishes it ([`DriveWatch::info`]), so a controller and every monitor
    /// show the same Hz for the same setpoint.
    /// While ussd reads the reference again (the drive came online, was reset or
    /// commissioned) it is not known, and a setpoint in Hz is refused with
    /// [`ClientError::ReferenceUnknown`]: nothing is scaled with the old one.
    pub fn run_hz(&self, hz: f32) -> Result<(), ClientError> {
        self.run_setpoint(self.hz_setpoint(hz)?)
    }

    /// Like [`Controller::run_percent`], in rpm: scaled by the drive's reference speed (a
    /// G120's p2000, [`DriveInfo::reference_rpm`]), which ussd reads with the motor's
    /// `pole_pairs` from the drive's configuration. A drive whose reference is a frequency
    /// (MICROMASTER 4's P2000), or a G120 configured without `pole_pairs`, has no reference
    /// speed ussd knows: refused with [`ClientError::InvalidSetpoint`]; while ussd reads it
    /// again, [`ClientError::ReferenceUnknown`]. Nothing is sent either way.
    ///
    /// [`DriveInfo::reference_rpm`]: uss_shm_types::diag::DriveInfo::reference_rpm
    pub fn run_rpm(&self, rpm: f32) -> Result<(), ClientError> {
        self.run_setpoint(self.rpm_setpoint(rpm)?)
    }

    /// The setpoint of `rpm`, scaled by the drive's reference speed, or why it cannot be.
    fn rpm_setpoint(&self, rpm: f32) -> Result<Setpoint, ClientError> {
        let info = self.shared.watch.info();
        if info.pole_pairs == 0 {
            return Err(ClientError::InvalidSetpoint {
                bus: self.shared.bus.clone(),
                address: self.shared.address.get(),
                asked: format!("{rpm} rpm"),
                problem: "cannot be scaled: ussd knows no reference speed of this drive (its \
                          reference is a frequency; a G120's p2000 in rpm is read with \
                          `pole_pairs` in its configuration); give the setpoint in Hz or %"
                    .to_owned(),
            });
        }
        self.scaled(rpm, info.reference_rpm(), "rpm")
    }

    /// The setpoint of `hz`, scaled by the drive's reference frequency as ussd publishes it, or
    /// why it cannot be scaled now (0 Hz is 0 in any scale).
    fn hz_setpoint(&self, hz: f32) -> Result<Setpoint, ClientError> {
        self.scaled(hz, self.shared.watch.info().reference(), "Hz")
    }

    /// The setpoint of `value` in `unit` of `reference` (100 %), or why it cannot be scaled now
    /// (0 is 0 in any scale).
    fn scaled(
        &self,
        value: f32,
        reference: Option<f32>,
        unit: &str,
    ) -> Result<Setpoint, ClientError> {
        if value == 0.0 {
            return Ok(Setpoint::from_raw(0));
        }
        let Some(reference) = reference else {
            // A latch (a changed reference latches the drive) is the stronger news: nothing
            // would be sent either way, and the program must re-arm before it runs again.
            self.check()?;
            return Err(ClientError::ReferenceUnknown {
                bus: self.shared.bus.clone(),
                address: self.shared.address.get(),
                asked: format!("{value} {unit}"),
            });
        };
        self.setpoint(value, reference, unit)
    }

    /// The setpoint of `value` in a unit of which `full` is 100 %, or why the word cannot carry
    /// it: every front-end's one check of a setpoint it is given.
    fn setpoint(&self, value: f32, full: f32, unit: &str) -> Result<Setpoint, ClientError> {
        Setpoint::try_from_percent(value / full * 100.0).ok_or_else(|| {
            let problem = if value.is_finite() {
                let (low, high) = (Setpoint::from_raw(i16::MIN), Setpoint::from_raw(i16::MAX));
                let reference = if unit == "Hz" {
                    format!(" of P2000 = {full:.2} Hz")
                } else if unit == "rpm" {
                    format!(" of p2000 = {full:.0} rpm")
                } else {
                    String::new()
                };
                format!(
                    "is beyond the setpoint's range, {:.2} .. {:.2} {unit} (-200 % .. +199.99 %{reference})",
                    low.percent() * full / 100.0,
                    high.percent() * full / 100.0,
                )
            } else {
                "is not a finite number".to_owned()
            };
            ClientError::InvalidSetpoint {
                bus: self.shared.bus.clone(),
                address: self.shared.address.get(),
                asked: format!("{value} {unit}"),
                problem,
            }
        })
    }

    /// STW1 0x047F with a raw setpoint.
    pub fn run_setpoint(&self, setpoint: Setpoint) -> Result<(), ClientError> {
        self.shared.publish(|w| {
            w.words[0] = with_direction(Stw1::RUN, w.words[0]).bits();
            set_word(w, 1, setpoint.word());
        })
    }

    /// Changes only the setpoint, in Hz of the drive's reference frequency as ussd publishes it
    /// (STW1 stays as it is: a running drive follows it, a stopped one stays stopped).
    pub fn set_hz(&self, hz: f32) -> Result<(), ClientError> {
        self.set_setpoint(self.hz_setpoint(hz)?)
    }

    /// Changes only the setpoint (STW1 stays as it is).
    pub fn set_setpoint(&self, setpoint: Setpoint) -> Result<(), ClientError> {
        self.shared.publish(|w| set_word(w, 1, setpoint.word()))
    }

    /// OFF1: ramp down along the ramp-down time, then S2 (STW1 0x047E).
    pub fn stop(&self) -> Result<(), ClientError> {
        self.command(Stw1::READY)
    }

    /// OFF2: coast stop, the motor is switched off at once; S1 follows (STW1 0x047C).
    pub fn coast(&self) -> Result<(), ClientError> {
        self.command(Stw1::COAST)
    }

    /// OFF3: quick stop along the OFF3 ramp; S1 follows (STW1 0x047A).
    pub fn quick_stop(&self) -> Result<(), ClientError> {
        self.command(Stw1::QUICK_STOP)
    }

    /// Sets or clears the reverse bit (STW1 bit 11), which inverts the setpoint.
    pub fn reverse(&self, reverse: bool) -> Result<(), ClientError> {
        self.shared.publish(|w| {
            let mut stw1 = Stw1::from_bits_retain(w.words[0]);
            stw1.set(Stw1::REVERSE, reverse);
            w.words[0] = stw1.bits();
        })
    }

    /// Jogs (STW1 0x057E right, 0x067E left) from S2; [`Controller::stop`] ends it.
    pub fn jog(&self, direction: Jog) -> Result<(), ClientError> {
        let bit = match direction {
            Jog::Right => Stw1::JOG_RIGHT,
            Jog::Left => Stw1::JOG_LEFT,
        };
        self.command(Stw1::READY | bit)
    }

    /// Acknowledges a fault with a rising edge of STW1 bit 7: sends 0x04FE until the drive
    /// received it (two exchanges, at most `timeout`), then 0x047E. The drive then shows S1
    /// (switching-on inhibited) or S2; [`Controller::enable`] continues from there. A coast or
    /// quick stop the controller sends stays through it (0x04FC then 0x047C; 0x04FA then
    /// 0x047A): an acknowledgement never weakens a stop, and is never an ON.
    pub fn acknowledge_fault(&self, timeout: Duration) -> Result<(), ClientError> {
        self.shared
            .publish(|w| w.words[0] = (held_stop(w.words[0]) | Stw1::FAULT_ACK).bits())?;
        let waited = self.wait_for(timeout, "fault acknowledge sent", {
            let start = self.inputs().latest().sequence;
            move |i| i.sequence >= start + 2
        });
        // Back to the stop whatever happened: the next acknowledge needs the falling edge.
        self.shared
            .publish(|w| w.words[0] = held_stop(w.words[0]).bits())?;
        waited.map(|_| ())
    }

    /// Sends `words` as they are (STW1 first). They must be exactly the drive's PZD length and
    /// keep STW1 bit 10 set, or [`ClientError::InvalidSample`]: ussd would refuse them and
    /// latch the drive.
    pub fn set_words(&self, words: &[u16]) -> Result<(), ClientError> {
        if words.len() > MAX_PZD_WORDS {
            return Err(uss_shm_types::ContractError::PzdWords(words.len()).into());
        }
        self.shared.publish(|w| {
            w.words = [0; MAX_PZD_WORDS];
            w.words[..words.len()].copy_from_slice(words);
            w.count = words.len();
        })
    }

    /// For a relay of a remote controller (the Zenoh bridge): acknowledges latch `named`, the
    /// latch the remote controller names for a re-arm it asked for at `asked_ns` (its command's
    /// own time on this host's `CLOCK_MONOTONIC`), only while the drive shows it
    /// ([`ClientError::NotTheLatch`] else) and it began before `asked_ns`
    /// ([`ClientError::Tripped`] else). The relay's next stop then re-arms the drive.
    pub fn acknowledge_latch(&self, named: u64, asked_ns: u64) -> Result<(), ClientError> {
        let mut state = self.shared.state();
        let input = self.shared.watch.latest();
        state
            .session
            .acknowledge(monotonic_ns(), &input, named, asked_ns)
            .map_err(|e| self.shared.error(e, &input))
    }

    /// Waits until `done` holds for the drive's input image, refreshing every
    /// [`Controller::refresh_period`] meanwhile (the program waits inside its own call). Fails
    /// with [`ClientError::Tripped`] as soon as the drive latches.
    pub fn wait_for(
        &self,
        timeout: Duration,
        wanted: &str,
        done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        self.wait_until(|_| timeout, wanted, done)
    }

    /// Like [`Controller::wait_for`], for what the drive's next poll brings: waits the drive's
    /// handshake time ([`DriveWatch::handshake`]) as its image states it while waiting.
    pub fn wait_polled(
        &self,
        wanted: &str,
        done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        self.wait_until(handshake, wanted, done)
    }

    fn wait_until(
        &self,
        timeout: impl Fn(&PzdInput) -> Duration,
        wanted: &str,
        mut done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        let start = Instant::now();
        let watch = &self.shared.watch;
        let first = watch.latest().sequence;
        let mut refreshed = start;
        let every = self.refresh_period();
        loop {
            let latest = self.check()?;
            if done(&latest) {
                return Ok(latest);
            }
            let timeout = timeout(&latest);
            if start.elapsed() >= timeout {
                return Err(watch.timed_out(timeout, wanted, first, &latest));
            }
            if refreshed.elapsed() >= every {
                self.keepalive()?;
                refreshed = Instant::now();
            }
            std::thread::sleep(crate::watch::POLL);
        }
    }

    /// Waits (refreshing) until the drive is in `state`.
    pub fn wait_for_state(
        &self,
        state: DriveState,
        timeout: Duration,
    ) -> Result<PzdInput, ClientError> {
        self.wait_for(timeout, state.short_name(), |i| {
            i.online != 0 && crate::state_of(i) == state
        })
    }

    /// Refreshes from a thread every `period` (or every [`Controller::refresh_period`] when
    /// that is shorter) until the returned [`Refresher`] is dropped or stopped, for tools whose
    /// loop calls less often than `period` but within the watchdog time: it stops refreshing
    /// when the program has not called for longer than the drive's watchdog time (a blocked or
    /// deadlocked loop trips the drive like a dead one), and while the drive shows a latch this
    /// controller has not acknowledged (the next call of the program reports it).
    pub fn spawn_refresher(&self, period: Duration) -> Refresher {
        let period = period.min(self.refresh_period());
        let shared = Arc::clone(&self.shared);
        let stop = Arc::new((Mutex::new(false), Condvar::new()));
        let thread = {
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || refresh_loop(&shared, &stop, period))
        };
        Refresher {
            stop,
            thread: Some(thread),
        }
    }

    /// How often this controller refreshes while the program waits inside one of its calls:
    /// a quarter of the drive's watchdog time, at most [`DEFAULT_REFRESH`] (20 ms). A control
    /// loop that calls at least this often never comes near the watchdog.
    pub fn refresh_period(&self) -> Duration {
        Duration::from_nanos(self.shared.state().session.refresh_ns())
    }

    /// Hands the drive back cleanly: ussd sends its safe command, latched, and shows it
    /// "released" (not a watchdog trip). Waits until ussd took the release (at most the
    /// drive's handshake time) and returns the image that says so. Dropping a controller does
    /// the same, ignoring errors.
    pub fn release(self) -> Result<PzdInput, ClientError> {
        self.release_shared()
    }

    /// [`Controller::release`] for a controller shared between threads (the C ABI's and the
    /// Python module's handles): every later call, of any thread, fails with
    /// [`ClientError::Released`]; a call waiting in another thread ends with it at its next
    /// refresh.
    pub fn release_shared(&self) -> Result<PzdInput, ClientError> {
        self.shared.release()
    }

    fn command(&self, stw1: Stw1) -> Result<(), ClientError> {
        self.shared.publish(|w| w.words[0] = stw1.bits())
    }
}

impl Drop for Controller {
    fn drop(&mut self) {
        // Nothing when released already. A drive that stays unreachable (ussd gone) ends the
        // wait at the timeout; the watchdog then covers it, as it covers a crash.
        let _ = self.shared.release();
    }
}

/// The stop control word `stw1` keeps through a fault acknowledgement: its coast (OFF2) or
/// quick stop (OFF3), else OFF1.
fn held_stop(stw1: u16) -> Stw1 {
    use uss_shm_types::StopCommand;
    let stop = StopCommand::of_stw1(stw1).unwrap_or(StopCommand::Off1);
    Stw1::from_bits_retain(stop.stw1())
}

/// `stw1` with the reverse bit of `previous`.
fn with_direction(stw1: Stw1, previous: u16) -> Stw1 {
    stw1 | (Stw1::from_bits_retain(previous) & Stw1::REVERSE)
}

/// Sets word `index`, widening the words if they were shorter.
fn set_word(words: &mut Words, index: usize, word: u16) {
    words.words[index] = word;
    words.count = words.count.max(index + 1);
}

type StopFlag = Arc<(Mutex<bool>, Condvar)>;

fn refresh_loop(shared: &Shared, stop: &StopFlag, period: Duration) -> Result<(), ClientError> {
    let (flag, wake) = &**stop;
    let mut stopped = flag.lock().unwrap_or_else(PoisonError::into_inner);
    loop {
        let (guard, _) = wake
            .wait_timeout_while(stopped, period, |s| !*s)
            .unwrap_or_else(PoisonError::into_inner);
        stopped = guard;
        if *stopped {
            return Ok(());
        }
        shared.refresh_in_background()?;
    }
}

/// A thread refreshing a [`Controller`]'s output image. Dropping it stops the thread.
#[derive(Debug)]
pub struct Refresher {
    stop: StopFlag,
    thread: Option<JoinHandle<Result<(), ClientError>>>,
}

impl Refresher {
    /// Stops the thread; returns the error that ended it early, if one did.
    pub fn stop(mut self) -> Result<(), ClientError> {
        self.halt()
    }

    fn halt(&mut self) -> Result<(), ClientError> {
        let (flag, wake) = &*self.stop;
        *flag.lock().unwrap_or_else(PoisonError::into_inner) = true;
        wake.notify_all();
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(panic)) => std::panic::resume_unwind(panic),
            None => Ok(()),
        }
    }
}

impl Drop for Refresher {
    fn drop(&mut self) {
        let _ = self.halt();
    }
}

/// The process (and node name) whose publisher holds the `out` service.
fn holder(node: &Node<Ipc>, service: &PubSub<Ipc, PzdOutput, ()>) -> Option<(i32, String)> {
    let mut ids = Vec::new();
    service.dynamic_config().list_publishers(|p| {
        ids.push(p.node_id);
        CallbackProgression::Continue
    });
    let mut found = None;
    let listed = Node::<Ipc>::list(node.config(), |state| {
        let view: &dyn NodeView = match &state {
            NodeState::Alive(v) => v,
            NodeState::Dead(v) => v,
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => {
                return CallbackProgression::Continue;
            }
        };
        if let Some(d) = view.details().as_ref().filter(|_| ids.contains(view.id())) {
            found = Some((d.process_id().value(), d.name().as_str().to_owned()));
            return CallbackProgression::Stop;
        }
        CallbackProgression::Continue
    });
    listed.ok().and(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_keeps_the_reverse_bit_and_plc_control() {
        let run = with_direction(Stw1::RUN, Stw1::READY.bits() | Stw1::REVERSE.bits());
        assert_eq!(run.bits(), 0x0C7F);
        assert_eq!(with_direction(Stw1::RUN, 0x047E).bits(), 0x047F);
        for w in [
            Stw1::READY,
            Stw1::RUN,
            Stw1::COAST,
            Stw1::QUICK_STOP,
            Stw1::ACK_FAULT,
        ] {
            assert!(w.contains(Stw1::CONTROL_BY_PLC), "{w:?}");
        }
        assert_eq!((Stw1::READY | Stw1::JOG_RIGHT).bits(), 0x057E);
        assert_eq!((Stw1::READY | Stw1::JOG_LEFT).bits(), 0x067E);
    }

    #[test]
    fn a_fault_acknowledgement_keeps_a_coast_or_quick_stop_and_is_never_an_on() {
        for (words, held) in [
            (0x047C, 0x047C),
            (0x047A, 0x047A),
            (0x0478, 0x047C),
            (0x047E, 0x047E),
            (0x047F, 0x047E),
            (0x0C7F, 0x047E),
            (0x057E, 0x047E),
        ] {
            assert_eq!(held_stop(words).bits(), held, "{words:#06X}");
            let ack = (held_stop(words) | Stw1::FAULT_ACK).bits();
            assert_eq!(ack, held | 0x0080, "{words:#06X}");
            assert_eq!(
                held_stop(ack).bits(),
                held,
                "{words:#06X}: back from the edge"
            );
        }
    }

    #[test]
    fn setting_the_setpoint_widens_short_words() {
        let mut words = Words {
            words: [0; MAX_PZD_WORDS],
            count: 1,
        };
        set_word(&mut words, 1, 0x2000);
        assert_eq!((words.count, words.words[1]), (2, 0x2000));
        words.count = 4;
        set_word(&mut words, 1, 0x1000);
        assert_eq!(words.count, 4);
    }

    #[test]
    fn monotonic_clock_advances() {
        let a = monotonic_ns();
        let b = monotonic_ns();
        assert!(a > 0 && b >= a);
    }
}
