//! `[bridge]`: the ROS 2 bridge. Owned by viz-bridge.
//!
//! ```toml
//! [bridge]
//! domain_id = 0
//! namespace = "/arthrosim"
//! [bridge.streams.probe_pose]
//! reliability = "best_effort"   # or "reliable" (default)
//! rate_hz = 0                   # 0: every sample
//! [bridge.streams.contacts]
//! enabled = false
//! ```
//!
//! External control of the probe is off unless asked for:
//!
//! ```toml
//! [bridge]
//! accept_target_pose = true     # default false: <ns>/probe/target_pose is counted, refused
//! [bridge.target_pose]
//! workspace_margin_m = 0.02     # box = the scene's surface bounds grown by this margin
//! max_jump_m = 0.005            # between consecutive accepted targets (or from the probe)
//! max_rate_hz = 100             # faster targets are refused
//! ```
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BridgeConfig {
    /// ROS 2 / DDS domain id (0..=232).
    pub domain_id: u16,
    /// Namespace of the session's topics (`/tf` and `/diagnostics` stay global).
    pub namespace: String,
    /// Fixed frame of every pose, wrench, marker and transform (REP-103, z up).
    pub world_frame: String,
    /// Depth of the bounded queue between the shared-memory reader and the DDS writer;
    /// when it is full (DDS stalled), messages are dropped and counted, never waited for.
    pub queue_depth: usize,
    /// Meniscus frame relative to the world frame (the surface stream is already in world).
    pub meniscus_pose: FramePose,
    /// Touch base frame relative to the world frame.
    pub touch_base_pose: FramePose,
    pub streams: BridgeStreams,
    /// Let `<ns>/probe/target_pose` drive the physics probe. Off by default: anyone on the
    /// DDS domain can publish there, and while the probe follows a remote target the device
    /// renders no force.
    pub accept_target_pose: bool,
    /// Bounds on accepted target poses (used only with `accept_target_pose`).
    pub target_pose: TargetPoseLimits,
}

/// What a remote target pose must satisfy to be forwarded to physics; every refusal is
/// counted and reported on `/diagnostics`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TargetPoseLimits {
    /// Workspace box corners, world m. Absent: the bounds of the scene's deformed surface
    /// (the first surface frame physics publishes) grown by `workspace_margin_m`; until that
    /// frame has arrived, every target is refused.
    pub workspace_min: Option<[f64; 3]>,
    pub workspace_max: Option<[f64; 3]>,
    /// Margin around the scene's surface bounds, m.
    pub workspace_margin_m: f64,
    /// Largest distance from the last accepted target (or, when none is recent, from the
    /// probe's current position), m.
    pub max_jump_m: f64,
    /// Largest rate of accepted targets, Hz.
    pub max_rate_hz: f64,
}

impl Default for TargetPoseLimits {
    fn default() -> Self {
        TargetPoseLimits {
            workspace_min: None,
            workspace_max: None,
            workspace_margin_m: 0.02,
            max_jump_m: 0.005,
            max_rate_hz: 100.0,
        }
    }
}

/// Hard ceilings a launch file cannot raise: a jump of 5 cm in one command, a margin of
/// 20 cm around the specimen, 1 kHz.
pub const MAX_TARGET_JUMP_M: f64 = 0.05;
pub const MAX_WORKSPACE_MARGIN_M: f64 = 0.2;
pub const MAX_TARGET_RATE_HZ: f64 = 1000.0;

impl Default for BridgeConfig {
    fn default() -> Self {
        BridgeConfig {
            domain_id: 0,
            namespace: "/arthrosim".into(),
            world_frame: "world".into(),
            queue_depth: 1024,
            meniscus_pose: FramePose::default(),
            touch_base_pose: FramePose::default(),
            streams: BridgeStreams::default(),
            accept_target_pose: false,
            target_pose: TargetPoseLimits::default(),
        }
    }
}

