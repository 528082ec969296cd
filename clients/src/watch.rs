//! Reading a drive's inputs ([`DriveWatch`]) and running in step with the bus
//! ([`CycleListener`]).

use crate::link::{HEARTBEAT_PERIOD, Link, Services};
use crate::open::{Ipc, entry, layout_verifier, opened, unknown_drive};
use crate::{Bus, ClientError};
use core::time::Duration;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::reader::EntryHandle;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Instant;
use uss_protocol::{DriveState, Setpoint, Zsw1};
use uss_shm_types::names;
use uss_shm_types::{Address, BlackboardKey, DriveDiag, DriveInfo, Generation, PzdInput};

/// How often the `wait_*` helpers look at the input image.
pub(crate) const POLL: Duration = Duration::from_millis(1);

/// The input image entry of one ussd generation, and its diagnostics entry of the drive, which
/// says what that ussd knows of it ([`DriveInfo`]: its reference frequency is read again
/// whenever it can have changed, so it is read with every image).
struct Port {
    generation: Generation,
    entry: EntryHandle<Ipc, BlackboardKey, PzdInput>,
    diag: EntryHandle<Ipc, BlackboardKey, DriveDiag>,
}

/// One look at a drive ([`DriveWatch::snapshot`]).
#[derive(Debug)]
pub struct Snapshot {
    /// The input image; `online = 0` when it cannot be trusted.
    pub image: PzdInput,
    /// What the ussd that wrote it says of the drive.
    pub info: DriveInfo,
    /// Why the image cannot be trusted (ussd gone, stopped, line down, drive unknown); None
    /// while it can.
    pub problem: Option<ClientError>,
}

/// What a watch keeps between reads.
struct State {
    port: Option<Port>,
    /// The last image read while ussd served the bus.
    last: PzdInput,
    /// What the ussd that wrote `last` says of the drive.
    info: DriveInfo,
}

/// A drive's input image (USS.md section 7: ZSW1, HIW, further PZD words), read from the
/// blackboard ussd writes after every poll. Reading never blocks and never allocates (unless
/// ussd was restarted: then the new generation's image is opened on the next read).
///
/// The image never shows a healthy picture that is not true: while ussd is gone or stopped,
/// or its line is down, [`DriveWatch::latest`] returns the last image with `online = 0`, and
/// [`DriveWatch::read`] says why with an error.
pub struct DriveWatch {
    link: Arc<Link>,
    address: Address,
    state: Mutex<State>,
}

impl core::fmt::Debug for DriveWatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("DriveWatch")
            .field("bus", &self.link.name.as_str())
            .field("address", &self.address.get())
            .finish_non_exhaustive()
    }
}

/// Opens the input image entry of drive `address` of the generation `services` belong to.
fn open_port(link: &Link, services: &Services, address: Address) -> Result<Port, ClientError> {
    let bus = link.name.as_str();
    let name = names::drive_in(&services.instance, address);
    let service = opened(
        link.node
            .service_builder(&name)
            .blackboard_opener::<BlackboardKey>()
            .open_with_attributes(&layout_verifier()?),
        bus,
        &name,
        unknown_drive(bus, address.get()),
    )?;
    let entry = entry(&service, bus, &name, BlackboardKey::IMAGE)?;
    let diag = services
        .diag
        .entry::<DriveDiag>(&BlackboardKey::drive(address))
        .map_err(|_| unknown_drive(bus, address.get())())?;
    Ok(Port {
        generation: services.generation(),
        entry,
        diag,
    })
}

impl DriveWatch {
    pub(crate) fn open(bus: &Bus, address: Address) -> Result<Self, ClientError> {
        let services = bus.services()?;
        let port = open_port(bus.link(), &services, address).map_err(|e| match e {
            ClientError::UnknownDrive { .. } => bus.unknown_drive(address),
            other => other,
        })?;
        let last = *port.entry.get();
        let info = port.diag.get().info;
        Ok(Self {
            link: Arc::clone(bus.link()),
            address,
            state: Mutex::new(State {
                port: Some(port),
                last,
                info,
            }),
        })
    }

