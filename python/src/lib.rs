//! `uss_rt._native`: the Rust client of uss-rt (`uss-client`) for Python. The heartbeat,
//! generation, latch and request rules are the Rust code itself (a controller's samples are
//! decided by `uss_control::session`), not a Python copy; `uss_rt/__init__.py` gives it the
//! documented Python API (enums, exception classes, `Value`). Every call that waits (a
//! parameter request, a re-arm, a wait for the drive) releases the GIL meanwhile.

mod control;
mod errors;
mod params;

use core::time::Duration;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::collections::HashMap;
use std::sync::{Mutex, PoisonError};
use uss_client::{Bus as RustBus, DriveWatch, Health, PzdInput, StopCommand};

/// An open bus: one iceoryx2 node, ussd's heartbeat and the services of the generation it
/// names (followed by themselves when a restarted ussd serves a new one).
#[pyclass(frozen, module = "uss_rt._native")]
struct Bus {
    inner: RustBus,
    /// One watch per drive read, kept so a read neither opens nor allocates.
    watches: Mutex<HashMap<u8, DriveWatch>>,
}

impl Bus {
    fn watch<R>(
        &self,
        py: Python<'_>,
        address: u8,
        f: impl FnOnce(&DriveWatch) -> R,
    ) -> PyResult<R> {
        let mut watches = self.watches.lock().unwrap_or_else(PoisonError::into_inner);
        let watch = match watches.entry(address) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => e.insert(
                self.inner
                    .watch(errors::drive(py, address)?)
                    .map_err(|err| errors::client(py, err))?,
            ),
        };
        Ok(f(watch))
    }
}

/// `state`, `pid` and, for a line down, its fault in words, of a heartbeat's health.
fn health_tuple(health: Health, bus: &str) -> (&'static str, u32, Option<String>) {
    let text = health.error(bus).map(|e| e.to_string());
    match health {
        Health::Running { pid } => ("running", pid, None),
        Health::LineDown { pid, .. } => ("line down", pid, text),
        Health::Stopped { pid, .. } => ("stopped", pid, text),
        Health::Gone { pid, .. } => ("gone", pid, text),
    }
}

#[pymethods]
impl Bus {
    #[getter]
    fn name(&self) -> &str {
        self.inner.name()
    }

    /// `(state, pid, problem)`: "running", "line down", "stopped" or "gone", ussd's process,
    /// and what a call that needs a polling bus would be told (None while running).
    fn health(&self) -> (&'static str, u32, Option<String>) {
        health_tuple(self.inner.health(), self.inner.name())
    }

    /// Raises what the heartbeat says when ussd does not poll the bus.
    fn check(&self, py: Python<'_>) -> PyResult<()> {
        match self.inner.health().error(self.inner.name()) {
            Some(e) => Err(errors::client(py, e)),
            None => Ok(()),
        }
    }

    /// The drives ussd polls, ascending (a list: a `Vec<u8>` would be `bytes`).
    fn drives(&self) -> Vec<u32> {
        widen(&self.inner.drives())
    }

    /// The bus status as ussd last published it, as a dict: the client's view of it (the fields
    /// of `ussctl status --json`'s `bus`), with the contract's layout `version` and `line_down`.
    fn status<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        // `ussctl status --json`'s view of the bus and its drives, and the contract's version
        // and line state of the same status.
        let s = self.inner.status().map_err(|e| errors::client(py, e))?;
        let view =
            uss_client::view::StatusView::of(&self.inner).map_err(|e| errors::client(py, e))?;
        let json =
            serde_json::to_string(&view).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let d = py
            .import("json")?
            .call_method1("loads", (json,))?
            .cast_into::<PyDict>()?;
        d.set_item("version", s.version)?;
        d.set_item("line_down", s.is_line_down())?;
        Ok(d)
    }

    /// A drive's diagnostics as ussd last published them: a dict with `info` and `counters`.
    fn diag<'py>(&self, py: Python<'py>, address: u8) -> PyResult<Bound<'py, PyDict>> {
        let diag = self
            .inner
            .diag(errors::drive(py, address)?)
            .map_err(|e| errors::client(py, e))?;
        let info = PyDict::new(py);
        info.set_item("reference_hz", diag.info.reference_hz)?;
        info.set_item("watchdog_ms", diag.info.watchdog_ms)?;
        info.set_item("safe_command", diag.info.safe_command)?;
        info.set_item("params_writable", diag.info.params_writable != 0)?;
        info.set_item("pkw_words", diag.info.pkw_words)?;
        info.set_item("pzd_words", diag.info.pzd_words)?;
        info.set_item("weight", diag.info.weight)?;
        let family = uss_client::DriveFamily::try_from(diag.info.family);
        info.set_item("family", family.map_or("unknown", |f| f.name()))?;
        let counters = PyDict::new(py);
        for (name, value) in diag.counters.named() {
            counters.set_item(name, value)?;
        }
        let d = PyDict::new(py);
        d.set_item("address", address)?;
        // Rule 3: diagnostics older than ussd's limit for them are not the drive as it is.
        let now = uss_client::monotonic_ns();
        d.set_item("online", diag.is_online_at(now))?;
        d.set_item("stale", diag.is_overdue(now))?;
        d.set_item("control", diag.control)?;
        d.set_item("latch_reason", diag.latch_reason)?;
        d.set_item("monitoring", diag.monitoring)?;
        d.set_item("monitoring_ms", diag.monitoring_ms)?;
        d.set_item("controller_pid", diag.controller_pid)?;
        d.set_item("info", info)?;
        d.set_item("counters", counters)?;
        Ok(d)
    }
}

