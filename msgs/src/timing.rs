//! The one latency histogram of arthrosim: every timing statistic the nodes publish and every
//! benchmark percentile comes from [`LatencyHistogram`], so p50s and p99s are comparable.
//!
//! It wraps `hdrhistogram` (3 significant digits: a recorded value is resolved to 0.1%)
//! with its range allocated up front, so [`LatencyHistogram::record`] never allocates (the
//! haptic tick records into it). Values above the range saturate at its top; the exact
//! maximum and the exact mean are kept beside it.
//!
//! Percentile definition: the smallest recorded value such that a fraction `q` of the samples
//! are at or below it (rank ⌈q·n⌉, at least 1), reported at the upper edge of its 0.1%
//! bucket and never above the exact maximum.

use hdrhistogram::Histogram;

/// Significant decimal digits kept (relative resolution 10⁻³).
const SIGNIFICANT_DIGITS: u8 = 3;

/// A fixed-range histogram of durations in nanoseconds (see the module documentation).
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    hist: Histogram<u64>,
    sum_ns: u128,
    max_ns: u64,
}

impl LatencyHistogram {
    /// A histogram resolving durations up to `max_ns` (at least 2 ns); larger values are
    /// counted at `max_ns`.
    pub fn new(max_ns: u64) -> LatencyHistogram {
        let hist = Histogram::new_with_bounds(1, max_ns.max(2), SIGNIFICANT_DIGITS)
            .expect("1 ≤ low, high ≥ 2·low and 3 significant digits are valid bounds");
        LatencyHistogram {
            hist,
            sum_ns: 0,
            max_ns: 0,
        }
    }

    /// Records one duration; does not allocate.
    pub fn record(&mut self, value_ns: u64) {
        self.hist.saturating_record(value_ns);
        self.sum_ns += value_ns as u128;
        self.max_ns = self.max_ns.max(value_ns);
    }

    /// Records a duration given in seconds (negative or non-finite values count as 0).
    pub fn record_s(&mut self, value_s: f64) {
        let ns = if value_s.is_finite() && value_s > 0.0 {
            (value_s * 1e9).round() as u64
        } else {
            0
        };
        self.record(ns);
    }

    pub fn count(&self) -> u64 {
        self.hist.len()
    }

    /// The exact largest duration recorded, ns (0 when empty).
    pub fn max_ns(&self) -> u64 {
        self.max_ns
    }

    /// The exact mean, ns (0 when empty).
    pub fn mean_ns(&self) -> f64 {
        match self.count() {
            0 => 0.0,
            n => self.sum_ns as f64 / n as f64,
        }
    }

    /// The value at or below which a fraction `q` (0..=1) of the samples lie, ns (see the
    /// module documentation); 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        if self.count() == 0 {
            return 0;
        }
        self.hist
            .value_at_quantile(q.clamp(0.0, 1.0))
            .min(self.max_ns)
    }

    pub fn quantile_us(&self, q: f64) -> f64 {
        self.quantile_ns(q) as f64 / 1e3
    }

    pub fn clear(&mut self) {
        self.hist.reset();
        self.sum_ns = 0;
        self.max_ns = 0;
    }

    /// Adds another histogram (of the same or a smaller range); does not allocate.
    pub fn merge(&mut self, other: &LatencyHistogram) {
        if self.hist.add(&other.hist).is_err() {
            // A wider source: fold its counts in at their (saturated) values.
            for v in other.hist.iter_recorded() {
                self.hist
                    .saturating_record_n(v.value_iterated_to(), v.count_at_value());
            }
        }
        self.sum_ns += other.sum_ns;
        self.max_ns = self.max_ns.max(other.max_ns);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_use_the_nearest_rank_and_stay_below_the_maximum() {
        let mut h = LatencyHistogram::new(1_000_000);
        assert_eq!(h.quantile_ns(0.99), 0);
        for v in 1..=100u64 {
            h.record(v * 1_000);
        }
        assert_eq!(h.count(), 100);
        // Rank ⌈0.5·100⌉ = 50 and ⌈0.99·100⌉ = 99, within the 0.1% resolution.
        let p50 = h.quantile_ns(0.5) as f64;
        let p99 = h.quantile_ns(0.99) as f64;
        assert!((p50 - 50_000.0).abs() <= 50.0, "{p50}");
        assert!((p99 - 99_000.0).abs() <= 99.0, "{p99}");
        assert_eq!(h.quantile_ns(1.0), 100_000);
        assert_eq!(h.max_ns(), 100_000);
        assert!((h.mean_ns() - 50_500.0).abs() < 1e-9);
        // Saturation keeps the count and the exact maximum.
        h.record(5_000_000);
        assert_eq!(h.count(), 101);
        assert_eq!(h.max_ns(), 5_000_000);
        assert!(h.quantile_ns(1.0) >= 1_000_000);
        let mut g = LatencyHistogram::new(1_000_000);
        g.merge(&h);
        assert_eq!(g.count(), 101);
        assert_eq!(g.max_ns(), 5_000_000);
        g.clear();
        assert_eq!((g.count(), g.max_ns(), g.quantile_ns(0.5)), (0, 0, 0));
    }
}
