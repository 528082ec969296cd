//! [`Controller`]: the one handle that writes a drive's output image (STW1, setpoint, further
//! PZD words), with helpers that follow the PROFIdrive state machine (USS.md section 7).

use crate::open::{Ipc, layout_verifier, opened};
use crate::{Bus, ClientError, DriveWatch};
use core::time::Duration;
use iceoryx2::node::NodeView;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::prelude::{CallbackProgression, Node, NodeState, PortFactory as _};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSub;
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Instant;
use uss_protocol::{DriveState, Setpoint, Stw1};
use uss_shm_types::names;
use uss_shm_types::{DriveAddress, MAX_PZD_WORDS, PzdInput, PzdOutput};

/// A refresh period that suits ussd's default watchdog of 100 ms (`watchdog_ms`).
pub const DEFAULT_REFRESH: Duration = Duration::from_millis(20);

/// How a [`Controller`] starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct ControlOptions {
    /// PZD words to send, STW1 and setpoint included (must equal the drive's PZD length,
    /// P2012 / `pzd` in ussd's configuration). `None`: as many as the drive replies with, and
    /// at least 2.
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

/// Shared with a [`Refresher`] thread.
struct Shared {
    publisher: Publisher<Ipc, PzdOutput, ()>,
    image: Mutex<Image>,
    pid: u32,
}

impl Shared {
    fn image(&self) -> std::sync::MutexGuard<'_, Image> {
        // The image is plain data, valid whatever a panicking holder left behind.
        self.image.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Changes the image with `f` and publishes it with the next sequence number.
    fn publish(&self, f: impl FnOnce(&mut Image)) -> Result<(), ClientError> {
        let mut image = self.image();
        f(&mut image);
        image.sequence = image.sequence.wrapping_add(1).max(1);
        let out = PzdOutput::from_words(
            &image.words[..image.count],
            image.sequence,
            monotonic_ns(),
            self.pid,
        )?;
        self.publisher
            .send_copy(out)
            .map_err(|e| ClientError::ipc("publishing the output image", e))?;
        Ok(())
    }
}

/// `CLOCK_MONOTONIC` in ns, the clock of every `*_ns` field of the contract.
pub(crate) fn monotonic_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).map_or(0, |t| {
        (t.tv_sec() as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(t.tv_nsec() as u64)
    })
}

/// Exclusive control of one drive: the only writer of its output image. Obtained from
/// [`Bus::control`]; a second controller for the same drive is refused while this one lives.
///
/// **Watchdog.** ussd sends the drive its safe command (OFF1 unless configured otherwise)
/// when the controller has not published a new sample within the drive's watchdog time
/// (`watchdog_ms` in ussd's configuration, 100 ms by default), and when no controller exists.
/// Every setter publishes; between changes call [`Controller::refresh`] at least once per
/// watchdog time (every [`DEFAULT_REFRESH`] suits the default), or let
/// [`Controller::spawn_refresher`] do it from a thread. Dropping the controller hands the drive
/// to that safe command.
///
/// The helpers keep STW1 bit 10 ("control by PLC") set: without it the drive ignores the PZD.
/// Every publish carries this process's id, a `CLOCK_MONOTONIC` time stamp and a new sequence
/// number.
pub struct Controller {
    bus: String,
    address: DriveAddress,
    shared: Arc<Shared>,
    watch: DriveWatch,
}

