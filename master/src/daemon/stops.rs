//! Operator stops take their own path (issue 21): a Unix stream socket per bus below the service
//! root (`uss_shm_types::names::stop_socket`, so the root's access rules hold), served by a
//! thread of its own. A stop never waits behind parameter requests, never needs an iceoryx2 port
//! (64 `ussctl watch` processes use up what the services admit) and never depends on the
//! heartbeat (a housekeeping thread that cannot publish). The bus thread sends the stop in its
//! next telegram (`crate::engine::turns`); the answer says which drives got it.

use crate::engine::EngineHandle;
use std::io::{Read as _, Write as _};
use std::os::unix::fs::PermissionsExt as _;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;
use uss_protocol::Address;
use uss_shm_types::{
    ALL_DRIVES, CommandError, OPERATOR_REQUEST_BYTES, OperatorRequest, OperatorResponse,
};

/// How long a connection may take to send its request: a client that connects and says
/// nothing holds the next stop back at most this long.
const REQUEST_WITHIN: Duration = Duration::from_millis(200);

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
    pub fn serve(path: &Path, bus: &str, handle: EngineHandle) -> std::io::Result<Self> {
        if UnixStream::connect(path).is_ok() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AddrInUse,
                format!("{} is served by another ussd", path.display()),
            ));
        }
        let _ = std::fs::remove_file(path);
        let listener = UnixListener::bind(path)?;
        // The root directory decides who may reach it (owner only, or the access group).
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))?;
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let stop = Arc::clone(&stop);
            std::thread::Builder::new()
                .name(format!("uss-{bus}-stop"))
                .spawn(move || {
                    for stream in listener.incoming() {
                        if stop.load(Ordering::Acquire) {
                            break;
                        }
                        if let Ok(stream) = stream {
                            answer(stream, &handle);
                        }
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

impl Drop for StopSocket {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        // Wakes the thread from its accept.
        let _ = UnixStream::connect(&self.path);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Reads one request from `stream`, hands it to the bus thread, answers.
fn answer(mut stream: UnixStream, handle: &EngineHandle) {
    let _ = stream.set_read_timeout(Some(REQUEST_WITHIN));
    let _ = stream.set_write_timeout(Some(REQUEST_WITHIN));
    let mut bytes = [0u8; OPERATOR_REQUEST_BYTES];
    if stream.read_exact(&mut bytes).is_err() {
        return;
    }
    let pid = nix::sys::socket::getsockopt(&stream, nix::sys::socket::sockopt::PeerCredentials)
        .map_or(0, |c| u32::try_from(c.pid()).unwrap_or(0));
    let response = match OperatorRequest::from_bytes(&bytes) {
        Some(request) => decide(request, handle, pid),
        None => OperatorResponse::refused(0, CommandError::Version),
    };
    let _ = stream.write_all(&response.to_bytes());
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
