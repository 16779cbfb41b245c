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
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    physics_node::node::run_node(Cli::parse().node)
}
