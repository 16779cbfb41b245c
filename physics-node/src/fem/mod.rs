//! Finite-element meniscus: linear corotational or stable neo-Hookean tetrahedra, lumped
//! mass, Rayleigh damping, gravity, implicit (backward) Euler, CG or sparse direct solve.
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

mod element;
pub mod material;
pub mod sparse;
mod stiffening;
pub mod test_meshes;

#[cfg(test)]
mod tests;

use launch_config::scene::SceneConfig;
use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};

use crate::mesh::TetMesh;
use element::{ElementOutput, TetRest, UpperScatter};
pub use material::{Material, MaterialModel, StrainStiffening};
pub use sparse::{BlockPattern, SparseCholesky};
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

/// CG preconditioner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preconditioner {
    /// Plain CG (SOFA's CGLinearSolver).
    None,
    /// Inverse of each node's 3×3 diagonal block.
    BlockJacobi,
    /// The rest-state system A0 factored once (refactored only if dt changes).
    RestCholesky,
    /// R A0⁻¹ Rᵀ with the per-node rotations (SOFA's WarpPreconditioner).
    WarpedRestCholesky,
}

/// How the corotational element finds its rotation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RotationMethod {
    /// SOFA's "large": Q of the QR decomposition of F (closed form, SOFA's default).
    Qr,
    /// Polar decomposition (nearest rotation, iterative, warm-started; rotation-invariant
    /// under shear).
    Polar,
}

impl RotationMethod {
    pub fn parse(s: &str) -> Option<RotationMethod> {
        match s.trim().to_ascii_lowercase().as_str() {
            "qr" | "large" => Some(RotationMethod::Qr),
            "polar" => Some(RotationMethod::Polar),
            _ => None,
        }
    }
}

/// Linear solver of the implicit step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinearSolver {
    Cg {
        max_iterations: usize,
        tolerance: f64,
        preconditioner: Preconditioner,
    },
    /// faer sparse Cholesky, numeric refactorization every step.
    Direct,
}

impl LinearSolver {
    /// SOFA's CG defaults: 25 iterations, tolerance 1e-9, no preconditioner.
    pub fn sofa_cg() -> Self {
        LinearSolver::Cg {
            max_iterations: 25,
            tolerance: 1e-9,
            preconditioner: Preconditioner::None,
        }
    }
}

/// Precision of the system matrix the CG products read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CgMatrix {
    /// Upper triangle packed in f32 (products accumulate in f64): half the memory the 26
    /// products of a step stream, so they run from L2 on the default meshes. Entries keep 7
    /// digits: right for SOFA's truncated CG, not for a CG asked to converge below ~1e-6.
    F32,
    /// Upper triangle in f64, for CG solves that must converge tightly.
    F64,
}

impl CgMatrix {
    pub fn parse(s: &str) -> Option<CgMatrix> {
        match s.trim().to_ascii_lowercase().as_str() {
            "f32" => Some(CgMatrix::F32),
            "f64" => Some(CgMatrix::F64),
            _ => None,
        }
    }
}

/// Settings of a [`FemModel`] besides mesh, material and fixed set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FemSettings {
    /// Nominal time step, s (used for the preconditioner factor; other dt refactor it).
    pub dt: f64,
    /// Gravity, m/s².
    pub gravity: Vector3<f64>,
    /// Rayleigh damping C = α M + β K: α (1/s), β (s).
    pub rayleigh_mass: f64,
    pub rayleigh_stiffness: f64,
    pub solver: LinearSolver,
    /// 0: fixed nodes held in place. > 0: fixed nodes attached by springs, N/m per node.
    pub support_stiffness: f64,
    /// Stable neo-Hookean: project the element Hessian to PSD (true) or use the consistent
    /// tangent (false; may be indefinite, use the direct solver then).
    pub project_tangent: bool,
    /// Rotation of the corotational elements (and of the per-node warp).
    pub rotation: RotationMethod,
    /// Precision of the matrix the CG solver multiplies with (unused by the direct solver).
    pub cg_matrix: CgMatrix,
    /// With the f32 CG matrix and corotational elements: an element's stiffness blocks are
    /// re-rotated only once its rotation has moved by more than this (max entry of R − R_K,
    /// ≈ rad) since they were built; 0 re-rotates every element every step (SOFA). Elastic
    /// forces always use the current rotation; only the implicit step's Jacobian lags.
    pub stiffness_rotation_tolerance: f64,
}

impl Default for FemSettings {
    fn default() -> Self {
        FemSettings {
            dt: 0.01,
            gravity: Vector3::new(0.0, 0.0, -9.81),
            rayleigh_mass: 0.0,
            rayleigh_stiffness: 0.0,
            solver: LinearSolver::sofa_cg(),
            support_stiffness: 0.0,
            project_tangent: true,
            rotation: RotationMethod::Qr,
            cg_matrix: CgMatrix::F32,
            stiffness_rotation_tolerance: 0.0,
        }
    }
}

impl FemSettings {
    /// Settings from a scene (`dt`, `gravity`, Rayleigh from `[material]`, `[solver]`,
    /// `support_stiffness` from `[meniscus]`).
    pub fn from_scene(scene: &SceneConfig) -> Result<Self, FemError> {
        let solver = match scene.solver.kind.trim().to_ascii_lowercase().as_str() {
            "cg" => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::None,
            },
            "cg-jacobi" => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::BlockJacobi,
            },
            "cg-cholesky" | "cg-rest-cholesky" => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::RestCholesky,
            },
            "cg-warped-cholesky" => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::WarpedRestCholesky,
            },
            "direct" => LinearSolver::Direct,
            other => {
                return Err(FemError::Input(format!(
                    "unknown solver kind `{other}` (expected `cg`, `cg-jacobi`, `cg-cholesky`, \
                     `cg-warped-cholesky` or `direct`)"
                )))
            }
        };
        let s = FemSettings {
            dt: scene.dt,
            gravity: Vector3::from(scene.gravity),
            rayleigh_mass: scene.material.rayleigh_mass,
            rayleigh_stiffness: scene.material.rayleigh_stiffness,
            solver,
            support_stiffness: scene.meniscus.support_stiffness,
            project_tangent: true,
            rotation: RotationMethod::parse(&scene.solver.rotation).ok_or_else(|| {
                FemError::Input(format!(
                    "unknown rotation `{}` (expected `qr` or `polar`)",
                    scene.solver.rotation
                ))
            })?,
            cg_matrix: CgMatrix::parse(&scene.solver.cg_matrix).ok_or_else(|| {
                FemError::Input(format!(
                    "unknown CG matrix precision `{}` (expected `f32` or `f64`)",
                    scene.solver.cg_matrix
                ))
            })?,
            stiffness_rotation_tolerance: scene.solver.stiffness_rotation_tolerance,
        };
        s.validate()?;
        Ok(s)
    }

    fn validate(&self) -> Result<(), FemError> {
        if !(self.dt.is_finite() && self.dt > 0.0) {
            return Err(FemError::Input(format!(
                "dt must be > 0 s, got {}",
                self.dt
            )));
        }
        if !self.gravity.iter().all(|g| g.is_finite()) {
            return Err(FemError::Input("gravity is not finite".into()));
        }
        for (name, v) in [
            ("rayleigh_mass", self.rayleigh_mass),
            ("rayleigh_stiffness", self.rayleigh_stiffness),
            ("support_stiffness", self.support_stiffness),
            (
                "stiffness_rotation_tolerance",
                self.stiffness_rotation_tolerance,
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(FemError::Input(format!("{name} must be ≥ 0, got {v}")));
            }
        }
        if self.stiffness_rotation_tolerance
            > launch_config::validate::MAX_STIFFNESS_ROTATION_TOLERANCE
        {
            return Err(FemError::Input(format!(
                "stiffness_rotation_tolerance {} rad is above {} rad (a stiffness matrix that \
                 never follows the rotations makes the implicit step diverge)",
                self.stiffness_rotation_tolerance,
                launch_config::validate::MAX_STIFFNESS_ROTATION_TOLERANCE
            )));
        }
        if let LinearSolver::Cg {
            max_iterations,
            tolerance,
            ..
        } = self.solver
        {
            if max_iterations == 0 || !(tolerance.is_finite() && tolerance >= 0.0) {
                return Err(FemError::Input(format!(
                    "CG needs ≥ 1 iteration and a tolerance ≥ 0 (got {max_iterations}, {tolerance})"
                )));
            }
        }
        Ok(())
    }
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
    /// Spring stiffness to the rest position per node (support), N/m.
    support: Vec<f64>,
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
    /// Factor of the current system for the direct solver.
    direct: Option<SparseCholesky>,
    last_dt: f64,
    last_stats: SolveStats,
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

