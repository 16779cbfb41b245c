//! Launch files: one TOML document that names the nodes of a session and configures each of
//! them. Every section type lives in its own module and is owned by the node it configures;
//! this crate only composes, validates and (in `launcher`) runs them.
//!
//! Unknown keys are errors (`deny_unknown_fields` everywhere); every field has a default, so
//! the smallest launch file is empty.

pub mod bridge;
pub mod device;
pub mod recording;
pub mod scene;

use serde::{Deserialize, Serialize};

pub use bridge::BridgeConfig;
pub use device::DeviceConfig;
pub use recording::RecordingConfig;
pub use scene::SceneConfig;

/// A whole launch file.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaunchFile {
    pub session: SessionConfig,
    pub nodes: NodesConfig,
    pub scene: SceneConfig,
    pub device: DeviceConfig,
    pub bridge: BridgeConfig,
    pub recording: RecordingConfig,
}

/// `[session]`: names and bounds of the session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SessionConfig {
    /// iceoryx2 session prefix (`[A-Za-z0-9_-]`); keeps concurrent sessions apart.
    pub name: String,
    /// Bounded run length in seconds; 0 runs until Ctrl-C (or the protocol ends).
    pub seconds: f64,
}

impl Default for SessionConfig {
    fn default() -> Self {
        SessionConfig {
            name: "default".into(),
            seconds: 0.0,
        }
    }
}

/// `[nodes]`: which node processes the launcher starts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NodesConfig {
    pub physics: bool,
    pub haptic: bool,
    pub bridge: bool,
    pub recorder: bool,
}

impl Default for NodesConfig {
    fn default() -> Self {
        NodesConfig {
            physics: true,
            haptic: true,
            bridge: true,
            recorder: true,
        }
    }
}
