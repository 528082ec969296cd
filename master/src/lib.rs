//! The USS bus master: configuration, transports, the real-time bus engine and the IPC bridge.
//! The engine arrives with the bus-engine work (see `shared/ARCHITECTURE.md`).
