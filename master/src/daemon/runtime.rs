//! Running buses: for each configured bus an engine on its transport in its own real-time
//! thread, its parameter bridge, its line thread (a serial bus) and its housekeeping thread
//! ([`super::housekeeping`]) (docs/ARCHITECTURE.md, "Data flow" and "Real-time setup").
//!
//! Start-up order matters: every engine (and so every buffer and channel) is built and its bus,
//! parameter and line threads spawned first; only then do the bus threads pin, raise their
//! priority, prefault and lock memory. The housekeeping threads are spawned after that (they
//! need each bus's real-time report): safe because memory is locked only where no limit applies
//! (memlock unlimited or `CAP_IPC_LOCK`, [`uss_realtime`]), so a later thread or mapping
//! cannot fail on it.

use crate::config::RxLatencyMs;
use crate::config::{BusConfig, Cpu, Device};
use crate::daemon::ipc::StatusPublisher;
use crate::daemon::line::{Line, LineKind, NotOpened, SerialLine, TcpLine};
use core::time::Duration;
use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, bounded};
use std::fmt::Write as _;
use std::thread::JoinHandle;
use thiserror::Error;
#[cfg(feature = "sim")]
use uss_drive_sim::{BusError, SimBus, SimTransport, VirtualWire};
use uss_engine::monitoring::{MonitoringSetup, WatchedParam};
use uss_engine::{
    DriveSetup, Engine, EngineConfig, EngineHandle, Event, MonotonicClock, Transport,
    TransportError,
};
use uss_protocol::Timing;
use uss_realtime::{RtReport, RtRequest, apply_to_current_thread};

/// Parameter jobs each drive can hold.
const MAILBOX_DEPTH: usize = 64;
/// Stack prefaulted in each bus thread.
const PREFAULT_STACK: usize = 256 * 1024;

/// How buses are run.
#[derive(Debug, Clone, Copy)]
pub struct RunOptions {
    /// Refuse to run without full real-time (pinning, `SCHED_FIFO`, memory lock where allowed).
    pub require_rt: bool,
    /// How often the summary is logged.
    pub summary_every: Duration,
}

/// A bus that could not start.
#[derive(Debug, Error)]
pub enum StartError {
    /// The bus's line is there and cannot be used as configured (its kind says why).
    #[error("bus {bus}: {source}")]
    Line {
        bus: String,
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[cfg(feature = "sim")]
    #[error("bus {bus}: simulated bus: {source}")]
    Sim { bus: String, source: BusError },
    /// Only for a configuration that did not go through `Config::parse`'s rules.
    #[cfg(feature = "sim")]
    #[error("bus {bus}: simulated drive {address}: {problem}")]
    SimDrive {
        bus: String,
        address: u8,
        problem: String,
    },
    /// Only when a `Device::Sim` is built by hand: the configuration refuses `device = "sim"`
    /// in a build without the simulator.
    #[cfg(not(feature = "sim"))]
    #[error("bus {bus}: this ussd was built without the simulated bus (the `sim` feature)")]
    NoSim { bus: String },
    /// `summary`: each failed step on a line of its own.
    #[error(
        "bus {bus}: real-time set-up incomplete and --require-rt given, so nothing was polled:{summary}\n  \
         run ussd as the packaged unit does (LimitRTPRIO=95, LimitMEMLOCK=infinity), or without \
         --require-rt to run best effort; `ussd --qualify` measures what this machine holds"
    )]
    RealTime { bus: String, summary: String },
    #[error(transparent)]
    Ipc(#[from] crate::daemon::ipc::IpcError),
    #[error("bus {bus}: cannot start its threads: {source}")]
    Spawn { bus: String, source: std::io::Error },
}

