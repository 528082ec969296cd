//! A [`crate::Bus`]'s connection to the ussd serving it: the bus's heartbeat (the one service
//! whose name survives a restart of ussd), what it says ([`Health`]), and the bus-wide
//! services of the generation it names. Everything opened from a `Bus` asks the link which
//! generation is current, and reopens its own ports when a restarted ussd serves a new one.

use crate::ClientError;
use crate::open::{Ipc, entry, layout_verifier, opened};
use core::time::Duration;
use iceoryx2::port::reader::{EntryHandle, Reader};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::Node;
use iceoryx2::service::port_factory::blackboard::PortFactory as Blackboard;
use std::sync::{Arc, Mutex, MutexGuard, OnceLock, PoisonError};
use std::time::Instant;
use uss_shm_types::names::{self, GONE_AFTER_NS, HEARTBEAT_PERIOD_NS};
use uss_shm_types::{
    BlackboardKey, BusName, BusState, BusStatus, Generation, Heartbeat, Instance, LAYOUT_VERSION,
    LineFault,
};

pub(crate) type ParamClient =
    crate::request::Requester<uss_shm_types::ParamRequest, uss_shm_types::ParamResponse>;

/// What the bus's heartbeat says of ussd. Time stamps are `CLOCK_MONOTONIC` ns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Health {
    /// ussd (process `pid`) polls the bus.
    Running { pid: u32 },
    /// ussd runs, but the bus line is down since `since_ns`; it reopens the device.
    LineDown {
        pid: u32,
        since_ns: u64,
        fault: LineFault,
        errno: i32,
    },
    /// ussd said it stops (a clean exit) at `at_ns`.
    Stopped { pid: u32, at_ns: u64 },
    /// No heartbeat since `last_ns`, longer than [`GONE_AFTER_NS`]: ussd died or hangs.
    Gone { pid: u32, last_ns: u64 },
}

impl Health {
    fn of(beat: &Heartbeat, now_ns: u64) -> Self {
        let pid = beat.pid;
        if beat.is_stale(now_ns) {
            return Self::Gone {
                pid,
                last_ns: beat.timestamp_ns,
            };
        }
        match beat.state() {
            Ok(BusState::Stopping) => Self::Stopped {
                pid,
                at_ns: beat.timestamp_ns,
            },
            Ok(BusState::LineDown) => Self::LineDown {
                pid,
                since_ns: beat.line_down_since_ns,
                fault: LineFault::try_from(beat.line_fault).unwrap_or(LineFault::Closed),
                errno: beat.line_errno,
            },
            Ok(BusState::Running) | Err(_) => Self::Running { pid },
        }
    }

    /// Whether ussd serves the bus (running, or waiting for its line).
    pub fn is_serving(&self) -> bool {
        matches!(self, Self::Running { .. } | Self::LineDown { .. })
    }

    /// The error a call that needs a polling bus gets now, if any.
    pub fn error(&self, bus: &str) -> Option<ClientError> {
        let now = monotonic_ns();
        let ago = |t: u64| Duration::from_nanos(now.saturating_sub(t));
        match *self {
            Self::Running { .. } => None,
            Self::LineDown {
                since_ns,
                fault,
                errno,
                ..
            } => Some(ClientError::LineDown {
                bus: bus.to_owned(),
                fault: fault_text(fault, errno),
                down_for: ago(since_ns),
            }),
            Self::Stopped { pid, at_ns } => Some(ClientError::UssdStopped {
                bus: bus.to_owned(),
                pid,
                ago: ago(at_ns),
            }),
            Self::Gone { pid, last_ns } => Some(ClientError::UssdGone {
                bus: bus.to_owned(),
                pid,
                silent_for: ago(last_ns),
            }),
        }
    }
}

/// A line fault in words.
/// The buses ussd serves on this machine now: its live nodes (`ussd-<bus>`) under the
/// shared-memory root, as far as this process may see them; sorted.
pub(crate) fn served_buses() -> Vec<String> {
    let mut buses: Vec<String> = uss_shm_types::names::live_ussds()
        .into_iter()
        .map(|u| u.bus)
        .collect();
    buses.sort();
    buses.dedup();
    buses
}

fn fault_text(fault: LineFault, errno: i32) -> String {
    match fault {
        LineFault::Io => format!(
            "the line's I/O failed: {}",
            std::io::Error::from_raw_os_error(errno)
        ),
        other => other.name().to_owned(),
    }
}

