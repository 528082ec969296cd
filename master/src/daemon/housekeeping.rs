//! A bus's housekeeping thread: logs the engine's events as they come, publishes status,
//! diagnostics and the heartbeat for clients, and logs the live and the final summary. Not
//! real-time: it may allocate, block and log.

use crate::config::{BusConfig, DriveEntry, ParamName};
use crate::daemon::ipc::StatusPublisher;
use core::time::Duration;
use crossbeam_channel::{Receiver, RecvTimeoutError};
use std::thread::JoinHandle;
use uss_catalogue::Catalogue;
use uss_engine::control::Latch;
use uss_engine::reference::Reference;
use uss_engine::stats::Stats;
use uss_engine::{EngineHandle, Event};
use uss_protocol::Address;
use uss_shm_types::{LatchReason, Monitoring, Rejection};

/// How often bus status, drive diagnostics and the heartbeat are published for clients: with
/// the engine's snapshot at most as old, what clients read is at most 100 ms old.
pub(super) const STATUS_EVERY: Duration =
    Duration::from_nanos(uss_shm_types::names::HEARTBEAT_PERIOD_NS);

/// How often captured telegrams are taken from the bus thread and published: a 187500-baud bus
/// captures about 700 telegrams per second, so a take holds at most a few dozen.
const CAPTURE_EVERY: Duration = Duration::from_millis(10);

/// How often the engine's statistics are looked at while a latch or re-arm waits to be
/// published: the engine publishes them at the end of the exchange that made the change, and
/// the diagnostics must not show a live drive for long after its image shows the latch.
const CHANGE_EVERY: Duration = Duration::from_millis(1);

