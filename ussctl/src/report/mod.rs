//! What ussctl prints: one report type per answer, shown as a table or text for people and
//! as JSON (`--json`) for machines. The JSON field names are part of ussctl's interface.

/// S1..S4, "fault", "not ready" from ZSW1; "offline" while the drive does not answer (its last
/// ZSW1 is history then); "unknown" until ussd's first poll decided.
use uss_client::view::shown_state;

mod backup;
mod drive;
mod scan;
mod stats;
mod status;

pub use backup::*;
pub use drive::*;
pub use scan::*;
pub use stats::*;
pub use status::*;

#[cfg(test)]
mod tests;
