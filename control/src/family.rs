//! What kind of USS slave a drive is: the family a drive's configuration names, which says which
//! parameters exist and what its profile's roles are. The contract carries it as a byte.

use crate::code_table;

code_table! {
    /// What kind of USS slave a drive is (its `family` in ussd's configuration); the `family`
    /// byte of [`DriveInfo`]. It says which parameters exist: a client reads a `generic`
    /// slave's parameters by value alone (typed by the reply), never asking for descriptions.
    pub enum DriveFamily {
        /// MICROMASTER 4 (MM420/430/440): the built-in catalogue.
        Micromaster4 = 0 => "micromaster4",
        /// SINAMICS G110.
        G110 = 1 => "g110",
        /// SINAMICS G120 with a CU240 on RS485.
        G120 = 2 => "g120",
        /// SIMOREG DC-Master 6RA70.
        Simoreg = 3 => "simoreg",
        /// A USS slave of no known family: nothing read unasked, raw words and numbers.
        Generic = 4 => "generic",
    }
}

impl DriveFamily {
    /// The family a byte names, read as an open code: a code this build does not know (a newer
    /// ussd's family) is a slave of no known family, [`DriveFamily::Generic`], which assumes
    /// nothing of its parameters; never another family's catalogue. So adding a family changes
    /// no layout: an older reader takes the new code as generic.
    pub fn of_code(code: u8) -> Self {
        Self::try_from(code).unwrap_or(Self::Generic)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_family_code_this_build_does_not_know_is_generic() {
        for family in DriveFamily::ALL {
            assert_eq!(DriveFamily::of_code(family.code()), *family);
        }
        let unknown = DriveFamily::ALL.len() as u8;
        assert_eq!(DriveFamily::of_code(unknown), DriveFamily::Generic);
        assert_eq!(DriveFamily::of_code(u8::MAX), DriveFamily::Generic);
    }
}