/// Logs events as they come, publishes status and diagnostics every [`STATUS_EVERY`], and logs
/// the summary every `every`; logs the final summary when the engine has stopped. While the bus
/// thread hangs (no progress for its [`crate::daemon::supervise::stall_bound`]) it publishes nothing:
/// no heartbeat, so clients learn within half a second more that nobody serves the bus.
pub(super) fn spawn(
    bus: &BusConfig,
    handle: EngineHandle,
    events: Receiver<Event>,
    mut publisher: StatusPublisher,
    mode: &'static str,
    every: Duration,
) -> std::io::Result<JoinHandle<()>> {
    let bus = bus.clone();
    let stall_bound = crate::daemon::supervise::stall_bound(&bus);
    std::thread::Builder::new()
        .name(format!("uss-{}-hk", bus.name))
        .spawn(move || {
            let mut previous: Option<Stats> = None;
            log_shortest_monitoring(&bus, &handle.stats());
            let start = std::time::Instant::now();
            let mut progress = (handle.progress(), start);
            let mut next_summary = start + every;
            let mut next_status = start;
            // A latch or re-arm not published yet: when it happened (bus time). It is published
            // as soon as the engine's statistics hold it, not at the next period, so a stop is
            // not shown as a live drive for up to STATUS_EVERY more.
            let mut control_changed: Option<Duration> = None;
            loop {
                let next = next_summary.min(next_status);
                let wait = next.saturating_duration_since(std::time::Instant::now());
                // How long to wait at most: not `every`, the summary's period, which this
                // once shadowed (a summary every wake-up after the first, 2bfcf5b).
                let poll = if control_changed.is_some() {
                    CHANGE_EVERY
                } else {
                    CAPTURE_EVERY
                };
                match events.recv_timeout(wait.min(poll)) {
                    Ok(event) => {
                        if let Some(at) = control_change(&event) {
                            control_changed = Some(control_changed.map_or(at, |c| c.min(at)));
                        }
                        log_event(&bus, &event);
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => break,
                }
                // Taken without waiting on the channel: a waiting receiver would make the bus
                // thread's every send a wake-up (a system call) in the real-time loop.
                while let Ok(record) = handle.captures().try_recv() {
                    trace_telegram(&bus, &record);
                    publisher.capture(&record);
                }
                // After every wake-up: a burst of events must not hold back the heartbeat,
                // by which clients tell that ussd lives.
                let now = std::time::Instant::now();
                if handle.progress() != progress.0 {
                    progress = (handle.progress(), now);
                }
                let hangs = now.duration_since(progress.1) >= stall_bound;
                // Waited for without the statistics' lock, which would hold back the engine's
                // publication of them (it skips a publication while a reader holds them).
                if let Some(at) = control_changed
                    && !hangs
                    && handle.published_at() >= at
                {
                    // The statistics now are at least that publication (it only moves on).
                    publisher.publish(&handle.stats(), true, handle.reopen_attempts());
                    control_changed = None;
                }
                if now >= next_status {
                    if !hangs {
                        publisher.publish(&handle.stats(), true, handle.reopen_attempts());
                    }
                    next_status = (next_status + STATUS_EVERY).max(now);
                }
                if now >= next_summary {
                    let stats = handle.stats();
                    tracing::info!(
                        "\n{}",
                        crate::daemon::summary::render(&bus, mode, &stats, previous.as_ref())
                            .trim_end()
                    );
                    previous = Some(stats);
                    next_summary = (next_summary + every).max(now);
                }
            }
            let stats = handle.stats();
            publisher.publish(&stats, false, handle.reopen_attempts());
            publisher.goodbye();
            tracing::info!(
                "final\n{}",
                crate::daemon::summary::render(&bus, mode, &stats, None).trim_end()
            );
        })
}

/// When `event` changed a drive's control (a latch, a re-arm) or what clients scale and judge
/// it by (its reference, its telegram monitoring), on the bus's clock.
fn control_change(event: &Event) -> Option<Duration> {
    match event {
        Event::Latched { latch, .. } => Some(latch.since),
        // A drive that came online has its picture forgotten: clients take no reference until
        // the diagnostics describe it anew (`DriveDiag::info_for`), so publish them at once.
        Event::Rearmed { at, .. }
        | Event::Reference { at, .. }
        | Event::Monitoring { at, .. }
        | Event::DriveOnline { at, .. } => Some(*at),
        _ => None,
    }
}

/// At start: the shortest telegram-off time that does not trip a drive between two of its
/// polls on this bus, the longest of its drives'.
fn log_shortest_monitoring(bus: &BusConfig, stats: &Stats) {
    if let Some(d) = stats.drives.iter().max_by_key(|d| d.monitoring_min) {
        tracing::info!(
            bus = bus.name,
            "drives are polled at worst every {} ms (drive {}): a telegram-off time below that trips a drive between polls",
            d.monitoring_min.as_millis(),
            d.address
        );
    }
}

/// Every telegram at `trace` level: direction, drive, outcome and bytes.
fn trace_telegram(bus: &BusConfig, r: &uss_shm_types::TelegramRecord) {
    if !tracing::enabled!(tracing::Level::TRACE) {
        return;
    }
    tracing::trace!(
        bus = bus.name,
        drive = r.address,
        sequence = r.sequence,
        "{} drive {} {}: {}",
        if r.is_request() { "->" } else { "<-" },
        r.address,
        r.outcome_name(),
        uss_shm_types::Hex(r.bytes())
    );
}

fn log_latch(bus: &BusConfig, address: Address, latch: &Latch, rejection: Rejection) {
    let (drive, at_s, pid) = (address.get(), latch.since.as_secs_f64(), latch.by_pid);
    let command = latch.command;
    let bus = bus.name.as_str();
    match latch.reason {
        LatchReason::Released => tracing::info!(
            bus,
            drive,
            at_s,
            pid,
            "drive {address}: released by its controller (process {pid}); sending {command}, latched"
        ),
        LatchReason::Override => tracing::warn!(
            bus,
            drive,
            at_s,
            pid,
            "drive {address}: operator {command} from process {pid}; latched until its controller re-arms (OFF1, then ON)"
        ),
        LatchReason::Rejected => tracing::warn!(
            bus,
            drive,
            at_s,
            pid,
            "drive {address}: refused a sample of process {pid} ({rejection}); sending {command}, latched until the controller re-arms (OFF1, then ON)"
        ),
        reason => tracing::warn!(
            bus,
            drive,
            at_s,
            pid,
            "drive {address}: {reason}; sending {command}, latched until the controller re-arms (OFF1, then ON)"
        ),
    }
}

/// The parameter a drive's key names, as the manuals write it (`P2014[0]`), or `otherwise`.
fn param_name(
    bus: &BusConfig,
    address: Address,
    key: fn(&DriveEntry) -> ParamName,
    otherwise: &str,
) -> String {
    bus.drives
        .iter()
        .find(|d| d.address == address)
        .and_then(|d| key(d).param())
        .map_or_else(|| otherwise.to_owned(), |p| p.to_string())
}

/// The family profile of drive `address` (none for a generic slave).
fn profile(bus: &BusConfig, address: Address) -> Option<&'static Catalogue> {
    bus.drives
        .iter()
        .find(|d| d.address == address)
        .and_then(|d| Catalogue::of(d.family))
}

