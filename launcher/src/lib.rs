//! The session launcher: starts the nodes a launch file names as child processes (each is
//! `arthrosim node <kind>`), supervises and restarts them, shows live status from the
//! shared-memory streams, and stops them in order.
//!
//! Data comes in from the launch file (`launch-config`) and, while the session runs, from the
//! physics and haptic nodes' streams ([`status`]); it goes out as the session folder
//! (`launch.toml`, `summary.json`, the recorder's MCAP) and the end-of-session summary in the
//! study's terms (computed by `session-metrics`).

pub mod status;
pub mod supervisor;

pub use supervisor::*;
