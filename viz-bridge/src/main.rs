use clap::Parser;

/// arthrosim ROS 2 bridge node.
#[derive(Parser)]
#[command(name = "viz-bridge", version)]
struct Cli {
    #[command(flatten)]
    node: viz_bridge::NodeArgs,
}

fn main() -> anyhow::Result<()> {
    viz_bridge::run_node(Cli::parse().node)
}
