//! Who commands a drive, and the operator's stop commands.
//!
//! A drive's output is either **live** (its controller's samples go to the drive) or
//! **latched** (it gets a stop command, the configured safe command or an operator's, until its
//! controller re-arms it the PROFIdrive way: a stop (STW1 bit 0 = 0, no jog) that names the
//! latch, `PzdOutput::latch_id` = the input image's `latch_id`, before an ON is passed again).
//! The input image and the diagnostics say which, since when, why, and what is sent. ussd keeps
//! the latch; a client cannot clear it any other way.
//!
//! Operator stop commands arrive on `uss/<bus>/<gen>/command` ([`OperatorRequest`] ->
//! [`OperatorResponse`], request-response): OFF1, OFF2 or OFF3 for one drive or every drive
//! of the bus, accepted from any process and overriding the drive's controller.

use crate::codes::{UnknownCode, code_table};
// The vocabulary is the domain's (`uss_control`); the contract carries it as bytes.
use crate::{ContractError, LAYOUT_VERSION};
#[cfg(feature = "ipc")]
use iceoryx2::prelude::ZeroCopySend;
pub use uss_control::{ControlState, LatchReason, NO_STOP_COMMAND, Rejection, StopCommand};

/// `address` of an [`OperatorRequest`] for every drive of the bus.
pub const ALL_DRIVES: u8 = u8::MAX;

code_table! {
    /// What ussd knows of the drive's own telegram monitoring (P2014 on MICROMASTER 4 / G110 /
    /// CU240S, p2040 on G120 / S110; USS.md section 5), the only protection when ussd or its
    /// line dies; the `monitoring` byte of the diagnostics.
    pub enum Monitoring {
        /// Not read yet (the drive has not been online since ussd started).
        Unknown = 0 => "not read yet",
        /// On, within the configured limit.
        On = 1 => "on",
        /// 0: the drive keeps running on its last command when telegrams stop.
        Off = 2 => "off",
        /// On, but longer than the configured limit.
        TooLong = 3 => "longer than the limit",
        /// The read failed (drive error, no parameter channel, timeout).
        Unreadable = 4 => "cannot be read",
        /// The configuration turns the check off (`monitoring_param = ""`).
        NotChecked = 5 => "not checked",
        /// On, but shorter than the longest time between two polls of the drive on this bus
        /// (`DriveDiag::monitoring_min_ms`): the drive trips (F0072) between polls.
        TooShort = 6 => "shorter than the poll period",
    }
}

code_table! {
    /// Why ussd refused an operator request; the `error` byte of [`OperatorResponse`].
    pub enum CommandError {
        Ok = 0 => "ok",
        /// No drive with this address on this bus.
        UnknownDrive = 1 => "unknown drive",
        /// `command` is not OFF1, OFF2 or OFF3.
        BadCommand = 2 => "not a stop command",
        /// The request speaks a version before the stop socket's bytes ([`STOP_BYTES_SINCE`]).
        Version = 3 => "layout version mismatch",
        /// ussd is shutting down (every drive gets its safe command anyway).
        Shutdown = 4 => "shut down",
        /// The requesting process holds more connections to the stop socket at once than ussd
        /// serves per process: this one was refused at once (the others are served).
        TooManyConnections = 5 => "too many connections from this process",
    }
}

/// An operator's stop command for one drive or every drive of a bus, from any process.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "ipc",
    derive(ZeroCopySend),
    type_name("UssOperatorRequestV9")
)]
pub struct OperatorRequest {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// Drive address 0..=31, or [`ALL_DRIVES`].
    pub address: u8,
    /// A [`StopCommand`] code (never [`NO_STOP_COMMAND`]).
    pub command: u8,
    pub reserved: [u8; 2],
}

