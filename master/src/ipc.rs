//! ussd's side of the shared-memory contract (`uss-shm-types`, iceoryx2 0.10): the services of
//! one bus and the three places that use them.
//!
//! - [`RtBridge`] runs in the bus thread as the engine's [`Bridge`]: it takes the latest
//!   controller sample of each drive (subscriber `receive`), publishes each drive's input image
//!   after every poll (blackboard `update_with_copy`) and signals exchange and cycle events
//!   (`notify`). None of these allocates (shm-types' pattern tests count it).
//! - [`StatusPublisher`] runs in the housekeeping thread: bus status and per-drive diagnostics.
//! - [`ParamServer`] runs in its own bridge thread: the request-response servers, which
//!   allocate per request and so stay out of the bus thread (ARCHITECTURE.md, "Data flow").
//!   Parameters: each multi-parameter request becomes one job per item, executed one PKW task
//!   at a time by the drive's mailbox, and every accepted request is answered exactly once;
//!   writes to a drive another process controls are refused unless forced. Operator commands:
//!   OFF1/OFF2/OFF3 for a drive or the whole bus from any process, handed to the bus thread
//!   through atomics (`EngineHandle::stop_drive`).
//!
//! ussd's ports are created with `ipc_threadsafe` so they can be made before the threads start
//! and moved into them; clients use plain `ipc` services, which interoperate.

use crate::control::Control;
use crate::engine::{Bridge, DriveSetup, EngineHandle, RequestError as EngineRefusal};
use crate::image::DriveImages;
use crate::jobs::{Job, JobResult, Outcome as JobOutcome};
use crate::stats::{DriveStatus, Failure, Stats};
use core::time::Duration;
use iceoryx2::active_request::ActiveRequest;
use iceoryx2::node::NodeView;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::server::Server;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::writer::{EntryHandleMut, Writer};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::service::port_factory::request_response::PortFactory as RequestResponseFactory;
use std::time::Instant;
use thiserror::Error;
use uss_protocol::{
    Address, LineError, ParamTask, PkwError, Pnu, Storage as PkwStorage, Subindex, Value,
};
use uss_shm_types::names::{self, LAYOUT_VERSION_ATTRIBUTE};
use uss_shm_types::{
    ALL_DRIVES, BlackboardKey, BusName, BusStatus, CommandError, ControlState, DriveAddress,
    DriveDiag, LAYOUT_VERSION, LastFailure, LatchReason, OperatorRequest, OperatorResponse,
    Outcome, ParamItem, ParamRequest, ParamResponse, ParamResult, PzdInput, PzdOutput,
    RequestError, RtMode, StopCommand, Storage, TaskCode,
};

type Svc = ipc_threadsafe::Service;

/// ussd's iceoryx2 node for one bus.
pub type IpcNode = Node<Svc>;

/// Clients (readers, listeners, parameter clients) one bus serves at once.
const MAX_CLIENTS: usize = 64;
/// Nodes that may use one service at once.
const MAX_NODES: usize = 128;

/// A service ussd could not create.
#[derive(Debug, Error)]
#[error("bus {bus}: cannot create {what}: {detail}")]
pub struct IpcError {
    pub bus: String,
    pub what: String,
    pub detail: String,
}

fn fail(bus: &BusName, what: impl Into<String>) -> impl FnOnce(String) -> IpcError {
    let (bus, what) = (bus.to_string(), what.into());
    move |detail| IpcError { bus, what, detail }
}

/// Formats any iceoryx2 error for an [`IpcError`].
fn text(e: impl core::fmt::Debug) -> String {
    format!("{e:?}")
}

/// Everything one bus shares, created before its threads start.
pub struct BusIpc {
    /// Keeps the node (and so every port's owner) alive as long as the bus runs.
    pub node: Node<Svc>,
    pub rt: RtBridge,
    pub status: StatusPublisher,
    pub params: ParamServer,
}

impl core::fmt::Debug for BusIpc {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("BusIpc")
            .field("bus", &self.status.bus.as_str())
            .finish_non_exhaustive()
    }
}

