//! A bus: open and close it, watch a drive, wait for its next exchange, stop drives as an
//! operator.

use crate::UssrtStatus;
use crate::error::{Failure, arg, drive, guard, out, text};
use core::ffi::c_char;
use core::time::Duration;
use std::collections::HashMap;
use std::sync::{Mutex, PoisonError};
use std::time::Instant;
use uss_client::{Bus, CycleEvent, CycleListener, DriveWatch, PzdInput, StopCommand};

/// An open bus (opaque): made by [`ussrt_bus_open`], owned by the caller until
/// [`ussrt_bus_close`]. Usable from several threads at once.
#[derive(Debug)]
pub struct UssrtBus {
    pub(crate) bus: Bus,
    /// One watch per drive looked at, kept so a read neither opens nor allocates.
    watches: Mutex<HashMap<u8, DriveWatch>>,
    /// Opened at the first wait for an exchange.
    listener: Mutex<Option<CycleListener>>,
}

/// One look at a drive: its input image and what it means.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct UssrtDrive {
    /// The input image as ussd wrote it (`uss_shm_types.h`); `online` is 0 when `stale` is 1.
    pub image: PzdInput,
    /// 1 when this is not the drive as it is now: ussd is gone or stopped, or its line is down
    /// (the image is the last one read).
    pub stale: u8,
    /// 1 while the drive gets its controller's words, 0 while latched (`image.latch_reason`
    /// says why, `image.latch_id` which latch).
    pub live: u8,
    /// The PROFIdrive state from ZSW1: 1..4 for S1..S4, 6 fault, 0 not ready.
    pub state: u8,
    pub reserved: u8,
    /// HIW in Hz of the drive's reference frequency; NaN while ussd reads the reference again.
    pub actual_hz: f32,
    /// The reference frequency (P2000) every Hz is scaled by, as ussd publishes it; 0 while
    /// ussd reads it again (the drive came online, was reset or commissioned): then
    /// `ussrt_control_run_hz` fails with `USSRT_STATUS_REFERENCE_UNKNOWN`.
    pub reference_hz: f32,
    /// The drive's watchdog time: a controller calls at least this often.
    pub watchdog_ms: u32,
}

impl UssrtDrive {
    pub(crate) fn of(watch: &DriveWatch) -> Self {
        let look = watch.snapshot();
        let image = look.image;
        Self {
            image,
            stale: u8::from(look.problem.is_some()),
            live: u8::from(image.is_live()),
            state: uss_client::state_of(&image).code(),
            reserved: 0,
            actual_hz: look.info.reference().map_or(f32::NAN, |r| {
                uss_client::Setpoint::from_word(image.hiw).hz(r)
            }),
            reference_hz: look.info.reference_hz,
            watchdog_ms: look.info.watchdog_ms,
        }
    }
}

impl UssrtBus {
    /// Runs `f` on drive `address`'s watch (opened at the first look).
    fn with_watch<R>(&self, address: u8, f: impl FnOnce(&DriveWatch) -> R) -> Result<R, Failure> {
        let mut watches = self.watches.lock().unwrap_or_else(PoisonError::into_inner);
        let watch = match watches.entry(address) {
            std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::hash_map::Entry::Vacant(e) => {
                e.insert(self.bus.watch(drive(address)?)?)
            }
        };
        Ok(f(watch))
    }
}

/// A stop command code of the caller: 1 OFF1, 2 OFF2, 3 OFF3 (`UssStopCommand`).
pub(crate) fn stop_command(code: u8) -> Result<StopCommand, Failure> {
    StopCommand::of_code(code).ok_or_else(|| {
        Failure::Argument(format!(
            "{code} is not a stop command: 1 OFF1 (ramp), 2 OFF2 (coast), 3 OFF3 (quick stop)"
        ))
    })
}

/// Opens bus `name` (as ussd's configuration names it) and writes the handle to `*bus`.
/// Fails with `NOT_RUNNING` when no ussd serves it.
///
/// # Safety
/// `name` is a NUL-terminated string; `bus` points to writable memory for one pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_bus_open(
    name: *const c_char,
    bus: *mut *mut UssrtBus,
) -> UssrtStatus {
    guard(|| {
        let name = text(name, "name")?;
        let bus = out(bus, "bus")?;
        let opened = Bus::open(name)?;
        *bus = Box::into_raw(Box::new(UssrtBus {
            bus: opened,
            watches: Mutex::default(),
            listener: Mutex::default(),
        }));
        Ok(())
    })
}

/// Closes a bus handle and frees it; NULL is ignored. Controllers opened from it stay usable.
///
/// # Safety
/// `bus` is NULL or a handle of [`ussrt_bus_open`] not closed yet, used by no other thread now.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_bus_close(bus: *mut UssrtBus) {
    if !bus.is_null() {
        // SAFETY: made by `Box::into_raw` in `ussrt_bus_open`, closed once (the caller's part).
        drop(unsafe { Box::from_raw(bus) });
    }
}

/// The drives ussd polls on the bus, as a bit mask (bit `a` set: drive `a`).
///
/// # Safety
/// `bus` is a live handle; `drives` points to writable memory for one `uint32_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_bus_drives(bus: *const UssrtBus, drives: *mut u32) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let drives = out(drives, "drives")?;
        *drives = bus
            .bus
            .drives()
            .iter()
            .fold(0u32, |m, &a| m | 1u32 << a.get());
        Ok(())
    })
}

/// Whether ussd serves the bus now: `OK`, or why not (`USSD_GONE`, `USSD_STOPPED`,
/// `LINE_DOWN`, with the message saying since when).
///
/// # Safety
/// `bus` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_bus_health(bus: *const UssrtBus) -> UssrtStatus {
    guard(|| {
        let bus = &arg(bus, "bus")?.bus;
        match bus.health().error(bus.name()) {
            Some(e) => Err(e.into()),
            None => Ok(()),
        }
    })
}

