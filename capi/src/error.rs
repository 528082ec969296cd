//! Status codes, the calling thread's last error, and the guard every exported function runs
//! its body in (no panic crosses the boundary).

use crate::UssrtStatus;
use core::ffi::{CStr, c_char};
use std::cell::RefCell;
use std::ffi::CString;
use std::panic::{AssertUnwindSafe, catch_unwind};
use uss_client::uss_shm_types::{DriveError, LatchReason, StopCommand};
use uss_client::{Address, ClientError, Latch, ParamError};

/// Details of the calling thread's last failure, beyond its status and message.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UssrtErrorInfo {
    /// The status of the last failure (`USSRT_STATUS_OK` after a success).
    pub status: UssrtStatus,
    /// With `TRIPPED` and `NOT_ARMED`: why the drive is latched (a `UssLatchReason` code of
    /// `uss_shm_types.h`), what it gets meanwhile (a `UssStopCommand` code), and why a sample
    /// was refused (a `UssRejection` code); with `STALLED`: the reason "controller stale" and
    /// the drive's safe command; 0 otherwise.
    pub latch_reason: u8,
    pub latch_command: u8,
    pub rejection: u8,
    pub reserved: u8,
    /// With `DRIVE_ERROR`: the drive's error number (USS.md section 6: 0 illegal PNU, 2 limit
    /// exceeded, ...), or 0xFFFF for reply 8 (no change rights); 0xFFFF otherwise.
    pub drive_error: u16,
    pub reserved2: u16,
    /// With a latch: the operator or controller process behind it (0 if unknown).
    pub latched_by_pid: u32,
    /// With a latch: how long ago it began, ms.
    pub latched_ms_ago: u32,
}

const NO_DRIVE_ERROR: u16 = 0xFFFF;

impl UssrtErrorInfo {
    const fn of(status: UssrtStatus) -> Self {
        Self {
            status,
            latch_reason: 0,
            latch_command: 0,
            rejection: 0,
            reserved: 0,
            drive_error: NO_DRIVE_ERROR,
            reserved2: 0,
            latched_by_pid: 0,
            latched_ms_ago: 0,
        }
    }

    fn with_latch(mut self, latch: &Latch) -> Self {
        self.latch_reason = latch.reason.code();
        self.latch_command = StopCommand::code_of(latch.command);
        self.rejection = latch.rejection.code();
        self.latched_by_pid = latch.by_pid;
        self.latched_ms_ago = u32::try_from(latch.ago.as_millis()).unwrap_or(u32::MAX);
        self
    }
}

/// Why a call failed, before it becomes a status and a message.
#[derive(Debug)]
pub(crate) enum Failure {
    Argument(String),
    Client(ClientError),
    Param(ParamError),
    Scan(uss_client::scan::ScanError),
    /// A drive's refusal and what to do about it (`Bus::refusal_hint`), said after its words.
    Hinted(ParamError, String),
}

impl From<uss_client::scan::ScanError> for Failure {
    fn from(e: uss_client::scan::ScanError) -> Self {
        Self::Scan(e)
    }
}

impl From<ClientError> for Failure {
    fn from(e: ClientError) -> Self {
        Self::Client(e)
    }
}

impl From<ParamError> for Failure {
    fn from(e: ParamError) -> Self {
        match e {
            ParamError::Client(c) => Self::Client(c),
            other => Self::Param(other),
        }
    }
}

fn client_info(e: &ClientError) -> UssrtErrorInfo {
    let info = UssrtErrorInfo::of(UssrtStatus::of(e.kind().status()));
    match e {
        ClientError::Tripped { latch, .. } | ClientError::NotArmed { latch, .. } => {
            info.with_latch(latch)
        }
        // A trip the program found itself: stale, with the drive's safe command.
        ClientError::Stalled { command, .. } => UssrtErrorInfo {
            latch_reason: LatchReason::Stale.code(),
            latch_command: StopCommand::code_of(*command),
            ..info
        },
        _ => info,
    }
}

