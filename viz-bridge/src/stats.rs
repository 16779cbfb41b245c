//! Counters shared between the shared-memory side and the DDS side of the bridge, turned into
//! `/diagnostics` once per second.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use msgs::haptic_to_monitor::HapticStats;
use msgs::ros_mapping::Topic;
use msgs::timing::LatencyHistogram;

/// Counts of one outbound stream.
#[derive(Debug, Default)]
pub struct StreamCounters {
    /// Handed to the DDS side.
    pub enqueued: AtomicU64,
    /// Written to DDS.
    pub published: AtomicU64,
    /// Dropped because the queue to the DDS side was full (DDS stalled).
    pub dropped_queue: AtomicU64,
    /// Dropped because the DDS writer refused (send window full, I/O error).
    pub dropped_dds: AtomicU64,
}

/// Everything the bridge counts.
#[derive(Debug, Default)]
pub struct BridgeStats {
    /// Per session topic, indexed by [`Topic`] (`/diagnostics` is written, not streamed).
    pub out: [StreamCounters; Topic::COUNT],
    pub contact_frames: AtomicU64,
    pub device_states: AtomicU64,
    pub surfaces: AtomicU64,
    pub skipped_triangles: AtomicU64,
    pub targets_forwarded: AtomicU64,
    pub grades_forwarded: AtomicU64,
    pub inbound_rejected: AtomicU64,
    /// Target poses refused by the gate, per [`crate::target_gate::Refusal`] (in its order).
    pub targets_refused: [AtomicU64; 5],
    pub ipc_errors: AtomicU64,
    /// Last physics step duration, ns.
    pub physics_step_ns: AtomicU64,
    /// Shared-memory transport latency (receipt − publish_ns) in the current window.
    pub ipc_latency_ns: Mutex<LatencyWindow>,
    /// Newest haptic loop statistics.
    pub haptic: Mutex<Option<HapticStats>>,
}

impl BridgeStats {
    pub fn stream(&self, topic: Topic) -> &StreamCounters {
        &self.out[topic as usize]
    }

    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    pub fn get(counter: &AtomicU64) -> u64 {
        counter.load(Ordering::Relaxed)
    }

    /// Records one transport latency sample (no allocation).
    pub fn record_ipc_latency(&self, ns: u64) {
        if let Ok(mut w) = self.ipc_latency_ns.lock() {
            w.record(ns);
        }
    }

    /// The run's totals as one JSON object (the bridge prints it as `BRIDGED {json}` when it
    /// stops, as the recorder prints `RECORDED`): the samples read from shared memory and, per
    /// streamed topic, what was handed to DDS, published and dropped. `/diagnostics` shows the
    /// same counters live, but only to a DDS reader; the line lets a session's log alone show
    /// whether the bridge kept up with the 1 kHz device stream.
    pub fn totals_json(&self, seconds: f64) -> serde_json::Value {
        let mut topics = serde_json::Map::new();
        let mut dropped = 0;
        for &topic in Topic::STREAMED {
            let c = self.stream(topic);
            let published = Self::get(&c.published);
            let (queue, dds) = (Self::get(&c.dropped_queue), Self::get(&c.dropped_dds));
            dropped += queue + dds;
            topics.insert(
                topic.relative().trim_start_matches('/').to_string(),
                serde_json::json!({
                    "enqueued": Self::get(&c.enqueued),
                    "published": published,
                    "dropped_queue": queue,
                    "dropped_dds": dds,
                    "published_hz": if seconds > 0.0 { published as f64 / seconds } else { 0.0 },
                }),
            );
        }
        serde_json::json!({
            "seconds": seconds,
            "contact_frames": Self::get(&self.contact_frames),
            "device_states": Self::get(&self.device_states),
            "surfaces": Self::get(&self.surfaces),
            "ipc_errors": Self::get(&self.ipc_errors),
            "dropped": dropped,
            "topics": topics,
        })
    }
}

/// Longest latency a diagnostics window resolves, ns (1 s; longer ones count as 1 s).
const LATENCY_WINDOW_MAX_NS: u64 = 1_000_000_000;

/// The latencies of one diagnostics window: a fixed-range [`LatencyHistogram`], so recording
/// never allocates and a stalled reporter cannot grow it.
#[derive(Debug, Clone)]
pub struct LatencyWindow(LatencyHistogram);

impl Default for LatencyWindow {
    fn default() -> Self {
        LatencyWindow(LatencyHistogram::new(LATENCY_WINDOW_MAX_NS))
    }
}

impl LatencyWindow {
    pub fn record(&mut self, ns: u64) {
        self.0.record(ns);
    }

    /// p50 and p99 of the window, µs (0 when empty); then starts a new window.
    pub fn take_p50_p99_us(&mut self) -> (f64, f64) {
        let r = (self.0.quantile_us(0.5), self.0.quantile_us(0.99));
        self.0.clear();
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn totals_count_reads_publications_and_drops_per_topic() {
        let s = BridgeStats::default();
        BridgeStats::add(&s.device_states, 2000);
        let c = s.stream(Topic::DeviceWrench);
        BridgeStats::add(&c.enqueued, 2000);
        BridgeStats::add(&c.published, 1990);
        BridgeStats::add(&c.dropped_queue, 7);
        BridgeStats::add(&s.stream(Topic::Tf).dropped_dds, 3);
        let t = s.totals_json(2.0);
        assert_eq!(t["device_states"], 2000);
        assert_eq!(t["dropped"], 10);
        let w = &t["topics"]["device/wrench"];
        assert_eq!(w["published"], 1990);
        assert_eq!(w["dropped_queue"], 7);
        assert_eq!(w["published_hz"], 995.0);
        assert_eq!(t["topics"]["tf"]["dropped_dds"], 3);
        assert!(t["topics"].get("diagnostics").is_none(), "{t}");
    }

    #[test]
    fn a_window_reports_its_percentiles_and_restarts() {
        let mut w = LatencyWindow::default();
        for v in (1..=100u64).rev() {
            w.record(v * 1_000);
        }
        let (p50, p99) = w.take_p50_p99_us();
        assert!((p50 - 50.0).abs() < 0.05, "{p50}");
        assert!((p99 - 99.0).abs() < 0.1, "{p99}");
        assert_eq!(w.take_p50_p99_us(), (0.0, 0.0));
    }
}
