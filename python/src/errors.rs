//! The Rust client's errors as `uss_rt`'s exceptions. The class is the code table's
//! (`uss_client::kinds`, generated into `uss_rt/_errors.py`), the message is the error's own
//! text; what it is about (bus, address, latch, outcome, ...) goes along as attributes.

use pyo3::BoundObject as _;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use uss_client::uss_shm_types::{
    DriveError, ItemOutcome, LatchReason, Outcome, PathError, RequestError, StopCommand,
};
use uss_client::{Address, ClientError, ErrorKind, ParamError};

/// An attribute of an exception: its name and its value, already a Python object.
type Detail<'py> = (&'static str, Bound<'py, PyAny>);

/// `uss_rt.<kind's class>(message, **details)` as the error to raise (`ValueError` for an
/// argument; a `RuntimeError` if the module is broken).
fn raise(py: Python<'_>, kind: ErrorKind, message: String, details: Vec<Detail<'_>>) -> PyErr {
    let class = kind.python_class();
    if class == "ValueError" || class.is_empty() {
        return PyValueError::new_err(message);
    }
    let made = (|| {
        let kwargs = PyDict::new(py);
        for (name, value) in details {
            kwargs.set_item(name, value)?;
        }
        py.import("uss_rt")?
            .getattr(class)?
            .call((message,), Some(&kwargs))
    })();
    match made {
        Ok(exception) => PyErr::from_value(exception),
        Err(e) => e,
    }
}

/// A scan's error (its line): `DeviceError` (an `OSError` too), with the device's words.
pub(crate) fn scan(py: Python<'_>, e: &uss_client::scan::ScanError) -> PyErr {
    raise(py, e.kind(), e.to_string(), Vec::new())
}

/// A value as a Python object (for the attributes).
fn obj<'py>(py: Python<'py>, value: impl IntoPyObject<'py>) -> Bound<'py, PyAny> {
    value
        .into_pyobject(py)
        .map_or_else(|_| py.None().into_bound(py), |v| v.into_any().into_bound())
}

/// Member `code` of the module's code table `table` (`LatchReason`, `Outcome`, ...), or the bare
/// number if the table has none.
fn member<'py>(py: Python<'py>, table: &str, code: u8) -> Bound<'py, PyAny> {
    py.import("uss_rt")
        .and_then(|m| m.getattr(table))
        .and_then(|t| t.call1((code,)))
        .unwrap_or_else(|_| obj(py, code))
}

/// What every `Tripped` carries: its drive, why it is latched and what it gets (table members,
/// or `None` where the error does not say), the process behind it and the message.
fn latched<'py>(
    py: Python<'py>,
    address: u8,
    (reason, command): (Bound<'py, PyAny>, Bound<'py, PyAny>),
    by_pid: u32,
    message: &str,
) -> Vec<Detail<'py>> {
    vec![
        ("address", obj(py, address)),
        ("reason", reason),
        ("command", command),
        ("by_pid", obj(py, by_pid)),
        ("detail", obj(py, message)),
    ]
}

/// A drive address from Python, checked where it enters: 0..=31, or the client's address
/// error.
pub(crate) fn drive(py: Python<'_>, address: u8) -> PyResult<Address> {
    Address::new(address).map_err(|e| client(py, ClientError::from(e)))
}

