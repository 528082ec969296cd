//! Exclusive control of a drive: the Rust `Controller`, whose session (`uss_control::session`)
//! decides every sample. The same rules as in Rust and Python: latched until the program's
//! explicit re-arm, only the program's own calls refresh the watchdog, a gap in them is a trip.
//! A handle is shared by the program's threads without a lock held through a call, so a stop
//! never waits behind another thread's wait (docs/SAFETY.md, STOP-NOWAIT).

use crate::UssrtStatus;
use crate::bus::{UssrtBus, UssrtDrive};
use crate::error::{Failure, arg, drive, guard, out};
use core::time::Duration;
use std::sync::{Arc, Mutex, PoisonError};
use uss_client::{ControlOptions, Controller, DriveState};

/// The one controller of a drive (opaque): made by [`ussrt_control_open`], owned by the caller
/// until [`ussrt_control_close`]. Usable from several threads at once: a call never waits for
/// another thread's call on the same handle (a stop goes out while another thread waits for a
/// state).
#[derive(Debug)]
pub struct UssrtController {
    /// `None` once released. Held only to take a reference, never through a call.
    controller: Mutex<Option<Arc<Controller>>>,
    bus: String,
    address: u8,
}

impl UssrtController {
    /// The controller, or `RELEASED`.
    fn controller(&self) -> Result<Arc<Controller>, Failure> {
        let held = self
            .controller
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        held.clone().ok_or_else(|| {
            Failure::Client(uss_client::ClientError::Released {
                bus: self.bus.clone(),
                address: self.address,
            })
        })
    }
}

/// Runs `f` on the controller behind `c`, or fails with `RELEASED`.
fn with(
    c: *const UssrtController,
    f: impl FnOnce(&Controller) -> Result<(), Failure>,
) -> UssrtStatus {
    guard(|| {
        let controller = arg(c, "controller")?.controller()?;
        f(&controller)
    })
}

/// Takes exclusive control of drive `address` (`CONTROLLED` while another process holds it)
/// and writes the handle to `*controller`. Opening re-arms nothing: the drive stays latched
/// (ussd's start, an operator's stop, an earlier controller's trip) until this program calls
/// [`ussrt_control_rearm_at`]; an ON before that fails with `TRIPPED`.
///
/// # Safety
/// `bus` is a live handle; `controller` points to writable memory for one pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_open(
    bus: *const UssrtBus,
    address: u8,
    controller: *mut *mut UssrtController,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let controller = out(controller, "controller")?;
        let c = bus
            .bus
            .control(drive(address)?, ControlOptions::default())?;
        *controller = Box::into_raw(Box::new(UssrtController {
            controller: Mutex::new(Some(Arc::new(c))),
            bus: bus.bus.name().to_owned(),
            address,
        }));
        Ok(())
    })
}

/// Hands the drive back (if not released yet: ussd sends its safe command, "released") and
/// frees the handle; NULL is ignored.
///
/// # Safety
/// `controller` is NULL or a handle of [`ussrt_control_open`] not closed yet, used by no other
/// thread now.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_close(controller: *mut UssrtController) {
    if !controller.is_null() {
        // SAFETY: made by `Box::into_raw` in `ussrt_control_open`, closed once.
        drop(unsafe { Box::from_raw(controller) });
    }
}

/// Hands the drive back cleanly: ussd sends its safe command, latched as "released" (not a
/// trip), once it took the release. Every later call but close fails with `RELEASED`.
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_release(controller: *const UssrtController) -> UssrtStatus {
    guard(|| {
        let c = arg(controller, "controller")?;
        let taken = c
            .controller
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        match taken {
            Some(controller) => controller
                .release_shared()
                .map(|_| ())
                .map_err(Failure::from),
            None => Ok(()),
        }
    })
}

/// Acknowledges the drive's latch (a trip, an operator's stop, ussd's start, a gap in this
/// program's calls) and re-arms it: OFF1 naming the latch, then waits until ussd passes this
/// controller's words again. Then an ON reaches the drive. `*drive` (may be NULL) gets the
/// drive as it is then.
///
/// `asked_ns` (`CLOCK_MONOTONIC` ns) is when the deliberate act that asked for the re-arm
/// happened: [`ussrt_process_start_ns`] for a program that re-arms once it is set up, the time
/// a pin was last seen low before its rise (`uss_vfd`), [`ussrt_monotonic_ns`] taken when the
/// program decided. A latch that began after it (an operator's stop between the ask and the
/// call) is not re-armed: `TRIPPED`, nothing is sent, the stop stays (docs/SAFETY.md, REARM).
///
/// # Safety
/// `controller` is a live handle; `drive` is NULL or writable memory for one `UssrtDrive`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_rearm_at(
    controller: *const UssrtController,
    asked_ns: u64,
    drive: *mut UssrtDrive,
) -> UssrtStatus {
    with(controller, |c| {
        c.rearm(asked_ns)?;
        // SAFETY: NULL or the caller's memory (as documented).
        if let Some(drive) = unsafe { drive.as_mut() } {
            *drive = UssrtDrive::of(c.inputs());
        }
        Ok(())
    })
}

