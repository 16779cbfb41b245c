//! `[recording]`: the recorder node. Owned by recordings.
//!
//! Every session is written to `<out>/<file_name>` (MCAP, ROS 2 profile). SI units.
use serde::{Deserialize, Serialize};

/// Chunk compression of the MCAP file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChunkCompression {
    Zstd,
    None,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordingConfig {
    /// Record this session (the launcher starts the recorder node only when true).
    pub enabled: bool,
    /// File name inside the session's output directory.
    pub file_name: String,
    /// Chunk compression (`zstd` or `none`).
    pub compression: ChunkCompression,
    /// zstd level (0 = library default, 3).
    pub zstd_level: u32,
    /// A chunk is finished and written at least this often, s: a recorder killed with
    /// `kill -9` leaves a file readable up to its last flush. Must be ≤ 1 s.
    pub flush_interval_s: f64,
    /// Target uncompressed chunk size, bytes (a chunk also ends at each flush).
    pub chunk_size_bytes: u64,
    /// How often the recorder drains its shared-memory queues, s. The device-state queue
    /// holds 2048 ticks (2 s at 1 kHz), so anything well below that loses nothing.
    pub drain_period_s: f64,
    /// Rate of the viewer-only topics in the file (meniscus surface marker, contact
    /// markers), Hz (0: only the first).
    pub mesh_rate_hz: f64,
    /// Also record each physics step's contact problem (H rows, δ_free, W, λ for the active
    /// rows) in the ContactStep messages. Lossless for the haptic re-solve and the gap
    /// diagnosis, but W grows with rows² (up to 73 kB per step): off by default; force,
    /// poses and contact count are always recorded.
    pub contact_problem: bool,
    /// Also write `metadata.yaml` beside the file, making the output directory a rosbag2
    /// folder that `ros2 bag info/play` open.
    pub rosbag2_folder: bool,
}

impl Default for RecordingConfig {
    fn default() -> Self {
        RecordingConfig {
            enabled: true,
            file_name: "session.mcap".into(),
            compression: ChunkCompression::Zstd,
            zstd_level: 0,
            flush_interval_s: 0.5,
            chunk_size_bytes: 4 << 20,
            drain_period_s: 0.002,
            mesh_rate_hz: 10.0,
            contact_problem: false,
            rosbag2_folder: true,
        }
    }
}

impl RecordingConfig {
    /// Checks ranges; returns a description of the first problem.
    pub fn validate(&self) -> Result<(), String> {
        if self.file_name.is_empty() || self.file_name.contains('/') {
            return Err(format!(
                "recording.file_name {:?} must be a plain file name",
                self.file_name
            ));
        }
        if !(self.flush_interval_s > 0.0 && self.flush_interval_s <= 1.0) {
            return Err(format!(
                "recording.flush_interval_s = {} must be in (0, 1] s",
                self.flush_interval_s
            ));
        }
        if !(self.drain_period_s > 0.0 && self.drain_period_s <= 0.5) {
            return Err(format!(
                "recording.drain_period_s = {} must be in (0, 0.5] s (the device queue holds 2 s)",
                self.drain_period_s
            ));
        }
        if !(self.mesh_rate_hz >= 0.0 && self.mesh_rate_hz.is_finite()) {
            return Err(format!(
                "recording.mesh_rate_hz = {} must be ≥ 0",
                self.mesh_rate_hz
            ));
        }
        if self.zstd_level > 22 {
            return Err(format!(
                "recording.zstd_level = {} must be ≤ 22",
                self.zstd_level
            ));
        }
        if self.chunk_size_bytes < 1024 {
            return Err(format!(
                "recording.chunk_size_bytes = {} must be ≥ 1024",
                self.chunk_size_bytes
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_section_is_the_default_and_valid() {
        let c: RecordingConfig = toml::from_str("").unwrap();
        assert_eq!(c, RecordingConfig::default());
        c.validate().unwrap();
    }

    #[test]
    fn unknown_keys_and_bad_ranges_are_rejected() {
        assert!(toml::from_str::<RecordingConfig>("flush_every = 1").is_err());
        let c: RecordingConfig =
            toml::from_str("flush_interval_s = 2.0\ncompression = \"none\"").unwrap();
        assert_eq!(c.compression, ChunkCompression::None);
        assert!(c.validate().is_err());
    }
}
