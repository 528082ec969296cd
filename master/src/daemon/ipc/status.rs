//! The housekeeping thread's side: [`StatusPublisher`] publishes the bus status, every
//! drive's diagnostics and ussd's heartbeat (which names this instance's generation) every
//! 50 ms, and says goodbye when ussd stops.

use super::{
    IpcError, IpcNode, MAX_CLIENTS, MAX_NODES, Svc, as_ns, fail, monotonic_ns, pid_of, text,
};
use core::time::Duration;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::writer::{EntryHandleMut, Writer};
use iceoryx2::prelude::*;
use uss_engine::DriveSetup;
use uss_engine::control::Control;
use uss_engine::stats::{DriveStatus, LineFailure, Stats};
use uss_protocol::Address;
use uss_shm_types::names::{self, LAYOUT_VERSION_ATTRIBUTE};
use uss_shm_types::{
    BlackboardKey, BusName, BusState, BusStatus, ControlState, DriveDiag, DriveInfo, Heartbeat,
    Instance, LAYOUT_VERSION, LatchReason, LineFault, LineState, RtMode, StopCommand,
    TelegramRecord,
};

/// The heartbeat's one publisher, on the bus's stable `ussd` service: opened when clients of
/// an earlier ussd still hold it (a dead predecessor's publisher was cleaned up with its node
/// just before), created otherwise. While another ussd serves the bus, its publisher holds
/// the slot: [`IpcError::Served`].
pub(super) fn heartbeat_publisher(
    node: &IpcNode,
    bus: &BusName,
) -> Result<Publisher<Svc, Heartbeat, ()>, IpcError> {
    let verifier = AttributeVerifier::new()
        .require(
            &LAYOUT_VERSION_ATTRIBUTE
                .try_into()
                .map_err(|e| fail(bus, "attributes")(text(e)))?,
            &LAYOUT_VERSION
                .to_string()
                .as_str()
                .try_into()
                .map_err(|e| fail(bus, "attributes")(text(e)))?,
        )
        .map_err(|e| fail(bus, "attributes")(text(e)))?;
    let service = node
        .service_builder(&names::heartbeat(bus))
        .publish_subscribe::<Heartbeat>()
        .max_publishers(1)
        .max_subscribers(MAX_CLIENTS * 4)
        .subscriber_max_buffer_size(1)
        .history_size(1)
        .enable_safe_overflow(true)
        .max_nodes(MAX_NODES)
        .open_or_create_with_attributes(&verifier)
        .map_err(|e| fail(bus, "the heartbeat service")(text(e)))?;
    match service.publisher_builder().create() {
        Ok(p) => Ok(p),
        Err(PublisherCreateError::ExceedsMaxSupportedPublishers) => {
            let mut holder = None;
            service.dynamic_config().list_publishers(|p| {
                holder = Some(p.node_id);
                CallbackProgression::Stop
            });
            Err(IpcError::Served {
                bus: bus.to_string(),
                pid: holder.and_then(|n| pid_of(node.config(), &n)),
            })
        }
        Err(e) => Err(fail(bus, "the heartbeat publisher")(text(e))),
    }
}

