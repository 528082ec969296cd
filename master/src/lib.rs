//! The USS bus master: configuration, transports, the real-time bus engine and the daemon
//! around it. The folders show the design:
//!
//! - [`engine`]: the circulating list on one line: timing rules, retries, offline handling,
//!   PKW mailboxes ([`engine::jobs`]), diagnostics ([`engine::stats`]), the decision of which
//!   PZD words go to a drive ([`engine::control`]), the check of the drive's own telegram
//!   monitoring ([`engine::monitoring`]) and reference frequency ([`engine::reference`]),
//!   lock-free process images ([`engine::image`]); and the
//!   traits it owns: [`engine::transport::Transport`], [`engine::clock::Clock`].
//! - [`transports`]: real serial devices ([`transports::serial`]) and the simulator's virtual
//!   wire (`transports::sim`, behind the default-on `sim` feature: a field build can leave the
//!   simulator out).
//! - [`daemon`]: buses in their real-time threads ([`daemon::runtime`], [`daemon::rt`]), the
//!   iceoryx2 services of a bus ([`daemon::ipc`]), the live summary ([`daemon::summary`]) and
//!   the service manager ([`daemon::supervise`]).
//! - [`config`]: the TOML configuration of `ussd`, validated with line and field in every error.

pub mod config;
pub mod daemon;
pub mod engine;
pub mod transports;

pub use engine::clock::{Clock, MonotonicClock, VirtualClock};
pub use engine::jobs::{Job, JobResult};
pub use engine::monitoring::{MonitoringSetup, WatchedParam};
pub use engine::reference::Reference;
pub use engine::stats::{DriveCounters, DriveStatus, LastFailure, Stats};
pub use engine::transport::{Rx, Transport, TransportError};
pub use engine::{
    Bridge, DriveSetup, Engine, EngineConfig, EngineHandle, Event, INTERNAL_JOB, LocalBridge,
    SubmitError,
};
#[cfg(feature = "sim")]
pub use transports::sim::SimTransport;