/// The engine settings for a configured bus.
pub fn engine_config(bus: &BusConfig) -> EngineConfig {
    EngineConfig {
        timing: Timing::new(bus.baud),
        response_timeout: bus.response_timeout_ms.get() + bus.timeout_margin_ms.get(),
        retries: bus.retries.get(),
        offline_after: bus.offline_after.get(),
        offline_probe: bus.offline_probe_ms.get(),
        cycle_time: bus.cycle_time_ms.period(),
        param_timeout: bus.param_timeout_ms.get(),
        echo: bus.echo,
        mailbox_depth: MAILBOX_DEPTH,
        publish_every: super::housekeeping::STATUS_EVERY,
        param_priority: bus.param_priority,
        safety_first: true,
        // Set where the line is known (`spawn`): configured, or from sysfs.
        rx_latency: bus.rx_latency_ms.map_or(Duration::ZERO, RxLatencyMs::get),
        capture: true,
        drives: bus
            .drives
            .iter()
            .map(|d| DriveSetup {
                address: d.address,
                layout: d.layout(),
                weight: d.weight.get(),
                safe: d.safe_command.command(),
                watchdog: d.watchdog_ms.get(),
                params_writable: d.params_writable,
                monitoring: MonitoringSetup {
                    param: d.monitoring_param().param().map(WatchedParam::from),
                    max: d.monitoring_max_ms.get(),
                    required: d.require_monitoring,
                },
                reference_hz: d.reference_hz.get(),
                reference_param: d.reference_param().param().map(WatchedParam::from),
                reference_unit: d.reference_unit(),
                rereads_after: uss_engine::picture::Rereads::of(
                    uss_catalogue::Catalogue::of(d.family)
                        .into_iter()
                        .flat_map(|c| c.rereads_after.iter().map(|p| p.pnu)),
                ),
                broadcast: d.broadcast,
                family: d.family,
            })
            .collect(),
    }
}

/// The simulated drives of a `device = "sim"` bus on the in-process virtual wire.
#[cfg(feature = "sim")]
pub fn sim_transport(bus: &BusConfig) -> Result<SimTransport, StartError> {
    let mut sim = SimBus::new(bus.seed());
    for d in &bus.drives {
        let spec = d.sim_spec().map_err(|problem| StartError::SimDrive {
            bus: bus.name.clone(),
            address: d.address.get(),
            problem,
        })?;
        sim.add(spec.config).map_err(|source| StartError::Sim {
            bus: bus.name.clone(),
            source,
        })?;
        if let Some(plan) = sim.faults_mut(spec.config.address) {
            *plan = spec.faults;
        }
    }
    let wire = VirtualWire::new(sim, Timing::new(bus.baud)).with_echo(bus.echo);
    Ok(SimTransport::new(wire))
}

/// What one look for dead client nodes did ([`RunningBus::cleanup_dead_nodes`]).
#[derive(Debug, Default, PartialEq, Eq)]
pub struct Cleanup {
    /// Dead nodes removed.
    pub removed: usize,
    /// The dead nodes still there after the cleanup: id, and the process id of the process that
    /// made it (none: its details are gone).
    pub left: Vec<(u128, Option<u32>)>,
}

/// A running bus.
#[derive(Debug)]
pub struct RunningBus {
    pub name: String,
    pub handle: EngineHandle,
    pub rt_report: RtReport,
    /// How long its bus thread may go without progress before it counts as hung
    /// ([`crate::daemon::supervise::stall_bound`]).
    pub stall_bound: Duration,
    /// How long its line may stay down before ussd counts as unhealthy (`None`: a simulated
    /// bus, or `line_down_limit_ms = 0`).
    pub line_down_limit: Option<Duration>,
    engine_thread: JoinHandle<Result<(), TransportError>>,
    params_thread: JoinHandle<()>,
    /// Reopens a serial line that failed (none for a simulated bus).
    line_thread: Option<JoinHandle<()>>,
    housekeeping: JoinHandle<()>,
    /// Operator stops on a path of their own (`crate::daemon::stops`).
    _stops: super::stops::StopSocket,
    /// The bus's iceoryx2 node: dropped last, after every thread using its ports.
    node: crate::daemon::ipc::IpcNode,
}

impl RunningBus {
    /// Removes what dead client processes left behind (ports, nodes), and says what it really
    /// removed: iceoryx2 0.10 counts a dead node whose details are gone as cleaned on every
    /// call, though it looks for its monitor in its global configuration, not ours, and removes
    /// nothing. A dead controller's drive has already got its safe command through the watchdog.
    /// Every bus of a ussd shares one root, so one bus's look serves them all. `None`: the
    /// nodes could not be listed, so this look says nothing.
    pub fn cleanup_dead_nodes(&self) -> Option<Cleanup> {
        let before = self.dead_nodes()?;
        if before.is_empty() {
            return Some(Cleanup::default());
        }
        let _ = self.node.try_cleanup_dead_nodes();
        let left = self.dead_nodes()?;
        Some(Cleanup {
            removed: before
                .iter()
                .filter(|(id, _)| !left.iter().any(|(l, _)| l == id))
                .count(),
            left,
        })
    }