/// The bus status and drive diagnostics blackboards, written by the housekeeping thread.
pub(super) fn create(
    node: &IpcNode,
    bus: &Instance,
    drives: &[DriveSetup],
    attributes: &AttributeSpecifier,
    (notifier, heartbeat): (Notifier<Svc>, Publisher<Svc, Heartbeat, ()>),
    clock_origin: Duration,
) -> Result<StatusPublisher, IpcError> {
    let addresses: Vec<Address> = drives.iter().map(|d| d.address).collect();
    let mut diag_builder = node
        .service_builder(&names::diag(bus))
        .blackboard_creator::<BlackboardKey>()
        .max_readers(MAX_CLIENTS)
        .max_nodes(MAX_NODES);
    for d in drives {
        // What a client needs before the first publish: what ussd knows of the drive.
        let initial = DriveDiag {
            info: info(d),
            ..DriveDiag::new(d.address.get())
        };
        diag_builder = diag_builder.add::<DriveDiag>(BlackboardKey::drive(d.address), initial);
    }
    let diag = diag_builder
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, "the diag blackboard")(text(e)))?;
    let diag_writer = diag
        .writer_builder()
        .create()
        .map_err(|e| fail(bus, "the diag writer")(text(e)))?;
    let mut diag_entries = Vec::with_capacity(addresses.len());
    for &address in &addresses {
        diag_entries.push(
            diag_writer
                .entry::<DriveDiag>(&BlackboardKey::drive(address))
                .map_err(|e| fail(bus, "a diag entry")(text(e)))?,
        );
    }
    let status = node
        .service_builder(&names::status(bus))
        .blackboard_creator::<BlackboardKey>()
        .max_readers(MAX_CLIENTS)
        .max_nodes(MAX_NODES)
        .add::<BusStatus>(BlackboardKey::IMAGE, BusStatus::EMPTY)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, "the status blackboard")(text(e)))?;
    let status_writer = status
        .writer_builder()
        .create()
        .map_err(|e| fail(bus, "the status writer")(text(e)))?;
    let status_entry = status_writer
        .entry::<BusStatus>(&BlackboardKey::IMAGE)
        .map_err(|e| fail(bus, "the status entry")(text(e)))?;
    let capture = node
        .service_builder(&names::capture(bus))
        .publish_subscribe::<TelegramRecord>()
        .max_publishers(1)
        .max_subscribers(names::CAPTURE_MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(names::CAPTURE_BUFFER)
        .history_size(0)
        .enable_safe_overflow(true)
        .max_nodes(MAX_NODES)
        .create_with_attributes(attributes)
        .map_err(|e| fail(bus, "the capture service")(text(e)))?
        .publisher_builder()
        .create()
        .map_err(|e| fail(bus, "the capture publisher")(text(e)))?;
    Ok(StatusPublisher {
        heartbeat,
        capture,
        beat: Heartbeat::new(std::process::id(), bus.generation),
        bus: bus.clone(),
        info: drives.iter().map(info).collect(),
        diag: diag_entries,
        status: status_entry,
        _writers: (diag_writer, status_writer),
        notifier,
        origin_ns: as_ns(clock_origin),
        rt: RtMode::BestEffort,
        rt_cpu: -1,
        rt_priority: 0,
    })
}

/// The housekeeping thread's ports: bus status and drive diagnostics.
pub struct StatusPublisher {
    bus: Instance,
    /// The bus's heartbeat (its generation names this instance's services), sent with each
    /// status.
    heartbeat: Publisher<Svc, Heartbeat, ()>,
    /// Every telegram of the bus, as the bus thread captured it.
    capture: Publisher<Svc, TelegramRecord, ()>,
    beat: Heartbeat,
    /// What ussd knows of each drive, in slot order.
    info: Vec<DriveInfo>,
    diag: Vec<EntryHandleMut<Svc, BlackboardKey, DriveDiag>>,
    status: EntryHandleMut<Svc, BlackboardKey, BusStatus>,
    _writers: (Writer<Svc, BlackboardKey>, Writer<Svc, BlackboardKey>),
    notifier: Notifier<Svc>,
    origin_ns: u64,
    rt: RtMode,
    rt_cpu: i32,
    rt_priority: u8,
}

impl core::fmt::Debug for StatusPublisher {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("StatusPublisher")
            .field("bus", &self.bus.bus.as_str())
            .finish_non_exhaustive()
    }
}

/// A drive's control as the contract carries it.
pub(super) struct ControlView {
    pub(super) state: ControlState,
    pub(super) reason: LatchReason,
    /// What a latched drive gets; `None` while live.
    pub(super) command: Option<StopCommand>,
    /// `CLOCK_MONOTONIC` ns of the latch (0 while live).
    pub(super) since_ns: u64,
    pub(super) by_pid: u32,
    /// The latch's id (0 while live).
    pub(super) id: u64,
}

impl ControlView {
    pub(super) fn of(status: &DriveStatus, origin_ns: u64) -> Self {
        match status.control {
            Control::Live => Self {
                state: ControlState::Live,
                reason: LatchReason::None,
                command: None,
                since_ns: 0,
                by_pid: 0,
                id: 0,
            },
            Control::Latched(l) => Self {
                state: ControlState::Latched,
                reason: l.reason,
                command: Some(l.command),
                since_ns: origin_ns.saturating_add(as_ns(l.since)),
                by_pid: l.by_pid,
                id: l.id,
            },
        }
    }
}

