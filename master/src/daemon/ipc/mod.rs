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

mod bridge;
pub mod requesters;
mod server;
mod status;
mod watches;

pub use bridge::RtBridge;
pub use server::ParamServer;
pub use status::StatusPublisher;

use core::time::Duration;
use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::{NodeDetails, NodeView};
use iceoryx2::prelude::*;
use thiserror::Error;
use uss_engine::DriveSetup;
use uss_protocol::Address;
use uss_shm_types::names::{self, LAYOUT_VERSION_ATTRIBUTE};
use uss_shm_types::{BusName, Generation, Instance, LAYOUT_VERSION};

/// uss-rt's iceoryx2 service variant (`uss_shm_types::service`), with thread-safe ports: they
/// are made before the bus threads start and moved into them.
pub(crate) type Svc = uss_shm_types::service::IpcThreadsafe;

/// ussd's iceoryx2 node for one bus.
pub type IpcNode = Node<Svc>;

/// Clients (readers, listeners, parameter clients) one bus serves at once.
pub(crate) const MAX_CLIENTS: usize = 64;
/// Nodes that may use one service at once.
pub(crate) const MAX_NODES: usize = 128;

/// A service ussd could not create.
#[derive(Debug, Error)]
pub enum IpcError {
    #[error("bus {bus}: cannot create {what}: {detail}")]
    Create {
        bus: String,
        what: String,
        detail: String,
    },
    /// Another ussd holds the bus's heartbeat: it serves the bus.
    #[error(
        "bus {bus} is already served by ussd{}: stop that one first, or give this bus another name",
        Process(*.pid)
    )]
    Served { bus: String, pid: Option<u32> },
}

/// ` process N`, or nothing when the process is not known.
struct Process(Option<u32>);

impl core::fmt::Display for Process {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.0 {
            Some(pid) => write!(f, " process {pid}"),
            None => Ok(()),
        }
    }
}

pub(crate) fn fail(
    bus: &impl core::fmt::Display,
    what: impl Into<String>,
) -> impl FnOnce(String) -> IpcError {
    let (bus, what) = (bus.to_string(), what.into());
    move |detail| IpcError::Create { bus, what, detail }
}

/// `CLOCK_MONOTONIC` in ns: the clock of every time stamp of the contract.
pub(crate) fn monotonic_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).map_or(0, |t| {
        (t.tv_sec() as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(t.tv_nsec() as u64)
    })
}

/// The process of a live iceoryx2 node.
pub(crate) fn pid_of(
    config: &iceoryx2::config::Config,
    node: &iceoryx2::identifiers::UniqueNodeId,
) -> Option<u32> {
    let mut found = None;
    let _ = Node::<Svc>::list(config, |state| {
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

/// Formats any iceoryx2 error for an [`IpcError`].
/// Every node iceoryx2 lists below `config`'s root: its id, whether it is dead (its process is
/// gone), and its process id where known (0: not). A node that is not listed at all died and was
/// cleaned up already (by ussd's periodic cleanup or by any other process that opened a node
/// since). `None` when the list cannot be read.
pub(crate) fn listed_nodes(config: &Config) -> Option<Vec<(UniqueNodeId, bool, u32)>> {
    fn pid(details: Option<&NodeDetails>) -> u32 {
        details
            .and_then(|d| u32::try_from(d.process_id().value()).ok())
            .unwrap_or(0)
    }
    let mut nodes = Vec::new();
    let listed = Node::<Svc>::list(config, |state| {
        nodes.push(match &state {
            NodeState::Alive(view) => (*view.id(), false, pid(view.details().as_ref())),
            NodeState::Dead(view) => (*view.id(), true, pid(view.details().as_ref())),
            NodeState::Inaccessible(id) | NodeState::Undefined(id) => (*id, false, 0),
        });
        CallbackProgression::Continue
    });
    listed.ok().map(|()| nodes)
}

pub(crate) fn text(e: impl core::fmt::Debug) -> String {
    format!("{e:?}")
}

pub(crate) fn as_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

/// Everything one bus shares, created before its threads start.
pub struct BusIpc {
    /// The bus and this ussd's generation: the names of its services.
    pub instance: Instance,
    /// Keeps the node (and so every port's owner) alive as long as the bus runs.
    pub node: Node<Svc>,
    pub rt: RtBridge,
    pub status: StatusPublisher,
    pub params: ParamServer,
}

impl core::fmt::Debug for BusIpc {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("BusIpc")
            .field("bus", &self.instance.bus.as_str())
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
    let bus = BusName::new(name).map_err(|e| IpcError::Create {
        bus: name.into(),
        what: "its services".into(),
        detail: e.to_string(),
    })?;
    let config = uss_shm_types::service::config().ok_or_else(|| IpcError::Create {
        bus: name.into(),
        what: "its node".into(),
        detail: format!(
            "{} is no absolute path iceoryx2 takes ({})",
            uss_shm_types::service::root().display(),
            uss_shm_types::service::ROOT_ENV
        ),
    })?;
    let node = NodeBuilder::new()
        .name(&names::ussd_node(&bus))
        .config(&config)
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
    let heartbeat = status::heartbeat_publisher(&node, &bus)?;
    // This instance's services: a name no earlier ussd used, so clients that still hold their
    // predecessor's services (and its locked blackboard entries) are no obstacle.
    let bus = Instance::new(bus, Generation(monotonic_ns()));

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
        let (drive, out) = bridge::create_drive(&node, &bus, address, &attributes)?;
        drives.push(drive);
        outs.push((address, out));
    }
    let (woken, results) = request_events(&node, &bus, &attributes)?;
    // The processes behind parameter jobs: watched by the parameter server, asked about by the
    // bus thread before a job of theirs leaves its mailbox.
    let requesters = std::sync::Arc::new(requesters::Requesters::default());
    let rt = RtBridge::new(
        drives,
        (notifier()?, results),
        as_ns(clock_origin),
        std::sync::Arc::clone(&requesters),
    );

    let status = status::create(
        &node,
        &bus,
        setups,
        &attributes,
        (notifier()?, heartbeat),
        clock_origin,
    )?;
    let params = server::create(&node, &bus, &attributes, (outs, woken), setups, requesters)?;
    Ok(BusIpc {
        instance: bus,
        node,
        rt,
        status,
        params,
    })
}

/// The event service by which clients and the bus thread wake the parameter bridge: its
/// listener and the bus thread's result notifier.
fn request_events(
    node: &IpcNode,
    bus: &Instance,
    attributes: &AttributeSpecifier,
) -> Result<
    (
        iceoryx2::port::listener::Listener<Svc>,
        iceoryx2::port::notifier::Notifier<Svc>,
    ),
    IpcError,
> {
    let requests = node
        .service_builder(&names::requests(bus))
        .event()
        .max_listeners(1)
        .max_notifiers(MAX_CLIENTS)
        .max_nodes(MAX_NODES)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, "the request event service")(text(e)))?;
    // The listener first: a notifier connects to the listeners there are when it is created
    // (a later listener is connected by the next notify, which allocates: not in the bus thread).
    let woken = requests
        .listener_builder()
        .create()
        .map_err(|e| fail(bus, "the request listener")(text(e)))?;
    let results = requests
        .notifier_builder()
        .default_event_id(EventId::new(names::RESULT_READY))
        .create()
        .map_err(|e| fail(bus, "the result notifier")(text(e)))?;
    Ok((woken, results))
}
