//! `ussd` around the engine: buses in their real-time threads, the iceoryx2 services clients use,
//! housekeeping and the live summary, the real-time set-up and the service manager.

pub mod access;
pub mod housekeeping;
pub mod ipc;
pub mod line;
pub mod qualify;
pub mod runtime;
pub mod stops;
pub mod summary;
pub mod supervise;
