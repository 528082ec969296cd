//! Code tables: a byte with a fixed meaning, as the contract carries it and the rules speak it.

/// A byte held a value its code table does not define.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, thiserror::Error)]
#[error("{code} is not a valid {table} code")]
pub struct UnknownCode {
    /// The table's Rust name, e.g. `TaskCode`.
    pub table: &'static str,
    pub code: u8,
}

/// Defines a `#[repr(u8)]` code table with `code()`, `name()`, `ALL` and `TryFrom<u8>`. Used by
/// this crate and by the contract (`uss-shm-types`) for its own tables.
#[macro_export]
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
            type Error = $crate::UnknownCode;

            fn try_from(code: u8) -> Result<Self, Self::Error> {
                match code {
                    $($code => Ok(Self::$variant),)+
                    _ => Err($crate::UnknownCode { table: stringify!($name), code }),
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
