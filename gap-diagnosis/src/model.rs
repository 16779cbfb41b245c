//! The force model the diagnosis replays trials through, behind a small trait so the
//! statistics can be developed and tested independently of the FE model.
use super::signal::{quat_conj, quat_mul, quat_rotate, quat_tilt};
use super::GapError;
use msgs::Pose;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A prescribed probe path on a uniform time grid `t0 + k dt`, k = 0..poses.len().
#[derive(Debug, Clone)]
pub struct ProbePath {
    pub t0: f64,
    pub dt: f64,
    pub poses: Vec<Pose>,
}

impl ProbePath {
    /// The probe's position at each grid step.
    pub fn positions(&self) -> Vec<[f64; 3]> {
        self.poses.iter().map(|p| p.position).collect()
    }
}

/// The model variations that need a re-simulation (everything else is post-processing).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variant {
    /// Global modulus scale.
    pub modulus_scale: f64,
    /// Neo-Hookean (stable neo-Hookean) instead of linear corotational.
    pub neo_hookean: bool,
    /// Coulomb friction coefficient.
    pub friction: f64,
    /// Specimen frame rotated about world x then y, radians.
    pub tilt: [f64; 2],
    /// 0: fixed inferior nodes; > 0: elastic support, N/m per node.
    pub support_stiffness: f64,
    /// Refined discretisation of the same specimen.
    pub fine_mesh: bool,
    /// Compliance of a penalty layer between probe and tissue, m/N per probe ball, added to
    /// the scene's (`[scene.contact] interface_compliance`): the contact nuisance's knot
    /// ([`crate::fit::CONTACT_KNOT`]).
    #[serde(default)]
    pub interface_compliance: f64,
}

impl Default for Variant {
    fn default() -> Self {
        Variant {
            modulus_scale: 1.0,
            neo_hookean: false,
            friction: 0.0,
            tilt: [0.0; 2],
            support_stiffness: 0.0,
            fine_mesh: false,
            interface_compliance: 0.0,
        }
    }
}

impl Variant {
    pub fn label(&self) -> String {
        let mut s = Vec::new();
        if self.modulus_scale != 1.0 {
            s.push(format!("E×{:.3}", self.modulus_scale));
        }
        if self.neo_hookean {
            s.push("neo-Hookean".into());
        }
        if self.friction != 0.0 {
            s.push(format!("μ={:.2}", self.friction));
        }
        if self.tilt != [0.0; 2] {
            s.push(format!(
                "tilt=({:.1}°,{:.1}°)",
                self.tilt[0].to_degrees(),
                self.tilt[1].to_degrees()
            ));
        }
        if self.support_stiffness > 0.0 {
            s.push(format!("support={:.0} N/m", self.support_stiffness));
        }
        if self.fine_mesh {
            s.push("fine mesh".into());
        }
        if self.interface_compliance > 0.0 {
            s.push(format!(
                "contact interface {:.0} N/mm",
                1e-3 / self.interface_compliance
            ));
        }
        if s.is_empty() {
            "baseline".into()
        } else {
            s.join(", ")
        }
    }
}

/// Replays a probe path kinematically and returns the force the tissue exerts on the probe at
/// every grid point (after the step that reaches that pose), world frame, N.
/// Implementations handle every field of [`Variant`] except `tilt`, which [`replay`] applies
/// by rotating the trajectory into the specimen frame.
pub trait ForceModel: Sync + Send {
    fn replay_untilted(
        &self,
        variant: &Variant,
        path: &ProbePath,
    ) -> Result<Vec<[f64; 3]>, GapError>;
    /// The replay with the number of steps the model itself flagged as faulty (the physics'
    /// per-step checks: a diverged contact solve, energy growth, ...). Models without such
    /// checks report none.
    fn replay_untilted_checked(
        &self,
        variant: &Variant,
        path: &ProbePath,
    ) -> Result<Replayed, GapError> {
        Ok(Replayed {
            forces: self.replay_untilted(variant, path)?,
            faulty_steps: 0,
        })
    }
    /// Short description for reports.
    fn describe(&self) -> String;
    /// A refined discretisation exists (the `mesh` effect can be assessed).
    fn has_refinement(&self) -> bool {
        true
    }
    /// What a variant's support stiffness (N/m per node of the replay's mesh) is, in those
    /// units, once this model has applied it: 1 for a model that takes it as it is. A truth
    /// levelled with the replay stiffens its support with its tissue, and the diagnosis then
    /// sees, and should fit, the levelled support ([`crate::recovery`] grades against it).
    fn support_scale(&self) -> f64 {
        1.0
    }
}

/// A replay's forces and how many of its steps the model flagged as faulty.
#[derive(Debug, Clone, PartialEq)]
pub struct Replayed {
    pub forces: Vec<[f64; 3]>,
    pub faulty_steps: u64,
}

impl Replayed {
    /// The physics flagged a step, or a force is not finite: not a solution.
    pub fn diverged(&self) -> bool {
        self.faulty_steps > 0 || self.forces.iter().flatten().any(|v| !v.is_finite())
    }
}

/// A model that counts the replays made through it, so a diagnosis can say how many each of
/// its stages made ([`crate::StageTimes`]): its time is almost all replays, and their number,
/// not their cost, is what differs between an effect alone and a pair.
pub struct Counting<'a> {
    inner: &'a dyn ForceModel,
    made: AtomicUsize,
}

impl<'a> Counting<'a> {
    pub fn new(inner: &'a dyn ForceModel) -> Self {
        Counting {
            inner,
            made: AtomicUsize::new(0),
        }
    }
    /// Replays made through it so far.
    pub fn made(&self) -> usize {
        self.made.load(Ordering::Relaxed)
    }
}

