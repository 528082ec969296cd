//! The PROFIdrive data types of parameters, with their type codes: the value of descriptive
//! element 1 (AK 4, USS.md section 6). The simulator describes its parameters with them, the
//! catalogue lists them, and a client asks a drive for them.

use core::fmt;

/// A parameter's PROFIdrive data type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataType {
    I16,
    I32,
    U16,
    U32,
    /// IEEE-754 single precision in a double word.
    Float,
}

impl DataType {
    /// Every type, in code order.
    pub const ALL: [Self; 5] = [Self::I16, Self::I32, Self::U16, Self::U32, Self::Float];

    /// The PROFIdrive type code.
    pub const fn code(self) -> u16 {
        match self {
            Self::I16 => 3,
            Self::I32 => 4,
            Self::U16 => 6,
            Self::U32 => 7,
            Self::Float => 8,
        }
    }

    /// The type of a PROFIdrive type code (descriptive element 1), if it is one of these.
    pub const fn from_code(code: u16) -> Option<Self> {
        match code {
            3 => Some(Self::I16),
            4 => Some(Self::I32),
            6 => Some(Self::U16),
            7 => Some(Self::U32),
            8 => Some(Self::Float),
            _ => None,
        }
    }

    /// The type a parameter list (the catalogue's TOML) names `name`: `I16`, `I32`, `U16`,
    /// `U32`, `Float`.
    pub fn named(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Whether values of this type travel as a double word (AK 3/8/11/13, replies 2/5).
    pub const fn is_dword(self) -> bool {
        matches!(self, Self::I32 | Self::U32 | Self::Float)
    }

    /// The name a parameter list (the catalogue's TOML) writes: `I16`, `I32`, `U16`, `U32`,
    /// `Float`.
    pub const fn name(self) -> &'static str {
        match self {
            Self::I16 => "I16",
            Self::I32 => "I32",
            Self::U16 => "U16",
            Self::U32 => "U32",
            Self::Float => "Float",
        }
    }
}

impl fmt::Display for DataType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Float => "float",
            other => other.name(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_type_code_reads_back_and_only_those() {
        for t in DataType::ALL {
            assert_eq!(DataType::from_code(t.code()), Some(t));
        }
        assert_eq!((0..=20).filter_map(DataType::from_code).count(), 5);
        assert!(DataType::Float.is_dword() && !DataType::I16.is_dword());
    }
}