/// The input image as a dict of its fields, codes as plain integers (`uss_rt` makes them
/// enums); `health` is the heartbeat's state when it was read.
pub(crate) fn image_dict<'py>(
    py: Python<'py>,
    address: u8,
    i: &PzdInput,
    health: &str,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("address", address)?;
    d.set_item("online", i.online)?;
    d.set_item("known", i.known)?;
    d.set_item("health", health)?;
    d.set_item("control", i.control)?;
    d.set_item("latch_reason", i.latch_reason)?;
    d.set_item("latch_command", i.latch_command)?;
    d.set_item("latches", i.latches)?;
    d.set_item("latched_since_ns", i.latched_since_ns)?;
    d.set_item("latch_id", i.latch_id)?;
    d.set_item("latched_by_pid", i.latched_by_pid)?;
    d.set_item("rejection", i.rejection)?;
    d.set_item("sent_stw1", i.sent_stw1)?;
    d.set_item("sent_setpoint", i.sent_setpoint)?;
    d.set_item("taken_sequence", i.taken_sequence)?;
    d.set_item("sequence", i.sequence)?;
    d.set_item("timestamp_ns", i.timestamp_ns)?;
    d.set_item("age_ns", i.age_ns)?;
    d.set_item("period_ns", i.period_ns)?;
    d.set_item("stale_after_ns", i.stale_after_ns)?;
    d.set_item("zsw1", i.zsw1)?;
    d.set_item("hiw", i.hiw)?;
    d.set_item("word_count", i.word_count)?;
    let words = i.words().map(|(w, n)| w[..n].to_vec()).unwrap_or_default();
    d.set_item("words", PyList::new(py, words)?)?;
    Ok(d)
}

/// When this process started, `CLOCK_MONOTONIC` ns (the kernel's start time, rounded down to
/// its 10 ms tick): what a script that re-arms once it is set up passes to `rearm`.
#[pyfunction]
fn process_start_ns() -> PyResult<u64> {
    uss_client::process_start_ns().map_err(pyo3::exceptions::PyOSError::new_err)
}

/// Opens bus `name` of a running ussd as node `node_name` (waits at most 0.5 s for its
/// heartbeat, without the GIL).
#[pyfunction]
fn open_bus(py: Python<'_>, name: &str, node_name: &str) -> PyResult<Bus> {
    let opened = py.detach(|| RustBus::open_as(name, node_name));
    let inner = opened.map_err(|e| errors::client(py, e))?;
    Ok(Bus {
        inner,
        watches: Mutex::default(),
    })
}

/// Drive `address`'s input image as ussd last wrote it; while ussd does not poll (gone,
/// stopped, line down) the last one read, `online` 0, `health` saying why.
#[pyfunction]
fn read_input<'py>(
    py: Python<'py>,
    bus: &Bound<'py, Bus>,
    address: u8,
) -> PyResult<Bound<'py, PyDict>> {
    let bus = bus.get();
    let health = bus.inner.health();
    let state = health_tuple(health, bus.inner.name()).0;
    if !health.is_serving()
        && !bus
            .watches
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .contains_key(&address)
    {
        // Never read and ussd does not poll: an empty image, offline, saying why.
        return image_dict(py, address, &PzdInput::EMPTY, state);
    }
    let look = bus.watch(py, address, DriveWatch::snapshot)?;
    // A problem the snapshot saw marks it too: the drive's poll overdue by ussd's own limit
    // (a stalled bus thread), or ussd went between two looks.
    let state = match (&look.problem, state) {
        (Some(uss_client::ClientError::Stale { .. }), "running") => "stale",
        (Some(_), "running") => "gone",
        (_, s) => s,
    };
    image_dict(py, address, &look.image, state)
}

fn stop_command(code: u8) -> PyResult<StopCommand> {
    StopCommand::of_code(code)
        .ok_or_else(|| PyValueError::new_err("a stop command is OFF1, OFF2 or OFF3"))
}

/// An operator's stop of drive `address` (OFF1, OFF2, OFF3 code), whoever controls it.
#[pyfunction]
fn stop_drive(py: Python<'_>, bus: &Bound<'_, Bus>, address: u8, command: u8) -> PyResult<()> {
    let bus = bus.get();
    let command = stop_command(command)?;
    let drive = errors::drive(py, address)?;
    py.detach(|| bus.inner.stop_drive(drive, command))
        .map_err(|e| errors::client(py, e))
}

