//! Parameters from Python: raw words, the manuals' notation as their own type (the catalogue
//! and the drive's own description, as in Rust), the fault report.

use crate::errors;
use crate::{NativeBus, duration};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use uss_client::uss_protocol::{ParamRef, Prefix};
use uss_client::{Address, Catalogue, DataType, ParamValue, Quantity, Value, WriteOptions};

fn raw(v: Value) -> (u32, bool) {
    match v {
        Value::Word(w) => (u32::from(w), false),
        Value::Dword(d) => (d, true),
    }
}

/// Parameter `pnu`, element `index` if any: 0..=254 (USS.md section 6).
fn param_at(pnu: u16, index: Option<u16>) -> PyResult<ParamRef> {
    let bad = |i| {
        PyValueError::new_err(format!(
            "subindex {i} is out of range 0..=254 (USS.md section 6)"
        ))
    };
    let narrow = index
        .map(|i| u8::try_from(i).map_err(|_| bad(i)))
        .transpose()?;
    ParamRef::numbered(pnu, narrow).map_err(|_| bad(index.unwrap_or_default()))
}

/// `pnu` (or its element `index`) of drive `address` as the raw `(value, is_dword)`.
#[pyfunction]
#[pyo3(signature = (bus, address, pnu, index_=None, timeout=7.5))]
fn read_param(
    py: Python<'_>,
    bus: &Bound<'_, NativeBus>,
    address: u8,
    pnu: u16,
    index_: Option<u16>,
    timeout: f64,
) -> PyResult<(u32, bool)> {
    let param = param_at(pnu, index_)?;
    let drive = errors::drive(py, address)?;
    let bus = bus
        .get()
        .inner
        .with_answer_timeout(Some(duration(timeout)?));
    py.detach(|| bus.read(drive, param))
        .map(raw)
        .map_err(|e| errors::param(py, &bus, e))
}

/// Up to 39 raw items of drive `address` in one request, run one after the other with no
/// other client's task between them (as Rust's `Bus::batch`): each `(pnu, index)` reads,
/// `(pnu, index, value, is_dword)` writes (RAM; `eeprom` for RAM and EEPROM, `force` while
/// another process controls the drive). One entry per item, in order: `(value, is_dword)`, or
/// the exception that item ended with (not raised). A failure of the request as a whole
/// (ussd refused it, did not answer) is raised.
#[pyfunction]
#[pyo3(signature = (bus, address, items, eeprom=false, force=false, timeout=7.5))]
fn batch(
    py: Python<'_>,
    bus: &Bound<'_, NativeBus>,
    address: u8,
    items: Vec<(u16, Option<u16>, Option<u32>, bool)>,
    eeprom: bool,
    force: bool,
    timeout: f64,
) -> PyResult<Vec<Py<PyAny>>> {
    use uss_client::ParamTask;
    let drive = errors::drive(py, address)?;
    let storage = uss_client::WriteOptions {
        eeprom,
        ..uss_client::WriteOptions::default()
    }
    .storage();
    let tasks = items
        .into_iter()
        .map(|(pnu, index, value, is_dword)| {
            let p = param_at(pnu, index)?;
            Ok(match value {
                None => ParamTask::read(p.pnu, p.index),
                Some(v) => {
                    let value = Value::from_raw(v, is_dword).ok_or_else(|| {
                        PyValueError::new_err(format!(
                            "{v} does not fit a word (0..=65535): pass is_dword=True"
                        ))
                    })?;
                    ParamTask::write(p.pnu, p.index, value, storage)
                }
            })
        })
        .collect::<PyResult<Vec<_>>>()?;
    if tasks.is_empty() || tasks.len() > uss_client::uss_shm_types::MAX_PARAM_ITEMS {
        return Err(PyValueError::new_err(format!(
            "a batch has 1 to {} items, not {}",
            uss_client::uss_shm_types::MAX_PARAM_ITEMS,
            tasks.len()
        )));
    }
    let bus = bus
        .get()
        .inner
        .with_answer_timeout(Some(duration(timeout)?));
    let results = py
        .detach(|| bus.try_batch(drive, &tasks, force))
        .map_err(|e| errors::param(py, &bus, e))?;
    results
        .into_iter()
        .map(|r| match r {
            Ok(v) => Ok(raw(v).into_pyobject(py)?.into_any().unbind()),
            Err(e) => Ok(errors::param(py, &bus, e).into_value(py).into_any()),
        })
        .collect()
}

