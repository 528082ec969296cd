//! Which PZD words go to a drive now: the [`Gate`], the one place that decides (ARCHITECTURE.md,
//! "Failure model"). It lives below the contract, in `uss_control::gate`, beside the client's
//! rules it answers; every poll of a drive asks it, and nothing else in ussd chooses words.

pub use uss_control::gate::{
    Control, ControlCounters, ControllerId, Gate, GateSetup, Latch, Operator, Poll, Transition,
    latch_id_of,
};