/// Creates every service of bus `name` for `drives` (in the engine's slot order).
/// `clock_origin` is the bus clock's origin on `CLOCK_MONOTONIC`, so time stamps published are
/// `CLOCK_MONOTONIC` nanoseconds as the contract says.
pub fn create(
    name: &str,
    setups: &[DriveSetup],
    clock_origin: Duration,
) -> Result<BusIpc, IpcError> {
    let addresses: Vec<Address> = setups.iter().map(|d| d.address).collect();
    let addresses = addresses.as_slice();
    // Keep iceoryx2's own diagnostics (large debug dumps) to errors; ussd reports the rest.
    set_log_level(LogLevel::Error);
    let bus = BusName::new(name).map_err(|e| IpcError {
        bus: name.into(),
        what: "its services".into(),
        detail: e.to_string(),
    })?;
    let node = NodeBuilder::new()
        .name(&names::ussd_node(&bus))
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Svc>()
        .map_err(|e| fail(&bus, "its node")(text(e)))?;
    // A ussd that was killed leaves its node behind; clean it up so its services can go.
    let _ = node.try_cleanup_dead_nodes();
    let attributes = AttributeSpecifier::new()
        .define(
            &LAYOUT_VERSION_ATTRIBUTE
                .try_into()
                .map_err(|e| fail(&bus, "attributes")(text(e)))?,
            &LAYOUT_VERSION
                .to_string()
                .as_str()
                .try_into()
                .map_err(|e| fail(&bus, "attributes")(text(e)))?,
        )
        .map_err(|e| fail(&bus, "attributes")(text(e)))?;

    let cycle = node
        .service_builder(&names::cycle(&bus))
        .event()
        .event_id_max_value(names::EVENT_ID_MAX)
        .notifier_dead_event(EventId::new(names::USSD_GONE))
        .max_listeners(MAX_CLIENTS)
        .max_notifiers(4)
        .max_nodes(MAX_NODES)
        .create_with_attributes(&attributes)
        .map_err(|e| fail(&bus, "the cycle event service")(text(e)))?;
    let notifier = || {
        cycle
            .notifier_builder()
            .create()
            .map_err(|e| fail(&bus, "a cycle notifier")(text(e)))
    };

    let mut drives = Vec::with_capacity(addresses.len());
    let mut outs = Vec::with_capacity(addresses.len());
    for &address in addresses {
        let (drive, out) = create_drive(&node, &bus, address, &attributes)?;
        drives.push(drive);
        outs.push((address, out));
    }
    let rt = RtBridge {
        drives,
        notifier: notifier()?,
        origin_ns: as_ns(clock_origin),
    };

    let status = create_status(&node, &bus, setups, &attributes, notifier()?, clock_origin)?;
    let params = node
        .service_builder(&names::params(&bus))
        .request_response::<ParamRequest, ParamResponse>()
        .max_clients(MAX_CLIENTS)
        .max_servers(1)
        .max_active_requests_per_client(4)
        .max_nodes(MAX_NODES)
        .create_with_attributes(&attributes)
        .map_err(|e| fail(&bus, "the parameter service")(text(e)))?;
    let server = params
        .server_builder()
        .create()
        .map_err(|e| fail(&bus, "the parameter server")(text(e)))?;
    let commands = node
        .service_builder(&names::command(&bus))
        .request_response::<OperatorRequest, OperatorResponse>()
        .max_clients(MAX_CLIENTS)
        .max_servers(1)
        .max_active_requests_per_client(4)
        .max_nodes(MAX_NODES)
        .create_with_attributes(&attributes)
        .map_err(|e| fail(&bus, "the command service")(text(e)))?;
    let command_server = commands
        .server_builder()
        .create()
        .map_err(|e| fail(&bus, "the command server")(text(e)))?;
    let params = ParamServer {
        server,
        commands: command_server,
        identities: Identities {
            config: node.config().clone(),
            params,
            commands,
            outs,
        },
        pending: Vec::new(),
        next_id: 1,
    };
    Ok(BusIpc {
        node,
        rt,
        status,
        params,
    })
}