fn log_monitoring(
    bus: &BusConfig,
    address: Address,
    at: Duration,
    (state, ms): (Monitoring, u32),
    shortest_ms: u32,
) {
    let param = param_name(
        bus,
        address,
        DriveEntry::monitoring_param,
        "the monitoring parameter",
    );
    // The fault a trip records and the parameter, as the drive's family profile names them.
    let family = profile(bus, address);
    let fault = family
        .and_then(Catalogue::telegram_off_fault_name)
        .unwrap_or_else(|| "its telegram-off fault".to_owned());
    let profile = family
        .and_then(Catalogue::monitoring_name)
        .unwrap_or_else(|| "none".to_owned());
    let (drive, at_s, bus) = (address.get(), at.as_secs_f64(), bus.name.as_str());
    match state {
        Monitoring::On => tracing::info!(
            bus,
            drive,
            at_s,
            "drive {address}: telegram monitoring on ({param} = {ms} ms)"
        ),
        Monitoring::Off => tracing::warn!(
            bus,
            drive,
            at_s,
            "drive {address}: telegram monitoring is OFF ({param} = 0): if ussd or its line dies, nothing stops this drive; set {param} to e.g. 100 ms (USS.md section 5)"
        ),
        Monitoring::TooShort => tracing::warn!(
            bus,
            drive,
            at_s,
            "drive {address}: telegram monitoring {param} = {ms} ms is shorter than the time between two polls of it on this bus (up to {shortest_ms} ms): it trips ({fault}) between polls; set {param} to at least {shortest_ms} ms, or poll it more often (weight, fewer drives, a faster baud rate)"
        ),
        Monitoring::TooLong => tracing::warn!(
            bus,
            drive,
            at_s,
            "drive {address}: telegram monitoring {param} = {ms} ms is longer than monitoring_max_ms: after ussd or its line dies the drive runs on for that long"
        ),
        other => tracing::warn!(
            bus,
            drive,
            at_s,
            "drive {address}: telegram monitoring {other} ({param}): check monitoring_param for this drive (its family profile names {profile})"
        ),
    }
}

fn log_reference(
    bus: &BusConfig,
    address: Address,
    at: Duration,
    reference: Reference,
    configured: f32,
) {
    let mut param = param_name(
        bus,
        address,
        DriveEntry::reference_param,
        "the reference parameter",
    );
    if let Some(pairs) = bus
        .drives
        .iter()
        .find(|d| d.address == address)
        .and_then(|d| d.pole_pairs)
    {
        param = format!("{param} (rpm) x {pairs} pole pairs / 60");
    }
    let (drive, at_s, bus) = (address.get(), at.as_secs_f64(), bus.name.as_str());
    match reference {
        Reference::Read(hz) if reference.differs_from(configured) => tracing::warn!(
            bus,
            drive,
            at_s,
            "drive {address}: reference frequency {param} = {hz} Hz, but reference_hz = {configured} in the configuration: Hz are scaled by the drive's {hz} Hz (run_hz, ussctl, the exporter); set reference_hz = {hz} to agree (USS.md section 7)"
        ),
        Reference::Read(hz) => tracing::debug!(
            bus,
            drive,
            at_s,
            "drive {address}: reference frequency {param} = {hz} Hz, as configured"
        ),
        Reference::Unknown => tracing::info!(
            bus,
            drive,
            at_s,
            "drive {address}: its reference frequency {param} is not known now (a reset or commissioning write took effect, or the drive no longer gives it as a frequency): it and the telegram monitoring are read again; Hz setpoints are refused until then"
        ),
        _ => tracing::warn!(
            bus,
            drive,
            at_s,
            "drive {address}: reference frequency {param} is not readable as Hz: Hz are scaled by reference_hz = {configured} as configured, unverified; set reference_param = \"\" for a drive whose {param} is not in Hz (G120: rpm)"
        ),
    }
}

/// What ussd's own reads of a drive (telegram monitoring, reference frequency) found.
fn log_own_read(bus: &BusConfig, event: &Event) {
    match *event {
        Event::Monitoring {
            address,
            at,
            state,
            ms,
            shortest_ms,
        } => log_monitoring(bus, address, at, (state, ms), shortest_ms),
        Event::Reference {
            address,
            at,
            reference,
            configured_hz,
        } => log_reference(bus, address, at, reference, configured_hz),
        _ => {}
    }
}

