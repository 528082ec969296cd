//! The selected drive's own view, read over the parameter channel in a thread of its own (the
//! screen never waits for the bus): its USS telegram counters r2024..r2031 of the COM link and
//! its fault buffer with the active warnings. Read again every few seconds while selected.

use core::time::Duration;
use std::collections::HashMap;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant;
use uss_client::uss_protocol::{ParamTask, Pnu, Subindex};
use uss_client::{Address, Bus, FaultReport};

/// How often the selected drive's counters are read again (8 reads in one request).
const PERIOD: Duration = Duration::from_secs(3);
/// How often its fault buffer is read again (32 reads) when its fault and warning bits stay as
/// they were.
const FAULTS_PERIOD: Duration = Duration::from_secs(30);

/// The drive's USS diagnostics r2024..r2031, as MICROMASTER 4 names them.
pub(crate) const COUNTERS: [(u16, &str); 8] = [
    (2024, "error-free"),
    (2025, "rejected"),
    (2026, "character frame"),
    (2027, "overrun"),
    (2028, "parity"),
    (2029, "start not found"),
    (2030, "BCC"),
    (2031, "length"),
];

/// Index of the COM link (RS485) in r2024..r2031; index 1 is the BOP link (MM420 Parameter
/// List 04/02 p.84).
const COM_LINK: u8 = 0;

/// One read of a drive.
pub(crate) struct Detail {
    pub drive: Address,
    pub at: Instant,
    /// r2024..r2031, each read or why not.
    pub counters: Vec<Result<u16, String>>,
    /// None: not read this time (the last read still holds).
    pub faults: Option<Result<FaultReport, String>>,
}

/// A wish: which drive, and whether its fault buffer too.
struct Wish {
    bus: String,
    drive: Address,
    faults: bool,
}

/// The thread that reads, and what it has read for each bus.
pub(crate) struct Reader {
    want: Sender<Wish>,
    done: Arc<Mutex<HashMap<String, Detail>>>,
    /// What was asked last, per bus: the drive, when, and when with the fault buffer (and the
    /// drive's fault and warning bits then).
    asked: Mutex<HashMap<String, Asked>>,
}

struct Asked {
    drive: Address,
    at: Instant,
    faults_at: Instant,
    bits: u16,
}

impl Reader {
    pub(crate) fn start() -> Self {
        let (want, wanted) = channel();
        let done = Arc::new(Mutex::new(HashMap::new()));
        let results = Arc::clone(&done);
        // Without the thread nothing is read, and the pane keeps saying so.
        let _ = std::thread::Builder::new()
            .name("top-detail".into())
            .spawn(move || serve(&wanted, &results));
        Self {
            want,
            done,
            asked: Mutex::new(HashMap::new()),
        }
    }

    /// Asks for `drive` of `bus` unless it was asked for within [`PERIOD`]; its fault buffer
    /// too when the drive is newly selected, its fault or warning bit (`bits` of ZSW1) changed,
    /// or after [`FAULTS_PERIOD`].
    pub(crate) fn want(&self, bus: &str, drive: Address, bits: u16) {
        let mut asked = self.asked.lock().unwrap_or_else(PoisonError::into_inner);
        let now = Instant::now();
        let (due, faults) = match asked.get(bus) {
            Some(a) if a.drive == drive => (
                a.at.elapsed() >= PERIOD || a.bits != bits,
                a.faults_at.elapsed() >= FAULTS_PERIOD || a.bits != bits,
            ),
            _ => (true, true),
        };
        if due {
            let last = asked.get(bus).filter(|a| a.drive == drive);
            let faults_at = if faults {
                now
            } else {
                last.map_or(now, |a| a.faults_at)
            };
            asked.insert(
                bus.to_owned(),
                Asked {
                    drive,
                    at: now,
                    faults_at,
                    bits,
                },
            );
            let _ = self.want.send(Wish {
                bus: bus.to_owned(),
                drive,
                faults,
            });
        }
    }

    /// The newest read of `bus`, once.
    pub(crate) fn take(&self, bus: &str) -> Option<Detail> {
        self.done
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(bus)
    }
}

/// Reads what is wanted, one at a time, the newest wish of each bus first.
fn serve(wanted: &Receiver<Wish>, done: &Mutex<HashMap<String, Detail>>) {
    let mut buses: HashMap<String, Bus> = HashMap::new();
    while let Ok(first) = wanted.recv() {
        let mut latest: HashMap<String, Wish> = HashMap::new();
        for w in core::iter::once(first).chain(wanted.try_iter()) {
            // A later wish for the same drive keeps an earlier wish's fault buffer read.
            let faults = w.faults
                || latest
                    .get(&w.bus)
                    .is_some_and(|l| l.drive == w.drive && l.faults);
            latest.insert(w.bus.clone(), Wish { faults, ..w });
        }
        for (name, wish) in latest {
            if !buses.contains_key(&name) {
                match Bus::open_as(&name, "ussctl-top-params") {
                    Ok(bus) => {
                        buses.insert(name.clone(), bus);
                    }
                    Err(_) => continue,
                }
            }
            let Some(bus) = buses.get(&name) else {
                continue;
            };
            let detail = read(bus, wish.drive, wish.faults);
            done.lock()
                .unwrap_or_else(PoisonError::into_inner)
                .insert(name, detail);
        }
    }
}

fn read(bus: &Bus, drive: Address, faults: bool) -> Detail {
    let tasks: Vec<ParamTask> = COUNTERS
        .iter()
        .filter_map(|&(pnu, _)| {
            Subindex::new(COM_LINK)
                .ok()
                .map(|i| ParamTask::read(Pnu::from_u16(pnu), Some(i)))
        })
        .collect();
    let counters = bus
        .batch(drive, &tasks)
        .into_iter()
        .map(|r| r.map(|v| v.as_u32() as u16).map_err(|e| e.to_string()))
        .collect();
    Detail {
        drive,
        at: Instant::now(),
        counters,
        faults: faults.then(|| bus.fault_report(drive).map_err(|e| e.to_string())),
    }
}
