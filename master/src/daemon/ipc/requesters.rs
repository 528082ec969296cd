//! Whether the process that asked for a parameter job still lives, as the bus thread checks it
//! before the job leaves the mailbox (the engine asks its bridge, [`RtBridge`](super::RtBridge),
//! `uss_engine::Bridge::requester_ended`): a dead client's work dies with it, at most the job
//! already on the wire finishes.
//!
//! The parameter server watches each requesting process through a pidfd (`pidfd_open`, Linux
//! 5.3+), which becomes readable when the process ends (a zombie included, and never confused
//! with a later process of the same pid) and registers it in a fixed table here, shared with
//! the bus thread's bridge; a job carries its requester's slot ([`Requester`]). The bus
//! thread's check is one `poll` with a zero timeout: no allocation, no blocking.

use core::sync::atomic::{AtomicI32, Ordering};
use std::os::fd::{AsRawFd, BorrowedFd, RawFd};
use uss_engine::jobs::Requester;

/// Requesters watched at once (one per client process with requests pending).
pub const REQUESTER_SLOTS: usize = 64;

const EMPTY: RawFd = -1;

/// The table of watched requesters: each slot holds a pidfd's number or [`EMPTY`].
#[derive(Debug)]
pub struct Requesters {
    fds: [AtomicI32; REQUESTER_SLOTS],
}

impl Default for Requesters {
    fn default() -> Self {
        Self {
            fds: core::array::from_fn(|_| AtomicI32::new(EMPTY)),
        }
    }
}

impl Requesters {
    /// Watches the process of `pidfd` in a free slot; `None` when all are taken (its jobs are
    /// then only cancelled by the bridge's periodic look for dead clients). The caller keeps
    /// the fd open until [`Requesters::forget`], and forgets only when no job of it is left.
    pub fn watch(&self, pidfd: BorrowedFd<'_>) -> Option<Requester> {
        let fd = pidfd.as_raw_fd();
        self.fds.iter().enumerate().find_map(|(i, slot)| {
            slot.compare_exchange(EMPTY, fd, Ordering::AcqRel, Ordering::Acquire)
                .ok()
                .map(|_| Requester::new(u16::try_from(i + 1).unwrap_or(0)))
        })
    }

    /// Frees the slot of `requester`.
    pub fn forget(&self, requester: Requester) {
        if let Some(slot) = slot(requester).and_then(|s| self.fds.get(s)) {
            slot.store(EMPTY, Ordering::Release);
        }
    }

    /// Whether `requester`'s process has ended. A requester nobody watches (or a slot freed
    /// already) is taken as alive: the bridge's periodic look covers it.
    pub fn has_ended(&self, requester: Requester) -> bool {
        let Some(fd) = slot(requester)
            .and_then(|s| self.fds.get(s))
            .map(|s| s.load(Ordering::Acquire))
            .filter(|&fd| fd != EMPTY)
        else {
            return false;
        };
        let mut pfd = nix::libc::pollfd {
            fd,
            events: nix::libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd; the fd stays open while a job of it is queued (`watch`).
        let ready = unsafe { nix::libc::poll(&raw mut pfd, 1, 0) };
        ready > 0 && pfd.revents & nix::libc::POLLIN != 0
    }
}

/// The table's slot of `requester`, if it has one.
fn slot(requester: Requester) -> Option<usize> {
    usize::from(requester.number()).checked_sub(1)
}

/// A pidfd of process `pid`: readable once the process has ended.
pub fn pidfd_of(pid: u32) -> std::io::Result<std::os::fd::OwnedFd> {
    let pid = nix::libc::pid_t::try_from(pid)
        .map_err(|_| std::io::Error::from(std::io::ErrorKind::InvalidInput))?;
    // SAFETY: pidfd_open takes a pid and flags and returns a new fd or -1.
    let fd = unsafe { nix::libc::syscall(nix::libc::SYS_pidfd_open, pid, 0) };
    if fd < 0 {
        return Err(std::io::Error::last_os_error());
    }
    let fd = RawFd::try_from(fd).map_err(|_| std::io::Error::from(std::io::ErrorKind::Other))?;
    // SAFETY: a new fd, owned by nobody else.
    Ok(unsafe { <std::os::fd::OwnedFd as std::os::fd::FromRawFd>::from_raw_fd(fd) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::fd::AsFd;
    use std::process::Command;

    #[test]
    fn a_watched_process_is_alive_until_it_ends_even_as_a_zombie() {
        let mut child = Command::new("sleep").arg("30").spawn().unwrap();
        let pidfd = pidfd_of(child.id()).unwrap();
        let table = Requesters::default();
        let r = table.watch(pidfd.as_fd()).unwrap();
        assert!(!table.has_ended(r));
        child.kill().unwrap();
        // Not reaped yet: a zombie has ended all the same.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        while !table.has_ended(r) {
            assert!(
                std::time::Instant::now() < deadline,
                "the kill was not seen"
            );
            std::thread::yield_now();
        }
        child.wait().unwrap();
        assert!(table.has_ended(r));
        table.forget(r);
        assert!(!table.has_ended(r), "a forgotten slot is nobody's");
        assert!(!table.has_ended(Requester::NONE));
    }

    #[test]
    fn a_full_table_watches_no_more() {
        let me = pidfd_of(std::process::id()).unwrap();
        let table = Requesters::default();
        let all: Vec<_> = (0..REQUESTER_SLOTS)
            .map(|_| table.watch(me.as_fd()).unwrap())
            .collect();
        assert_eq!(table.watch(me.as_fd()), None);
        table.forget(all[7]);
        assert_eq!(table.watch(me.as_fd()), Some(all[7]));
    }
}