fn type_name(t: DataType) -> &'static str {
    match t {
        DataType::I16 => "I16",
        DataType::I32 => "I32",
        DataType::U16 => "U16",
        DataType::U32 => "U32",
        DataType::Float => "Float",
    }
}

/// A parameter value as a dict: `param` (`P1082`), `raw`, `is_dword`, `data_type`, `value`
/// (float or int), `unit`, `name`, `shown` (`50.00 Hz`), `text` (`P1082 = 50.00 Hz`).
fn value_dict<'py>(py: Python<'py>, v: &ParamValue) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let (raw, is_dword) = raw(v.raw);
    d.set_item("param", v.id())?;
    d.set_item("raw", raw)?;
    d.set_item("is_dword", is_dword)?;
    d.set_item("data_type", type_name(v.data_type))?;
    match v.value() {
        Quantity::Real(x) => d.set_item("value", x)?,
        Quantity::Whole(n) => d.set_item("value", n)?,
    }
    d.set_item("unit", v.unit())?;
    d.set_item("name", v.name())?;
    d.set_item("bits", v.info.is_some_and(|p| p.bits.is_some()))?;
    d.set_item("shown", v.shown())?;
    d.set_item("text", v.to_string())?;
    Ok(d)
}

fn param_ref(text: &str) -> PyResult<ParamRef> {
    text.trim()
        .parse::<ParamRef>()
        .map_err(|e| PyValueError::new_err(format!("{text:?}: {e}")))
}

/// Reads `param` in the manuals' notation as its own type.
#[pyfunction]
#[pyo3(signature = (bus, address, param, timeout=7.5))]
fn read<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    param: &str,
    timeout: f64,
) -> PyResult<Bound<'py, PyDict>> {
    typed(py, bus, address, param, timeout, |bus, drive, param| {
        bus.read_param(drive, param)
    })
}

/// Reads every element of an array parameter named without one (r0947: all 8), or the one
/// element or plain parameter named, each as its own type.
#[pyfunction]
#[pyo3(signature = (bus, address, param, timeout=7.5))]
fn read_elements<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    param: &str,
    timeout: f64,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let values = answered(py, bus, address, param, timeout, |bus, drive, param| {
        bus.read_elements(drive, param)
    })?;
    values.iter().map(|v| value_dict(py, v)).collect()
}

/// A parameter call `f` of `param` (its bus answering within `timeout` s), made without the GIL;
/// its error as the matching `uss_rt` exception.
fn answered<T: Send>(
    py: Python<'_>,
    bus: &Bound<'_, NativeBus>,
    address: u8,
    param: &str,
    timeout: f64,
    f: impl FnOnce(&uss_client::Bus, Address, ParamRef) -> Result<T, uss_client::ParamError> + Send,
) -> PyResult<T> {
    let param = param_ref(param)?;
    let drive = errors::drive(py, address)?;
    let bus = bus
        .get()
        .inner
        .with_answer_timeout(Some(duration(timeout)?));
    py.detach(|| f(&bus, drive, param))
        .map_err(|e| errors::param_of(py, &bus, drive, param, e))
}

/// A typed parameter call `f` of `param`, answered within `timeout` s, without the GIL.
fn typed<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    param: &str,
    timeout: f64,
    f: impl FnOnce(&uss_client::Bus, Address, ParamRef) -> Result<ParamValue, uss_client::ParamError>
    + Send,
) -> PyResult<Bound<'py, PyDict>> {
    value_dict(py, &answered(py, bus, address, param, timeout, f)?)
}

/// Writes `text` to `param`, converted to the parameter's own type; the value the drive holds.
#[pyfunction]
#[pyo3(signature = (bus, address, param, text, eeprom=false, force=false, timeout=7.5, unsafe_write=false))]
#[allow(clippy::too_many_arguments)] // the Python call's own keyword arguments
fn write<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    param: &str,
    text: &str,
    eeprom: bool,
    force: bool,
    timeout: f64,
    unsafe_write: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let options = WriteOptions {
        eeprom,
        force,
        unsafe_write,
    };
    typed(py, bus, address, param, timeout, |bus, drive, param| {
        bus.write_param(drive, param, text, options)
    })
}

/// A call `f` on drive `address` of `bus`, without the GIL, its error raised as Python's.
fn on_drive<T: Send>(
    py: Python<'_>,
    bus: &Bound<'_, NativeBus>,
    address: u8,
    f: impl FnOnce(&uss_client::Bus, Address) -> Result<T, uss_client::ParamError> + Send,
) -> PyResult<T> {
    let bus = &bus.get().inner;
    let drive = errors::drive(py, address)?;
    py.detach(|| f(bus, drive))
        .map_err(|e| errors::param(py, bus, e))
}

