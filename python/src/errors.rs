//! The Rust client's errors as the exception classes of `uss_rt` (defined in Python, so their
//! constructors, attributes and messages stay what scripts already catch).

use pyo3::BoundObject as _;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use uss_client::uss_shm_types::{DriveError, ParamResult, PathError, RequestError, StopCommand};
use uss_client::{Address, ClientError, Latch, ParamError};

/// `uss_rt.<class>(*args)` as the error to raise (a `RuntimeError` if the module is broken).
fn raise<'py>(
    py: Python<'py>,
    class: &str,
    args: impl IntoPyObject<'py, Target = PyTuple>,
) -> PyErr {
    let made = args.into_pyobject(py).map_err(Into::into).and_then(|args| {
        let args = args.into_bound();
        py.import("uss_rt")
            .and_then(|m| m.getattr(class))
            .and_then(|c| c.call1(args))
    });
    match made {
        Ok(exception) => PyErr::from_value(exception),
        Err(e) => e,
    }
}

fn seconds(d: core::time::Duration) -> f64 {
    d.as_secs_f64()
}

fn latched(py: Python<'_>, class: &str, address: u8, latch: &Latch, message: String) -> PyErr {
    raise(
        py,
        class,
        (
            address,
            latch.reason.code(),
            StopCommand::code_of(latch.command),
            latch.by_pid,
            message,
        ),
    )
}

/// A client error as the matching `uss_rt` exception.
/// A drive address from Python, checked where it enters: 0..=31, or the client's address
/// error.
pub(crate) fn drive(py: Python<'_>, address: u8) -> PyResult<Address> {
    Address::new(address).map_err(|e| client(py, ClientError::from(e)))
}

pub(crate) fn client(py: Python<'_>, e: ClientError) -> PyErr {
    let message = e.to_string();
    match e {
        ClientError::Name(_) => PyValueError::new_err(message),
        ClientError::NotRunning { bus } => raise(py, "NotRunning", (bus,)),
        ClientError::UnknownDrive {
            bus,
            address,
            known,
        } => raise(
            py,
            "UnknownDrive",
            (
                bus,
                address,
                known.iter().map(|&a| u32::from(a)).collect::<Vec<u32>>(),
            ),
        ),
        ClientError::Controlled { bus, address, .. } => {
            raise(py, "Controlled", (bus, address, message))
        }
        ClientError::Incompatible { bus, service } => raise(py, "Incompatible", (bus, service)),
        ClientError::UssdGone {
            bus,
            pid,
            silent_for,
        } => raise(py, "UssdGone", (bus, pid, seconds(silent_for))),
        ClientError::UssdStopped { bus, pid, ago } => {
            raise(py, "UssdStopped", (bus, pid, seconds(ago)))
        }
        ClientError::LineDown {
            bus,
            fault,
            down_for,
        } => raise(py, "LineDown", (bus, fault, seconds(down_for))),
        ClientError::Tripped { address, latch, .. } => {
            latched(py, "Tripped", address, &latch, message)
        }
        ClientError::NotArmed { address, latch, .. } => {
            latched(py, "NotArmed", address, &latch, message)
        }
        ClientError::Stalled { address, gap, .. } => {
            raise(py, "Stalled", (address, seconds(gap), message))
        }
        ClientError::CommandRefused { bus, error } => {
            raise(py, "CommandRefused", (bus, error.code()))
        }
        ClientError::InvalidSample { .. } | ClientError::PzdWords { .. } => {
            PyValueError::new_err(message)
        }
        ClientError::Stale { .. } | ClientError::WaitTimeout { .. } => {
            raise(py, "WaitTimeout", (message,))
        }
        ClientError::NotControllable { .. } => raise(py, "NotControllable", (message,)),
        ClientError::Superseded { .. } => raise(py, "Superseded", (message,)),
        _ => raise(py, "UssError", (message,)),
    }
}

/// A parameter error as the matching `uss_rt` exception; `bus` and `address` name an unknown
/// drive.
pub(crate) fn param(py: Python<'_>, bus: &uss_client::Bus, address: u8, e: ParamError) -> PyErr {
    let message = e.to_string();
    // The codes of `uss_rt.Outcome` for the path failures.
    let failed = |outcome: u8| raise(py, "ParamFailed", (outcome,));
    match e {
        ParamError::Drive(DriveError::Refused(p)) => raise(py, "DriveError", (p.number(),)),
        ParamError::Drive(DriveError::NoChangeRights) => failed(5),
        ParamError::Path(PathError::Timeout) => raise(py, "ParamTimeout", ()),
        ParamError::Path(PathError::DriveOffline) => failed(7),
        ParamError::Path(PathError::MailboxFull) => failed(8),
        ParamError::Path(PathError::Shutdown) => failed(9),
        ParamError::Path(PathError::LineDown) => failed(11),
        ParamError::Path(PathError::Cancelled) => failed(12),
        ParamError::Path(PathError::Refused(error)) => refused(py, bus, address, error, None),
        ParamError::Refused { error, item } => refused(py, bus, address, error, item),
        ParamError::Controlled { .. } => {
            raise(py, "Refused", (RequestError::Controlled.code(), None::<u8>))
        }
        ParamError::NoAnswer(timeout) => raise(
            py,
            "NoAnswer",
            (
                bus.name().to_owned(),
                format!("did not answer within {} s", seconds(timeout)),
            ),
        ),
        ParamError::Dropped => raise(
            py,
            "NoAnswer",
            (
                bus.name().to_owned(),
                "dropped the request without answering".to_owned(),
            ),
        ),
        ParamError::Value { .. } => PyValueError::new_err(message),
        ParamError::MaybeApplied { failure, telegrams } => raise(
            py,
            "MaybeApplied",
            (
                ParamResult::of(&Err(failure), 0, 0).outcome,
                telegrams,
                message,
            ),
        ),
        ParamError::Client(c) => client(py, c),
        _ => raise(py, "UssError", (message,)),
    }
}

fn refused(
    py: Python<'_>,
    bus: &uss_client::Bus,
    address: u8,
    error: RequestError,
    item: Option<u8>,
) -> PyErr {
    if error == RequestError::UnknownDrive {
        return raise(
            py,
            "UnknownDrive",
            (bus.name().to_owned(), address, crate::widen(&bus.drives())),
        );
    }
    raise(py, "Refused", (error.code(), item))
}