pub(crate) fn param_info(e: &ParamError) -> UssrtErrorInfo {
    match e {
        ParamError::Client(c) => client_info(c),
        ParamError::Drive(DriveError::Refused(p)) => UssrtErrorInfo {
            drive_error: p.number(),
            ..UssrtErrorInfo::of(UssrtStatus::DriveError)
        },
        _ => UssrtErrorInfo::of(UssrtStatus::of(e.kind().status())),
    }
}

impl Failure {
    fn info(&self) -> UssrtErrorInfo {
        match self {
            Self::Argument(_) => UssrtErrorInfo::of(UssrtStatus::InvalidArgument),
            Self::Client(e) => client_info(e),
            Self::Param(e) | Self::Hinted(e, _) => param_info(e),
            Self::Scan(e) => UssrtErrorInfo::of(UssrtStatus::of(e.kind().status())),
        }
    }

    fn message(&self) -> String {
        match self {
            Self::Argument(m) => m.clone(),
            Self::Client(e) => e.to_string(),
            Self::Param(e) => e.to_string(),
            Self::Scan(e) => e.to_string(),
            Self::Hinted(e, hint) => format!("{e}: {hint}"),
        }
    }
}

struct Last {
    info: UssrtErrorInfo,
    message: CString,
}

thread_local! {
    static LAST: RefCell<Last> = RefCell::new(Last {
        info: UssrtErrorInfo::of(UssrtStatus::Ok),
        message: CString::default(),
    });
}

fn remember(info: UssrtErrorInfo, message: &str) {
    // A message with a NUL byte inside is cut there; it never fails.
    let text = message.split('\0').next().unwrap_or_default();
    let message = CString::new(text).unwrap_or_default();
    LAST.with(|l| *l.borrow_mut() = Last { info, message });
}

/// Runs `f` (an exported function's body): its failure, or a panic, becomes the status and the
/// thread's last error; success clears it.
pub(crate) fn guard(f: impl FnOnce() -> Result<(), Failure>) -> UssrtStatus {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => {
            remember(UssrtErrorInfo::of(UssrtStatus::Ok), "");
            UssrtStatus::Ok
        }
        Ok(Err(failure)) => {
            let info = failure.info();
            remember(info, &failure.message());
            info.status
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            remember(
                UssrtErrorInfo::of(UssrtStatus::Internal),
                &format!("a defect in libussrt (please report it): {what}"),
            );
            UssrtStatus::Internal
        }
    }
}

/// `ptr` as a reference, or an argument error naming `what`.
pub(crate) fn arg<'a, T>(ptr: *const T, what: &str) -> Result<&'a T, Failure> {
    // SAFETY: the caller passes a pointer to a live `T` or NULL (the header says so); NULL is
    // refused here.
    unsafe { ptr.as_ref() }.ok_or_else(|| Failure::Argument(format!("{what} is NULL")))
}

/// A caller's drive address, checked here, where it enters: 0..=31, or the client's address
/// error.
pub(crate) fn drive(address: u8) -> Result<Address, Failure> {
    Address::new(address).map_err(|e| Failure::from(ClientError::from(e)))
}

/// `ptr` as a mutable reference (an output of the caller), or an argument error.
pub(crate) fn out<'a, T>(ptr: *mut T, what: &str) -> Result<&'a mut T, Failure> {
    // SAFETY: as `arg`, for memory the caller lends for writing.
    unsafe { ptr.as_mut() }.ok_or_else(|| Failure::Argument(format!("{what} is NULL")))
}

/// A NUL-terminated UTF-8 string of the caller.
pub(crate) fn text<'a>(ptr: *const c_char, what: &str) -> Result<&'a str, Failure> {
    if ptr.is_null() {
        return Err(Failure::Argument(format!("{what} is NULL")));
    }
    // SAFETY: not NULL; the caller passes a NUL-terminated string that lives during the call.
    unsafe { CStr::from_ptr(ptr) }
        .to_str()
        .map_err(|_| Failure::Argument(format!("{what} is not UTF-8")))
}

/// The message of the calling thread's last failure ("" after a success): owned by the
/// library, valid until this thread's next `ussrt_*` call. Never NULL.
#[unsafe(no_mangle)]
pub extern "C" fn ussrt_last_error() -> *const c_char {
    LAST.with(|l| l.borrow().message.as_ptr())
}

