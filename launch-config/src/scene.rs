//! `[scene]`: the physics node's scene. Owned by physics-node.
//!
//! SI units. A mesh spec is `default:lateral:coarse|fine|finest`, `default:medial:...`
//! (the project's parametric meniscus; the resolution may also be chosen divisions
//! `ARCxRADIALxVERTICAL`, see [`parse_mesh_divisions`]), `study:lateral` / `study:medial` (the study's meshes
//! from `ARTHROSIM_DATA`, with the study's scale and, for the lateral, its fixed nodes), or a
//! path to a `.msh` file.
pub use crate::choices::{
    CgMatrix, MaterialModel, MaterialPreset, OfflineSolver, RotationMethod, SolverKind,
};
use serde::{Deserialize, Serialize};

/// The resolutions of the parametric meniscus a mesh spec may name, for messages.
pub const RESOLUTIONS: &str = "coarse | fine | finest, or divisions ARCxRADIALxVERTICAL \
    such as 44x3x2, each at least 1, at most 100,000 nodes";
/// Most nodes chosen divisions may make: ten times the `finest` mesh (10,504), already far
/// beyond what a scene can step; without a bound `400x400x400` would ask for 64 M nodes.
pub const MAX_DIVISION_NODES: usize = 100_000;

/// Whether `s` is a parametric mesh resolution ([`RESOLUTIONS`]): a named one or chosen
/// divisions. The one rule for launch files and experiment folders.
pub fn is_mesh_resolution(s: &str) -> bool {
    matches!(s, "coarse" | "fine" | "finest") || parse_mesh_divisions(s).is_some()
}

/// Chosen divisions of the parametric meniscus, `ARCxRADIALxVERTICAL` (arc, radial and
/// vertical element counts, each ≥ 1, at most [`MAX_DIVISION_NODES`] nodes), as a mesh
/// spec's resolution (`default:lateral:44x3x2`), for mesh convergence studies: the one
/// parser for the launch file's check and the mesh loader.
pub fn parse_mesh_divisions(s: &str) -> Option<[usize; 3]> {
    let mut out = [0usize; 3];
    let mut parts = s.split('x');
    for d in &mut out {
        let text = parts.next()?;
        if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        *d = text.parse().ok().filter(|&d| d >= 1)?;
    }
    let nodes = out
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d.checked_add(1)?))?;
    (parts.next().is_none() && nodes <= MAX_DIVISION_NODES).then_some(out)
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneConfig {
    /// Time step, s.
    pub dt: f64,
    /// Gravity, m/s², world frame (z up).
    pub gravity: [f64; 3],
    pub meniscus: MeniscusConfig,
    pub material: MaterialConfig,
    pub solver: SolverConfig,
    pub contact: ContactConfig,
    pub probe: ProbeConfig,
    pub faults: FaultConfig,
    /// Material (degeneration grade) changes are prepared off the real-time loop and swapped
    /// in; at most one change starts per this interval, s (later commands are coalesced).
    pub material_change_interval_s: f64,
}

impl Default for SceneConfig {
    fn default() -> Self {
        SceneConfig {
            dt: 0.01,
            gravity: [0.0, 0.0, -9.81],
            meniscus: MeniscusConfig::default(),
            material: MaterialConfig::default(),
            solver: SolverConfig::default(),
            contact: ContactConfig::default(),
            probe: ProbeConfig::default(),
            faults: FaultConfig::default(),
            material_change_interval_s: 1.0,
        }
    }
}

/// `[scene.faults]`: the checks every physics step passes before its frame may be rendered.
/// A step that fails one is published with a fault flag, rolled back and counted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FaultConfig {
    /// Largest contact force on the probe that is physical for the scene, N. The study's
    /// probings stay below 25 N and the Touch renders at most 3.3 N; a diverging contact
    /// solve reaches 10⁴–10⁶ N.
    pub max_contact_force_n: f64,
    /// Deepest probe penetration left after the contact correction, m (a converged solve
    /// leaves ~0; the contact distance is 1.1 mm).
    pub max_penetration_m: f64,
    /// Largest relative residual ‖b − AΔv‖/‖b‖ of the free-motion CG. The truncated CG (25
    /// iterations) does not reach its tolerance by design; a residual of this size means it
    /// made no progress at all.
    pub max_cg_residual: f64,
    /// Relative slack of the energy check: without contact, the tissue's kinetic energy may
    /// not exceed the mechanical energy it had when the last contact ended by more than this.
    pub energy_tolerance: f64,
    /// After this many faulty steps in a row, roll back to the rest state instead of the last
    /// good one.
    pub rest_after_faults: u32,
}

impl Default for FaultConfig {
    fn default() -> Self {
        FaultConfig {
            max_contact_force_n: 200.0,
            max_penetration_m: 3e-3,
            max_cg_residual: 1.0,
            energy_tolerance: 0.05,
            rest_after_faults: 3,
        }
    }
}