    /// The dead nodes below this node's root: id, and the process id its details name; `None`
    /// when they cannot be listed.
    fn dead_nodes(&self) -> Option<Vec<(u128, Option<u32>)>> {
        let nodes = crate::daemon::ipc::listed_nodes(self.node.config())?;
        Some(
            nodes
                .into_iter()
                .filter(|&(_, dead, _)| dead)
                .map(|(id, _, pid)| (id.value(), (pid != 0).then_some(pid)))
                .collect(),
        )
    }

    /// Whether the bus thread has ended without being asked to (it cannot go on: a simulated
    /// bus whose wire failed, or a line nobody can reopen). A serial line that fails does not
    /// end it: the bus waits, line down, until its line thread reopened the device.
    pub fn has_failed(&self) -> bool {
        self.engine_thread.is_finished() && !self.handle.is_stopped()
    }

    /// How many steps its bus thread has made ([`EngineHandle::progress`]).
    pub fn progress(&self) -> u64 {
        self.handle.progress()
    }

    /// Stops the engine (pending jobs end with "shutdown", each drive gets its safe command
    /// once) and waits for its threads; the housekeeping thread logs the final summary. A bus
    /// thread that does not end within its stall bound (plus a second) hangs: it is left
    /// behind (it ends with the process) and reported.
    pub fn stop(self) -> Result<(), StopError> {
        self.handle.stop();
        let deadline = std::time::Instant::now() + self.stall_bound + Duration::from_secs(1);
        while !self.engine_thread.is_finished() {
            if std::time::Instant::now() >= deadline {
                return Err(StopError::Hung(self.stall_bound + Duration::from_secs(1)));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let result = self.engine_thread.join().unwrap_or(Ok(()));
        let _ = self.params_thread.join();
        if let Some(line) = self.line_thread {
            let _ = line.join();
        }
        let _ = self.housekeeping.join();
        result.map_err(StopError::Line)
    }
}

/// Why a bus did not stop cleanly.
#[derive(Debug, Error)]
pub enum StopError {
    #[error("{0}")]
    Line(#[from] TransportError),
    #[error(
        "its bus thread hangs (no end within {0:?} of the stop): its drives got no safe command \
         from ussd; their telegram monitoring (P2014) stops them"
    )]
    Hung(Duration),
}

/// A bus whose engine thread is spawned and waits for the go signal.
struct Spawned {
    bus: BusConfig,
    handle: EngineHandle,
    reports: Receiver<RtReport>,
    thread: JoinHandle<Result<(), TransportError>>,
    params_thread: JoinHandle<()>,
    line_thread: Option<JoinHandle<()>>,
    events: Receiver<Event>,
    status: StatusPublisher,
    node: crate::daemon::ipc::IpcNode,
}

/// How a bus thread gets its line back after it failed: it hands what held the device to the
/// line thread (which closes it, then reopens), then waits for the new transport, checking for
/// a stop now and then.
struct Reopen<T> {
    ask: Sender<Option<T>>,
    /// The transport and its receive latency.
    reopened: Receiver<(T, Duration)>,
    /// Gives up the failed line's device ([`Line::release`]).
    release: fn(&mut T) -> Option<T>,
}

/// Runs `engine` until it is stopped; when its line fails, releases the device and waits (line
/// down, allocating nothing) for a reopened transport and resumes. Without `reopen` a failed
/// line ends the bus.
fn run_bus<T: Transport, C: uss_engine::clock::Clock, B: uss_engine::Bridge>(
    engine: &mut Engine<T, C, B>,
    handle: &EngineHandle,
    reopen: Option<&Reopen<T>>,
) -> Result<(), TransportError> {
    loop {
        let Err(error) = engine.run() else {
            return Ok(());
        };
        let Some(reopen) = reopen else {
            return Err(error);
        };
        // The old descriptor goes first: while it is open the device's exclusive lock refuses
        // the reopen, and a USB adapter's minor stays taken.
        let _ = reopen
            .ask
            .try_send((reopen.release)(engine.transport_mut()));
        loop {
            if handle.is_stopped() {
                return engine.shutdown();
            }
            handle.note_progress();
            match reopen.reopened.recv_timeout(uss_engine::IDLE_STEP) {
                Ok((transport, rx_latency)) => {
                    engine.restore(transport, rx_latency);
                    break;
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => return Err(error),
            }
        }
    }
}

/// The first wait before reopening a failed line, and the longest (it doubles in between).
const REOPEN_FIRST: Duration = Duration::from_millis(100);
const REOPEN_MAX: Duration = Duration::from_secs(5);

/// A device opened again: its transport, a report for the log, and the receive latency of the
/// device as it is now (detected on every open: a replug may bring another adapter).
struct Reopened<T> {
    transport: T,
    report: String,
    rx_latency: Duration,
}

/// Opens a bus's device again, or says why not.
type Opener<T> = Box<dyn FnMut() -> Result<Reopened<T>, String> + Send>;

/// How a failed line of a serial bus is given up and opened again.
struct Reopening<T> {
    /// The line as configured (a device's path, reopened by name: a replugged adapter).
    device: String,
    open: Opener<T>,
    /// Gives up the failed line's device ([`Line::release`]).
    release: fn(&mut T) -> Option<T>,
}

/// The line thread of a serial bus: on each ask, closes what held the device, reopens `device`
/// by its configured path with backoff until it opens (or the bus stops) and hands the
/// transport to the bus thread. Not real-time: closing and opening a device allocate and may
/// block.
fn spawn_line<T: Send + 'static>(
    bus: &BusConfig,
    device: String,
    mut open: Opener<T>,
    handle: EngineHandle,
    asks: Receiver<Option<T>>,
    reopened: Sender<(T, Duration)>,
) -> std::io::Result<JoinHandle<()>> {
    let name = bus.name.clone();
    std::thread::Builder::new()
        .name(format!("uss-{}-line", bus.name))
        .spawn(move || {
            while let Ok(old) = asks.recv() {
                let closing = std::time::Instant::now();
                drop(old);
                if closing.elapsed() > Duration::from_secs(1) {
                    tracing::warn!(
                        bus = %name,
                        device = %device,
                        "closing the failed line took {:.1} s (its driver waited for output)",
                        closing.elapsed().as_secs_f64()
                    );
                }
                let Some(transport) = reopen_with_backoff(&name, &device, &mut open, &handle)
                else {
                    return;
                };
                if reopened.send(transport).is_err() {
                    return;
                }
            }
        })
}

/// Tries to open the device after 0.1 s, 0.2 s, ... up to every 5 s, until it opens or the bus
/// stops (`None`).
fn reopen_with_backoff<T>(
    bus: &str,
    device: &str,
    open: &mut Opener<T>,
    handle: &EngineHandle,
) -> Option<(T, Duration)> {
    let started = std::time::Instant::now();
    let mut delay = REOPEN_FIRST;
    let mut attempts = 0u32;
    loop {
        if !sleep_unless_stopped(handle, delay) {
            return None;
        }
        attempts += 1;
        handle.note_reopen_attempt();
        match open() {
            Ok(Reopened {
                transport,
                report,
                rx_latency,
            }) => {
                tracing::info!(
                    bus,
                    device,
                    attempts,
                    down_s = started.elapsed().as_secs_f64(),
                    "line reopened after {attempts} attempts: {report}"
                );
                return Some((transport, rx_latency));
            }
            Err(e) => {
                // The first failure, then one line a minute or so: the status has the count.
                if attempts == 1 || attempts.is_multiple_of(12) {
                    tracing::warn!(
                        bus,
                        device,
                        attempts,
                        "cannot reopen the line yet ({e}); retrying, at most every {} s",
                        REOPEN_MAX.as_secs()
                    );
                }
                delay = (delay * 2).min(REOPEN_MAX);
            }
        }
    }
}

/// Sleeps `d` in steps of 50 ms; `false` as soon as the bus is asked to stop.
fn sleep_unless_stopped(handle: &EngineHandle, d: Duration) -> bool {
    let end = std::time::Instant::now() + d;
    loop {
        if handle.is_stopped() {
            return false;
        }
        let left = end.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            return true;
        }
        std::thread::sleep(left.min(Duration::from_millis(50)));
    }
}

