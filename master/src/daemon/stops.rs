//! Operator stops take their own path (issue 21): a Unix stream socket per bus below the service
//! root (`uss_shm_types::names::stop_socket`, so the root's access rules hold), served by a
//! thread of its own. A stop never waits behind parameter requests, never needs an iceoryx2 port
//! (64 `ussctl watch` processes use up what the services admit) and never depends on the
//! heartbeat (a housekeeping thread that cannot publish). The bus thread sends the stop in its
//! next telegram (`uss_engine::turns`); the answer says which drives got it.
//!
//! **Nobody delays a stop** (docs/SAFETY.md, STOP-ANYWHERE). The thread waits on every
//! connection at once (poll(2)) and answers each request the moment its bytes are in: a
//! connection that says nothing holds no other back, it is closed after [`REQUEST_WITHIN`]. A
//! process may hold [`MAX_PER_PROCESS`] connections at once (its further ones are refused at
//! once, with [`CommandError::TooManyConnections`]), and the thread [`MAX_CONNECTIONS`] in all
//! (beyond, the process that holds the most gives up its oldest for the new one), so whatever
//! the processes of the access group do, a stop of another process is taken in microseconds.
//!
//! **A storm of connections** (processes that connect and close in a tight loop) queues no stop
//! behind it (issue 45: one such process held a stop back 98 to 333 ms, forty up to 2.45 s):
//! the kernel queues only [`BACKLOG`] connections for the thread, so a connection beyond waits
//! in connect(2) behind at most one of each other waiting thread, not behind thousands, and the
//! storm's processes sleep there instead of taking the CPU. When that queue is full, a client
//! adds its stop to the bus's stop board too ([`Board`]), which no queue holds back.
//!
//! **A stop is sendable across versions**: a request of any layout version since the stop
//! socket's bytes were frozen ([`uss_shm_types::STOP_BYTES_SINCE`]) stops, answered in its own
//! version.

use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use std::io::{ErrorKind, Read as _, Write as _};
use std::os::fd::AsFd as _;
use std::os::unix::fs::PermissionsExt as _;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use uss_engine::EngineHandle;
use uss_protocol::Address;
use uss_shm_types::{
    ALL_DRIVES, CommandError, OPERATOR_REQUEST_BYTES, OperatorRequest, OperatorResponse, StopBoard,
};

/// How long a connection may take to send its request before it is closed.
const REQUEST_WITHIN: Duration = Duration::from_millis(200);
/// Connections one process may hold at once.
pub const MAX_PER_PROCESS: usize = 8;
/// Connections served at once.
pub const MAX_CONNECTIONS: usize = 256;
/// The longest the thread waits before it looks at the stop board again.
const BOARD_EVERY: Duration = Duration::from_millis(1);
/// Connections the kernel queues for the thread to take: see [`bind`].
const BACKLOG: i32 = 16;
/// Connections taken per wait, before the thread looks at the requests of those it holds.
const ACCEPT_PER_TURN: usize = 32;

/// The bus's stop socket and the thread that serves it.
#[derive(Debug)]
pub struct StopSocket {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl StopSocket {
    /// Binds `path` (replacing a socket a dead ussd left; refusing one a live ussd serves) and
    /// serves it for the engine behind `handle`.
    /// Also makes the bus's stop board at `board` ([`Board`]), read at every turn and at least
    /// every [`BOARD_EVERY`].
    pub fn serve(
        path: &Path,
        board: &Path,
        bus: &str,
        handle: EngineHandle,
    ) -> std::io::Result<Self> {
        if UnixStream::connect(path).is_ok() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AddrInUse,
                format!("{} is served by another ussd", path.display()),
            ));
        }
        let _ = std::fs::remove_file(path);
        let listener = bind(path)?;
        listener.set_nonblocking(true)?;
        // The root directory decides who may reach it (owner only, or the access group).
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))?;
        let mut board = Board::create(board)?;
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let stop = Arc::clone(&stop);
            std::thread::Builder::new()
                .name(format!("uss-{bus}-stop"))
                .spawn(move || {
                    let mut served = Connections::default();
                    while !stop.load(Ordering::Acquire) {
                        board.look(&handle);
                        served.turn(&listener, &handle);
                    }
                })?
        };
        Ok(Self {
            path: path.to_owned(),
            stop,
            thread: Some(thread),
        })
    }
}

