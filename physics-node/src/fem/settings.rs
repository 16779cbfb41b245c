//! FEM settings: the linear solver, CG preconditioner and matrix precision, and the
//! element rotation method, from a launch file's `[scene.solver]`.

use super::*;

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
    /// A factor of the step's own system, refactored only after a solve needed more than
    /// [`LAGGED_FACTOR_ITERATIONS`] iterations (the system changes only slowly, with the
    /// element rotations and the stiffening): a converged solve at about the cost of a few
    /// triangular solves per step instead of a numeric factorization (offline replays).
    LaggedFactor,
}

/// With [`Preconditioner::LaggedFactor`]: a solve that needed more iterations than this
/// refactors the system at the next step (a fresh factor converges in one or two: it is
/// stored in f32, [`crate::fem::FactorPrecision::F32`]).
pub const LAGGED_FACTOR_ITERATIONS: usize = 4;

/// Precision of the system matrix the CG products read: the launch file's choice.
pub use launch_config::scene::CgMatrix;
/// How the corotational element finds its rotation: the launch file's choice, parsed once.
pub use launch_config::scene::RotationMethod;
use launch_config::scene::SolverKind;

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

    /// The solver keeps a sparse Cholesky factor of the whole current system (the direct
    /// solve, and the lagged-factor preconditioner), so the full f64 matrix is assembled
    /// rather than only the upper triangle the other CG variants read.
    pub fn factors_current_system(&self) -> bool {
        matches!(
            self,
            LinearSolver::Direct
                | LinearSolver::Cg {
                    preconditioner: Preconditioner::LaggedFactor,
                    ..
                }
        )
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
        let solver = match scene.solver.kind {
            SolverKind::Cg => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::None,
            },
            SolverKind::CgJacobi => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::BlockJacobi,
            },
            SolverKind::CgCholesky => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::RestCholesky,
            },
            SolverKind::CgWarpedCholesky => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::WarpedRestCholesky,
            },
            SolverKind::CgLaggedFactor => LinearSolver::Cg {
                max_iterations: scene.solver.cg_iterations as usize,
                tolerance: scene.solver.cg_tolerance,
                preconditioner: Preconditioner::LaggedFactor,
            },
            SolverKind::Direct => LinearSolver::Direct,
        };
        let s = FemSettings {
            dt: scene.dt,
            gravity: Vector3::from(scene.gravity),
            rayleigh_mass: scene.material.rayleigh_mass,
            rayleigh_stiffness: scene.material.rayleigh_stiffness,
            solver,
            // The support lumps collagenous structures of the meniscus' own kind (horn and
            // coronary attachments): a degeneration grade softens it as it softens the tissue.
            support_stiffness: scene.meniscus.support_stiffness
                * super::Material::degeneration_factor(scene.material.degeneration_grade)?,
            project_tangent: true,
            rotation: scene.solver.rotation,
            cg_matrix: scene.solver.cg_matrix,
            stiffness_rotation_tolerance: scene.solver.stiffness_rotation_tolerance,
        };
        s.validate()?;
        Ok(s)
    }

    pub(super) fn validate(&self) -> Result<(), FemError> {
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