/// `CLOCK_MONOTONIC` now, ns: the clock of every `*_ns` field and of a re-arm's `asked_ns`.
#[unsafe(no_mangle)]
pub extern "C" fn ussrt_monotonic_ns() -> u64 {
    uss_client::monotonic_ns()
}

/// When this process started, `CLOCK_MONOTONIC` ns (the kernel's start time, rounded down to
/// its 10 ms tick), into `*started_ns`: the `asked_ns` of a program that re-arms once it is set
/// up, so a stop while it starts is not re-armed by it. `IPC` when `/proc` cannot tell.
///
/// # Safety
/// `started_ns` points to writable memory for one `uint64_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_process_start_ns(started_ns: *mut u64) -> UssrtStatus {
    guard(|| {
        let started_ns = out(started_ns, "started_ns")?;
        *started_ns = uss_client::process_start_ns().map_err(|e| {
            Failure::Client(uss_client::ClientError::Ipc {
                what: "reading when this process started (/proc/self/stat)".to_owned(),
                detail: e.to_string(),
            })
        })?;
        Ok(())
    })
}

/// The drive as this controller sees it, into `*drive`; `TRIPPED` when it latched since this
/// controller acknowledged a latch (`*drive` is written then too), `STALLED` after a gap in the
/// program's calls. A read: it does not refresh the watchdog ([`ussrt_control_keepalive`] does).
///
/// # Safety
/// `controller` is a live handle; `drive` points to writable memory for one `UssrtDrive`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_check(
    controller: *const UssrtController,
    drive: *mut UssrtDrive,
) -> UssrtStatus {
    with(controller, |c| {
        let drive = out(drive, "drive")?;
        let checked = c.check();
        *drive = UssrtDrive::of(c.inputs());
        checked.map(|_| ()).map_err(Failure::from)
    })
}

/// The control loop's refresh: the current words again. Call it (or any other command) at
/// least once per watchdog time (`UssrtDrive::watchdog_ms`).
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_keepalive(
    controller: *const UssrtController,
) -> UssrtStatus {
    with(controller, |c| Ok(c.keepalive()?))
}

/// How often this controller's loop should call at least, in microseconds, into `*period_us`:
/// a quarter of the drive's watchdog time, at most 20 ms (`USS_MAX_REFRESH_NS`), the period the
/// library's own waits refresh at. A loop that calls this often never comes near the watchdog.
///
/// # Safety
/// `controller` is a live handle; `period_us` points to writable memory for one `uint32_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_refresh_period(
    controller: *const UssrtController,
    period_us: *mut u32,
) -> UssrtStatus {
    with(controller, |c| {
        let period_us = out(period_us, "period_us")?;
        *period_us = u32::try_from(c.refresh_period().as_micros()).unwrap_or(u32::MAX);
        Ok(())
    })
}

/// OFF1 with everything else enabled (STW1 0x047E): S1 -> S2; stops a running drive along its
/// ramp. It re-arms nothing: a latched drive needs [`ussrt_control_rearm_at`].
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_enable(controller: *const UssrtController) -> UssrtStatus {
    with(controller, |c| Ok(c.enable()?))
}

/// ON (STW1 0x047F) with a setpoint in Hz of the drive's reference frequency (negative: the
/// other way). `TRIPPED` on a latched drive this program has not re-armed
/// ([`ussrt_control_rearm_at`]).
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_run_hz(
    controller: *const UssrtController,
    hz: f32,
) -> UssrtStatus {
    with(controller, |c| Ok(c.run_hz(hz)?))
}

/// A new setpoint in Hz, the control word as it is: a running drive follows it, a stopped one
/// stays stopped.
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_set_hz(
    controller: *const UssrtController,
    hz: f32,
) -> UssrtStatus {
    with(controller, |c| Ok(c.set_hz(hz)?))
}

/// Jog directions of [`ussrt_control_jog`] (STW1 bit 8 right, bit 9 left).
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UssrtJog {
    Right = 1,
    Left = 2,
}

