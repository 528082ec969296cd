//! What the configuration's values may be, in the words its errors use: the rules
//! ([`super::rules`]) and the reporter ([`super::errors`]) both say them.

use uss_shm_types::names::{BusName, MAX_BUS_NAME_LEN};

/// What a bus name is: [`BusName`]'s rule (it becomes part of shared-memory service names).
pub const BUS_NAMES: &str = "a bus name is 1..=32 characters from A-Z, a-z, 0-9, _ and - (it \
                             becomes part of shared-memory service names)";

/// What a device is.
pub const DEVICES: &str = if cfg!(feature = "sim") {
    "device is \"sim\" (the built-in simulated bus), the path of a serial device, or \
     tcp://host:port (a serial device server's port)"
} else {
    "device is the path of a serial device, or tcp://host:port (a serial device server's \
     port)"
};

// The words of [`BUS_NAMES`] say 32.
const _: () = assert!(MAX_BUS_NAME_LEN == 32);

/// Whether `name` can name a bus ([`BusName`]).
pub fn valid_bus_name(name: &str) -> bool {
    BusName::new(name).is_ok()
}
