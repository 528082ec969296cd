//! Sans-I/O codec for the Siemens USS protocol, as described in `docs/USS.md`.
//!
//! Everything here works on caller-owned buffers and caller-supplied timestamps: no I/O, no clock,
//! no allocation. The crate is `no_std`; the master's real-time thread and the drive simulator
//! both build on it.
//!
//! - [`adr`]: slave addresses and the ADR byte (USS.md section 3).
//! - [`telegram`]: encoding and validating whole telegrams, BCC, PKW/PZD layouts (section 3).
//! - [`framer`]: the incremental receive framer with start-pause and residual-time rules (section 4).
//! - [`exchange`]: one master exchange without I/O: start pause, reply deadline, framer (section 4).
//! - [`notation`]: parameters as the manuals write them (`P1082`, `r0947[3]`).
//! - [`pkw`]: parameter tasks and replies, PNU paging, error numbers, reply matching (section 6).
//! - [`pzd`]: STW1/ZSW1 flag types, the PROFIdrive states, setpoint scaling (section 7).
//! - [`timing`]: character time, start pause, residual time, worst case and wire floor (section 4).
#![cfg_attr(not(test), no_std)]

pub mod adr;
pub mod data_type;
pub mod exchange;
pub mod framer;
pub mod notation;
pub mod pkw;
pub mod pzd;
#[cfg(feature = "serde")]
pub mod serde_impls;
pub mod telegram;
pub mod timing;

pub use adr::{Address, AddressError, Adr};
pub use data_type::DataType;
pub use framer::{FrameError, Framer, FramerConfig, LineError};
pub use notation::{NotationError, ParamRef, Prefix};
pub use pkw::{
    ErrorNumber, ParamReply, ParamTask, PkwError, Pnu, PnuError, ReplyKind, Storage, Subindex,
    Value,
};
pub use pzd::{DriveState, Setpoint, Stw1, Zsw1};
pub use telegram::{
    DecodeError, EncodeError, Layout, LayoutError, PkwMode, PzdCount, Telegram, Words, bcc, encode,
    encode_raw,
};
pub use timing::{Baud, BaudError, MAX_RESPONSE_DELAY, Timing};
