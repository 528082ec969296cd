//! Who may use ussd's services: the root directory of uss-rt's iceoryx2 files
//! (`uss_shm_types::service::root`, `/dev/shm/uss-rt`), made and checked by ussd before any of
//! its nodes. Inside it iceoryx2 opens every file to all; the root alone decides: owner-only
//! (mode 0700), or with `access_group` readable and writable by that group (mode 2770, the
//! group set) so its members run monitors and controllers as their own users. Everybody else
//! cannot enter it, and the client library says why.

use nix::unistd::{Gid, Group, Uid, User, chown, geteuid};
use std::os::unix::fs::{DirBuilderExt as _, MetadataExt as _};
use std::path::PathBuf;
use thiserror::Error;

/// The root as ussd left it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Access {
    pub root: PathBuf,
    /// The group that may use the services, with its gid; `None`: owner-only.
    pub group: Option<(String, u32)>,
}

impl core::fmt::Display for Access {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match &self.group {
            Some((name, gid)) => write!(
                f,
                "shared memory in {}: ussd's user and the members of group {name} (gid {gid}) may use the services (mode 2770)",
                self.root.display()
            ),
            None => write!(
                f,
                "shared memory in {}: only ussd's user (and root) may use the services (mode 0700; access_group opens it to a group)",
                self.root.display()
            ),
        }
    }
}

/// Why ussd cannot make the root what its configuration asks.
#[derive(Debug, Error)]
pub enum AccessError {
    #[error(
        "access_group = {0:?}: no such group on this machine: create it (groupadd {0}) or change the configuration"
    )]
    NoSuchGroup(String),
    #[error("{}: {what} failed: {source}", path.display())]
    Io {
        path: PathBuf,
        what: &'static str,
        source: std::io::Error,
    },
    #[error("{} is not a directory (a symbolic link or a file): remove it; ussd makes it", path.display())]
    NotADirectory { path: PathBuf },
    #[error(
        "{} belongs to user {owner}, not to ussd's user {me}: remove it (ussd makes it) or run ussd as {owner}",
        path.display()
    )]
    Foreign {
        path: PathBuf,
        owner: String,
        me: String,
    },
    /// An existing directory that is no uss-rt root (a sticky shared directory such as
    /// /dev/shm, one inside a running ussd's root, any directory with files of others): ussd
    /// changes the owner and mode of its root, and must never do that to another directory.
    #[error(
        "{} is not a shared-memory root of uss-rt ({why}): ussd would change who may use it; nothing was changed. Name a new or empty directory of its own in {}",
        path.display(),
        uss_shm_types::service::ROOT_ENV
    )]
    NotARoot { path: PathBuf, why: String },
    /// Another ussd is starting on the same root this moment and did not finish in time.
    #[error(
        "another ussd is starting on {} (it holds {}) and did not finish within {} s: nothing was changed; try again, or look for a ussd hanging at its start",
        path.display(),
        lock.display(),
        START_LOCK_WAIT.as_secs()
    )]
    Starting { path: PathBuf, lock: PathBuf },
    /// A running ussd uses the root as it is: this one would change who may use its services.
    #[error(
        "{} is in use by {running}, {now}; this ussd (user {me}) would make it {wanted} and cut \
         that ussd's clients off: nothing was changed. Run this ussd as {owner} with the same \
         access_group, give it its own root ({}), or stop that ussd first",
        path.display(),
        uss_shm_types::service::ROOT_ENV,
        me = .users.0,
        owner = .users.1
    )]
    InUse {
        path: PathBuf,
        /// `ussd process 812 (user uss, bus sim)`, the running ones named.
        running: String,
        /// Who may use it now: `user uss, group uss, mode 2770`.
        now: String,
        wanted: String,
        /// This ussd's user and the root's owner.
        users: Box<(String, String)>,
    },
}

/// A ussd that runs on the root now: its process, its user and its bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Running {
    pub pid: u32,
    pub uid: Option<u32>,
    pub bus: String,
}

impl core::fmt::Display for Running {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "ussd process {}", self.pid)?;
        match self.uid {
            Some(uid) => write!(f, " (user {}, bus {})", user_name(uid), self.bus),
            None => write!(f, " (bus {})", self.bus),
        }
    }
}

/// Every ussd that runs on the shared-memory root now (its live iceoryx2 node `ussd-<bus>`),
/// other than this process; empty when there is no root yet or it cannot be read.
pub fn running() -> Vec<Running> {
    let me = std::process::id();
    uss_shm_types::names::live_ussds()
        .into_iter()
        .filter(|u| u.pid != me)
        .map(|u| Running {
            pid: u.pid,
            uid: uid_of(u.pid),
            bus: u.bus,
        })
        .collect()
}