/// p50, p99, p99.9 and max of a timing histogram, ns (zeros while empty).
fn quantiles(h: &hdrhistogram::Histogram<u64>) -> [u64; 4] {
    if h.is_empty() {
        return [0; 4];
    }
    [
        h.value_at_quantile(0.5),
        h.value_at_quantile(0.99),
        h.value_at_quantile(0.999),
        h.max(),
    ]
}

/// What ussd knows of a drive from its configuration, as the contract carries it.
fn info(d: &DriveSetup) -> DriveInfo {
    DriveInfo {
        reference_hz: d.reference_hz,
        watchdog_ms: u32::try_from(d.watchdog.as_millis()).unwrap_or(u32::MAX),
        safe_command: d.safe.code(),
        params_writable: u8::from(d.params_writable),
        pkw_words: d.layout.pkw.p2013() as u8,
        pzd_words: d.layout.pzd.get() as u8,
        weight: d.weight,
        family: d.family.code(),
        pole_pairs: match d.reference_unit {
            uss_engine::reference::ReferenceUnit::Rpm { pole_pairs } => pole_pairs,
            uss_engine::reference::ReferenceUnit::Hz => 0,
        },
        ..DriveInfo::UNKNOWN
    }
}

impl StatusPublisher {
    /// Records the real-time mode the bus thread obtained.
    pub fn set_rt(&mut self, realtime: bool, cpu: Option<usize>, priority: Option<u8>) {
        self.rt = if realtime {
            RtMode::Realtime
        } else {
            RtMode::BestEffort
        };
        self.rt_cpu = cpu.and_then(|c| i32::try_from(c).ok()).unwrap_or(-1);
        self.rt_priority = priority.unwrap_or(0);
    }

    /// Publishes `stats` as the bus status and every drive's diagnostics, and the heartbeat
    /// (running, line down, or, with `running` false, stopping); `reopen_attempts` counts
    /// attempts to reopen a line that is down.
    pub fn publish(&mut self, stats: &Stats, running: bool, reopen_attempts: u32) {
        self.publish_diagnostics(stats);
        self.publish_status(stats, running, reopen_attempts);
        let _ = self
            .notifier
            .notify_with_custom_event_id(EventId::new(names::STATUS_PUBLISHED));
        let bus_state = if running {
            if stats.line.down.is_some() {
                BusState::LineDown
            } else {
                BusState::Running
            }
        } else {
            BusState::Stopping
        };
        self.beat(bus_state, stats);
    }

    fn publish_diagnostics(&self, stats: &Stats) {
        let ns = |d: Duration| self.origin_ns.saturating_add(as_ns(d));
        for (((entry, d), &info), h) in self
            .diag
            .iter()
            .zip(&stats.drives)
            .zip(&self.info)
            .zip(&stats.drive_histograms)
        {
            let control = ControlView::of(d, self.origin_ns);
            entry.update_with_copy(DriveDiag {
                consecutive_failed_polls: d.consecutive_failed_polls,
                last_zsw1: d.last_zsw1,
                last_hiw: d.last_hiw,
                online: u8::from(d.online),
                known: u8::from(d.known),
                no_reply: u8::from(d.no_reply),
                control: control.state.code(),
                last_failure: d.last_failure.code(),
                latch_reason: control.reason.code(),
                latch_command: StopCommand::code_of(control.command),
                rejection: d.rejection.code(),
                monitoring: d.monitoring.code(),
                monitoring_ms: d.monitoring_ms,
                picture: d.picture,
                controller_pid: d.controller_pid,
                since_ns: ns(d.since),
                last_good_ns: d.last_good.map_or(uss_shm_types::diag::NEVER, ns),
                latched_since_ns: control.since_ns,
                // Clients scale Hz by the drive's own reference once it was read, and by none
                // while it is read again.
                info: DriveInfo {
                    reference_hz: d
                        .reference
                        .scale(info.reference_hz)
                        .unwrap_or(DriveInfo::REFERENCE_NOT_KNOWN),
                    ..info
                },
                counters: d.counters,
                exchange_ns: quantiles(&h.exchange),
                response_delay_ns: quantiles(&h.response_delay),
                period_ns: as_ns(d.period),
                stale_after_ns: as_ns(d.stale_after),
                monitoring_min_ms: u32::try_from(d.monitoring_min.as_millis()).unwrap_or(u32::MAX),
                ..DriveDiag::new(d.address.get())
            });
        }
    }