/// `CLOCK_MONOTONIC` in ns, the clock of every `*_ns` field of the contract.
pub fn monotonic_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).map_or(0, |t| {
        (t.tv_sec() as u64)
            .saturating_mul(1_000_000_000)
            .saturating_add(t.tv_nsec() as u64)
    })
}

/// When this process started, `CLOCK_MONOTONIC` ns: the moment of the deliberate act behind a
/// program that re-arms once it is set up (`ussctl run`, a Python script started to run a
/// drive), to pass to [`crate::Controller::rearm`]. A stop that lands while the program starts
/// (its libraries load, it opens the bus) is then not re-armed by it (SAFETY.md REARM).
///
/// The kernel's own start time (`/proc/self/stat`, field 22, clock ticks since boot on
/// `CLOCK_BOOTTIME`) moved onto `CLOCK_MONOTONIC`. It is rounded down to its tick (10 ms), so it
/// is never later than the start: a stop just before the start is not re-armed either.
pub fn process_start_ns() -> std::io::Result<u64> {
    let stat = std::fs::read_to_string("/proc/self/stat")?;
    let ticks = start_ticks(&stat).ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("/proc/self/stat has no start time: {stat:?}"),
        )
    })?;
    let per_second = nix::unistd::sysconf(nix::unistd::SysconfVar::CLK_TCK)
        .ok()
        .flatten()
        .and_then(|t| u64::try_from(t).ok())
        .filter(|&t| t > 0)
        .unwrap_or(100);
    let started_boot = u128::from(ticks) * 1_000_000_000 / u128::from(per_second);
    let clock = |id| {
        nix::time::clock_gettime(id)
            .map(|t| {
                u128::try_from(t.tv_sec()).unwrap_or(0) * 1_000_000_000
                    + u128::try_from(t.tv_nsec()).unwrap_or(0)
            })
            .map_err(std::io::Error::from)
    };
    let mono = clock(nix::time::ClockId::CLOCK_MONOTONIC)?;
    let boot = clock(nix::time::ClockId::CLOCK_BOOTTIME)?;
    // CLOCK_BOOTTIME runs ahead of CLOCK_MONOTONIC by the time the machine was suspended.
    let started = started_boot.saturating_sub(boot.saturating_sub(mono));
    Ok(u64::try_from(started).unwrap_or(u64::MAX))
}

/// Field 22 of a `/proc/PID/stat` line (`starttime`), counted after the command's closing
/// parenthesis (the command itself may hold spaces and parentheses).
fn start_ticks(stat: &str) -> Option<u64> {
    let (_, after) = stat.rsplit_once(')')?;
    after.split_whitespace().nth(19)?.parse().ok()
}

/// The bus-wide services of one ussd instance.
pub(crate) struct Services {
    pub(crate) instance: Instance,
    status: EntryHandle<Ipc, BlackboardKey, BusStatus>,
    pub(crate) diag_service: Blackboard<Ipc, BlackboardKey>,
    pub(crate) diag: Reader<Ipc, BlackboardKey>,
    pub(crate) params: OnceLock<ParamClient>,
    /// The request and answer events of the parameter requester.
    pub(crate) events: OnceLock<Arc<crate::request::RequestEvents>>,
}

impl Services {
    fn open(node: &Node<Ipc>, instance: Instance) -> Result<Self, ClientError> {
        let bus = instance.bus.as_str();
        let not_running = || ClientError::not_running(bus.to_owned());
        let verifier = layout_verifier()?;
        let status_name = names::status(&instance);
        let status_service = opened(
            node.service_builder(&status_name)
                .blackboard_opener::<BlackboardKey>()
                .open_with_attributes(&verifier),
            bus,
            &status_name,
            not_running,
        )?;
        let status = entry(&status_service, bus, &status_name, BlackboardKey::IMAGE)?;
        let diag_name = names::diag(&instance);
        let diag_service = opened(
            node.service_builder(&diag_name)
                .blackboard_opener::<BlackboardKey>()
                .open_with_attributes(&verifier),
            bus,
            &diag_name,
            not_running,
        )?;
        let diag = diag_service
            .reader_builder()
            .create()
            .map_err(|e| ClientError::ipc(format!("reading {}", diag_name.as_str()), e))?;
        Ok(Self {
            instance,
            status,
            diag_service,
            diag,
            params: OnceLock::new(),
            events: OnceLock::new(),
        })
    }

    pub(crate) fn status(&self) -> BusStatus {
        *self.status.get()
    }

    pub(crate) fn generation(&self) -> Generation {
        self.instance.generation
    }
}

