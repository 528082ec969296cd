//! [`Controller`]: the one handle that writes a drive's output image (STW1, setpoint, further
//! PZD words), with helpers that follow the PROFIdrive state machine (USS.md section 7), and
//! the latch rules of ussd (`uss_shm_types::control`) surfaced as typed errors.

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
use uss_shm_types::{ControlState, DriveAddress, Generation, MAX_PZD_WORDS, PzdInput, PzdOutput};

/// A refresh period that suits ussd's default watchdog of 100 ms (`watchdog_ms`).
pub const DEFAULT_REFRESH: Duration = Duration::from_millis(20);
/// How long a call waits for ussd to take an OFF1 before passing an ON ([`Controller::rearm`],
/// or an ON right after [`Controller::enable`]), and for a release on drop.
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(1);

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
        Self { words: Some(words) }
    }
}

/// Jogging direction (STW1 bits 8 and 9).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Jog {
    Right,
    Left,
}

/// What the controller sends, and the sequence of its last write.
#[derive(Debug, Clone, Copy)]
struct Image {
    words: [u16; MAX_PZD_WORDS],
    count: usize,
    sequence: u64,
}

/// Which latch of the drive this controller knows about: `(latches, latched_since_ns)` of the
/// input image. A latch in the image other than this one is news (a trip, an override).
type LatchId = (u32, u64);

fn latch_id(i: &PzdInput) -> LatchId {
    (i.latches, i.latched_since_ns)
}

/// The publisher on the `out` service of one ussd generation.
struct Port {
    generation: Generation,
    publisher: Publisher<Ipc, PzdOutput, ()>,
}

/// The controller's own state, shared with a [`Refresher`] thread.
struct State {
    port: Port,
    image: Image,
    known_latch: LatchId,
    /// An OFF1 went out while `known_latch` held: ussd re-arms the drive when it takes it.
    off1_sent: bool,
}

/// Shared with a [`Refresher`] thread.
struct Shared {
    link: Arc<Link>,
    state: Mutex<State>,
    watch: DriveWatch,
    pid: u32,
    bus: String,
    address: u8,
    /// The drive's PZD length: every sample carries exactly this many words.
    pzd: usize,
}

impl Shared {
    fn state(&self) -> MutexGuard<'_, State> {
        // Plain data, valid whatever a panicking holder left behind.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The error for a latch this controller has not acknowledged, if the image shows one.
    fn news(&self, input: &PzdInput, state: &State) -> Option<ClientError> {
        let latched = input.control == ControlState::Latched.code();
        (latched && latch_id(input) != state.known_latch)
            .then(|| ClientError::latched(&self.bus, self.address, input, true))
    }

    /// Changes the image with `f`, checks it, and publishes it with the next sequence number.
    /// Fails without publishing when the drive latched since this controller last looked
    /// ([`ClientError::Tripped`]), when the words would be refused by ussd
    /// ([`ClientError::InvalidSample`]), and when an ON is asked of a latched drive that no OFF1
    /// of this controller has re-armed ([`ClientError::NotArmed`]).
    fn publish(&self, f: impl FnOnce(&mut Image)) -> Result<(), ClientError> {
        let services = self.link.check()?;
        let mut state = self.state();
        self.follow(&mut state, &services)?;
        let input = self.watch.latest();
        if let Some(e) = self.news(&input, &state) {
            return Err(e);
        }
        let mut next = state.image;
        f(&mut next);
        let sample = self.sample(&next)?;
        // ON or a jog runs the motor; only a stop re-arms (ussd's rule).
        let on = self.pzd > 0 && !uss_shm_types::pzd::is_stop(next.words[0]);
        let latched = !input.is_live();
        if on && latched {
            if !state.off1_sent {
                return Err(ClientError::latched(&self.bus, self.address, &input, false));
            }
            // The OFF1 is out: wait (without the lock, so a refresher keeps going) until ussd
            // took it and the drive is live, then pass the ON.
            drop(state);
            let armed = self.watch.wait_for(HANDSHAKE_TIMEOUT, "re-armed", |i| {
                i.is_live() || latch_id(i) != latch_id(&input)
            })?;
            state = self.state();
            if let Some(e) = self.news(&armed, &state) {
                return Err(e);
            }
            if !armed.is_live() {
                return Err(ClientError::latched(&self.bus, self.address, &armed, false));
            }
        } else if latched && !on {
            state.off1_sent = true;
        }
        Self::send(&mut state, next, sample)
    }