/// A listening socket at `path` whose queue of connections not yet taken is [`BACKLOG`] long.
/// A connection beyond it waits in connect(2), in the kernel's order of arrival, behind at most
/// one connection of each other waiting thread, and a process that connects in a tight loop
/// sleeps there instead of spinning; not behind the thousands a storm puts in a long queue
/// (`SOMAXCONN`, 4096, what `UnixListener::bind` asks for).
fn bind(path: &Path) -> std::io::Result<UnixListener> {
    use nix::sys::socket::{AddressFamily, Backlog, SockFlag, SockType, UnixAddr, listen, socket};
    let fd = socket(
        AddressFamily::Unix,
        SockType::Stream,
        SockFlag::SOCK_CLOEXEC,
        None,
    )?;
    nix::sys::socket::bind(std::os::fd::AsRawFd::as_raw_fd(&fd), &UnixAddr::new(path)?)?;
    listen(&fd, Backlog::new(BACKLOG).map_err(std::io::Error::from)?)?;
    Ok(UnixListener::from(fd))
}

impl Drop for StopSocket {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        // Wakes the thread from its poll.
        let _ = UnixStream::connect(&self.path);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

/// The bus's stop board (`uss_shm_types::StopBoard`): a stop a client adds when the socket's
/// queue is full. Read with pread(2), not mapped: a process of the access group that truncates
/// the file makes a read short (nothing new), never a fault in ussd.
#[derive(Debug)]
struct Board {
    file: std::fs::File,
    /// Removed when the board goes (with its thread).
    path: PathBuf,
    /// The counters as last read.
    seen: [u8; StopBoard::BYTES],
}

impl Drop for Board {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

impl Board {
    /// A new board at `path` (one a dead ussd left is replaced), every counter 0.
    fn create(path: &Path) -> std::io::Result<Self> {
        let _ = std::fs::remove_file(path);
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(path)?;
        file.set_len(StopBoard::BYTES as u64)?;
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))?;
        Ok(Self {
            file,
            path: path.to_owned(),
            seen: [0; StopBoard::BYTES],
        })
    }

    /// Hands every stop added since the last look to the bus thread (a counter that changed: a
    /// torn read makes one look changed at worst, and a stop too many is a stop).
    fn look(&mut self, handle: &EngineHandle) {
        let mut now = [0u8; StopBoard::BYTES];
        let Ok(n) = std::os::unix::fs::FileExt::read_at(&self.file, &mut now, 0) else {
            return;
        };
        if n != StopBoard::BYTES || now == self.seen {
            return;
        }
        for at in (0..StopBoard::BYTES).step_by(4) {
            if now[at..at + 4] != self.seen[at..at + 4]
                && let Some(request) = StopBoard::request_at(at)
            {
                // Who added it is not known here: its request on the socket names it.
                let _ = decide(request, handle, 0);
            }
        }
        self.seen = now;
    }
}

/// A connection whose request is not complete yet.
#[derive(Debug)]
struct Connection {
    stream: UnixStream,
    /// The peer process (`SO_PEERCRED`: the kernel's word, not the peer's), 0 if unknown.
    pid: u32,
    bytes: [u8; OPERATOR_REQUEST_BYTES],
    got: usize,
    /// When it is closed unanswered.
    deadline: Instant,
}

/// The connections the stop thread waits on.
#[derive(Debug, Default)]
struct Connections {
    open: Vec<Connection>,
}

impl Connections {
    /// One wait on the listener and every connection (at most until the nearest deadline), then
    /// what it brought: new connections taken, complete requests answered, late ones closed.
    fn turn(&mut self, listener: &UnixListener, handle: &EngineHandle) {
        let now = Instant::now();
        let wait = self
            .open
            .iter()
            .map(|c| c.deadline.saturating_duration_since(now))
            .min()
            .unwrap_or(BOARD_EVERY)
            .min(BOARD_EVERY);
        let ready: Vec<bool> = {
            let mut fds = Vec::with_capacity(self.open.len() + 1);
            fds.push(PollFd::new(listener.as_fd(), PollFlags::POLLIN));
            fds.extend(
                self.open
                    .iter()
                    .map(|c| PollFd::new(c.stream.as_fd(), PollFlags::POLLIN)),
            );
            let timeout =
                PollTimeout::try_from(wait.as_millis().max(1)).unwrap_or(PollTimeout::MAX);
            match poll(&mut fds, timeout) {
                Ok(_) => {}
                // A signal: look again.
                Err(nix::errno::Errno::EINTR) => return,
                Err(e) => {
                    // Not expected (EINVAL, ENOMEM): said, and no busy loop meanwhile.
                    tracing::warn!("the stop socket's poll failed: {e}; trying again");
                    std::thread::sleep(Duration::from_millis(10));
                    return;
                }
            }
            fds.iter()
                .map(|f| f.revents().is_some_and(|r| !r.is_empty()))
                .collect()
        };
        // Requests first: a connection that has its bytes in is answered before new ones come.
        let mut flags = ready.iter().skip(1).copied();
        self.open.retain_mut(|c| {
            let readable = flags.next().unwrap_or(false);
            if readable && c.read(handle) {
                return false;
            }
            if c.deadline <= Instant::now() {
                // A last look before it is closed: bytes that came since the poll are answered.
                let _ = c.read(handle);
                return false;
            }
            true
        });
        if ready.first().copied().unwrap_or(false) {
            self.accept(listener, handle);
        }
    }

