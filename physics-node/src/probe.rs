//! The hook probe: a rigid 6-DoF body with a collision model of spheres (points with a radius),
//! driven by an implicit spring–damper coupling toward the device proxy (as SOFA's
//! RestShapeSpringsForceField) or kinematically along a prescribed pose.
//!
//! Body frame: origin at the hook tip (the point the device proxy maps to). The 35 g are
//! lumped at that origin with the rotational inertia of a slender rod about it; with the
//! stiff coupling (1e5 N/m against 35 g) the probe follows the proxy within micrometres in
//! free space, so the simplification only shows in contact, where the coupling dominates.

use crate::error::PhysicsError;
use launch_config::scene::ProbeConfig;
use nalgebra::{Matrix3, Point3, Quaternion, UnitQuaternion, Vector3};
use std::path::Path;

/// Length of the rod used for the probe's inertia, m (Arthrex AR-10000 class hook probe).
const ROD_LENGTH: f64 = 0.15;
/// Radius of the rod used for the inertia about its own axis, m.
const ROD_RADIUS: f64 = 1.5e-3;
/// Built-in hook: tip → elbow, m (the bent end of an arthroscopic hook probe).
const HOOK_LENGTH: f64 = 3.0e-3;
/// Built-in shaft: elbow → handle; only the part that can reach the joint is modelled, m.
const SHAFT_LENGTH: f64 = 40.0e-3;
/// Inclination of the built-in shaft from the body z axis, degrees. The hook is bent at 90°
/// to the shaft, so in the identity pose (z along the outward surface normal, the pose the
/// emulated operator holds) the hook points down at the tissue at the same angle: the tip is
/// the lowest point, the elbow sits HOOK_LENGTH·cos(45°) ≈ 2.1 mm above it, and the shaft
/// rises away from the tissue. A hook laid flat (the earlier model) put the whole arm on
/// the surface, so the contact was carried beside the tip instead of by it.
const SHAFT_INCLINATION_DEG: f64 = 45.0;

/// One collision primitive of the probe: a sphere in the body frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CollisionSphere {
    /// Centre in the body frame, m.
    pub local: Vector3<f64>,
    /// Radius, m (0 for the points of a line model: the contact distance is used then).
    pub radius: f64,
}

/// How the probe moves this step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProbeDrive {
    /// Coupling spring toward the proxy pose; the probe is a dynamic body.
    Coupled,
    /// Prescribed pose; the probe has infinite mass in contact.
    Kinematic,
}

/// The probe's rigid state and its coupling.
#[derive(Debug, Clone)]
pub struct Probe {
    pub spheres: Vec<CollisionSphere>,
    mass: f64,
    /// Body-frame inertia about the origin, kg·m².
    inertia_body: Matrix3<f64>,
    stiffness: f64,
    angular_stiffness: f64,
    damping: f64,
    angular_damping: f64,
    pub drive: ProbeDrive,
    /// Pose and twist at the start of the step (after last step's correction).
    pub position: Vector3<f64>,
    pub orientation: UnitQuaternion<f64>,
    pub velocity: Vector3<f64>,
    pub angular_velocity: Vector3<f64>,
    /// Free-motion pose and twist (the linearisation point of the contact problem).
    pub free_position: Vector3<f64>,
    pub free_orientation: UnitQuaternion<f64>,
    pub free_velocity: Vector3<f64>,
    pub free_angular_velocity: Vector3<f64>,
    /// Target of the coupling (device proxy) or prescribed pose.
    pub target_position: Vector3<f64>,
    pub target_orientation: UnitQuaternion<f64>,
    /// Inverse effective mass of the implicit step, linear (scalar) and angular (world).
    inv_mass_eff: f64,
    inv_inertia_eff: Matrix3<f64>,
}