/// A load-time transform: x' = R(rotation) · (scale · x) + translation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TransformConfig {
    /// Uniform scale applied to raw coordinates (e.g. 0.026 for the study's raw → m).
    pub scale: f64,
    /// Rotation, degrees, applied as extrinsic x then y then z.
    pub rotation_deg: [f64; 3],
    /// Translation after scaling and rotation, m.
    pub translation: [f64; 3],
}

impl Default for TransformConfig {
    fn default() -> Self {
        TransformConfig {
            scale: 1.0,
            rotation_deg: [0.0; 3],
            translation: [0.0; 3],
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MeniscusConfig {
    /// Mesh spec (see module docs).
    pub mesh: String,
    /// Optional high-resolution visual surface (OBJ or STL) mapped onto the tets.
    pub visual: Option<String>,
    /// Transform for a `.msh` path (ignored for `default:` and `study:` specs, which carry
    /// their own).
    pub transform: TransformConfig,
    /// Transform for the visual surface file.
    pub visual_transform: TransformConfig,
    /// Fixed set: `inferior` (nodes on the inferior surface), `none`, or a path to a file of
    /// 0-based node indices.
    pub fixed: String,
    /// 0: fixed nodes are held. > 0: they are held by springs of this stiffness per node,
    /// N/m (elastic support of the inferior surface).
    pub support_stiffness: f64,
}

impl Default for MeniscusConfig {
    fn default() -> Self {
        MeniscusConfig {
            mesh: "default:lateral:coarse".into(),
            visual: None,
            transform: TransformConfig::default(),
            visual_transform: TransformConfig::default(),
            fixed: "inferior".into(),
            support_stiffness: 0.0,
        }
    }
}

/// Largest `[scene.material] strain_stiffening` rate (per unit strain): beyond it the
/// modulus grows more than e^10 over a strain of 0.2, far stiffer than any soft tissue.
pub const MAX_STRAIN_STIFFENING: f64 = 50.0;
/// Largest `[scene.meniscus] support_stiffness`, N/m per node (a support this stiff is
/// indistinguishable from holding the nodes).
pub const MAX_SUPPORT_STIFFNESS: f64 = 1.0e7;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MaterialConfig {
    /// `lateral` (E 3.50 MPa, ν 0.29), `medial` (E 3.84 MPa, ν 0.26) or `custom`.
    pub preset: MaterialPreset,
    /// Young's modulus, Pa; overrides the preset.
    pub youngs_modulus: Option<f64>,
    /// Poisson's ratio; overrides the preset.
    pub poisson_ratio: Option<f64>,
    /// Density, kg/m³.
    pub density: f64,
    /// `corotational` (linear corotational) or `neo-hookean` (stable neo-Hookean).
    pub model: MaterialModel,
    /// Degeneration grade 0..=2: modulus × (1 − 0.205 · grade), grade 2 = −41%.
    pub degeneration_grade: f64,
    /// Extra global modulus scale (specimen variability; fitted to measured probing in the
    /// default scene).
    pub modulus_scale: f64,
    /// Strain stiffening: element modulus × exp(rate · ε_eq) (ε_eq the element's von Mises
    /// equivalent strain), 0 = linear. Allowed 0..=[`MAX_STRAIN_STIFFENING`].
    pub strain_stiffening: f64,
    /// Rayleigh damping coefficients (mass, stiffness).
    pub rayleigh_mass: f64,
    pub rayleigh_stiffness: f64,
}

impl Default for MaterialConfig {
    fn default() -> Self {
        MaterialConfig {
            preset: MaterialPreset::Lateral,
            youngs_modulus: None,
            poisson_ratio: None,
            density: 1090.0,
            model: MaterialModel::Corotational,
            degeneration_grade: 0.0,
            modulus_scale: 1.0,
            strain_stiffening: 0.0,
            rayleigh_mass: 0.0,
            rayleigh_stiffness: 0.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SolverConfig {
    /// `cg` (SOFA's CG), `cg-jacobi`, `cg-cholesky`, `cg-warped-cholesky` (CG preconditioned
    /// by the rest factor, rotation-warped) or `direct` (faer sparse Cholesky every step).
    pub kind: SolverKind,
    pub cg_iterations: u32,
    pub cg_tolerance: f64,
    /// Element rotation of the corotational FEM: `qr` (SOFA's "large", default) or `polar`.
    pub rotation: RotationMethod,
    /// Precision of the matrix the CG products read: `f32` (default; half the memory
    /// traffic, right for SOFA's truncated CG) or `f64` (for a CG that must converge
    /// below ~1e-6).
    pub cg_matrix: CgMatrix,
    /// With the f32 CG matrix: re-rotate an element's stiffness blocks only once its rotation
    /// moved by more than this (≈ rad) since they were built; 0 = every element every step,
    /// as SOFA. Elastic forces always use the current rotation. At most
    /// [`crate::validate::MAX_STIFFNESS_ROTATION_TOLERANCE`].
    pub stiffness_rotation_tolerance: f64,
    /// How offline replays solve the step (the live node ignores it): `cg` (default: CG
    /// preconditioned by a lagged factor of the step's matrix, to `offline_tolerance`),
    /// `direct` (a Cholesky solve every step) or `scene` (as the live node). See
    /// [`Self::offline`].
    pub offline: OfflineSolver,
    /// Relative residual an offline `cg` stops at, within
    /// [`OFFLINE_TOLERANCE_MIN`]..=[`OFFLINE_TOLERANCE_MAX`].
    pub offline_tolerance: f64,
}

/// Tightest `offline_tolerance`: below ~1e-12 the f64 residual of a ~10⁴-unknown system is
/// round-off, and CG would run to its iteration ceiling without getting there.
pub const OFFLINE_TOLERANCE_MIN: f64 = 1e-12;
/// Loosest `offline_tolerance`: a looser CG is a truncated solve again, which is what the
/// offline setting exists to avoid.
pub const OFFLINE_TOLERANCE_MAX: f64 = 1e-4;
/// Iteration ceiling of an offline `cg`: a guard, not the stopping rule (the tolerance is;
/// the warped rest preconditioner reaches 1e-8 in tens of iterations on the study meshes).
pub const OFFLINE_CG_MAX_ITERATIONS: u32 = 1000;

/// A `[scene.solver]` setting outside its bounds.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SolverConfigError {
    #[error("scene.solver.offline_tolerance: {0}")]
    OfflineTolerance(String),
}

impl SolverConfig {
    /// What is wrong with `offline_tolerance`, if anything (the one check, shared by
    /// [`crate::validate`] and [`Self::offline`]).
    pub fn offline_tolerance_problem(&self) -> Option<String> {
        let t = self.offline_tolerance;
        (!(t.is_finite() && (OFFLINE_TOLERANCE_MIN..=OFFLINE_TOLERANCE_MAX).contains(&t))).then(
            || {
                format!(
                    "{t:e} is out of range; allowed: {OFFLINE_TOLERANCE_MIN:e} ≤ \
                     offline_tolerance ≤ {OFFLINE_TOLERANCE_MAX:e} (relative residual of the \
                     offline CG)"
                )
            },
        )
    }

    /// The solver settings an offline replay steps with: a converged solve instead of the
    /// live node's iteration-capped CG. Offline there is no 1 ms budget, and a truncated
    /// solve under-resolves the deformation (a numerical dissipation that the gap diagnosis
    /// would otherwise read as a tissue effect).
    pub fn offline(&self) -> Result<SolverConfig, SolverConfigError> {
        if let Some(p) = self.offline_tolerance_problem() {
            return Err(SolverConfigError::OfflineTolerance(p));
        }
        let mut s = self.clone();
        match self.offline {
            OfflineSolver::Scene => {}
            OfflineSolver::Direct => {
                s.kind = SolverKind::Direct;
                // the direct solver reads the full f64 matrix, every element re-rotated
                s.stiffness_rotation_tolerance = 0.0;
            }
            OfflineSolver::Cg => {
                s.kind = SolverKind::CgLaggedFactor;
                s.cg_iterations = OFFLINE_CG_MAX_ITERATIONS;
                s.cg_tolerance = self.offline_tolerance;
                s.cg_matrix = CgMatrix::F64;
                s.stiffness_rotation_tolerance = 0.0;
            }
        }
        Ok(s)
    }
}

impl Default for SolverConfig {
    fn default() -> Self {
        SolverConfig {
            kind: SolverKind::Cg,
            cg_iterations: 25,
            cg_tolerance: 1e-9,
            rotation: RotationMethod::Qr,
            cg_matrix: CgMatrix::F32,
            // 1e-3 rad: a quarter of the default fine mesh's elements turn that far per step
            // while the probe slides; the mean contact force moves by < 1e-4 relative.
            stiffness_rotation_tolerance: 1e-3,
            offline: OfflineSolver::Cg,
            offline_tolerance: 1e-6,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ContactConfig {
    /// Proximity at which a contact constraint is created, m.
    pub alarm_distance: f64,
    /// Target separation of an active contact, m.
    pub contact_distance: f64,
    /// Coulomb friction coefficient.
    pub friction: f64,
    pub lcp_tolerance: f64,
    pub lcp_max_iterations: u32,
    /// At most this many contacts per step (≤ msgs::MAX_CONTACTS).
    pub max_contacts: u32,
    /// Compliance of the contact interface itself, m/N: 0 is SOFA's hard contact (Lagrange
    /// multipliers, no penetration once solved); > 0 a penalty contact of stiffness 1/this
    /// per probe ball, in series with the tissue: a ball penetrates the surface by this ×
    /// its normal force, however many contact points carry it. The gap self-test's truth
    /// uses one, so that it differs from the replay in its contact formulation as an
    /// independent FE code would.
    pub interface_compliance: f64,
    /// Spread each probe ball's force over its Hertz contact patch, on the nodes under it with
    /// weights continuous in the ball's position, instead of holding the closest point of
    /// every close triangle (physics-node's `ContactParams::hertz_patch`). Off
    /// by default: the replay and the calibrated scenes hold the closest points.
    pub hertz_patch: bool,
}

impl Default for ContactConfig {
    fn default() -> Self {
        ContactConfig {
            alarm_distance: 3.408e-3,
            contact_distance: 1.136e-3,
            friction: 0.0,
            lcp_tolerance: 1e-3,
            lcp_max_iterations: 1000,
            max_contacts: 32,
            interface_compliance: 0.0,
            hertz_patch: false,
        }
    }
}

/// `[scene.probe] model` values that name a built-in collision model rather than an OBJ file.
pub const BUILTIN_PROBE_MODELS: [&str; 3] = ["default", "hook", "sphere"];

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProbeConfig {
    /// `default` or `hook` (built-in hook probe: tip ball, 3 mm hook, 40 mm shaft, as chains of
    /// balls of `tip_radius`), `sphere` (the tip ball alone, for indentation tests) or a path to an OBJ
    /// collision model (its vertices and sampled edges become contact points; radius 0, so
    /// `contact.contact_distance` acts as their thickness).
    pub model: String,
    /// Transform for an OBJ collision model.
    pub transform: TransformConfig,
    /// Probe mass, kg (Arthrex AR-10000: 35 g).
    pub mass: f64,
    /// Radius of the probe tip, m.
    pub tip_radius: f64,
    /// Coupling spring between device proxy and probe: linear N/m, angular N·m/rad.
    pub coupling_stiffness: f64,
    pub coupling_angular_stiffness: f64,
    /// Coupling damping: linear N·s/m, angular N·m·s/rad.
    pub coupling_damping: f64,
    pub coupling_angular_damping: f64,
    /// Initial probe pose (position m, quaternion xyzw).
    pub initial_position: [f64; 3],
    pub initial_orientation: [f64; 4],
}

impl Default for ProbeConfig {
    fn default() -> Self {
        ProbeConfig {
            model: "default".into(),
            transform: TransformConfig::default(),
            mass: 0.035,
            tip_radius: 1.5e-3,
            coupling_stiffness: 1.0e5,
            coupling_angular_stiffness: 50.0,
            coupling_damping: 50.0,
            coupling_angular_damping: 0.05,
            initial_position: [0.0, 0.0, 0.05],
            initial_orientation: [0.0, 0.0, 0.0, 1.0],
        }
    }
}

#[cfg(test)]
mod offline_solver_tests {
    use super::*;

    /// The offline solve is converged by default and leaves the live `kind` alone; each
    /// choice maps to its solver, and a tolerance outside the bounds is an error naming the
    /// key and the allowed range.
    #[test]
    fn offline_solver_maps_and_checks_its_tolerance() {
        let live = SolverConfig::default();
        assert_eq!(live.kind, SolverKind::Cg);
        assert_eq!(live.cg_iterations, 25);
        let off = live.offline().unwrap();
        assert_eq!(off.kind, SolverKind::CgLaggedFactor);
        assert_eq!(off.cg_tolerance, 1e-6);
        assert_eq!(off.cg_iterations, OFFLINE_CG_MAX_ITERATIONS);
        assert_eq!(off.cg_matrix, CgMatrix::F64);
        let direct = SolverConfig {
            offline: OfflineSolver::Direct,
            ..live.clone()
        };
        assert_eq!(direct.offline().unwrap().kind, SolverKind::Direct);
        let scene = SolverConfig {
            offline: OfflineSolver::Scene,
            ..live.clone()
        };
        assert_eq!(scene.offline().unwrap(), scene);
        for bad in [0.0, 1e-13, 1e-3, f64::NAN, f64::INFINITY, -1e-6] {
            let s = SolverConfig {
                offline_tolerance: bad,
                ..live.clone()
            };
            let e = s.offline().unwrap_err().to_string();
            assert!(
                e.starts_with("scene.solver.offline_tolerance:") && e.contains("allowed: 1e-12"),
                "{bad}: {e}"
            );
        }
        for good in [OFFLINE_TOLERANCE_MIN, 1e-8, OFFLINE_TOLERANCE_MAX] {
            let s = SolverConfig {
                offline_tolerance: good,
                ..live.clone()
            };
            assert!(s.offline().is_ok(), "{good}");
        }
    }
}