/// What the link knows.
struct State {
    /// The newest heartbeat.
    last: Heartbeat,
    /// The bus-wide services of `last`'s generation, once opened.
    current: Option<Arc<Services>>,
    /// When the heartbeat subscriber was last read.
    checked_ns: u64,
    /// When (this process's clock) `last`'s time stamp last changed: a heartbeat that stops
    /// changing is a ussd gone whatever the two clocks say (a program whose clock runs behind
    /// ussd's, in a time namespace of its own, saw every stamp in its future, aged 0: issue
    /// 47's sweep showed it a paused ussd's drives online and fresh).
    changed_ns: u64,
}

/// See the module documentation.
pub(crate) struct Link {
    pub(crate) name: BusName,
    pub(crate) node: Node<Ipc>,
    heartbeat: Subscriber<Ipc, Heartbeat, ()>,
    state: Mutex<State>,
}

/// Calls closer together than this reuse the last look at the heartbeat.
const CHECK_EVERY_NS: u64 = 1_000_000;

impl Link {
    /// Subscribes to bus `name`'s heartbeat and waits for one (at most [`GONE_AFTER_NS`]),
    /// then opens the generation it names.
    pub(crate) fn open(name: BusName, node: Node<Ipc>) -> Result<Self, ClientError> {
        let bus = name.as_str().to_owned();
        let not_running = || ClientError::not_running(bus.clone());
        let heartbeat_name = names::heartbeat(&name);
        let service = opened(
            node.service_builder(&heartbeat_name)
                .publish_subscribe::<Heartbeat>()
                .open_with_attributes(&layout_verifier()?),
            &bus,
            &heartbeat_name,
            not_running,
        )?;
        let heartbeat = service
            .subscriber_builder()
            .buffer_size(1)
            .create()
            .map_err(|e| {
                ClientError::ipc(format!("subscribing to {}", heartbeat_name.as_str()), e)
            })?;
        // A new subscriber is connected at the publisher's next heartbeat.
        let deadline = Instant::now() + Duration::from_nanos(GONE_AFTER_NS);
        let first = loop {
            if let Some(beat) = newest(&heartbeat) {
                break beat;
            }
            if Instant::now() >= deadline {
                // The service lives while clients of a former ussd hold it, but nobody beats:
                // that ussd died, hangs or stopped, and none serves the bus now.
                return Err(ClientError::UssdGone {
                    bus: bus.clone(),
                    pid: 0,
                    silent_for: Duration::from_nanos(GONE_AFTER_NS),
                });
            }
            std::thread::sleep(Duration::from_millis(2));
        };
        let link = Self {
            name,
            node,
            heartbeat,
            state: Mutex::new({
                let now = monotonic_ns();
                State {
                    last: first,
                    current: None,
                    checked_ns: now,
                    changed_ns: now,
                }
            }),
        };
        if let Some(e) = Health::of(&first, monotonic_ns()).error(&bus)
            && matches!(
                e,
                ClientError::UssdStopped { .. } | ClientError::UssdGone { .. }
            )
        {
            return Err(e);
        }
        link.state().current = Some(Arc::new(Services::open(
            &link.node,
            link.instance_of(&first),
        )?));
        Ok(link)
    }

