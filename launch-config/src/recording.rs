//! `[recording]`: the recorder node. Owned by recordings.
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordingConfig {
    pub enabled: bool,
}

impl Default for RecordingConfig {
    fn default() -> Self {
        RecordingConfig { enabled: true }
    }
}
