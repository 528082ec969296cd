//! The USS bus master: configuration, transports, the real-time bus engine and its runtime.
//!
//! - [`engine`]: the circulating list on one line: timing rules, retries, offline handling,
//!   PKW mailboxes, diagnostics; generic over [`transport::Transport`] and [`clock::Clock`].
//! - [`control`]: the one place that decides which PZD words go to a drive (live sample,
//!   safe command, latched, operator override, rejected sample).
//! - [`monitoring`]: the check of the drive's own telegram monitoring (P2014 / p2040).
//! - [`transport`], [`serial`]: the virtual wire to the simulator and real serial devices.
//! - [`config`]: the TOML configuration of `ussd`, validated with line and field in every error.
//! - [`runtime`], [`summary`]: buses in their real-time threads, housekeeping and the live summary.
//! - [`clock`]: the monotonic clock with absolute sleeps, and a virtual clock for tests.
//! - [`image`]: lock-free process images shared with clients.
//! - [`ipc`]: the iceoryx2 services of a bus: images, events, diagnostics, parameter requests.
//! - [`jobs`]: parameter jobs, results and the per-drive mailbox.
//! - [`rt`]: CPU pinning, `SCHED_FIFO`, stack prefault and memory locking, with honest reports.
//! - [`stats`]: per-drive and per-bus diagnostics and histograms.

pub mod clock;
pub mod config;
pub mod control;
pub mod engine;
pub mod image;
pub mod ipc;
pub mod jobs;
pub mod monitoring;
pub mod rt;
pub mod runtime;
pub mod serial;
pub mod stats;
pub mod summary;
pub mod supervise;
pub mod transport;

pub use clock::{Clock, MonotonicClock, VirtualClock};
pub use engine::{
    Bridge, DriveSetup, Engine, EngineConfig, EngineHandle, Event, INTERNAL_JOB, LocalBridge,
    RequestError,
};
pub use jobs::{Job, JobResult, Outcome};
pub use monitoring::MonitoringSetup;
pub use stats::{DriveCounters, DriveStatus, Failure, Stats};
pub use transport::{Rx, SimTransport, Transport, TransportError};
