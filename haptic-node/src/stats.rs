//! Fixed-size histograms of the servo loop (no allocation after construction) and the
//! statistics message built from them.

/// A linear histogram of durations in nanoseconds with a fixed bin width and an overflow
/// bin; tracks the exact maximum. Percentiles are bin upper edges (resolution = bin width).
#[derive(Debug, Clone)]
pub struct Histogram {
    bins: Box<[u64]>,
    bin_ns: u64,
    overflow: u64,
    count: u64,
    sum_ns: u128,
    max_ns: u64,
}

impl Histogram {
    /// `bins` bins of `bin_ns` each; values beyond `bins × bin_ns` land in the overflow bin.
    pub fn new(bins: usize, bin_ns: u64) -> Histogram {
        Histogram {
            bins: vec![0; bins.max(1)].into_boxed_slice(),
            bin_ns: bin_ns.max(1),
            overflow: 0,
            count: 0,
            sum_ns: 0,
            max_ns: 0,
        }
    }

    pub fn record(&mut self, value_ns: u64) {
        let i = (value_ns / self.bin_ns) as usize;
        match self.bins.get_mut(i) {
            Some(b) => *b += 1,
            None => self.overflow += 1,
        }
        self.count += 1;
        self.sum_ns += value_ns as u128;
        self.max_ns = self.max_ns.max(value_ns);
    }

    pub fn count(&self) -> u64 {
        self.count
    }

    pub fn max_ns(&self) -> u64 {
        self.max_ns
    }

    pub fn mean_ns(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum_ns as f64 / self.count as f64
        }
    }

    /// The value below which fraction `q` of the samples lie (upper bin edge; the maximum
    /// when it falls in the overflow bin). 0 when empty.
    pub fn quantile_ns(&self, q: f64) -> u64 {
        if self.count == 0 {
            return 0;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.count as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (i, b) in self.bins.iter().enumerate() {
            seen += b;
            if seen >= rank {
                return ((i as u64 + 1) * self.bin_ns).min(self.max_ns);
            }
        }
        self.max_ns
    }

    pub fn quantile_us(&self, q: f64) -> f64 {
        self.quantile_ns(q) as f64 / 1e3
    }

    pub fn clear(&mut self) {
        self.bins.fill(0);
        self.overflow = 0;
        self.count = 0;
        self.sum_ns = 0;
        self.max_ns = 0;
    }

    /// Adds another histogram of the same shape.
    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.bins.iter_mut().zip(other.bins.iter()) {
            *a += b;
        }
        self.overflow += other.overflow;
        self.count += other.count;
        self.sum_ns += other.sum_ns;
        self.max_ns = self.max_ns.max(other.max_ns);
    }
}

/// The histograms the servo loop keeps.
#[derive(Debug, Clone)]
pub struct LoopStats {
    /// |actual wake-up − deadline|, 0.1 µs bins up to 2 ms.
    pub period_error: Histogram,
    /// LCP solve time, 0.1 µs bins up to 1 ms.
    pub lcp: Histogram,
    /// Age of the frame a tick used, 10 µs bins up to 200 ms.
    pub frame_age: Histogram,
    /// Physics publish → receivable here (transport probe thread), 0.1 µs bins up to 5 ms.
    pub transport: Histogram,
    pub lcp_iterations_sum: u64,
    pub lcp_solves: u64,
    pub ticks: u64,
    pub overruns: u64,
    pub fault_ticks: u64,
    pub faults_seen: u32,
    /// Ticks whose frame had at least one contact, and the largest force rendered.
    pub contact_ticks: u64,
    pub max_rendered_n: f64,
}

impl Default for LoopStats {
    fn default() -> Self {
        Self::new()
    }
}

impl LoopStats {
    pub fn new() -> LoopStats {
        LoopStats {
            period_error: Histogram::new(20_000, 100),
            lcp: Histogram::new(10_000, 100),
            frame_age: Histogram::new(20_000, 10_000),
            transport: Histogram::new(50_000, 100),
            lcp_iterations_sum: 0,
            lcp_solves: 0,
            ticks: 0,
            overruns: 0,
            fault_ticks: 0,
            faults_seen: 0,
            contact_ticks: 0,
            max_rendered_n: 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_of_a_known_distribution() {
        let mut h = Histogram::new(100, 1_000);
        for v in 0..100u64 {
            h.record(v * 1_000 + 500);
        }
        assert_eq!(h.count(), 100);
        assert_eq!(h.quantile_ns(0.5), 50_000);
        assert_eq!(h.quantile_ns(0.99), 99_000);
        assert_eq!(h.max_ns(), 99_500);
        h.record(10_000_000);
        assert_eq!(
            h.quantile_ns(1.0),
            10_000_000,
            "overflow reports the maximum"
        );
        h.clear();
        assert_eq!(h.quantile_ns(0.5), 0);
    }
}
