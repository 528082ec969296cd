//! Parameters: in the manuals' notation as their own type (`P1082` = `50.00 Hz`), as raw words,
//! and the fault report.

use crate::UssrtStatus;
use crate::bus::UssrtBus;
use crate::error::{Failure, arg, drive, guard, out, param_info, text};
use core::ffi::c_char;
use uss_client::uss_protocol::ParamRef;
#[cfg(test)]
use uss_client::uss_protocol::Subindex;
use uss_client::{ParamValue, Typed, Value, WriteOptions};

/// `flags` bit of a write: RAM and EEPROM (survives a power cycle) instead of RAM only.
pub const USSRT_WRITE_EEPROM: u32 = 1;
/// `flags` bit of a write: write even while another process controls the drive (deliberate).
pub const USSRT_WRITE_FORCE: u32 = 2;
/// Write even a parameter that takes the drive away from ussd (command or setpoint source,
/// COM link, telegram monitoring off, factory reset); ussd logs it, the value is verified.
pub const USSRT_WRITE_UNSAFE: u32 = 4;
/// `index` of a raw read or write for a parameter without index.
pub const USSRT_NO_INDEX: i32 = -1;

/// A parameter value and what it is.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct UssrtValue {
    /// The value in its own type and unit: a float parameter's float, an integer's integer
    /// (exact), a fixed-point parameter's steps in its unit (SIMOREG P303's raw 1000 is 10.0 s).
    pub value: f64,
    /// The word or double word the drive sent.
    pub raw: u32,
    /// 1: a double word (PKW reply 2 or 5).
    pub is_dword: u8,
    /// 1: an IEEE-754 float (from the catalogue or the drive's description).
    pub is_float: u8,
    pub reserved: [u8; 2],
    /// The manuals' text, NUL-terminated: `P1082 = 50.00 Hz`.
    pub text: [c_char; 64],
    /// The unit (`Hz`, `s`), empty when none is known.
    pub unit: [c_char; 16],
}

/// One recorded fault.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct UssrtFault {
    /// F0072 -> 72.
    pub number: u16,
    pub has_value: u8,
    /// Element of the fault buffer (r0947 on MICROMASTER 4): 0 is the newest.
    pub slot: u8,
    /// The fault value (r0949), its 32 bits as the drive sent them (signed on a G120), when
    /// `has_value`.
    pub value: u32,
    /// The catalogue's text, NUL-terminated (empty when it does not know the fault).
    pub text: [c_char; 64],
}

/// The drive's fault buffer and active warnings, where its family keeps them (MICROMASTER 4:
/// r0947 with r0949 values and r2110; G120: r0945, r0949, r2122; SIMOREG: r947, r949).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct UssrtFaultReport {
    /// Faults in `faults`, newest first.
    pub fault_count: u8,
    /// Warnings in `warnings`; 0xFF when the drive has none uss-rt reads.
    pub warning_count: u8,
    /// The parameter the fault numbers were read from: 947 (MICROMASTER 4, SIMOREG), 945 (G120).
    pub codes_pnu: u16,
    pub faults: [UssrtFault; 8],
    /// Active warnings: A0501 -> 501 (4 on MICROMASTER 4, up to 8 current alarms on G120).
    pub warnings: [u16; 8],
}

/// `s` into `buf`, cut at a character boundary to fit with its NUL.
fn copy_text(buf: &mut [c_char], s: &str) {
    let mut n = s.len().min(buf.len().saturating_sub(1));
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    for (b, &c) in buf.iter_mut().zip(&s.as_bytes()[..n]) {
        *b = c as c_char;
    }
    if let Some(end) = buf.get_mut(n) {
        *end = 0;
    }
}

fn value_of(v: &ParamValue) -> UssrtValue {
    let is_float = u8::from(matches!(v.typed(), Typed::Float(_)));
    let value = v.value().as_f64();
    let (raw, is_dword) = raw_of(v.raw);
    let mut out = UssrtValue {
        value,
        raw,
        is_dword,
        is_float,
        reserved: [0; 2],
        text: [0; 64],
        unit: [0; 16],
    };
    copy_text(&mut out.text, &v.to_string());
    copy_text(&mut out.unit, v.unit());
    out
}

fn raw_of(v: Value) -> (u32, u8) {
    match v {
        Value::Word(w) => (u32::from(w), 0),
        Value::Dword(d) => (d, 1),
    }
}

/// A raw value to write: a double word (`dword` != 0), or a word (a value above 0xFFFF is
/// refused).
fn raw_value(value: u32, dword: u8) -> Result<Value, Failure> {
    Value::from_raw(value, dword != 0)
        .ok_or_else(|| Failure::Argument(format!("{value} does not fit a word (0..=65535)")))
}