impl BridgeConfig {
    /// The session → ROS 2 mapping these settings describe (namespace, world frame, fixed
    /// frames); the bridge publishes and the recorder records through it.
    pub fn ros_mapping(&self) -> msgs::ros_mapping::Mapping {
        let pose = |f: &FramePose| msgs::Pose {
            position: f.position,
            orientation: f.orientation,
        };
        msgs::ros_mapping::Mapping {
            namespace: self.namespace.clone(),
            world_frame: self.world_frame.clone(),
            meniscus_pose: pose(&self.meniscus_pose),
            touch_base_pose: pose(&self.touch_base_pose),
        }
    }
}

/// A fixed frame: position (m) and quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FramePose {
    pub position: [f64; 3],
    pub orientation: [f64; 4],
}

impl Default for FramePose {
    fn default() -> Self {
        FramePose {
            position: [0.0; 3],
            orientation: [0.0, 0.0, 0.0, 1.0],
        }
    }
}

/// DDS reliability of one stream. A reliable writer serves both reliable and best-effort
/// readers; a best-effort writer serves only best-effort readers (RViz and `ros2 topic echo`
/// default to reliable).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Reliability {
    Reliable,
    BestEffort,
}

/// DDS durability of one stream: transient-local keeps the last `depth` samples for late
/// joiners (latched).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Durability {
    Volatile,
    TransientLocal,
}

/// One topic's settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreamConfig {
    pub enabled: bool,
    pub reliability: Reliability,
    pub durability: Durability,
    /// History depth (keep-last); also the reliable resend window.
    pub depth: usize,
    /// Maximum publish rate, Hz; 0 publishes every sample.
    pub rate_hz: f64,
}

impl StreamConfig {
    fn every(depth: usize) -> StreamConfig {
        StreamConfig {
            enabled: true,
            reliability: Reliability::Reliable,
            durability: Durability::Volatile,
            depth,
            rate_hz: 0.0,
        }
    }

    fn at(rate_hz: f64, depth: usize) -> StreamConfig {
        StreamConfig {
            rate_hz,
            ..StreamConfig::every(depth)
        }
    }

    /// Minimum interval between two publications, ns (0: every sample).
    pub fn min_interval_ns(&self) -> u64 {
        if self.rate_hz > 0.0 && self.rate_hz.is_finite() {
            (1e9 / self.rate_hz) as u64
        } else {
            0
        }
    }
}

impl Default for StreamConfig {
    fn default() -> Self {
        StreamConfig::every(10)
    }
}

/// Per-topic settings. Topic names are fixed (see the viz-bridge docs); out = published,
/// in = subscribed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BridgeStreams {
    /// out `<ns>/probe/pose`, every physics step.
    pub probe_pose: StreamConfig,
    /// out `<ns>/probe/wrench`: contact force on the probe, eq. (1), world frame.
    pub probe_wrench: StreamConfig,
    /// out `<ns>/device/wrench`: force rendered on the Touch, 1 kHz.
    pub device_wrench: StreamConfig,
    /// out `<ns>/device/joint_states`.
    pub joint_states: StreamConfig,
    /// out `<ns>/device/buttons`.
    pub buttons: StreamConfig,
    /// out `<ns>/meniscus/mesh`: triangle list at viewer rate, latched.
    pub mesh: StreamConfig,
    /// out `<ns>/contacts`: contact points and normals.
    pub contacts: StreamConfig,
    /// out `/tf`.
    pub tf: StreamConfig,
    /// out `/diagnostics`, 1 Hz.
    pub diagnostics: StreamConfig,
    /// in `<ns>/probe/target_pose` → physics ProbeTarget.
    pub target_pose: StreamConfig,
    /// in `<ns>/material/degeneration_grade` → physics MaterialCommand.
    pub degeneration_grade: StreamConfig,
}

impl BridgeStreams {
    /// The settings of an outbound session topic.
    pub fn of(&self, topic: msgs::ros_mapping::Topic) -> &StreamConfig {
        use msgs::ros_mapping::Topic;
        match topic {
            Topic::ProbePose => &self.probe_pose,
            Topic::ProbeWrench => &self.probe_wrench,
            Topic::DeviceWrench => &self.device_wrench,
            Topic::JointStates => &self.joint_states,
            Topic::Buttons => &self.buttons,
            Topic::Mesh => &self.mesh,
            Topic::Contacts => &self.contacts,
            Topic::Tf => &self.tf,
            Topic::Diagnostics => &self.diagnostics,
        }
    }
}

