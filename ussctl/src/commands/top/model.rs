//! One bus's screen: the connection to its ussd (opened again and again while there is none),
//! what was read last, rates between two reads, and when each shown value last changed.

use super::Pending;
use super::detail::{Detail, Reader};
use crate::report::{BusView, ControlView, DriveView};
use core::time::Duration;
use std::collections::HashMap;
use std::time::Instant;
use uss_client::uss_protocol::Zsw1;
use uss_client::{Address, Bus, BusStatus, DriveDiag, DriveWatch, Health, PzdInput, Setpoint};

/// How often a bus without ussd is tried again.
const RECONNECT: Duration = Duration::from_secs(1);
/// How long a changed value stays marked.
pub(crate) const MARKED_FOR: Duration = Duration::from_secs(2);

/// A drive as last read: ussd's diagnostics and the input image.
pub(crate) struct TopDrive {
    /// As ussd lists it (the same as `diag.address`).
    pub address: Address,
    pub diag: DriveDiag,
    pub row: DriveView,
    /// The setpoint the last poll sent, Hz (None before an image was read).
    pub set_hz: Option<f32>,
    /// The image's control, with the operator's process behind an override.
    pub control: ControlView,
}

/// The columns whose changes are marked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Col {
    Online,
    Control,
    State,
    Zsw1,
    Rejected,
    Timeouts,
    LastError,
}

/// One bus.
pub(crate) struct Screen {
    pub name: String,
    bus: Option<Bus>,
    /// Why no ussd could be reached (while `bus` is None).
    pub open_error: Option<String>,
    next_open: Instant,
    watches: Vec<DriveWatch>,
    pub health: Option<Health>,
    pub status: Option<BusStatus>,
    pub report: Option<BusView>,
    pub drives: Vec<TopDrive>,
    /// Exchanges per second and cycle time (ms), from the last two status publications.
    pub rates: Option<(f64, f64)>,
    last_counts: Option<(u64, u64, u64)>,
    /// When the read of the status or the drives last failed, and why.
    pub read_error: Option<String>,
    pub selected: usize,
    /// Each marked value's last text and when it changed.
    changes: HashMap<(u8, Col), (String, Instant)>,
    /// The selected drive's own counters and fault buffer, when read.
    pub detail: Option<Detail>,
}

impl Screen {
    pub(crate) fn new(name: &str) -> Self {
        Self {
            name: name.to_owned(),
            bus: None,
            open_error: None,
            next_open: Instant::now(),
            watches: Vec::new(),
            health: None,
            status: None,
            report: None,
            drives: Vec::new(),
            rates: None,
            last_counts: None,
            read_error: None,
            selected: 0,
            changes: HashMap::new(),
            detail: None,
        }
    }

    pub(crate) fn selected_drive(&self) -> Option<Address> {
        self.drives.get(self.selected).map(|d| d.address)
    }

    pub(crate) fn select(&mut self, step: isize) {
        if !self.drives.is_empty() {
            let last = self.drives.len() - 1;
            self.selected = self.selected.saturating_add_signed(step).min(last);
        }
    }

    /// Whether the value in `col` of `drive` changed within [`MARKED_FOR`].
    pub(crate) fn changed(&self, drive: u8, col: Col) -> bool {
        self.changes
            .get(&(drive, col))
            .is_some_and(|(_, at)| at.elapsed() < MARKED_FOR)
    }

    /// Whether a ussd was reached (its last picture may be stale since).
    pub(crate) fn bus_open(&self) -> bool {
        self.bus.is_some()
    }

    /// Whether ussd serves the bus (its heartbeat is fresh and says so).
    pub(crate) fn serving(&self) -> bool {
        self.health.as_ref().is_some_and(Health::is_serving)
    }

    /// Reads the bus again; `shown`: ask for the selected drive's own counters too.
    pub(crate) fn refresh(&mut self, details: &Reader, shown: bool) {
        if self.bus.is_none() {
            if Instant::now() < self.next_open {
                return;
            }
            self.next_open = Instant::now() + RECONNECT;
            match Bus::open_as(&self.name, "ussctl-top") {
                Ok(bus) => {
                    self.bus = Some(bus);
                    self.open_error = None;
                }
                Err(e) => {
                    self.open_error = Some(e.to_string());
                    return;
                }
            }
        }
        let Some(bus) = &self.bus else { return };
        self.health = Some(bus.health());
        match read(bus, &mut self.watches) {
            Ok((status, drives)) => {
                self.read_error = None;
                self.rate(&status);
                self.report = Some(BusView::new(&self.name, &status));
                self.status = Some(status);
                self.mark(&drives);
                self.drives = drives;
                self.selected = self.selected.min(self.drives.len().saturating_sub(1));
            }
            Err(e) => self.read_error = Some(e.to_string()),
        }
        if let Some(mut d) = details.take(&self.name) {
            // A read without the fault buffer keeps the last one read of the same drive.
            if d.faults.is_none() {
                d.faults = self
                    .detail
                    .take()
                    .filter(|old| old.drive == d.drive)
                    .and_then(|old| old.faults);
            }
            self.detail = Some(d);
        }
        if shown
            && self.serving()
            && let Some(d) = self.drives.get(self.selected)
        {
            let bits = d.diag.last_zsw1 & (Zsw1::FAULT | Zsw1::WARNING).bits();
            details.want(&self.name, d.address, bits);
        }
    }