impl FemModel {
    /// Builds the model. `fixed` are held in place, or supported by springs when
    /// `settings.support_stiffness > 0`.
    pub fn new(
        mesh: &TetMesh,
        material: Material,
        fixed: &[usize],
        settings: FemSettings,
    ) -> Result<Self, FemError> {
        material.validate()?;
        settings.validate()?;
        let n = mesh.nodes.len();
        if n == 0 || mesh.tets.is_empty() {
            return Err(FemError::Mesh(format!(
                "mesh has {n} nodes and {} tets; need at least one tet",
                mesh.tets.len()
            )));
        }
        for (i, p) in mesh.nodes.iter().enumerate() {
            if !p.iter().all(|c| c.is_finite()) {
                return Err(FemError::Mesh(format!(
                    "node {i} has a non-finite coordinate"
                )));
            }
        }
        let mut rest_elems = Vec::with_capacity(mesh.tets.len());
        let mut mass = vec![0.0; n];
        for (e, t) in mesh.tets.iter().enumerate() {
            if let Some(&bad) = t.iter().find(|&&i| i >= n) {
                return Err(FemError::Mesh(format!(
                    "tet {e} refers to node {bad}, but the mesh has {n} nodes"
                )));
            }
            let r = TetRest::new([
                &mesh.nodes[t[0]],
                &mesh.nodes[t[1]],
                &mesh.nodes[t[2]],
                &mesh.nodes[t[3]],
            ])
            .ok_or_else(|| {
                FemError::Mesh(format!(
                    "tet {e} {t:?} has zero or negative volume (orient tets positively)"
                ))
            })?;
            for &i in t {
                mass[i] += material.density * r.volume / 4.0;
            }
            rest_elems.push(r);
        }
        let mut held = vec![false; n];
        let mut support = vec![0.0; n];
        for &i in fixed {
            if i >= n {
                return Err(FemError::Input(format!(
                    "fixed node {i} out of range (mesh has {n} nodes)"
                )));
            }
            if settings.support_stiffness > 0.0 {
                support[i] = settings.support_stiffness;
            } else {
                held[i] = true;
            }
        }
        let mut free_index = vec![NO_BLOCK; n];
        let mut free_nodes = Vec::new();
        for i in 0..n {
            // A node in no tet has no mass: hold it so the system stays definite.
            if !held[i] && mass[i] > 0.0 {
                free_index[i] = free_nodes.len() as u32;
                free_nodes.push(i);
            }
        }
        let nf = free_nodes.len();
        let (pattern, elem_blocks) = BlockPattern::from_tets(&free_index, nf, &mesh.tets);
        let nnz = pattern.nnz_blocks();
        let upper32 = UpperF32::new(&pattern);
        let upper_scatter = upper32.scatter(&pattern, &free_index, &mesh.tets, &elem_blocks);
        let (mu, lambda) = material.lame();
        let stiffening = StiffeningState::new(StrainStiffening::NONE, &mesh.tets, &rest_elems, n);
        let mut model = FemModel {
            material,
            mu,
            lambda,
            settings,
            tets: mesh.tets.clone(),
            rest_elems,
            rest: mesh.nodes.clone(),
            x: mesh.nodes.clone(),
            v: vec![Vector3::zeros(); n],
            x_free: mesh.nodes.clone(),
            v_free: vec![Vector3::zeros(); n],
            mass,
            support,
            free_index,
            free_nodes,
            elem_rot: vec![UnitQuaternion::identity(); mesh.tets.len()],
            elem_rot_m: vec![Matrix3::identity(); mesh.tets.len()],
            node_rot_q: vec![UnitQuaternion::identity(); n],
            node_rot: vec![Matrix3::identity(); n],
            node_rot_sum: vec![Matrix3::zeros(); n],
            pattern,
            elem_blocks,
            upper_scatter,
            a: vec![Matrix3::zeros(); nnz],
            upper32,
            elem_rot_k: vec![Matrix3::identity(); mesh.tets.len()],
            upper32_k_scale: f64::NAN,
            upper32_age: 0,
            stiffness_updates: 0,
            jacobi: vec![Matrix3::zeros(); nf],
            force: vec![Vector3::zeros(); n],
            rhs: vec![0.0; 3 * nf],
            dv: vec![0.0; 3 * nf],
            r: vec![0.0; 3 * nf],
            p: vec![0.0; 3 * nf],
            q: vec![0.0; 3 * nf],
            z: vec![0.0; 3 * nf],
            rest_factor: None,
            direct: None,
            last_dt: settings.dt,
            last_stats: SolveStats::default(),
            stiffening,
        };
        model.prepare_solver()?;
        Ok(model)
    }

    /// Builds whatever factorization the chosen solver needs (allocates; not in the step).
    fn prepare_solver(&mut self) -> Result<(), FemError> {
        if self.free_nodes.is_empty() {
            return Ok(());
        }
        match self.settings.solver {
            LinearSolver::Cg {
                preconditioner: Preconditioner::RestCholesky | Preconditioner::WarpedRestCholesky,
                ..
            } => {
                let dt = self.settings.dt;
                self.assemble_rest_system(dt);
                self.rest_factor = Some((dt, SparseCholesky::new(&self.pattern, &self.a, 1)?));
            }
            LinearSolver::Direct => {
                let dt = self.settings.dt;
                self.assemble_rest_system(dt);
                self.direct = Some(SparseCholesky::new(&self.pattern, &self.a, 1)?);
            }
            _ => {}
        }
        Ok(())
    }

    // ---- accessors -------------------------------------------------------------------

    pub fn material(&self) -> &Material {
        &self.material
    }
    pub fn settings(&self) -> &FemSettings {
        &self.settings
    }
    pub fn node_count(&self) -> usize {
        self.x.len()
    }
    pub fn tet_count(&self) -> usize {
        self.tets.len()
    }
    pub fn tets(&self) -> &[[usize; 4]] {
        &self.tets
    }
    /// Committed positions, m.
    pub fn positions(&self) -> &[Point3<f64>] {
        &self.x
    }
    /// Committed velocities, m/s.
    pub fn velocities(&self) -> &[Vector3<f64>] {
        &self.v
    }
    /// Rest positions, m.
    pub fn rest_positions(&self) -> &[Point3<f64>] {
        &self.rest
    }
    /// Free-motion (plus applied corrections) positions of the step in progress.
    pub fn free_positions(&self) -> &[Point3<f64>] {
        &self.x_free
    }
    pub fn free_velocities(&self) -> &[Vector3<f64>] {
        &self.v_free
    }
    /// Lumped nodal masses, kg.
    pub fn masses(&self) -> &[f64] {
        &self.mass
    }
    /// Free (simulated) row of a node in the reduced system, None when held.
    pub fn free_index(&self, node: usize) -> Option<usize> {
        match self.free_index.get(node) {
            Some(&i) if i != NO_BLOCK => Some(i as usize),
            _ => None,
        }
    }
    /// Nodes in the reduced system, in row order.
    pub fn free_nodes(&self) -> &[usize] {
        &self.free_nodes
    }
    pub fn is_held(&self, node: usize) -> bool {
        self.free_index(node).is_none()
    }
    /// Statistics of the last linear solve.
    /// Elements whose stiffness blocks the last step wrote (all on a rebuild; see
    /// [`FemSettings::stiffness_rotation_tolerance`]); 0 outside the packed CG path.
    pub fn stiffness_updates(&self) -> usize {
        self.stiffness_updates
    }