    fn state(&self) -> MutexGuard<'_, State> {
        // Plain data, valid whatever a panicking holder left behind.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn instance_of(&self, beat: &Heartbeat) -> Instance {
        Instance::new(self.name.clone(), beat.generation())
    }

    /// What the heartbeat says now, and the services of the generation it names (when ussd
    /// serves the bus and they could be opened). Reads the heartbeat at most every 1 ms.
    pub(crate) fn current(&self) -> (Health, Option<Arc<Services>>) {
        let now = monotonic_ns();
        let mut state = self.state();
        if now.saturating_sub(state.checked_ns) >= CHECK_EVERY_NS {
            state.checked_ns = now;
            if let Some(beat) = newest(&self.heartbeat) {
                if beat.timestamp_ns != state.last.timestamp_ns {
                    state.changed_ns = now;
                }
                state.last = beat;
            }
        }
        let mut health = Health::of(&state.last, now);
        if health.is_serving() && now.saturating_sub(state.changed_ns) > GONE_AFTER_NS {
            // Silent by this process's own clock (its `ago` of `changed_ns`).
            health = Health::Gone {
                pid: state.last.pid,
                last_ns: state.changed_ns,
            };
        }
        if !health.is_serving() {
            return (health, None);
        }
        let generation = state.last.generation();
        if state.current.as_ref().map(|s| s.generation()) != Some(generation) {
            // A restarted ussd: its services exist before its first heartbeat.
            let instance = self.instance_of(&state.last);
            state.current = Services::open(&self.node, instance).ok().map(Arc::new);
        }
        (health, state.current.clone())
    }

    /// The services of the current generation, or the error that says why there are none.
    pub(crate) fn services(&self) -> Result<Arc<Services>, ClientError> {
        match self.current() {
            (_, Some(s)) => Ok(s),
            (health, None) => Err(health
                .error(self.name.as_str())
                .unwrap_or_else(|| ClientError::not_running(self.name.as_str().to_owned()))),
        }
    }

    /// The newest heartbeat's time stamp (ussd's `CLOCK_MONOTONIC`) and when this process read
    /// it (its own): what moves a moment of this process onto ussd's clock
    /// (`uss_shm_types::on_latch_clock`).
    pub(crate) fn ussd_clock(&self) -> (u64, u64) {
        let _ = self.current();
        let state = self.state();
        (state.last.timestamp_ns, state.checked_ns)
    }

    /// What the heartbeat says now.
    pub(crate) fn health(&self) -> Health {
        self.current().0
    }

    /// The error for calls that need a bus that polls, if the heartbeat says it does not.
    pub(crate) fn check(&self) -> Result<Arc<Services>, ClientError> {
        let (health, services) = self.current();
        if let Some(e) = health.error(self.name.as_str()) {
            return Err(e);
        }
        services.ok_or_else(|| ClientError::not_running(self.name.as_str().to_owned()))
    }
}

/// The newest heartbeat waiting in `subscriber`, if any (of this layout version).
fn newest(subscriber: &Subscriber<Ipc, Heartbeat, ()>) -> Option<Heartbeat> {
    let mut newest = None;
    while let Ok(Some(beat)) = subscriber.receive() {
        if beat.version == LAYOUT_VERSION {
            newest = Some(*beat);
        }
    }
    newest
}

/// The heartbeat period, for callers that wait in steps.
pub(crate) const HEARTBEAT_PERIOD: Duration = Duration::from_nanos(HEARTBEAT_PERIOD_NS);

#[cfg(test)]
mod tests {
    use super::*;

    fn beat(state: BusState, at: u64) -> Heartbeat {
        Heartbeat {
            state: state.code(),
            timestamp_ns: at,
            line_fault: LineFault::Closed.code(),
            line_down_since_ns: 5,
            ..Heartbeat::new(42, Generation(1))
        }
    }

    #[test]
    fn health_follows_the_heartbeat_state_and_age() {
        let t = 10_000_000_000;
        assert_eq!(
            Health::of(&beat(BusState::Running, t), t),
            Health::Running { pid: 42 }
        );
        assert_eq!(
            Health::of(&beat(BusState::Stopping, t), t),
            Health::Stopped { pid: 42, at_ns: t }
        );
        assert!(matches!(
            Health::of(&beat(BusState::LineDown, t), t),
            Health::LineDown {
                since_ns: 5,
                fault: LineFault::Closed,
                ..
            }
        ));
        let late = t + GONE_AFTER_NS + 1;
        assert_eq!(
            Health::of(&beat(BusState::Running, t), late),
            Health::Gone {
                pid: 42,
                last_ns: t
            }
        );
        assert!(Health::of(&beat(BusState::LineDown, t), t).is_serving());
        assert!(!Health::of(&beat(BusState::Running, t), late).is_serving());
    }

    #[test]
    fn the_start_time_is_field_22_after_the_command_whatever_it_holds() {
        let line = "4242 (a) b (c)) S 1 4242 4242 0 -1 4194560 100 0 0 0 1 2 0 0 20 0 1 0 987654 1000 10 18446744073709551615";
        assert_eq!(start_ticks(line), Some(987_654));
        assert_eq!(start_ticks("4242 (cut) S 1 2"), None);
        assert_eq!(start_ticks("no parenthesis"), None);
    }

    #[test]
    fn this_process_started_before_now_and_after_boot() {
        let started = process_start_ns().unwrap();
        let now = monotonic_ns();
        assert!(started <= now, "{started} > {now}");
        // A child started now starts later than this test process did.
        let child = std::process::Command::new("sh")
            .args(["-c", "cat /proc/self/stat"])
            .output()
            .unwrap();
        let ticks = start_ticks(&String::from_utf8_lossy(&child.stdout)).unwrap();
        let own = start_ticks(&std::fs::read_to_string("/proc/self/stat").unwrap()).unwrap();
        assert!(ticks >= own);
    }
}
