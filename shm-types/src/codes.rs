//! Code tables (`u8` fields with a fixed meaning) and the errors of checking a payload.

use thiserror::Error;

/// A `u8` field held a value its code table does not define.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Error)]
#[error("{code} is not a valid {table} code")]
pub struct UnknownCode {
    /// The table's Rust name, e.g. `TaskCode`.
    pub table: &'static str,
    pub code: u8,
}

/// A payload that breaks the contract.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Error)]
pub enum ContractError {
    #[error(
        "layout version {found}, this side speaks {expected}: rebuild the client against the same uss-shm-types"
    )]
    Version { expected: u32, found: u32 },
    #[error("{0} PZD words: a drive exchanges at most 16 (USS.md section 3)")]
    PzdWords(usize),
    #[error(transparent)]
    Code(#[from] UnknownCode),
}

/// The C and Python name of a Rust name: `PzdOutput` -> `PZD_OUTPUT`, `Off1` -> `OFF1`,
/// `DwordOverThreeWords` -> `DWORD_OVER_THREE_WORDS` (the C header's constants and the Python
/// enums' members are spelt so).
pub fn screaming_snake(camel: &str) -> String {
    let mut out = String::new();
    for (i, c) in camel.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_uppercase());
    }
    out
}

/// Defines a `#[repr(u8)]` code table with `code()`, `name()`, `ALL` and `TryFrom<u8>`.
macro_rules! code_table {
    (
        $(#[$meta:meta])*
        pub enum $name:ident {
            $( $(#[$vmeta:meta])* $variant:ident = $code:literal => $text:literal, )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u8)]
        pub enum $name {
            $( $(#[$vmeta])* $variant = $code, )+
        }

        impl $name {
            /// Every code of the table, in code order.
            pub const ALL: &[Self] = &[$(Self::$variant,)+];

            /// The byte carried in the payload.
            pub const fn code(self) -> u8 {
                self as u8
            }

            /// A short human-readable name.
            pub const fn name(self) -> &'static str {
                match self {
                    $(Self::$variant => $text,)+
                }
            }
        }

        impl TryFrom<u8> for $name {
            type Error = $crate::codes::UnknownCode;

            fn try_from(code: u8) -> Result<Self, Self::Error> {
                match code {
                    $($code => Ok(Self::$variant),)+
                    _ => Err($crate::codes::UnknownCode { table: stringify!($name), code }),
                }
            }
        }

        impl From<$name> for u8 {
            fn from(value: $name) -> u8 {
                value.code()
            }
        }

        impl core::fmt::Display for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str(self.name())
            }
        }
    };
}

pub(crate) use code_table;