    pub fn last_solve(&self) -> SolveStats {
        self.last_stats
    }
    /// Block pattern of the reduced system.
    pub fn pattern(&self) -> &BlockPattern {
        &self.pattern
    }

    /// Replaces the material (e.g. a new degeneration grade between probings). Same model
    /// kind keeps all factorizations' patterns; rest factors are rebuilt (allocates).
    pub fn set_material(&mut self, material: Material) -> Result<(), FemError> {
        material.validate()?;
        // Lumped mass follows density.
        let scale = material.density / self.material.density;
        for m in &mut self.mass {
            *m *= scale;
        }
        self.material = material;
        let (mu, lambda) = material.lame();
        self.mu = mu;
        self.lambda = lambda;
        self.upper32_k_scale = f64::NAN;
        self.prepare_solver()
    }

    /// Sets the strain-stiffening law (see [`StrainStiffening`]); the factors follow from the
    /// next step's committed state.
    pub fn set_stiffening(&mut self, law: StrainStiffening) {
        self.stiffening.law = law;
        self.stiffening.reset();
        self.upper32_k_scale = f64::NAN;
    }

    pub fn stiffening(&self) -> StrainStiffening {
        self.stiffening.law
    }

    /// Modulus factor per node (volume-weighted mean of its elements') of the committed state
    /// at the last `free_motion`; all 1 with the linear law.
    pub fn node_stiffening(&self) -> &[f64] {
        &self.stiffening.node
    }

    /// Modulus factor per element at the last `free_motion`.
    pub fn element_stiffening(&self) -> &[f64] {
        &self.stiffening.elem
    }

    /// Sets a node's committed position (kinematic held nodes, test set-ups) and free position.
    pub fn set_position(&mut self, node: usize, p: Point3<f64>) -> Result<(), FemError> {
        if node >= self.x.len() || !p.iter().all(|c| c.is_finite()) {
            return Err(FemError::Input(format!(
                "set_position: bad node {node} or position"
            )));
        }
        self.x[node] = p;
        self.x_free[node] = p;
        Ok(())
    }

    /// Sets a free node's committed velocity.
    pub fn set_velocity(&mut self, node: usize, v: Vector3<f64>) -> Result<(), FemError> {
        if node >= self.x.len() || !v.iter().all(|c| c.is_finite()) {
            return Err(FemError::Input(format!(
                "set_velocity: bad node {node} or velocity"
            )));
        }
        if self.free_index(node).is_some() {
            self.v[node] = v;
            self.v_free[node] = v;
        }
        Ok(())
    }

    /// Back to rest: positions, velocities, rotations and warm start reset.
    pub fn reset(&mut self) {
        self.x.copy_from_slice(&self.rest);
        self.x_free.copy_from_slice(&self.rest);
        self.v.fill(Vector3::zeros());
        self.v_free.fill(Vector3::zeros());
        self.elem_rot.fill(UnitQuaternion::identity());
        self.elem_rot_m.fill(Matrix3::identity());
        self.node_rot_q.fill(UnitQuaternion::identity());
        self.node_rot.fill(Matrix3::identity());
        self.dv.fill(0.0);
        self.upper32_k_scale = f64::NAN;
        self.stiffening.reset();
    }

    // ---- assembly --------------------------------------------------------------------

    /// The CG system lives in `upper32` (f32), not in the upper triangle of `a`.
    fn packed_cg_matrix(&self) -> bool {
        matches!(self.settings.solver, LinearSolver::Cg { .. })
            && self.settings.cg_matrix == CgMatrix::F32
    }

    /// One pass over the elements at positions `self.x` (or at rest): elastic forces into
    /// `self.force`, and `k_scale · K`. `full`: both triangles into `self.a` (Cholesky
    /// gathers the lower one); otherwise the diagonal and upper blocks into `self.upper32`,
    /// which is all the CG product reads.
    fn assemble(&mut self, at_rest: bool, k_scale: f64, want_k: bool, full: bool) {
        self.assemble_with(
            at_rest,
            k_scale,
            want_k,
            full,
            ROTATION_ITERATIONS,
            ROTATION_TOLERANCE,
        )
    }

    fn assemble_with(
        &mut self,
        at_rest: bool,
        k_scale: f64,
        want_k: bool,
        full: bool,
        rot_iters: usize,
        rot_tol: f64,
    ) {
        let FemModel {
            tets,
            rest_elems,
            x,
            rest,
            elem_rot,
            elem_rot_m,
            a,
            force,
            elem_blocks,
            upper_scatter,
            upper32,
            elem_rot_k,
            upper32_k_scale,
            upper32_age,
            stiffness_updates,
            pattern,
            free_index,
            material,
            mu,
            lambda,
            settings,
            stiffening,
            ..
        } = self;
        // The rest system stays linear (it is the reference of the warped compliance).
        let stiff_active = !at_rest && stiffening.law.is_active();
        let (mu, lambda) = (*mu, *lambda);
        force.fill(Vector3::zeros());
        // The common case (corotational, f32 CG matrix) writes its blocks straight into the
        // packed upper triangle from a scatter map built once; other materials assemble into
        // `a` and are packed afterwards.
        let packed = !full && settings.cg_matrix == CgMatrix::F32;
        let fused = want_k && packed && material.model == MaterialModel::Corotational;
        if want_k && !fused {
            if full {
                a.fill(Matrix3::zeros());
            } else {
                for (&d, &end) in pattern.diag.iter().zip(&pattern.row_ptr[1..]) {
                    a[d..end].fill(Matrix3::zeros());
                }
            }
        }
        let pos: &[Point3<f64>] = if at_rest { rest } else { x };
        if fused {
            // Rebuild from zero when the blocks are missing, for another dt, or old enough
            // that the f32 round-off of their in-place updates could add up; otherwise
            // re-rotate only the elements that turned.
            let rebuild = !(*upper32_k_scale == k_scale)
                || *upper32_age >= STIFFNESS_REBUILD_STEPS
                || settings.stiffness_rotation_tolerance <= 0.0;
            if rebuild {
                upper32.clear();
                *upper32_k_scale = k_scale;
                *upper32_age = 0;
            } else {
                *upper32_age += 1;
            }
            *stiffness_updates = CorotationalUpperPass {
                tets,
                rest_elems,
                pos,
                rotation: if at_rest {
                    None
                } else {
                    Some((settings.rotation, rot_iters, rot_tol))
                },
                elem_rot,
                elem_rot_m,
                mu,
                lambda,
                k_scale,
                upper_scatter,
                blocks: upper32.blocks_mut(),
                force,
                elem_rot_k,
                rebuild,
                tolerance: settings.stiffness_rotation_tolerance,
                scale: if stiff_active { &stiffening.elem } else { &[] },
                scale_k: &mut stiffening.elem_k,
            }
            .run();
            return;
        }
        let mut out = ElementOutput::zero();
        for (e, t) in tets.iter().enumerate() {
            let re = &rest_elems[e];
            let xe = [
                pos[t[0]].coords,
                pos[t[1]].coords,
                pos[t[2]].coords,
                pos[t[3]].coords,
            ];
            let f = re.deformation_gradient(xe);
            // Both materials keep the element rotation: the corotational element works in it,
            // and the warped compliance averages it per node.
            let rot = if at_rest {
                Matrix3::identity()
            } else {
                let r = element_rotation(
                    settings.rotation,
                    &f,
                    &mut elem_rot[e],
                    &elem_rot_m[e],
                    rot_iters,
                    rot_tol,
                );
                elem_rot_m[e] = r;
                r
            };
            let (mu, lambda) = if stiff_active {
                (mu * stiffening.elem[e], lambda * stiffening.elem[e])
            } else {
                (mu, lambda)
            };
            match material.model {
                MaterialModel::Corotational => {
                    element::corotational(re, &f, &rot, mu, lambda, want_k, &mut out);
                }
                MaterialModel::StableNeoHookean => {
                    element::stable_neo_hookean(
                        re,
                        &f,
                        mu,
                        lambda,
                        settings.project_tangent,
                        want_k,
                        &mut out,
                    );
                }
            }
            for k in 0..4 {
                force[t[k]] += out.force[k];
            }
            if !want_k {
                continue;
            }
            let eb = &elem_blocks[e];
            for ia in 0..4 {
                for ib in ia..4 {
                    let kab = &out.k[ia][ib];
                    let idx = eb[ia * 4 + ib];
                    if idx == NO_BLOCK {
                        continue;
                    }
                    if ia == ib {
                        a[idx as usize] += kab * k_scale;
                        continue;
                    }
                    let kba = kab.transpose();
                    if full {
                        a[idx as usize] += kab * k_scale;
                        a[eb[ib * 4 + ia] as usize] += kba * k_scale;
                    } else if free_index[t[ia]] < free_index[t[ib]] {
                        a[idx as usize] += kab * k_scale;
                    } else {
                        a[eb[ib * 4 + ia] as usize] += kba * k_scale;
                    }
                }
            }
        }
        if want_k && packed {
            upper32.pack(pattern, a);
            // Packed from a full assembly: not blocks the element pass may update in place.
            *upper32_k_scale = f64::NAN;
        }
    }

