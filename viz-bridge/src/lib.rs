//! viz-bridge: puts an arthrosim session on ROS 2 (pure Rust DDS through ros2-client), so
//! RViz2, Foxglove or any ROS 2 node on the lab network sees it and can drive the probe.
//! Data comes in from the physics and haptic nodes' shared-memory streams and goes out as
//! ROS 2 topics on the lab network (and, inbound, as commands to the physics node).
//!
//! Topics (namespace from `[bridge] namespace`, default `/arthrosim`):
//! out `probe/pose` (PoseStamped), `probe/wrench` (WrenchStamped, contact force on the probe,
//! eq. (1), world frame), `device/wrench`, `device/joint_states`, `device/buttons` (Joy),
//! `meniscus/mesh` (Marker TRIANGLE_LIST, transient-local), `contacts` (MarkerArray), `/tf`,
//! `/diagnostics`; in `probe/target_pose` (PoseStamped → physics ProbeTarget, only with
//! `[bridge] accept_target_pose = true`, and then bounded: see [`target_gate`]) and
//! `material/degeneration_grade` (Float64 → physics MaterialCommand).
//!
//! Two threads: the shared-memory thread (iceoryx2 ports are not `Send`) converts samples
//! and hands them to the DDS thread through a bounded queue; when DDS stalls the queue fills
//! and samples are dropped and counted (reported on `/diagnostics`), so the physics and
//! haptic loops never notice the network.

pub mod bridge;
pub mod convert;
pub mod dds;
pub mod stats;
pub mod target_gate;

use std::path::Path;

use anyhow::Context as _;
use launch_config::BridgeConfig;

pub use bridge::{Bridge, BridgeError};

/// Command-line arguments of the bridge node (also `arthrosim node bridge`).
#[derive(Debug, Clone, clap::Args)]
pub struct NodeArgs {
    /// `--launch` (its `[bridge]` section), `--session`, `--out` (accepted for a uniform node
    /// CLI; the bridge writes no files).
    #[command(flatten)]
    pub common: launch_config::node::CommonArgs,
}

/// The `[bridge]` section of a launch file, loaded and validated with the whole file by
/// `launch_config::load` (errors name the file, line and key); no file: defaults.
pub fn load_config(path: Option<&Path>) -> anyhow::Result<BridgeConfig> {
    let config = match path {
        None => BridgeConfig::default(),
        Some(path) => {
            launch_config::load(path)
                .with_context(|| format!("loading launch file {}", path.display()))?
                .bridge
        }
    };
    config.validate()?;
    Ok(config)
}

/// Default log filter: warnings, minus RustDDS's per-datagram size notices and the ROS_DISTRO
/// notice (override with RUST_LOG).
const QUIET_LOGS: &str = "warn,rustdds::network::udp_sender=error,ros2_client::distributions=error";

/// Runs the bridge node until SIGINT / SIGTERM.
pub fn run_node(args: NodeArgs) -> anyhow::Result<()> {
    launch_config::node::init_tracing(QUIET_LOGS);
    let stop = msgs::lifecycle::install_stop_flag();
    let config = load_config(args.common.launch.as_deref())?;
    let session = msgs::ipc::session_name(args.common.session.as_deref())?;
    let mut bridge = Bridge::new(config, &session)?;
    bridge.start().context("starting the bridge")?;
    msgs::lifecycle::announce_ready("bridge");
    let started = std::time::Instant::now();
    let result = bridge.run(stop);
    // After `run` the DDS thread is joined, so the counts are final.
    let totals = bridge.stats().totals_json(started.elapsed().as_secs_f64());
    println!("BRIDGED {totals}");
    result?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn launch_file_bridge_section_is_read_and_errors_name_the_file() {
        let dir = std::env::temp_dir().join(format!("viz-bridge-load-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.toml");
        std::fs::write(&good, "[bridge]\ndomain_id = 42\nnamespace = \"/lab\"\n").unwrap();
        let config = load_config(Some(&good)).unwrap();
        assert_eq!((config.domain_id, config.namespace.as_str()), (42, "/lab"));

        let bad = dir.join("bad.toml");
        std::fs::write(&bad, "[bridge]\nnamespace = \"lab/\"\n").unwrap();
        let err = format!("{:#}", load_config(Some(&bad)).unwrap_err());
        assert!(
            err.contains("bad.toml") && err.contains("namespace"),
            "{err}"
        );

        let unknown = dir.join("unknown.toml");
        std::fs::write(&unknown, "[bridge]\ntopics = 3\n").unwrap();
        let err = format!("{:#}", load_config(Some(&unknown)).unwrap_err());
        assert!(
            err.contains("unknown.toml") && err.contains("topics"),
            "{err}"
        );
        assert_eq!(load_config(None).unwrap(), BridgeConfig::default());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
