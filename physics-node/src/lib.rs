//! The physics node: corotational FEM meniscus, hook probe, frictional contact and the
//! contact compliance published to the haptic node.

pub mod compliance;
pub mod contact;
pub mod error;
pub mod faults;
pub mod fem;
pub mod geometry;
pub mod mesh;
pub mod node;
pub mod probe;
pub mod sim;
pub mod visual;