/// Bytes of an [`OperatorRequest`] on the stop socket.
pub const OPERATOR_REQUEST_BYTES: usize = 8;
/// The first layout version whose stop socket spoke these bytes. They are frozen since (the
/// request's 8 bytes, the answer's 12, the [`StopCommand`] codes 1..=3), so a stop is sendable
/// across versions: ussd takes the stop of an older or newer client, and answers in the
/// request's own version.
pub const STOP_BYTES_SINCE: u32 = 7;
/// Bytes of an [`OperatorResponse`] on the stop socket.
pub const OPERATOR_RESPONSE_BYTES: usize = 12;

/// The one answer to an [`OperatorRequest`].
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "ipc",
    derive(ZeroCopySend),
    type_name("UssOperatorResponseV9")
)]
pub struct OperatorResponse {
    /// [`LAYOUT_VERSION`].
    pub version: u32,
    /// A [`CommandError`] code; 0 when the command was handed to the bus thread.
    pub error: u8,
    /// The request's [`StopCommand`] code.
    pub command: u8,
    pub reserved: [u8; 2],
    /// Bit `a` set: drive `a` gets the command from its next poll on, latched.
    pub drives: u32,
}

/// The stop board ([`crate::names::stop_board`]): a stop that no queue can hold back. A
/// request the stop socket cannot take at once (its queue of connections is full: a storm of
/// connections of other processes) is added here too: the counter of its drive (or of
/// [`ALL_DRIVES`], the last row) and command grows by one (an atomic add in the mapped file),
/// and ussd's stop thread, which reads the board at least every millisecond, stops the drive as
/// for the request; the request on the socket follows as usual and names its process. Rows
/// 0..=31 are drive addresses, row 32 is every drive; in each, OFF1, OFF2, OFF3; each counter a
/// native-endian `u32`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StopBoard;

impl StopBoard {
    /// Rows: one per address 0..=31 and one for every drive.
    pub const ROWS: usize = 33;
    /// Bytes of the file.
    pub const BYTES: usize = Self::ROWS * 3 * 4;

    /// The byte offset of the counter of `command` for `address` (or [`ALL_DRIVES`]); `None`
    /// for another address.
    pub const fn offset(address: u8, command: StopCommand) -> Option<usize> {
        let row = match address {
            ALL_DRIVES => Self::ROWS - 1,
            a if (a as usize) < Self::ROWS - 1 => a as usize,
            _ => return None,
        };
        let column = match command {
            StopCommand::Off1 => 0,
            StopCommand::Off2 => 1,
            StopCommand::Off3 => 2,
        };
        Some((row * 3 + column) * 4)
    }

    /// The request a counter at byte `offset` stands for.
    pub fn request_at(offset: usize) -> Option<OperatorRequest> {
        let word = offset / 4;
        let (row, column) = (word / 3, word % 3);
        let address = match row {
            r if r == Self::ROWS - 1 => ALL_DRIVES,
            r if r < Self::ROWS - 1 => u8::try_from(r).ok()?,
            _ => return None,
        };
        let command = [StopCommand::Off1, StopCommand::Off2, StopCommand::Off3][column];
        Some(OperatorRequest::new(address, command))
    }
}

impl OperatorRequest {
    /// A request for `command` on drive `address` (or [`ALL_DRIVES`]).
    pub const fn new(address: u8, command: StopCommand) -> Self {
        Self {
            version: LAYOUT_VERSION,
            address,
            command: command.code(),
            reserved: [0; 2],
        }
    }

    /// Its bytes on the stop socket ([`crate::names::stop_socket`]): version (little-endian),
    /// address, command, two reserved bytes.
    pub fn to_bytes(&self) -> [u8; OPERATOR_REQUEST_BYTES] {
        let v = self.version.to_le_bytes();
        [v[0], v[1], v[2], v[3], self.address, self.command, 0, 0]
    }

