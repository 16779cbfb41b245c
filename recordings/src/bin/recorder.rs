//! The recorder node: `recorder --session NAME --out DIR [--launch FILE]`.
use clap::Parser;

#[derive(Parser)]
#[command(about = "arthrosim recorder node: the session's physics and haptic streams to MCAP")]
struct Cli {
    #[command(flatten)]
    node: recordings::recorder::NodeArgs,
}

fn main() -> anyhow::Result<()> {
    recordings::recorder::run_node(Cli::parse().node)
}