/// A client error as the matching `uss_rt` exception.
pub(crate) fn client(py: Python<'_>, e: ClientError) -> PyErr {
    let (kind, message) = (e.kind(), e.to_string());
    let details = match e {
        ClientError::NotRunning { bus, served } => {
            vec![("bus", obj(py, bus)), ("served", obj(py, served))]
        }
        ClientError::UnknownDrive {
            bus,
            address,
            known,
        } => vec![
            ("bus", obj(py, bus)),
            ("address", obj(py, address)),
            (
                "known",
                obj(py, known.iter().map(|&a| u32::from(a)).collect::<Vec<_>>()),
            ),
        ],
        ClientError::Controlled { bus, address, .. } => {
            vec![("bus", obj(py, bus)), ("address", obj(py, address))]
        }
        ClientError::Incompatible { bus, service } => {
            vec![("bus", obj(py, bus)), ("service", obj(py, service))]
        }
        ClientError::UssdGone {
            bus,
            pid,
            silent_for,
        } => vec![
            ("bus", obj(py, bus)),
            ("pid", obj(py, pid)),
            ("silent_for", obj(py, silent_for.as_secs_f64())),
        ],
        ClientError::UssdStopped { bus, pid, ago } => vec![
            ("bus", obj(py, bus)),
            ("pid", obj(py, pid)),
            ("ago", obj(py, ago.as_secs_f64())),
        ],
        ClientError::LineDown {
            bus,
            fault,
            down_for,
        } => vec![
            ("bus", obj(py, bus)),
            ("fault", obj(py, fault)),
            ("down_for", obj(py, down_for.as_secs_f64())),
        ],
        ClientError::Tripped { address, latch, .. }
        | ClientError::NotArmed { address, latch, .. } => {
            let reason = member(py, "LatchReason", latch.reason.code());
            let command = member(py, "StopCommand", StopCommand::code_of(latch.command));
            latched(py, address, (reason, command), latch.by_pid, &message)
        }
        ClientError::Stalled {
            address,
            gap,
            command,
            ..
        } => {
            // The drive's own safe command: what ussd stops a stale controller's drive with.
            let reason = member(py, "LatchReason", LatchReason::Stale.code());
            let command = member(py, "StopCommand", StopCommand::code_of(command));
            let mut details = latched(py, address, (reason, command), 0, &message);
            details.push(("gap", obj(py, gap.as_secs_f64())));
            details
        }
        // A latch named that is not the drive's: a Tripped without one to name.
        ClientError::NotTheLatch { address, .. } => {
            let none = || py.None().into_bound(py);
            latched(py, address, (none(), none()), 0, &message)
        }
        ClientError::CommandRefused { bus, error } => vec![
            ("bus", obj(py, bus)),
            ("error", member(py, "CommandError", error.code())),
        ],
        _ => Vec::new(),
    };
    raise(py, kind, message, details)
}

/// How an item ended, as `uss_rt.Outcome`'s code.
fn outcome(ended: &ItemOutcome) -> u8 {
    Outcome::of(ended).code()
}

/// A parameter error as the matching `uss_rt` exception (`bus` named in its details).
pub(crate) fn param(py: Python<'_>, bus: &uss_client::Bus, e: ParamError) -> PyErr {
    param_hinted(py, bus, e, None)
}

/// [`param`] of an access to `param` of drive `address`: a refusal with what to do about it
/// (`Bus::refusal_hint`) says it after its own words, and as the attribute `hint`.
pub(crate) fn param_of(
    py: Python<'_>,
    bus: &uss_client::Bus,
    address: Address,
    param: uss_client::ParamRef,
    e: ParamError,
) -> PyErr {
    let hint = bus.refusal_hint(address, param, &e);
    param_hinted(py, bus, e, hint)
}

fn param_hinted(
    py: Python<'_>,
    bus: &uss_client::Bus,
    e: ParamError,
    hint: Option<String>,
) -> PyErr {
    let (kind, mut message) = (e.kind(), e.to_string());
    if let Some(h) = &hint {
        message = format!("{message}: {h}");
    }
    let refused = |error: RequestError, item: Option<u8>| {
        vec![
            ("error", member(py, "RequestError", error.code())),
            ("item", obj(py, item)),
        ]
    };
    let details = match e {
        ParamError::Drive(DriveError::Refused(p)) => {
            vec![("number", obj(py, p.number())), ("hint", obj(py, hint))]
        }
        ParamError::Drive(d) => vec![("outcome", member(py, "Outcome", outcome(&Ok(Err(d)))))],
        ParamError::Path(PathError::Refused(error)) => refused(error, None),
        ParamError::Refused { error, item } => refused(error, item),
        ParamError::Controlled { .. } => refused(RequestError::Controlled, None),
        ParamError::Path(path) => vec![("outcome", member(py, "Outcome", outcome(&Err(path))))],
        ParamError::NoAnswer(_) | ParamError::Dropped => vec![("bus", obj(py, bus.name()))],
        ParamError::MaybeApplied { failure, telegrams } => vec![
            ("outcome", member(py, "Outcome", outcome(&Err(failure)))),
            ("telegrams", obj(py, telegrams)),
        ],
        ParamError::Client(c) => return client(py, c),
        _ => Vec::new(),
    };
    raise(py, kind, message, details)
}