    /// A0 = M + h C0 + h² K0 at rest into `self.a`.
    fn assemble_rest_system(&mut self, dt: f64) {
        let (alpha, beta) = (
            self.settings.rayleigh_mass,
            self.settings.rayleigh_stiffness,
        );
        let k_scale = dt * beta + dt * dt;
        self.assemble(true, k_scale, true, true);
        for (row, &node) in self.free_nodes.iter().enumerate() {
            let d = (1.0 + dt * alpha) * self.mass[node] + k_scale * self.support[node];
            let blk = &mut self.a[self.pattern.diag[row]];
            blk[(0, 0)] += d;
            blk[(1, 1)] += d;
            blk[(2, 2)] += d;
        }
    }

    // ---- stepping --------------------------------------------------------------------

    /// Free motion over `dt` with per-node external forces (N; held nodes ignore theirs):
    /// one linearized backward-Euler step from the committed state into the free state.
    /// Does not allocate.
    pub fn free_motion(
        &mut self,
        dt: f64,
        external_forces: &[Vector3<f64>],
    ) -> Result<SolveStats, FemError> {
        let n = self.x.len();
        if external_forces.len() != n {
            return Err(FemError::Input(format!(
                "{} external forces for {n} nodes",
                external_forces.len()
            )));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(FemError::Input(format!("dt must be > 0 s, got {dt}")));
        }
        self.last_dt = dt;
        // Secant modulus factors of the committed state (no-op for the linear law).
        self.stiffening
            .update(&self.tets, &self.rest_elems, &self.x, &self.elem_rot_m);
        let (alpha, beta) = (
            self.settings.rayleigh_mass,
            self.settings.rayleigh_stiffness,
        );
        let k_scale = dt * beta + dt * dt;
        // CG reads only the upper triangle; the direct solver factors the lower one.
        let full = matches!(self.settings.solver, LinearSolver::Direct);
        self.assemble(false, k_scale, true, full);
        // K·v for the implicit damping and stiffness terms, from the assembled k_scale·K
        // (before the mass goes on the diagonal): one sparse product instead of two 3×3
        // products per element block during assembly.
        for (row, &node) in self.free_nodes.iter().enumerate() {
            let vi = self.v[node];
            self.z[3 * row] = vi.x;
            self.z[3 * row + 1] = vi.y;
            self.z[3 * row + 2] = vi.z;
        }
        let packed = self.packed_cg_matrix();
        if packed {
            self.upper32.mul_dot(&self.z, &mut self.q, false);
        } else {
            self.pattern.mul_dot_upper(&self.a, &self.z, &mut self.q);
        }
        let inv_k_scale = 1.0 / k_scale;
        let g = self.settings.gravity;
        for (row, &node) in self.free_nodes.iter().enumerate() {
            let m = self.mass[node];
            let ks = self.support[node];
            let d = (1.0 + dt * alpha) * m + k_scale * ks;
            if packed {
                self.upper32.set_shift(row, d);
            } else {
                let blk = &mut self.a[self.pattern.diag[row]];
                blk[(0, 0)] += d;
                blk[(1, 1)] += d;
                blk[(2, 2)] += d;
            }
            let vi = self.v[node];
            let disp = self.x[node] - self.rest[node];
            let f = external_forces[node] + self.force[node] + g * m
                - vi * (alpha * m)
                - (Vector3::new(self.q[3 * row], self.q[3 * row + 1], self.q[3 * row + 2])
                    * inv_k_scale
                    + vi * ks)
                    * (beta + dt)
                - disp * ks;
            let b = f * dt;
            self.rhs[3 * row] = b.x;
            self.rhs[3 * row + 1] = b.y;
            self.rhs[3 * row + 2] = b.z;
        }
        let stats = self.solve_system(dt)?;
        self.last_stats = stats;
        // Free state: held nodes stay where they are.
        self.x_free.copy_from_slice(&self.x);
        self.v_free.fill(Vector3::zeros());
        for (row, &node) in self.free_nodes.iter().enumerate() {
            let dv = Vector3::new(self.dv[3 * row], self.dv[3 * row + 1], self.dv[3 * row + 2]);
            let v = self.v[node] + dv;
            if !v.iter().all(|c| c.is_finite()) {
                return Err(FemError::Diverged(format!(
                    "non-finite velocity at node {node} after the implicit solve"
                )));
            }
            self.v_free[node] = v;
            self.x_free[node] = self.x[node] + v * dt;
        }
        Ok(stats)
    }

    /// Constraint correction: moves the given nodes of the free state by dx (m) and changes
    /// their velocity by dx/dt (dt of the last free motion), consistent with x = x₀ + dt·v.
    /// Held nodes are left in place.
    pub fn apply_correction(&mut self, node_dx: &[(usize, Vector3<f64>)]) -> Result<(), FemError> {
        let inv_dt = 1.0 / self.last_dt;
        for &(node, dx) in node_dx {
            if node >= self.x.len() {
                return Err(FemError::Input(format!(
                    "correction for node {node} out of range"
                )));
            }
            if self.free_index[node] == NO_BLOCK {
                continue;
            }
            self.x_free[node] += dx;
            self.v_free[node] += dx * inv_dt;
        }
        Ok(())
    }

