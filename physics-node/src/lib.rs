//! The physics node: corotational FEM meniscus, hook probe, frictional contact and the
//! contact compliance published to the haptic node.
//!
//! Data comes in from the launch file's `[scene]` (the mesh through `scene-geometry`) and,
//! every step, from the haptic node's device state (the proxy the probe is coupled to). Data
//! goes out every step as a contact frame (`msgs::physics_to_haptic`: W = H A⁻¹ Hᵀ, the
//! constraint directions, the free violation, the contact force) to the haptic node, the
//! bridge, the recorder and the launcher's status, and as the deformed surface to viewers.
//! The same [`sim::Simulation`] is driven offline by `gap-diagnosis` and `probe-curve`.

pub mod compliance;
pub mod contact;
pub mod error;
pub mod faults;
pub mod fem;
pub mod node;
pub mod probe;
pub mod probe_curve;
pub mod sim;
pub mod tissue_fit;

// The contact frame's W is laid out with msgs' row stride and solved by contact-lcp, which
// has no dependencies and so keeps its own copy of the capacities: check they agree.
const _: () = assert!(
    msgs::MAX_CONTACTS == contact_lcp::MAX_CONTACTS
        && msgs::ROWS_PER_CONTACT == contact_lcp::ROWS_PER_CONTACT
        && msgs::MAX_ROWS == contact_lcp::MAX_ROWS,
    "msgs and contact-lcp disagree on the contact capacity"
);

// Meshes, probing sites and the visual mapping live below the physics (the haptic node's
// emulated operator needs the sites without the FEM); re-exported under their old paths.
pub use scene_geometry::{geometry, mesh, visual};