/// Jogs (`USSRT_JOG_RIGHT` or `USSRT_JOG_LEFT`) at the drive's jog frequency (P1058/P1059)
/// while the calls keep coming; [`ussrt_control_stop`] ends it.
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_jog(
    controller: *const UssrtController,
    direction: u8,
) -> UssrtStatus {
    with(controller, |c| {
        let direction = match direction {
            d if d == UssrtJog::Right as u8 => uss_client::Jog::Right,
            d if d == UssrtJog::Left as u8 => uss_client::Jog::Left,
            other => {
                return Err(Failure::Argument(format!(
                    "{other} is no jog direction: USSRT_JOG_RIGHT (1) or USSRT_JOG_LEFT (2)"
                )));
            }
        };
        Ok(c.jog(direction)?)
    })
}

/// ON with a setpoint in % of the reference (-200..+199.99).
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_run_percent(
    controller: *const UssrtController,
    percent: f32,
) -> UssrtStatus {
    with(controller, |c| Ok(c.run_percent(percent)?))
}

/// ON with a setpoint in rpm of the drive's reference speed (a G120's p2000, read with
/// `pole_pairs` in its configuration): `USSRT_STATUS_INVALID_ARGUMENT` for a drive with no
/// reference speed, `USSRT_STATUS_REFERENCE_UNKNOWN` while ussd reads it again; nothing sent.
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_run_rpm(
    controller: *const UssrtController,
    rpm: f32,
) -> UssrtStatus {
    with(controller, |c| Ok(c.run_rpm(rpm)?))
}

/// OFF1: ramp down, then S2 (STW1 0x047E).
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_stop(controller: *const UssrtController) -> UssrtStatus {
    with(controller, |c| Ok(c.stop()?))
}

/// OFF2: coast, the motor is switched off at once (STW1 0x047C).
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_coast(controller: *const UssrtController) -> UssrtStatus {
    with(controller, |c| Ok(c.coast()?))
}

/// OFF3: quick stop along the OFF3 ramp (STW1 0x047A).
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_quick_stop(
    controller: *const UssrtController,
) -> UssrtStatus {
    with(controller, |c| Ok(c.quick_stop()?))
}

/// Sets (`reverse` != 0) or clears the reverse bit (STW1 bit 11).
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_reverse(
    controller: *const UssrtController,
    reverse: u8,
) -> UssrtStatus {
    with(controller, |c| Ok(c.reverse(reverse != 0)?))
}

/// Acknowledges a drive fault (a rising edge of STW1 bit 7, at most `timeout_ms` for the drive
/// to receive it), then OFF1; a coast or quick stop the controller sends stays (0x04FC then
/// 0x047C, 0x04FA then 0x047A): never an ON.
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_acknowledge_fault(
    controller: *const UssrtController,
    timeout_ms: u32,
) -> UssrtStatus {
    with(controller, |c| {
        Ok(c.acknowledge_fault(Duration::from_millis(u64::from(timeout_ms)))?)
    })
}

/// Sends `count` PZD words (STW1 first) as they are: exactly the drive's PZD length, STW1 bit
/// 10 set, or `INVALID_SAMPLE` and nothing is sent.
///
/// # Safety
/// `controller` is a live handle; `words` points to `count` readable `uint16_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_set_words(
    controller: *const UssrtController,
    words: *const u16,
    count: usize,
) -> UssrtStatus {
    with(controller, |c| {
        if words.is_null() {
            return Err(Failure::Argument("words is NULL".to_owned()));
        }
        if count > uss_client::uss_shm_types::MAX_PZD_WORDS {
            return Err(Failure::Argument(format!(
                "{count} words: a drive has 0..=16"
            )));
        }
        // SAFETY: not NULL, `count` (at most 16) words of the caller (as documented).
        let words = unsafe { core::slice::from_raw_parts(words, count) };
        Ok(c.set_words(words)?)
    })
}

/// Waits (at most `timeout_ms`, refreshing the watchdog meanwhile: this program waits inside
/// its own call) until the drive is in PROFIdrive state `state` (1..4 for S1..S4).
/// `TRIPPED` as soon as the drive latches.
///
/// # Safety
/// `controller` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_control_wait_state(
    controller: *const UssrtController,
    state: u8,
    timeout_ms: u32,
) -> UssrtStatus {
    with(controller, |c| {
        let wanted = DriveState::of_code(state)
            .filter(|s| (1..=4).contains(&s.code()))
            .ok_or_else(|| Failure::Argument(format!("state {state}: wait for 1..4 (S1..S4)")))?;
        c.wait_for_state(wanted, Duration::from_millis(u64::from(timeout_ms)))?;
        Ok(())
    })
}
