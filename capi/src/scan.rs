//! `ussrt_scan`: the drives on a line ussd does not serve (`uss_client::scan`).

use crate::error::{Failure, guard, out, text};
use crate::status::UssrtStatus;
use core::ffi::c_char;
use uss_client::scan::{ScanOptions, scan};
use uss_client::uss_protocol::Baud;

/// A slave `ussrt_scan` found.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct UssrtScanned {
    pub baud: u32,
    pub address: u8,
    /// Its parameter channel as P2013 says it: 0, 3, 4, 127 (variable); 255: not known (it
    /// answered the mirror telegram, no layout).
    pub pkw: u8,
    /// Its PZD length (P2012).
    pub pzd: u8,
    /// 1: `zsw1` is the status word it answered with.
    pub has_zsw1: u8,
    pub zsw1: u16,
    /// Its firmware times 100 (209: 2.09); 0: not told.
    pub firmware: u16,
    /// The family to configure, as `UssDriveFamily` codes it (a G110 answers as a
    /// MICROMASTER 4); 255: not told (SIMOREG, a generic slave: name it yourself).
    pub family: u8,
    /// 1: every part of it confirmed (the layout by two replies to different tasks, the family
    /// by its identification); 0: unsure (`ussctl scan` says why).
    pub sure: u8,
}

/// Scans the serial line `device` (a line ussd does not serve: no bus, no ussd): at each of the
/// `baud_count` rates `bauds` (NULL and 0: MICROMASTER's P2010 rates 1200..115200), each of the
/// `address_count` addresses (NULL and 0: 0..31) is asked by a mirror telegram, and each slave
/// that answers is identified into `found` (up to `capacity`); `*count` gets how many were
/// found, by rate and then address (`capacity` of rates times addresses always suffices; less
/// than `*count` is `INVALID_ARGUMENT`, the first `capacity` written). A silent address is
/// asked `tries` times (1..20). Every probe carries OFF1 (STW1 0x047E, setpoint 0): a drive
/// that runs under USS control on that line ramps down and stays off. A line that cannot be
/// used (missing, busy, not a tty, no permission, failed): `DEVICE`. It takes a while (32
/// addresses at 8 rates: about half a minute on an empty line) and cannot be cut short.
///
/// # Safety
/// `device` a NUL-terminated string; `bauds` `baud_count` values and `addresses`
/// `address_count` values (NULL when 0); `found` writable memory for `capacity` entries (NULL
/// when 0); `count` writable memory for one `size_t`.
#[unsafe(no_mangle)]
#[allow(
    clippy::too_many_arguments,
    reason = "a C call's arrays each come with their length"
)]
pub unsafe extern "C" fn ussrt_scan(
    device: *const c_char,
    bauds: *const u32,
    baud_count: usize,
    addresses: *const u8,
    address_count: usize,
    tries: u32,
    found: *mut UssrtScanned,
    capacity: usize,
    count: *mut usize,
) -> UssrtStatus {
    guard(|| {
        let device = std::path::PathBuf::from(text(device, "device")?);
        let count = out(count, "count")?;
        let mut options = ScanOptions {
            tries,
            ..ScanOptions::default()
        };
        // SAFETY: the caller's arrays of their counts (as documented).
        if let Some(rates) = unsafe { array(bauds, baud_count, "bauds") }? {
            options.bauds = rates
                .iter()
                .map(|&b| Baud::new(b).map_err(|e| Failure::Argument(e.to_string())))
                .collect::<Result<_, _>>()?;
        }
        // SAFETY: as above.
        if let Some(list) = unsafe { array(addresses, address_count, "addresses") }? {
            options.addresses = list
                .iter()
                .map(|&a| crate::error::drive(a))
                .collect::<Result<_, _>>()?;
        }
        if capacity > 0 && found.is_null() {
            return Err(Failure::Argument(
                "found is NULL with a capacity above 0".to_owned(),
            ));
        }
        let scanned = scan(
            &device,
            &options,
            &uss_client::cancel::NeverCancelled,
            &mut |_, _| {},
            &mut |_| {},
        )?;
        *count = scanned.drives.len();
        for (i, f) in scanned.drives.iter().take(capacity).enumerate() {
            let entry = UssrtScanned {
                baud: f.baud.get(),
                address: f.address.get(),
                pkw: f
                    .pkw
                    .map_or(u8::MAX, |m| u8::try_from(m.p2013()).unwrap_or(u8::MAX)),
                pzd: u8::try_from(f.pzd).unwrap_or(u8::MAX),
                has_zsw1: u8::from(f.zsw1.is_some()),
                zsw1: f.zsw1.unwrap_or(0),
                firmware: f
                    .firmware
                    .map_or(0, |v| (v * 100.0).round().clamp(0.0, 65535.0) as u16),
                family: f.family.map_or(u8::MAX, uss_client::DriveFamily::code),
                sure: u8::from(f.unsure.is_none()),
            };
            // SAFETY: `i` < `capacity`, the caller's room (as documented).
            unsafe { found.add(i).write(entry) };
        }
        if scanned.drives.len() > capacity {
            return Err(Failure::Argument(format!(
                "found: room for {capacity}, {} found (the first {capacity} written)",
                scanned.drives.len()
            )));
        }
        Ok(())
    })
}

/// The caller's `len` values at `ptr`, `None` for none (NULL and 0).
///
/// # Safety
/// `ptr` points at `len` values, or `len` is 0.
unsafe fn array<'a, T>(ptr: *const T, len: usize, what: &str) -> Result<Option<&'a [T]>, Failure> {
    match (ptr.is_null(), len) {
        (_, 0) => Ok(None),
        (true, _) => Err(Failure::Argument(format!(
            "{what} is NULL with a count above 0"
        ))),
        // SAFETY: as the caller promises.
        (false, n) => Ok(Some(unsafe { core::slice::from_raw_parts(ptr, n) })),
    }
}
