//! Scene geometry: the meniscus meshes and where the probe meets them, below the physics.
//!
//! Data comes in from files (Gmsh `.msh` tetrahedral meshes, OBJ/STL surfaces, fixed-node
//! lists, all read with errors that name the file and line) or from the built-in parametric
//! lateral/medial meniscus; [`mesh::load_scene_mesh`] turns a launch file's
//! `[scene.meniscus]` into a placed tetrahedral mesh with its fixed nodes and the study's
//! probing sites (posterior, mid, anterior). Data goes out to the physics node (FEM and
//! contact), to the haptic node's emulated operator (the probing sites, without linking the
//! FEM) and to offline re-simulation. [`visual`] maps a high-resolution visual surface onto
//! the tetrahedra so a viewer sees the deformed tissue.
//!
//! Units: metres; world frame z-up.

pub mod geometry;
pub mod mesh;
pub mod visual;
