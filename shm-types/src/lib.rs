//! The shared-memory contract between `ussd` and client processes. Its types arrive with the
//! iceoryx2 work (see `shared/ARCHITECTURE.md`, "Data flow"); the crate exists so the workspace has
//! its final shape.