/// Converts a wire pose into nalgebra (position, unit quaternion); rejects non-finite or
/// zero quaternions.
pub fn pose_to_nalgebra(pose: &msgs::Pose) -> Option<(Vector3<f64>, UnitQuaternion<f64>)> {
    if !pose.is_finite() {
        return None;
    }
    let [x, y, z, w] = pose.orientation;
    let q = Quaternion::new(w, x, y, z);
    if q.norm() < 1e-9 {
        return None;
    }
    Some((
        Vector3::from(pose.position),
        UnitQuaternion::from_quaternion(q),
    ))
}

/// Converts (position, unit quaternion) into a wire pose.
pub fn nalgebra_to_pose(p: &Vector3<f64>, q: &UnitQuaternion<f64>) -> msgs::Pose {
    let c = q.quaternion().coords; // [x, y, z, w]
    msgs::Pose {
        position: [p.x, p.y, p.z],
        orientation: [c.x, c.y, c.z, c.w],
    }
}

impl Probe {
    /// Builds the probe from its configuration; `data_dir` resolves relative OBJ paths that
    /// are not found as given.
    pub fn new(
        cfg: &ProbeConfig,
        contact_distance: f64,
        data_dir: &Path,
    ) -> Result<Probe, PhysicsError> {
        let bad = |what: &str| PhysicsError::Config(format!("probe: {what}"));
        if !(cfg.mass.is_finite() && cfg.mass > 0.0) {
            return Err(bad("mass must be finite and > 0"));
        }
        if !(cfg.tip_radius.is_finite() && cfg.tip_radius >= 0.0) {
            return Err(bad("tip_radius must be finite and ≥ 0"));
        }
        for (name, v) in [
            ("coupling_stiffness", cfg.coupling_stiffness),
            ("coupling_angular_stiffness", cfg.coupling_angular_stiffness),
            ("coupling_damping", cfg.coupling_damping),
            ("coupling_angular_damping", cfg.coupling_angular_damping),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(&format!("{name} must be finite and ≥ 0")));
            }
        }
        let init = msgs::Pose {
            position: cfg.initial_position,
            orientation: cfg.initial_orientation,
        };
        let (position, orientation) = pose_to_nalgebra(&init)
            .ok_or_else(|| bad("initial pose is not finite or has a zero quaternion"))?;

        let spheres = match cfg.model.as_str() {
            "default" | "hook" => builtin_hook(cfg.tip_radius),
            "sphere" => vec![CollisionSphere {
                local: Vector3::zeros(),
                radius: cfg.tip_radius,
            }],
            path => {
                let mut p = Path::new(path).to_path_buf();
                if !p.exists() && p.is_relative() {
                    p = data_dir.join(path);
                }
                obj_line_model(&p, &cfg.transform, contact_distance)?
            }
        };
        if spheres.is_empty() {
            return Err(bad("collision model has no points"));
        }

        // Slender rod along the longest extent of the collision model, pivoting at the tip.
        let axis = principal_axis(&spheres);
        let m = cfg.mass;
        let i_perp = m * ROD_LENGTH * ROD_LENGTH / 12.0;
        let i_axis = 0.5 * m * ROD_RADIUS * ROD_RADIUS;
        let inertia_body =
            Matrix3::identity() * i_perp + axis * axis.transpose() * (i_axis - i_perp);

        let mut probe = Probe {
            spheres,
            mass: m,
            inertia_body,
            stiffness: cfg.coupling_stiffness,
            angular_stiffness: cfg.coupling_angular_stiffness,
            damping: cfg.coupling_damping,
            angular_damping: cfg.coupling_angular_damping,
            drive: ProbeDrive::Coupled,
            position,
            orientation,
            velocity: Vector3::zeros(),
            angular_velocity: Vector3::zeros(),
            free_position: position,
            free_orientation: orientation,
            free_velocity: Vector3::zeros(),
            free_angular_velocity: Vector3::zeros(),
            target_position: position,
            target_orientation: orientation,
            inv_mass_eff: 0.0,
            inv_inertia_eff: Matrix3::zeros(),
        };
        probe.inv_mass_eff = 1.0 / m;
        probe.inv_inertia_eff = probe
            .inertia_body
            .try_inverse()
            .unwrap_or_else(Matrix3::zeros);
        Ok(probe)
    }

    pub fn mass(&self) -> f64 {
        self.mass
    }

    /// Sets the coupling target (device proxy) and switches to coupled drive.
    pub fn set_proxy(&mut self, p: Vector3<f64>, q: UnitQuaternion<f64>) {
        self.target_position = p;
        self.target_orientation = q;
        self.drive = ProbeDrive::Coupled;
    }

    /// Prescribes the pose of the next step (kinematic drive).
    pub fn set_kinematic(&mut self, p: Vector3<f64>, q: UnitQuaternion<f64>) {
        self.target_position = p;
        self.target_orientation = q;
        self.drive = ProbeDrive::Kinematic;
    }

    /// Free motion: implicit Euler of the coupled rigid body under gravity, or the prescribed
    /// pose. Also sets the effective inverse mass used by the contact compliance.
    pub fn free_motion(&mut self, dt: f64, gravity: &Vector3<f64>) {
        match self.drive {
            ProbeDrive::Kinematic => {
                self.free_position = self.target_position;
                self.free_orientation = self.target_orientation;
                self.free_velocity = (self.target_position - self.position) / dt;
                let dq = self.target_orientation * self.orientation.inverse();
                self.free_angular_velocity = dq.scaled_axis() / dt;
                self.inv_mass_eff = 0.0;
                self.inv_inertia_eff = Matrix3::zeros();
            }
            ProbeDrive::Coupled => {
                // (m + dt c + dt² k) v⁺ = m v + dt (k (x_t − x) + m g): the spring is taken at
                // the end of the step, so any stiffness is stable at dt = 10 ms.
                let m_eff = self.mass + dt * self.damping + dt * dt * self.stiffness;
                let rhs = self.mass * self.velocity
                    + dt * (self.stiffness * (self.target_position - self.position)
                        + self.mass * gravity);
                self.inv_mass_eff = 1.0 / m_eff;
                self.free_velocity = rhs * self.inv_mass_eff;
                self.free_position = self.position + dt * self.free_velocity;

                let r = self.orientation.to_rotation_matrix();
                let j_world = r.matrix() * self.inertia_body * r.matrix().transpose();
                let j_eff = j_world
                    + Matrix3::identity()
                        * (dt * self.angular_damping + dt * dt * self.angular_stiffness);
                self.inv_inertia_eff = j_eff.try_inverse().unwrap_or_else(Matrix3::zeros);
                let err = (self.target_orientation * self.orientation.inverse()).scaled_axis();
                let rhs_w = j_world * self.angular_velocity + dt * self.angular_stiffness * err;
                self.free_angular_velocity = self.inv_inertia_eff * rhs_w;
                self.free_orientation =
                    UnitQuaternion::from_scaled_axis(dt * self.free_angular_velocity)
                        * self.orientation;
            }
        }
    }

    /// World position of collision sphere `i` at the start of the step.
    #[inline]
    pub fn sphere_world(&self, i: usize) -> Vector3<f64> {
        self.position + self.orientation * self.spheres[i].local
    }

    /// World position of collision sphere `i` after free motion.
    #[inline]
    pub fn sphere_world_free(&self, i: usize) -> Vector3<f64> {
        self.free_position + self.free_orientation * self.spheres[i].local
    }

    /// Arm of sphere `i` from the free position (the angular part of H is taken about it).
    #[inline]
    pub fn arm_free(&self, i: usize) -> Vector3<f64> {
        self.free_orientation * self.spheres[i].local
    }

    /// Velocity change of the probe for a generalized impulse `[linear; angular]` about the
    /// free position: M_eff⁻¹ (zero for a kinematic probe).
    #[inline]
    pub fn mobility(
        &self,
        linear: &Vector3<f64>,
        angular: &Vector3<f64>,
    ) -> (Vector3<f64>, Vector3<f64>) {
        (linear * self.inv_mass_eff, self.inv_inertia_eff * angular)
    }

    /// Corrected motion: applies the contact impulse (linear, angular about the free position)
    /// on top of the free motion and commits the step.
    pub fn commit(&mut self, dt: f64, impulse: &Vector3<f64>, angular_impulse: &Vector3<f64>) {
        let (dv, dw) = self.mobility(impulse, angular_impulse);
        self.velocity = self.free_velocity + dv;
        self.angular_velocity = self.free_angular_velocity + dw;
        self.position = self.free_position + dt * dv;
        self.orientation = UnitQuaternion::from_scaled_axis(dt * dw) * self.free_orientation;
        if self.drive == ProbeDrive::Kinematic {
            // A prescribed probe ends exactly where it was told to be.
            self.velocity = self.free_velocity;
            self.angular_velocity = self.free_angular_velocity;
        }
    }

    /// Kinetic energy, J (for the energy test and diagnostics).
    pub fn kinetic_energy(&self) -> f64 {
        let r = self.orientation.to_rotation_matrix();
        let j = r.matrix() * self.inertia_body * r.matrix().transpose();
        0.5 * self.mass * self.velocity.norm_squared()
            + 0.5 * self.angular_velocity.dot(&(j * self.angular_velocity))
    }

    /// Potential energy of the coupling spring, J.
    pub fn coupling_energy(&self) -> f64 {
        let dx = self.target_position - self.position;
        let dq = (self.target_orientation * self.orientation.inverse()).scaled_axis();
        0.5 * self.stiffness * dx.norm_squared() + 0.5 * self.angular_stiffness * dq.norm_squared()
    }

    pub fn pose(&self) -> msgs::Pose {
        nalgebra_to_pose(&self.position, &self.orientation)
    }

    pub fn free_pose(&self) -> msgs::Pose {
        nalgebra_to_pose(&self.free_position, &self.free_orientation)
    }

    pub fn target_pose(&self) -> msgs::Pose {
        nalgebra_to_pose(&self.target_position, &self.target_orientation)
    }
}