    /// A request read from the stop socket; `None` unless exactly
    /// [`OPERATOR_REQUEST_BYTES`] arrived ([`OperatorRequest::validate`] judges the rest).
    pub fn from_bytes(b: &[u8]) -> Option<Self> {
        let &[v0, v1, v2, v3, address, command, r0, r1] = b else {
            return None;
        };
        Some(Self {
            version: u32::from_le_bytes([v0, v1, v2, v3]),
            address,
            command,
            reserved: [r0, r1],
        })
    }

    /// Checks version (any since [`STOP_BYTES_SINCE`]: a stop is a stop) and command; returns
    /// the command.
    pub fn validate(&self) -> Result<StopCommand, CommandError> {
        if self.version < STOP_BYTES_SINCE {
            return Err(CommandError::Version);
        }
        StopCommand::try_from(self.command).map_err(|_| CommandError::BadCommand)
    }
}

impl OperatorResponse {
    /// The answer for the drives in `drives` (bit = address).
    pub const fn done(command: StopCommand, drives: u32) -> Self {
        Self {
            version: LAYOUT_VERSION,
            error: CommandError::Ok.code(),
            command: command.code(),
            reserved: [0; 2],
            drives,
        }
    }

    /// A refusal: no drive got the command.
    pub const fn refused(command: u8, error: CommandError) -> Self {
        Self {
            version: LAYOUT_VERSION,
            error: error.code(),
            command,
            reserved: [0; 2],
            drives: 0,
        }
    }

    /// This answer in `version`, the request's own (since [`STOP_BYTES_SINCE`] the bytes are
    /// the same), so a client of another version reads it as its own.
    #[must_use]
    pub const fn in_version(self, version: u32) -> Self {
        Self { version, ..self }
    }

    /// Whether this answer speaks the stop socket's bytes (any version since
    /// [`STOP_BYTES_SINCE`]).
    pub fn check_version(&self) -> Result<(), ContractError> {
        if self.version >= STOP_BYTES_SINCE {
            Ok(())
        } else {
            Err(ContractError::Version {
                expected: LAYOUT_VERSION,
                found: self.version,
            })
        }
    }

    pub fn error(&self) -> Result<CommandError, UnknownCode> {
        CommandError::try_from(self.error)
    }

    /// Its bytes on the stop socket: version and drives little-endian.
    pub fn to_bytes(&self) -> [u8; OPERATOR_RESPONSE_BYTES] {
        let v = self.version.to_le_bytes();
        let d = self.drives.to_le_bytes();
        [
            v[0],
            v[1],
            v[2],
            v[3],
            self.error,
            self.command,
            0,
            0,
            d[0],
            d[1],
            d[2],
            d[3],
        ]
    }

    /// An answer read from the stop socket; `None` unless exactly
    /// [`OPERATOR_RESPONSE_BYTES`] arrived.
    pub fn from_bytes(b: &[u8]) -> Option<Self> {
        let &[v0, v1, v2, v3, error, command, r0, r1, d0, d1, d2, d3] = b else {
            return None;
        };
        Some(Self {
            version: u32::from_le_bytes([v0, v1, v2, v3]),
            error,
            command,
            reserved: [r0, r1],
            drives: u32::from_le_bytes([d0, d1, d2, d3]),
        })
    }