/// What ussd read of a drive again after a reset or a quick commissioning, into `d`.
fn read_again(d: &Bound<'_, PyDict>, picture: &uss_client::Picture) -> PyResult<()> {
    d.set_item("reference_hz", picture.reference_hz)?;
    d.set_item("monitoring", picture.monitoring.to_string())?;
    d.set_item("monitoring_ms", picture.monitoring_ms)
}

/// Puts every setting of the drive back to its factory value (P0010 = 30, P0970 = 1), waits
/// for it and for ussd's new reading: `{"writes": ["P0010 := 30", "P0970 := 1"], "seconds",
/// "reference_hz" (None: not read yet), "monitoring", "monitoring_ms"}`.
#[pyfunction]
#[pyo3(signature = (bus, address, unsafe_write=false, force=false))]
fn factory_reset<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    unsafe_write: bool,
    force: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let options = WriteOptions {
        eeprom: false,
        force,
        unsafe_write,
    };
    let reset = on_drive(py, bus, address, |bus, drive| {
        bus.factory_reset(drive, options)
    })?;
    let d = PyDict::new(py);
    d.set_item("writes", reset.writes())?;
    d.set_item("seconds", reset.took.as_secs_f64())?;
    read_again(&d, &reset.picture)?;
    Ok(d)
}

/// Quick commissioning: P0010 = 1, `motor` as `(param, text)` in order, then P3900 = `end`,
/// waited for: `{"writes": [...], "raised", "seconds", "reference_hz", "monitoring",
/// "monitoring_ms"}`.
#[pyfunction]
#[pyo3(signature = (bus, address, motor, end=3, unsafe_write=false, force=false))]
#[allow(
    clippy::needless_pass_by_value,
    reason = "pyo3 extracts the list by value"
)]
fn quick_commission<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    motor: Vec<(String, String)>,
    end: u16,
    unsafe_write: bool,
    force: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let options = WriteOptions {
        eeprom: false,
        force,
        unsafe_write,
    };
    let motor = motor
        .iter()
        .map(|(p, v)| Ok((param_ref(p)?, v.as_str())))
        .collect::<PyResult<Vec<_>>>()?;
    let done = on_drive(py, bus, address, |bus, drive| {
        bus.quick_commission(drive, &motor, end, options)
    })?;
    let d = PyDict::new(py);
    d.set_item("writes", done.writes())?;
    d.set_item("raised", done.raised_text())?;
    d.set_item("seconds", done.took.as_secs_f64())?;
    read_again(&d, &done.picture)?;
    Ok(d)
}

/// Every setting of the drive as the backup file's TOML (`Bus::upload_with`); `discover`
/// (first, last): also the settable parameters of that range the catalogue does not list, as
/// the drive describes them.
#[pyfunction]
#[pyo3(signature = (bus, address, discover=None))]
fn backup(
    py: Python<'_>,
    bus: &Bound<'_, NativeBus>,
    address: u8,
    discover: Option<(u16, u16)>,
) -> PyResult<String> {
    let options = uss_client::backup::UploadOptions {
        discover: discover.map(|(a, b)| a..=b),
    };
    let upload = on_drive(py, bus, address, |bus, drive| {
        bus.upload_with(drive, &options, &mut |_, _| {})
    })?;
    Ok(upload.file.to_text())
}

/// The drive compared with a backup file's TOML (`other` a str) or another drive (an int):
/// `{"same": n, "differ": [{"param", "name", "drive", "other"}], "ignored": [...]}`.
#[pyfunction]
fn diff<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    other: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let compared = if let Ok(text) = other.extract::<String>() {
        on_drive(py, bus, address, |bus, drive| {
            bus.diff_file(drive, &text, "backup", &mut |_, _| {})
        })?
    } else {
        let second = errors::drive(py, other.extract::<u8>()?)?;
        on_drive(py, bus, address, |bus, drive| {
            bus.diff_drives(drive, second, &mut |_, _| {})
        })?
    };
    let lines = pyo3::types::PyList::empty(py);
    for d in &compared.differ {
        let line = PyDict::new(py);
        line.set_item("param", d.param.to_string())?;
        line.set_item("name", d.info.name.as_str())?;
        line.set_item("drive", d.drive.map(|v| d.info.show(v)))?;
        line.set_item("other", d.other.map(|v| d.info.show(v)))?;
        lines.append(line)?;
    }
    let out = PyDict::new(py);
    out.set_item("same", compared.same)?;
    out.set_item("differ", lines)?;
    out.set_item("ignored", compared.ignored)?;
    Ok(out)
}