impl core::fmt::Debug for Controller {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Controller")
            .field("bus", &self.bus)
            .field("address", &self.address.get())
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
        let name = names::drive_out(bus.bus_name(), address);
        let service = opened(
            bus.node()
                .service_builder(&name)
                .publish_subscribe::<PzdOutput>()
                .open_with_attributes(&layout_verifier()?),
            bus.name(),
            &name,
            || bus.unknown_drive(address.get()),
        )?;
        let publisher = match service.publisher_builder().create() {
            Ok(p) => p,
            Err(PublisherCreateError::ExceedsMaxSupportedPublishers) => {
                let (pid, node) = holder(bus.node(), &service).unzip();
                return Err(ClientError::Controlled {
                    bus: bus.name().to_owned(),
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
        let watch = DriveWatch::open(bus, address)?;
        let count = match options.words {
            Some(n) if n > MAX_PZD_WORDS => {
                return Err(uss_shm_types::ContractError::PzdWords(n).into());
            }
            Some(n) => n,
            None => usize::from(watch.latest().word_count).clamp(2, MAX_PZD_WORDS),
        };
        let mut words = [0; MAX_PZD_WORDS];
        words[0] = Stw1::READY.bits();
        Ok(Self {
            bus: bus.name().to_owned(),
            address,
            shared: Arc::new(Shared {
                publisher,
                image: Mutex::new(Image {
                    words,
                    count,
                    // A clock-based start: the first sample of a new controller never repeats
                    // its predecessor's last sequence number (ussd counts a refresh only when
                    // the sequence changes).
                    sequence: monotonic_ns(),
                }),
                pid: std::process::id(),
            }),
            watch,
        })
    }

    /// The drive's address.
    pub fn address(&self) -> u8 {
        self.address.get()
    }

    /// The drive's inputs, read while controlling it.
    pub fn inputs(&self) -> &DriveWatch {
        &self.watch
    }

    /// The words this controller sends (STW1 first).
    pub fn words(&self) -> Vec<u16> {
        let image = self.shared.image();
        image.words[..image.count].to_vec()
    }

    /// The current STW1.
    pub fn stw1(&self) -> Stw1 {
        Stw1::from_bits_retain(self.shared.image().words[0])
    }

    /// The sequence number of the last publish.
    pub fn sequence(&self) -> u64 {
        self.shared.image().sequence
    }

    /// Re-publishes the current words with a new sequence number: the watchdog refresh.
    pub fn refresh(&self) -> Result<(), ClientError> {
        self.shared.publish(|_| {})
    }

    /// STW1 0x047E (OFF1, everything else enabled): S1 -> S2 (ready to switch on). Also
    /// stops a running drive along its ramp, like [`Controller::stop`].
    pub fn enable(&self) -> Result<(), ClientError> {
        self.command(Stw1::READY)
    }

    /// STW1 0x047F with a setpoint in % of the reference (0x4000 = 100 %, -200..+199.99 %):
    /// S2 -> S3 -> S4, running. A negative setpoint runs the other way (signed HSW, USS.md
    /// section 7); a drive may block negative setpoints by its own parameters.
    pub fn run_percent(&self, percent: f32) -> Result<(), ClientError> {
        self.run_setpoint(Setpoint::from_percent(percent))
    }

    /// Like [`Controller::run_percent`], in Hz given the drive's reference frequency P2000.
    pub fn run_hz(&self, hz: f32, reference_hz: f32) -> Result<(), ClientError> {
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
            let start = self.watch.latest().sequence;
            move |i| i.sequence >= start + 2
        });
        // Back to 0x047E whatever happened: the next acknowledge needs the falling edge.
        self.command(Stw1::READY)?;
        waited.map(|_| ())
    }

    /// Sends `words` as they are (STW1 first, at most 16), e.g. for drives with more PZD
    /// words. Keep STW1 bit 10 set: with it clear the drive ignores the PZD.
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
    /// [`DEFAULT_REFRESH`] meanwhile so the watchdog stays quiet.
    pub fn wait_for(
        &self,
        timeout: Duration,
        wanted: &str,
        mut done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        let start = Instant::now();
        let first = self.watch.latest().sequence;
        let mut refreshed = start;
        loop {
            let latest = self.watch.latest();
            if done(&latest) {
                return Ok(latest);
            }
            if start.elapsed() >= timeout {
                return Err(self.watch.timed_out(timeout, wanted, first, &latest));
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
    /// stopped. Setters keep working meanwhile.
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

    fn command(&self, stw1: Stw1) -> Result<(), ClientError> {
        self.shared.publish(|i| i.words[0] = stw1.bits())
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
        shared.publish(|_| {})?;
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
    fn monotonic_clock_advances() {
        let a = monotonic_ns();
        let b = monotonic_ns();
        assert!(a > 0 && b >= a);
    }
}
