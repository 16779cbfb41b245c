//! The physics node: corotational FEM meniscus, hook probe, frictional contact and the
//! contact compliance published to the haptic node.

pub mod compliance;
pub mod contact;
pub mod error;
pub mod fem;
pub mod node;
pub mod probe;
pub mod sim;

// Meshes, probing sites and the visual mapping live below the physics (the haptic node's
// emulated operator needs the sites without the FEM); re-exported under their old paths.
pub use scene_geometry::{geometry, mesh, visual};