fn param_ref(param: *const c_char) -> Result<ParamRef, Failure> {
    let text = text(param, "param")?;
    text.parse::<ParamRef>()
        .map_err(|e| Failure::Argument(format!("{text:?}: {e}")))
}

/// Parameter `pnu`, element `index` (or none: [`USSRT_NO_INDEX`]).
fn param_at(pnu: u16, index: i32) -> Result<ParamRef, Failure> {
    let bad = || {
        Failure::Argument(format!(
            "index {index}: array indices are 0..=254, or -1 for none"
        ))
    };
    let index = match index {
        USSRT_NO_INDEX => None,
        i => Some(u8::try_from(i).map_err(|_| bad())?),
    };
    ParamRef::numbered(pnu, index).map_err(|_| bad())
}

fn options(flags: u32) -> Result<WriteOptions, Failure> {
    if flags & !(USSRT_WRITE_EEPROM | USSRT_WRITE_FORCE | USSRT_WRITE_UNSAFE) != 0 {
        return Err(Failure::Argument(format!(
            "flags {flags:#x}: only USSRT_WRITE_EEPROM, USSRT_WRITE_FORCE and \
             USSRT_WRITE_UNSAFE are defined"
        )));
    }
    Ok(WriteOptions {
        eeprom: flags & USSRT_WRITE_EEPROM != 0,
        force: flags & USSRT_WRITE_FORCE != 0,
        unsafe_write: flags & USSRT_WRITE_UNSAFE != 0,
    })
}

/// Reads `param` of drive `address`, written as the manuals do (`"P1082"`, `"r0021"`,
/// `"P0947[3]"`, `"r0947.3"`), as its own type into `*value`. `DRIVE_ERROR` with the drive's
/// error number when it refuses (`ussrt_last_error_info`).
///
/// # Safety
/// `bus` is a live handle; `param` a NUL-terminated string; `value` writable memory for one
/// `UssrtValue`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_read(
    bus: *const UssrtBus,
    address: u8,
    param: *const c_char,
    value: *mut UssrtValue,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let value = out(value, "value")?;
        let read = bus.bus.read_param(drive(address)?, param_ref(param)?)?;
        *value = value_of(&read);
        Ok(())
    })
}

/// Reads every element of an array parameter named without one (`"r0947"`: all 8), or the one
/// element or plain parameter named, each as its own type, into `values[0..]`; `*count` gets
/// how many. `INVALID_ARGUMENT` when `capacity` is smaller than the parameter's elements
/// (`*count` then says how many it has; nothing is read).
///
/// # Safety
/// `bus` is a live handle; `param` a NUL-terminated string; `values` writable memory for
/// `capacity` `UssrtValue`s; `count` writable memory for one `size_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_read_elements(
    bus: *const UssrtBus,
    address: u8,
    param: *const c_char,
    values: *mut UssrtValue,
    capacity: usize,
    count: *mut usize,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let count = out(count, "count")?;
        let param = param_ref(param)?;
        let drive = drive(address)?;
        let needed = bus.bus.element_count(drive, param);
        *count = needed;
        if capacity < needed {
            return Err(Failure::Argument(format!(
                "{param} has {needed} elements: give room for them (capacity {capacity})"
            )));
        }
        out(values, "values")?;
        let read = bus.bus.read_elements(drive, param)?;
        // SAFETY: non-NULL (checked) and `capacity` values long (as documented).
        let values = unsafe { core::slice::from_raw_parts_mut(values, capacity) };
        for (slot, v) in values.iter_mut().zip(&read) {
            *slot = value_of(v);
        }
        *count = read.len();
        Ok(())
    })
}

/// Writes `text` (`"45"`, `"2.5"`, `"0x1F"`) to `param`, converted to the parameter's own type;
/// what does not fit, or a read-only parameter, is refused before the bus (`VALUE`). `flags`:
/// `USSRT_WRITE_EEPROM`, `USSRT_WRITE_FORCE`, `USSRT_WRITE_UNSAFE`. `*held` (may be NULL) gets the value the drive
/// now holds.
///
/// # Safety
/// `bus` is a live handle; `param` and `text` NUL-terminated strings; `held` NULL or writable
/// memory for one `UssrtValue`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_write(
    bus: *const UssrtBus,
    address: u8,
    param: *const c_char,
    value_text: *const c_char,
    flags: u32,
    held: *mut UssrtValue,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let param = param_ref(param)?;
        let value_text = text(value_text, "value_text")?;
        let address = drive(address)?;
        let written = bus
            .bus
            .write_param(address, param, value_text, options(flags)?)
            .map_err(|e| match bus.bus.refusal_hint(address, param, &e) {
                Some(hint) => Failure::Hinted(e, hint),
                None => e.into(),
            })?;
        // SAFETY: NULL or the caller's memory (as documented).
        if let Some(held) = unsafe { held.as_mut() } {
            *held = value_of(&written);
        }
        Ok(())
    })
}

