//! The lines the engine talks over: serial devices and pseudo-terminals, and the simulator's
//! virtual wire.

pub mod serial;
pub mod sim;
