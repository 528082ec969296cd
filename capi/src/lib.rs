//! The C ABI of the uss-rt client (`libussrt.so`, `libussrt.a`, `include/ussrt.h`): C and C++
//! programs reach ussd through the Rust client library itself, so the heartbeat, generation,
//! latch and request rules are the same code as in Rust (`uss_control::session` decides what
//! a controller publishes), not a fifth copy.
//!
//! Conventions every function follows (the header says them again):
//! - Every function returns a [`UssrtStatus`]: `USSRT_STATUS_OK` (0) or what went wrong.
//!   [`ussrt_last_error`] gives the message of the calling thread's last failure (with what
//!   to do), [`ussrt_last_error_info`] its details (the latch, the drive's error number).
//! - Handles ([`UssrtBus`], [`UssrtController`]) are made by `*_open` and owned by the
//!   caller until `*_close`; each may be used from several threads. Output structs are the
//!   caller's memory, written only on success. Strings in are NUL-terminated UTF-8 and are
//!   only read during the call.
//! - No Rust panic crosses the boundary: one is caught and returned as
//!   `USSRT_STATUS_INTERNAL` (build with unwinding, the `lib` profile, as `install.sh` does).
//! - Time-outs are milliseconds; drive addresses 0..=31.

mod bus;
mod control;
mod error;
mod params;
mod scan;
mod status;

pub use bus::{UssrtBus, UssrtDrive};
pub use control::UssrtController;
pub use error::{UssrtErrorInfo, ussrt_last_error, ussrt_last_error_info};
pub use params::{UssrtCancel, UssrtDescription, UssrtFault, UssrtFaultReport, UssrtValue};
pub use scan::UssrtScanned;
pub use status::UssrtStatus;

/// The version of this library, e.g. `"0.1.0"`: a static string, never freed.
#[unsafe(no_mangle)]
pub extern "C" fn ussrt_version() -> *const core::ffi::c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}