impl Default for BridgeStreams {
    fn default() -> Self {
        BridgeStreams {
            probe_pose: StreamConfig::every(100),
            probe_wrench: StreamConfig::every(100),
            device_wrench: StreamConfig::every(100),
            joint_states: StreamConfig::at(100.0, 10),
            buttons: StreamConfig::at(30.0, 10),
            mesh: StreamConfig {
                durability: Durability::TransientLocal,
                ..StreamConfig::at(30.0, 1)
            },
            contacts: StreamConfig::at(30.0, 10),
            tf: StreamConfig::at(100.0, 100),
            diagnostics: StreamConfig::at(1.0, 10),
            target_pose: StreamConfig::every(10),
            // Volatile readers match volatile and transient-local writers alike.
            degeneration_grade: StreamConfig::every(1),
        }
    }
}

/// A `[bridge]` setting that cannot work.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BridgeConfigError {
    #[error("bridge.domain_id = {0}: must be 0..=232 (DDS port mapping)")]
    DomainId(u16),
    #[error("bridge.namespace = {0:?}: must be absolute, like \"/arthrosim\" ([A-Za-z0-9_] segments, no trailing slash)")]
    Namespace(String),
    #[error("bridge.queue_depth = 0: must be at least 1")]
    QueueDepth,
    #[error("bridge.streams.{0}.depth = 0: must be at least 1")]
    Depth(&'static str),
    #[error("bridge.streams.{0}.rate_hz = {1}: must be finite and >= 0")]
    Rate(&'static str, f64),
    #[error("bridge.{0}: orientation must be a finite unit quaternion [x, y, z, w]")]
    Frame(&'static str),
    #[error("bridge.target_pose.{0} = {1}: must be finite, > 0 and at most {2}")]
    TargetLimit(&'static str, f64, f64),
    #[error("bridge.target_pose: workspace_min and workspace_max must both be given, finite, with min < max on every axis")]
    Workspace,
}

impl BridgeConfig {
    /// Checks the values serde cannot (ranges, name syntax).
    pub fn validate(&self) -> Result<(), BridgeConfigError> {
        if self.domain_id > 232 {
            return Err(BridgeConfigError::DomainId(self.domain_id));
        }
        let ns_ok = self.namespace == "/"
            || (self.namespace.starts_with('/')
                && self.namespace[1..].split('/').all(|seg| {
                    !seg.is_empty()
                        && seg.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                        && !seg.starts_with(|c: char| c.is_ascii_digit())
                }));
        if !ns_ok {
            return Err(BridgeConfigError::Namespace(self.namespace.clone()));
        }
        if self.queue_depth == 0 {
            return Err(BridgeConfigError::QueueDepth);
        }
        for (name, frame) in [
            ("meniscus_pose", &self.meniscus_pose),
            ("touch_base_pose", &self.touch_base_pose),
        ] {
            let norm: f64 = frame.orientation.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !(frame.position.iter().all(|v| v.is_finite()) && (norm - 1.0).abs() < 1e-6) {
                return Err(BridgeConfigError::Frame(name));
            }
        }
        let t = &self.target_pose;
        for (name, value, max) in [
            (
                "workspace_margin_m",
                t.workspace_margin_m,
                MAX_WORKSPACE_MARGIN_M,
            ),
            ("max_jump_m", t.max_jump_m, MAX_TARGET_JUMP_M),
            ("max_rate_hz", t.max_rate_hz, MAX_TARGET_RATE_HZ),
        ] {
            if !(value.is_finite() && value > 0.0 && value <= max) {
                return Err(BridgeConfigError::TargetLimit(name, value, max));
            }
        }
        match (t.workspace_min, t.workspace_max) {
            (None, None) => {}
            (Some(lo), Some(hi))
                if lo.iter().chain(hi.iter()).all(|v| v.is_finite())
                    && (0..3).all(|k| lo[k] < hi[k]) => {}
            _ => return Err(BridgeConfigError::Workspace),
        }
        for (name, stream) in self.streams.named() {
            if stream.depth == 0 {
                return Err(BridgeConfigError::Depth(name));
            }
            if !(stream.rate_hz.is_finite() && stream.rate_hz >= 0.0) {
                return Err(BridgeConfigError::Rate(name, stream.rate_hz));
            }
        }
        Ok(())
    }
}

impl BridgeStreams {
    /// Every stream with its key name.
    pub fn named(&self) -> [(&'static str, &StreamConfig); 11] {
        [
            ("probe_pose", &self.probe_pose),
            ("probe_wrench", &self.probe_wrench),
            ("device_wrench", &self.device_wrench),
            ("joint_states", &self.joint_states),
            ("buttons", &self.buttons),
            ("mesh", &self.mesh),
            ("contacts", &self.contacts),
            ("tf", &self.tf),
            ("diagnostics", &self.diagnostics),
            ("target_pose", &self.target_pose),
            ("degeneration_grade", &self.degeneration_grade),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_section_gives_defaults_and_streams_parse() {
        let cfg: BridgeConfig = toml::from_str("").unwrap();
        assert_eq!(cfg, BridgeConfig::default());
        cfg.validate().unwrap();
        let cfg: BridgeConfig = toml::from_str(
            "domain_id = 7\n[streams.probe_pose]\nreliability = \"best_effort\"\nrate_hz = 500\n\
             [streams.contacts]\nenabled = false\n",
        )
        .unwrap();
        assert_eq!(cfg.streams.probe_pose.reliability, Reliability::BestEffort);
        assert_eq!(cfg.streams.probe_pose.min_interval_ns(), 2_000_000);
        assert!(!cfg.streams.contacts.enabled);
        assert_eq!(cfg.streams.mesh.durability, Durability::TransientLocal);
    }

    #[test]
    fn bad_values_are_named() {
        assert!(toml::from_str::<BridgeConfig>("[streams.pose]\n").is_err());
        let mut cfg = BridgeConfig {
            namespace: "arthrosim/".into(),
            ..Default::default()
        };
        assert!(matches!(
            cfg.validate(),
            Err(BridgeConfigError::Namespace(_))
        ));
        cfg.namespace = "/lab_1/arthrosim".into();
        cfg.validate().unwrap();
        cfg.streams.tf.rate_hz = -1.0;
        assert_eq!(cfg.validate(), Err(BridgeConfigError::Rate("tf", -1.0)));
    }

    #[test]
    fn target_poses_are_refused_by_default_and_limits_are_bounded() {
        let cfg: BridgeConfig = toml::from_str("").unwrap();
        assert!(!cfg.accept_target_pose);
        let cfg: BridgeConfig = toml::from_str(
            "accept_target_pose = true\n[target_pose]\nmax_jump_m = 0.002\n\
             workspace_min = [-0.1, -0.1, -0.05]\nworkspace_max = [0.1, 0.1, 0.1]\n",
        )
        .unwrap();
        cfg.validate().unwrap();
        assert!(cfg.accept_target_pose);
        assert_eq!(cfg.target_pose.max_jump_m, 0.002);
        let mut bad = cfg.clone();
        bad.target_pose.max_jump_m = 1.0;
        assert_eq!(
            bad.validate(),
            Err(BridgeConfigError::TargetLimit(
                "max_jump_m",
                1.0,
                MAX_TARGET_JUMP_M
            ))
        );
        let mut bad = cfg.clone();
        bad.target_pose.workspace_max = None;
        assert_eq!(bad.validate(), Err(BridgeConfigError::Workspace));
        let mut bad = cfg;
        bad.target_pose.workspace_min = Some([0.2, -0.1, -0.05]);
        assert_eq!(bad.validate(), Err(BridgeConfigError::Workspace));
    }
}