/// Copies every setting of drive `address` from RAM to ROM (P0971 on MICROMASTER 4, p0971 on
/// SINAMICS G120) and returns once the drive is done: what it holds survives a power cycle.
/// The access level the copy needs is raised and put back, in EEPROM too. A G120 stores no
/// single value in EEPROM (`USSRT_WRITE_EEPROM` is `REFUSED` there): write to RAM, then call
/// this. `REFUSED` for a family without a known copy (generic, SIMOREG).
///
/// # Safety
/// `bus` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_save(bus: *const UssrtBus, address: u8) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        bus.bus.save_to_rom(drive(address)?)?;
        Ok(())
    })
}

/// A commissioning call's `flags`: `USSRT_WRITE_UNSAFE` (required: the call's guarded write is
/// asked for deliberately) and `USSRT_WRITE_FORCE` (while another process controls the drive);
/// the calls write RAM only, so `USSRT_WRITE_EEPROM` is refused.
fn commissioning(flags: u32) -> Result<WriteOptions, Failure> {
    if flags & !(USSRT_WRITE_FORCE | USSRT_WRITE_UNSAFE) != 0 {
        return Err(Failure::Argument(format!(
            "flags {flags:#x}: only USSRT_WRITE_UNSAFE and USSRT_WRITE_FORCE are defined here"
        )));
    }
    options(flags)
}

/// Puts every setting of drive `address` back to its factory value as its manual gives it
/// (MICROMASTER 4 and G120: P0010 = 30, then P0970 = 1), and returns once the drive is done
/// and ussd has read again what it scales and judges the drive by (its reference: a
/// `ussrt_control_run_hz` is `REFERENCE_UNKNOWN` until then). The writes are deliberate (ussd
/// logs them as unsafe: the command source, the COM link and the telegram monitoring go back to
/// their defaults): only with `USSRT_WRITE_UNSAFE` in `flags` (`REFUSED` without it, nothing
/// written), and `USSRT_WRITE_FORCE` while another process controls the drive. RAM only:
/// `ussrt_param_save` stores it. `REFUSED` for a family without a known reset.
///
/// # Safety
/// `bus` is a live handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_factory_reset(
    bus: *const UssrtBus,
    address: u8,
    flags: u32,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        bus.bus
            .factory_reset(drive(address)?, commissioning(flags)?)?;
        Ok(())
    })
}

/// Quick commissioning as the drive's manual gives it: P0010 = 1, then `count` motor values
/// (`params[i]` written as the manuals do, `"P0304"`; `values[i]` as text in its own unit,
/// `"400"`), in order, then P3900 = `end` (3: the motor model only; 2: and the I/O back to
/// factory values; 1: and every other setting, the command source, the COM link and the
/// telegram monitoring included), and returns once the drive is done and ussd has read it
/// again. A value the drive refuses is `DRIVE_ERROR` with the drive out of quick
/// commissioning (P0010 back to 0) and the access level put back; values written before stay
/// in RAM. The end of quick commissioning is a guarded write: only with `USSRT_WRITE_UNSAFE` in
/// `flags` (`REFUSED` without it, nothing written); the motor values are written as any write
/// (a guarded one among them is `REFUSED`); `USSRT_WRITE_FORCE` while another process controls
/// the drive. `REFUSED` for a family without a known quick commissioning.
///
/// # Safety
/// `bus` is a live handle; `params` and `values` arrays of `count` NUL-terminated strings
/// (NULL when `count` is 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_quick_commission(
    bus: *const UssrtBus,
    address: u8,
    params: *const *const c_char,
    values: *const *const c_char,
    count: usize,
    end: u16,
    flags: u32,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let options = commissioning(flags)?;
        let mut motor = Vec::with_capacity(count);
        if count > 0 {
            if params.is_null() || values.is_null() {
                return Err(Failure::Argument(
                    "params and values: NULL with a count above 0".to_owned(),
                ));
            }
            for i in 0..count {
                // SAFETY: the caller's arrays of `count` pointers (as documented).
                let (p, v) = unsafe { (*params.add(i), *values.add(i)) };
                motor.push((param_ref(p)?, text(v, "values[i]")?));
            }
        }
        bus.bus
            .quick_commission(drive(address)?, &motor, end, options)?;
        Ok(())
    })
}