impl ForceModel for Counting<'_> {
    fn replay_untilted(&self, v: &Variant, p: &ProbePath) -> Result<Vec<[f64; 3]>, GapError> {
        self.made.fetch_add(1, Ordering::Relaxed);
        self.inner.replay_untilted(v, p)
    }
    fn replay_untilted_checked(&self, v: &Variant, p: &ProbePath) -> Result<Replayed, GapError> {
        // the inner model's own default calls its own unchecked replay, not this one's: one
        // count per replay
        self.made.fetch_add(1, Ordering::Relaxed);
        self.inner.replay_untilted_checked(v, p)
    }
    fn describe(&self) -> String {
        self.inner.describe()
    }
    fn has_refinement(&self) -> bool {
        self.inner.has_refinement()
    }
    fn support_scale(&self) -> f64 {
        self.inner.support_scale()
    }
}

/// Replay with the specimen tilted: a specimen rotated by R in the world sees the probe path
/// R⁻¹·p (about the world origin = specimen footprint centre), and its force comes back as R·f.
pub fn replay(
    model: &dyn ForceModel,
    variant: &Variant,
    path: &ProbePath,
) -> Result<Vec<[f64; 3]>, GapError> {
    replay_checked(model, variant, path).map(|r| r.forces)
}

/// [`replay`] with the model's count of faulty steps.
pub fn replay_checked(
    model: &dyn ForceModel,
    variant: &Variant,
    path: &ProbePath,
) -> Result<Replayed, GapError> {
    if variant.tilt == [0.0; 2] {
        return model.replay_untilted_checked(variant, path);
    }
    let r = quat_tilt(variant.tilt[0], variant.tilt[1]);
    let ri = quat_conj(r);
    let local = ProbePath {
        t0: path.t0,
        dt: path.dt,
        poses: path
            .poses
            .iter()
            .map(|p| Pose {
                position: quat_rotate(ri, p.position),
                orientation: quat_mul(ri, p.orientation),
            })
            .collect(),
    };
    let mut v = variant.clone();
    v.tilt = [0.0; 2];
    let mut out = model.replay_untilted_checked(&v, &local)?;
    for x in out.forces.iter_mut() {
        *x = quat_rotate(r, *x);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model whose physics flags `faulty` steps while its forces stay finite and small:
    /// what a caught divergence looks like after the rollback.
    struct Flagging {
        faulty: u64,
    }

    impl ForceModel for Flagging {
        fn replay_untilted(
            &self,
            _: &Variant,
            path: &ProbePath,
        ) -> Result<Vec<[f64; 3]>, GapError> {
            Ok(vec![[0.0, 0.0, 1.0]; path.poses.len()])
        }
        fn replay_untilted_checked(
            &self,
            v: &Variant,
            path: &ProbePath,
        ) -> Result<Replayed, GapError> {
            Ok(Replayed {
                forces: self.replay_untilted(v, path)?,
                faulty_steps: self.faulty,
            })
        }
        fn describe(&self) -> String {
            "flagging".into()
        }
    }

    /// A probe held still for `n` steps of 10 ms.
    fn still_path(n: usize) -> ProbePath {
        ProbePath {
            t0: 0.0,
            dt: 0.01,
            poses: vec![Pose::IDENTITY; n],
        }
    }

    fn tilted_by(tilt: [f64; 2]) -> Variant {
        Variant {
            tilt,
            ..Variant::default()
        }
    }

    /// A replay is diverged when the physics flagged a step, whatever its forces look like
    /// (issue 14: the diagnosis reads the fault flag, not a force heuristic), also through
    /// the tilt's rotation of the path; unflagged finite forces are a solution.
    #[test]
    fn a_replay_is_diverged_by_the_physics_fault_flag() {
        let path = still_path(5);
        let tilted = tilted_by([0.10472, 0.0]);
        for variant in [Variant::default(), tilted] {
            let r = replay_checked(&Flagging { faulty: 1 }, &variant, &path).unwrap();
            assert!(
                r.diverged(),
                "{variant:?}: a flagged step is a diverged replay"
            );
            assert_eq!(r.forces.len(), 5);
            let r = replay_checked(&Flagging { faulty: 0 }, &variant, &path).unwrap();
            assert!(!r.diverged(), "{variant:?}");
        }
        // Without a flag, a non-finite force is still not a solution.
        let r = Replayed {
            forces: vec![[f64::NAN, 0.0, 0.0]],
            faulty_steps: 0,
        };
        assert!(r.diverged());
    }

    /// Each replay through [`Counting`] is one, tilted (the path turned, then the untilted
    /// checked replay) or not, and a model whose checked replay is its default (which calls
    /// its own unchecked one) is not counted twice.
    #[test]
    fn a_counted_replay_counts_once_tilted_or_not() {
        struct Plain;
        impl ForceModel for Plain {
            fn replay_untilted(
                &self,
                _: &Variant,
                path: &ProbePath,
            ) -> Result<Vec<[f64; 3]>, GapError> {
                Ok(vec![[0.0, 0.0, 1.0]; path.poses.len()])
            }
            fn describe(&self) -> String {
                "plain".into()
            }
        }
        let path = still_path(3);
        let tilted = tilted_by([0.0, 0.05]);
        for inner in [&Plain as &dyn ForceModel, &Flagging { faulty: 0 }] {
            let counted = Counting::new(inner);
            assert_eq!(counted.made(), 0);
            replay_checked(&counted, &Variant::default(), &path).unwrap();
            replay_checked(&counted, &tilted, &path).unwrap();
            replay(&counted, &tilted, &path).unwrap();
            assert_eq!(counted.made(), 3, "{}", inner.describe());
            assert_eq!(counted.describe(), inner.describe());
        }
    }
}
