//! Benchmarks of uss-rt live in `benches/benches/`; each prints ratios measured in one run
//! (see `docs/ARCHITECTURE.md`, "Measuring"). Run them with `cargo bench -p uss-benches`.
//! This library holds what they share.

use hdrhistogram::Histogram;

/// `p50 / p99 / p99.9 / max` of a nanosecond histogram, in microseconds.
pub fn percentiles_us(h: &Histogram<u64>) -> String {
    let us = |v: u64| v as f64 / 1000.0;
    format!(
        "p50 {:8.1} us  p99 {:8.1} us  p99.9 {:8.1} us  max {:8.1} us  (n = {})",
        us(h.value_at_quantile(0.5)),
        us(h.value_at_quantile(0.99)),
        us(h.value_at_quantile(0.999)),
        us(h.max()),
        h.len()
    )
}

/// The parts of a benchmark to run: `cargo bench` passes harness flags such as `--bench`; any
/// other argument names a part, and no name means every part (`cargo bench -p uss-benches -- scale`).
#[derive(Debug)]
pub struct Parts(Vec<String>);

impl Parts {
    pub fn from_args() -> Self {
        Self(
            std::env::args()
                .skip(1)
                .filter(|a| !a.starts_with("--"))
                .collect(),
        )
    }

    pub fn wanted(&self, name: &str) -> bool {
        self.0.is_empty() || self.0.iter().any(|o| o == name)
    }
}
