use clap::Parser;

/// The arthrosim haptic node (1 kHz force rendering for the Touch or its emulator).
#[derive(Parser)]
#[command(name = "haptic-node", version)]
struct Cli {
    #[command(flatten)]
    node: haptic_node::NodeArgs,
}

fn main() -> anyhow::Result<()> {
    haptic_node::run_node(Cli::parse().node)
}