    fn cache(&self) -> MutexGuard<'_, State> {
        // Plain data, valid whatever a panicking holder left behind.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The latest input image, what ussd says of the drive, and, when the image cannot be
    /// trusted, why: all from one read of the image. A stale image is the last one read, with
    /// `online = 0`.
    pub fn snapshot(&self) -> Snapshot {
        let (health, services) = self.link.current();
        let mut state = self.cache();
        if let Some(services) = services.filter(|_| health.is_serving()) {
            if state.port.as_ref().map(|p| p.generation) != Some(services.generation()) {
                state.port = open_port(&self.link, &services, self.address).ok();
            }
            if let Some((last, info)) = state.port.as_ref().map(|p| {
                let last = *p.entry.get();
                (last, p.diag.get().info_for(&last))
            }) {
                state.last = last;
                state.info = info;
            }
        }
        let mut problem = health.error(self.link.name.as_str());
        let mut image = state.last;
        if problem.is_none() && image.is_overdue(crate::link::monotonic_ns()) {
            // ussd serves the bus, but the drive's poll is overdue by ussd's own limit: the
            // image is not the drive as it is (a stalled bus thread, a line slower than it was).
            problem = Some(ClientError::Stale {
                bus: self.link.name.as_str().to_owned(),
                address: self.address.get(),
                timeout: Duration::from_nanos(image.stale_after_ns),
            });
        }
        if problem.is_some() || state.port.is_none() {
            image.online = 0;
        }
        let problem = problem.or_else(|| {
            state.port.is_none().then(|| ClientError::UnknownDrive {
                bus: self.link.name.as_str().to_owned(),
                address: self.address.get(),
                known: Vec::new(),
            })
        });
        Snapshot {
            image,
            info: state.info,
            problem,
        }
    }

    /// The drive's address.
    pub fn address(&self) -> Address {
        self.address
    }

    /// The latest input image. `sequence` counts good replies (0 = none yet); `online` is 0
    /// while the drive does not answer, and while ussd does not poll it (gone, stopped, line
    /// down); `known` is 0 until ussd's first poll decided `online`.
    pub fn latest(&self) -> PzdInput {
        self.snapshot().image
    }

    /// The latest input image, or why it cannot be trusted: [`ClientError::UssdGone`],
    /// [`ClientError::UssdStopped`], [`ClientError::LineDown`].
    pub fn read(&self) -> Result<PzdInput, ClientError> {
        let s = self.snapshot();
        s.problem.map_or(Ok(s.image), Err)
    }

    /// How long ago the image's reply arrived.
    pub fn age(&self) -> Duration {
        let at = self.snapshot().image.timestamp_ns;
        Duration::from_nanos(crate::link::monotonic_ns().saturating_sub(at))
    }

    /// Whether the drive answers.
    pub fn is_online(&self) -> bool {
        self.latest().online != 0
    }

    /// The latest status word ZSW1.
    pub fn zsw1(&self) -> Zsw1 {
        Zsw1::from_bits_retain(self.latest().zsw1)
    }

    /// The PROFIdrive state read from the latest ZSW1 (USS.md section 7).
    pub fn state(&self) -> DriveState {
        DriveState::from_zsw1(self.zsw1())
    }

    /// What ussd says of the drive (its configuration): reference frequency, PZD and PKW
    /// lengths, watchdog, safe command, writability. A restarted ussd's description replaces
    /// the old one on the next read.
    pub fn info(&self) -> DriveInfo {
        self.snapshot().info
    }

    /// The main actual value HIW in Hz, scaled by the drive's reference frequency P2000 as
    /// ussd publishes it ([`DriveInfo::reference_hz`]: the drive's own value once read); NaN
    /// while ussd reads the reference again (no Hz are known then).
    pub fn actual_hz(&self) -> f32 {
        let s = self.snapshot();
        s.info
            .reference()
            .map_or(f32::NAN, |r| Setpoint::from_word(s.image.hiw).hz(r))
    }

    /// The main actual value HIW in % of the reference.
    pub fn actual_percent(&self) -> f32 {
        Setpoint::from_word(self.latest().hiw).percent()
    }

    /// How long to wait for what the drive's next poll brings (a stop confirmed, a re-arm or
    /// release taken): ussd's freshness limit for the drive as its image states it (its turn in
    /// the circulating list and one poll with all its retries), at least
    /// [`crate::HANDSHAKE_TIMEOUT`]. 31 drives at 9600 baud poll each drive only every 1.3 s.
    pub fn handshake(&self) -> Duration {
        Duration::from_nanos(self.latest().handshake_ns())
    }

    /// How long to wait for ussd to read the drive's reference again (after it came online,
    /// was reset or commissioned) before a setpoint in Hz can be scaled: its two own reads
    /// (monitoring, then reference) each take a poll to ask and one to answer, so four of the
    /// drive's handshake times.
    pub fn reference_wait(&self) -> Duration {
        self.handshake() * 4
    }

