//! Exclusive control of a drive from Python: the Rust `Controller`, whose session decides every
//! sample. A refresher fills the gaps between the program's calls, only while the program
//! called within the drive's watchdog time: a Python loop that blocks trips its drive.

use crate::errors;
use crate::{NativeBus, duration, image_dict};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use uss_client::{
    ClientError, ControlOptions, Controller as RustController, DEFAULT_REFRESH, Refresher,
};

/// The one controller of a drive: `uss_rt.Controller` is this class with the images' codes as
/// enums. Its threads call it at once: no lock is held through a call, so a stop never waits
/// behind another thread's wait (docs/SAFETY.md, STOP-NOWAIT).
#[pyclass(frozen, subclass, module = "uss_rt._native")]
pub(crate) struct Controller {
    /// `None` once released; held only to take a reference, never through a call.
    inner: Mutex<Option<(Arc<RustController>, Refresher)>>,
    bus: String,
    address: u8,
    pzd: usize,
}

impl Controller {
    fn held(&self) -> MutexGuard<'_, Option<(Arc<RustController>, Refresher)>> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The controller, unless released.
    fn controller(&self) -> Option<Arc<RustController>> {
        self.held().as_ref().map(|(c, _)| Arc::clone(c))
    }

    /// Runs `f` on the controller without the GIL; a released controller is an error.
    fn with<R: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&RustController) -> Result<R, ClientError> + Send,
    ) -> PyResult<R> {
        let controller = self.controller();
        let result = py.detach(|| match controller {
            Some(c) => f(&c),
            None => Err(ClientError::Released {
                bus: self.bus.clone(),
                address: self.address,
            }),
        });
        result.map_err(|e| errors::client(py, e))
    }

    fn image<'py>(&self, py: Python<'py>, c: &RustController) -> PyResult<Bound<'py, PyDict>> {
        let look = c.inputs().snapshot();
        let health = if look.problem.is_some() {
            "gone"
        } else {
            "running"
        };
        image_dict(py, self.address, &look.image, health)
    }
}

#[pymethods]
impl Controller {
    /// Takes exclusive control of drive `address`; a refresher thread (every quarter of the
    /// drive's watchdog time, at most every 20 ms) fills the gaps between the program's own
    /// calls while they come within the watchdog time.
    #[new]
    #[pyo3(signature = (bus, address, *_args, **_kwargs))]
    fn new(
        py: Python<'_>,
        bus: &Bound<'_, NativeBus>,
        address: u8,
        _args: &Bound<'_, pyo3::types::PyTuple>,
        _kwargs: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let rust_bus = &bus.get().inner;
        let drive = errors::drive(py, address)?;
        let opened = py.detach(|| rust_bus.control(drive, ControlOptions::default()));
        let c = opened.map_err(|e| errors::client(py, e))?;
        let refresher = c.spawn_refresher(DEFAULT_REFRESH);
        let pzd = c.words().len();
        Ok(Self {
            inner: Mutex::new(Some((Arc::new(c), refresher))),
            bus: rust_bus.name().to_owned(),
            address,
            pzd,
        })
    }

    #[getter]
    fn address(&self) -> u8 {
        self.address
    }

    /// The drive's PZD length: every sample carries this many words.
    #[getter]
    fn words_count(&self) -> usize {
        self.pzd
    }

    /// The words this controller sends (STW1 first); empty once released.
    fn words(&self) -> Vec<u16> {
        self.controller().map(|c| c.words()).unwrap_or_default()
    }

    /// The reference frequency P2000 ussd publishes now (0x4000 = 100 %): the drive's own value
    /// once ussd has read it; 0.0 while ussd reads it (again: the drive came online, was reset
    /// or commissioned), when `run_hz` raises `ReferenceUnknown`.
    #[getter]
    fn reference_hz(&self, py: Python<'_>) -> PyResult<f32> {
        self.with(py, |c| Ok(c.inputs().info().reference_hz))
    }