    /// Constraint correction from a full vector (3 per node, m).
    pub fn apply_correction_full(&mut self, dx: &[f64]) -> Result<(), FemError> {
        if dx.len() != 3 * self.x.len() {
            return Err(FemError::Input(format!(
                "correction vector has {} entries, expected {}",
                dx.len(),
                3 * self.x.len()
            )));
        }
        let inv_dt = 1.0 / self.last_dt;
        for &node in &self.free_nodes {
            let d = Vector3::new(dx[3 * node], dx[3 * node + 1], dx[3 * node + 2]);
            self.x_free[node] += d;
            self.v_free[node] += d * inv_dt;
        }
        Ok(())
    }

    /// The free (and corrected) state becomes the committed state.
    pub fn commit(&mut self) {
        self.x.copy_from_slice(&self.x_free);
        self.v.copy_from_slice(&self.v_free);
    }

    /// `free_motion` then `commit` (no contact).
    pub fn step(
        &mut self,
        dt: f64,
        external_forces: &[Vector3<f64>],
    ) -> Result<SolveStats, FemError> {
        let s = self.free_motion(dt, external_forces)?;
        self.commit();
        Ok(s)
    }

    fn solve_system(&mut self, dt: f64) -> Result<SolveStats, FemError> {
        if self.free_nodes.is_empty() {
            return Ok(SolveStats::default());
        }
        match self.settings.solver {
            LinearSolver::Direct => {
                let chol = self
                    .direct
                    .as_mut()
                    .ok_or_else(|| FemError::Solver("direct solver not prepared".into()))?;
                chol.refactor(&self.a)?;
                self.dv.copy_from_slice(&self.rhs);
                chol.solve_in_place(&mut self.dv);
                Ok(SolveStats {
                    iterations: 0,
                    relative_residual: 0.0,
                })
            }
            LinearSolver::Cg {
                max_iterations,
                tolerance,
                preconditioner,
            } => {
                match preconditioner {
                    Preconditioner::BlockJacobi => {
                        let packed = self.packed_cg_matrix();
                        for (row, inv) in self.jacobi.iter_mut().enumerate() {
                            let d = if packed {
                                self.upper32.diagonal_block(row, true)
                            } else {
                                self.a[self.pattern.diag[row]]
                            };
                            *inv = d.try_inverse().unwrap_or_else(Matrix3::identity);
                        }
                    }
                    Preconditioner::RestCholesky | Preconditioner::WarpedRestCholesky => {
                        let stale = match &self.rest_factor {
                            Some((fdt, _)) => *fdt != dt,
                            None => true,
                        };
                        if stale {
                            self.refactor_rest_preconditioner(dt)?;
                        }
                        if preconditioner == Preconditioner::WarpedRestCholesky {
                            self.update_node_rotations();
                        }
                    }
                    Preconditioner::None => {}
                }
                Ok(self.cg(max_iterations, tolerance, preconditioner))
            }
        }
    }

    /// Refactors the rest preconditioner for another dt (numeric only; keeps `self.a`).
    fn refactor_rest_preconditioner(&mut self, dt: f64) -> Result<(), FemError> {
        // The rest system needs its own value array: build it in a copy of `a` swapped in
        // and out (allocates, but only when dt differs from the nominal one).
        let current = std::mem::take(&mut self.a);
        self.a = current.clone();
        self.assemble_rest_system(dt);
        let res = match &mut self.rest_factor {
            Some((fdt, chol)) => {
                *fdt = dt;
                chol.refactor(&self.a)
            }
            None => SparseCholesky::new(&self.pattern, &self.a, 1).map(|c| {
                self.rest_factor = Some((dt, c));
            }),
        };
        self.a = current;
        // assemble() overwrote `force`, but the right-hand side is already built.
        res
    }

    /// z = P⁻¹ r.
    fn precondition(&mut self, pc: Preconditioner) {
        match pc {
            Preconditioner::None => self.z.copy_from_slice(&self.r),
            Preconditioner::BlockJacobi => {
                for (row, inv) in self.jacobi.iter().enumerate() {
                    let r = Vector3::new(self.r[3 * row], self.r[3 * row + 1], self.r[3 * row + 2]);
                    let z = inv * r;
                    self.z[3 * row] = z.x;
                    self.z[3 * row + 1] = z.y;
                    self.z[3 * row + 2] = z.z;
                }
            }
            Preconditioner::RestCholesky | Preconditioner::WarpedRestCholesky => {
                let warped = pc == Preconditioner::WarpedRestCholesky;
                for (row, &node) in self.free_nodes.iter().enumerate() {
                    let r = Vector3::new(self.r[3 * row], self.r[3 * row + 1], self.r[3 * row + 2]);
                    let z = if warped {
                        self.node_rot[node].transpose() * r
                    } else {
                        r
                    };
                    self.z[3 * row] = z.x;
                    self.z[3 * row + 1] = z.y;
                    self.z[3 * row + 2] = z.z;
                }
                if let Some((_, chol)) = &mut self.rest_factor {
                    chol.solve_in_place(&mut self.z);
                }
                if warped {
                    for (row, &node) in self.free_nodes.iter().enumerate() {
                        let z = self.node_rot[node]
                            * Vector3::new(
                                self.z[3 * row],
                                self.z[3 * row + 1],
                                self.z[3 * row + 2],
                            );
                        self.z[3 * row] = z.x;
                        self.z[3 * row + 1] = z.y;
                        self.z[3 * row + 2] = z.z;
                    }
                }
            }
        }
    }

    /// Preconditioned CG on A Δv = rhs from Δv = 0 (SOFA's default, `warmStart` off). A warm
    /// start from the previous Δv extrapolates the last step's acceleration: with the
    /// iteration cap binding (always, at tolerance 1e-9) that made plain 25-iteration CG
    /// unstable under contact on the study's medial mesh and 10-iteration CG on the
    /// 2,560-node default; from zero, a truncated solve only under-resolves (dissipates).
    /// Products read the upper triangle: packed in f32 (`self.upper32`) or in `self.a`.
    fn cg(&mut self, max_iter: usize, tol: f64, pc: Preconditioner) -> SolveStats {
        let packed = self.packed_cg_matrix();
        self.dv.fill(0.0);
        let b_norm = dot(&self.rhs, &self.rhs).sqrt();
        if b_norm == 0.0 {
            return SolveStats::default();
        }
        // r = b − A·0
        self.r.copy_from_slice(&self.rhs);
        let mut r_norm = b_norm;
        let mut iterations = 0;
        if r_norm / b_norm <= tol {
            return SolveStats {
                iterations,
                relative_residual: r_norm / b_norm,
            };
        }
        // Unpreconditioned: z = r, so skip the copy and reuse r·r for r·z.
        let plain = pc == Preconditioner::None;
        let mut rz = if plain {
            self.p.copy_from_slice(&self.r);
            dot(&self.r, &self.r)
        } else {
            self.precondition(pc);
            self.p.copy_from_slice(&self.z);
            dot(&self.r, &self.z)
        };
        while iterations < max_iter {
            iterations += 1;
            let pq = if packed {
                self.upper32.mul_dot(&self.p, &mut self.q, true)
            } else {
                self.pattern.mul_dot_upper(&self.a, &self.p, &mut self.q)
            };
            if !(pq > 0.0) {
                break;
            }
            let alpha = rz / pq;
            let mut rr = 0.0;
            for (((dv, r), p), q) in self
                .dv
                .iter_mut()
                .zip(self.r.iter_mut())
                .zip(&self.p)
                .zip(&self.q)
            {
                *dv += alpha * p;
                *r -= alpha * q;
                rr += *r * *r;
            }
            r_norm = rr.sqrt();
            if r_norm / b_norm <= tol {
                break;
            }
            let rz_new = if plain {
                rr
            } else {
                self.precondition(pc);
                dot(&self.r, &self.z)
            };
            let beta = rz_new / rz;
            rz = rz_new;
            let z: &[f64] = if plain { &self.r } else { &self.z };
            for (p, z) in self.p.iter_mut().zip(z) {
                *p = z + beta * *p;
            }
        }
        SolveStats {
            iterations,
            relative_residual: r_norm / b_norm,
        }
    }