/// The bus status and drive diagnostics blackboards, written by the housekeeping thread.
fn create_status(
    node: &IpcNode,
    bus: &BusName,
    drives: &[DriveSetup],
    attributes: &AttributeSpecifier,
    notifier: Notifier<Svc>,
    clock_origin: Duration,
) -> Result<StatusPublisher, IpcError> {
    let addresses: Vec<Address> = drives.iter().map(|d| d.address).collect();
    let mut diag_builder = node
        .service_builder(&names::diag(bus))
        .blackboard_creator::<BlackboardKey>()
        .max_readers(MAX_CLIENTS)
        .max_nodes(MAX_NODES);
    for d in drives {
        let a =
            DriveAddress::new(d.address.get()).map_err(|e| fail(bus, "a drive")(e.to_string()))?;
        // What a client needs before the first publish: the drive's PZD length.
        let initial = DriveDiag {
            pzd_words: d.layout.pzd.get() as u8,
            ..DriveDiag::new(d.address.get())
        };
        diag_builder = diag_builder.add::<DriveDiag>(BlackboardKey::drive(a), initial);
    }
    let diag = diag_builder
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, "the diag blackboard")(text(e)))?;
    let diag_writer = diag
        .writer_builder()
        .create()
        .map_err(|e| fail(bus, "the diag writer")(text(e)))?;
    let mut diag_entries = Vec::with_capacity(addresses.len());
    for &address in &addresses {
        let a =
            DriveAddress::new(address.get()).map_err(|e| fail(bus, "a drive")(e.to_string()))?;
        diag_entries.push(
            diag_writer
                .entry::<DriveDiag>(&BlackboardKey::drive(a))
                .map_err(|e| fail(bus, "a diag entry")(text(e)))?,
        );
    }
    let status = node
        .service_builder(&names::status(bus))
        .blackboard_creator::<BlackboardKey>()
        .max_readers(MAX_CLIENTS)
        .max_nodes(MAX_NODES)
        .add::<BusStatus>(BlackboardKey::IMAGE, BusStatus::EMPTY)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, "the status blackboard")(text(e)))?;
    let status_writer = status
        .writer_builder()
        .create()
        .map_err(|e| fail(bus, "the status writer")(text(e)))?;
    let status_entry = status_writer
        .entry::<BusStatus>(&BlackboardKey::IMAGE)
        .map_err(|e| fail(bus, "the status entry")(text(e)))?;
    Ok(StatusPublisher {
        bus: bus.clone(),
        pzd_words: drives.iter().map(|d| d.layout.pzd.get() as u8).collect(),
        diag: diag_entries,
        status: status_entry,
        _writers: (diag_writer, status_writer),
        notifier,
        origin_ns: as_ns(clock_origin),
        rt: RtMode::BestEffort,
        rt_cpu: -1,
        rt_priority: 0,
    })
}

type OutService = PubSubFactory<Svc, PzdOutput, ()>;

/// The services of one drive: its output (ussd subscribes; the factory stays with the
/// parameter server, which asks it who controls the drive) and its input image (ussd writes).
fn create_drive(
    node: &IpcNode,
    bus: &BusName,
    address: Address,
    attributes: &AttributeSpecifier,
) -> Result<(RtDrive, OutService), IpcError> {
    let a = DriveAddress::new(address.get()).map_err(|e| fail(bus, "a drive")(e.to_string()))?;
    let out = node
        .service_builder(&names::drive_out(bus, a))
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
        .service_builder(&names::drive_in(bus, a))
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
        event: EventId::new(names::exchange_completed(a)),
        last: (0, 0),
        period: 0,
        subscriber,
        entry,
        _writer: writer,
    };
    Ok((drive, out))
}

fn as_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

struct RtDrive {
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
    origin_ns: u64,
}

impl core::fmt::Debug for RtBridge {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("RtBridge")
            .field("drives", &self.drives.len())
            .finish_non_exhaustive()
    }
}