/// Uploads every setting of drive `address` as STARTER does (each setting of its family's
/// catalogue with every element the drive has, its data sets included, and its firmware) into
/// `text` as the backup file's TOML, NUL-terminated: what `ussctl param backup` writes and
/// `ussctl param restore` reads. `*length` gets the text's length without the NUL; a
/// `capacity` of at most `*length` is `INVALID_ARGUMENT` (nothing written: call again with
/// room for `*length + 1`; each call uploads anew, so give room to spare). `REFUSED` for a
/// generic slave.
///
/// # Safety
/// `bus` is a live handle; `text` writable memory for `capacity` bytes (NULL when `capacity`
/// is 0); `length` writable memory for one `size_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_backup(
    bus: *const UssrtBus,
    address: u8,
    text: *mut c_char,
    capacity: usize,
    length: *mut usize,
) -> UssrtStatus {
    // SAFETY: passed on as the caller gave them, as documented for both.
    unsafe { backup_text(bus, address, None, text, capacity, length) }
}

/// `ussrt_param_backup`, and the settable parameters numbered `first..=last` that the
/// catalogue does not list, as the drive describes them (AK 4, one exchange per number; the
/// file's `[described]`): the rest of a drive's list where uss-rt's is not whole. `first`
/// above `last` is `VALUE`, refused before the bus.
///
/// # Safety
/// As `ussrt_param_backup`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_backup_discover(
    bus: *const UssrtBus,
    address: u8,
    first: u16,
    last: u16,
    text: *mut c_char,
    capacity: usize,
    length: *mut usize,
) -> UssrtStatus {
    // SAFETY: passed on as the caller gave them, as documented.
    unsafe { backup_text(bus, address, Some(first..=last), text, capacity, length) }
}

/// The backup's text into the caller's buffer.
///
/// # Safety
/// As `ussrt_param_backup`.
unsafe fn backup_text(
    bus: *const UssrtBus,
    address: u8,
    discover: Option<core::ops::RangeInclusive<u16>>,
    text: *mut c_char,
    capacity: usize,
    length: *mut usize,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let length = out(length, "length")?;
        let options = uss_client::backup::UploadOptions { discover };
        let upload = bus
            .bus
            .upload_with(drive(address)?, &options, &mut |_, _| {})?;
        let file = upload.file.to_text();
        *length = file.len();
        if capacity <= file.len() || text.is_null() {
            return Err(Failure::Argument(format!(
                "the backup is {} bytes: give room for {} (capacity {capacity})",
                file.len(),
                file.len() + 1
            )));
        }
        // SAFETY: non-NULL (checked) and `capacity` bytes long (as documented), more than the
        // text and its NUL.
        let room = unsafe { core::slice::from_raw_parts_mut(text.cast::<u8>(), capacity) };
        room[..file.len()].copy_from_slice(file.as_bytes());
        room[file.len()] = 0;
        Ok(())
    })
}

/// Compares drive `address` with the backup file `backup_text` (its TOML, NUL-terminated, as
/// `ussrt_param_backup` gives it): `*differ` gets the elements that differ, `*same` (may be
/// NULL) those that are the same. A file that fails its checks (another family, a value
/// outside its limits, ...) is `VALUE` with the line in `ussrt_last_error`.
///
/// # Safety
/// `bus` is a live handle; `backup_text` a NUL-terminated string; `differ` writable memory for
/// one `size_t`; `same` NULL or writable memory for one `size_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_diff(
    bus: *const UssrtBus,
    address: u8,
    backup_text: *const c_char,
    differ: *mut usize,
    same: *mut usize,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let file = text(backup_text, "backup_text")?;
        let differ = out(differ, "differ")?;
        let diff = bus
            .bus
            .diff_file(drive(address)?, file, "backup_text", &mut |_, _| {})?;
        *differ = diff.differ.len();
        // SAFETY: NULL or the caller's memory (as documented).
        if let Some(same) = unsafe { same.as_mut() } {
            *same = diff.same;
        }
        Ok(())
    })
}