    // ---- rotations, energies, compliance ----------------------------------------------

    /// Element rotations of the last assembly (corotational frame per tet).
    pub fn element_rotation(&self, tet: usize) -> Option<Matrix3<f64>> {
        self.elem_rot_m.get(tet).copied()
    }

    /// Recomputes per-node rotations: the average of the incident element rotations,
    /// orthonormalised (nearest rotation, warm-started). No allocation.
    pub fn update_node_rotations(&mut self) {
        self.node_rot_sum.fill(Matrix3::zeros());
        for (t, r) in self.tets.iter().zip(&self.elem_rot_m) {
            for &i in t {
                self.node_rot_sum[i] += r;
            }
        }
        for i in 0..self.x.len() {
            self.node_rot[i] = element_rotation(
                self.settings.rotation,
                &self.node_rot_sum[i],
                &mut self.node_rot_q[i],
                &self.node_rot[i],
                ROTATION_ITERATIONS,
                ROTATION_TOLERANCE,
            );
        }
    }

    /// Per-node rotations as of the last [`Self::update_node_rotations`] (which uses the
    /// element rotations of the last `free_motion`, i.e. of the committed state).
    pub fn node_rotations(&self) -> &[Matrix3<f64>] {
        &self.node_rot
    }

    /// Elastic strain energy of the committed state, J (plus support springs).
    pub fn elastic_energy(&mut self) -> f64 {
        let mut total = 0.0;
        let mut out = ElementOutput::zero();
        for (e, t) in self.tets.iter().enumerate() {
            let re = &self.rest_elems[e];
            let f = re.deformation_gradient([
                self.x[t[0]].coords,
                self.x[t[1]].coords,
                self.x[t[2]].coords,
                self.x[t[3]].coords,
            ]);
            match self.material.model {
                MaterialModel::Corotational => {
                    let mut q = self.elem_rot[e];
                    let rot = element_rotation(
                        self.settings.rotation,
                        &f,
                        &mut q,
                        &self.elem_rot_m[e],
                        ROTATION_ITERATIONS_COLD,
                        ROTATION_TOLERANCE_COLD,
                    );
                    element::corotational(re, &f, &rot, self.mu, self.lambda, false, &mut out);
                }
                MaterialModel::StableNeoHookean => {
                    element::stable_neo_hookean(
                        re,
                        &f,
                        self.mu,
                        self.lambda,
                        false,
                        false,
                        &mut out,
                    );
                }
            }
            total += out.energy;
        }
        for i in 0..self.x.len() {
            total += 0.5 * self.support[i] * (self.x[i] - self.rest[i]).norm_squared();
        }
        total
    }

    /// Kinetic energy of the committed state, J.
    pub fn kinetic_energy(&self) -> f64 {
        self.v
            .iter()
            .zip(&self.mass)
            .map(|(v, m)| 0.5 * m * v.norm_squared())
            .sum()
    }

    /// Gravitational potential energy −Σ m g·x, J.
    pub fn gravity_energy(&self) -> f64 {
        self.x
            .iter()
            .zip(&self.mass)
            .map(|(x, m)| -m * self.settings.gravity.dot(&x.coords))
            .sum()
    }

    /// Elastic nodal forces at the committed positions (N), written to `out` (len = nodes).
    pub fn elastic_forces(&mut self, out: &mut [Vector3<f64>]) -> Result<(), FemError> {
        if out.len() != self.x.len() {
            return Err(FemError::Input(
                "elastic_forces: wrong output length".into(),
            ));
        }
        self.assemble_with(
            false,
            0.0,
            false,
            true,
            ROTATION_ITERATIONS_COLD,
            ROTATION_TOLERANCE_COLD,
        );
        for i in 0..out.len() {
            out[i] = self.force[i] - (self.x[i] - self.rest[i]) * self.support[i];
        }
        Ok(())
    }

    /// Factors the rest-state system A0 = M + dt C0 + dt² K0 once, for precomputed
    /// constraint correction. `max_block_columns`: widest block solved without allocating.
    pub fn rest_compliance(
        &mut self,
        dt: f64,
        max_block_columns: usize,
    ) -> Result<RestCompliance, FemError> {
        if !(dt.is_finite() && dt > 0.0) {
            return Err(FemError::Input(format!("dt must be > 0 s, got {dt}")));
        }
        if self.free_nodes.is_empty() {
            return Err(FemError::Input("every node is held: no compliance".into()));
        }
        let saved = self.a.clone();
        self.assemble_rest_system(dt);
        let chol = SparseCholesky::new(&self.pattern, &self.a, max_block_columns);
        self.a = saved;
        let cols = max_block_columns.max(1);
        Ok(RestCompliance {
            chol: chol?,
            free_index: self.free_index.clone(),
            free_nodes: self.free_nodes.clone(),
            n_nodes: self.x.len(),
            max_cols: cols,
            scratch: vec![0.0; 3 * self.free_nodes.len() * cols],
            dt,
        })
    }

    /// Quasi-static equilibrium under `external_forces` (+ gravity if `with_gravity`) by
    /// Newton iterations on K Δx = f with a direct solve (allocates; for set-up and tests).
    /// Converged when the largest update is below `tolerance` × the mesh's size. Returns
    /// the number of Newton iterations.
    pub fn solve_static(
        &mut self,
        external_forces: &[Vector3<f64>],
        with_gravity: bool,
        max_iterations: usize,
        tolerance: f64,
    ) -> Result<usize, FemError> {
        let n = self.x.len();
        if external_forces.len() != n {
            return Err(FemError::Input(format!(
                "{} external forces for {n} nodes",
                external_forces.len()
            )));
        }
        if self.free_nodes.is_empty() {
            return Ok(0);
        }
        let (mut lo, mut hi) = (self.rest[0].coords, self.rest[0].coords);
        for p in &self.rest {
            lo = lo.inf(&p.coords);
            hi = hi.sup(&p.coords);
        }
        let size = (hi - lo).norm();
        let saved_v = self.v.clone();
        self.v.fill(Vector3::zeros());
        let mut chol: Option<SparseCholesky> = None;
        let mut rhs = vec![0.0; 3 * self.free_nodes.len()];
        let g = if with_gravity {
            self.settings.gravity
        } else {
            Vector3::zeros()
        };
        let mut result = Err(FemError::Solver(format!(
            "static solve did not converge in {max_iterations} Newton iterations"
        )));
        for it in 1..=max_iterations {
            self.assemble_with(
                false,
                1.0,
                true,
                true,
                ROTATION_ITERATIONS_COLD,
                ROTATION_TOLERANCE_COLD,
            );
            for (row, &node) in self.free_nodes.iter().enumerate() {
                let ks = self.support[node];
                let blk = &mut self.a[self.pattern.diag[row]];
                blk[(0, 0)] += ks;
                blk[(1, 1)] += ks;
                blk[(2, 2)] += ks;
                let r = external_forces[node] + g * self.mass[node] + self.force[node]
                    - (self.x[node] - self.rest[node]) * ks;
                rhs[3 * row] = r.x;
                rhs[3 * row + 1] = r.y;
                rhs[3 * row + 2] = r.z;
            }
            match &mut chol {
                Some(c) => c.refactor(&self.a)?,
                None => chol = Some(SparseCholesky::new(&self.pattern, &self.a, 1)?),
            }
            let c = chol.as_mut().expect("factor built above");
            c.solve_in_place(&mut rhs);
            let mut step = 0.0f64;
            for (row, &node) in self.free_nodes.iter().enumerate() {
                let d = Vector3::new(rhs[3 * row], rhs[3 * row + 1], rhs[3 * row + 2]);
                step = step.max(d.amax());
                self.x[node] += d;
            }
            if !step.is_finite() {
                result = Err(FemError::Diverged(
                    "static solve produced non-finite positions".into(),
                ));
                break;
            }
            if step <= tolerance * size {
                result = Ok(it);
                break;
            }
        }
        self.v = saved_v;
        self.x_free.copy_from_slice(&self.x);
        self.v_free.copy_from_slice(&self.v);
        result
    }
}

