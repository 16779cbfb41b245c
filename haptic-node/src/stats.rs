//! The servo loop's histograms ([`LatencyHistogram`], the workspace's one latency histogram:
//! no allocation after construction) and the statistics message built from them.

pub use msgs::timing::LatencyHistogram;

/// Range of the transport-latency histograms, ns (5 ms).
pub const TRANSPORT_MAX_NS: u64 = 5_000_000;

/// The histograms the servo loop keeps.
#[derive(Debug, Clone)]
pub struct LoopStats {
    /// |actual wake-up − deadline|, up to 2 ms.
    pub period_error: LatencyHistogram,
    /// LCP solve time, up to 1 ms.
    pub lcp: LatencyHistogram,
    /// Age of the frame a tick used, up to 200 ms.
    pub frame_age: LatencyHistogram,
    /// Physics publish → receivable here (transport probe thread), up to 5 ms.
    pub transport: LatencyHistogram,
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
            period_error: LatencyHistogram::new(2_000_000),
            lcp: LatencyHistogram::new(1_000_000),
            frame_age: LatencyHistogram::new(200_000_000),
            transport: LatencyHistogram::new(TRANSPORT_MAX_NS),
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
