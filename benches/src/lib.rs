//! Benchmarks of uss-rt live in `benches/benches/`; each prints ratios measured in one run
//! (see `shared/ARCHITECTURE.md`, "Measuring"). Run them with `cargo bench -p uss-benches`.
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