impl Bridge for RtBridge {
    fn take_sample(&mut self, slot: usize, _: &DriveImages) -> Option<PzdOutput> {
        let d = self.drives.get(slot)?;
        // Buffer 1 with safe overflow: at most the latest sample is waiting. It goes to the
        // engine as it arrived; the engine's gate checks it.
        let mut latest = None;
        while let Ok(Some(sample)) = d.subscriber.receive() {
            latest = Some(*sample);
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
        let c = ControlView::of(status, origin);
        image.control = c.state.code();
        image.latch_reason = c.reason.code();
        image.latch_command = c.command.code();
        image.latched_since_ns = c.since_ns;
        image.latched_by_pid = c.by_pid;
        image.latches = u32::try_from(status.counters.latches).unwrap_or(u32::MAX);
        image.rejection = status.rejection.code();
        image.taken_sequence = status.taken_sequence;
        [image.sent_stw1, image.sent_setpoint] = status.sent;
        d.entry.update_with_copy(image);
        let _ = self.notifier.notify_with_custom_event_id(d.event);
    }

    fn cycle_completed(&mut self) {
        let _ = self
            .notifier
            .notify_with_custom_event_id(EventId::new(names::CYCLE_COMPLETED));
    }
}

/// The housekeeping thread's ports: bus status and drive diagnostics.
pub struct StatusPublisher {
    bus: BusName,
    /// Each drive's PZD length, in slot order.
    pzd_words: Vec<u8>,
    diag: Vec<EntryHandleMut<Svc, BlackboardKey, DriveDiag>>,
    status: EntryHandleMut<Svc, BlackboardKey, BusStatus>,
    _writers: (Writer<Svc, BlackboardKey>, Writer<Svc, BlackboardKey>),
    notifier: Notifier<Svc>,
    origin_ns: u64,
    rt: RtMode,
    rt_cpu: i32,
    rt_priority: u8,
}

impl core::fmt::Debug for StatusPublisher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StatusPublisher")
            .field("bus", &self.bus.as_str())
            .finish_non_exhaustive()
    }
}

/// A drive's control as the contract carries it.
struct ControlView {
    state: ControlState,
    reason: LatchReason,
    command: StopCommand,
    /// `CLOCK_MONOTONIC` ns of the latch (kept after a re-arm: when the last latch began).
    since_ns: u64,
    by_pid: u32,
}

impl ControlView {
    fn of(status: &DriveStatus, origin_ns: u64) -> Self {
        match status.control {
            Control::Live => Self {
                state: ControlState::Live,
                reason: LatchReason::None,
                command: StopCommand::None,
                since_ns: 0,
                by_pid: 0,
            },
            Control::Latched(l) => Self {
                state: ControlState::Latched,
                reason: l.reason,
                command: l.command,
                since_ns: origin_ns.saturating_add(as_ns(l.since)),
                by_pid: l.by_pid,
            },
        }
    }
}

fn failure_code(f: Option<Failure>) -> LastFailure {
    match f {
        None => LastFailure::None,
        Some(Failure::NoResponse) => LastFailure::NoResponse,
        Some(Failure::MissingStx) => LastFailure::MissingStx,
        Some(Failure::StartPause) => LastFailure::StartPause,
        Some(Failure::BadLge) => LastFailure::BadLge,
        Some(Failure::Bcc) => LastFailure::Bcc,
        Some(Failure::Residual) => LastFailure::Residual,
        Some(Failure::Length) => LastFailure::Length,
        Some(Failure::WrongAddress) => LastFailure::WrongAddress,
        Some(Failure::Line(LineError::Parity)) => LastFailure::Parity,
        Some(Failure::Line(LineError::Framing)) => LastFailure::Framing,
        Some(Failure::Line(LineError::Overrun)) => LastFailure::Overrun,
        Some(Failure::Echo) => LastFailure::Echo,
    }
}

impl StatusPublisher {
    /// Records the real-time mode the bus thread obtained.
    pub fn set_rt(&mut self, realtime: bool, cpu: Option<usize>, priority: Option<u8>) {
        self.rt = if realtime {
            RtMode::Realtime
        } else {
            RtMode::BestEffort
        };
        self.rt_cpu = cpu.and_then(|c| i32::try_from(c).ok()).unwrap_or(-1);
        self.rt_priority = priority.unwrap_or(0);
    }

