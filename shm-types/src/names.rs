//! Where everything is: service names, blackboard keys, event ids and service attributes, all
//! derived from the bus name. This module is the only place that spells them; other languages
//! follow the table below.
//!
//! | service name                       | pattern          | keys / ids                             |
//! |------------------------------------|------------------|----------------------------------------|
//! | `uss/<bus>/ussd`                   | publish-subscribe| `Heartbeat`; 1 publisher (ussd), subscriber buffer 1, history 1, safe overflow |
//! | `uss/<bus>/<gen>/drive/<addr>/out` | publish-subscribe| `PzdOutput`; 1 publisher, subscriber buffer 1, no history, safe overflow |
//! | `uss/<bus>/<gen>/drive/<addr>/in`  | blackboard       | [`BlackboardKey::IMAGE`] -> `PzdInput`  |
//! | `uss/<bus>/<gen>/diag`             | blackboard       | [`BlackboardKey::drive`] (address) -> `DriveDiag` |
//! | `uss/<bus>/<gen>/status`           | blackboard       | [`BlackboardKey::IMAGE`] -> `BusStatus` |
//! | `uss/<bus>/<gen>/cycle`            | event            | [`exchange_completed`], [`CYCLE_COMPLETED`], [`STATUS_PUBLISHED`], [`USSD_GONE`] |
//! | `uss/<bus>/<gen>/params`           | request-response | `ParamRequest` -> `ParamResponse`       |
//! | `uss/<bus>/<gen>/command`          | request-response | `OperatorRequest` -> `OperatorResponse` |
//! | `uss/<bus>/<gen>/capture`          | publish-subscribe| `TelegramRecord`; 1 publisher (ussd), subscriber buffer [`CAPTURE_BUFFER`], no history |
//! | `uss/<bus>/<gen>/requests`         | event            | [`REQUEST_SENT`]: a client notifies after sending on `params` or `command`; [`RESULT_READY`] (ussd's own) |
//! | `uss/<bus>/<gen>/answers`          | event            | [`ANSWER_SENT`]: ussd notifies after answering on `params` or `command` |
//!
//! `<bus>` is 1 to 32 characters of `A-Z a-z 0-9 _ -`; `<gen>` is the serving ussd's
//! [`Generation`] (16 lowercase hex digits), read from the newest heartbeat; `<addr>` is the
//! drive address in decimal without leading zeros (0..=31, USS.md section 1). Every service
//! carries the attribute [`LAYOUT_VERSION_ATTRIBUTE`] = `LAYOUT_VERSION` in decimal.
//!
//! A client opens `uss/<bus>/ussd` first: its newest heartbeat names the generation (and tells
//! whether ussd runs, its line is down, or it is stopping); no heartbeat within
//! [`GONE_AFTER_NS`] means ussd is gone. When a heartbeat names another generation, ussd was
//! restarted: the client drops the old generation's ports and opens the new one's.
//!
//! Why `out` is publish-subscribe and not a blackboard (measured with iceoryx2 0.10 in
//! `tests/patterns.rs`): both enforce one writer with a clear error, but a blackboard entry
//! whose writer was killed stays locked for every later writer until the service is recreated
//! (eclipse-iceoryx/iceoryx2#2008), so a controller crash would lock the drive's output. A
//! single publisher is cleaned up with its dead node and the next controller takes over. ussd's
//! subscriber `receive` does not allocate; the controller's `send_copy` allocates once per
//! sample (in the controller's process).

use core::fmt;
#[cfg(feature = "ipc")]
use iceoryx2::prelude::{NodeName, ServiceName, ZeroCopySend};
use thiserror::Error;

/// Longest bus name.
pub const MAX_BUS_NAME_LEN: usize = 32;
/// Highest USS slave address (USS.md section 1).
pub const MAX_ADDRESS: u8 = 31;
const _: () = assert!(MAX_ADDRESS == uss_protocol::Address::MAX);

/// Service attribute every ussd service defines: the payload layout version, in decimal.
pub const LAYOUT_VERSION_ATTRIBUTE: &str = "uss.layout_version";

/// A name that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Error)]
pub enum NameError {
    #[error("bus name {0:?} must be 1 to 32 characters of A-Z, a-z, 0-9, '_' or '-'")]
    BusName(String),
}

/// A validated bus name: 1 to 32 characters of `[A-Za-z0-9_-]`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BusName(String);

