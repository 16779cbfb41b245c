//! The recorder node: `recorder --session NAME --out DIR [--launch FILE]`.
use clap::Parser;

#[derive(Parser)]
#[command(about = "arthrosim recorder node: the session's physics and haptic streams to MCAP")]
struct Cli {
    #[command(flatten)]
    node: recordings::recorder::NodeArgs,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    recordings::recorder::run_node(Cli::parse().node)
}
