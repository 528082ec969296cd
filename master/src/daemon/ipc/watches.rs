//! The processes behind parameter requests, watched so the bus thread can end a dead client's
//! jobs before they leave the mailbox ([`super::requesters`]): one pidfd per client node,
//! opened at its first request and kept while it lives (a client that asks again costs no
//! lookup), closed once it has no request pending and has ended, or when the table is needed
//! for another client.

use super::requesters::{Requesters, pidfd_of};
use iceoryx2::identifiers::UniqueNodeId;
use std::collections::HashMap;
use std::os::fd::{AsFd, OwnedFd};
use std::sync::Arc;
use uss_engine::jobs::Requester;

/// One watched client process.
#[derive(Debug)]
struct Watch {
    pid: u32,
    pidfd: OwnedFd,
    requester: Requester,
    /// Its requests not answered yet: while any is, its jobs may still be queued.
    pending: usize,
}

/// See the module documentation.
#[derive(Debug)]
pub(super) struct Watches {
    by_node: HashMap<UniqueNodeId, Watch>,
    /// The table the bus thread checks.
    table: Arc<Requesters>,
}

impl Watches {
    pub(super) fn new(table: Arc<Requesters>) -> Self {
        Self {
            by_node: HashMap::new(),
            table,
        }
    }

    /// The requester of a new request from `node`, whose process `pid()` looks up (only at
    /// the node's first request); [`Requester::NONE`] when it cannot be watched.
    pub(super) fn request(
        &mut self,
        node: UniqueNodeId,
        pid: impl FnOnce() -> Option<u32>,
    ) -> Requester {
        if let Some(w) = self.by_node.get_mut(&node) {
            w.pending += 1;
            return w.requester;
        }
        let Some((pid, pidfd)) = pid().and_then(|pid| Some((pid, pidfd_of(pid).ok()?))) else {
            return Requester::NONE;
        };
        let watched = self.table.watch(pidfd.as_fd()).or_else(|| {
            // The table is full: make room from clients with nothing pending.
            self.drop_idle(|_| true);
            self.table.watch(pidfd.as_fd())
        });
        let Some(requester) = watched else {
            return Requester::NONE;
        };
        self.by_node.insert(
            node,
            Watch {
                pid,
                pidfd,
                requester,
                pending: 1,
            },
        );
        requester
    }

    /// The process of `node`, if it is watched.
    pub(super) fn pid(&self, node: UniqueNodeId) -> Option<u32> {
        self.by_node.get(&node).map(|w| w.pid)
    }

    /// A request of `node` was answered; a client that has ended is let go of.
    pub(super) fn answered(&mut self, node: UniqueNodeId) {
        if let Some(w) = self.by_node.get_mut(&node) {
            w.pending = w.pending.saturating_sub(1);
        }
        self.drop_idle(|w| ended(&w.pidfd));
    }

    /// Lets go of the clients with nothing pending that `drop` picks: their jobs are all
    /// answered, so no queued job names their requester any more.
    fn drop_idle(&mut self, drop: impl Fn(&Watch) -> bool) {
        let table = &self.table;
        self.by_node.retain(|_, w| {
            let keep = w.pending > 0 || !drop(w);
            if !keep {
                table.forget(w.requester);
            }
            keep
        });
    }
}

/// Whether the process of `pidfd` has ended (its pidfd is readable).
fn ended(pidfd: &OwnedFd) -> bool {
    let mut fds = [nix::poll::PollFd::new(
        pidfd.as_fd(),
        nix::poll::PollFlags::POLLIN,
    )];
    matches!(nix::poll::poll(&mut fds, nix::poll::PollTimeout::ZERO), Ok(n) if n > 0)
}