impl BusName {
    pub fn new(name: &str) -> Result<Self, NameError> {
        let valid = (1..=MAX_BUS_NAME_LEN).contains(&name.len())
            && name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
        if valid {
            Ok(Self(name.to_owned()))
        } else {
            Err(NameError::BusName(name.to_owned()))
        }
    }

    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for BusName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// A drive address is the codec's validated [`Address`] (0..=31, USS.md section 1): one type
/// for one concept, from the wire to the service names.
pub use uss_protocol::Address;

/// The key type of every ussd blackboard. Keys are compared byte for byte; C, C++ and Python
/// declare it as a struct with one `uint32_t value` and the type name `UssBlackboardKey`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssBlackboardKey"))]
pub struct BlackboardKey {
    pub value: u32,
}

impl BlackboardKey {
    /// The single entry of the `in` and `status` blackboards.
    pub const IMAGE: Self = Self { value: 0 };

    /// A drive's entry in the `diag` blackboard: its address.
    pub const fn drive(address: Address) -> Self {
        Self {
            value: address.get() as u32,
        }
    }
}

/// Publishers of an `out` service: exactly one controller per drive. A second publisher is
/// refused with `PublisherCreateError::ExceedsMaxSupportedPublishers`.
pub const OUT_MAX_PUBLISHERS: usize = 1;
/// Subscriber buffer of an `out` service: with safe overflow, ussd receives the latest sample
/// only.
pub const OUT_LATEST_ONLY: usize = 1;
/// History of an `out` service: none. A restarted ussd acts only on samples published after it
/// subscribed, never on one its predecessor had already seen (`crate::control`).
pub const OUT_HISTORY: usize = 0;

/// Requests one client port of `params` or `command` may have on their way at once (and loan
/// at once); a client library queues its threads' further requests until one is answered.
pub const MAX_ACTIVE_REQUESTS: usize = 4;

/// How often ussd publishes its heartbeat, ns.
pub const HEARTBEAT_PERIOD_NS: u64 = 50_000_000;
/// A heartbeat older than this means ussd is gone (killed, hung): 10 periods, 500 ms.
pub const GONE_AFTER_NS: u64 = 10 * HEARTBEAT_PERIOD_NS;
/// How old a drive's diagnostics may be when a client reads them while ussd runs well: the bus
/// thread snapshots them every heartbeat period, ussd copies the snapshot for clients every
/// period, and a wake-up may come late; 3 periods, 150 ms. A drive's diagnostics are overdue
/// ([`crate::DriveDiag::is_overdue`]) only past its own limit and this.
pub const DIAG_AGE_NS: u64 = 3 * HEARTBEAT_PERIOD_NS;

/// Highest event id on `uss/<bus>/<gen>/cycle`; ussd creates the service with it.
pub const EVENT_ID_MAX: usize = 63;
/// A pass through the circulating list completed (USS.md section 5).
pub const CYCLE_COMPLETED: usize = 32;
/// `status` and `diag` were republished.
pub const STATUS_PUBLISHED: usize = 33;
/// ussd's notifier died without saying goodbye (the service's `notifier_dead_event`, emitted
/// by whoever cleans up the dead ussd node). Clients then drop and reopen every ussd service:
/// a restarted ussd cannot update a blackboard entry its dead predecessor held while the
/// service lives on (iceoryx2 0.10, eclipse-iceoryx/iceoryx2#2008).
pub const USSD_GONE: usize = 34;

// Event ids never collide: drive addresses first, then the bus-wide events, all within the
// service's range.
const _: () = assert!(
    (MAX_ADDRESS as usize) < CYCLE_COMPLETED
        && CYCLE_COMPLETED < STATUS_PUBLISHED
        && STATUS_PUBLISHED < USSD_GONE
        && USSD_GONE <= EVENT_ID_MAX
);

/// An exchange with the drive completed and its `in` image was updated: the event id is the
/// drive address (0..=31).
pub const fn exchange_completed(address: Address) -> usize {
    address.get() as usize
}

/// One ussd instance: its services live under `uss/<bus>/<generation>/`, so a restarted ussd
/// never meets the services its predecessor left to clients (iceoryx2 keeps a service while
/// any port holds it, and a blackboard entry whose writer was killed stays locked,
/// eclipse-iceoryx/iceoryx2#2008). Clients learn the current generation from the bus's
/// [`heartbeat`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Generation(pub u64);

impl fmt::Display for Generation {
    /// 16 lowercase hex digits, as in the service names.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:016x}", self.0)
    }
}

/// The services of one ussd instance on one bus.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Instance {
    pub bus: BusName,
    pub generation: Generation,
}

impl Instance {
    pub fn new(bus: BusName, generation: Generation) -> Self {
        Self { bus, generation }
    }

    #[cfg(feature = "ipc")]
    fn service(&self, rest: &str) -> ServiceName {
        service(&format!("uss/{}/{}/{rest}", self.bus, self.generation))
    }
}