    /// Publishes `stats` as the bus status and every drive's diagnostics.
    pub fn publish(&self, stats: &Stats, running: bool) {
        let ns = |d: Duration| self.origin_ns.saturating_add(as_ns(d));
        for ((entry, d), &pzd_words) in self.diag.iter().zip(&stats.drives).zip(&self.pzd_words) {
            let c = &d.counters;
            let control = ControlView::of(d, self.origin_ns);
            entry.update_with_copy(DriveDiag {
                consecutive_failed_polls: d.consecutive_failed_polls,
                last_zsw1: d.last_zsw1,
                last_hiw: d.last_hiw,
                online: u8::from(d.online),
                no_reply: u8::from(d.no_reply),
                control: control.state.code(),
                last_failure: failure_code(d.last_failure).code(),
                latch_reason: control.reason.code(),
                latch_command: control.command.code(),
                rejection: d.rejection.code(),
                monitoring: d.monitoring.code(),
                pzd_words,
                monitoring_ms: d.monitoring_ms,
                controller_pid: d.controller_pid,
                since_ns: ns(d.since),
                last_good_ns: d.last_good.map_or(uss_shm_types::diag::NEVER, ns),
                latched_since_ns: control.since_ns,
                requests: c.requests,
                good: c.good,
                rejected: c.rejected,
                timeouts: c.timeouts,
                retries: c.retries,
                failed_polls: c.failed_polls,
                missing_stx: c.missing_stx,
                start_pause: c.start_pause,
                bad_lge: c.bad_lge,
                bcc: c.bcc,
                residual: c.residual,
                length: c.length,
                wrong_address: c.wrong_address,
                parity: c.parity,
                framing: c.framing,
                overrun: c.overrun,
                echo: c.echo,
                pkw_busy: c.pkw_busy,
                jobs_done: c.jobs_done,
                watchdog_trips: c.watchdog_trips,
                latches: c.latches,
                rejected_outputs: c.rejected_outputs,
                releases: c.releases,
                overrides: c.overrides,
                ..DriveDiag::new(d.address.get())
            });
        }
        let b = &stats.bus;
        self.status.update_with_copy(BusStatus {
            rt_cpu: self.rt_cpu,
            rt_mode: self.rt.code(),
            rt_priority: self.rt_priority,
            drive_count: stats.drives.len() as u8,
            running: u8::from(running),
            efficiency_ppm: b.efficiency().map_or(0, |e| (e * 1e6) as u32),
            exchanges: b.exchanges,
            good: b.good,
            cycles: b.cycles,
            cycle_overruns: b.cycle_overruns,
            events_dropped: b.events_dropped,
            results_lost: b.results_lost,
            jobs_accepted: b.jobs_accepted,
            jobs_finished: b.jobs_finished,
            mean_exchange_ns: stats.histograms.exchange.mean() as u64,
            bus_clock_ns: as_ns(stats.at),
            timestamp_ns: ns(stats.at),
            ..BusStatus::EMPTY
        });
        let _ = self
            .notifier
            .notify_with_custom_event_id(EventId::new(names::STATUS_PUBLISHED));
    }

    /// Tells listeners ussd is leaving this bus (the same event a dead ussd's notifier leaves
    /// behind), so clients drop their ports and the services can go.
    pub fn goodbye(&self) {
        let _ = self
            .notifier
            .notify_with_custom_event_id(EventId::new(names::USSD_GONE));
    }
}

type Active = ActiveRequest<Svc, ParamRequest, (), ParamResponse, ()>;

/// A request whose items are on their way.
struct Pending {
    active: Active,
    response: ParamResponse,
    /// Job id of item 0; item i is `first_id + i`.
    first_id: u64,
    count: u64,
    remaining: usize,
}

