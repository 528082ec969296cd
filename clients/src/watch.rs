//! Reading a drive's inputs ([`DriveWatch`]) and running in step with the bus
//! ([`CycleListener`]).

use crate::open::{Ipc, layout_verifier, opened};
use crate::{Bus, ClientError};
use core::time::Duration;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::reader::EntryHandle;
use std::time::Instant;
use uss_protocol::{DriveState, Setpoint, Zsw1};
use uss_shm_types::names;
use uss_shm_types::{BlackboardKey, DriveAddress, PzdInput};

/// How often the `wait_*` helpers look at the input image.
pub(crate) const POLL: Duration = Duration::from_millis(1);

/// A drive's input image (USS.md section 7: ZSW1, HIW, further PZD words), read from the
/// blackboard ussd writes after every good reply. Reading never blocks and never allocates.
pub struct DriveWatch {
    bus: String,
    address: DriveAddress,
    entry: EntryHandle<Ipc, BlackboardKey, PzdInput>,
}

impl core::fmt::Debug for DriveWatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("DriveWatch")
            .field("bus", &self.bus)
            .field("address", &self.address.get())
            .finish_non_exhaustive()
    }
}

impl DriveWatch {
    pub(crate) fn open(bus: &Bus, address: DriveAddress) -> Result<Self, ClientError> {
        let name = names::drive_in(bus.bus_name(), address);
        let service = opened(
            bus.node()
                .service_builder(&name)
                .blackboard_opener::<BlackboardKey>()
                .open_with_attributes(&layout_verifier()?),
            bus.name(),
            &name,
            || bus.unknown_drive(address.get()),
        )?;
        let entry = service
            .reader_builder()
            .create()
            .map_err(|e| ClientError::ipc(format!("reading {}", name.as_str()), e))?
            .entry::<PzdInput>(&BlackboardKey::IMAGE)
            .map_err(|_| ClientError::Incompatible {
                bus: bus.name().to_owned(),
                service: name.as_str().to_owned(),
            })?;
        Ok(Self {
            bus: bus.name().to_owned(),
            address,
            entry,
        })
    }

    /// The drive's address.
    pub fn address(&self) -> u8 {
        self.address.get()
    }

    /// The latest input image. `sequence` counts good replies (0 = none yet); `online` is 0
    /// while the drive does not answer.
    pub fn latest(&self) -> PzdInput {
        *self.entry.get()
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

    /// The main actual value HIW in Hz, given the drive's reference frequency P2000.
    pub fn actual_hz(&self, reference_hz: f32) -> f32 {
        Setpoint::from_word(self.latest().hiw).hz(reference_hz)
    }

    /// The main actual value HIW in % of the reference.
    pub fn actual_percent(&self) -> f32 {
        Setpoint::from_word(self.latest().hiw).percent()
    }

    /// Waits until `done` holds for the input image (looking every millisecond) and returns
    /// that image; after `timeout`, fails with [`ClientError::WaitTimeout`] naming `wanted`.
    pub fn wait_for(
        &self,
        timeout: Duration,
        wanted: &str,
        mut done: impl FnMut(&PzdInput) -> bool,
    ) -> Result<PzdInput, ClientError> {
        let deadline = Instant::now() + timeout;
        let first = self.latest().sequence;
        loop {
            let latest = self.latest();
            if done(&latest) {
                return Ok(latest);
            }
            if Instant::now() >= deadline {
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

    /// The error of a wait that began when the image had sequence `first`: stale when ussd
    /// wrote nothing meanwhile (an offline drive's image is still written after every poll).
    pub(crate) fn timed_out(
        &self,
        timeout: Duration,
        wanted: &str,
        first: u64,
        latest: &PzdInput,
    ) -> ClientError {
        if latest.sequence == first && latest.online != 0 {
            return ClientError::Stale {
                bus: self.bus.clone(),
                address: self.address.get(),
                timeout,
            };
        }
        ClientError::WaitTimeout {
            bus: self.bus.clone(),
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
    /// ussd died: drop this [`Bus`] and everything opened from it, then open the bus again
    /// once ussd runs (a restarted ussd cannot update blackboards its predecessor held while
    /// clients keep them open).
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
/// instead of polling.
pub struct CycleListener {
    bus: String,
    listener: Listener<Ipc>,
}

impl core::fmt::Debug for CycleListener {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CycleListener")
            .field("bus", &self.bus)
            .finish_non_exhaustive()
    }
}

impl CycleListener {
    pub(crate) fn open(bus: &Bus) -> Result<Self, ClientError> {
        let name = names::cycle(bus.bus_name());
        let service = opened(
            bus.node()
                .service_builder(&name)
                .event()
                .open_with_attributes(&layout_verifier()?),
            bus.name(),
            &name,
            || ClientError::NotRunning {
                bus: bus.name().to_owned(),
            },
        )?;
        let listener = service
            .listener_builder()
            .create()
            .map_err(|e| ClientError::ipc(format!("listening on {}", name.as_str()), e))?;
        Ok(Self {
            bus: bus.name().to_owned(),
            listener,
        })
    }

    /// Waits up to `timeout` for events and hands each to `f` (an id notified several times
    /// since the last wait is handed over once). Returns how many ids were handed over: 0
    /// after a timeout.
    pub fn wait(
        &self,
        timeout: Duration,
        mut f: impl FnMut(CycleEvent),
    ) -> Result<usize, ClientError> {
        let mut n = 0;
        self.listener
            .timed_wait(
                |a| {
                    n += 1;
                    f(CycleEvent::from_id(a.id.as_value()));
                },
                timeout,
            )
            .map_err(|e| ClientError::ipc("waiting for cycle events", e))?;
        Ok(n)
    }

    /// Hands over the events already pending, without waiting.
    pub fn try_events(&self, mut f: impl FnMut(CycleEvent)) -> Result<usize, ClientError> {
        let mut n = 0;
        self.listener
            .try_wait(|a| {
                n += 1;
                f(CycleEvent::from_id(a.id.as_value()));
            })
            .map_err(|e| ClientError::ipc("reading cycle events", e))?;
        Ok(n)
    }

    /// Waits until `event` arrives: `Ok(true)`, or `Ok(false)` after `timeout`. Fails with
    /// [`ClientError::UssdGone`] when ussd died.
    pub fn wait_for(&self, event: CycleEvent, timeout: Duration) -> Result<bool, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            let (mut seen, mut gone) = (false, false);
            let left = deadline.saturating_duration_since(Instant::now());
            self.wait(left, |e| {
                seen |= e == event;
                gone |= e == CycleEvent::UssdGone;
            })?;
            if gone && event != CycleEvent::UssdGone {
                return Err(ClientError::UssdGone {
                    bus: self.bus.clone(),
                });
            }
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