/// Built-in hook probe: tip sphere at the origin, the hook rising from the tip to the elbow
/// (toward −x and +z), the shaft at 90° to the hook rising from the elbow toward +x and +z
/// (see [`SHAFT_INCLINATION_DEG`]). Segments are sampled with spheres (capsules as chains of
/// balls).
fn builtin_hook(radius: f64) -> Vec<CollisionSphere> {
    let r = radius.max(0.5e-3);
    let mut out = Vec::new();
    let mut push_segment = |a: Vector3<f64>, b: Vector3<f64>, spacing: f64, skip_first: bool| {
        let len = (b - a).norm();
        let n = ((len / spacing).ceil() as usize).max(1);
        for k in 0..=n {
            if k == 0 && skip_first {
                continue;
            }
            out.push(CollisionSphere {
                local: a + (b - a) * (k as f64 / n as f64),
                radius: r,
            });
        }
    };
    let (sin, cos) = SHAFT_INCLINATION_DEG.to_radians().sin_cos();
    let shaft_dir = Vector3::new(sin, 0.0, cos);
    // Elbow → tip, perpendicular to the shaft and pointing down.
    let hook_dir = Vector3::new(cos, 0.0, -sin);
    let tip = Vector3::zeros();
    let elbow = tip - hook_dir * HOOK_LENGTH;
    let top = elbow + shaft_dir * SHAFT_LENGTH;
    // Spacing r leaves valleys of 13% of r between the balls of a chain.
    push_segment(tip, elbow, r, false);
    push_segment(elbow, top, r, true);
    out
}