/// Builds one engine and spawns its thread. The thread waits on `go` before its real-time set-up
/// and exits at once if `go` is dropped instead (another bus failed to start). With `line`
/// (a serial bus: its device and how to open it), a line thread reopens the device when it
/// fails.
fn spawn<T: Transport + Send + 'static>(
    bus: &BusConfig,
    transport: T,
    options: RunOptions,
    go: &Receiver<()>,
    line: Option<Reopening<T>>,
    rx_latency: Duration,
) -> Result<Spawned, StartError> {
    let clock = MonotonicClock::new();
    let config = EngineConfig {
        rx_latency,
        ..engine_config(bus)
    };
    let ipc = crate::daemon::ipc::create(&bus.name, &config.drives, clock.origin())?;
    let (mut engine, handle, events) = Engine::with_bridge(config, transport, clock, ipc.rt);
    let mut params = ipc.params;
    for d in &bus.drives {
        if let Some(writable) = d.writable() {
            params.limit_writes(d.address, writable);
        }
    }
    let params_handle = handle.clone();
    let params_thread = std::thread::Builder::new()
        .name(format!("uss-{}-params", bus.name))
        .spawn(move || params.run(&params_handle))
        .map_err(|source| StartError::Spawn {
            bus: bus.name.clone(),
            source,
        })?;
    let request = RtRequest {
        cpu: bus.cpu.map(Cpu::get),
        priority: bus.priority.get(),
        lock_memory: true,
        prefault_stack_bytes: PREFAULT_STACK,
    };
    let (report_tx, reports) = bounded(1);
    let go = go.clone();
    let require_rt = options.require_rt;
    let spawn_error = |source| StartError::Spawn {
        bus: bus.name.clone(),
        source,
    };
    let (reopen, line_thread) = match line {
        Some(Reopening {
            device,
            open,
            release,
        }) => {
            let (ask, asks) = bounded(1);
            let (give, reopened) = bounded(1);
            let thread =
                spawn_line(bus, device, open, handle.clone(), asks, give).map_err(spawn_error)?;
            let reopen = Reopen {
                ask,
                reopened,
                release,
            };
            (Some(reopen), Some(thread))
        }
        None => (None, None),
    };
    let bus_handle = handle.clone();
    let thread = std::thread::Builder::new()
        .name(format!("uss-{}", bus.name))
        .stack_size(PREFAULT_STACK * 4)
        .spawn(move || {
            if go.recv().is_err() {
                return Ok(());
            }
            let report = apply_to_current_thread(&request);
            let proceed = report.is_full_rt() || !require_rt;
            let _ = report_tx.send(report);
            if !proceed {
                return Ok(());
            }
            // Wake-ups as precise as the kernel allows (the default slack is 50 us).
            let _ = nix::sys::prctl::set_timerslack(1);
            run_bus(&mut engine, &bus_handle, reopen.as_ref())
        })
        .map_err(|source| StartError::Spawn {
            bus: bus.name.clone(),
            source,
        })?;
    Ok(Spawned {
        bus: bus.clone(),
        handle,
        reports,
        thread,
        params_thread,
        line_thread,
        events,
        status: ipc.status,
        node: ipc.node,
    })
}

