//! Telegram capture: every telegram of a bus as ussd's bus thread sent and received it, from
//! `uss/<bus>/<gen>/capture` ([`TelegramRecord`]).

use crate::link::Link;
use crate::open::{Ipc, layout_verifier, opened};
use crate::{Bus, ClientError};
use iceoryx2::port::subscriber::Subscriber;
use std::sync::Arc;
use uss_shm_types::names::{self, CAPTURE_MAX_SUBSCRIBERS};
use uss_shm_types::{Generation, TelegramRecord};

/// A subscription to a bus's telegrams. Records arrive in the order the bus thread captured
/// them; a capture that does not take them for a while ([`names::CAPTURE_BUFFER`] records,
/// about 2 s of a busy bus) loses the oldest, and [`Capture::lost`] counts them.
pub struct Capture {
    link: Arc<Link>,
    generation: Generation,
    subscriber: Subscriber<Ipc, TelegramRecord, ()>,
    last_sequence: u64,
    lost: u64,
}

impl core::fmt::Debug for Capture {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Capture")
            .field("bus", &self.link.name.as_str())
            .field("lost", &self.lost)
            .finish_non_exhaustive()
    }
}

impl Capture {
    pub(crate) fn open(bus: &Bus) -> Result<Self, ClientError> {
        let services = bus.services()?;
        let link = Arc::clone(bus.link());
        let name = names::capture(&services.instance);
        let bus_name = link.name.as_str();
        let service = opened(
            link.node
                .service_builder(&name)
                .publish_subscribe::<TelegramRecord>()
                .open_with_attributes(&layout_verifier()?),
            bus_name,
            &name,
            || ClientError::not_running(bus_name.to_owned()),
        )?;
        let subscriber = service.subscriber_builder().create().map_err(|e| {
            ClientError::ipc(
                format!(
                    "capturing the telegrams of {bus_name} (at most {CAPTURE_MAX_SUBSCRIBERS} \
                     captures at once)"
                ),
                e,
            )
        })?;
        Ok(Self {
            generation: services.generation(),
            link,
            subscriber,
            last_sequence: 0,
            lost: 0,
        })
    }

    /// The records that arrived since the last call, oldest first. Fails when ussd no longer
    /// serves the bus as it did when the capture began (gone, stopped, restarted, line down):
    /// what it captured until then was taken by earlier calls.
    pub fn take(&mut self) -> Result<Vec<TelegramRecord>, ClientError> {
        let mut records = Vec::new();
        while let Some(sample) = self
            .subscriber
            .receive()
            .map_err(|e| ClientError::ipc("receiving captured telegrams", e))?
        {
            let record = *sample;
            record.check()?;
            if self.last_sequence != 0 && record.sequence > self.last_sequence + 1 {
                self.lost += record.sequence - self.last_sequence - 1;
            }
            self.last_sequence = record.sequence;
            records.push(record);
        }
        if records.is_empty() {
            let services = self.link.check()?;
            if services.generation() != self.generation {
                return Err(ClientError::ipc(
                    format!("capturing the telegrams of {}", self.link.name.as_str()),
                    "ussd was restarted: start the capture again",
                ));
            }
        }
        Ok(records)
    }

    /// Records lost between those taken (the subscriber's buffer overflowed).
    pub const fn lost(&self) -> u64 {
        self.lost
    }
}
