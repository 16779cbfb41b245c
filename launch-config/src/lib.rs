//! Launch files: one TOML document that names the nodes of a session and configures each of
//! them. Every section type lives in its own module and is owned by the node it configures;
//! this crate only composes, loads and validates them ([`load`], [`validate`]). The
//! `launcher` crate runs them.
//!
//! Unknown keys are errors (`deny_unknown_fields` everywhere); every field has a default, so
//! the smallest launch file is empty. Every error names the file, the line and column, the
//! key, and what is allowed.
//!
//! Relative file paths in a launch file (`.msh` meshes, visual surfaces, fixed-node lists,
//! probe models, replay files) are resolved against the launch file's folder when it is
//! loaded, so the [`LaunchFile`] a node receives only holds absolute paths.

pub mod bridge;
pub mod choices;
pub mod device;
pub mod load;
pub mod node;
pub mod recording;
pub mod scene;
pub mod training;
pub mod validate;
pub mod viewer;

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

pub use bridge::BridgeConfig;
pub use device::DeviceConfig;
pub use load::{load, load_str, parse_str, Issue, LaunchError};
pub use recording::RecordingConfig;
pub use scene::SceneConfig;
pub use training::TrainingConfig;
pub use validate::validate;
pub use viewer::ViewerConfig;

/// The default session (parametric lateral meniscus, emulated Touch performing the study's
/// probing protocol, bridge and recorder on), compiled into every binary so `arthrosim run`
/// works without any file.
pub const DEFAULT_LAUNCH: &str = include_str!("../launch/default.toml");
/// Name under which the embedded default appears in messages.
pub const DEFAULT_LAUNCH_ORIGIN: &str = "<embedded default.toml>";

/// Environment variable naming the folder of the study's reference data.
pub const DATA_ENV: &str = "ARTHROSIM_DATA";

/// Folder of the study's reference data: `$ARTHROSIM_DATA`, else `../shared/data` next to
/// the workspace this binary was built from, else `../shared/data` relative to the working
/// directory.
pub fn data_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os(DATA_ENV) {
        return PathBuf::from(dir);
    }
    let built = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data"));
    if built.is_dir() {
        return built;
    }
    PathBuf::from("../shared/data")
}

/// A whole launch file.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaunchFile {
    pub session: SessionConfig,
    pub nodes: NodesConfig,
    pub launcher: LauncherConfig,
    pub scene: SceneConfig,
    pub device: DeviceConfig,
    pub bridge: BridgeConfig,
    pub recording: RecordingConfig,
    pub viewer: ViewerConfig,
    pub training: TrainingConfig,
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

/// What the launcher does when a node process dies on its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    /// A node that fails ends the session (the others are stopped cleanly).
    Never,
    /// A node that exits with an error or a signal is started again, up to
    /// `max_restarts` times, after `restart_backoff_s` (doubling each time).
    OnFailure,
}

/// `[launcher]`: how the launcher supervises its nodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LauncherConfig {
    /// `never` or `on-failure`.
    pub restart: RestartPolicy,
    /// Restarts allowed per node in one session.
    pub max_restarts: u32,
    /// Wait before the first restart, s; doubles with each further restart of that node.
    pub restart_backoff_s: f64,
    /// How long a node may take to print `READY <node>`, s.
    pub ready_timeout_s: f64,
    /// How long a node may take to stop after SIGTERM before it is killed, s.
    pub stop_grace_s: f64,
    /// Live status refresh period, s.
    pub status_period_s: f64,
}

impl Default for LauncherConfig {
    fn default() -> Self {
        LauncherConfig {
            restart: RestartPolicy::OnFailure,
            max_restarts: 3,
            restart_backoff_s: 0.5,
            ready_timeout_s: 60.0,
            stop_grace_s: 5.0,
            status_period_s: 0.25,
        }
    }
}
