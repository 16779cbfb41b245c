//! What a restarted recorder already has: the newest sequence number of each lossless stream
//! (device ticks, contact steps) per publisher instance that is safely in an earlier part.
//!
//! The haptic and physics publishers keep their recent samples for late subscribers (iceoryx2
//! history, `msgs::Topic::HISTORY`), so a recorder restarted after a crash first receives the
//! samples published while it was down — and also those its predecessor had already written.
//! Each part's progress is saved beside it at every flush (what a `kill -9` leaves in the file
//! is exactly what was flushed), and the next part skips what an earlier one holds: the
//! set of parts then has every sample once.

use crate::error::RecordingError;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One lossless stream's progress: the newest sequence written per publisher instance, and
/// the last sample written (for sequence continuity across the restart).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StreamProgress {
    /// Publisher instance id → newest sequence number written.
    pub newest: BTreeMap<u64, u64>,
    /// (instance, sequence) of the last sample written.
    pub last: Option<(u64, u64)>,
}

impl StreamProgress {
    /// Notes a written sample.
    pub fn wrote(&mut self, instance: u64, sequence: u64) {
        self.raise(instance, sequence);
        self.last = Some((instance, sequence));
    }

    fn raise(&mut self, instance: u64, sequence: u64) {
        let newest = self.newest.entry(instance).or_insert(sequence);
        *newest = (*newest).max(sequence);
    }

    /// True when an earlier part already holds this sample.
    pub fn holds(&self, instance: u64, sequence: u64) -> bool {
        self.newest.get(&instance).is_some_and(|&s| sequence <= s)
    }

    fn merge(&mut self, other: &StreamProgress) {
        for (&instance, &sequence) in &other.newest {
            self.raise(instance, sequence);
        }
        if other.last.is_some() {
            self.last = other.last;
        }
    }
}

/// Progress of one part (or, merged, of every earlier part).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    pub device_ticks: StreamProgress,
    pub contact_steps: StreamProgress,
}

/// The progress file of a part: hidden, beside it (`.session.1.mcap.progress.json`).
pub fn progress_path(part: &Path) -> PathBuf {
    let name = part
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    part.with_file_name(format!(".{name}.progress.json"))
}

impl Progress {
    /// Saves the progress of `part` (write then rename: a crash leaves the old one or the new
    /// one, never half of one).
    pub fn save(&self, part: &Path) -> Result<(), RecordingError> {
        let path = progress_path(part);
        let tmp = path.with_extension("json.tmp");
        let text = serde_json::to_vec(self)
            .map_err(|e| RecordingError::io(&path, std::io::Error::other(e)))?;
        std::fs::write(&tmp, text).map_err(|e| RecordingError::io(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| RecordingError::io(&path, e))
    }

    /// What the parts before `part` (in the recording's part order) hold, merged. A part without a progress file (never flushed) holds nothing to skip; one that
    /// cannot be read is reported and skipped (its samples may then appear twice, never not
    /// at all).
    pub fn of_earlier_parts(part: &Path) -> Progress {
        let mut merged = Progress::default();
        let Ok(parts) = crate::read::session_parts(part) else {
            return merged;
        };
        for earlier in parts.iter().take_while(|p| p.as_path() != part) {
            let path = progress_path(earlier);
            let text = match std::fs::read(&path) {
                Ok(t) => t,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
                Err(e) => {
                    tracing::warn!(file = %path.display(), error = %e, "progress file unreadable; its samples may be recorded twice");
                    continue;
                }
            };
            match serde_json::from_slice::<Progress>(&text) {
                Ok(p) => {
                    merged.device_ticks.merge(&p.device_ticks);
                    merged.contact_steps.merge(&p.contact_steps);
                }
                Err(e) => {
                    tracing::warn!(file = %path.display(), error = %e, "progress file malformed; its samples may be recorded twice");
                }
            }
        }
        merged
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn earlier_parts_are_merged_and_their_samples_held() {
        let dir = std::env::temp_dir().join(format!("arthrosim-resume-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let first = dir.join("session.mcap");
        let second = dir.join("session.1.mcap");
        let third = dir.join("session.2.mcap");
        for p in [&first, &second, &third] {
            std::fs::write(p, b"x").unwrap();
        }
        let mut a = Progress::default();
        for s in 1..=100 {
            a.device_ticks.wrote(7, s);
        }
        a.contact_steps.wrote(9, 10);
        a.save(&first).unwrap();
        // The second part: the haptic node restarted (a new instance) and went on.
        let mut b = Progress::default();
        b.device_ticks.wrote(7, 150);
        b.device_ticks.wrote(8, 20);
        b.save(&second).unwrap();
        // A torn progress file of a third part is skipped, not fatal.
        std::fs::write(progress_path(&third), b"{\"device_ticks\":").unwrap();
        let fourth = dir.join("session.3.mcap");
        std::fs::write(&fourth, b"x").unwrap();

        let merged = Progress::of_earlier_parts(&fourth);
        assert!(merged.device_ticks.holds(7, 150) && merged.device_ticks.holds(7, 1));
        assert!(!merged.device_ticks.holds(7, 151));
        assert!(merged.device_ticks.holds(8, 20) && !merged.device_ticks.holds(8, 21));
        assert!(
            !merged.device_ticks.holds(99, 1),
            "an unknown instance is new"
        );
        assert_eq!(merged.device_ticks.last, Some((8, 20)));
        assert!(merged.contact_steps.holds(9, 10) && !merged.contact_steps.holds(9, 11));
        // A part continues only the ones before it.
        assert_eq!(Progress::of_earlier_parts(&first), Progress::default());
        assert!(!Progress::of_earlier_parts(&second).device_ticks.holds(8, 1));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
