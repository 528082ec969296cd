//! The heartbeat of the ussd serving a bus, on `uss/<bus>/ussd` (see [`crate::names`]): which
//! instance serves the bus (its generation names every other service), whether it runs, its
//! line is down, or it is stopping, and proof of life every [`names::HEARTBEAT_PERIOD_NS`].
//!
//! A client that sees no new heartbeat for [`names::GONE_AFTER_NS`] knows ussd is gone (killed
//! or hung) and must not show a healthy picture: its images are stale. A heartbeat with
//! another generation means ussd was restarted: the client reopens the new generation's
//! services. A heartbeat in [`BusState::Stopping`] is ussd's last word before a clean exit.

use crate::codes::{UnknownCode, code_table};
use crate::diag::LineFault;
use crate::names::{self, Generation};
use crate::{LAYOUT_VERSION, check_version};
#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;

code_table! {
    /// What ussd says of its bus; the `state` byte of [`Heartbeat`].
    pub enum BusState {
        /// Polling the drives.
        Running = 0 => "running",
        /// The line failed; ussd reopens it (see `line_fault`).
        LineDown = 1 => "line down",
        /// ussd is stopping cleanly: this is its last heartbeat.
        Stopping = 2 => "stopping",
    }
}

/// One heartbeat.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "ipc", derive(ZeroCopySend), type_name("UssHeartbeatV9"))]
pub struct Heartbeat {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// ussd's process id.
    pub pid: u32,
    /// The instance's [`Generation`]: its services are `uss/<bus>/<generation>/...`.
    pub generation: u64,
    /// Counts the heartbeats of this instance.
    pub sequence: u64,
    /// When it was sent, `CLOCK_MONOTONIC` ns.
    pub timestamp_ns: u64,
    /// Exchanges the bus thread completed (its progress).
    pub exchanges: u64,
    /// When the line went down, `CLOCK_MONOTONIC` ns (0 while up).
    pub line_down_since_ns: u64,
    /// A [`BusState`] code.
    pub state: u8,
    /// A [`LineFault`] code (0 while the line is up).
    pub line_fault: u8,
    pub reserved: [u8; 2],
    /// With [`LineFault::Io`]: the errno.
    pub line_errno: i32,
}

impl Heartbeat {
    /// The first heartbeat of an instance.
    pub const fn new(pid: u32, generation: Generation) -> Self {
        Self {
            version: LAYOUT_VERSION,
            pid,
            generation: generation.0,
            sequence: 0,
            timestamp_ns: 0,
            exchanges: 0,
            line_down_since_ns: 0,
            state: BusState::Running.code(),
            line_fault: LineFault::None.code(),
            reserved: [0; 2],
            line_errno: 0,
        }
    }

    pub fn generation(&self) -> Generation {
        Generation(self.generation)
    }

    pub fn state(&self) -> Result<BusState, UnknownCode> {
        BusState::try_from(self.state)
    }

    /// Whether the heartbeat is too old at `now_ns` (`CLOCK_MONOTONIC`): ussd is gone.
    pub const fn is_stale(&self, now_ns: u64) -> bool {
        now_ns.saturating_sub(self.timestamp_ns) > names::GONE_AFTER_NS
    }

    /// Checks the layout version.
    pub fn check(&self) -> Result<(), crate::ContractError> {
        check_version(self.version)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_heartbeat_is_stale_after_ten_periods() {
        let mut h = Heartbeat::new(7, Generation(9));
        h.timestamp_ns = 1_000_000_000;
        assert!(!h.is_stale(1_000_000_000 + names::GONE_AFTER_NS));
        assert!(h.is_stale(1_000_000_001 + names::GONE_AFTER_NS));
        assert!(
            !h.is_stale(0),
            "a clock behind the sender's is not staleness"
        );
        assert_eq!(
            (h.generation(), h.state()),
            (Generation(9), Ok(BusState::Running))
        );
        assert_eq!(names::GONE_AFTER_NS, 500_000_000);
    }
}