/// Ctrl-C of the Python program as the library's cancel of a restore or a scan: the call runs
/// without the GIL and asks Python between its steps whether a signal came.
#[derive(Default)]
struct Interrupted(std::sync::atomic::AtomicUsize);

impl uss_client::cancel::Cancel for Interrupted {
    fn asked(&self) -> usize {
        use std::sync::atomic::Ordering;
        if Python::attach(|py| py.check_signals().is_err()) {
            self.0.fetch_add(1, Ordering::Relaxed);
        }
        self.0.load(Ordering::Relaxed)
    }

    fn why(&self) -> &'static str {
        "Ctrl-C"
    }
}

/// Writes a backup file's TOML to the drive (`Bus::restore`): the report as a dict.
#[pyfunction]
#[pyo3(signature = (bus, address, text, eeprom=false, dry_run=false, force=false, unsafe_write=false, other_firmware=false, put_back_within=30.0))]
#[allow(
    clippy::too_many_arguments,
    clippy::fn_params_excessive_bools,
    reason = "the Python call's own keyword arguments"
)]
fn restore<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    text: &str,
    eeprom: bool,
    dry_run: bool,
    force: bool,
    unsafe_write: bool,
    other_firmware: bool,
    put_back_within: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let options = uss_client::restore::RestoreOptions {
        eeprom,
        dry_run,
        force,
        unsafe_write,
        other_firmware,
        put_back_within: duration(put_back_within)?,
    };
    let cancel = Interrupted::default();
    let done = on_drive(py, bus, address, |bus, drive| {
        let catalogue = uss_client::backup::settings_catalogue(drive, bus.family(drive))?;
        let loaded = uss_client::backup::BackupFile::parse(text, "backup", catalogue)?;
        bus.restore(
            drive,
            &loaded,
            options,
            &cancel,
            &mut |_, _| {},
            &mut |_| {},
        )
    })?;
    if uss_client::cancel::Cancel::asked(&cancel) > 0 {
        // What the restore raised is put back: the program stops as Ctrl-C asked.
        return Err(pyo3::exceptions::PyKeyboardInterrupt::new_err(format!(
            "the restore of drive {address} was cut short: {}",
            done.cut_short.as_deref().unwrap_or("Ctrl-C")
        )));
    }
    let lines = pyo3::types::PyList::empty(py);
    for l in &done.lines {
        let line = PyDict::new(py);
        line.set_item("param", &l.param)?;
        line.set_item("was", &l.was)?;
        line.set_item("wanted", &l.wanted)?;
        line.set_item("result", &l.result)?;
        lines.append(line)?;
    }
    let left: Vec<(String, u16, u16, &str)> = done
        .left_raised
        .iter()
        .map(|l| (l.param.to_string(), l.to, l.was, l.meaning))
        .collect();
    let d = PyDict::new(py);
    d.set_item("complete", done.is_complete())?;
    d.set_item("equal", done.equal)?;
    d.set_item("written", done.written)?;
    d.set_item("refused", done.refused)?;
    d.set_item("unknown", done.unknown)?;
    d.set_item("kept", done.kept)?;
    d.set_item("cut_short", &done.cut_short)?;
    d.set_item("left_raised", left)?;
    d.set_item("stored", &done.stored)?;
    d.set_item("ignored", &done.ignored)?;
    d.set_item("lines", lines)?;
    d.set_item("seconds", done.took.as_secs_f64())?;
    Ok(d)
}

/// Copies every setting of the drive from RAM to ROM (P0971 / p0971): `{"param": "P0971",
/// "raised": "P0003 1 -> 3 -> 1" or None}`.
#[pyfunction]
fn save_to_rom<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
) -> PyResult<Bound<'py, PyDict>> {
    let saved = on_drive(py, bus, address, uss_client::Bus::save_to_rom)?;
    let d = PyDict::new(py);
    d.set_item("param", saved.param.to_string())?;
    d.set_item("raised", saved.raised_text())?;
    Ok(d)
}

