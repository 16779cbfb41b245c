//! Physics fault detection and rollback: every step is checked before its frame may be
//! rendered (energy growth without input, a contact force beyond the scene's bound, probe
//! penetration after the correction, LCP and CG convergence). A faulty step is flagged in
//! the frame ([`msgs::physics_to_haptic::physics_fault`]), the state goes back to the last
//! good one (at rest), or to the rest state after repeated faults, and the fault is counted
//! and logged once per kind.
//!
//! Everything here is preallocated at construction: checking, snapshotting and rolling back
//! allocate nothing.

use crate::fem::FemModel;
use crate::probe::Probe;
use launch_config::scene::FaultConfig;
use msgs::physics_to_haptic::physics_fault;
use msgs::MAX_ROWS;
use nalgebra::{Point3, UnitQuaternion, Vector3};

/// What the step reported to the checks.
#[derive(Debug, Clone, Copy, Default)]
pub struct StepReport {
    /// Active contacts in the step.
    pub contacts: usize,
    /// Contact force on the probe, N.
    pub force: [f64; 3],
    /// Relative residual of the free-motion CG (0 for a direct solve).
    pub cg_residual: f64,
    /// The LCP converged (true when there was nothing to solve).
    pub lcp_converged: bool,
    /// Deepest penetration after the contact correction, m (≥ 0).
    pub penetration: f64,
}

/// Probe pose at the last good step.
#[derive(Debug, Clone, Copy)]
struct ProbeSnapshot {
    position: Vector3<f64>,
    orientation: UnitQuaternion<f64>,
}

/// The checks, the last good state and the counters.
#[derive(Debug)]
pub struct FaultMonitor {
    cfg: FaultConfig,
    good_x: Vec<Point3<f64>>,
    good_probe: Option<ProbeSnapshot>,
    /// Tissue mechanical energy (elastic + kinetic + gravity) when the last contact ended, J,
    /// and its scale for the tolerance; None while in contact.
    energy_ref: Option<(f64, f64)>,
    consecutive: u32,
    /// Faulty steps since start.
    pub faulty_steps: u64,
    /// Union of the fault bits seen (each kind is logged once).
    logged: u32,
}

/// Deepest penetration left after the correction: −min over normal rows of δ_free + (W λ)ₙ,
/// clamped at 0. `compliance` is row-major with stride `MAX_ROWS`.
pub fn corrected_penetration(
    compliance: &[f64],
    free_violation: &[f64],
    lambda: &[f64],
    rows: usize,
) -> f64 {
    let mut deepest: f64 = 0.0;
    for n in (0..rows).step_by(3) {
        let w = &compliance[n * MAX_ROWS..n * MAX_ROWS + rows];
        let delta: f64 = free_violation[n]
            + w.iter()
                .zip(&lambda[..rows])
                .map(|(a, b)| a * b)
                .sum::<f64>();
        if delta.is_nan() {
            return f64::INFINITY;
        }
        deepest = deepest.max(-delta);
    }
    deepest
}

impl FaultMonitor {
    pub fn new(cfg: &FaultConfig, fem: &FemModel) -> FaultMonitor {
        FaultMonitor {
            cfg: cfg.clone(),
            good_x: fem.positions().to_vec(),
            good_probe: None,
            energy_ref: None,
            consecutive: 0,
            faulty_steps: 0,
            logged: 0,
        }
    }

    /// Checks a completed step; returns its fault bits (0: good). `fem` is the committed
    /// state after the step.
    pub fn check(&mut self, report: &StepReport, fem: &mut FemModel) -> u32 {
        let c = &self.cfg;
        let mut faults = 0;
        let f = report.force;
        let force = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        if !(force <= c.max_contact_force_n) {
            faults |= physics_fault::FORCE_BOUND;
        }
        if !(report.penetration <= c.max_penetration_m) {
            faults |= physics_fault::PENETRATION;
        }
        if !report.lcp_converged {
            faults |= physics_fault::LCP_NOT_CONVERGED;
        }
        if !(report.cg_residual <= c.max_cg_residual) {
            faults |= physics_fault::CG_NOT_CONVERGED;
        }
        if report.contacts > 0 {
            // Contact is the input: the energy reference restarts when it ends.
            self.energy_ref = None;
        } else {
            let moving = fem.kinetic_energy() + fem.gravity_energy();
            match self.energy_ref {
                None => {
                    // Once per contact release (a full element pass, no allocation).
                    let elastic = fem.elastic_energy();
                    let total = elastic + moving;
                    let scale = elastic + fem.kinetic_energy();
                    if total.is_finite() {
                        self.energy_ref = Some((total, scale));
                    } else {
                        faults |= physics_fault::ENERGY_GROWTH;
                    }
                }
                Some((reference, scale)) => {
                    // Elastic energy ≥ 0, so kinetic + gravity can only exceed the energy at
                    // release if the total grew.
                    let slack = c.energy_tolerance * scale + 1e-9;
                    if !(moving <= reference + slack) {
                        faults |= physics_fault::ENERGY_GROWTH;
                    }
                }
            }
        }
        faults
    }