impl fmt::Display for Instance {
    /// The bus name, as messages name a bus.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.bus.fmt(f)
    }
}

/// The heartbeat of the ussd serving `bus` (publish-subscribe, one publisher, history 1): the
/// one service whose name stays when ussd restarts. It says which generation serves the bus.
#[cfg(feature = "ipc")]
pub fn heartbeat(bus: &BusName) -> ServiceName {
    service(&format!("uss/{bus}/ussd"))
}

/// The controller's output image of one drive.
#[cfg(feature = "ipc")]
pub fn drive_out(i: &Instance, address: Address) -> ServiceName {
    i.service(&format!("drive/{address}/out"))
}

/// The drive's input image, written by ussd after every poll.
#[cfg(feature = "ipc")]
pub fn drive_in(i: &Instance, address: Address) -> ServiceName {
    i.service(&format!("drive/{address}/in"))
}

/// Diagnostics of every drive of the bus, keyed by address.
#[cfg(feature = "ipc")]
pub fn diag(i: &Instance) -> ServiceName {
    i.service("diag")
}

/// The bus status.
#[cfg(feature = "ipc")]
pub fn status(i: &Instance) -> ServiceName {
    i.service("status")
}

/// Exchange and cycle events.
#[cfg(feature = "ipc")]
pub fn cycle(i: &Instance) -> ServiceName {
    i.service("cycle")
}

/// Parameter requests.
#[cfg(feature = "ipc")]
pub fn params(i: &Instance) -> ServiceName {
    i.service("params")
}

/// The bus's stop socket: a Unix stream socket below the service root
/// ([`crate::service::root`], so the same access rules hold) where ussd takes operator stops
/// ([`crate::OperatorRequest`], answered by an [`crate::OperatorResponse`]) on a path of their own:
/// first, with no iceoryx2 port to run out of and no heartbeat to depend on.
pub fn stop_socket(bus: &BusName) -> std::path::PathBuf {
    crate::service::root().join(format!("{}.stop", bus.as_str()))
}

/// Bus `bus`'s stop board ([`crate::StopBoard`]): a file below the service root (its access
/// rules hold) where a process adds a stop without a queue, when the stop socket's queue is
/// full (a storm of connections of other processes).
pub fn stop_board(bus: &BusName) -> std::path::PathBuf {
    crate::service::root().join(format!("{}.stops", bus.as_str()))
}

/// Every telegram of the bus, as ussd's bus thread sent and received it.
#[cfg(feature = "ipc")]
pub fn capture(i: &Instance) -> ServiceName {
    i.service("capture")
}

/// Records a `capture` subscriber holds before the oldest are lost: 2 s of a bus at
/// 187500 baud.
pub const CAPTURE_BUFFER: usize = 1024;

/// Captures at once (`ussctl capture` and the like): each holds [`CAPTURE_BUFFER`] records of
/// shared memory.
pub const CAPTURE_MAX_SUBSCRIBERS: usize = 4;

/// Clients notify [`REQUEST_SENT`] here after sending a parameter request or an operator
/// command, so ussd takes it at once; a request without it is still taken, within
/// [`REQUEST_POLL_NS`].
#[cfg(feature = "ipc")]
pub fn requests(i: &Instance) -> ServiceName {
    i.service("requests")
}

/// ussd notifies [`ANSWER_SENT`] here after each answer on `params` and `command`, so a
/// waiting client receives it at once instead of polling.
#[cfg(feature = "ipc")]
pub fn answers(i: &Instance) -> ServiceName {
    i.service("answers")
}

/// The event id clients notify on [`requests`].
pub const REQUEST_SENT: usize = 0;
/// The event id ussd's bus thread notifies on [`requests`] when a parameter job's result is
/// ready for the parameter bridge (ussd-internal).
pub const RESULT_READY: usize = 1;
/// The event id on [`answers`].
pub const ANSWER_SENT: usize = 0;
/// How often ussd looks for requests that came without a [`REQUEST_SENT`] event, ns.
pub const REQUEST_POLL_NS: u64 = 2_000_000;

/// What the name of ussd's node for a bus begins with ([`ussd_node`], [`live_ussds`]).
#[cfg(feature = "ipc")]
const USSD_NODE_PREFIX: &str = "ussd-";

/// The name of ussd's node for a bus, as `Node::list` shows it.
#[cfg(feature = "ipc")]
pub fn ussd_node(bus: &BusName) -> NodeName {
    // At most 5 + 32 characters of [A-Za-z0-9_-]: within NodeName's 128-character limit.
    NodeName::new(&format!("{USSD_NODE_PREFIX}{bus}")).expect("bus names make valid node names")
}

