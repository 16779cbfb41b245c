//! Finite-element meniscus: linear corotational or stable neo-Hookean tetrahedra, lumped
//! mass, Rayleigh damping, gravity, implicit (backward) Euler, CG or sparse direct solve.
//!
//! # Files, one concern each
//! [`settings`] (solver choices), `model` (construction, state, accessors), `assembly` (forces
//! and system matrix), `stepping` (backward Euler, correction, static solve), `cg`, the
//! vectorised `corotational_pass`, `energy` (rotations, energies, forces), `rest_compliance`
//! (precomputed constraint correction), [`material`], `element` and [`sparse`].
//!
//! # Step API (FreeMotionAnimationLoop order)
//! ```text
//! model.free_motion(dt, &external_forces)?;   // free velocities/positions into scratch;
//!                                             // committed state untouched
//! model.free_positions() / free_velocities()  // what collision detection looks at
//! model.node_rotations()                      // per-node rotations for warping A0⁻¹
//! model.apply_correction(&[(node, dx)])       // constraint correction: x += dx, v += dx/dt
//! model.commit();                             // free (+ corrected) state becomes the state
//! ```
//! `step(dt, f)` is `free_motion` + `commit`. None of these allocate.
//!
//! # Linearized backward Euler
//! With K = −∂f/∂x (for the corotational element R K0 Rᵀ, ∂R/∂x neglected as in SOFA),
//! C = α M + β K (Rayleigh), h = dt:
//! `(M + h C + h² K) Δv = h (f(x, v) − h K v)`, then `v⁺ = v + Δv`, `x⁺ = x + h v⁺`.
//! Held (fixed) nodes are removed from the system; with `support_stiffness > 0` the fixed set
//! is instead attached to its rest positions by springs of that stiffness per node.
//!
//! # Precomputed constraint correction
//! [`FemModel::rest_compliance`] factors A0 = M + h C0 + h² K0 (rest state) once and returns a
//! [`RestCompliance`] that solves A0⁻¹ b on full 3·nodes vectors (held dofs give zero), one
//! column or a block of columns at once, without allocating. Rotations for warping
//! (A⁻¹ ≈ R A0⁻¹ Rᵀ) come from [`FemModel::node_rotations`].
//!
//! # CG
//! SOFA defaults: at most 25 iterations, tolerance 1e-9 on the relative residual ‖r‖/‖b‖,
//! start from Δv = 0 (a warm start destabilised truncated solves, see `FemModel::cg`). Preconditioners: none (SOFA), block Jacobi, or the
//! rest-state Cholesky factor (optionally warped by the node rotations), which typically
//! converges in a few iterations.
//!
//! # Cost (release, `cargo run --release -p physics-node --example fem_timing`)
//! Study lateral mesh (258 nodes, 632 tets, 144 free): free motion p50 ≈ 0.27 ms with
//! `cg-warped-cholesky` (≈ 3 iterations), ≈ 0.42–0.66 ms with plain 25-iteration CG, measured
//! on a shared 2-core machine at load 6–7. The 2,560-node default mesh (10,584 tets) takes
//! 13–15 ms with 25-iteration CG under the same load: the block product (≈ 35%) and the
//! element kernels (≈ 50%) dominate. Rotation extraction is warm-started (tolerance 1e-7 rad,
//! at most 4 iterations per step). The CG step assembles and multiplies only the diagonal and
//! upper blocks of the symmetric system (half the memory traffic of the product; the direct
//! solver and the rest factor still get both triangles): 2,560-node mesh 6.1–6.7 ms p50 with
//! plain 25-iteration CG against 6.8–7.0 ms before (alternating A/B runs, load 3.5–3.9).

mod assembly;
mod cg;
mod corotational_pass;
mod element;
mod energy;
pub mod material;
mod model;
mod rest_compliance;
pub mod settings;
pub mod sparse;
mod stepping;
mod stiffening;
pub mod test_meshes;

#[cfg(test)]
mod tests;

use launch_config::scene::SceneConfig;
use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};

use crate::mesh::TetMesh;
use corotational_pass::{element_rotation, CorotationalPass, StiffnessTarget};
use element::{ElementOutput, TetRest, UpperScatter};
pub use material::{Material, MaterialModel, StrainStiffening};
pub use rest_compliance::RestCompliance;
pub use settings::{
    CgMatrix, FemSettings, LinearSolver, Preconditioner, RotationMethod, LAGGED_FACTOR_ITERATIONS,
};
pub use sparse::{BlockPattern, FactorPrecision, SparseCholesky};
use sparse::{UpperF32, NO_BLOCK};
use stiffening::StiffeningState;

/// Errors of the FEM model.
#[derive(Debug, thiserror::Error)]
pub enum FemError {
    #[error("FEM mesh: {0}")]
    Mesh(String),
    #[error("FEM material: {0}")]
    Material(String),
    #[error("FEM solver: {0}")]
    Solver(String),
    #[error("FEM input: {0}")]
    Input(String),
    #[error("FEM state diverged: {0}")]
    Diverged(String),
}

