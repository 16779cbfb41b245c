//! What every node process (physics, haptic, bridge, recorder) shares on its command line and
//! in its logging: each node's argument struct flattens [`CommonArgs`] and adds its own flags,
//! and each node's `run_node` calls [`init_tracing`].

use std::path::PathBuf;

/// The arguments every node takes (`#[command(flatten)]` them into the node's own struct).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct CommonArgs {
    /// Launch file (TOML); the node reads its own section (`[scene]`, `[device]`, `[bridge]`,
    /// `[recording]`). None: defaults.
    #[arg(long, value_name = "FILE")]
    pub launch: Option<PathBuf>,
    /// Session name (shared-memory service prefix). Default: $ARTHROSIM_SESSION or `default`.
    #[arg(long, value_name = "NAME")]
    pub session: Option<String>,
    /// Session folder for the node's files: physics `contact_force.csv`, haptic
    /// `haptic-stats.json`, recorder `session.mcap` (default: the current folder); the bridge
    /// writes none. None: the physics and haptic nodes write no file.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// Logs to stderr (stdout carries the READY line). `RUST_LOG` filters; without it
/// `default_filter` does (e.g. `"info"`). A second call keeps the first subscriber.
pub fn init_tracing(default_filter: &str) {
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter)),
        )
        .try_init();
}