    /// The addresses that got the command, ascending.
    pub fn addresses(&self) -> impl Iterator<Item = crate::Address> + '_ {
        crate::Address::all().filter(|a| self.drives & (1 << a.get()) != 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stop_commands_carry_plc_control_and_grow_stronger_from_off1_to_off2() {
        for c in [StopCommand::Off1, StopCommand::Off2, StopCommand::Off3] {
            let stw1 = c.stw1();
            assert_ne!(stw1 & 0x0400, 0, "{c}: bit 10");
            assert_eq!(stw1 & 0x0001, 0, "{c}: bit 0 (ON) clear");
        }
        assert_eq!(StopCommand::of_code(NO_STOP_COMMAND), None);
        for c in [None, Some(StopCommand::Off1), Some(StopCommand::Off3)] {
            assert_eq!(StopCommand::of_code(StopCommand::code_of(c)), c);
        }
        assert!(StopCommand::Off2.strength() > StopCommand::Off3.strength());
        assert!(StopCommand::Off3.strength() > StopCommand::Off1.strength());
    }

    proptest::proptest! {
        #[test]
        fn stop_socket_bytes_read_back_and_any_other_length_is_refused(
            bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..32)
        ) {
            // Read back as written (the reserved bytes are written as zeros).
            let request = OperatorRequest::from_bytes(&bytes);
            proptest::prop_assert_eq!(request.is_some(), bytes.len() == OPERATOR_REQUEST_BYTES);
            if let Some(r) = request {
                let mut again = r.to_bytes();
                again[6..].copy_from_slice(&bytes[6..]);
                proptest::prop_assert_eq!(&again[..], &bytes[..]);
            }
            let response = OperatorResponse::from_bytes(&bytes);
            proptest::prop_assert_eq!(response.is_some(), bytes.len() == OPERATOR_RESPONSE_BYTES);
            if let Some(r) = response {
                let mut again = r.to_bytes();
                again[6..8].copy_from_slice(&bytes[6..8]);
                proptest::prop_assert_eq!(&again[..], &bytes[..]);
            }
        }
    }

    #[test]
    fn operator_requests_name_a_stop_command() {
        assert_eq!(
            OperatorRequest::new(3, StopCommand::Off2).validate(),
            Ok(StopCommand::Off2)
        );
        assert_eq!(
            OperatorRequest {
                command: NO_STOP_COMMAND,
                ..OperatorRequest::new(3, StopCommand::Off1)
            }
            .validate(),
            Err(CommandError::BadCommand)
        );
        let mut r = OperatorRequest::new(ALL_DRIVES, StopCommand::Off1);
        r.command = 9;
        assert_eq!(r.validate(), Err(CommandError::BadCommand));
        r.version = 1;
        assert_eq!(r.validate(), Err(CommandError::Version));
        // A stop of an older (or newer) client since the stop socket's bytes were frozen stops.
        for version in [STOP_BYTES_SINCE, LAYOUT_VERSION - 1, LAYOUT_VERSION + 1] {
            let r = OperatorRequest {
                version,
                ..OperatorRequest::new(3, StopCommand::Off2)
            };
            assert_eq!(r.validate(), Ok(StopCommand::Off2), "version {version}");
        }
        // Every counter of the stop board stands for its own request, and back.
        for address in (0..32).chain([ALL_DRIVES]) {
            for command in [StopCommand::Off1, StopCommand::Off2, StopCommand::Off3] {
                let at = StopBoard::offset(address, command).unwrap();
                assert!(at + 4 <= StopBoard::BYTES);
                assert_eq!(
                    StopBoard::request_at(at),
                    Some(OperatorRequest::new(address, command))
                );
            }
        }
        assert_eq!(StopBoard::offset(32, StopCommand::Off1), None);
        assert_eq!(StopBoard::request_at(StopBoard::BYTES), None);
        let answer = OperatorResponse::done(StopCommand::Off2, 1 << 3).in_version(8);
        assert_eq!(answer.version, 8);
        assert!(answer.check_version().is_ok());
        assert!(
            answer
                .in_version(STOP_BYTES_SINCE - 1)
                .check_version()
                .is_err()
        );
    }

    #[test]
    fn operator_response_lists_the_drives_it_reached() {
        let r = OperatorResponse::done(StopCommand::Off3, (1 << 1) | (1 << 31));
        let reached: Vec<u8> = r.addresses().map(crate::Address::get).collect();
        assert_eq!(reached, [1, 31]);
        assert_eq!(r.error(), Ok(CommandError::Ok));
        let r = OperatorResponse::refused(2, CommandError::UnknownDrive);
        assert_eq!((r.drives, r.error()), (0, Ok(CommandError::UnknownDrive)));
    }
}