/// `flags` bit of a restore: copy RAM to ROM once every value is in RAM.
pub const USSRT_RESTORE_EEPROM: u32 = 1;
/// `flags` bit of a restore: write even while another process controls the drive.
pub const USSRT_RESTORE_FORCE: u32 = 2;
/// `flags` bit of a restore: write guarded parameters too (command or setpoint source, ...).
pub const USSRT_RESTORE_UNSAFE: u32 = 4;
/// `flags` bit of a restore: write nothing, say what would be written.
pub const USSRT_RESTORE_DRY_RUN: u32 = 8;
/// `flags` bit of a restore: restore a backup of other firmware all the same.
pub const USSRT_RESTORE_OTHER_FIRMWARE: u32 = 16;

/// What a restore did (`ussrt_param_restore`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct UssrtRestore {
    /// 1: every value written (and stored, with `USSRT_RESTORE_EEPROM`); 0: run it again to
    /// complete it.
    pub complete: u8,
    /// What a restore cut short raised on the way and could not put back (the access level,
    /// quick commissioning): 0 normally; see `ussctl param restore` for which.
    pub left_raised: u8,
    /// 1 with `USSRT_RESTORE_EEPROM` when RAM was copied to ROM.
    pub stored: u8,
    /// Values the drive already held, written, refused, unknown (the answer lost: the drive
    /// may hold it), and link settings kept (address, baud rate, PZD/PKW length).
    pub equal: u32,
    pub written: u32,
    pub refused: u32,
    pub unknown: u32,
    pub kept: u32,
}

/// Writes the backup file `backup_text` (its TOML, NUL-terminated, as `ussrt_param_backup`
/// gives it) to drive `address` as STARTER downloads it: the whole file checked first
/// (family, firmware, every value), then only what differs, in a safe order (the access level
/// raised and quick commissioning entered where needed, and put back), each value checked
/// against the drive's answer; the COM link ussd talks over is kept. `flags`:
/// `USSRT_RESTORE_EEPROM`, `USSRT_RESTORE_FORCE`, `USSRT_RESTORE_UNSAFE`,
/// `USSRT_RESTORE_DRY_RUN`, `USSRT_RESTORE_OTHER_FIRMWARE`. `*result` says what it did; an
/// incomplete restore is `OK` with `complete` 0. Nothing written: `REFUSED` (a guarded
/// parameter without `USSRT_RESTORE_UNSAFE`, another controller, a generic slave), `VALUE` (a
/// file that fails its checks, another family or firmware).
///
/// # Safety
/// `bus` is a live handle; `backup_text` a NUL-terminated string; `result` writable memory for
/// one `UssrtRestore`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_restore(
    bus: *const UssrtBus,
    address: u8,
    backup_text: *const c_char,
    flags: u32,
    result: *mut UssrtRestore,
) -> UssrtStatus {
    // SAFETY: the caller's arguments as documented; no cancel.
    unsafe {
        ussrt_param_restore_cancellable(bus, address, backup_text, flags, core::ptr::null(), result)
    }
}

/// A cancel another thread or a signal handler cuts a restore short with
/// (`ussrt_param_restore_cancellable`, `ussrt_cancel`).
#[derive(Debug, Default)]
pub struct UssrtCancel(uss_client::cancel::CancelHandle);

/// Makes a cancel (`*cancel`), not asked yet; free it with `ussrt_cancel_free`.
///
/// # Safety
/// `cancel` is writable memory for one pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_cancel_new(cancel: *mut *mut UssrtCancel) -> UssrtStatus {
    guard(|| {
        let cancel = out(cancel, "cancel")?;
        *cancel = Box::into_raw(Box::default());
        Ok(())
    })
}

/// Asks the call that was given `cancel` to stop between its steps: a restore writes no
/// further value and puts back what it raised (asked again: it leaves what it could not put
/// back yet). One atomic add, nothing else: safe from a signal handler (SIGINT, SIGTERM) and
/// from any thread. `INVALID_ARGUMENT` for NULL.
///
/// # Safety
/// `cancel` is NULL or a live cancel.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_cancel(cancel: *const UssrtCancel) -> UssrtStatus {
    // SAFETY: NULL or live (as documented); no guard: nothing here allocates or unwinds.
    match unsafe { cancel.as_ref() } {
        Some(c) => {
            c.0.cancel();
            UssrtStatus::Ok
        }
        None => UssrtStatus::InvalidArgument,
    }
}

/// Frees a cancel (NULL: nothing); no call may be using it.
///
/// # Safety
/// `cancel` is NULL or made by `ussrt_cancel_new` and freed once.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_cancel_free(cancel: *mut UssrtCancel) {
    if !cancel.is_null() {
        // SAFETY: made by `Box::into_raw` in `ussrt_cancel_new`, freed once.
        drop(unsafe { Box::from_raw(cancel) });
    }
}

