//! The haptic node: a 1 kHz process that owns the Touch (or its emulator, or a replayed
//! trajectory), re-solves the newest contact frame's LCP for the device's current position
//! (Peterlik et al. 2011; SOFA's LCPForceFeedback), renders the force within the device's
//! limits, and publishes the device state back to the physics node.
//!
//! Data comes in from the device (or its emulator, whose operator probes the sites that
//! `scene-geometry` places; the FEM is not linked here) and from the physics node's contact
//! frames; it goes out as motor forces and as device states to the physics node, the bridge,
//! the recorder and the launcher.
//!
//! Safety: a stale frame ramps the force to zero; a restarted physics node is resumed under
//! the rate limit; non-finite device positions, frames and forces are quarantined.

pub mod config;
pub mod device;
pub mod node;
pub mod render;
pub mod servo;
pub mod stats;
pub mod transport;

// The contact frame's W is laid out with msgs' row stride and solved by contact-lcp, which
// has no dependencies and so keeps its own copy of the capacities: check they agree.
const _: () = assert!(
    msgs::MAX_CONTACTS == contact_lcp::MAX_CONTACTS
        && msgs::ROWS_PER_CONTACT == contact_lcp::ROWS_PER_CONTACT
        && msgs::MAX_ROWS == contact_lcp::MAX_ROWS,
    "msgs and contact-lcp disagree on the contact capacity"
);

use std::path::PathBuf;

/// Command-line arguments of the haptic node (also used by `arthrosim node haptic`).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct NodeArgs {
    /// `--launch` (its `[device]` section), `--session`, `--out` (`haptic-stats.json`).
    #[command(flatten)]
    pub common: launch_config::node::CommonArgs,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM or the device ends).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Override `[device] backend` (touch | emulated | replay).
    #[arg(long, value_name = "BACKEND")]
    pub device: Option<launch_config::device::DeviceBackend>,
    /// Replay this CSV trajectory (sets the backend to `replay`).
    #[arg(long, value_name = "CSV")]
    pub replay: Option<PathBuf>,
    /// Do not ask for SCHED_FIFO / mlockall.
    #[arg(long)]
    pub no_realtime: bool,
    /// Measure physics publish → receivable latency with a watching thread (spins at
    /// SCHED_FIFO for about one physics step per period; for the benchmark).
    #[arg(long)]
    pub transport_probe: bool,
}

/// Runs the node until stopped (see [`node::run`]).
pub fn run_node(args: NodeArgs) -> anyhow::Result<()> {
    init_tracing();
    node::run(args)
}

/// Logs to stderr at `info` (the nodes' shared setup).
pub fn init_tracing() {
    launch_config::node::init_tracing("info");
}