fn open_and_spawn(
    bus: &BusConfig,
    options: RunOptions,
    go: &Receiver<()>,
) -> Result<Spawned, StartError> {
    match &bus.device {
        #[cfg(feature = "sim")]
        Device::Sim => {
            let t = sim_transport(bus)?;
            spawn(bus, t, options, go, None, Duration::ZERO)
        }
        #[cfg(not(feature = "sim"))]
        Device::Sim => Err(StartError::NoSim {
            bus: bus.name.clone(),
        }),
        Device::Serial(path) => spawn_on_line(bus, options, go, SerialLine::new(bus, path)),
        Device::Tcp(address) => spawn_on_line(bus, options, go, TcpLine::new(bus, address)),
    }
}

/// Opens a bus's line of any kind and spawns its threads, with a line thread that opens it
/// again when it fails. A line not there yet starts the bus line down (its line thread opens it
/// when it appears); one that is there and refused stops ussd's start.
fn spawn_on_line<K: LineKind>(
    bus: &BusConfig,
    options: RunOptions,
    go: &Receiver<()>,
    mut kind: K,
) -> Result<Spawned, StartError> {
    let name = kind.name();
    let transport = match kind.open() {
        Ok(opened) => {
            tracing::info!(bus = %bus.name, device = %name, "opened: {}", opened.report);
            Line::Open(opened.transport)
        }
        Err(NotOpened::NotThere(why)) => {
            tracing::warn!(
                bus = %bus.name,
                device = %name,
                "{why}: the bus starts line down and opens it when it appears"
            );
            Line::Absent
        }
        Err(NotOpened::Refused(source)) => {
            return Err(StartError::Line {
                bus: bus.name.clone(),
                source,
            });
        }
    };
    let rx_latency = kind.rx_latency(&bus.name);
    let bus_name = bus.name.clone();
    let open: Opener<Line<K::Transport>> = Box::new(move || {
        let opened = kind.open().map_err(|e| e.to_string())?;
        Ok(Reopened {
            transport: Line::Open(opened.transport),
            report: opened.report,
            // Read again: the device absent at start, or replugged into another adapter, a
            // connection over another route, is not what it was.
            rx_latency: kind.rx_latency(&bus_name),
        })
    });
    let line = Reopening {
        device: name,
        open,
        release: K::release,
    };
    spawn(bus, transport, options, go, Some(line), rx_latency)
}