/// The parameter bridge's servers. See the module documentation.
pub struct ParamServer {
    server: Server<Svc, ParamRequest, (), ParamResponse, ()>,
    commands: Server<Svc, OperatorRequest, (), OperatorResponse, ()>,
    identities: Identities,
    pending: Vec<Pending>,
    next_id: u64,
}

/// Who is behind a request and who controls a drive, from iceoryx2's own records (the node
/// of each port and the process of each node), not from what a client says of itself.
struct Identities {
    config: iceoryx2::config::Config,
    params: RequestResponseFactory<Svc, ParamRequest, (), ParamResponse, ()>,
    commands: RequestResponseFactory<Svc, OperatorRequest, (), OperatorResponse, ()>,
    outs: Vec<(Address, OutService)>,
}

impl Identities {
    /// The process of a live node.
    fn pid(&self, node: &iceoryx2::identifiers::UniqueNodeId) -> Option<u32> {
        let mut found = None;
        let _ = Node::<Svc>::list(&self.config, |state| {
            if let NodeState::Alive(view) = &state
                && view.id() == node
            {
                found = view
                    .details()
                    .as_ref()
                    .and_then(|d| u32::try_from(d.process_id().value()).ok());
                return CallbackProgression::Stop;
            }
            CallbackProgression::Continue
        });
        found
    }

    /// The process that sent a parameter request.
    fn param_client(&self, origin: iceoryx2::identifiers::UniqueClientId) -> Option<u32> {
        let mut node = None;
        self.params.dynamic_config().list_clients(|c| {
            if c.client_id == origin {
                node = Some(c.node_id);
                return CallbackProgression::Stop;
            }
            CallbackProgression::Continue
        });
        node.and_then(|n| self.pid(&n))
    }

    /// The process that sent an operator command.
    fn command_client(&self, origin: iceoryx2::identifiers::UniqueClientId) -> Option<u32> {
        let mut node = None;
        self.commands.dynamic_config().list_clients(|c| {
            if c.client_id == origin {
                node = Some(c.node_id);
                return CallbackProgression::Stop;
            }
            CallbackProgression::Continue
        });
        node.and_then(|n| self.pid(&n))
    }

    /// The live process that holds the drive's `out` publisher (its controller), if any.
    fn controller(&self, address: Address) -> Option<u32> {
        let (_, out) = self.outs.iter().find(|(a, _)| *a == address)?;
        let mut node = None;
        out.dynamic_config().list_publishers(|p| {
            node = Some(p.node_id);
            CallbackProgression::Stop
        });
        node.and_then(|n| self.pid(&n))
    }
}

impl core::fmt::Debug for ParamServer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ParamServer")
            .field("pending", &self.pending.len())
            .finish_non_exhaustive()
    }
}

/// The PKW task an item asks for (USS.md section 6).
fn task_of(item: &ParamItem, code: TaskCode) -> Result<ParamTask, RequestError> {
    let pnu = Pnu::from_u16(item.pnu);
    let index = u8::try_from(item.index)
        .ok()
        .and_then(|i| Subindex::new(i).ok())
        .ok_or(RequestError::BadSubindex)?;
    let storage = match item.storage().map_err(|_| RequestError::BadStorage)? {
        Storage::Ram => PkwStorage::Ram,
        Storage::RamAndEeprom => PkwStorage::RamAndEeprom,
    };
    let word = || Value::Word(item.value as u16);
    let dword = Value::Dword(item.value);
    Ok(match code {
        TaskCode::Read => ParamTask::Read { pnu },
        TaskCode::WriteWord => ParamTask::Write {
            pnu,
            value: word(),
            storage,
        },
        TaskCode::WriteDword => ParamTask::Write {
            pnu,
            value: dword,
            storage,
        },
        TaskCode::ReadArray => ParamTask::ReadArray { pnu, index },
        TaskCode::WriteArrayWord => ParamTask::WriteArray {
            pnu,
            index,
            value: word(),
            storage,
        },
        TaskCode::WriteArrayDword => ParamTask::WriteArray {
            pnu,
            index,
            value: dword,
            storage,
        },
        TaskCode::ReadElementCount => ParamTask::ReadArrayLen { pnu },
        TaskCode::ReadDescription => ParamTask::ReadDescription {
            pnu,
            element: index,
        },
    })
}