    /// Takes the connections waiting on `listener`, at most [`ACCEPT_PER_TURN`] (a flood that
    /// reconnects as fast as it is closed must not keep the thread from the requests it holds);
    /// a request already in is answered at once.
    fn accept(&mut self, listener: &UnixListener, handle: &EngineHandle) {
        for _ in 0..ACCEPT_PER_TURN {
            let stream = match listener.accept() {
                Ok((s, _)) => s,
                Err(e) if e.kind() == ErrorKind::WouldBlock => return,
                // ECONNABORTED, EMFILE, ...: the next turn tries again.
                Err(_) => return,
            };
            let pid =
                nix::sys::socket::getsockopt(&stream, nix::sys::socket::sockopt::PeerCredentials)
                    .map_or(0, |c| u32::try_from(c.pid()).unwrap_or(0));
            if stream.set_nonblocking(true).is_err() {
                continue;
            }
            let mut c = Connection {
                stream,
                pid,
                bytes: [0; OPERATOR_REQUEST_BYTES],
                got: 0,
                deadline: Instant::now() + REQUEST_WITHIN,
            };
            // A request already in is answered, whoever sent it: a stop costs nothing.
            if c.read(handle) {
                continue;
            }
            let held = self.open.iter().filter(|o| o.pid == pid).count();
            if pid != 0 && held >= MAX_PER_PROCESS {
                c.answer(OperatorResponse::refused(
                    0,
                    CommandError::TooManyConnections,
                ));
                continue;
            }
            if self.open.len() >= MAX_CONNECTIONS {
                self.evict();
            }
            self.open.push(c);
        }
    }
}

impl Connections {
    /// Makes room for one connection: the oldest connection of the processes that hold the
    /// most goes, so a process with one connection (an operator's stop on its way) is the last
    /// to lose it, however many processes a flood of idle connections forks, and of equals the
    /// one that had the longest to say something.
    fn evict(&mut self) {
        let mut held: std::collections::HashMap<u32, usize> = std::collections::HashMap::new();
        for c in &self.open {
            *held.entry(c.pid).or_default() += 1;
        }
        // `open` is in arrival order: of equal counts the first (oldest) wins.
        let victim = self
            .open
            .iter()
            .enumerate()
            .max_by_key(|&(i, c)| (held.get(&c.pid).copied(), core::cmp::Reverse(i)))
            .map(|(i, _)| i);
        if let Some(i) = victim {
            self.open.remove(i);
        }
    }
}

impl Connection {
    /// Reads what arrived; once the request is complete (or the peer went) answers it and
    /// returns true: the connection is done.
    fn read(&mut self, handle: &EngineHandle) -> bool {
        loop {
            match self.stream.read(&mut self.bytes[self.got..]) {
                Ok(0) => return true,
                Ok(n) => {
                    self.got += n;
                    if self.got == OPERATOR_REQUEST_BYTES {
                        let response = match OperatorRequest::from_bytes(&self.bytes) {
                            Some(request) => {
                                decide(request, handle, self.pid).in_version(request.version)
                            }
                            None => OperatorResponse::refused(0, CommandError::Version),
                        };
                        self.answer(response);
                        return true;
                    }
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return false,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => return true,
            }
        }
    }

    /// Sends `response` (a few bytes: the socket's buffer takes them at once).
    fn answer(&mut self, response: OperatorResponse) {
        let _ = self.stream.write_all(&response.to_bytes());
    }
}

/// The answer to `request` from process `pid`: the stop handed to the bus thread, or why not.
fn decide(request: OperatorRequest, handle: &EngineHandle, pid: u32) -> OperatorResponse {
    let command = match request.validate() {
        Ok(c) => c,
        Err(e) => return OperatorResponse::refused(request.command, e),
    };
    if handle.is_stopped() {
        return OperatorResponse::refused(request.command, CommandError::Shutdown);
    }
    let target = match request.address {
        ALL_DRIVES => None,
        a => match Address::new(a) {
            Ok(a) => Some(a),
            Err(_) => {
                return OperatorResponse::refused(request.command, CommandError::UnknownDrive);
            }
        },
    };
    match handle.stop_drive(target, command, pid) {
        Ok(drives) => OperatorResponse::done(command, drives),
        Err(_) => OperatorResponse::refused(request.command, CommandError::UnknownDrive),
    }
}
