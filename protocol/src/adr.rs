//! Slave addresses and the ADR byte (USS.md sections 1 and 3).

use thiserror::Error;

/// A slave address, 0..=31 (USS.md section 1). Some families accept fewer (CU240S/S110: 0..=30,
/// the S7-1200 library: 1..=16); that is a configuration concern, not a wire one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Address(u8);

/// An address outside 0..=31.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
#[error("slave address {0} is out of range: USS addresses are 0..=31")]
pub struct AddressError(pub u8);

impl Address {
    /// The highest address the ADR byte can carry (5 bits).
    pub const MAX: u8 = 31;

    /// Validates an address.
    pub const fn new(address: u8) -> Result<Self, AddressError> {
        if address <= Self::MAX {
            Ok(Self(address))
        } else {
            Err(AddressError(address))
        }
    }

    /// The address as a number, 0..=31.
    pub const fn get(self) -> u8 {
        self.0
    }

    /// All 32 addresses in ascending order.
    pub fn all() -> impl Iterator<Item = Address> {
        (0..=Self::MAX).map(Address)
    }
}

impl TryFrom<u8> for Address {
    type Error = AddressError;
    fn try_from(value: u8) -> Result<Self, Self::Error> {
        Self::new(value)
    }
}

impl core::fmt::Display for Address {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.0.fmt(f)
    }
}

/// The ADR byte: address in bits 0-4, broadcast bit 5, mirror bit 6, special telegram bit 7
/// (USS.md section 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Adr {
    pub address: Address,
    /// Bit 5: every slave processes the telegram and none replies.
    pub broadcast: bool,
    /// Bit 6: the slave returns the telegram unchanged (only meaningful with `special` clear).
    pub mirror: bool,
    /// Bit 7: special telegram; slaves that do not define it reject it.
    pub special: bool,
}

impl Adr {
    const BROADCAST: u8 = 1 << 5;
    const MIRROR: u8 = 1 << 6;
    const SPECIAL: u8 = 1 << 7;

    /// A plain telegram to one slave.
    pub const fn to(address: Address) -> Self {
        Self {
            address,
            broadcast: false,
            mirror: false,
            special: false,
        }
    }

    /// A broadcast (bit 5, address bits 0): every slave that takes broadcasts processes it,
    /// none replies.
    pub const fn broadcast() -> Self {
        Self {
            address: Address(0),
            broadcast: true,
            mirror: false,
            special: false,
        }
    }

    /// The byte on the wire.
    pub const fn to_byte(self) -> u8 {
        let mut b = self.address.0;
        if self.broadcast {
            b |= Self::BROADCAST;
        }
        if self.mirror {
            b |= Self::MIRROR;
        }
        if self.special {
            b |= Self::SPECIAL;
        }
        b
    }

    /// Splits a received ADR byte; every byte value is a valid ADR.
    pub const fn from_byte(b: u8) -> Self {
        Self {
            address: Address(b & 0x1F),
            broadcast: b & Self::BROADCAST != 0,
            mirror: b & Self::MIRROR != 0,
            special: b & Self::SPECIAL != 0,
        }
    }

    /// A mirror telegram is one with bit 6 set and bit 7 clear (USS.md section 3).
    pub const fn is_mirror(self) -> bool {
        self.mirror && !self.special
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn address_range_is_0_to_31() {
        assert_eq!(Address::new(0).unwrap().get(), 0);
        assert_eq!(Address::new(31).unwrap().get(), 31);
        assert_eq!(Address::new(32), Err(AddressError(32)));
        assert_eq!(Address::all().count(), 32);
    }

    #[test]
    fn adr_bits_follow_uss_md_section_3() {
        let a = Address::new(5).unwrap();
        assert_eq!(Adr::to(a).to_byte(), 0x05);
        let b = Adr {
            broadcast: true,
            ..Adr::to(a)
        };
        assert_eq!(b.to_byte(), 0x25);
        let m = Adr {
            mirror: true,
            ..Adr::to(a)
        };
        assert_eq!(m.to_byte(), 0x45);
        assert!(Adr::from_byte(0x45).is_mirror());
        assert!(!Adr::from_byte(0xC5).is_mirror());
        assert!(Adr::from_byte(0x85).special);
    }

    #[test]
    fn every_adr_byte_round_trips() {
        for b in 0..=255u8 {
            assert_eq!(Adr::from_byte(b).to_byte(), b);
        }
    }
}