fn refusal_of(e: EngineRefusal) -> RequestError {
    match e {
        EngineRefusal::UnknownDrive(_) => RequestError::UnknownDrive,
        EngineRefusal::WritesDisabled(_) => RequestError::WritesDisabled,
        EngineRefusal::Pkw {
            error: PkwError::NoChannel,
            ..
        } => RequestError::NoParameterChannel,
        EngineRefusal::Pkw {
            error: PkwError::DwordOverThreeWords,
            ..
        } => RequestError::DwordOverThreeWords,
        EngineRefusal::Pkw {
            error: PkwError::Subindex(_),
            ..
        } => RequestError::BadSubindex,
        EngineRefusal::Pkw { .. } | EngineRefusal::PzdWords { .. } => RequestError::ValueType,
        EngineRefusal::Busy(_) => RequestError::Busy,
        EngineRefusal::Stopped => RequestError::Shutdown,
        EngineRefusal::ReservedJobId(_) | EngineRefusal::NotAStop(_) => RequestError::BadTask,
    }
}

fn result_of(r: &JobResult) -> ParamResult {
    let (outcome, value, drive_error) = match r.outcome {
        JobOutcome::Value(v) => (Outcome::Value, Some(v), 0),
        JobOutcome::ElementCount(n) => (Outcome::ElementCount, Some(Value::Word(n)), 0),
        JobOutcome::Description(v) => (Outcome::Description, Some(v), 0),
        JobOutcome::DriveError(e) => (Outcome::DriveError, None, e.number()),
        JobOutcome::NoChangeRights => (Outcome::NoChangeRights, None, 0),
        JobOutcome::Timeout => (Outcome::Timeout, None, 0),
        JobOutcome::DriveOffline => (Outcome::DriveOffline, None, 0),
        JobOutcome::MailboxFull => (Outcome::MailboxFull, None, 0),
        JobOutcome::Shutdown => (Outcome::Shutdown, None, 0),
    };
    ParamResult {
        outcome: outcome.code(),
        value_is_dword: u8::from(value.is_some_and(Value::is_dword)),
        drive_error,
        value: value.map_or(0, Value::as_u32),
        telegrams: r.telegrams,
        on_wire_ns: as_ns(r.on_wire),
        ..ParamResult::NOT_RUN
    }
}

impl ParamServer {
    /// Serves requests until the engine stops, then answers what is still pending (the
    /// engine ends every job it holds with "shutdown"; jobs it never took get that here).
    pub fn run(mut self, handle: &EngineHandle) {
        while !handle.is_stopped() {
            self.serve_once(handle, Duration::from_millis(1));
        }
        let deadline = Instant::now() + Duration::from_secs(2);
        while !self.pending.is_empty() && Instant::now() < deadline {
            self.serve_once(handle, Duration::from_millis(5));
        }
        for mut p in self.pending.drain(..) {
            for r in &mut p.response.results[..p.count as usize] {
                if r.outcome == Outcome::NotRun.code() {
                    *r = ParamResult {
                        outcome: Outcome::Shutdown.code(),
                        ..ParamResult::NOT_RUN
                    };
                }
            }
            let _ = p.active.send_copy(p.response);
        }
    }

    /// Takes new requests, then waits up to `wait` for job results and routes them.
    pub fn serve_once(&mut self, handle: &EngineHandle, wait: Duration) {
        self.serve_commands(handle);
        while let Ok(Some(active)) = self.server.receive() {
            self.accept(active, handle);
        }
        let mut wait = wait;
        while let Some(r) = handle.recv_result(wait) {
            self.route(&r);
            wait = Duration::ZERO;
        }
    }