/// `ussrt_param_restore`, cut short when `cancel` (NULL: never) is asked
/// (`ussrt_cancel`, from another thread or a signal handler): no further value is written,
/// what the restore raised is put back, and it returns `OK` with `complete` 0 (and
/// `left_raised` what it could not put back, when asked twice).
///
/// # Safety
/// As `ussrt_param_restore`; `cancel` NULL or a live cancel for the whole call.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_restore_cancellable(
    bus: *const UssrtBus,
    address: u8,
    backup_text: *const c_char,
    flags: u32,
    cancel: *const UssrtCancel,
    result: *mut UssrtRestore,
) -> UssrtStatus {
    guard(|| {
        // SAFETY: NULL or live for the call (as documented).
        let cancel = unsafe { cancel.as_ref() };
        let bus = arg(bus, "bus")?;
        let file = text(backup_text, "backup_text")?;
        let result = out(result, "result")?;
        let known = USSRT_RESTORE_EEPROM
            | USSRT_RESTORE_FORCE
            | USSRT_RESTORE_UNSAFE
            | USSRT_RESTORE_DRY_RUN
            | USSRT_RESTORE_OTHER_FIRMWARE;
        if flags & !known != 0 {
            return Err(Failure::Argument(format!(
                "flags {flags:#x}: only the USSRT_RESTORE_ flags are defined"
            )));
        }
        let options = uss_client::restore::RestoreOptions {
            eeprom: flags & USSRT_RESTORE_EEPROM != 0,
            dry_run: flags & USSRT_RESTORE_DRY_RUN != 0,
            force: flags & USSRT_RESTORE_FORCE != 0,
            unsafe_write: flags & USSRT_RESTORE_UNSAFE != 0,
            other_firmware: flags & USSRT_RESTORE_OTHER_FIRMWARE != 0,
            ..Default::default()
        };
        let drive = drive(address)?;
        let catalogue = uss_client::backup::settings_catalogue(drive, bus.bus.family(drive))?;
        let loaded = uss_client::backup::BackupFile::parse(file, "backup_text", catalogue)
            .map_err(uss_client::ParamError::from)?;
        let never = uss_client::cancel::CancelHandle::default();
        let done = bus.bus.restore(
            drive,
            &loaded,
            options,
            cancel.map_or(&never, |c| &c.0),
            &mut |_, _| {},
            &mut |_| {},
        )?;
        let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
        *result = UssrtRestore {
            complete: u8::from(done.is_complete()),
            left_raised: u8::try_from(done.left_raised.len()).unwrap_or(u8::MAX),
            stored: u8::from(
                done.stored
                    .as_ref()
                    .is_some_and(|s| !s.starts_with("not stored")),
            ),
            equal: count(done.equal),
            written: count(done.written),
            refused: count(done.refused),
            unknown: count(done.unknown),
            kept: count(done.kept),
        };
        Ok(())
    })
}

/// Reads parameter number `pnu` (element `index`, or `USSRT_NO_INDEX`) as the raw word or
/// double word the drive sends: `*value`, and `*is_dword` (may be NULL).
///
/// # Safety
/// `bus` is a live handle; `value` writable memory for one `uint32_t`; `is_dword` NULL or
/// writable memory for one `uint8_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_read_raw(
    bus: *const UssrtBus,
    address: u8,
    pnu: u16,
    index: i32,
    value: *mut u32,
    is_dword: *mut u8,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let value = out(value, "value")?;
        let (raw, dword) = raw_of(bus.bus.read(drive(address)?, param_at(pnu, index)?)?);
        *value = raw;
        // SAFETY: NULL or the caller's memory (as documented).
        if let Some(is_dword) = unsafe { is_dword.as_mut() } {
            *is_dword = dword;
        }
        Ok(())
    })
}

/// Writes `value` to parameter number `pnu` (element `index`, or `USSRT_NO_INDEX`) as a double
/// word (`dword` != 0) or a word (a value above 0xFFFF is refused); `flags` as
/// [`ussrt_param_write`]. `*held` (may be NULL) gets what the drive answered.
///
/// # Safety
/// `bus` is a live handle; `held` NULL or writable memory for one `uint32_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_write_raw(
    bus: *const UssrtBus,
    address: u8,
    pnu: u16,
    index: i32,
    value: u32,
    dword: u8,
    flags: u32,
    held: *mut u32,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let value = raw_value(value, dword)?;
        let answered = bus.bus.write_with(
            drive(address)?,
            param_at(pnu, index)?,
            value,
            options(flags)?,
        )?;
        // SAFETY: NULL or the caller's memory (as documented).
        if let Some(held) = unsafe { held.as_mut() } {
            *held = raw_of(answered).0;
        }
        Ok(())
    })
}