/// The element pass of the common case (corotational material, CG solver): forces and the
/// upper triangle of `k_scale · K`, written straight to their blocks.
struct CorotationalUpperPass<'a> {
    tets: &'a [[usize; 4]],
    rest_elems: &'a [TetRest],
    pos: &'a [Point3<f64>],
    /// Rotation method, iterations and tolerance; None at rest (identity).
    rotation: Option<(RotationMethod, usize, f64)>,
    elem_rot: &'a mut [UnitQuaternion<f64>],
    elem_rot_m: &'a mut [Matrix3<f64>],
    mu: f64,
    lambda: f64,
    k_scale: f64,
    upper_scatter: &'a [UpperScatter],
    /// Packed f32 upper blocks (see [`UpperF32`]).
    blocks: &'a mut [f32],
    force: &'a mut [Vector3<f64>],
    /// Rotation each element's blocks were built with.
    elem_rot_k: &'a mut [Matrix3<f64>],
    /// Add every element's blocks (into cleared `blocks`) instead of updating.
    rebuild: bool,
    /// Re-rotate an element's blocks once its rotation moved by more than this.
    tolerance: f64,
    /// Modulus factor per element (strain stiffening); empty: 1 everywhere.
    scale: &'a [f64],
    /// Factor each element's blocks were built with (updated when rebuilt).
    scale_k: &'a mut [f64],
}

impl CorotationalUpperPass<'_> {
    /// Returns the number of elements whose blocks were written.
    fn run(self) -> usize {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                // SAFETY: the features were just detected.
                return unsafe { self.run_avx2() };
            }
        }
        self.run_portable()
    }

    /// The same loop compiled for AVX2/FMA (the kernels inline into it): the element
    /// arithmetic is ~600 flops a tet, a third of a step on the 2,560-node mesh.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn run_avx2(self) -> usize {
        self.run_portable()
    }

    #[inline(always)]
    fn run_portable(mut self) -> usize {
        let mut written = 0;
        let mut start = 0;
        if matches!(self.rotation, Some((RotationMethod::Qr, _, _))) {
            // Four elements side by side: rotation and forces lane by lane, which the
            // compiler turns into 4-wide arithmetic (the scalar chain of square roots and
            // divisions per element was the pass's cost).
            let chunks = self.tets.len() / 4;
            for c in 0..chunks {
                let e0 = 4 * c;
                let (rots, forces) = self.qr_forces_x4(e0);
                for l in 0..4 {
                    written += self.finish(e0 + l, &rots[l], &forces[l]) as usize;
                }
            }
            start = 4 * chunks;
        }
        let mut nodal = [Vector3::zeros(); 4];
        for e in start..self.tets.len() {
            let t = self.tets[e];
            let re = &self.rest_elems[e];
            let f = re.deformation_gradient([
                self.pos[t[0]].coords,
                self.pos[t[1]].coords,
                self.pos[t[2]].coords,
                self.pos[t[3]].coords,
            ]);
            let rot = match self.rotation {
                None => Matrix3::identity(),
                Some((method, iterations, tolerance)) => {
                    let r = element_rotation(
                        method,
                        &f,
                        &mut self.elem_rot[e],
                        &self.elem_rot_m[e],
                        iterations,
                        tolerance,
                    );
                    self.elem_rot_m[e] = r;
                    r
                }
            };
            element::corotational_forces(re, &f, &rot, self.mu, self.lambda, &mut nodal);
            written += self.finish(e, &rot, &nodal) as usize;
        }
        written
    }

    /// Element `e`'s forces onto its nodes, and its stiffness blocks when the pass rebuilds
    /// or its rotation moved past the tolerance. True when the blocks were written.
    #[inline(always)]
    fn finish(&mut self, e: usize, rot: &Matrix3<f64>, nodal: &[Vector3<f64>; 4]) -> bool {
        let t = self.tets[e];
        let s = self.scale.get(e).copied().unwrap_or(1.0);
        for k in 0..4 {
            self.force[t[k]] += nodal[k] * s;
        }
        let built = &mut self.elem_rot_k[e];
        let s_built = self.scale_k[e];
        let rescaled = s != s_built;
        if !self.rebuild {
            let turned = (rot - *built).amax() > self.tolerance;
            let stiffened = (s - s_built).abs() > self.tolerance * s_built;
            if !(turned || stiffened) {
                return false;
            }
            if rescaled {
                // The modulus changed: take the old blocks out whole, then add the new ones.
                element::corotational_stiffness_upper(
                    &self.rest_elems[e],
                    built,
                    None,
                    -self.mu * s_built,
                    -self.lambda * s_built,
                    self.k_scale,
                    &self.upper_scatter[e],
                    self.blocks,
                );
            }
        }
        let replaced = if self.rebuild || rescaled {
            None
        } else {
            Some(*built)
        };
        element::corotational_stiffness_upper(
            &self.rest_elems[e],
            rot,
            replaced.as_ref(),
            self.mu * s,
            self.lambda * s,
            self.k_scale,
            &self.upper_scatter[e],
            self.blocks,
        );
        *built = *rot;
        self.scale_k[e] = s;
        true
    }

    /// QR rotations (into `elem_rot_m`) and corotational nodal forces of elements
    /// `e0..e0 + 4`, computed lane by lane: the same arithmetic as [`element::qr_rotation`]
    /// and [`element::corotational_forces`] (node 0's force as minus the others').
    #[inline(always)]
    fn qr_forces_x4(&mut self, e0: usize) -> ([Matrix3<f64>; 4], [[Vector3<f64>; 4]; 4]) {
        type L = [f64; 4];
        // Edge vectors d_b = x_b − x_0 and rest gradients g_b (b = 1..3), per lane.
        let mut d = [[[0.0; 4]; 3]; 3];
        let mut g = [[[0.0; 4]; 3]; 3];
        let mut vol: L = [0.0; 4];
        for l in 0..4 {
            let t = self.tets[e0 + l];
            let re = &self.rest_elems[e0 + l];
            let x0 = self.pos[t[0]].coords;
            for b in 0..3 {
                let db = self.pos[t[b + 1]].coords - x0;
                for k in 0..3 {
                    d[b][k][l] = db[k];
                    g[b][k][l] = re.grad[b + 1][k];
                }
            }
            vol[l] = re.volume;
        }
        // F[i][j] = Σ_b d_b[i] g_b[j].
        let mut f = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                f[i][j] = lanes(|l| {
                    d[0][i][l] * g[0][j][l] + d[1][i][l] * g[1][j][l] + d[2][i][l] * g[2][j][l]
                });
            }
        }
        // QR: q0 = c0/|c0|, u1 = c1 − c0 (c0·c1)/(c0·c0), q1 = u1/|u1|, q2 = q0 × q1.
        let n0_sq =
            lanes(|l| f[0][0][l] * f[0][0][l] + f[1][0][l] * f[1][0][l] + f[2][0][l] * f[2][0][l]);
        let c01 =
            lanes(|l| f[0][0][l] * f[0][1][l] + f[1][0][l] * f[1][1][l] + f[2][0][l] * f[2][1][l]);
        let s = lanes(|l| c01[l] / n0_sq[l]);
        let mut u1 = [[0.0; 4]; 3];
        for i in 0..3 {
            u1[i] = lanes(|l| f[i][1][l] - f[i][0][l] * s[l]);
        }
        let n1_sq = lanes(|l| u1[0][l] * u1[0][l] + u1[1][l] * u1[1][l] + u1[2][l] * u1[2][l]);
        let inv0 = lanes(|l| 1.0 / n0_sq[l].sqrt());
        let inv1 = lanes(|l| 1.0 / n1_sq[l].sqrt());
        let mut r = [[[0.0; 4]; 3]; 3]; // r[i][j]: row i, column j
        for i in 0..3 {
            r[i][0] = lanes(|l| f[i][0][l] * inv0[l]);
            r[i][1] = lanes(|l| u1[i][l] * inv1[l]);
        }
        for i in 0..3 {
            let (j, k) = ((i + 1) % 3, (i + 2) % 3);
            r[i][2] = lanes(|l| r[j][0][l] * r[k][1][l] - r[k][0][l] * r[j][1][l]);
        }
        let mut rots = [Matrix3::zeros(); 4];
        for l in 0..4 {
            let valid = n0_sq[l] > 1e-24
                && n0_sq[l].is_finite()
                && n1_sq[l] > 1e-24 * n0_sq[l].max(1.0)
                && n1_sq[l].is_finite();
            if valid {
                rots[l] = Matrix3::from_fn(|i, j| r[i][j][l]);
                self.elem_rot_m[e0 + l] = rots[l];
            } else {
                // Degenerate element: keep its previous rotation, as the scalar path.
                rots[l] = self.elem_rot_m[e0 + l];
                for i in 0..3 {
                    for j in 0..3 {
                        r[i][j][l] = rots[l][(i, j)];
                    }
                }
            }
        }
        // Small strain in the rotated frame: eps = sym(RᵀF) − I, σ = 2μ eps + λ tr(eps) I.
        let mut fr = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                fr[i][j] = lanes(|l| {
                    r[0][i][l] * f[0][j][l] + r[1][i][l] * f[1][j][l] + r[2][i][l] * f[2][j][l]
                });
            }
        }
        let (mu, lambda) = (self.mu, self.lambda);
        let tr = lanes(|l| fr[0][0][l] + fr[1][1][l] + fr[2][2][l] - 3.0);
        let mut sigma = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                sigma[i][j] = lanes(|l| {
                    let eps = 0.5 * (fr[i][j][l] + fr[j][i][l]) - if i == j { 1.0 } else { 0.0 };
                    2.0 * mu * eps + if i == j { lambda * tr[l] } else { 0.0 }
                });
            }
        }
        // P = −V R σ; f_b = P g_b (b = 1..3), f_0 = −(f_1 + f_2 + f_3).
        let mut p = [[[0.0; 4]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                p[i][j] = lanes(|l| {
                    -vol[l]
                        * (r[i][0][l] * sigma[0][j][l]
                            + r[i][1][l] * sigma[1][j][l]
                            + r[i][2][l] * sigma[2][j][l])
                });
            }
        }
        let mut forces = [[Vector3::zeros(); 4]; 4];
        for b in 0..3 {
            for i in 0..3 {
                let fb = lanes(|l| {
                    p[i][0][l] * g[b][0][l] + p[i][1][l] * g[b][1][l] + p[i][2][l] * g[b][2][l]
                });
                for l in 0..4 {
                    forces[l][b + 1][i] = fb[l];
                }
            }
        }
        for nodal in forces.iter_mut() {
            nodal[0] = -(nodal[1] + nodal[2] + nodal[3]);
        }
        (rots, forces)
    }
}