    fn rate(&mut self, s: &BusStatus) {
        let now = (s.timestamp_ns, s.exchanges, s.cycles);
        if let Some((t, exchanges, cycles)) = self.last_counts {
            if now.0 > t && now.1 >= exchanges {
                let dt = (now.0 - t) as f64 / 1e9;
                let per_s = (now.1 - exchanges) as f64 / dt;
                let cycle_ms = if now.2 > cycles {
                    dt * 1e3 / (now.2 - cycles) as f64
                } else {
                    f64::NAN
                };
                self.rates = Some((per_s, cycle_ms));
            } else if now.0 == t {
                return;
            }
        }
        self.last_counts = Some(now);
    }

    /// Notes which shown values changed since the last read.
    fn mark(&mut self, drives: &[TopDrive]) {
        let now = Instant::now();
        for d in drives {
            let r = &d.row;
            for (col, text) in [
                (Col::Online, r.online.to_string()),
                (Col::Control, d.control.human()),
                (Col::State, r.state.to_owned()),
                (Col::Zsw1, r.zsw1_hex.clone()),
                (Col::Rejected, r.rejected.to_string()),
                (Col::Timeouts, r.timeouts.to_string()),
                (Col::LastError, r.last_error.to_owned()),
            ] {
                match self.changes.get_mut(&(r.address, col)) {
                    Some((last, at)) if *last != text => {
                        *last = text;
                        *at = now;
                    }
                    Some(_) => {}
                    None => {
                        // The first read is no change.
                        self.changes.insert(
                            (r.address, col),
                            (text, now.checked_sub(MARKED_FOR).unwrap_or(now)),
                        );
                    }
                }
            }
        }
    }

    /// Sends a confirmed stop; the text says what was sent.
    pub(crate) fn stop(&self, p: Pending) -> Result<String, String> {
        let bus = self
            .bus
            .as_ref()
            .ok_or_else(|| format!("no ussd serves bus {}", self.name))?;
        match p.drive {
            Some(d) => bus.stop_drive(d, p.command).map(|()| {
                format!(
                    "{} sent to drive {d}: latched until its controller re-arms it",
                    p.command
                )
            }),
            None => bus.stop_all(p.command).map(|all| {
                format!(
                    "{} sent to every drive of bus {} ({} drives): latched until re-armed",
                    p.command,
                    self.name,
                    all.len()
                )
            }),
        }
        .map_err(|e| e.to_string())
    }
}

/// The bus status and each drive, with the watches of the drives ussd serves now.
fn read(
    bus: &Bus,
    watches: &mut Vec<DriveWatch>,
) -> Result<(BusStatus, Vec<TopDrive>), uss_client::ClientError> {
    let status = bus.status()?;
    let addresses = bus.drives();
    if watches
        .iter()
        .map(DriveWatch::address)
        .ne(addresses.iter().copied())
    {
        *watches = addresses
            .iter()
            .filter_map(|&a| bus.watch(a).ok())
            .collect();
    }
    let mut drives = Vec::with_capacity(addresses.len());
    for &a in &addresses {
        let diag = bus.diag(a)?;
        let look = watches
            .iter()
            .find(|w| w.address() == a)
            .map(DriveWatch::snapshot);
        // The drive's poll overdue by ussd's own limit (a stalled bus thread): not online as
        // the diagnostics last said.
        let overdue = look
            .as_ref()
            .is_some_and(|l| matches!(l.problem, Some(uss_client::ClientError::Stale { .. })));
        let image: Option<PzdInput> = look.map(|l| l.image);
        let set_hz = image.and_then(|i| {
            let reference = diag.info.reference()?;
            Some(Setpoint::from_word(i.sent_setpoint).hz(reference))
        });
        let control = image.map_or_else(
            || ControlView::of_diag(&diag),
            |i| ControlView::of_input(&i),
        );
        let row = DriveView::new(&diag, uss_client::monotonic_ns()).stale_when(overdue);
        drives.push(TopDrive {
            address: a,
            diag,
            row,
            set_hz,
            control,
        });
    }
    Ok((status, drives))
}
