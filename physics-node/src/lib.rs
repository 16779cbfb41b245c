//! The physics node: corotational FEM meniscus, hook probe, frictional contact and the
//! contact compliance published to the haptic node.

pub mod mesh;
