//! Cross-crate and multi-process integration tests live in `tests/tests/`; this library holds
//! what they share.
