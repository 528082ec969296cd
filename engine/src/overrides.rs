//! Operator stops, of one drive or of every drive, from any thread to the bus thread without
//! locks ([`Overrides`]).

use core::sync::atomic::{AtomicU32, Ordering};
use uss_shm_types::StopCommand;

/// Operator stop commands for one drive, from any thread, taken by the bus thread without
/// locks: a counter per command (so OFF2 and OFF1 arriving between two polls both count and
/// the stronger wins) and the last requester's process id.
#[derive(Debug, Default)]
pub(crate) struct Overrides {
    /// OFF1, OFF2, OFF3.
    pub(crate) counts: [AtomicU32; 3],
    pub(crate) pid: AtomicU32,
}

impl Overrides {
    /// The strongest command that arrived since the counts in `seen` (which it brings up to
    /// date): the bus thread's one way of taking operator stops, a drive's or every drive's.
    pub(crate) fn take(&self, seen: &mut [u32; 3]) -> Option<StopCommand> {
        let mut strongest: Option<StopCommand> = None;
        for (i, command) in STOPS.into_iter().enumerate() {
            let count = self.counts[i].load(Ordering::Acquire);
            if count != seen[i] {
                seen[i] = count;
                if strongest.is_none_or(|s| command.strength() > s.strength()) {
                    strongest = Some(command);
                }
            }
        }
        strongest
    }
}

pub(crate) const STOPS: [StopCommand; 3] =
    [StopCommand::Off1, StopCommand::Off2, StopCommand::Off3];

/// Where `command` is in [`STOPS`] (and in the counters kept in that order).
pub(crate) const fn stop_index(command: StopCommand) -> usize {
    match command {
        StopCommand::Off1 => 0,
        StopCommand::Off2 => 1,
        StopCommand::Off3 => 2,
    }
}
