//! The shared-memory contract between `ussd` and its client processes (Rust, C, C++, Python):
//! the payloads they exchange over iceoryx2 0.10, their code tables, and where to find them.
//!
//! | service ([`names`])                | iceoryx2 pattern          | written by              | read by | payload |
//! |------------------------------------|---------------------------|-------------------------|---------|---------|
//! | `uss/<bus>/ussd`                   | publish-subscribe         | ussd (one publisher)    | anyone  | [`Heartbeat`] |
//! | `uss/<bus>/<gen>/drive/<addr>/out` | publish-subscribe         | exactly one controller  | ussd    | [`PzdOutput`] |
//! | `uss/<bus>/<gen>/drive/<addr>/in`  | blackboard, key 0         | ussd                    | anyone  | [`PzdInput`] |
//! | `uss/<bus>/<gen>/diag`             | blackboard, key = address | ussd                    | anyone  | [`DriveDiag`] |
//! | `uss/<bus>/<gen>/status`           | blackboard, key 0         | ussd                    | anyone  | [`BusStatus`] |
//! | `uss/<bus>/<gen>/cycle`            | event                     | ussd                    | anyone  | event ids in [`names`] |
//! | `uss/<bus>/<gen>/params`           | request-response          | clients ask, ussd answers | -     | [`ParamRequest`] / [`ParamResponse`] |
//! | `uss/<bus>/<gen>/command`          | request-response          | any process asks, ussd answers | - | [`OperatorRequest`] / [`OperatorResponse`] |
//! | `uss/<bus>/<gen>/capture`          | publish-subscribe         | ussd                    | anyone  | [`TelegramRecord`] |
//! | `uss/<bus>/<gen>/requests`         | event                     | clients, after sending a request | ussd | [`names::REQUEST_SENT`] |
//! | `uss/<bus>/<gen>/answers`          | event                     | ussd, after each answer | clients | [`names::ANSWER_SENT`] |
//!
//! `<gen>` is the serving ussd instance's generation, named by its heartbeat: a restarted ussd
//! serves a new generation while clients of the old one still hold its services.
//!
//! ussd creates every service; clients open them. The `out` service admits one publisher, so
//! "one controlling writer per drive" is a property of the service, not a convention: a second
//! controller is refused with `PublisherCreateError::ExceedsMaxSupportedPublishers`, and a
//! controller that died is replaced as soon as its dead node is cleaned up (which opening the
//! service does). Stopping a drive is open to every process: an operator's OFF1/OFF2/OFF3 on
//! `command` overrides the controller and latches ([`control`]). [`names`] says why `out` is not a blackboard.
//!
//! Rules every payload type follows, so C, C++ and Python can mirror it:
//! - `#[repr(C)]`, fixed-width fields only (no `bool`, no `usize`), no implicit padding: spare
//!   bytes are explicit `reserved` fields and are written as zero. [`layout::LAYOUTS`] pins every
//!   size, alignment and offset.
//! - The first field is `version`, written as [`LAYOUT_VERSION`]; readers check it.
//! - An explicit iceoryx2 type name ending in `V<LAYOUT_VERSION>` (e.g. `UssPzdOutputV1`):
//!   iceoryx2 compares type name, size and alignment when a port is opened, so a client built
//!   against another layout fails at open time instead of reading garbage.
//! - Enumerated `u8` fields stay plain `u8` in the payload (a foreign writer may put any byte
//!   there); the code tables are `#[repr(u8)]` enums with `TryFrom<u8>`. The control vocabulary
//!   (latches, stops, rejections, families) and the rules that speak it ([`Session`], ussd's
//!   `Gate`) are `uss_control`'s, below this contract; it carries them as bytes and
//!   re-exports them.
//! - Time stamps (`*_ns`) are `CLOCK_MONOTONIC` nanoseconds unless a field says otherwise.

pub mod capture;
mod codes;
pub mod control;
pub mod diag;
pub mod heartbeat;
pub mod layout;
pub mod names;
pub mod outcome;
pub mod params;
pub mod pzd;
pub mod service;

pub use capture::{CAPTURE_BYTES, CAPTURE_TASK, CAPTURE_TRUNCATED, Direction, Hex, TelegramRecord};
pub use codes::{ContractError, UnknownCode, screaming_snake};
pub use control::{
    ALL_DRIVES, CommandError, ControlState, LatchReason, Monitoring, NO_STOP_COMMAND,
    OPERATOR_REQUEST_BYTES, OPERATOR_RESPONSE_BYTES, OperatorRequest, OperatorResponse, Rejection,
    STOP_BYTES_SINCE, StopBoard, StopCommand,
};
pub use diag::{
    BusStatus, DriveCounters, DriveDiag, DriveFamily, DriveInfo, EXCHANGE_BUCKETS,
    EXCHANGE_BUCKETS_NS, LastFailure, LineFault, LineState, RtMode,
};
pub use heartbeat::{BusState, Heartbeat};
pub use names::{Address, BlackboardKey, BusName, Generation, Instance, NameError};
pub use outcome::{Answer, DriveError, ItemOutcome, PathError, ResultError};
pub use params::{
    MAX_PARAM_ITEMS, Outcome, ParamItem, ParamRequest, ParamResponse, ParamResult, REQUEST_FORCE,
    REQUEST_PUT_BACK, REQUEST_UNSAFE, Refusal, RequestError, Storage, TaskCode,
};
pub use pzd::{
    EXTRA_PZD_WORDS, MAX_PZD_WORDS, MIN_HANDSHAKE_NS, OUTPUT_RELEASE, PzdInput, PzdOutput,
};
// The rules a controller follows live below the contract (`uss_control::session`); they read
// the contract's input image ([`PzdInput`] is a `DriveImage`) and make samples it carries.
pub use uss_control::session;
pub use uss_control::{
    DriveImage, LatchView, MAX_REFRESH_NS, Sample, Session, SessionError, SessionSetup, Step,
    Words, on_latch_clock, refresh_ns,
};

/// The layout version of every payload type in this crate. Bump it with any change to a type's
/// fields, sizes or code tables, together with the type names' `V<n>` suffix. The drive family
/// is an open code (`uss_control::DriveFamily::of_code`: a reader takes a code it does not know
/// as generic), so a new family is no such change.
pub const LAYOUT_VERSION: u32 = 9;

/// Checks a payload's `version` field.
pub const fn check_version(found: u32) -> Result<(), ContractError> {
    if found == LAYOUT_VERSION {
        Ok(())
    } else {
        Err(ContractError::Version {
            expected: LAYOUT_VERSION,
            found,
        })
    }
}
