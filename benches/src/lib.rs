//! Benchmarks of uss-rt live in `benches/benches/`; each prints ratios measured in one run
//! (see `shared/ARCHITECTURE.md`, "Measuring").