fn abandon(spawned: Vec<Spawned>, go: Sender<()>) {
    drop(go);
    for s in spawned {
        s.handle.stop();
        let _ = s.thread.join();
        let _ = s.params_thread.join();
        if let Some(line) = s.line_thread {
            let _ = line.join();
        }
    }
}

/// Starts every bus of the configuration.
pub fn start(buses: &[BusConfig], options: RunOptions) -> Result<Vec<RunningBus>, StartError> {
    let (go_tx, go_rx) = bounded(buses.len());
    let mut spawned = Vec::new();
    for bus in buses {
        match open_and_spawn(bus, options, &go_rx) {
            Ok(s) => spawned.push(s),
            Err(e) => {
                abandon(spawned, go_tx);
                return Err(e);
            }
        }
    }
    // Every buffer, port and thread exists: now the bus threads may lock memory.
    for _ in buses {
        let _ = go_tx.send(());
    }
    let mut running = Vec::new();
    let mut failure = None;
    for s in spawned {
        let Ok(rt_report) = s.reports.recv() else {
            failure.get_or_insert(StartError::RealTime {
                bus: s.bus.name.clone(),
                summary: "\n  the bus thread ended before its real-time set-up".into(),
            });
            abandon(vec![s], bounded(0).0);
            continue;
        };
        if rt_report.is_full_rt() {
            tracing::info!(bus = %s.bus.name, mode = rt_report.mode(), "{}", rt_report.summary());
        } else if options.require_rt {
            // Its thread polled nothing: no warning that it runs, no summary of it; the
            // failure says what failed, once.
            failure.get_or_insert(StartError::RealTime {
                bus: s.bus.name.clone(),
                summary: rt_report.failures.iter().fold(String::new(), |mut all, f| {
                    let _ = write!(all, "\n  {f}");
                    all
                }),
            });
            abandon(vec![s], bounded(0).0);
            continue;
        } else {
            tracing::warn!(bus = %s.bus.name, mode = rt_report.mode(), "real-time set-up incomplete, running best effort: {}", rt_report.summary());
        }
        warn_unverified_references(&s.bus);
        let mut status = s.status;
        status.set_rt(rt_report.is_full_rt(), rt_report.cpu, rt_report.priority);
        let housekeeping = super::housekeeping::spawn(
            &s.bus,
            s.handle.clone(),
            s.events,
            status,
            rt_report.mode(),
            options.summary_every,
        )
        .map_err(|source| StartError::Spawn {
            bus: s.bus.name.clone(),
            source,
        })?;
        let stops = uss_shm_types::BusName::new(&s.bus.name)
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e.to_string()))
            .and_then(|name| {
                super::stops::StopSocket::serve(
                    &uss_shm_types::names::stop_socket(&name),
                    &uss_shm_types::names::stop_board(&name),
                    &s.bus.name,
                    s.handle.clone(),
                )
            })
            .map_err(|source| StartError::Spawn {
                bus: s.bus.name.clone(),
                source,
            })?;
        running.push(RunningBus {
            name: s.bus.name.clone(),
            handle: s.handle,
            rt_report,
            stall_bound: crate::daemon::supervise::stall_bound(&s.bus),
            line_down_limit: Some(s.bus.line_down_limit_ms.get())
                .filter(|d| s.bus.device.is_line() && !d.is_zero()),
            engine_thread: s.thread,
            params_thread: s.params_thread,
            line_thread: s.line_thread,
            housekeeping,
            _stops: stops,
            node: s.node,
        });
    }
    if let Some(e) = failure {
        for b in running {
            let _ = b.stop();
        }
        return Err(e);
    }
    Ok(running)
}