/// Result of one linear solve.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SolveStats {
    /// CG iterations (0 for the direct solver).
    pub iterations: usize,
    /// ‖b − A Δv‖ / ‖b‖ at exit (CG's own estimate).
    pub relative_residual: f64,
}

/// The FE model of one deformable body.
pub struct FemModel {
    material: Material,
    mu: f64,
    lambda: f64,
    settings: FemSettings,
    tets: Vec<[usize; 4]>,
    rest_elems: Vec<TetRest>,
    rest: Vec<Point3<f64>>,
    x: Vec<Point3<f64>>,
    v: Vec<Vector3<f64>>,
    x_free: Vec<Point3<f64>>,
    v_free: Vec<Vector3<f64>>,
    mass: Vec<f64>,
    /// Spring stiffness to the rest position per node (support), N/m: the secant stiffness
    /// of the committed state (`support_rest` stiffened, see `stiffening`).
    support: Vec<f64>,
    /// Support spring stiffness per node at rest, N/m (0: not supported).
    support_rest: Vec<f64>,
    /// Mean thickness of the body above its support (volume / supported area), m: the length
    /// that turns a support displacement into a strain.
    support_length: f64,
    /// Free row of each node, NO_BLOCK when held.
    free_index: Vec<u32>,
    free_nodes: Vec<usize>,
    /// Polar warm start per element (unused with QR).
    elem_rot: Vec<UnitQuaternion<f64>>,
    /// Rotation of each element at the last assembly.
    elem_rot_m: Vec<Matrix3<f64>>,
    node_rot_q: Vec<UnitQuaternion<f64>>,
    node_rot: Vec<Matrix3<f64>>,
    node_rot_sum: Vec<Matrix3<f64>>,
    pattern: BlockPattern,
    elem_blocks: Vec<[u32; 16]>,
    /// Per tet, its targets in `upper32` (the corotational element pass writes there).
    upper_scatter: Vec<UpperScatter>,
    /// The system for the direct solver (both triangles) and the cold paths (energies,
    /// static solves, rest factor).
    a: Vec<Matrix3<f64>>,
    /// The system the CG solver reads: its upper triangle packed in f32 (k_scale·K; the
    /// mass and support diagonal is its per-row shift).
    upper32: UpperF32,
    /// Rotation each element's blocks in `upper32` were built with.
    elem_rot_k: Vec<Matrix3<f64>>,
    /// k_scale the blocks in `upper32` were built for (NaN: not built, rebuild).
    upper32_k_scale: f64,
    /// Steps since `upper32` was last rebuilt from zero (bounds f32 drift of the updates).
    upper32_age: u32,
    /// Elements whose blocks were re-rotated in the last step (all of them on a rebuild).
    stiffness_updates: usize,
    jacobi: Vec<Matrix3<f64>>,
    force: Vec<Vector3<f64>>,
    rhs: Vec<f64>,
    dv: Vec<f64>,
    r: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
    z: Vec<f64>,
    /// Rest-state factor for the CG preconditioner, with the dt it was built for.
    rest_factor: Option<(f64, SparseCholesky)>,
    /// Factor of the current system for the direct solver (and the lagged-factor
    /// preconditioner).
    direct: Option<SparseCholesky>,
    /// Lagged-factor preconditioner: refactor `direct` before the next solve.
    refactor_lagged: bool,
    last_dt: f64,
    last_stats: SolveStats,
    /// Largest node displacement of the last committed step, m: how far the tissue still
    /// moves ([`FemModel::last_step_motion`]). Infinite until a step is committed, and again
    /// whenever the state or the material is set from outside.
    last_motion: f64,
    /// Strain-stiffening factors (all 1 with the linear law).
    stiffening: StiffeningState,
}

impl std::fmt::Debug for FemModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FemModel")
            .field("nodes", &self.x.len())
            .field("tets", &self.tets.len())
            .field("free_nodes", &self.free_nodes.len())
            .field("material", &self.material)
            .field("settings", &self.settings)
            .finish()
    }
}

/// Rotation extraction in the step: warm-started from last step, one or two iterations are
/// typical; 1e-7 rad is a spurious strain far below anything the contact resolves, and the
/// next step continues from there.
const ROTATION_ITERATIONS: usize = 4;
/// With in-place stiffness updates, the packed blocks are rebuilt from zero this often: each
/// update rounds to f32, and 256 of them stay below 1e-6 of a block.
const STIFFNESS_REBUILD_STEPS: u32 = 256;
const ROTATION_TOLERANCE: f64 = 1e-7;
/// Cold starts outside the step (energies, forces, static solves): converge fully.
const ROTATION_ITERATIONS_COLD: usize = 100;
const ROTATION_TOLERANCE_COLD: f64 = 1e-12;