/// One item of a batch ([`ussrt_param_batch`]): a read (`write` 0) or a write of `value` (a
/// double word when `dword` != 0, else a word) of parameter number `pnu`, element `index` (or
/// `USSRT_NO_INDEX`).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct UssrtParamItem {
    pub pnu: u16,
    pub write: u8,
    pub dword: u8,
    pub index: i32,
    pub value: u32,
}

/// What one item of a batch ended with: `status` `USSRT_STATUS_OK` with the word or double
/// word the drive answered, or the item's own failure (`DRIVE_ERROR` with the drive's error
/// number in `drive_error`, `MAYBE_APPLIED`, `TIMEOUT`, ...).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct UssrtParamResult {
    pub status: UssrtStatus,
    /// The drive's error number with `DRIVE_ERROR`, else 0xFFFF.
    pub drive_error: u16,
    /// 1: a double word.
    pub is_dword: u8,
    pub reserved: u8,
    pub value: u32,
}

/// Runs up to 39 items of drive `address` in one request, one after the other with no other
/// client's task between them, whole or not at all (Rust's `Bus::batch`): `results[i]` gets
/// what `items[i]` ended with. Returns `USSRT_STATUS_OK` when ussd answered the request (each item's own status is in
/// its result), or the failure of the request as a whole (then no result is written). `flags`:
/// `USSRT_WRITE_EEPROM` (writes to RAM and EEPROM), `USSRT_WRITE_FORCE`; a guarded parameter is
/// written with `ussrt_param_write_raw` and `USSRT_WRITE_UNSAFE` only.
///
/// # Safety
/// `bus` is a live handle; `items` readable memory for `count` items; `results` writable
/// memory for `count` results.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_batch(
    bus: *const UssrtBus,
    address: u8,
    items: *const UssrtParamItem,
    count: usize,
    flags: u32,
    results: *mut UssrtParamResult,
) -> UssrtStatus {
    guard(|| {
        use uss_client::ParamTask;
        let bus = arg(bus, "bus")?;
        let max = uss_client::uss_shm_types::MAX_PARAM_ITEMS;
        if count == 0 || count > max {
            return Err(Failure::Argument(format!(
                "a batch has 1 to {max} items, not {count}"
            )));
        }
        if flags & USSRT_WRITE_UNSAFE != 0 {
            return Err(Failure::Argument(
                "USSRT_WRITE_UNSAFE is not taken by a batch: write a guarded parameter with ussrt_param_write_raw".into(),
            ));
        }
        let options = options(flags)?;
        arg(items, "items")?;
        out(results, "results")?;
        // SAFETY: non-NULL (checked) and `count` items long (as documented).
        let items = unsafe { core::slice::from_raw_parts(items, count) };
        let storage = options.storage();
        let tasks = items
            .iter()
            .map(|i| {
                let p = param_at(i.pnu, i.index)?;
                Ok(if i.write == 0 {
                    ParamTask::read(p.pnu, p.index)
                } else {
                    ParamTask::write(p.pnu, p.index, raw_value(i.value, i.dword)?, storage)
                })
            })
            .collect::<Result<Vec<_>, Failure>>()?;
        let answered = bus.bus.try_batch(drive(address)?, &tasks, options.force)?;
        // SAFETY: non-NULL (checked) and `count` results long (as documented).
        let results = unsafe { core::slice::from_raw_parts_mut(results, count) };
        for (slot, result) in results.iter_mut().zip(answered) {
            *slot = match result {
                Ok(v) => {
                    let (value, is_dword) = raw_of(v);
                    UssrtParamResult {
                        status: UssrtStatus::Ok,
                        drive_error: 0xFFFF,
                        is_dword,
                        reserved: 0,
                        value,
                    }
                }
                Err(e) => {
                    let info = param_info(&e);
                    UssrtParamResult {
                        status: info.status,
                        drive_error: info.drive_error,
                        is_dword: 0,
                        reserved: 0,
                        value: 0,
                    }
                }
            };
        }
        Ok(())
    })
}