    /// The drive's input image.
    fn inputs<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        match self.controller() {
            Some(c) => self.image(py, &c),
            None => Err(errors::client(
                py,
                ClientError::Released {
                    bus: self.bus.clone(),
                    address: self.address,
                },
            )),
        }
    }

    /// The image, or the latch (Tripped) or stall this controller has not acknowledged.
    fn check<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        self.with(py, |c| c.check().map(|_| ()))?;
        self.inputs(py)
    }

    /// Acknowledges the latch and re-arms: OFF1 naming it, then waits until the drive is live.
    /// `asked_ns` (`CLOCK_MONOTONIC`, `time.monotonic_ns()`): when the deliberate act behind
    /// it happened; a latch that began after it is not re-armed (`Tripped`).
    fn rearm<'py>(&self, py: Python<'py>, asked_ns: u64) -> PyResult<Bound<'py, PyDict>> {
        self.with(py, |c| c.rearm(asked_ns).map(|_| ()))?;
        self.inputs(py)
    }

    /// The control loop's refresh: the current words again.
    fn keepalive(&self, py: Python<'_>) -> PyResult<()> {
        self.with(py, RustController::keepalive)
    }

    /// OFF1 (STW1 0x047E): S1 -> S2; stops a running drive. It re-arms nothing: a latched drive
    /// needs `rearm`.
    fn enable(&self, py: Python<'_>) -> PyResult<()> {
        self.with(py, RustController::enable)
    }

    /// ON (STW1 0x047F) with a setpoint in Hz, scaled by the reference frequency P2000 that
    /// ussd publishes (`reference_hz`).
    fn run_hz(&self, py: Python<'_>, hz: f32) -> PyResult<()> {
        self.with(py, |c| c.run_hz(hz))
    }

    /// ON with a setpoint in % of the reference frequency (-200 .. +199.99).
    fn run_percent(&self, py: Python<'_>, percent: f32) -> PyResult<()> {
        self.with(py, |c| c.run_percent(percent))
    }

    /// ON with a setpoint in rpm of the drive's reference speed (a G120's p2000, read with
    /// `pole_pairs` in its configuration); a drive with no reference speed raises
    /// `ValueError`, nothing sent.
    fn run_rpm(&self, py: Python<'_>, rpm: f32) -> PyResult<()> {
        self.with(py, |c| c.run_rpm(rpm))
    }

    /// A new setpoint in Hz, the control word as it is: a running drive follows it, a stopped
    /// one stays stopped.
    fn set_hz(&self, py: Python<'_>, hz: f32) -> PyResult<()> {
        self.with(py, |c| c.set_hz(hz))
    }

    /// Jogs (STW1 bit 8 `"right"`, bit 9 `"left"`) at the drive's jog frequency (P1058/P1059)
    /// while the calls keep coming; `stop` ends it.
    #[pyo3(signature = (direction = "right"))]
    fn jog(&self, py: Python<'_>, direction: &str) -> PyResult<()> {
        let direction = match direction {
            "right" => uss_client::Jog::Right,
            "left" => uss_client::Jog::Left,
            other => {
                return Err(pyo3::exceptions::PyValueError::new_err(format!(
                    "{other:?} is no jog direction: \"right\" or \"left\""
                )));
            }
        };
        self.with(py, |c| c.jog(direction))
    }

    /// OFF1: ramp down, then S2.
    fn stop(&self, py: Python<'_>) -> PyResult<()> {
        self.with(py, RustController::stop)
    }

    /// OFF2: pulses off at once, the motor coasts.
    fn coast(&self, py: Python<'_>) -> PyResult<()> {
        self.with(py, RustController::coast)
    }

    /// OFF3: the quick-stop ramp.
    fn quick_stop(&self, py: Python<'_>) -> PyResult<()> {
        self.with(py, RustController::quick_stop)
    }

    /// Sets or clears the reverse bit (STW1 bit 11).
    #[pyo3(signature = (reverse = None))]
    fn reverse(&self, py: Python<'_>, reverse: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let reverse = reverse.map_or(Ok(true), Bound::is_truthy)?;
        self.with(py, |c| c.reverse(reverse))
    }

    /// Acknowledges a fault: a rising edge of STW1 bit 7 until the drive received it (at most
    /// `timeout` s; `None`: the drive's handshake time, `handshake()`), then OFF1; a coast or
    /// quick stop the controller sends stays (0x04FC then 0x047C, 0x04FA then 0x047A).
    #[pyo3(signature = (timeout=None))]
    fn acknowledge(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<()> {
        let timeout = timeout.map(duration).transpose()?;
        self.with(py, |c| {
            c.acknowledge_fault(timeout.unwrap_or_else(|| c.inputs().handshake()))
        })
    }

    /// How long a call waits for what the drive's next poll brings, s: ussd's freshness limit
    /// for the drive (its turn in the circulating list and the poll with its retries), at least
    /// 1 s. A full line at 9600 baud polls each drive only every 1.3 s.
    fn handshake(&self, py: Python<'_>) -> PyResult<f64> {
        self.with(py, |c| Ok(c.inputs().handshake().as_secs_f64()))
    }

    /// Sends the PZD `words` as they are (STW1 first, bit 10 set, the drive's length).
    #[allow(clippy::needless_pass_by_value)] // PyO3 extracts a Python list as a Vec
    fn set_words(&self, py: Python<'_>, words: Vec<u16>) -> PyResult<()> {
        self.with(py, |c| c.set_words(&words))
    }

    /// Waits (without the GIL but for the predicate, refreshing meanwhile: the program waits
    /// inside its own call) until `predicate(image)` holds; the image that satisfied it.
    fn wait_for<'py>(
        &self,
        py: Python<'py>,
        predicate: &Bound<'py, PyAny>,
        timeout: f64,
        what: &str,
    ) -> PyResult<Bound<'py, PyDict>> {
        let timeout = duration(timeout)?;
        let address = self.address;
        let predicate = predicate.clone().unbind();
        let failed: Mutex<Option<PyErr>> = Mutex::new(None);
        let waited = self.with(py, |c| {
            c.wait_for(timeout, what, |i| {
                Python::attach(|py| {
                    let image = image_dict(py, address, i, "running")?;
                    predicate.bind(py).call1((image,))?.is_truthy()
                })
                .unwrap_or_else(|e| {
                    // The predicate raised: end the wait, raise it.
                    *failed.lock().unwrap_or_else(PoisonError::into_inner) = Some(e);
                    true
                })
            })
        });
        if let Some(e) = failed.into_inner().unwrap_or_else(PoisonError::into_inner) {
            return Err(e);
        }
        image_dict(py, address, &waited?, "running")
    }

    /// Hands the drive back cleanly: ussd sends its safe command and shows it "released", which
    /// is not a watchdog trip. Later calls raise; a second release does nothing.
    fn release(&self, py: Python<'_>) -> PyResult<()> {
        let taken = self.held().take();
        let Some((c, refresher)) = taken else {
            return Ok(());
        };
        let released = py.detach(|| {
            let _ = refresher.stop();
            c.release_shared().map(|_| ())
        });
        released.map_err(|e| errors::client(py, e))
    }

    /// Waits until the drive shows PROFIdrive state `state` (1..4 for S1..S4, 6 fault),
    /// refreshing the watchdog meanwhile; raises Tripped as soon as the drive latches,
    /// `WaitTimeout` after `timeout` s. The image that showed it.
    fn wait_for_state<'py>(
        &self,
        py: Python<'py>,
        state: u8,
        timeout: f64,
    ) -> PyResult<Bound<'py, PyDict>> {
        let wanted = drive_state(state)?;
        let timeout = duration(timeout)?;
        let image = self.with(py, |c| c.wait_for_state(wanted, timeout))?;
        image_dict(py, self.address, &image, "running")
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __exit__(
        &self,
        py: Python<'_>,
        _kind: &Bound<'_, PyAny>,
        _value: &Bound<'_, PyAny>,
        _trace: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        self.release(py)
    }

    fn __repr__(&self) -> String {
        let stw1 = self.words().first().copied().unwrap_or(0);
        format!(
            "Controller(bus='{}', drive={}, stw1={stw1:#06x})",
            self.bus, self.address
        )
    }
}

/// A PROFIdrive state by its number (`DriveState::code`: 1..4 for S1..S4, 6 fault), as every
/// front-end numbers it.
fn drive_state(code: u8) -> PyResult<uss_client::DriveState> {
    uss_client::DriveState::of_code(code)
        .filter(|s| s.code() != 0)
        .ok_or_else(|| {
            pyo3::exceptions::PyValueError::new_err(format!(
                "{code} is no drive state: 1..4 for S1..S4, 5 switching off, 6 fault"
            ))
        })
}