/// Reads the bus's status as ussd publishes it (`UssBusStatus` of `uss_shm_types.h`: counters,
/// line state, exchange times, the bus thread's scheduling) into `*status`.
///
/// # Safety
/// `bus` is a live handle; `status` points to writable memory for one `UssBusStatus`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_bus_status(
    bus: *const UssrtBus,
    status: *mut uss_client::BusStatus,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let status = out(status, "status")?;
        *status = bus.bus.status()?;
        Ok(())
    })
}

/// Reads drive `address`'s diagnostics as ussd publishes them (`UssDriveDiag`: its counters,
/// its configuration `info`, its link) into `*diag`. Diagnostics older than ussd's limit for
/// them (`stale_after_ns` and `USS_DIAG_AGE_NS` after `last_good_ns`: a paused ussd, a stalled
/// bus thread) come with `online = 0`: they are not the drive as it is.
///
/// # Safety
/// `bus` is a live handle; `diag` points to writable memory for one `UssDriveDiag`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_drive_diag(
    bus: *const UssrtBus,
    address: u8,
    diag: *mut uss_client::DriveDiag,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let diag = out(diag, "diag")?;
        let mut read = bus.bus.diag(drive(address)?)?;
        if !read.is_online_at(uss_client::monotonic_ns()) {
            read.online = 0;
        }
        *diag = read;
        Ok(())
    })
}

/// Reads drive `address`'s latest input image and what it means into `*drive`. Never blocks on
/// ussd; a stale image (ussd gone, stopped, line down) is returned with `stale = 1` and the
/// status `OK`: the caller decides.
///
/// # Safety
/// `bus` is a live handle; `drive` points to writable memory for one `UssrtDrive`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_drive_read(
    bus: *const UssrtBus,
    address: u8,
    drive: *mut UssrtDrive,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let drive = out(drive, "drive")?;
        *drive = bus.with_watch(address, UssrtDrive::of)?;
        Ok(())
    })
}

/// Waits (at most `timeout_ms`) for drive `address`'s next exchange, so a control loop runs in
/// step with the bus. `TIMEOUT` when none came; `USSD_GONE`, `USSD_STOPPED` or `LINE_DOWN` when
/// ussd does not poll.
///
/// # Safety
/// `bus` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_wait_exchange(
    bus: *const UssrtBus,
    address: u8,
    timeout_ms: u32,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        bus.with_watch(address, |_| ())?;
        let mut listener = bus.listener.lock().unwrap_or_else(PoisonError::into_inner);
        if listener.is_none() {
            *listener = Some(bus.bus.cycle_listener()?);
        }
        let Some(listener) = listener.as_ref() else {
            return Err(Failure::Argument("no listener".to_owned()));
        };
        let timeout = Duration::from_millis(u64::from(timeout_ms));
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if listener.wait_for(CycleEvent::Exchange(address), left)? {
                return Ok(());
            }
            if Instant::now() >= deadline {
                return Err(Failure::Client(uss_client::ClientError::Stale {
                    bus: bus.bus.name().to_owned(),
                    address,
                    timeout,
                }));
            }
        }
    })
}

/// An operator's stop of drive `address`, whoever controls it: `command` 1 OFF1 (ramp), 2 OFF2
/// (coast), 3 OFF3 (quick stop). Latched until the drive's controller re-arms it.
///
/// # Safety
/// `bus` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_stop_drive(
    bus: *const UssrtBus,
    address: u8,
    command: u8,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        bus.bus
            .stop_drive(drive(address)?, stop_command(command)?)?;
        Ok(())
    })
}

/// Waits until drive `address` got a stop command at least as strong as `command` (1 OFF1, 2
/// OFF2, 3 OFF3) from an operator: its image shows the override and the control word that went
/// out. `timeout_ms` 0 waits the drive's own time (its turn in the circulating list, or its next
/// probe while offline, and the poll). On success `*drive` (may be NULL) gets the drive as it
/// is then. `NOT_CONTROLLABLE` when the drive does not take its commands from this link (the
/// stop went out but is not obeyed); `TIMEOUT` when it was not seen in time.
///
/// # Safety
/// `bus` is a live handle; `drive` is NULL or points to writable memory for one `UssrtDrive`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_wait_stopped(
    bus: *const UssrtBus,
    address: u8,
    command: u8,
    timeout_ms: u32,
    drive_out: *mut UssrtDrive,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let address = drive(address)?;
        let timeout = (timeout_ms > 0).then(|| Duration::from_millis(u64::from(timeout_ms)));
        bus.bus
            .wait_stopped(address, stop_command(command)?, timeout)?;
        // SAFETY: NULL or the caller's memory for one UssrtDrive (as documented).
        if let Some(out) = unsafe { drive_out.as_mut() } {
            *out = UssrtDrive::of(&bus.bus.watch(address)?);
        }
        Ok(())
    })
}

/// An operator's stop of every drive of the bus (see [`ussrt_stop_drive`]); `*drives` (may be
/// NULL) gets the drives it reached as a bit mask.
///
/// # Safety
/// `bus` is a live handle; `drives` is NULL or points to writable memory for one `uint32_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_stop_all(
    bus: *const UssrtBus,
    command: u8,
    drives: *mut u32,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let reached = bus.bus.stop_all(stop_command(command)?)?;
        // SAFETY: NULL or the caller's memory for one u32 (as documented).
        if let Some(drives) = unsafe { drives.as_mut() } {
            *drives = reached.iter().fold(0, |m, &a| m | 1u32 << a.get());
        }
        Ok(())
    })
}