/// The name of status code `status` in snake case (`"ok"`, `"tripped"`, `"not_armed"`, ...;
/// `"unknown"` for a code this library does not have), for logs: the same word as the Rust
/// client's error and the Python exception. Static; never NULL.
#[unsafe(no_mangle)]
pub extern "C" fn ussrt_status_name(status: i32) -> *const c_char {
    UssrtStatus::ALL
        .iter()
        .find(|s| **s as i32 == status)
        .map_or(c"unknown", |s| s.name())
        .as_ptr()
}

/// Copies the details of the calling thread's last failure into `*info` (the caller's
/// memory). Returns `USSRT_STATUS_INVALID_ARGUMENT` for a NULL `info` and leaves the last
/// error as it was.
///
/// # Safety
/// `info` is NULL or points to writable memory for one `UssrtErrorInfo`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn ussrt_last_error_info(info: *mut UssrtErrorInfo) -> UssrtStatus {
    // SAFETY: as documented.
    match unsafe { info.as_mut() } {
        Some(info) => {
            *info = LAST.with(|l| l.borrow().info);
            UssrtStatus::Ok
        }
        None => UssrtStatus::InvalidArgument,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn last() -> (UssrtErrorInfo, String) {
        let mut info = UssrtErrorInfo::of(UssrtStatus::Ok);
        // SAFETY: a local.
        assert_eq!(
            unsafe { ussrt_last_error_info(&raw mut info) },
            UssrtStatus::Ok
        );
        // SAFETY: the library's NUL-terminated message.
        let text = unsafe { CStr::from_ptr(ussrt_last_error()) };
        (info, text.to_str().unwrap_or_default().to_owned())
    }

    #[test]
    fn a_failure_leaves_its_status_and_message_and_a_success_clears_them() {
        let status = guard(|| Err(Failure::Argument("bus is NULL".to_owned())));
        assert_eq!(status, UssrtStatus::InvalidArgument);
        assert_eq!(last().1, "bus is NULL");
        assert_eq!(last().0.status, UssrtStatus::InvalidArgument);
        assert_eq!(guard(|| Ok(())), UssrtStatus::Ok);
        assert_eq!(last(), (UssrtErrorInfo::of(UssrtStatus::Ok), String::new()));
    }

    #[test]
    fn every_status_has_its_name_in_code_order() {
        for (code, status) in UssrtStatus::ALL.iter().enumerate() {
            assert_eq!(*status as usize, code);
            // SAFETY: a static NUL-terminated name.
            let name = unsafe { CStr::from_ptr(ussrt_status_name(code as i32)) };
            assert_eq!(name, status.name());
        }
        // SAFETY: as above.
        let tripped = unsafe { CStr::from_ptr(ussrt_status_name(8)) };
        assert_eq!(tripped, c"tripped");
        // SAFETY: as above.
        let unknown = unsafe { CStr::from_ptr(ussrt_status_name(99)) };
        assert_eq!(unknown, c"unknown");
    }

    #[test]
    fn a_panic_is_caught_and_named() {
        let status = guard(|| panic!("boom"));
        assert_eq!(status, UssrtStatus::Internal);
        assert!(last().1.ends_with("boom"), "{}", last().1);
    }

    #[test]
    fn a_drive_error_carries_its_number() {
        use uss_client::uss_protocol::ErrorNumber;
        let e = ParamError::Drive(DriveError::Refused(ErrorNumber::LimitExceeded));
        let status = guard(|| Err(e.into()));
        assert_eq!(status, UssrtStatus::DriveError);
        assert_eq!(last().0.drive_error, 2);
    }

    #[test]
    fn null_pointers_and_bad_text_are_argument_errors() {
        assert!(matches!(
            arg::<u8>(core::ptr::null(), "bus"),
            Err(Failure::Argument(m)) if m == "bus is NULL"
        ));
        let bad = [0xFFu8, 0];
        assert!(matches!(
            text(bad.as_ptr().cast(), "name"),
            Err(Failure::Argument(m)) if m == "name is not UTF-8"
        ));
        // SAFETY: testing the NULL check itself.
        assert_eq!(
            unsafe { ussrt_last_error_info(core::ptr::null_mut()) },
            UssrtStatus::InvalidArgument
        );
    }
}