/// One value per lane of a 4-element group.
#[inline(always)]
fn lanes(f: impl Fn(usize) -> f64) -> [f64; 4] {
    [f(0), f(1), f(2), f(3)]
}

/// Rotation of `a` (a deformation gradient or a sum of rotations) by `method`; QR falls back
/// to `previous` for a degenerate `a`, polar warm-starts from (and updates) `q`.
#[inline]
fn element_rotation(
    method: RotationMethod,
    a: &Matrix3<f64>,
    q: &mut UnitQuaternion<f64>,
    previous: &Matrix3<f64>,
    iterations: usize,
    tolerance: f64,
) -> Matrix3<f64> {
    match method {
        RotationMethod::Qr => element::qr_rotation(a).unwrap_or(*previous),
        RotationMethod::Polar => element::extract_rotation(a, q, iterations, tolerance),
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The rest-state system A0 = M + dt C0 + dt² K0 factored once (precomputed constraint
/// correction). Solves act on full vectors of 3 entries per mesh node; held nodes' entries
/// are ignored on input and zero on output. No allocation after construction.
pub struct RestCompliance {
    chol: SparseCholesky,
    free_index: Vec<u32>,
    free_nodes: Vec<usize>,
    n_nodes: usize,
    max_cols: usize,
    scratch: Vec<f64>,
    dt: f64,
}

impl std::fmt::Debug for RestCompliance {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RestCompliance")
            .field("nodes", &self.n_nodes)
            .field("free_nodes", &self.free_nodes.len())
            .field("dt", &self.dt)
            .field("cholesky", &self.chol)
            .finish()
    }
}

impl RestCompliance {
    /// The time step A0 was built for, s.
    pub fn dt(&self) -> f64 {
        self.dt
    }
    pub fn node_count(&self) -> usize {
        self.n_nodes
    }
    /// Row of a node in the reduced (free-dof) system, None when held.
    pub fn free_index(&self, node: usize) -> Option<usize> {
        match self.free_index.get(node) {
            Some(&i) if i != NO_BLOCK => Some(i as usize),
            _ => None,
        }
    }
    /// The factor itself, on reduced vectors (3 per free node, in `free_index` order).
    pub fn cholesky_mut(&mut self) -> &mut SparseCholesky {
        &mut self.chol
    }

    /// x ← A0⁻¹ x, `x.len() == 3 * nodes` (velocity response, m/s per N·s of impulse;
    /// multiply by dt for displacement).
    pub fn solve_in_place(&mut self, x: &mut [f64]) {
        self.solve_block_in_place(x, 1);
    }

    /// X ← A0⁻¹ X for `ncols` full-length columns stored column-major
    /// (`x.len() == 3 * nodes * ncols`); solved as blocks of up to `max_block_columns`.
    pub fn solve_block_in_place(&mut self, x: &mut [f64], ncols: usize) {
        let full = 3 * self.n_nodes;
        assert_eq!(
            x.len(),
            full * ncols,
            "RestCompliance: right-hand side size"
        );
        let red = 3 * self.free_nodes.len();
        let mut c0 = 0;
        while c0 < ncols {
            let k = (ncols - c0).min(self.max_cols);
            let s = &mut self.scratch[..red * k];
            for c in 0..k {
                let col = &x[(c0 + c) * full..(c0 + c + 1) * full];
                for (row, &node) in self.free_nodes.iter().enumerate() {
                    s[c * red + 3 * row..c * red + 3 * row + 3]
                        .copy_from_slice(&col[3 * node..3 * node + 3]);
                }
            }
            self.chol.solve_block_in_place(s, k);
            for c in 0..k {
                let col = &mut x[(c0 + c) * full..(c0 + c + 1) * full];
                col.fill(0.0);
                for (row, &node) in self.free_nodes.iter().enumerate() {
                    col[3 * node..3 * node + 3]
                        .copy_from_slice(&s[c * red + 3 * row..c * red + 3 * row + 3]);
                }
            }
            c0 += k;
        }
    }
}