/// A drive whose reference is a speed (G120: p2000 in rpm) without its pole pairs: Hz are
/// scaled by `reference_hz` as configured, which nothing checks against the drive.
fn warn_unverified_references(bus: &BusConfig) {
    for d in &bus.drives {
        let speed = uss_catalogue::Catalogue::of(d.family).and_then(|c| c.reference_speed);
        if let Some(speed) = speed.filter(|_| d.reference_param().param().is_none()) {
            tracing::warn!(
                bus = %bus.name,
                drive = d.address.get(),
                "drive {}: its setpoint reference {speed} is a speed in rpm; Hz (run_hz, ussctl, the exporter) are scaled by reference_hz = {} as configured, unverified: set pole_pairs (2 for a 4-pole motor) and ussd reads {speed} and scales by {speed} x pole_pairs / 60, or use percent",
                d.address,
                d.reference_hz.get()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
    use uss_engine::clock::Clock;
    use uss_engine::transport::Rx;

    /// A device whose writes fail and whose close is observed: while it is open, it holds the
    /// device's exclusive lock, as a serial port does.
    struct Held {
        open: Arc<AtomicBool>,
    }

    impl Drop for Held {
        fn drop(&mut self) {
            self.open.store(false, Ordering::Release);
        }
    }

    impl Transport for Held {
        fn flush_input(&mut self, _now: Duration) -> Result<(), TransportError> {
            Ok(())
        }
        fn send(&mut self, _bytes: &[u8], _now: Duration) -> Result<Duration, TransportError> {
            Err(TransportError::Stalled)
        }
        fn recv(
            &mut self,
            deadline: Duration,
            clock: &mut impl Clock,
        ) -> Result<Option<Rx>, TransportError> {
            clock.sleep_until(deadline);
            Ok(None)
        }
    }

    fn bus() -> BusConfig {
        let toml = "[[bus]]\nname = \"held\"\ndevice = \"/dev/ttyUSB0\"\nbaud = 115200\n\n[[bus.drive]]\naddress = 1\n";
        crate::config::Config::parse(toml, "test")
            .unwrap()
            .buses
            .remove(0)
    }

    #[test]
    fn a_failed_line_is_closed_before_it_is_reopened() {
        let bus = bus();
        let open = Arc::new(AtomicBool::new(true));
        let transport = Line::Open(Held { open: open.clone() });
        let (mut engine, handle, _events) =
            Engine::new(engine_config(&bus), transport, MonotonicClock::new());
        // The reopen is refused as busy while the old descriptor is open, like serialport's
        // flock; once it is closed, the device opens (and fails again at once).
        let (refused, opened) = (Arc::new(AtomicU32::new(0)), Arc::new(AtomicU32::new(0)));
        let open_device: Opener<Line<Held>> = {
            let (old, refused, opened) = (open.clone(), refused.clone(), opened.clone());
            Box::new(move || {
                if old.load(Ordering::Acquire) {
                    refused.fetch_add(1, Ordering::Relaxed);
                    return Err("device is busy (opened exclusively by another process)".into());
                }
                opened.fetch_add(1, Ordering::Relaxed);
                let next = Arc::new(AtomicBool::new(true));
                Ok(Reopened {
                    transport: Line::Open(Held { open: next }),
                    report: "opened".into(),
                    rx_latency: Duration::ZERO,
                })
            })
        };
        let (ask, asks) = bounded(1);
        let (give, reopened) = bounded(1);
        let line = spawn_line(
            &bus,
            "/dev/ttyUSB0".into(),
            open_device,
            handle.clone(),
            asks,
            give,
        )
        .unwrap();
        let bus_handle = handle.clone();
        let thread = std::thread::spawn(move || {
            let reopen = Reopen {
                ask,
                reopened,
                release: Line::take,
            };
            run_bus(&mut engine, &bus_handle, Some(&reopen))
        });
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while opened.load(Ordering::Relaxed) < 2 {
            assert!(std::time::Instant::now() < deadline, "never reopened");
            std::thread::sleep(Duration::from_millis(10));
        }
        handle.stop();
        let _ = thread.join().unwrap();
        line.join().unwrap();
        assert!(!open.load(Ordering::Acquire), "the failed line was closed");
        assert_eq!(
            refused.load(Ordering::Relaxed),
            0,
            "no reopen found it open"
        );
    }
}