/// An operator's stop of every drive; the addresses it reached.
#[pyfunction]
fn stop_all(py: Python<'_>, bus: &Bound<'_, Bus>, command: u8) -> PyResult<Vec<u32>> {
    let bus = bus.get();
    let command = stop_command(command)?;
    py.detach(|| bus.inner.stop_all(command))
        .map(|drives| widen(&drives))
        .map_err(|e| errors::client(py, e))
}

/// Addresses as a Python list of ints (`PyO3` makes a `Vec<u8>` `bytes`).
fn widen(addresses: &[uss_client::Address]) -> Vec<u32> {
    addresses.iter().map(|a| u32::from(a.get())).collect()
}

/// Waits (at most `timeout` s, without the GIL; `None`: the drive's handshake time) until
/// drive `address`'s image shows an operator's stop at least as strong as `command` and its
/// control word went out.
#[pyfunction]
#[pyo3(signature = (bus, address, command, timeout=None))]
fn wait_stopped<'py>(
    py: Python<'py>,
    bus: &Bound<'py, Bus>,
    address: u8,
    command: u8,
    timeout: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let bus = bus.get();
    let command = stop_command(command)?;
    let timeout = timeout.map(duration).transpose()?;
    let drive = errors::drive(py, address)?;
    let image = py
        .detach(|| bus.inner.wait_stopped(drive, command, timeout))
        .map_err(|e| errors::client(py, e))?;
    let state = health_tuple(bus.inner.health(), bus.inner.name()).0;
    image_dict(py, address, &image, state)
}

/// Waits (at most `timeout` s, without the GIL) for `count` more exchanges with drive
/// `address`, so a loop runs in step with the bus; the image after them. Raises `WaitTimeout`
/// when they do not come, `UssdGone`, `UssdStopped` or `LineDown` when ussd does not poll.
#[pyfunction]
#[pyo3(signature = (bus, address, count=1, timeout=1.0))]
fn wait_exchange<'py>(
    py: Python<'py>,
    bus: &Bound<'py, Bus>,
    address: u8,
    count: u64,
    timeout: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let timeout = duration(timeout)?;
    let bus = bus.get();
    let drive = errors::drive(py, address)?;
    // A watch of its own: the bus's are not held through a wait (another thread's read).
    let image = py
        .detach(|| bus.inner.watch(drive)?.wait_exchanges(count, timeout))
        .map_err(|e| errors::client(py, e))?;
    image_dict(py, address, &image, "running")
}

pub(crate) fn duration(seconds: f64) -> PyResult<Duration> {
    Duration::try_from_secs_f64(seconds)
        .map_err(|_| PyValueError::new_err(format!("{seconds}: give a number of seconds >= 0")))
}

/// `{table: {member name: code}}` of every code table of the contract: `uss_rt` makes its
/// enums from them, so Python and Rust cannot disagree.
#[pyfunction]
fn code_tables(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    use uss_client::uss_shm_types as t;
    let tables = PyDict::new(py);
    macro_rules! table {
        ($($name:ident),* $(,)?) => {$(
            let d = PyDict::new(py);
            for v in t::$name::ALL {
                d.set_item(t::screaming_snake(&format!("{v:?}")), v.code())?;
            }
            tables.set_item(stringify!($name), d)?;
        )*};
    }
    table!(
        ControlState,
        LatchReason,
        Rejection,
        StopCommand,
        Monitoring,
        CommandError,
        RequestError,
        Outcome,
        TaskCode,
        Storage,
        LastFailure,
        LineState,
        LineFault,
        BusState,
        RtMode,
        Direction,
    );
    // The control word each stop command sends (USS.md section 7), as the contract says it.
    let stop_words = PyDict::new(py);
    for command in t::StopCommand::ALL {
        stop_words.set_item(command.code(), command.stw1())?;
    }
    tables.set_item("STOP_STW1", stop_words)?;
    Ok(tables)
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("LAYOUT_VERSION", uss_client::uss_shm_types::LAYOUT_VERSION)?;
    m.add_class::<Bus>()?;
    m.add_class::<control::Controller>()?;
    m.add_function(wrap_pyfunction!(open_bus, m)?)?;
    m.add_function(wrap_pyfunction!(process_start_ns, m)?)?;
    m.add_function(wrap_pyfunction!(read_input, m)?)?;
    m.add_function(wrap_pyfunction!(stop_drive, m)?)?;
    m.add_function(wrap_pyfunction!(stop_all, m)?)?;
    m.add_function(wrap_pyfunction!(wait_stopped, m)?)?;
    m.add_function(wrap_pyfunction!(wait_exchange, m)?)?;
    m.add_function(wrap_pyfunction!(code_tables, m)?)?;
    params::register(m)?;
    Ok(())
}

pub(crate) use Bus as NativeBus;
