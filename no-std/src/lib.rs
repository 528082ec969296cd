//! A firmware's view of uss-rt: the codec (and the control rules) with nothing that links
//! `std`. This library defines its own panic handler, as a `no_std` program must; were `std`
//! linked by any crate below it, the build would fail with a duplicate `panic_impl`. `.ci/run`
//! builds it; nothing runs it.
#![no_std]

use uss_protocol::{Address, Adr, Setpoint, Stw1, encode};

/// Encodes a run telegram for drive `address` at `hz` of `reference_hz` into `out` (at least
/// 32 bytes); returns its length, or 0 when the address or the buffer is wrong.
///
/// # Safety
/// `out` points to `len` writable bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn uss_no_std_run_telegram(
    address: u8,
    hz: f32,
    reference_hz: f32,
    out: *mut u8,
    len: usize,
) -> usize {
    if out.is_null() {
        return 0;
    }
    // SAFETY: the caller gives `len` writable bytes at `out`.
    let out = unsafe { core::slice::from_raw_parts_mut(out, len) };
    let Ok(address) = Address::new(address) else {
        return 0;
    };
    let setpoint = Setpoint::from_hz(hz, reference_hz);
    encode(out, Adr::to(address), &[], &[Stw1::RUN.bits(), setpoint.word()]).unwrap_or(0)
}


/// How strongly control word `stw1` stops a drive (0 runs it, 1 OFF1, 2 OFF3, 3 OFF2): the
/// control rules' own test, as the engine and every controller make it.
#[unsafe(no_mangle)]
pub extern "C" fn uss_no_std_stop_strength(stw1: u16) -> u8 {
    uss_control::stop_strength(stw1)
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {}
}
