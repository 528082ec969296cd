//! `status`: the bus and its drives, each drive's control (live or latched, why).

use std::fmt::Write as _;

/// The client's one view of the bus, of a drive and of its control (`uss_client::view`), as
/// Python and the bridge show them too; ussctl adds only its human lines and warnings.
pub use uss_client::view::{BusView, ControlView, DriveView};

/// The bus's line in `status` and `top`.
pub trait BusLine {
    fn human(&self) -> String;
}

impl BusLine for BusView {
    fn human(&self) -> String {
        let mut out = format!(
            "bus {}: {}, {}{}, {} drives, {} cycles, {} exchanges ({} good), mean exchange {:.0} us",
            self.bus,
            if self.running { "running" } else { "stopped" },
            self.rt_mode,
            if self.rt_cpu >= 0 {
                format!(" on CPU {} priority {}", self.rt_cpu, self.rt_priority)
            } else {
                String::new()
            },
            self.drive_count,
            self.cycles,
            self.exchanges,
            self.good,
            self.mean_exchange_us,
        );
        if let Some(e) = self.efficiency {
            let _ = write!(out, ", efficiency {e:.2}");
        }
        if self.out_of_turn > 0 {
            let _ = write!(out, ", {} polls out of turn", self.out_of_turn);
        }
        if self.broadcasts > 0 {
            let _ = write!(out, ", {} broadcast stops", self.broadcasts);
        }
        if let Some(error) = &self.line_error {
            let _ = write!(
                out,
                "\nLINE DOWN ({error}): every drive offline; ussd reopens the device ({} attempts so far)",
                self.reopen_attempts
            );
        }
        out
    }
}

pub(super) use uss_client::view::last_failure;

/// What `status` warns of a drive.
trait DriveWarnings {
    fn commands_warning(&self) -> Option<String>;
    fn monitoring_warning(&self) -> Option<String>;
}

impl DriveWarnings for DriveView {
    /// A drive that answers but does not take its commands from this link.
    fn commands_warning(&self) -> Option<String> {
        (self.online && !self.takes_commands && d_has_pzd(self)).then(|| {
            format!(
                "drive {}: NOT CONTROLLABLE: it does not take its commands from this link (ZSW1 bit 9, control requested, is 0): it ignores ussd's control words, stops included; its command source is elsewhere{}",
                self.address,
                command_source_hint(self.profile)
            )
        })
    }

    /// Whether the drive's own telegram monitoring deserves a warning; the parameter and the
    /// fault are its family profile's.
    fn monitoring_warning(&self) -> Option<String> {
        let param = self
            .profile
            .and_then(|c| c.monitoring)
            .map_or_else(|| "its telegram-off time".to_owned(), |p| p.to_string());
        let fault = self
            .profile
            .and_then(uss_client::Catalogue::telegram_off_fault_name)
            .unwrap_or_else(|| "its telegram-off fault".to_owned());
        match self.monitoring {
            "on" | "not read yet" | "not checked" => None,
            "off" => Some(format!(
                "drive {}: telegram monitoring is OFF: if ussd or its line dies, nothing stops this drive; set {param}, e.g. to 100 ms",
                self.address
            )),
            "shorter than the poll period" => Some(format!(
                "drive {}: telegram monitoring is {} ms, shorter than the time between two polls of it on this bus (up to {} ms): it trips ({fault}) between polls; set {param} to at least {} ms, or poll it more often",
                self.address, self.monitoring_ms, self.monitoring_min_ms, self.monitoring_min_ms
            )),
            "longer than the limit" => Some(format!(
                "drive {}: telegram monitoring is {} ms, longer than monitoring_max_ms: after ussd or its line dies it runs on for that long",
                self.address, self.monitoring_ms
            )),
            other => Some(format!(
                "drive {}: telegram monitoring {other}: check monitoring_param in ussd's configuration",
                self.address
            )),
        }
    }
}

/// What makes a drive of `profile`'s family take its commands from USS: "(P0700 = 5 takes
/// them from USS)", or nothing where uss-rt does not know it.
fn command_source_hint(profile: Option<&uss_client::Catalogue>) -> String {
    profile
        .and_then(uss_client::Catalogue::command_source_setting)
        .map(|s| format!(" ({s} takes them from USS)"))
        .unwrap_or_default()
}

/// Whether the drive's images carry a ZSW1 at all (PZD words configured): a drive without
/// process data has no control word to take.
fn d_has_pzd(d: &DriveView) -> bool {
    d.pzd_words > 0
}

/// `status`: the client's one view of the bus and its drives.
pub use uss_client::view::StatusView as StatusReport;

/// `status`'s lines.
pub trait StatusLines {
    fn human(&self) -> String;
}

impl StatusLines for StatusReport {
    fn human(&self) -> String {
        let mut out = self.bus.human();
        out.push('\n');
        let _ = writeln!(
            out,
            "{:>4}  {:<6}  {:<9}  {:<6}  {:>9}  {:>10}  {:>8}  {:>8}  {:>9}  {:<16}  {:<32}  flags",
            "addr",
            "online",
            "state",
            "ZSW1",
            "actual Hz",
            "good",
            "rejected",
            "timeouts",
            "polled ms",
            "last error",
            "control"
        );
        for d in &self.drives {
            let _ = writeln!(
                out,
                "{:>4}  {:<6}  {:<9}  {:<6}  {:>9.2}  {:>10}  {:>8}  {:>8}  {:>9}  {:<16}  {:<32}  {}",
                d.address,
                if d.online { "yes" } else { "no" },
                d.state,
                d.zsw1_hex,
                d.actual_hz,
                d.good,
                d.rejected,
                d.timeouts,
                d.period_ms
                    .map_or_else(|| "-".to_owned(), |ms| format!("{ms:.0}")),
                d.last_error,
                d.control.human(),
                d.flags.join(",")
            );
        }
        for warning in self.drives.iter().filter_map(DriveView::commands_warning) {
            let _ = writeln!(out, "warning: {warning}");
        }
        for warning in self.drives.iter().filter_map(DriveView::monitoring_warning) {
            let _ = writeln!(out, "warning: {warning}");
        }
        if self.drives.iter().any(|d| d.control.state == "latched") {
            out.push_str(
                "latched: the drive gets the stop command shown until a controller re-arms it (its explicit rearm, `ussctl run`)\n",
            );
        }
        out
    }
}