    /// The sample `image` makes with the next sequence number, as ussd would check it.
    fn sample(&self, image: &Image) -> Result<PzdOutput, ClientError> {
        let sequence = image.sequence.wrapping_add(1).max(1);
        let sample = PzdOutput::from_words(
            &image.words[..image.count],
            sequence,
            monotonic_ns(),
            self.pid,
        )?;
        sample
            .validate(self.pzd)
            .map_err(|rejection| ClientError::InvalidSample {
                bus: self.bus.clone(),
                address: self.address,
                rejection,
            })?;
        Ok(sample)
    }

    /// After a restart of ussd, publishes on the new generation's `out` service.
    fn follow(&self, state: &mut State, services: &Services) -> Result<(), ClientError> {
        if state.port.generation != services.generation() {
            let address = DriveAddress::new(self.address)?;
            state.port = open_port(&self.link, services, address)?;
        }
        Ok(())
    }

    fn send(state: &mut State, mut image: Image, sample: PzdOutput) -> Result<(), ClientError> {
        state
            .port
            .publisher
            .send_copy(sample)
            .map_err(|e| ClientError::ipc("publishing the output image", e))?;
        image.sequence = sample.sequence;
        state.image = image;
        Ok(())
    }

    /// Publishes a release and waits (at most `timeout`) until ussd took it, so the publisher
    /// can go: iceoryx2 drops samples not yet received with their publisher.
    fn release(&self, timeout: Duration) -> Result<PzdInput, ClientError> {
        // Nobody to hand the drive to: the watchdog of a new ussd is not involved either.
        let services = self.link.check()?;
        let mut state = self.state();
        self.follow(&mut state, &services)?;
        let sequence = state.image.sequence.wrapping_add(1).max(1);
        let sample = PzdOutput::release(sequence, monotonic_ns(), self.pid);
        state
            .port
            .publisher
            .send_copy(sample)
            .map_err(|e| ClientError::ipc("publishing the release", e))?;
        state.image.sequence = sequence;
        drop(state);
        self.watch
            .wait_for(timeout, "release taken", |i| i.taken_sequence == sequence)
    }
}

use crate::link::monotonic_ns;

