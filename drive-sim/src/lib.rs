//! Simulated USS drives that behave like MICROMASTER 4 / SINAMICS G120 on the wire
//! (see `docs/USS.md`).
//!
//! - [`drive`]: one drive: PROFIdrive state machine, ramp, PKW handshake, telegram monitoring.
//! - [`family`]: the families it plays (every family with a profile: MICROMASTER 4, G110, G120,
//!   SIMOREG): their parameter sets, the parameters the drive model uses, and the behaviour each
//!   profile names.
//! - [`params`]: its parameter table with limits, types, arrays, RAM vs EEPROM and error numbers.
//! - [`bus`]: drives at addresses 0..=31 on one bus, who answers what.
//! - [`fault`]: the fault injector (dropped, corrupted, truncated, late, misaddressed replies,
//!   noise, unplugging).
//! - [`wire`]: the in-process virtual wire with real character timing, for the master's tests.
//! - [`serve`]: serving a bus on a serial device or a pseudo-terminal.
//! - [`spec`]: the `ADDR[:key=value,...]` drive specifications of the `uss-sim` command line.

pub mod bus;
pub mod drive;
pub mod family;
pub mod fault;
pub mod options;
pub mod params;
pub mod serve;
pub mod spec;
#[cfg(feature = "transport")]
pub mod transport;
pub mod wire;

pub use bus::{BusError, SimBus, Slot};
pub use drive::{Counters, Drive, DriveConfig, State, Stop};
pub use fault::{Fault, FaultPlan, Reply};
pub use options::SimOptions;
#[cfg(feature = "transport")]
pub use transport::SimTransport;
pub use wire::{RxByte, VirtualWire};