/// How long a ussd waits for another one that starts on the same root ([`StartLock`]).
pub const START_LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(10);

/// Held from before ussd looks for running ussds until its own nodes exist: two ussds started
/// at one moment on an empty root each saw none and each made the root as it asked, the last
/// one winning (the sweep of issue 47: the group ussd's members were cut off). An exclusive
/// `flock` on `<root>.lock` beside the root: the second waits for the first's nodes, then sees
/// them. The lock is the file's, not its contents': any user may take it on a file it can read.
#[derive(Debug)]
pub struct StartLock {
    _file: std::fs::File,
}

impl StartLock {
    /// Waits up to [`START_LOCK_WAIT`] for the root's start lock.
    ///
    /// # Errors
    /// [`AccessError::Starting`] when another ussd holds it that long; [`AccessError::Io`] when
    /// the lock file cannot be made or opened.
    pub fn take() -> Result<Self, AccessError> {
        use std::os::fd::AsRawFd as _;
        use std::os::unix::fs::OpenOptionsExt as _;
        let root = uss_shm_types::service::root();
        let mut lock = root.clone().into_os_string();
        lock.push(".lock");
        let lock = PathBuf::from(lock);
        let io = |what| {
            let path = lock.clone();
            move |source| AccessError::Io { path, what, source }
        };
        if let Some(parent) = lock.parent() {
            std::fs::create_dir_all(parent).map_err(io("mkdir"))?;
        }
        // Another user's lock file is opened to read: flock needs no more.
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .mode(0o644)
            .custom_flags(nix::libc::O_NOFOLLOW)
            .open(&lock)
            .or_else(|_| {
                std::fs::OpenOptions::new()
                    .read(true)
                    .custom_flags(nix::libc::O_NOFOLLOW)
                    .open(&lock)
            })
            .map_err(io("open"))?;
        let until = std::time::Instant::now() + START_LOCK_WAIT;
        loop {
            // SAFETY: flock on a descriptor this function owns; no memory is handed over.
            let r = unsafe {
                nix::libc::flock(file.as_raw_fd(), nix::libc::LOCK_EX | nix::libc::LOCK_NB)
            };
            if r == 0 {
                return Ok(Self { _file: file });
            }
            let e = std::io::Error::last_os_error();
            if e.raw_os_error() != Some(nix::libc::EWOULDBLOCK) {
                return Err(io("flock")(e));
            }
            if std::time::Instant::now() > until {
                return Err(AccessError::Starting { path: root, lock });
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }
}

/// Why an existing directory is no uss-rt root, or `None` when it is one: not a sticky shared
/// directory (/dev/shm, /tmp), and empty or holding only what iceoryx2 (`nodes`, `services`,
/// `iox2_*`, with one of the two directories) and ussd's stop boards (`*.stop`, `*.stops`)
/// make there.
fn not_a_root(path: &std::path::Path, meta: &std::fs::Metadata) -> Option<String> {
    if meta.mode() & 0o1000 != 0 {
        return Some(format!(
            "a shared directory (mode {:o}, sticky) such as /dev/shm holds roots, it is none",
            meta.mode() & 0o7777
        ));
    }
    let ours = |name: &str| {
        matches!(name, "nodes" | "services")
            || name.starts_with("iox2_")
            || std::path::Path::new(name)
                .extension()
                .is_some_and(|e| e == "stop" || e == "stops")
    };
    let names: Vec<String> = match std::fs::read_dir(path) {
        Ok(entries) => entries
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect(),
        Err(e) => return Some(format!("cannot list it: {e}")),
    };
    if let Some(name) = names.iter().find(|n| !ours(n)) {
        return Some(format!(
            "it holds {name:?}, which neither iceoryx2 nor ussd makes there"
        ));
    }
    // iceoryx2's files without its two directories: a directory inside a root (its services).
    let has = |n: &str| names.iter().any(|m| m == n);
    if !(names.is_empty() || has("nodes") || has("services")) {
        return Some(
            "it holds iceoryx2's files but neither a nodes nor a services directory: the inside of \
             another root"
                .to_owned(),
        );
    }
    None
}

/// The real user of process `pid` (`/proc/<pid>/status`).
fn uid_of(pid: u32) -> Option<u32> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("Uid:"))?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// `user uss, group uss, mode 2770`.
fn who_may(uid: u32, gid: u32, mode: u32) -> String {
    let group = Group::from_gid(Gid::from_raw(gid))
        .ok()
        .flatten()
        .map_or_else(|| gid.to_string(), |g| g.name);
    format!(
        "user {}, group {group}, mode {:o}",
        user_name(uid),
        mode & 0o7777
    )
}

fn user_name(uid: u32) -> String {
    User::from_uid(Uid::from_raw(uid))
        .ok()
        .flatten()
        .map_or_else(|| uid.to_string(), |u| u.name)
}

/// The group `access_group` names: a name, or a number (a gid).
fn group(access_group: &str) -> Result<(String, u32), AccessError> {
    let found = if let Ok(gid) = access_group.parse::<u32>() {
        Group::from_gid(Gid::from_raw(gid))
            .ok()
            .flatten()
            .map_or((access_group.to_owned(), gid), |g| (g.name, gid))
    } else {
        let g = Group::from_name(access_group)
            .ok()
            .flatten()
            .ok_or_else(|| AccessError::NoSuchGroup(access_group.to_owned()))?;
        (g.name, g.gid.as_raw())
    };
    Ok(found)
}

/// Makes the root directory (when it is not there) and gives it the owner, group and mode the
/// configuration asks for: ussd's user, `access_group`'s group with mode 2770, or mode 0700.
/// Refuses a root that is a link or a file, or another user's (unless ussd runs as root), and
/// changes nothing of a root that `running` ussd processes use ([`running`]): a root in use
/// that is not already as asked is refused, naming them.
pub fn prepare(access_group: Option<&str>, running: &[Running]) -> Result<Access, AccessError> {
    let path = uss_shm_types::service::root();
    let io = |what, path: &PathBuf| {
        let path = path.clone();
        move |source| AccessError::Io { path, what, source }
    };
    let group = access_group.map(group).transpose()?;
    match std::fs::symlink_metadata(&path) {
        Ok(meta) if !meta.file_type().is_dir() => {
            return Err(AccessError::NotADirectory { path });
        }
        Ok(meta) => {
            let me = geteuid();
            let (mode, gid) = match &group {
                Some((_, gid)) => (0o2770, *gid),
                None => (0o700, meta.gid()),
            };
            let as_asked =
                meta.uid() == me.as_raw() && meta.gid() == gid && meta.mode() & 0o7777 == mode;
            if !as_asked && let Some(why) = not_a_root(&path, &meta) {
                return Err(AccessError::NotARoot { path, why });
            }
            if !running.is_empty() && !as_asked {
                return Err(AccessError::InUse {
                    running: running
                        .iter()
                        .map(ToString::to_string)
                        .collect::<Vec<_>>()
                        .join(", "),
                    now: who_may(meta.uid(), meta.gid(), meta.mode()),
                    wanted: who_may(me.as_raw(), gid, mode),
                    users: Box::new((user_name(me.as_raw()), user_name(meta.uid()))),
                    path,
                });
            }
            if meta.uid() != me.as_raw() {
                if !me.is_root() {
                    return Err(AccessError::Foreign {
                        owner: user_name(meta.uid()),
                        me: user_name(me.as_raw()),
                        path,
                    });
                }
                // Root takes it over: nobody else decides who enters ussd's services.
                chown(&path, Some(me), None)
                    .map_err(|e| io("chown", &path)(std::io::Error::from(e)))?;
            }
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            std::fs::DirBuilder::new()
                .recursive(true)
                .mode(0o700)
                .create(&path)
                .map_err(io("mkdir", &path))?;
        }
        Err(e) => return Err(io("stat", &path)(e)),
    }
    let mode = match &group {
        Some((_, gid)) => {
            chown(&path, None, Some(Gid::from_raw(*gid)))
                .map_err(|e| io("chown", &path)(std::io::Error::from(e)))?;
            0o2770
        }
        None => 0o700,
    };
    // The path is ussd's directory, no link (checked above; in /dev/shm, sticky, nobody else
    // may replace it).
    std::fs::set_permissions(&path, std::os::unix::fs::PermissionsExt::from_mode(mode))
        .map_err(io("chmod", &path))?;
    Ok(Access { root: path, group })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_group_is_found_by_name_or_number_and_a_missing_one_is_named() {
        let (name, gid) = group("0").unwrap();
        assert_eq!((name.as_str(), gid), ("root", 0));
        assert_eq!(group("root").unwrap(), ("root".to_owned(), 0));
        let e = group("no-such-group-here").unwrap_err();
        assert_eq!(
            e.to_string(),
            "access_group = \"no-such-group-here\": no such group on this machine: create it \
             (groupadd no-such-group-here) or change the configuration"
        );
    }
}
