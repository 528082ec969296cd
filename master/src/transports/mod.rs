//! The lines the engine talks over: serial devices and pseudo-terminals, and the simulator's
//! virtual wire.

pub mod latency;
pub mod rate;
pub mod serial;
#[cfg(feature = "sim")]
pub mod sim;