    /// Waits (looking every millisecond, at most `timeout`) until ussd knows the drive's
    /// reference frequency, and returns it: after ussd's start, a drive coming online, a reset
    /// or commissioning write it reads it again, and no Hz are scaled until then.
    /// [`ClientError::ReferenceUnknown`] when it is still not known after `timeout`
    /// ([`DriveWatch::reference_wait`] is the drive's own bound).
    pub fn wait_for_reference(&self, timeout: Duration) -> Result<f32, ClientError> {
        let until = std::time::Instant::now() + timeout;
        loop {
            if let Some(hz) = self.info().reference() {
                return Ok(hz);
            }
            if std::time::Instant::now() >= until {
                return Err(ClientError::ReferenceUnknown {
                    bus: self.link.name.as_str().to_owned(),
                    address: self.address.get(),
                    asked: "a setpoint in Hz".to_owned(),
                });
            }
            std::thread::sleep(POLL);
        }
    }

    /// Waits until `done` holds for the input image (looking every millisecond) and returns
    /// that image; after `timeout`, fails with [`ClientError::WaitTimeout`] naming `wanted`.
    pub fn wait_for(
        &self,
        timeout: Duration,
        wanted: &str,
        done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        self.wait_until(|_| timeout, wanted, done)
    }

    /// Like [`DriveWatch::wait_for`], for what the drive's next poll brings: waits the drive's
    /// [`DriveWatch::handshake`] time, as its image states it while waiting.
    pub fn wait_polled(
        &self,
        wanted: &str,
        done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        self.wait_until(|i| Duration::from_nanos(i.handshake_ns()), wanted, done)
    }

    fn wait_until(
        &self,
        timeout: impl Fn(&PzdInput) -> Duration,
        wanted: &str,
        mut done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        let start = Instant::now();
        let first = self.latest().sequence;
        loop {
            let latest = self.latest();
            if done(&latest) {
                return Ok(latest);
            }
            let timeout = timeout(&latest);
            if start.elapsed() >= timeout {
                return Err(self.timed_out(timeout, wanted, first, &latest));
            }
            std::thread::sleep(POLL);
        }
    }

    /// Waits until the drive is in `state`.
    pub fn wait_for_state(
        &self,
        state: DriveState,
        timeout: Duration,
    ) -> Result<PzdInput, ClientError> {
        self.wait_for(timeout, state.short_name(), |i| {
            i.online != 0 && crate::state_of(i) == state
        })
    }

    /// Waits until ussd completed `n` more exchanges with the drive: after it returns, at
    /// least `n - 1` telegrams were built after the call began (so with `n = 2` the drive
    /// has received whatever was published before the call).
    pub fn wait_exchanges(&self, n: u64, timeout: Duration) -> Result<PzdInput, ClientError> {
        let start = self.latest().sequence;
        self.wait_for(timeout, &format!("{n} exchanges"), |i| {
            i.sequence >= start + n
        })
    }

    /// The error of a wait that began when the image had sequence `first`: why ussd does not
    /// poll, or stale when ussd wrote nothing meanwhile (an offline drive's image is still
    /// written after every poll).
    pub(crate) fn timed_out(
        &self,
        timeout: Duration,
        wanted: &str,
        first: u64,
        latest: &PzdInput,
    ) -> ClientError {
        if let Some(e) = self.snapshot().problem {
            return e;
        }
        if latest.sequence == first && latest.online != 0 {
            return ClientError::Stale {
                bus: self.link.name.as_str().to_owned(),
                address: self.address.get(),
                timeout,
            };
        }
        ClientError::WaitTimeout {
            bus: self.link.name.as_str().to_owned(),
            address: self.address.get(),
            timeout,
            wanted: wanted.to_owned(),
            online: latest.online != 0,
            zsw1: latest.zsw1,
        }
    }
}

/// One notification on the bus's `cycle` event service.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CycleEvent {
    /// An exchange with this drive completed and its input image was updated.
    Exchange(u8),
    /// A pass through the circulating list completed (USS.md section 5).
    CycleCompleted,
    /// `status` and `diag` were republished.
    StatusPublished,
    /// ussd left this generation (a clean stop says goodbye; a killed ussd's dead notifier
    /// says it when its node is cleaned up). The heartbeat says the same within 0.5 s, and a
    /// restarted ussd is followed by itself.
    UssdGone,
    /// An id this client does not know (a newer ussd).
    Other(usize),
}

impl CycleEvent {
    pub fn from_id(id: usize) -> Self {
        match id {
            names::CYCLE_COMPLETED => Self::CycleCompleted,
            names::STATUS_PUBLISHED => Self::StatusPublished,
            names::USSD_GONE => Self::UssdGone,
            a if a <= usize::from(names::MAX_ADDRESS) => Self::Exchange(a as u8),
            other => Self::Other(other),
        }
    }
}