/// Reads the drive's fault buffer with fault values and texts, and its active warnings, in one
/// request, into `*report`.
///
/// # Safety
/// `bus` is a live handle; `report` writable memory for one `UssrtFaultReport`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_fault_report(
    bus: *const UssrtBus,
    address: u8,
    report: *mut UssrtFaultReport,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let report = out(report, "report")?;
        let read = bus.bus.fault_report(drive(address)?)?;
        let empty = UssrtFault {
            number: 0,
            value: 0,
            has_value: 0,
            slot: 0,
            text: [0; 64],
        };
        let mut r = UssrtFaultReport {
            fault_count: 0,
            warning_count: 0xFF,
            codes_pnu: read.codes.pnu.get(),
            faults: [empty; 8],
            warnings: [0; 8],
        };
        for (slot, f) in r.faults.iter_mut().zip(&read.faults) {
            slot.number = f.number;
            slot.value = f.value.unwrap_or(0);
            slot.has_value = u8::from(f.value.is_some());
            slot.slot = f.slot;
            copy_text(&mut slot.text, f.text.unwrap_or_default());
            r.fault_count += 1;
        }
        if let Some(warnings) = &read.warnings {
            r.warning_count = 0;
            for (slot, w) in r.warnings.iter_mut().zip(warnings) {
                *slot = w.number;
                r.warning_count += 1;
            }
        }
        *report = r;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_cut_at_a_character_boundary_and_terminated() {
        let mut buf = [1 as c_char; 5];
        copy_text(&mut buf, "abc°def");
        // Four bytes fit: "abc" and the first of the two of "°", inside it: cut before it.
        assert_eq!(
            buf[..4],
            [b'a' as c_char, b'b' as c_char, b'c' as c_char, 0]
        );
        let mut buf = [1 as c_char; 4];
        copy_text(&mut buf, "Hz");
        assert_eq!(buf[..3], [b'H' as c_char, b'z' as c_char, 0]);
    }

    #[test]
    fn indices_and_flags_outside_their_range_are_argument_errors() {
        assert_eq!(param_at(947, -1).ok().and_then(|p| p.index), None);
        assert_eq!(
            param_at(947, 254)
                .ok()
                .and_then(|p| p.index)
                .map(Subindex::get),
            Some(254)
        );
        assert!(param_at(947, 255).is_err() && param_at(947, -2).is_err());
        assert!(options(8).is_err());
        let o = options(USSRT_WRITE_EEPROM | USSRT_WRITE_FORCE).ok();
        assert_eq!(
            o.map(|o| (o.eeprom, o.force, o.unsafe_write)),
            Some((true, true, false))
        );
        assert!(options(USSRT_WRITE_UNSAFE).is_ok_and(|o| o.unsafe_write));
    }
}

/// What a drive says one of its parameters is (`ussrt_param_describe`): its PROFIdrive
/// descriptive elements.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct UssrtDescription {
    /// Its data type, as PROFIdrive codes it (descriptive element 1): 3 Integer16, 4
    /// Integer32, 6 Unsigned16, 7 Unsigned32, 8 `FloatingPoint`.
    pub data_type: u8,
    /// 1: `elements` is said (descriptive element 2): 0 a plain parameter, else its data sets
    /// or array elements.
    pub has_elements: u8,
    pub elements: u16,
    /// 1 read-only, 0 settable (descriptive element 4); 255: not said.
    pub read_only: u8,
    /// 1: `min` / `max` are said (descriptive elements 7 and 8; a 3-word channel cannot carry
    /// them), in the parameter's own unit.
    pub has_min: u8,
    pub has_max: u8,
    pub reserved: u8,
    pub min: f64,
    pub max: f64,
}

/// What drive `address` says `param` (the manuals' notation, `"P1120"`) is, by its PROFIdrive
/// descriptive elements in one request (data type, elements, read-only, limits), into
/// `*description`. A parameter the drive does not have: `DRIVE_ERROR` (its number); a generic
/// slave is never asked: `VALUE`.
///
/// # Safety
/// `bus` is a live handle; `param` a NUL-terminated string; `description` writable memory for
/// one `UssrtDescription`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_param_describe(
    bus: *const UssrtBus,
    address: u8,
    param: *const c_char,
    description: *mut UssrtDescription,
) -> UssrtStatus {
    guard(|| {
        let bus = arg(bus, "bus")?;
        let param = param_ref(param)?;
        let description = out(description, "description")?;
        let said = bus.bus.drive_description(drive(address)?, param.pnu)?;
        *description = UssrtDescription {
            data_type: u8::try_from(said.data_type.code()).unwrap_or(u8::MAX),
            has_elements: u8::from(said.elements.is_some()),
            elements: said.elements.unwrap_or(0),
            read_only: said.read_only.map_or(u8::MAX, u8::from),
            has_min: u8::from(said.min.is_some()),
            has_max: u8::from(said.max.is_some()),
            reserved: 0,
            min: said.min.unwrap_or(0.0),
            max: said.max.unwrap_or(0.0),
        };
        Ok(())
    })
}