/// Points of a line collision model read from an OBJ (vertices, and the edges of `l` and `f`
/// elements sampled at twice the contact distance), as spheres of radius 0.
fn obj_line_model(
    path: &Path,
    transform: &launch_config::scene::TransformConfig,
    contact_distance: f64,
) -> Result<Vec<CollisionSphere>, PhysicsError> {
    let text = std::fs::read_to_string(path).map_err(|e| PhysicsError::Io {
        path: path.display().to_string(),
        detail: e.to_string(),
    })?;
    let bad = |line: usize, what: String| PhysicsError::Parse {
        path: path.display().to_string(),
        line,
        detail: what,
    };
    let rot = rotation_from_deg(transform.rotation_deg);
    let t = Vector3::from(transform.translation);
    let mut verts: Vec<Vector3<f64>> = Vec::new();
    let mut edges: Vec<(usize, usize)> = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let mut c = [0.0; 3];
                for v in c.iter_mut() {
                    let s = it.next().ok_or_else(|| {
                        bad(ln + 1, "vertex with fewer than 3 coordinates".into())
                    })?;
                    *v = s
                        .parse::<f64>()
                        .map_err(|_| bad(ln + 1, format!("bad coordinate {s:?}")))?;
                    if !v.is_finite() {
                        return Err(bad(ln + 1, "non-finite coordinate".into()));
                    }
                }
                verts.push(rot * (Vector3::from(c) * transform.scale) + t);
            }
            Some(tag @ ("l" | "f")) => {
                let mut idx = Vec::new();
                for s in it {
                    let first = s.split('/').next().unwrap_or("");
                    let i: i64 = first
                        .parse()
                        .map_err(|_| bad(ln + 1, format!("bad index {s:?}")))?;
                    let i = if i < 0 { verts.len() as i64 + i } else { i - 1 };
                    if i < 0 || i as usize >= verts.len() {
                        return Err(bad(
                            ln + 1,
                            format!("index {s} out of range ({} vertices)", verts.len()),
                        ));
                    }
                    idx.push(i as usize);
                }
                let closed = tag == "f";
                for k in 0..idx.len().saturating_sub(1) {
                    edges.push((idx[k], idx[k + 1]));
                }
                if closed && idx.len() > 2 {
                    edges.push((idx[idx.len() - 1], idx[0]));
                }
            }
            _ => {}
        }
    }
    if verts.is_empty() {
        return Err(bad(0, "no vertices".into()));
    }
    let spacing = (2.0 * contact_distance).max(1e-4);
    // Deduplicate on a grid of a tenth of the spacing, in a BTreeSet: deterministic order.
    let q = spacing * 0.1;
    let mut seen = std::collections::BTreeSet::new();
    let mut out = Vec::new();
    let mut add = |p: Vector3<f64>| {
        let key = (
            (p.x / q).round() as i64,
            (p.y / q).round() as i64,
            (p.z / q).round() as i64,
        );
        if seen.insert(key) {
            out.push(CollisionSphere {
                local: p,
                radius: 0.0,
            });
        }
    };
    for v in &verts {
        add(*v);
    }
    edges.sort_unstable_by_key(|&(a, b)| (a.min(b), a.max(b)));
    edges.dedup_by_key(|e| (e.0.min(e.1), e.0.max(e.1)));
    for &(a, b) in &edges {
        let (pa, pb) = (verts[a], verts[b]);
        let n = ((pb - pa).norm() / spacing).ceil() as usize;
        for k in 1..n {
            add(pa + (pb - pa) * (k as f64 / n as f64));
        }
    }
    Ok(out)
}

/// Rotation from extrinsic x, then y, then z angles in degrees (the scene transform rule).
pub fn rotation_from_deg(deg: [f64; 3]) -> Matrix3<f64> {
    let r = |axis: Vector3<f64>, d: f64| {
        *nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), d.to_radians())
            .matrix()
    };
    r(Vector3::z(), deg[2]) * r(Vector3::y(), deg[1]) * r(Vector3::x(), deg[0])
}

/// Unit direction of the longest bounding-box extent of the collision model (the rod axis).
fn principal_axis(spheres: &[CollisionSphere]) -> Vector3<f64> {
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for s in spheres {
        lo = lo.inf(&s.local);
        hi = hi.sup(&s.local);
    }
    let ext = hi - lo;
    let k = ext.imax();
    let mut axis = Vector3::zeros();
    axis[k] = 1.0;
    axis
}

/// Helper for tests and the bench: a pose at `p` with orientation `q`.
pub fn pose(p: Point3<f64>, q: UnitQuaternion<f64>) -> msgs::Pose {
    nalgebra_to_pose(&p.coords, &q)
}
