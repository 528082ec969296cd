//! Serde for the validated protocol types (the `serde` feature), so a configuration reads them
//! checked: a value out of range is an error in the type's own words, e.g. "is out of range:
//! USS addresses are 0..=31" (the reader names the key and value). Numbers are read as any
//! integer and range checked here, so a too large value gets the same message as a slightly too
//! large one; a value of another type is "not an integer: USS addresses are 0..=31".

use crate::{Address, Baud, DataType, PkwMode, PzdCount};
use core::fmt;
use serde::de::Error as _;
use serde::de::Visitor;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// An integer of the file, whatever its width; `allowed` says what is (for a wrong type too):
/// "expected an integer: ...". For other range-checked integers read the same way.
pub fn integer<'de, D: Deserializer<'de>>(d: D, allowed: &'static str) -> Result<i64, D::Error> {
    struct Integer(&'static str);
    impl Visitor<'_> for Integer {
        type Value = i64;
        fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            write!(f, "an integer: {}", self.0)
        }
        fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<i64, E> {
            Ok(v)
        }
        fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<i64, E> {
            i64::try_from(v).map_err(|_| E::custom(OutOfRange(self.0)))
        }
    }
    d.deserialize_any(Integer(allowed))
}

/// A value outside what `.0` allows; the caller names the value.
struct OutOfRange<'a>(&'a str);

impl fmt::Display for OutOfRange<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "is out of range: {}", self.0)
    }
}

const ADDRESSES: &str = "USS addresses are 0..=31";
const BAUDS: &str = "baud rates are 300..=12000000 (USS.md section 2 names 300 to 187500)";
const PZD_WORDS: &str = "PZD words (P2012) are 0..=16";
const PKW_LENGTHS: &str = "the PKW length (P2013) is 0, 3, 4 or 127 (variable)";

/// A data type by the name a parameter list writes (`Float`, `U16`, ...).
impl<'de> Deserialize<'de> for DataType {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Name;
        impl Visitor<'_> for Name {
            type Value = DataType;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a data type: I16, I32, U16, U32 or Float")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<DataType, E> {
                DataType::named(v)
                    .ok_or_else(|| E::unknown_variant(v, &["I16", "I32", "U16", "U32", "Float"]))
            }
        }
        d.deserialize_str(Name)
    }
}

impl<'de> Deserialize<'de> for Address {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let n = integer(d, ADDRESSES)?;
        u8::try_from(n)
            .ok()
            .and_then(|a| Address::new(a).ok())
            .ok_or_else(|| D::Error::custom(OutOfRange(ADDRESSES)))
    }
}

impl Serialize for Address {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u8(self.get())
    }
}

impl<'de> Deserialize<'de> for Baud {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let n = integer(d, BAUDS)?;
        u32::try_from(n)
            .ok()
            .and_then(|b| Baud::new(b).ok())
            .ok_or_else(|| D::Error::custom(OutOfRange(BAUDS)))
    }
}

impl Serialize for Baud {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u32(self.get())
    }
}

impl<'de> Deserialize<'de> for PzdCount {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let n = integer(d, PZD_WORDS)?;
        usize::try_from(n)
            .ok()
            .and_then(|w| PzdCount::new(w).ok())
            .ok_or_else(|| D::Error::custom(OutOfRange(PZD_WORDS)))
    }
}

impl Serialize for PzdCount {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u8(self.get() as u8)
    }
}

/// As P2013: 0, 3, 4 or 127.
impl<'de> Deserialize<'de> for PkwMode {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let n = integer(d, PKW_LENGTHS)?;
        u16::try_from(n)
            .ok()
            .and_then(PkwMode::from_p2013)
            .ok_or_else(|| D::Error::custom(format_args!("is not allowed: {PKW_LENGTHS}")))
    }
}

impl Serialize for PkwMode {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u16(self.p2013())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, Deserialize, Serialize)]
    struct Drive {
        address: Address,
        baud: Baud,
        pkw: PkwMode,
        pzd: PzdCount,
    }

    fn read(text: &str) -> Result<Drive, String> {
        toml::from_str(text).map_err(|e| e.message().to_owned())
    }

    #[test]
    fn valid_values_round_trip_and_bad_ones_say_what_is_allowed() {
        let text = "address = 3\nbaud = 19200\npkw = 127\npzd = 4\n";
        let drive = read(text).unwrap();
        assert_eq!(drive.pkw, PkwMode::Variable);
        assert_eq!(toml::to_string(&drive).unwrap(), text);
        let with = |key: &str, value: &str| {
            read(&text.replace(&format!("{key} = "), &format!("{key} = {value} #")))
        };
        assert_eq!(
            with("address", "40").unwrap_err(),
            "is out of range: USS addresses are 0..=31"
        );
        assert_eq!(
            with("address", "300").unwrap_err(),
            "is out of range: USS addresses are 0..=31"
        );
        assert!(
            with("address", "\"3\"")
                .unwrap_err()
                .ends_with("expected an integer: USS addresses are 0..=31")
        );
        assert!(with("baud", "100").unwrap_err().contains("300..=12000000"));
        assert_eq!(
            with("pkw", "5").unwrap_err(),
            "is not allowed: the PKW length (P2013) is 0, 3, 4 or 127 (variable)"
        );
        assert_eq!(
            with("pzd", "17").unwrap_err(),
            "is out of range: PZD words (P2012) are 0..=16"
        );
    }
}