/// The fault buffer with values, times and texts, and the active warnings, where the drive's
/// family keeps them: `{"codes": "r0947", "values": "r0949", "warnings_from": "r2110",
/// "faults": [...], "warnings": [...] or None}`.
#[pyfunction]
fn fault_report<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
) -> PyResult<Bound<'py, PyDict>> {
    let report = on_drive(py, bus, address, uss_client::Bus::fault_report)?;
    let faults = pyo3::types::PyList::empty(py);
    for f in &report.faults {
        let d = PyDict::new(py);
        d.set_item("slot", f.slot)?;
        d.set_item("number", f.number)?;
        d.set_item("value", f.value)?;
        d.set_item("time", f.when())?;
        d.set_item("text", f.text)?;
        faults.append(d)?;
    }
    let d = PyDict::new(py);
    d.set_item("codes", report.notation(report.codes))?;
    d.set_item("values", report.values.map(|p| report.notation(p)))?;
    d.set_item(
        "warnings_from",
        report.warnings_from.map(|p| report.notation(p)),
    )?;
    d.set_item("faults", faults)?;
    let warnings = report
        .warnings
        .map(|ws| ws.iter().map(|w| (w.number, w.text)).collect::<Vec<_>>());
    d.set_item("warnings", warnings)?;
    Ok(d)
}

/// `(pnu, index, prefix)` of a parameter as the manuals write it.
#[pyfunction]
fn parse_param(text: &str) -> PyResult<(u16, Option<u8>, &'static str)> {
    let p = param_ref(text)?;
    let prefix = match p.prefix {
        Prefix::LowerP => "p",
        Prefix::R => "r",
        Prefix::P | Prefix::None => "P",
    };
    Ok((p.pnu.get(), p.index.map(uss_client::Subindex::get), prefix))
}

/// The built-in catalogue of drive family `family` (its configuration name, as `diag()`'s
/// `info["family"]` says it); `None` for a `generic` slave, whose texts nobody knows.
fn family_catalogue(family: &str) -> PyResult<Option<&'static Catalogue>> {
    let Some(family) = Catalogue::family_named(family) else {
        return Err(PyValueError::new_err(format!(
            "{family:?} is not a drive family: give one of {}",
            Catalogue::family_names()
        )));
    };
    Ok(Catalogue::of(family))
}

/// The text of fault `number` (F0072 -> 72) in the catalogue of drive family `family`; `None`
/// where the family's catalogue has none (a number means different faults in different
/// families).
#[pyfunction]
#[pyo3(signature = (number, family = "micromaster4"))]
fn fault_text(number: u16, family: &str) -> PyResult<Option<&'static str>> {
    Ok(family_catalogue(family)?.and_then(|c| c.fault(number)))
}

/// The text of warning `number` (A0501 -> 501) in the catalogue of drive family `family`.
#[pyfunction]
#[pyo3(signature = (number, family = "micromaster4"))]
fn warning_text(number: u16, family: &str) -> PyResult<Option<&'static str>> {
    Ok(family_catalogue(family)?.and_then(|c| c.warning(number)))
}

/// What drive `address` says `param` is (descriptive elements 1, 2, 4, 7, 8:
/// `Bus::drive_description`) beside what the family's catalogue says: `{"param", "family",
/// "drive": {"data_type", "elements", "read_only", "min", "max"}, "catalogue": None or
/// {"name", "data_type", "unit", "array", "data_sets", "level", "change", "min", "max",
/// "default", "agrees"}}`.
#[pyfunction]
#[pyo3(signature = (bus, address, param, timeout=7.5))]
fn describe<'py>(
    py: Python<'py>,
    bus: &Bound<'py, NativeBus>,
    address: u8,
    param: &str,
    timeout: f64,
) -> PyResult<Bound<'py, PyDict>> {
    let (said, entry, family) = answered(py, bus, address, param, timeout, |bus, drive, p| {
        let said = bus.drive_description(drive, p.pnu)?;
        Ok((said, bus.catalogue_entry(drive, p.pnu), bus.family(drive)))
    })?;
    let drive = PyDict::new(py);
    drive.set_item("data_type", format!("{:?}", said.data_type))?;
    drive.set_item("elements", said.elements)?;
    drive.set_item("read_only", said.read_only)?;
    drive.set_item("min", said.min)?;
    drive.set_item("max", said.max)?;
    let d = PyDict::new(py);
    d.set_item(
        "param",
        entry.map_or_else(|| param.to_owned(), |p| p.id.to_string()),
    )?;
    d.set_item("family", family.name())?;
    d.set_item("drive", drive)?;
    match entry {
        None => d.set_item("catalogue", py.None())?,
        Some(p) => {
            let c = PyDict::new(py);
            c.set_item("name", &p.name)?;
            c.set_item("data_type", format!("{:?}", p.data_type))?;
            c.set_item("unit", &p.unit)?;
            c.set_item("array", p.array)?;
            c.set_item("data_sets", p.data_sets)?;
            c.set_item("level", p.level)?;
            c.set_item("change", p.change.words())?;
            c.set_item("min", p.min)?;
            c.set_item("max", p.max)?;
            c.set_item("default", p.default)?;
            c.set_item("agrees", p.data_type == said.data_type)?;
            d.set_item("catalogue", c)?;
        }
    }
    Ok(d)
}

