//! Counters shared between the shared-memory side and the DDS side of the bridge, turned into
//! `/diagnostics` once per second.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use msgs::haptic_to_monitor::HapticStats;

/// Published (outbound) streams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    ProbePose = 0,
    ProbeWrench,
    DeviceWrench,
    JointStates,
    Buttons,
    Mesh,
    Contacts,
    Tf,
}

pub const OUT_STREAMS: usize = 8;

impl Stream {
    pub const ALL: [Stream; OUT_STREAMS] = [
        Stream::ProbePose,
        Stream::ProbeWrench,
        Stream::DeviceWrench,
        Stream::JointStates,
        Stream::Buttons,
        Stream::Mesh,
        Stream::Contacts,
        Stream::Tf,
    ];

    /// The session topic of this stream (`msgs::ros_mapping`, shared with the recorder).
    pub fn ros_topic(self) -> msgs::ros_mapping::Topic {
        use msgs::ros_mapping::Topic;
        match self {
            Stream::ProbePose => Topic::ProbePose,
            Stream::ProbeWrench => Topic::ProbeWrench,
            Stream::DeviceWrench => Topic::DeviceWrench,
            Stream::JointStates => Topic::JointStates,
            Stream::Buttons => Topic::Buttons,
            Stream::Mesh => Topic::Mesh,
            Stream::Contacts => Topic::Contacts,
            Stream::Tf => Topic::Tf,
        }
    }

    /// Topic relative to the namespace (`/tf` is absolute).
    pub fn topic(self) -> &'static str {
        self.ros_topic().relative()
    }
}

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
    pub out: [StreamCounters; OUT_STREAMS],
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
    /// Shared-memory transport latency (receipt − publish_ns) in the current window, ns.
    pub ipc_latency_ns: Mutex<Vec<u64>>,
    /// Newest haptic loop statistics.
    pub haptic: Mutex<Option<HapticStats>>,
}

impl BridgeStats {
    pub fn stream(&self, s: Stream) -> &StreamCounters {
        &self.out[s as usize]
    }

    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    pub fn get(counter: &AtomicU64) -> u64 {
        counter.load(Ordering::Relaxed)
    }

    /// Records one transport latency sample (bounded so a stalled reporter cannot grow it).
    pub fn record_ipc_latency(&self, ns: u64) {
        if let Ok(mut v) = self.ipc_latency_ns.lock() {
            if v.len() < 100_000 {
                v.push(ns);
            }
        }
    }
}

/// p-th percentile (0..=1) of `samples` (sorted in place); 0 when empty.
pub fn percentile(samples: &mut [u64], p: f64) -> u64 {
    if samples.is_empty() {
        return 0;
    }
    samples.sort_unstable();
    let idx = ((samples.len() - 1) as f64 * p).round() as usize;
    samples[idx.min(samples.len() - 1)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_a_window() {
        let mut v: Vec<u64> = (1..=100).rev().collect();
        assert_eq!(percentile(&mut v, 0.5), 51);
        assert_eq!(percentile(&mut v, 0.99), 99);
        assert_eq!(percentile(&mut [], 0.5), 0);
    }
}
