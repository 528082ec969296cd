//! The bus thread's side: [`RtBridge`], the engine's [`Bridge`]. It takes the latest
//! controller sample of each drive (subscriber `receive`) and hands it to the engine as it
//! arrived, publishes each drive's input image after every poll (blackboard
//! `update_with_copy`) and signals exchange and cycle events (`notify`). None of these
//! allocates (shm-types' pattern tests count it).

use super::requesters::Requesters;
use super::status::ControlView;
use super::{IpcError, IpcNode, MAX_CLIENTS, MAX_NODES, Svc, fail, text};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::writer::{EntryHandleMut, Writer};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use std::sync::Arc;
use uss_engine::Bridge;
use uss_engine::control::ControllerId;
use uss_engine::image::DriveImages;
use uss_engine::jobs::Requester;
use uss_engine::stats::DriveStatus;
use uss_protocol::Address;
use uss_shm_types::names;
use uss_shm_types::{BlackboardKey, Instance, PzdInput, PzdOutput, StopCommand};

pub(crate) type OutService = PubSubFactory<Svc, PzdOutput, ()>;

/// The services of one drive: its output (ussd subscribes; the factory stays with the
/// parameter server, which asks it who controls the drive) and its input image (ussd writes).
pub(super) fn create_drive(
    node: &IpcNode,
    bus: &Instance,
    address: Address,
    attributes: &AttributeSpecifier,
) -> Result<(RtDrive, OutService), IpcError> {
    let out = node
        .service_builder(&names::drive_out(bus, address))
        .publish_subscribe::<PzdOutput>()
        .max_publishers(names::OUT_MAX_PUBLISHERS)
        .max_subscribers(2)
        .subscriber_max_buffer_size(names::OUT_LATEST_ONLY)
        .history_size(names::OUT_HISTORY)
        .enable_safe_overflow(true)
        .max_nodes(MAX_NODES)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, format!("the output service of drive {address}"))(text(e)))?;
    let subscriber = out
        .subscriber_builder()
        .buffer_size(names::OUT_LATEST_ONLY)
        .create()
        .map_err(|e| fail(bus, format!("the output subscriber of drive {address}"))(text(e)))?;
    let input = node
        .service_builder(&names::drive_in(bus, address))
        .blackboard_creator::<BlackboardKey>()
        .max_readers(MAX_CLIENTS)
        .max_nodes(MAX_NODES)
        .add::<PzdInput>(BlackboardKey::IMAGE, PzdInput::EMPTY)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, format!("the input blackboard of drive {address}"))(text(e)))?;
    let writer = input
        .writer_builder()
        .create()
        .map_err(|e| fail(bus, format!("the input writer of drive {address}"))(text(e)))?;
    let entry = writer
        .entry::<PzdInput>(&BlackboardKey::IMAGE)
        .map_err(|e| fail(bus, format!("the input entry of drive {address}"))(text(e)))?;
    let drive = RtDrive {
        event: EventId::new(names::exchange_completed(address)),
        last: (0, 0),
        period: 0,
        subscriber,
        entry,
        _writer: writer,
    };
    Ok((drive, out))
}

pub(super) struct RtDrive {
    event: EventId,
    /// Number and time stamp of the last good reply published, for the update period.
    last: (u64, u64),
    /// Time between the last two good replies.
    period: u64,
    subscriber: Subscriber<Svc, PzdOutput, ()>,
    entry: EntryHandleMut<Svc, BlackboardKey, PzdInput>,
    _writer: Writer<Svc, BlackboardKey>,
}

/// The bus thread's ports. See the module documentation.
pub struct RtBridge {
    drives: Vec<RtDrive>,
    notifier: Notifier<Svc>,
    /// Wakes the parameter bridge when a job's result is ready ([`names::RESULT_READY`]).
    results: Notifier<Svc>,
    origin_ns: u64,
    /// The processes behind parameter jobs, as the parameter server watches them.
    requesters: Arc<Requesters>,
}

impl RtBridge {
    pub(super) fn new(
        drives: Vec<RtDrive>,
        (notifier, results): (Notifier<Svc>, Notifier<Svc>),
        origin_ns: u64,
        requesters: Arc<Requesters>,
    ) -> Self {
        Self {
            drives,
            notifier,
            results,
            origin_ns,
            requesters,
        }
    }
}

impl core::fmt::Debug for RtBridge {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("RtBridge")
            .field("drives", &self.drives.len())
            .finish_non_exhaustive()
    }
}

impl Bridge for RtBridge {
    fn take_sample(&mut self, slot: usize, _: &DriveImages) -> Option<(PzdOutput, ControllerId)> {
        let d = self.drives.get(slot)?;
        // Buffer 1 with safe overflow: at most the latest sample is waiting. It goes to the
        // engine as it arrived, with its publisher's id and process (iceoryx2's, from the
        // header its port wrote: not what the sample says of itself, `controller_pid`, which a
        // program may fill with any number); the engine's gate checks it.
        let mut latest = None;
        while let Ok(Some(sample)) = d.subscriber.receive() {
            let header = sample.header();
            let pid = iceoryx2::prelude::PayloadHeader::node_id(header)
                .pid::<Svc>()
                .map_or(0, |p| u32::try_from(p.value()).unwrap_or(0));
            latest = Some((
                PzdOutput {
                    controller_pid: pid,
                    ..*sample
                },
                ControllerId(header.publisher_id().value()),
            ));
        }
        latest
    }

    fn after_poll(&mut self, slot: usize, images: &DriveImages, status: &DriveStatus) {
        let origin = self.origin_ns;
        let Some(d) = self.drives.get_mut(slot) else {
            return;
        };
        let words = images
            .input
            .is_written()
            .then(|| images.input.read())
            .flatten();
        let mut image = match words {
            Some(w) => {
                let at = origin.saturating_add(w.stamp_ns);
                if w.number != d.last.0 {
                    // A new good reply: its age is the time since the one before (update period).
                    let period = if d.last.0 == 0 {
                        0
                    } else {
                        at.saturating_sub(d.last.1)
                    };
                    d.last = (w.number, at);
                    d.period = period;
                }
                PzdInput::from_words(w.as_slice(), w.number, at, d.period)
                    .unwrap_or(PzdInput::EMPTY)
            }
            None => PzdInput::EMPTY,
        };
        image.online = u8::from(status.online);
        image.known = u8::from(status.known);
        image.picture = status.picture;
        let c = ControlView::of(status, origin);
        image.control = c.state.code();
        image.latch_reason = c.reason.code();
        image.latch_command = StopCommand::code_of(c.command);
        image.latched_since_ns = c.since_ns;
        image.latch_id = c.id;
        image.latched_by_pid = c.by_pid;
        image.latches = u32::try_from(status.counters.latches).unwrap_or(u32::MAX);
        image.rejection = status.rejection.code();
        image.taken_sequence = status.taken_sequence;
        [image.sent_stw1, image.sent_setpoint] = status.sent;
        image.period_ns = u64::try_from(status.period.as_nanos()).unwrap_or(u64::MAX);
        image.stale_after_ns = u64::try_from(status.stale_after.as_nanos()).unwrap_or(u64::MAX);
        d.entry.update_with_copy(image);
        let _ = self.notifier.notify_with_custom_event_id(d.event);
    }

    fn cycle_completed(&mut self) {
        let _ = self
            .notifier
            .notify_with_custom_event_id(EventId::new(names::CYCLE_COMPLETED));
    }

    fn job_done(&mut self) {
        let _ = self.results.notify();
    }
    fn requester_ended(&self, requester: Requester) -> bool {
        self.requesters.has_ended(requester)
    }
}
