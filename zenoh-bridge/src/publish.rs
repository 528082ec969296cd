//! One bus on Zenoh: its status, each drive's input images (each new one, woken by the bus's
//! exchange event, which names the drive to look at; at most `max_rate` per drive), diagnostics and description, and the bus's
//! liveliness token, declared only while ussd serves the bus (withdrawn when ussd is gone,
//! stopped or its line is down, and when the bridge stops).

use crate::keys::Keys;
use crate::payload::{Diag, Info, Input, Status};
use core::time::Duration;
use serde::Serialize;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;
use uss_client::{Bus, CycleEvent, DriveDiag, DriveWatch, Health, PzdInput};
use zenoh::bytes::Encoding;
use zenoh::liveliness::LivelinessToken;
use zenoh::{Session, Wait};

/// How often the status goes out (and when ussd comes or goes).
const STATUS_EVERY: Duration = Duration::from_millis(500);
const DIAG_EVERY: Duration = Duration::from_secs(1);
const INFO_EVERY: Duration = Duration::from_secs(5);
/// How often a bus without ussd is tried again.
const RECONNECT: Duration = Duration::from_millis(250);
/// The longest wait for an exchange event before the health is looked at again.
const WAIT_STEP: Duration = Duration::from_millis(20);
/// Every drive's image is looked at this often, besides those an exchange event names (an
/// image that changed without one: a drive going offline, ussd going).
const SWEEP_EVERY: Duration = Duration::from_millis(250);
/// Every drive.
const ALL: u32 = u32::MAX;

/// What one bus's publisher was asked for.
#[derive(Debug, Clone)]
pub struct Options {
    pub bus: String,
    pub keys: Keys,
    /// At most this many images per second and drive (None: every one).
    pub max_rate: Option<f64>,
    /// The bus's check of puts and queries: its refusals go out with the status.
    pub gate: std::sync::Arc<crate::gate::Gate>,
}

/// Puts `value` as JSON on `key`; a failed put is reported on stderr and survived (the next one
/// may pass).
fn put(session: &Session, key: &str, value: &impl Serialize) {
    let Ok(json) = serde_json::to_string(value) else {
        return;
    };
    if let Err(e) = session
        .put(key, json)
        .encoding(Encoding::APPLICATION_JSON)
        .wait()
    {
        eprintln!("uss-zenoh: put {key}: {e}");
    }
}

/// A drive being published: its watch and what went out last.
struct Drive {
    watch: DriveWatch,
    last: Option<(PzdInput, bool)>,
    sent_at: Option<Instant>,
    key: String,
    /// The diagnostics last read: while ussd does not answer for them (gone, stopped, paused
    /// past its heartbeat's limit), they go out again marked stale, so a remote reader's last
    /// put never stands as a live drive (rule 3).
    last_diag: Option<DriveDiag>,
}

/// One bus's state between rounds.
struct Publisher<'a> {
    session: &'a Session,
    o: &'a Options,
    bus: Option<Bus>,
    next_open: Instant,
    drives: Vec<Drive>,
    token: Option<LivelinessToken>,
    serving: bool,
    /// The ussd whose drive list `drives` follows.
    pid: Option<u32>,
    next_status: Instant,
    next_diag: Instant,
    next_info: Instant,
}

