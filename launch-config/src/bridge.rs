//! `[bridge]`: the ROS 2 bridge. Owned by viz-bridge.
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BridgeConfig {
    pub domain_id: u16,
    pub namespace: String,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        BridgeConfig {
            domain_id: 0,
            namespace: "/arthrosim".into(),
        }
    }
}
