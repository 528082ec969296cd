//! Parameters as the drive manuals write them (USS.md section 6): `r0021` (read-only,
//! monitoring), `P1082` (settable; `p1082` on G120/S110), a bare `1082`, and an array element as
//! `P0947[3]` or `r0947.3`. The number is the PNU, the index the subindex.

use crate::pkw::{Pnu, Subindex};
use core::fmt;
use core::str::FromStr;

/// How a parameter was prefixed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Prefix {
    /// `P`: a settable parameter (MICROMASTER 4, G110).
    P,
    /// `p`: a settable parameter (G120, S110).
    LowerP,
    /// `r`: a read-only (monitoring) parameter.
    R,
    /// No letter.
    None,
}

/// A parameter reference: PNU, optional array index, and the prefix it was written with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct ParamRef {
    pub pnu: Pnu,
    pub index: Option<Subindex>,
    pub prefix: Prefix,
}

/// Text that is not a parameter reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum NotationError {
    #[error("write a parameter as P1082, p1082, r0021 or 1082, an element as P0947[3] or r0947.3")]
    Form,
    #[error("parameter numbers are 0..=65535")]
    Number,
    #[error("array indices are 0..=254")]
    Index,
}

impl ParamRef {
    /// Parameter `pnu` without index, written `P` + 4 digits.
    pub const fn new(pnu: Pnu) -> Self {
        Self {
            pnu,
            index: None,
            prefix: Prefix::P,
        }
    }

    /// `P` + `number`, as the manuals write a settable parameter (`ParamRef::p(1082)` is
    /// P1082).
    pub const fn p(number: u16) -> Self {
        Self::new(Pnu::from_u16(number))
    }

    /// `r` + `number`, as the manuals write a monitoring parameter (`ParamRef::r(947)` is
    /// r0947).
    pub const fn r(number: u16) -> Self {
        Self {
            prefix: Prefix::R,
            ..Self::p(number)
        }
    }

    /// Parameter `number` (P), element `index` when there is one (0..=254): what a caller that
    /// holds numbers (C, Python) names.
    pub fn numbered(number: u16, index: Option<u8>) -> Result<Self, NotationError> {
        let param = Self::p(number);
        match index {
            None => Ok(param),
            Some(i) => Subindex::new(i)
                .map(|i| param.at(i))
                .map_err(|_| NotationError::Index),
        }
    }

    /// The same parameter, element `index`.
    #[must_use]
    pub const fn at(self, index: Subindex) -> Self {
        Self {
            index: Some(index),
            ..self
        }
    }
}

fn digits(s: &str) -> Option<u32> {
    if s.is_empty() || s.len() > 6 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

impl FromStr for ParamRef {
    type Err = NotationError;

    fn from_str(s: &str) -> Result<Self, NotationError> {
        let (prefix, body) = match s.as_bytes().first() {
            Some(b'P') => (Prefix::P, &s[1..]),
            Some(b'p') => (Prefix::LowerP, &s[1..]),
            Some(b'r' | b'R') => (Prefix::R, &s[1..]),
            _ => (Prefix::None, s),
        };
        let (number, index) = if let Some(open) = body.find('[') {
            let inner = body[open + 1..]
                .strip_suffix(']')
                .ok_or(NotationError::Form)?;
            (&body[..open], Some(inner))
        } else if let Some((number, index)) = body.split_once('.') {
            (number, Some(index))
        } else {
            (body, None)
        };
        let number = digits(number).ok_or(NotationError::Form)?;
        let pnu = Pnu::new(number).map_err(|_| NotationError::Number)?;
        let index = match index {
            Some(i) => {
                let i = digits(i).ok_or(NotationError::Form)?;
                let i = u8::try_from(i).map_err(|_| NotationError::Index)?;
                Some(Subindex::new(i).map_err(|_| NotationError::Index)?)
            }
            None => None,
        };
        Ok(Self { pnu, index, prefix })
    }
}

impl fmt::Display for ParamRef {
    /// The manuals' form: a letter, four digits, `[index]` (`r0947[3]`, `P1082`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let letter = match self.prefix {
            Prefix::P | Prefix::None => "P",
            Prefix::LowerP => "p",
            Prefix::R => "r",
        };
        write!(f, "{letter}{:04}", self.pnu.get())?;
        match self.index {
            Some(i) => write!(f, "[{}]", i.get()),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(s: &str) -> Result<ParamRef, NotationError> {
        s.parse()
    }

    fn pnu_index(s: &str) -> (u16, Option<u8>) {
        let p = r(s).unwrap();
        (p.pnu.get(), p.index.map(Subindex::get))
    }

    #[test]
    fn every_form_of_the_manuals_is_accepted() {
        assert_eq!(pnu_index("P1082"), (1082, None));
        assert_eq!(pnu_index("p1082"), (1082, None));
        assert_eq!(pnu_index("r0021"), (21, None));
        assert_eq!(pnu_index("1082"), (1082, None));
        assert_eq!(pnu_index("P0947[3]"), (947, Some(3)));
        assert_eq!(pnu_index("r0947.3"), (947, Some(3)));
        assert_eq!(pnu_index("P2014.1"), (2014, Some(1)));
        assert_eq!(pnu_index("65535[254]"), (65535, Some(254)));
        assert_eq!(r("p2040").unwrap().prefix, Prefix::LowerP);
        assert_eq!(r("R21").unwrap().prefix, Prefix::R);
    }

    #[test]
    fn what_is_not_a_parameter_says_why() {
        for bad in [
            "", "P", "x12", "12a", "-1", "947.", ".3", "1.2.3", "P0947[3", "P0947[]", "947[x]",
            "P 1082", "0000001",
        ] {
            assert_eq!(r(bad), Err(NotationError::Form), "{bad:?}");
        }
        assert_eq!(r("65536"), Err(NotationError::Number));
        assert_eq!(r("947.255"), Err(NotationError::Index));
        assert_eq!(r("947[300]"), Err(NotationError::Index));
    }

    #[test]
    fn it_is_written_back_in_the_manuals_form() {
        assert_eq!(r("r21").unwrap().to_string(), "r0021");
        assert_eq!(r("1082").unwrap().to_string(), "P1082");
        assert_eq!(r("p2040").unwrap().to_string(), "p2040");
        assert_eq!(r("r0947.3").unwrap().to_string(), "r0947[3]");
        let p = ParamRef::new(Pnu::from_u16(2014)).at(Subindex::new(1).unwrap());
        assert_eq!(p.to_string(), "P2014[1]");
        assert_eq!(r(&p.to_string()), Ok(p));
    }
}