impl Publisher<'_> {
    fn health(&self) -> Option<Health> {
        self.bus.as_ref().map(Bus::health)
    }

    /// Opens the bus when there is none; true when one is open.
    fn open(&mut self) -> bool {
        if self.bus.is_none() && Instant::now() >= self.next_open {
            self.next_open = Instant::now() + RECONNECT;
            if let Ok(bus) = Bus::open_as(&self.o.bus, "uss-zenoh") {
                self.bus = Some(bus);
                self.follow_drives();
            }
        }
        self.bus.is_some()
    }

    /// Takes the drive list of the ussd serving the bus now (a restarted ussd may run other
    /// drives): drives still there keep what went out last.
    fn follow_drives(&mut self) {
        let Some(bus) = &self.bus else { return };
        let mut drives = Vec::new();
        for a in bus.drives() {
            if let Some(i) = self.drives.iter().position(|d| d.watch.address() == a) {
                drives.push(self.drives.swap_remove(i));
            } else if let Ok(watch) = bus.watch(a) {
                drives.push(Drive {
                    watch,
                    last: None,
                    sent_at: None,
                    key: self.o.keys.input(a),
                    last_diag: None,
                });
            }
        }
        self.drives = drives;
        self.next_info = Instant::now();
    }

    /// Declares or withdraws the bus's token as ussd serves it or not; publishes the status
    /// when that changed.
    fn presence(&mut self) {
        let health = self.health();
        let serving = health.as_ref().is_some_and(Health::is_serving);
        let pid = match health {
            Some(Health::Running { pid } | Health::LineDown { pid, .. }) => Some(pid),
            _ => None,
        };
        if pid.is_some() && pid != self.pid {
            self.pid = pid;
            self.follow_drives();
        }
        if serving != self.serving {
            self.serving = serving;
            self.token = if serving {
                match self
                    .session
                    .liveliness()
                    .declare_token(self.o.keys.alive())
                    .wait()
                {
                    Ok(t) => Some(t),
                    Err(e) => {
                        eprintln!("uss-zenoh: liveliness token {}: {e}", self.o.keys.alive());
                        None
                    }
                }
            } else {
                None
            };
            self.next_status = Instant::now();
        }
        if Instant::now() >= self.next_status {
            self.next_status = Instant::now() + STATUS_EVERY;
            let status = self.bus.as_ref().and_then(|b| b.status().ok());
            put(
                self.session,
                &self.o.keys.status(),
                &Status {
                    refused: self.o.gate.refused(),
                    ..Status::new(&self.o.bus, health.as_ref(), status.as_ref())
                },
            );
        }
    }

    /// Publishes the image of each drive in `due` (a bit per address) that changed (and, while
    /// ussd does not serve the bus or the drive's poll is overdue, its last image once, marked
    /// stale).
    fn inputs(&mut self, due: u32) {
        let min_gap = self
            .o
            .max_rate
            .filter(|r| *r > 0.0)
            .map(|r| Duration::from_secs_f64(1.0 / r));
        for d in &mut self.drives {
            if due & (1 << d.watch.address().get()) == 0 {
                continue;
            }
            let look = d.watch.snapshot();
            let stale = !self.serving || look.problem.is_some();
            let image = look.image;
            let changed = d
                .last
                .is_none_or(|(last, last_stale)| !last.same_picture(&image) || last_stale != stale);
            // A stale mark always goes out; fresh images at most at `max_rate`.
            let too_soon = !stale
                && d.last.is_some_and(|(_, s)| !s)
                && min_gap.is_some_and(|gap| d.sent_at.is_some_and(|t| t.elapsed() < gap));
            if changed && !too_soon {
                put(
                    self.session,
                    &d.key,
                    &Input::new(
                        &self.o.bus,
                        d.watch.address().get(),
                        &image,
                        &look.info,
                        stale,
                    ),
                );
                d.last = Some((image, stale));
                d.sent_at = Some(Instant::now());
            }
        }
    }

    fn diagnostics(&mut self) {
        let now = Instant::now();
        let (diag_due, info_due) = (now >= self.next_diag, now >= self.next_info);
        if !diag_due && !info_due {
            return;
        }
        let Some(bus) = &self.bus else { return };
        for d in &mut self.drives {
            let a = d.watch.address();
            let read = bus.diag(a).ok();
            if read.is_some() {
                d.last_diag = read;
            }
            let Some(diag) = d.last_diag else { continue };
            if diag_due {
                put(
                    self.session,
                    &self.o.keys.diag(a),
                    &Diag::new(&self.o.bus, &diag, !self.serving || read.is_none()),
                );
            }
            if info_due && read.is_some() {
                put(
                    self.session,
                    &self.o.keys.info(a),
                    &Info::new(&self.o.bus, &diag),
                );
            }
        }
        if diag_due {
            self.next_diag = now + DIAG_EVERY;
        }
        if info_due {
            self.next_info = now + INFO_EVERY;
        }
    }
}

/// Publishes bus `o.bus` until `stop`; withdraws its token on the way out.
pub fn run(session: &Session, o: &Options, stop: &Arc<AtomicBool>) {
    let now = Instant::now();
    let mut p = Publisher {
        session,
        o,
        bus: None,
        next_open: now,
        drives: Vec::new(),
        token: None,
        serving: false,
        pid: None,
        next_status: now,
        next_diag: now,
        next_info: now,
    };
    let mut cycle = None;
    let mut next_sweep = now;
    while !stop.load(Ordering::Relaxed) {
        if !p.open() {
            p.presence();
            std::thread::sleep(RECONNECT.min(Duration::from_millis(50)));
            continue;
        }
        if cycle.is_none() {
            cycle = p.bus.as_ref().and_then(|b| b.cycle_listener().ok());
        }
        // Woken by the exchange events, which name the drives to look at; while ussd is gone
        // the wait fails at once.
        let mut due = 0u32;
        let waited = cycle.as_ref().map(|c| {
            c.wait(WAIT_STEP, |e| {
                if let CycleEvent::Exchange(a) = e {
                    due |= 1u32.checked_shl(u32::from(a)).unwrap_or(0);
                }
            })
        });
        if !matches!(waited, Some(Ok(_))) {
            std::thread::sleep(WAIT_STEP);
        }
        p.presence();
        if !p.serving || Instant::now() >= next_sweep {
            due = ALL;
            next_sweep = Instant::now() + SWEEP_EVERY;
        }
        p.inputs(due);
        p.diagnostics();
    }
    if let Some(t) = p.token.take() {
        let _ = t.undeclare().wait();
    }
}
