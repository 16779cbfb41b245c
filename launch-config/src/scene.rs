//! `[scene]`: the physics node's scene. Owned by physics-node.
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneConfig {
    /// Time step, s.
    pub dt: f64,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig { dt: 0.01 }
    }
}
