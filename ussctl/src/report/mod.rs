//! What ussctl prints: one report type per answer, shown as a table or text for people and
//! as JSON (`--json`) for machines. The JSON field names are part of ussctl's interface.

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
