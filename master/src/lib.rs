//! `ussd`, the USS bus master daemon, around the bus engine (`uss-engine`) and its lines
//! (`uss-serial`, and the simulator's virtual wire from `uss-drive-sim` behind the default-on
//! `sim` feature: a field build can leave the simulator out). The folders show the design:
//!
//! - [`daemon`]: buses in their real-time threads ([`daemon::runtime`]), a line that may be
//!   absent and is reopened ([`daemon::line`]), the iceoryx2 services of a bus
//!   ([`daemon::ipc`]), the live summary ([`daemon::summary`]) and the service manager
//!   ([`daemon::supervise`]).
//! - [`config`]: the TOML configuration of `ussd`, validated with line and field in every error.

pub mod config;
pub mod daemon;