/// Whether a drive takes its commands from this link (ZSW1 bit 9), when that changes.
fn log_commands(bus: &BusConfig, address: Address, at: Duration, taken: bool) {
    let (drive, at_s) = (address.get(), at.as_secs_f64());
    if taken {
        tracing::info!(
            bus = bus.name,
            drive,
            at_s,
            "drive {address} takes its commands from this link again (ZSW1 bit 9 = 1)"
        );
    } else {
        let source = profile(bus, address)
            .and_then(Catalogue::command_source_setting)
            .map(|s| format!(" ({s} takes them from USS)"))
            .unwrap_or_default();
        tracing::warn!(
            bus = bus.name,
            drive,
            at_s,
            "drive {address} does not take its commands from this link (ZSW1 bit 9, control requested, is 0): it ignores ussd's control words, stops included; its command source is elsewhere{source}: stop it where it takes its commands"
        );
    }
}

fn log_event(bus: &BusConfig, event: &Event) {
    match *event {
        Event::DriveOffline {
            address,
            at,
            failure,
        } => {
            tracing::warn!(
                bus = bus.name,
                drive = address.get(),
                at_s = at.as_secs_f64(),
                "drive {address} does not respond ({}): offline",
                failure.name()
            );
        }
        Event::Commands { address, at, taken } => log_commands(bus, address, at, taken),
        Event::DriveOnline { address, at } => {
            tracing::info!(
                bus = bus.name,
                drive = address.get(),
                at_s = at.as_secs_f64(),
                "drive {address} online"
            );
        }
        Event::Latched {
            address,
            latch,
            rejection,
        } => log_latch(bus, address, &latch, rejection),
        Event::Rearmed { address, at, pid } => {
            tracing::info!(
                bus = bus.name,
                drive = address.get(),
                at_s = at.as_secs_f64(),
                pid,
                "drive {address}: re-armed by process {pid} (a stop naming the latch): its controller's words go out again"
            );
        }
        Event::Monitoring { .. } | Event::Reference { .. } => log_own_read(bus, event),
        Event::LineDown { at, fault } => {
            tracing::error!(
                bus = bus.name,
                at_s = at.as_secs_f64(),
                "line down ({fault}): every drive offline, pending parameter jobs ended; reopening the device with backoff (0.1 s doubling to 5 s); meanwhile only the drives' own telegram monitoring stops them"
            );
        }
        Event::LineUp { at, down_for } => {
            tracing::info!(
                bus = bus.name,
                at_s = at.as_secs_f64(),
                down_s = down_for.as_secs_f64(),
                "line back after {:.1} s: every drive latched until a controller re-arms it (its explicit rearm: OFF1 naming the latch, then ON)",
                down_for.as_secs_f64()
            );
        }
        Event::Retry {
            address,
            at,
            attempt,
            failure,
        } => {
            tracing::debug!(
                bus = bus.name,
                drive = address.get(),
                at_s = at.as_secs_f64(),
                attempt,
                "drive {address}: {}, retry {attempt} of {}",
                failure.name(),
                bus.retries.get()
            );
        }
        Event::StateChanged {
            address,
            at,
            from,
            to,
        } => log_state(bus, address, at, from, to),
        Event::CycleOverrun { at, took } => {
            tracing::warn!(
                bus = bus.name,
                at_s = at.as_secs_f64(),
                took_ms = took.as_secs_f64() * 1e3,
                "cycle took longer than cycle_time"
            );
        }
    }
}

/// A drive's change of state: a fault (the drive's own trip) as a warning with what to do,
/// its end as information, the rest at debug level.
fn log_state(
    bus: &BusConfig,
    address: uss_protocol::Address,
    at: core::time::Duration,
    from: Option<uss_protocol::DriveState>,
    to: uss_protocol::DriveState,
) {
    use uss_protocol::DriveState;
    let was = from.map_or("unknown", DriveState::short_name);
    if to == DriveState::Fault {
        // A trip of the drive itself (its telegram monitoring F0072, an overcurrent): said
        // where an operator looks, with what to do.
        tracing::warn!(
            bus = bus.name,
            drive = address.get(),
            at_s = at.as_secs_f64(),
            "drive {address}: FAULT ({was} -> fault): the drive tripped; `ussctl faults {address}` names the fault, `ussctl ack {address}` acknowledges it once its cause is gone"
        );
    } else if from == Some(DriveState::Fault) {
        tracing::info!(
            bus = bus.name,
            drive = address.get(),
            at_s = at.as_secs_f64(),
            "drive {address}: fault cleared (now {})",
            to.short_name()
        );
    } else {
        tracing::debug!(
            bus = bus.name,
            drive = address.get(),
            at_s = at.as_secs_f64(),
            "drive {address}: {was} -> {}",
            to.short_name()
        );
    }
}