    fn publish_status(&self, stats: &Stats, running: bool, reopen_attempts: u32) {
        let ns = |d: Duration| self.origin_ns.saturating_add(as_ns(d));
        // The engine's own counters are the contract's; this adds what only ussd knows.
        self.status.update_with_copy(BusStatus {
            rt_cpu: self.rt_cpu,
            rt_mode: self.rt.code(),
            rt_priority: self.rt_priority,
            drive_count: stats.drives.len() as u8,
            running: u8::from(running),
            efficiency_ppm: stats.bus.efficiency_ppm(),
            mean_exchange_ns: stats.histograms.exchange.mean() as u64,
            bus_clock_ns: as_ns(stats.at),
            timestamp_ns: ns(stats.at),
            line_state: if stats.line.down.is_some() {
                LineState::Down
            } else {
                LineState::Up
            }
            .code(),
            line_fault: contract_fault(stats.line.down).0.code(),
            line_errno: contract_fault(stats.line.down).1,
            line_down_since_ns: stats.line.down.map_or(0, |(since, _)| ns(since)),
            line_downs: stats.line.downs,
            reopen_attempts,
            exchange_ns: quantiles(&stats.histograms.exchange),
            response_delay_ns: quantiles(&stats.histograms.response_delay),
            turnaround_ns: quantiles(&stats.histograms.turnaround),
            exchange_count: stats.histograms.exchange.len(),
            exchange_sum_ns: (stats.histograms.exchange.mean()
                * stats.histograms.exchange.len() as f64) as u64,
            exchange_le: uss_shm_types::EXCHANGE_BUCKETS_NS
                .map(|le| stats.histograms.exchange.count_between(0, le)),
            ..stats.bus
        });
    }

    /// Sends the next heartbeat.
    fn beat(&mut self, bus_state: BusState, stats: &Stats) {
        let origin_ns = self.origin_ns;
        let b = &mut self.beat;
        b.sequence += 1;
        b.timestamp_ns = monotonic_ns();
        b.exchanges = stats.bus.exchanges;
        b.state = bus_state.code();
        let (fault, errno) = contract_fault(stats.line.down);
        (b.line_fault, b.line_errno) = (fault.code(), errno);
        b.line_down_since_ns = stats
            .line
            .down
            .map_or(0, |(since, _)| origin_ns.saturating_add(as_ns(since)));
        // A client that is not there cannot miss it; the next one gets the history.
        let _ = self.heartbeat.send_copy(*b);
    }

    /// Publishes a telegram the bus thread captured, its times made `CLOCK_MONOTONIC`. A
    /// subscriber that does not keep up loses its oldest records.
    pub fn capture(&self, record: &TelegramRecord) {
        let record = TelegramRecord {
            start_ns: record.start_ns.saturating_add(self.origin_ns),
            end_ns: record.end_ns.saturating_add(self.origin_ns),
            ..*record
        };
        let _ = self.capture.send_copy(record);
    }

    /// Tells listeners ussd is leaving this bus (the same event a dead ussd's notifier leaves
    /// behind), so clients drop their ports and the services can go.
    pub fn goodbye(&self) {
        let _ = self
            .notifier
            .notify_with_custom_event_id(EventId::new(names::USSD_GONE));
    }
}

/// A line fault as the contract writes it: its code and, for an I/O error, the errno.
fn contract_fault(down: Option<(Duration, LineFailure)>) -> (LineFault, i32) {
    match down {
        None => (LineFault::None, 0),
        Some((_, LineFailure::Closed)) => (LineFault::Closed, 0),
        Some((_, LineFailure::Io(errno))) => (LineFault::Io, errno),
        Some((_, LineFailure::Stalled)) => (LineFault::Stalled, 0),
    }
}
