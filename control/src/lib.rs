//! The control vocabulary of uss-rt and its two rule machines, below the shared-memory contract:
//! what a stop is and how hard it stops, why a drive is latched, why a controller's words were
//! refused, what kind of drive a bus holds; the rules a controller follows ([`Session`]) and
//! ussd's decision of which words go to a drive ([`Gate`]), each pure and tested as a table.
//! ussd's engine, the client library and every front-end speak it; the contract
//! (`uss-shm-types`) carries each of these as bytes and re-exports them.
//!
//! No I/O, no clock, no allocation, no `std`: a firmware or a tool takes it alone.
//!
//! - `stop`: [`StopCommand`] (OFF1, OFF2, OFF3) and what a control word does ([`is_stop`],
//!   [`stop_strength`]), from the codec's [`uss_protocol::Stw1`].
//! - `latch`: [`ControlState`], [`LatchReason`], [`Rejection`].
//! - `family`: [`DriveFamily`].
//! - `sample`: what a controller publishes ([`Sample`]) and what ussd received ([`Received`]).
//! - `session`: the rules a controller follows, written once ([`Session`]).
//! - `gate`: ussd's side, which words go to a drive now ([`Gate`]).
//! - `codes`: the code tables' shape ([`code_table!`], [`UnknownCode`]), shared with the
//!   contract's own tables.
#![no_std]

pub mod codes;
pub mod family;
pub mod gate;
pub mod latch;
pub mod sample;
pub mod session;
pub mod stop;

pub use codes::UnknownCode;
pub use family::DriveFamily;
pub use gate::{
    Control, ControlCounters, ControllerId, Gate, GateSetup, Latch, Operator, Poll, Transition,
    latch_id_of,
};
pub use latch::{ControlState, LatchReason, Rejection};
pub use sample::{Body, MAX_PZD_WORDS, Received, Sample, Words};
pub use session::{
    DriveImage, LatchView, MAX_REFRESH_NS, REARM_STW1, Session, SessionError, SessionSetup, Step,
    on_latch_clock, refresh_ns,
};
pub use stop::{NO_STOP_COMMAND, StopCommand, is_stop, stop_strength};