    /// A step that failed numerically (solver error, non-finite state): logged once, with its
    /// detail, in place of [`Self::roll_back`]'s line for that kind (which only this call
    /// knows the detail of); the fault itself is counted by `roll_back`.
    pub fn note_numerical(&mut self, detail: &str) {
        if self.logged & physics_fault::NUMERICAL == 0 {
            self.logged |= physics_fault::NUMERICAL;
            tracing::warn!(
                tripped = "numerical",
                detail,
                "physics fault: step not rendered, state rolled back (logged once per kind)"
            );
        }
    }

    /// Remembers the committed state of a good step.
    pub fn commit_good(&mut self, fem: &FemModel, probe: &Probe) {
        self.good_x.copy_from_slice(fem.positions());
        self.good_probe = Some(ProbeSnapshot {
            position: probe.position,
            orientation: probe.orientation,
        });
        self.consecutive = 0;
    }

    /// Rolls a faulty step back: the last good positions at rest, or the rest state after
    /// `rest_after_faults` faults in a row. Counts the fault and logs each kind once.
    /// Returns true when it went back to the rest state.
    pub fn roll_back(
        &mut self,
        faults: u32,
        time: f64,
        fem: &mut FemModel,
        probe: &mut Probe,
    ) -> bool {
        self.faulty_steps += 1;
        self.consecutive += 1;
        let new_kinds = faults & !self.logged;
        if new_kinds != 0 {
            self.logged |= new_kinds;
            let what: Vec<&str> = physics_fault::names(new_kinds).collect();
            tracing::warn!(
                time_s = time,
                tripped = what.join(", "),
                "physics fault: step not rendered, state rolled back (logged once per kind)"
            );
        }
        let to_rest = self.consecutive >= self.cfg.rest_after_faults.max(1);
        let zero = Vector3::zeros();
        for n in 0..fem.node_count() {
            let p = if to_rest {
                fem.rest_positions()[n]
            } else {
                self.good_x[n]
            };
            // Both only fail for an out-of-range node or a non-finite value: neither here.
            let _ = fem.set_position(n, p);
            let _ = fem.set_velocity(n, zero);
        }
        if let Some(s) = self.good_probe {
            probe.position = s.position;
            probe.orientation = s.orientation;
            probe.free_position = s.position;
            probe.free_orientation = s.orientation;
        }
        probe.velocity = zero;
        probe.angular_velocity = zero;
        probe.free_velocity = zero;
        probe.free_angular_velocity = zero;
        self.energy_ref = None;
        if to_rest {
            self.good_x.copy_from_slice(fem.positions());
            self.consecutive = 0;
        }
        to_rest
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrected_penetration_reads_normal_rows_only() {
        let mut w = vec![0.0; MAX_ROWS * MAX_ROWS];
        // Two contacts; the first normal row is corrected by its own impulse.
        w[0] = 1e-3;
        let mut dfree = [0.0; 6];
        dfree[0] = -2e-3;
        dfree[1] = -1.0; // a tangent row: ignored
        dfree[3] = -5e-4;
        let mut lambda = [0.0; 6];
        lambda[0] = 1.0; // δ₀ = −2 mm + 1 mm
        let p = corrected_penetration(&w, &dfree, &lambda, 6);
        assert!((p - 1e-3).abs() < 1e-12, "{p}");
        lambda[0] = 3.0;
        let p = corrected_penetration(&w, &dfree, &lambda, 6);
        assert!((p - 5e-4).abs() < 1e-12, "{p}");
        dfree[3] = f64::NAN;
        assert!(corrected_penetration(&w, &dfree, &lambda, 6).is_infinite());
    }

    /// A 1 cm cube held at its base, at rest (gravity on), and a probe.
    fn cube() -> (FemModel, Probe) {
        use crate::fem::test_meshes::{box_mesh, nodes_where};
        use crate::fem::{FemSettings, Material};
        let mesh = box_mesh(0.01, 0.01, 0.01, 2, 2, 2);
        let fixed = nodes_where(&mesh, |p| p.z < 1e-9);
        let fem = FemModel::new(&mesh, Material::lateral(), &fixed, FemSettings::default())
            .expect("cube model");
        let cfg = launch_config::scene::ProbeConfig::default();
        let probe = Probe::new(&cfg, 1.1e-3, std::path::Path::new(".")).expect("probe");
        (fem, probe)
    }

    fn good_step() -> StepReport {
        StepReport {
            contacts: 1,
            force: [0.0, 0.0, 2.0],
            cg_residual: 1e-3,
            lcp_converged: true,
            penetration: 1e-4,
        }
    }

    /// Each check trips its own bit, and only its own: a diverged force (or a NaN one),
    /// a deep penetration, an unconverged LCP or CG, and kinetic energy appearing without
    /// contact. The divergence regression test (`tests/fault_divergence.rs`) exercises the
    /// force bound end to end; the other kinds are only reachable here.
    #[test]
    fn every_check_trips_its_own_fault_bit() {
        let (mut fem, _) = cube();
        let cfg = FaultConfig::default();
        let mut m = FaultMonitor::new(&cfg, &fem);
        assert_eq!(m.check(&good_step(), &mut fem), 0);
        type Spoil = fn(&mut StepReport);
        let cases: [(u32, Spoil); 6] = [
            (physics_fault::FORCE_BOUND, |r| r.force = [0.0, 1e4, 0.0]),
            (physics_fault::FORCE_BOUND, |r| r.force[2] = f64::NAN),
            (physics_fault::PENETRATION, |r| r.penetration = 1e-2),
            (physics_fault::PENETRATION, |r| r.penetration = f64::NAN),
            (physics_fault::LCP_NOT_CONVERGED, |r| {
                r.lcp_converged = false
            }),
            (physics_fault::CG_NOT_CONVERGED, |r| r.cg_residual = 5.0),
        ];
        for (bit, spoil) in cases {
            let mut r = good_step();
            spoil(&mut r);
            assert_eq!(m.check(&r, &mut fem), bit, "{r:?}");
        }
        // No contact: the first step sets the energy reference, a still tissue passes.
        let free = StepReport {
            contacts: 0,
            force: [0.0; 3],
            ..good_step()
        };
        assert_eq!(m.check(&free, &mut fem), 0);
        assert_eq!(m.check(&free, &mut fem), 0);
        // Kinetic energy from nowhere (no contact, no load): energy growth.
        for n in 0..fem.node_count() {
            fem.set_velocity(n, Vector3::new(0.0, 0.0, 0.5)).unwrap();
        }
        assert_eq!(m.check(&free, &mut fem), physics_fault::ENERGY_GROWTH);
        // Contact is an input: the same motion in contact is not energy growth, and the
        // reference restarts when the contact ends (this state becomes the new one).
        assert_eq!(m.check(&good_step(), &mut fem), 0);
        assert_eq!(m.check(&free, &mut fem), 0);
    }

    /// A faulty step goes back to the last good state at rest; faults in a row go back to
    /// the rest state. Both are counted.
    #[test]
    fn roll_back_restores_the_last_good_state_then_the_rest_state() {
        let (mut fem, mut probe) = cube();
        let cfg = FaultConfig {
            rest_after_faults: 2,
            ..FaultConfig::default()
        };
        let mut m = FaultMonitor::new(&cfg, &fem);
        let top = (0..fem.node_count())
            .max_by(|&a, &b| {
                fem.rest_positions()[a]
                    .z
                    .total_cmp(&fem.rest_positions()[b].z)
            })
            .unwrap();
        let rest = fem.rest_positions()[top];
        let good = rest + Vector3::new(0.0, 0.0, -1e-4);
        fem.set_position(top, good).unwrap();
        probe.position = Vector3::new(0.0, 0.0, 0.02);
        m.commit_good(&fem, &probe);
        // A diverged step moved both.
        fem.set_position(top, rest + Vector3::new(0.0, 0.0, 0.5))
            .unwrap();
        fem.set_velocity(top, Vector3::new(9.0, 0.0, 0.0)).unwrap();
        probe.position = Vector3::new(1.0, 0.0, 0.0);
        probe.velocity = Vector3::new(3.0, 0.0, 0.0);
        let to_rest = m.roll_back(physics_fault::FORCE_BOUND, 0.01, &mut fem, &mut probe);
        assert!(!to_rest);
        assert_eq!(fem.positions()[top], good);
        assert_eq!(fem.kinetic_energy(), 0.0);
        assert_eq!(probe.position, Vector3::new(0.0, 0.0, 0.02));
        assert_eq!(probe.velocity, Vector3::zeros());
        // A second fault in a row: back to the rest state.
        fem.set_position(top, rest + Vector3::new(0.0, 0.0, 0.5))
            .unwrap();
        let to_rest = m.roll_back(physics_fault::NUMERICAL, 0.02, &mut fem, &mut probe);
        assert!(to_rest);
        assert_eq!(fem.positions()[top], rest);
        assert_eq!(m.faulty_steps, 2);
    }
}