/// A ussd alive on this machine's shared-memory root: the bus its node (`ussd-<bus>`) serves
/// and its process.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveUssd {
    pub bus: String,
    pub pid: u32,
}

/// Every ussd alive on the shared-memory root now (its live iceoryx2 node, [`ussd_node`], of a
/// process that runs ussd), as far as this process may see them; empty without a root or one
/// it cannot read. The one walk of the nodes that ussd (is a bus or the root in use?) and the
/// clients (which buses are served?) share.
#[cfg(feature = "ipc")]
pub fn live_ussds() -> Vec<LiveUssd> {
    use iceoryx2::node::{NodeState, NodeView as _};
    use iceoryx2::prelude::{CallbackProgression, Node};
    let Some(config) = crate::service::config() else {
        return Vec::new();
    };
    if !crate::service::root().is_dir() {
        return Vec::new();
    }
    let mut found = Vec::new();
    let _ = Node::<crate::service::IpcThreadsafe>::list(&config, |state| {
        if let NodeState::Alive(view) = &state
            && let Some(details) = view.details().as_ref()
            && let Some(bus) = details.name().as_str().strip_prefix(USSD_NODE_PREFIX)
            && let Ok(pid) = u32::try_from(details.process_id().value())
            && !names_another_program(pid)
        {
            found.push(LiveUssd {
                bus: bus.to_owned(),
                pid,
            });
        }
        CallbackProgression::Continue
    });
    found
}

/// Whether process `pid` is visible here and runs a program other than ussd, by the name the
/// kernel keeps for it (`/proc/PID/comm`, which begins `ussd` for ussd and a copy renamed
/// `ussd-test`). A node name is any string a client passes (`open_bus(..., node_name=...)`);
/// the program's name is not, unless the program renames itself (`prctl`), which no client
/// library call does. A process not visible (another PID namespace sharing the root) is taken
/// at its node's word.
#[cfg(feature = "ipc")]
fn names_another_program(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/comm")).is_ok_and(|comm| !comm.starts_with("ussd"))
}

#[cfg(feature = "ipc")]
fn service(name: &str) -> ServiceName {
    // Built from a validated bus name (at most 32 of [A-Za-z0-9_-]) and an address of at most
    // two digits: never empty, never "iox2://"-prefixed, far below the 255-character limit.
    ServiceName::new(name).expect("bus names make valid service names")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bus(name: &str) -> BusName {
        BusName::new(name).unwrap()
    }

    #[test]
    #[cfg(feature = "ipc")]
    fn service_names_follow_the_table() {
        let b = bus("line-1_A");
        let i = Instance::new(b.clone(), Generation(0x1234_abcd));
        let a = Address::new(7).unwrap();
        let g = "000000001234abcd";
        assert_eq!(heartbeat(&b).as_str(), "uss/line-1_A/ussd");
        assert_eq!(
            drive_out(&i, a).as_str(),
            format!("uss/line-1_A/{g}/drive/7/out")
        );
        assert_eq!(
            drive_in(&i, a).as_str(),
            format!("uss/line-1_A/{g}/drive/7/in")
        );
        assert_eq!(diag(&i).as_str(), format!("uss/line-1_A/{g}/diag"));
        assert_eq!(status(&i).as_str(), format!("uss/line-1_A/{g}/status"));
        assert_eq!(cycle(&i).as_str(), format!("uss/line-1_A/{g}/cycle"));
        assert_eq!(params(&i).as_str(), format!("uss/line-1_A/{g}/params"));
        assert_eq!(ussd_node(&b).as_str(), "ussd-line-1_A");
        let longest = Instance::new(bus(&"x".repeat(32)), Generation(u64::MAX));
        assert!(drive_out(&longest, a).as_str().len() < 255);
    }

    #[test]
    fn bus_names_outside_the_charset_or_length_are_refused() {
        for bad in ["", "a/b", "a b", "bus.1", "ü", &"x".repeat(33)] {
            assert_eq!(
                BusName::new(bad),
                Err(NameError::BusName(bad.to_owned())),
                "{bad:?}"
            );
        }
        assert_eq!(bus(&"x".repeat(32)).as_str().len(), 32);
    }

    #[test]
    fn addresses_above_31_are_refused() {
        assert_eq!(Address::new(31).map(Address::get), Ok(31));
        assert!(Address::new(32).is_err());
    }

    #[test]
    fn diag_keys_are_the_addresses() {
        let a = Address::new(12).unwrap();
        assert_eq!(BlackboardKey::drive(a), BlackboardKey { value: 12 });
        assert_eq!(BlackboardKey::IMAGE.value, 0);
    }
}
