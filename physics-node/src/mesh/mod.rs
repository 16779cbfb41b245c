//! Meshes: the tetrahedral simulation mesh, triangle surfaces (visual and collision models),
//! readers for Gmsh MSH 4.1 / 2.2, OBJ and STL, and load-time transforms.
//!
//! All positions are in metres once loaded (the scene transform converts authored units).

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
