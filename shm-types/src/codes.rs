//! Code tables (`u8` fields with a fixed meaning: their shape is `uss_control`'s) and the errors
//! of checking a payload.

use thiserror::Error;
pub use uss_control::UnknownCode;

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

pub(crate) use uss_control::code_table;
