//! The physics node binary: parses the node arguments and runs the node (see `physics_node::node`).
use clap::Parser;

#[derive(Parser, Debug)]
#[command(
    name = "physics-node",
    about = "arthrosim physics node: FEM meniscus, probe contact, contact compliance"
)]
struct Cli {
    #[command(flatten)]
    node: physics_node::node::NodeArgs,
}

fn main() -> anyhow::Result<()> {
    physics_node::node::run_node(Cli::parse().node)
}
