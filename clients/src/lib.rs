//! The Rust client API of uss-rt. It arrives with the iceoryx2 work (see
//! `shared/ARCHITECTURE.md`, "Data flow").
