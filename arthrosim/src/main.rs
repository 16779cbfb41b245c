//! `arthrosim`: the one command of the project. `run` starts a whole session from a launch
//! file (or the embedded default), `validate` checks launch files, `replay`, `recordings`,
//! `gap` and `reality` work on recordings and experiments, and the hidden `node` subcommand
//! runs one node in this process (the launcher starts each node that way, so a session needs
//! only this executable).
//!
//! Data comes in from launch files, recordings and experiment folders; the command only wires
//! the library crates (`launcher`, `recordings`, `gap-diagnosis`, the nodes).

mod cli;
mod commands;

use clap::Parser;

fn main() {
    let cli = cli::Cli::parse();
    match commands::dispatch(cli) {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::exit(1);
        }
    }
}
