//! Operator stop commands (OFF1, OFF2, OFF3) for one drive or a whole bus, from any process,
//! through ussd's stop socket ([`uss_shm_types::names::stop_socket`]): a path of their own,
//! with no iceoryx2 port to run out of and no heartbeat to depend on. They override the drive's
//! controller and latch: the drive gets the command until its controller re-arms it (OFF1,
//! then ON), and the controller's next call fails with [`ClientError::Tripped`].

use crate::{Bus, ClientError};
use core::time::Duration;
use std::io::{ErrorKind, Read as _, Write as _};
use std::os::unix::net::UnixStream;
use uss_shm_types::{
    ALL_DRIVES, Address, CommandError, LatchReason, OPERATOR_RESPONSE_BYTES, OperatorRequest,
    OperatorResponse, PzdInput, StopCommand,
};
use uss_shm_types::{StopBoard, names};

/// When this bus handle last sent each drive a stop (`CLOCK_MONOTONIC` ns, 0: never), for
/// [`Bus::wait_stopped`] to confirm that stop.
#[derive(Debug, Default)]
pub(crate) struct StopsSent([std::sync::atomic::AtomicU64; 32]);

impl StopsSent {
    /// A stop goes out now to `address` (`None`: every drive).
    fn mark(&self, address: Option<Address>) {
        use std::sync::atomic::Ordering;
        let now = crate::monotonic_ns();
        match address {
            Some(a) => self.0[usize::from(a.get())].store(now, Ordering::Relaxed),
            None => self.0.iter().for_each(|t| t.store(now, Ordering::Relaxed)),
        }
    }