    fn accept(&mut self, active: Active, handle: &EngineHandle) {
        let request = *active.payload();
        if let Some(refusal) = self.refuse_controlled(&active, &request) {
            let _ = active.send_copy(refusal);
            return;
        }
        let (address, items) = match request.validate() {
            Ok(ok) => ok,
            Err(refusal) => {
                // A client that died meanwhile cannot be answered; nothing else to do.
                let _ = active.send_copy(ParamResponse::refused(request.address, refusal));
                return;
            }
        };
        let Ok(address) = Address::new(address.get()) else {
            let refusal = ParamResponse::new(request.address);
            let _ = active.send_copy(ParamResponse {
                error: RequestError::UnknownDrive.code(),
                ..refusal
            });
            return;
        };
        let mut response = ParamResponse::new(address.get());
        response.count = items.len() as u8;
        let first_id = self.next_id;
        self.next_id += items.len() as u64;
        let mut remaining = 0;
        for (i, item) in items.iter().enumerate() {
            // `validate` checked every item's task code.
            let submitted = item
                .check()
                .and_then(|code| task_of(item, code))
                .and_then(|task| {
                    handle
                        .submit(Job {
                            id: first_id + i as u64,
                            address,
                            task,
                        })
                        .map_err(refusal_of)
                });
            match submitted {
                Ok(()) => remaining += 1,
                Err(e) => response.results[i] = ParamResult::refused(e),
            }
        }
        if remaining == 0 {
            let _ = active.send_copy(response);
            return;
        }
        self.pending.push(Pending {
            active,
            response,
            first_id,
            count: items.len() as u64,
            remaining,
        });
    }

    /// A write to a drive that another process controls is refused unless the request says it
    /// is deliberate ([`uss_shm_types::REQUEST_FORCE`]); reads are never restricted, and the
    /// controlling process may write through its own handles.
    fn refuse_controlled(&self, active: &Active, request: &ParamRequest) -> Option<ParamResponse> {
        let writes = request.items[..usize::from(request.count).min(request.items.len())]
            .iter()
            .any(|i| i.task().is_ok_and(TaskCode::is_write));
        if !writes || request.is_forced() || request.validate().is_err() {
            return None;
        }
        let address = Address::new(request.address).ok()?;
        let controller = self.identities.controller(address)?;
        let requester = self.identities.param_client(active.origin());
        if requester == Some(controller) {
            return None;
        }
        let mut response = ParamResponse::refused(
            request.address,
            uss_shm_types::Refusal {
                error: RequestError::Controlled,
                item: None,
            },
        );
        response.controller_pid = controller;
        Some(response)
    }

    /// Answers operator commands: each goes to the bus thread at once (it applies it at the
    /// drive's next poll, latched) and is answered with the drives it reached.
    fn serve_commands(&mut self, handle: &EngineHandle) {
        while let Ok(Some(active)) = self.commands.receive() {
            let request = *active.payload();
            let response = match request.validate() {
                Err(e) => OperatorResponse::refused(request.command, e),
                Ok(_) if handle.is_stopped() => {
                    OperatorResponse::refused(request.command, CommandError::Shutdown)
                }
                Ok(command) => {
                    let pid = self.identities.command_client(active.origin()).unwrap_or(0);
                    let target = match request.address {
                        ALL_DRIVES => Ok(None),
                        a => Address::new(a).map(Some),
                    };
                    match target.map(|t| handle.stop_drive(t, command, pid)) {
                        Ok(Ok(drives)) => OperatorResponse::done(command, drives),
                        Ok(Err(_)) | Err(_) => {
                            OperatorResponse::refused(request.command, CommandError::UnknownDrive)
                        }
                    }
                }
            };
            // A client that died meanwhile cannot be answered; the command stands.
            let _ = active.send_copy(response);
        }
    }

    fn route(&mut self, r: &JobResult) {
        let id = r.job.id;
        let Some(at) = self
            .pending
            .iter()
            .position(|p| (p.first_id..p.first_id + p.count).contains(&id))
        else {
            return;
        };
        let p = &mut self.pending[at];
        p.response.results[(id - p.first_id) as usize] = result_of(r);
        p.remaining -= 1;
        if p.remaining == 0 {
            let p = self.pending.swap_remove(at);
            let _ = p.active.send_copy(p.response);
        }
    }
}