/// Scans a line ussd does not serve (`uss_client::scan::scan`): every probe carries OFF1. Runs
/// without the GIL; Ctrl-C ends it after the address under way and raises `KeyboardInterrupt`.
#[pyfunction]
#[pyo3(signature = (device, bauds=None, addresses=None, tries=4))]
#[allow(
    clippy::needless_pass_by_value,
    reason = "pyo3 extracts the path by value (a str or an os.PathLike)"
)]
fn scan(
    py: Python<'_>,
    device: std::path::PathBuf,
    bauds: Option<Vec<u32>>,
    addresses: Option<Vec<u8>>,
    tries: u32,
) -> PyResult<Bound<'_, PyDict>> {
    use uss_client::scan::ScanOptions;
    let mut options = ScanOptions {
        tries,
        ..ScanOptions::default()
    };
    if let Some(bauds) = bauds {
        options.bauds = bauds
            .into_iter()
            .map(uss_client::uss_protocol::Baud::new)
            .collect::<Result<_, _>>()
            .map_err(|e| pyo3::exceptions::PyValueError::new_err(e.to_string()))?;
    }
    if let Some(addresses) = addresses {
        options.addresses = addresses
            .into_iter()
            .map(|a| errors::drive(py, a))
            .collect::<PyResult<_>>()?;
    }
    let cancel = Interrupted::default();
    let scanned = py
        .detach(|| uss_client::scan::scan(&device, &options, &cancel, &mut |_, _| {}, &mut |_| {}))
        .map_err(|e| errors::scan(py, &e))?;
    if scanned.cut_short {
        return Err(pyo3::exceptions::PyKeyboardInterrupt::new_err(format!(
            "the scan of {} was cut short after {} drives",
            device.display(),
            scanned.drives.len()
        )));
    }
    let drives = pyo3::types::PyList::empty(py);
    for f in &scanned.drives {
        let d = PyDict::new(py);
        d.set_item("baud", f.baud.get())?;
        d.set_item("address", f.address.get())?;
        d.set_item(
            "pkw",
            f.pkw
                .map(uss_client::uss_protocol::telegram::PkwMode::p2013),
        )?;
        d.set_item("pzd", f.pzd)?;
        d.set_item("zsw1", f.zsw1)?;
        d.set_item("firmware", f.firmware)?;
        d.set_item("family", f.family.map(uss_client::DriveFamily::name))?;
        d.set_item("unsure", &f.unsure)?;
        drives.append(d)?;
    }
    let out = PyDict::new(py);
    out.set_item("drives", drives)?;
    out.set_item("seconds", scanned.took.as_secs_f64())?;
    Ok(out)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(scan, m)?)?;
    m.add_function(wrap_pyfunction!(describe, m)?)?;
    m.add_function(wrap_pyfunction!(read_param, m)?)?;
    m.add_function(wrap_pyfunction!(batch, m)?)?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(read_elements, m)?)?;
    m.add_function(wrap_pyfunction!(write, m)?)?;
    m.add_function(wrap_pyfunction!(fault_report, m)?)?;
    m.add_function(wrap_pyfunction!(save_to_rom, m)?)?;
    m.add_function(wrap_pyfunction!(factory_reset, m)?)?;
    m.add_function(wrap_pyfunction!(backup, m)?)?;
    m.add_function(wrap_pyfunction!(diff, m)?)?;
    m.add_function(wrap_pyfunction!(restore, m)?)?;
    m.add_function(wrap_pyfunction!(quick_commission, m)?)?;
    m.add_function(wrap_pyfunction!(parse_param, m)?)?;
    m.add_function(wrap_pyfunction!(fault_text, m)?)?;
    m.add_function(wrap_pyfunction!(warning_text, m)?)?;
    Ok(())
}