/// Wakes on the bus's exchange and cycle events, so a control loop runs in step with the bus
/// instead of polling. Follows a restarted ussd to its new generation.
pub struct CycleListener {
    link: Arc<Link>,
    listener: Mutex<(Generation, Listener<Ipc>)>,
}

impl core::fmt::Debug for CycleListener {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CycleListener")
            .field("bus", &self.link.name.as_str())
            .finish_non_exhaustive()
    }
}

fn open_listener(link: &Link, services: &Services) -> Result<Listener<Ipc>, ClientError> {
    let bus = link.name.as_str();
    let name = names::cycle(&services.instance);
    let service = opened(
        link.node
            .service_builder(&name)
            .event()
            .open_with_attributes(&layout_verifier()?),
        bus,
        &name,
        || ClientError::not_running(bus.to_owned()),
    )?;
    service
        .listener_builder()
        .create()
        .map_err(|e| ClientError::ipc(format!("listening on {}", name.as_str()), e))
}

impl CycleListener {
    pub(crate) fn open(bus: &Bus) -> Result<Self, ClientError> {
        let services = bus.services()?;
        let listener = open_listener(bus.link(), &services)?;
        Ok(Self {
            link: Arc::clone(bus.link()),
            listener: Mutex::new((services.generation(), listener)),
        })
    }

    /// The listener of the current generation (reopened after a restart of ussd), or why ussd
    /// does not serve the bus.
    fn listener(&self) -> Result<MutexGuard<'_, (Generation, Listener<Ipc>)>, ClientError> {
        let services = self.link.check()?;
        let mut current = self.listener.lock().unwrap_or_else(PoisonError::into_inner);
        if current.0 != services.generation() {
            *current = (services.generation(), open_listener(&self.link, &services)?);
        }
        Ok(current)
    }

    /// Waits up to `timeout` for events and hands each to `f` (an id notified several times
    /// since the last wait is handed over once). Returns how many ids were handed over: 0
    /// after a timeout. Fails when ussd is gone, stopped or its line is down (looked at every
    /// heartbeat period while waiting).
    pub fn wait(
        &self,
        timeout: Duration,
        mut f: impl FnMut(CycleEvent),
    ) -> Result<usize, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let step = deadline
                .saturating_duration_since(Instant::now())
                .min(HEARTBEAT_PERIOD);
            let mut n = 0;
            self.listener()?
                .1
                .timed_wait(
                    |a| {
                        n += 1;
                        f(CycleEvent::from_id(a.id.as_value()));
                    },
                    step,
                )
                .map_err(|e| ClientError::ipc("waiting for cycle events", e))?;
            if n > 0 || Instant::now() >= deadline {
                return Ok(n);
            }
        }
    }

    /// Hands over the events already pending, without waiting.
    pub fn try_events(&self, mut f: impl FnMut(CycleEvent)) -> Result<usize, ClientError> {
        let mut n = 0;
        self.listener()?
            .1
            .try_wait(|a| {
                n += 1;
                f(CycleEvent::from_id(a.id.as_value()));
            })
            .map_err(|e| ClientError::ipc("reading cycle events", e))?;
        Ok(n)
    }

    /// Waits until `event` arrives: `Ok(true)`, or `Ok(false)` after `timeout`. Fails when
    /// ussd is gone, stopped or its line is down.
    pub fn wait_for(&self, event: CycleEvent, timeout: Duration) -> Result<bool, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let mut seen = false;
            let left = deadline.saturating_duration_since(Instant::now());
            self.wait(left, |e| seen |= e == event)?;
            if seen {
                return Ok(true);
            }
            if Instant::now() >= deadline {
                return Ok(false);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn event_ids_map_to_events() {
        assert_eq!(CycleEvent::from_id(0), CycleEvent::Exchange(0));
        assert_eq!(CycleEvent::from_id(31), CycleEvent::Exchange(31));
        assert_eq!(
            CycleEvent::from_id(names::CYCLE_COMPLETED),
            CycleEvent::CycleCompleted
        );
        assert_eq!(
            CycleEvent::from_id(names::STATUS_PUBLISHED),
            CycleEvent::StatusPublished
        );
        assert_eq!(CycleEvent::from_id(names::USSD_GONE), CycleEvent::UssdGone);
        assert_eq!(CycleEvent::from_id(40), CycleEvent::Other(40));
    }
}
