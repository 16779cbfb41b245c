//! Meshes: the tetrahedral simulation mesh, triangle surfaces (visual and collision models),
//! readers for Gmsh MSH 4.1 / 2.2, OBJ and STL, load-time transforms, the smooth surface
//! through a mesh's boundary and uniform refinement.
//!
//! All positions are in metres once loaded (the scene transform converts authored units).

pub mod boxes;
mod error;
mod fixed;
mod msh;
mod msh_write;
mod refine;
mod scene;
pub mod smooth;
mod surface_io;
pub mod topology;
mod transform;

pub use error::MeshError;
pub use fixed::{parse_fixed_nodes, read_fixed_nodes};
pub use msh::{parse_msh, read_msh, MshMesh};
pub use msh_write::{write_msh22, write_refined_once, RefinedFiles};
pub use refine::{refine_once, Midpoints};
pub use scene::{load_scene_mesh, resolve_data_dir, LoadedMeniscus};
pub use surface_io::{parse_obj, parse_stl, read_obj, read_stl, read_surface};
pub use topology::{Sliver, SLIVER_QUALITY, ZERO_VOLUME_RELATIVE};
pub use transform::Transform;

use nalgebra::Point3;

/// A tetrahedral mesh, every tet positively oriented (det[x1−x0, x2−x0, x3−x0] > 0).
#[derive(Debug, Clone, PartialEq)]
pub struct TetMesh {
    /// Rest positions, m.
    pub nodes: Vec<Point3<f64>>,
    /// Node indices per tetrahedron.
    pub tets: Vec<[usize; 4]>,
}

/// A triangle surface: visual model, collision model or the boundary of a [`TetMesh`].
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceMesh {
    pub vertices: Vec<Point3<f64>>,
    /// Counter-clockwise seen from outside (normals point out).
    pub triangles: Vec<[usize; 3]>,
}

#[cfg(test)]
pub(crate) mod tests;