    fn get(&self, address: Address) -> u64 {
        self.0[usize::from(address.get())].load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// `sent_ns`, a moment of this process's clock, on ussd's (the clock of the latch ids), as a
/// lower bound for the latch a stop sent then makes, by ussd's heartbeat `(its time stamp, when
/// this process read it)`: the same moment when the two clocks are one (the heartbeat read
/// within a second of its stamp), else moved by the offset the heartbeat shows (a process in a
/// time namespace of its own), which errs early by the heartbeat's age at most. 0 stays 0 (any
/// latch).
fn on_ussd_clock(sent_ns: u64, (beat_ns, read_ns): (u64, u64)) -> u64 {
    if sent_ns == 0 {
        return 0;
    }
    let behind = i128::from(read_ns) - i128::from(beat_ns);
    if (0..=1_000_000_000).contains(&behind) {
        sent_ns
    } else {
        uss_shm_types::on_latch_clock(sent_ns, beat_ns, read_ns)
    }
}

/// How long ussd may take to answer an operator command.
const COMMAND_TIMEOUT: Duration = Duration::from_secs(2);

impl Bus {
    /// Stops drive `address` with `command` (OFF1 ramp, OFF2 coast, OFF3 quick stop), whoever
    /// controls it. Returns once ussd has handed the command to the bus thread, which sends it
    /// in its next telegram; [`Bus::wait_stopped`] waits until the drive's image shows it.
    pub fn stop_drive(&self, address: Address, command: StopCommand) -> Result<(), ClientError> {
        self.stops_sent.mark(Some(address));
        match self.operator(address.get(), command) {
            Err(ClientError::CommandRefused {
                error: CommandError::UnknownDrive,
                ..
            }) => Err(self.unknown_drive(address)),
            other => other.map(|_| ()),
        }
    }

    /// Stops every drive of the bus with `command`; returns their addresses.
    pub fn stop_all(&self, command: StopCommand) -> Result<Vec<Address>, ClientError> {
        self.stops_sent.mark(None);
        self.operator(ALL_DRIVES, command)
    }

    /// Waits until drive `address` got a stop command at least as strong as `command` from an
    /// operator (its input image shows the override and the control word that went out) and
    /// returns that image. `timeout` `None` waits the drive's own time for it
    /// ([`crate::DriveWatch::handshake`]: its turn in the circulating list, or its next probe
    /// while offline, and the poll).
    ///
    /// After a stop of this bus handle ([`Bus::stop_drive`], [`Bus::stop_all`]) it is that
    /// stop it confirms, as [`Bus::wait_stopped_since`] with the moment it was sent: a drive
    /// that showed an as strong stop of an older latch already (ussd latches the new stop anew
    /// at the drive's next poll) is waited for until it shows the new one.
    pub fn wait_stopped(
        &self,
        address: Address,
        command: StopCommand,
        timeout: Option<Duration>,
    ) -> Result<PzdInput, ClientError> {
        let sent = self.stops_sent.get(address);
        self.wait_stopped_since(address, command, sent, timeout)
    }

    /// [`Bus::wait_stopped`] for a stop sent at `sent_ns` ([`crate::monotonic_ns`] taken just
    /// before it was sent, 0 for any): the image's latch must have begun at or after it, so
    /// it is that stop's (or a later one's), never an older latch that shows as strong a stop.
    /// For a stop sent without this handle (`uss_client::stop`, another process).
    pub fn wait_stopped_since(
        &self,
        address: Address,
        command: StopCommand,
        sent_ns: u64,
        timeout: Option<Duration>,
    ) -> Result<PzdInput, ClientError> {
        let watch = self.watch(address)?;
        let wanted = format!("{command} applied");
        let since = on_ussd_clock(sent_ns, self.link().ussd_clock());
        let shown = |i: &PzdInput| {
            i.latch_reason == LatchReason::Override.code()
                && i.latch_id >= since
                && StopCommand::of_code(i.latch_command).is_some_and(|got| {
                    got.strength() >= command.strength() && got.stw1() == i.sent_stw1
                })
        };
        let last = match timeout {
            Some(timeout) => watch.wait_for(timeout, &wanted, shown),
            None => watch.wait_polled(&wanted, shown),
        }?;
        if last.word_count > 0
            && !uss_protocol::Zsw1::from_bits_retain(last.zsw1)
                .contains(uss_protocol::Zsw1::CONTROL_REQUESTED)
        {
            return Err(ClientError::NotControllable {
                bus: self.link().name.to_string(),
                address: address.get(),
                command: command.to_string(),
                zsw1: last.zsw1,
                setting: uss_catalogue::Catalogue::of(self.family(address))
                    .and_then(uss_catalogue::Catalogue::command_source_setting),
            });
        }
        Ok(last)
    }

    fn operator(&self, address: u8, command: StopCommand) -> Result<Vec<Address>, ClientError> {
        send_stop(&self.link().name, address, command)
    }
}

/// Stops drive `address` (`None`: every drive) of bus `bus` with `command`, whoever controls
/// it, through ussd's stop socket alone: no [`Bus`] is opened, so neither the heartbeat nor the
/// services' port limits (many clients at once) stand in the way. Returns the drives that got
/// it; the bus thread sends it in its next telegram, latched. What a tool calls first when the
/// machine must stop; [`Bus::wait_stopped`] confirms it where the images can be read.
pub fn stop(
    bus: &str,
    address: Option<Address>,
    command: StopCommand,
) -> Result<Vec<Address>, ClientError> {
    let name = uss_shm_types::BusName::new(bus)?;
    send_stop(&name, address.map_or(ALL_DRIVES, Address::get), command)
}

/// Connections to the stop socket a stop tries when ussd closes one without an answer (a flood
/// of idle connections made it make room): a stop is answered or fails for a reason, never lost
/// quietly.
const STOP_TRIES: usize = 3;

/// One request on bus `bus`'s stop socket and its answer.
fn send_stop(
    bus: &uss_shm_types::BusName,
    address: u8,
    command: StopCommand,
) -> Result<Vec<Address>, ClientError> {
    // Who may reach ussd: the root's access rules, said as for every other path.
    crate::open::iceoryx_config(bus.as_str())?;
    let path = names::stop_socket(bus);
    let mut tries = 0;
    let bytes = loop {
        tries += 1;
        match stop_once(bus, &path, OperatorRequest::new(address, command)) {
            Ok(bytes) => break bytes,
            // Closed before it answered: ussd made room for another connection, or it ended
            // (then the next connect says it is not running).
            Err(Closed) if tries < STOP_TRIES => {}
            Err(Closed) => {
                return Err(ClientError::ipc(
                    "a stop command on ussd's stop socket",
                    format!(
                        "ussd closed the connection without an answer {STOP_TRIES} times: it serves \
                         too many connections at once (idle ones of other processes)"
                    ),
                ));
            }
            Err(Failed(e)) => return Err(e),
        }
    };
    let response = OperatorResponse::from_bytes(&bytes)
        .ok_or_else(|| ClientError::ipc("ussd's answer to a stop command", "bad length"))?;
    response.check_version()?;
    match response.error() {
        Ok(CommandError::Ok) => Ok(response.addresses().collect()),
        Ok(error) => Err(ClientError::CommandRefused {
            bus: bus.as_str().to_owned(),
            error,
        }),
        Err(e) => Err(uss_shm_types::ContractError::from(e).into()),
    }
}

/// Why one try on the stop socket did not bring an answer.
enum StopTry {
    /// ussd closed (or reset) the connection before it answered.
    Closed,
    Failed(ClientError),
}
use StopTry::{Closed, Failed};

/// A connection to the stop socket at `path`. When its queue is full (a storm of connections
/// of other processes: connect(2) would wait behind them), `request` goes onto the bus's stop
/// board first, which no queue holds back, and then the connection is waited for as always
/// (its answer, and the process it names).
fn connect(
    bus: &uss_shm_types::BusName,
    path: &std::path::Path,
    request: OperatorRequest,
) -> std::io::Result<UnixStream> {
    use nix::sys::socket::{AddressFamily, SockFlag, SockType, UnixAddr, socket};
    let fd = socket(
        AddressFamily::Unix,
        SockType::Stream,
        SockFlag::SOCK_NONBLOCK | SockFlag::SOCK_CLOEXEC,
        None,
    )?;
    let at_once =
        nix::sys::socket::connect(std::os::fd::AsRawFd::as_raw_fd(&fd), &UnixAddr::new(path)?);
    match at_once {
        Ok(()) => {
            let stream = UnixStream::from(fd);
            stream.set_nonblocking(false)?;
            Ok(stream)
        }
        Err(nix::errno::Errno::EAGAIN) => {
            // A board that cannot be reached changes nothing: the socket still takes the stop.
            let _ = post_to_board(bus, request);
            UnixStream::connect(path)
        }
        Err(e) => Err(e.into()),
    }
}

/// Adds `request` to bus `bus`'s stop board (`uss_shm_types::StopBoard`): one atomic add to
/// its counter in the mapped file.
fn post_to_board(bus: &uss_shm_types::BusName, request: OperatorRequest) -> std::io::Result<()> {
    use nix::sys::mman::{MapFlags, ProtFlags, mmap, munmap};
    use std::sync::atomic::{AtomicU32, Ordering};
    let invalid = |what: &str| std::io::Error::new(ErrorKind::InvalidInput, what.to_owned());
    let command = request.validate().map_err(|_| invalid("not a stop"))?;
    let at = StopBoard::offset(request.address, command).ok_or_else(|| invalid("no such drive"))?;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(names::stop_board(bus))?;
    if file.metadata()?.len() < StopBoard::BYTES as u64 {
        return Err(invalid("the stop board is shorter than its layout"));
    }
    let len = core::num::NonZeroUsize::new(StopBoard::BYTES).ok_or_else(|| invalid("empty"))?;
    // SAFETY: a new shared mapping of the board's first BYTES bytes (the file is at least that
    // long, checked above); it aliases nothing of this process and is unmapped below.
    let map = unsafe {
        mmap(
            None,
            len,
            ProtFlags::PROT_READ | ProtFlags::PROT_WRITE,
            MapFlags::MAP_SHARED,
            &file,
            0,
        )
    }?;
    // SAFETY: `at + 4 <= BYTES` and `at` is a multiple of 4, so counter `at / 4` of the
    // page-aligned mapping is in bounds and aligned for `AtomicU32` (a `u32`'s layout); every process
    // touches these bytes only atomically (ussd reads them with pread).
    let counter = unsafe { &*map.as_ptr().cast::<AtomicU32>().add(at / 4) };
    counter.fetch_add(1, Ordering::SeqCst);
    // SAFETY: the mapping made above, of `len` bytes; `counter` is not used after this.
    unsafe { munmap(map, len.get()) }?;
    Ok(())
}

/// One connection to the stop socket at `path`: `request` written, the answer's bytes read.
fn stop_once(
    bus: &uss_shm_types::BusName,
    path: &std::path::Path,
    request: OperatorRequest,
) -> Result<[u8; OPERATOR_RESPONSE_BYTES], StopTry> {
    let mut stream = match connect(bus, path, request) {
        Ok(s) => s,
        Err(e) if matches!(e.kind(), ErrorKind::NotFound | ErrorKind::ConnectionRefused) => {
            return Err(Failed(ClientError::not_running(bus.as_str().to_owned())));
        }
        Err(e) => {
            return Err(Failed(ClientError::ipc(
                "connecting to ussd's stop socket",
                e,
            )));
        }
    };
    let failed = |e: std::io::Error| match e.kind() {
        ErrorKind::UnexpectedEof | ErrorKind::ConnectionReset | ErrorKind::BrokenPipe => Closed,
        ErrorKind::WouldBlock | ErrorKind::TimedOut => Failed(ClientError::ipc(
            "waiting for ussd's answer to a stop command",
            format!("{} {COMMAND_TIMEOUT:?}", crate::error::NO_ANSWER),
        )),
        _ => Failed(ClientError::ipc("a stop command on ussd's stop socket", e)),
    };
    stream
        .set_read_timeout(Some(COMMAND_TIMEOUT))
        .and_then(|()| stream.set_write_timeout(Some(COMMAND_TIMEOUT)))
        .and_then(|()| stream.write_all(&request.to_bytes()))
        .map_err(failed)?;
    let mut bytes = [0u8; OPERATOR_RESPONSE_BYTES];
    stream.read_exact(&mut bytes).map_err(failed)?;
    Ok(bytes)
}