/// This process's publisher on drive `address`'s `out` service of the generation `services`
/// belong to; [`ClientError::Controlled`] while another process holds it.
fn open_port(link: &Link, services: &Services, address: DriveAddress) -> Result<Port, ClientError> {
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
///
/// **Latched until re-armed.** ussd passes this controller's words to the drive only while the
/// drive is *live*. It starts *latched* (ussd's start), and latches again when this
/// controller stops publishing within the drive's watchdog time (100 ms by default: it froze,
/// hung or died), when a sample would be misread by the drive, when an operator stops the
/// drive from another process (`ussctl stop/coast/quick-stop`), or when the bus line comes
/// back. A latched drive gets its safe command (OFF1 unless configured otherwise) until this
/// controller re-arms it the PROFIdrive way: OFF1, then ON.
///
/// - A new controller re-arms with its first OFF1: [`Controller::enable`] (or
///   [`Controller::rearm`]), then [`Controller::run_hz`] and friends.
/// - A latch after that is news: the next call fails with [`ClientError::Tripped`] (when and
///   why), and so does every call until [`Controller::rearm`] acknowledges it. A frozen
///   controller that resumes, or its refresher, never restarts the motor by itself.
/// - An ON while latched, before an OFF1 of this controller re-armed the drive, fails with
///   [`ClientError::NotArmed`].
///
/// **Watchdog.** Every setter publishes; between changes call [`Controller::refresh`] at least
/// once per watchdog time (every [`DEFAULT_REFRESH`] suits the default), or let
/// [`Controller::spawn_refresher`] do it from a thread. Dropping the controller (or
/// [`Controller::release`]) hands the drive back cleanly: ussd sends the safe command and shows
/// the drive "released", which is not a watchdog trip.
///
/// Every sample keeps STW1 bit 10 ("control by PLC") set, carries exactly the drive's PZD
/// length, this process's id, a `CLOCK_MONOTONIC` time stamp and a new sequence number; a
/// sample ussd would refuse is refused here first ([`ClientError::InvalidSample`]).
pub struct Controller {
    shared: Arc<Shared>,
    released: bool,
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
        address: DriveAddress,
        options: ControlOptions,
    ) -> Result<Self, ClientError> {
        let diag = bus.diag(address.get())?;
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
            ClientError::UnknownDrive { .. } => bus.unknown_drive(address.get()),
            other => other,
        })?;
        let watch = DriveWatch::open(bus, address)?;
        let mut words = [0; MAX_PZD_WORDS];
        words[0] = Stw1::READY.bits();
        let known_latch = latch_id(&watch.latest());
        Ok(Self {
            shared: Arc::new(Shared {
                link: Arc::clone(bus.link()),
                state: Mutex::new(State {
                    port,
                    image: Image {
                        words,
                        count: pzd,
                        // A clock-based start: the first sample of a new controller never
                        // repeats its predecessor's last sequence number (ussd takes a sample
                        // as new only when the sequence changes).
                        sequence: monotonic_ns(),
                    },
                    known_latch,
                    off1_sent: false,
                }),
                watch,
                pid: std::process::id(),
                bus: bus.name().to_owned(),
                address: address.get(),
                pzd,
            }),
            released: false,
        })
    }

    /// The drive's address.
    pub fn address(&self) -> u8 {
        self.shared.address
    }

    /// The drive's inputs, read while controlling it.
    pub fn inputs(&self) -> &DriveWatch {
        &self.shared.watch
    }

    /// The words this controller sends (STW1 first).
    pub fn words(&self) -> Vec<u16> {
        let state = self.shared.state();
        state.image.words[..state.image.count].to_vec()
    }

    /// The current STW1.
    pub fn stw1(&self) -> Stw1 {
        Stw1::from_bits_retain(self.shared.state().image.words[0])
    }

    /// The sequence number of the last publish.
    pub fn sequence(&self) -> u64 {
        self.shared.state().image.sequence
    }

    /// The latest input image, or [`ClientError::Tripped`] when the drive latched since this
    /// controller last acknowledged a latch. For control loops that read more than they write.
    pub fn check(&self) -> Result<PzdInput, ClientError> {
        self.shared.link.check()?;
        let state = self.shared.state();
        let input = self.shared.watch.latest();
        match self.shared.news(&input, &state) {
            Some(e) => Err(e),
            None => Ok(input),
        }
    }

    /// Re-publishes the current words with a new sequence number: the watchdog refresh.
    pub fn refresh(&self) -> Result<(), ClientError> {
        self.shared.publish(|_| {})
    }

    /// Acknowledges the drive's latch (a trip, an override, ussd's start) and re-arms it the
    /// PROFIdrive way: sends OFF1 (STW1 0x047E, setpoint and every further word 0) and waits until ussd has taken it
    /// and the drive is live again. Then an ON ([`Controller::run_hz`], ...) reaches the drive.
    /// The drive itself may need [`Controller::acknowledge_fault`] too.
    pub fn rearm(&self) -> Result<PzdInput, ClientError> {
        {
            let mut state = self.shared.state();
            let input = self.shared.watch.latest();
            if !input.is_live() {
                state.known_latch = latch_id(&input);
                state.off1_sent = false;
            }
        }
        // OFF1 with every other word 0: nothing of the words before the latch (a setpoint,
        // PZD3.. such as STW2 or a second setpoint) goes out again with the re-arm.
        self.shared.publish(|i| {
            i.words = [0; MAX_PZD_WORDS];
            i.words[0] = Stw1::READY.bits();
        })?;
        let live = self.wait_for(HANDSHAKE_TIMEOUT, "re-armed (live)", PzdInput::is_live);
        match live {
            Ok(input) => Ok(input),
            Err(ClientError::WaitTimeout { .. } | ClientError::Stale { .. }) => {
                Err(ClientError::latched(
                    &self.shared.bus,
                    self.shared.address,
                    &self.inputs().latest(),
                    false,
                ))
            }
            Err(e) => Err(e),
        }
    }

    /// STW1 0x047E (OFF1, everything else enabled): S1 -> S2 (ready to switch on). Also
    /// stops a running drive along its ramp, like [`Controller::stop`], and re-arms a latched
    /// drive whose latch this controller knows (its first OFF1 after the latch).
    pub fn enable(&self) -> Result<(), ClientError> {
        self.command(Stw1::READY)
    }

    /// STW1 0x047F with a setpoint in % of the reference (0x4000 = 100 %, -200..+199.99 %):
    /// S2 -> S3 -> S4, running. A negative setpoint runs the other way (signed HSW, USS.md
    /// section 7); a drive may block negative setpoints by its own parameters.
    pub fn run_percent(&self, percent: f32) -> Result<(), ClientError> {
        self.run_setpoint(Setpoint::from_percent(percent))
    }

    /// Like [`Controller::run_percent`], in Hz: scaled by the drive's reference frequency
    /// P2000 as ussd's configuration gives it ([`DriveWatch::info`]), so a controller and every
    /// monitor show the same Hz for the same setpoint.
    pub fn run_hz(&self, hz: f32) -> Result<(), ClientError> {
        let reference_hz = self.shared.watch.info().reference_hz;
        self.run_setpoint(Setpoint::from_hz(hz, reference_hz))
    }

    /// STW1 0x047F with a raw setpoint.
    pub fn run_setpoint(&self, setpoint: Setpoint) -> Result<(), ClientError> {
        self.shared.publish(|i| {
            i.words[0] = with_direction(Stw1::RUN, i.words[0]).bits();
            set_word(i, 1, setpoint.word());
        })
    }

    /// Changes only the setpoint (STW1 stays as it is).
    pub fn set_setpoint(&self, setpoint: Setpoint) -> Result<(), ClientError> {
        self.shared.publish(|i| set_word(i, 1, setpoint.word()))
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
        self.shared.publish(|i| {
            let mut stw1 = Stw1::from_bits_retain(i.words[0]);
            stw1.set(Stw1::REVERSE, reverse);
            i.words[0] = stw1.bits();
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
    /// (switching-on inhibited) or S2; [`Controller::enable`] continues from there.
    pub fn acknowledge_fault(&self, timeout: Duration) -> Result<(), ClientError> {
        self.command(Stw1::ACK_FAULT)?;
        let waited = self.wait_for(timeout, "fault acknowledge sent", {
            let start = self.inputs().latest().sequence;
            move |i| i.sequence >= start + 2
        });
        // Back to 0x047E whatever happened: the next acknowledge needs the falling edge.
        self.command(Stw1::READY)?;
        waited.map(|_| ())
    }

    /// Sends `words` as they are (STW1 first). They must be exactly the drive's PZD length and
    /// keep STW1 bit 10 set, or [`ClientError::InvalidSample`]: ussd would refuse them and
    /// latch the drive.
    pub fn set_words(&self, words: &[u16]) -> Result<(), ClientError> {
        if words.len() > MAX_PZD_WORDS {
            return Err(uss_shm_types::ContractError::PzdWords(words.len()).into());
        }
        self.shared.publish(|i| {
            i.words = [0; MAX_PZD_WORDS];
            i.words[..words.len()].copy_from_slice(words);
            i.count = words.len();
        })
    }

    /// Waits until `done` holds for the drive's input image, refreshing every
    /// [`DEFAULT_REFRESH`] meanwhile so the watchdog stays quiet. Fails with
    /// [`ClientError::Tripped`] as soon as the drive latches.
    pub fn wait_for(
        &self,
        timeout: Duration,
        wanted: &str,
        mut done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        let start = Instant::now();
        let watch = &self.shared.watch;
        let first = watch.latest().sequence;
        let mut refreshed = start;
        loop {
            let latest = self.check()?;
            if done(&latest) {
                return Ok(latest);
            }
            if start.elapsed() >= timeout {
                return Err(watch.timed_out(timeout, wanted, first, &latest));
            }
            if refreshed.elapsed() >= DEFAULT_REFRESH {
                self.refresh()?;
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

    /// Refreshes from a thread every `period` until the returned [`Refresher`] is dropped or
    /// stopped. Setters keep working meanwhile. While the drive is latched by news this
    /// controller has not acknowledged, the refresher publishes nothing (the next call of the
    /// owning thread reports the latch); after [`Controller::rearm`] it goes on.
    pub fn spawn_refresher(&self, period: Duration) -> Refresher {
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

    /// Hands the drive back cleanly: ussd sends its safe command, latched, and shows it
    /// "released" (not a watchdog trip). Waits until ussd took the release (at most
    /// [`HANDSHAKE_TIMEOUT`]) and returns the image that says so. Dropping a controller does
    /// the same, ignoring errors.
    pub fn release(mut self) -> Result<PzdInput, ClientError> {
        self.released = true;
        self.shared.release(HANDSHAKE_TIMEOUT)
    }

    fn command(&self, stw1: Stw1) -> Result<(), ClientError> {
        self.shared.publish(|i| i.words[0] = stw1.bits())
    }
}

impl Drop for Controller {
    fn drop(&mut self) {
        if !self.released {
            // A drive that stays unreachable (ussd gone) ends the wait at the timeout; the
            // watchdog then covers it, as it covers a crash.
            let _ = self.shared.release(HANDSHAKE_TIMEOUT);
        }
    }
}

/// `stw1` with the reverse bit of `previous`.
fn with_direction(stw1: Stw1, previous: u16) -> Stw1 {
    stw1 | (Stw1::from_bits_retain(previous) & Stw1::REVERSE)
}

/// Sets word `index`, widening the image if it was shorter.
fn set_word(image: &mut Image, index: usize, word: u16) {
    image.words[index] = word;
    image.count = image.count.max(index + 1);
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
        match shared.publish(|_| {}) {
            // The owner learns of a latch (or of ussd's absence) at its next call and decides;
            // until then the refresher must not keep a tripped drive's controller looking
            // alive. After a re-arm (or a reconnect) it goes on.
            Ok(())
            | Err(
                ClientError::Tripped { .. }
                | ClientError::NotArmed { .. }
                | ClientError::UssdGone { .. }
                | ClientError::UssdStopped { .. }
                | ClientError::LineDown { .. },
            ) => {}
            Err(e) => return Err(e),
        }
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
    fn setting_the_setpoint_widens_a_short_image() {
        let mut image = Image {
            words: [0; MAX_PZD_WORDS],
            count: 1,
            sequence: 0,
        };
        set_word(&mut image, 1, 0x2000);
        assert_eq!((image.count, image.words[1]), (2, 0x2000));
        image.count = 4;
        set_word(&mut image, 1, 0x1000);
        assert_eq!(image.count, 4);
    }

    #[test]
    fn a_latch_is_known_by_its_count_and_start() {
        let mut i = PzdInput::EMPTY;
        i.latches = 3;
        i.latched_since_ns = 99;
        assert_eq!(latch_id(&i), (3, 99));
    }

    #[test]
    fn monotonic_clock_advances() {
        let a = monotonic_ns();
        let b = monotonic_ns();
        assert!(a > 0 && b >= a);
    }
}
