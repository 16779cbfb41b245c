//! `[device]`: the haptic node's device backend and safety limits. Owned by haptic-node.
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviceConfig {
    /// `touch`, `emulated` or `replay`.
    pub backend: String,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        DeviceConfig {
            backend: "emulated".into(),
        }
    }
}
