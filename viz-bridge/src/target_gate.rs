//! The gate a remote probe target passes before it reaches physics: off unless
//! `[bridge] accept_target_pose`, and then finite, a unit quaternion, inside the workspace box,
//! no farther than `max_jump_m` from where the probe is (or was last sent), and no faster
//! than `max_rate_hz`. Every refusal is counted by reason (reported on `/diagnostics`).
//!
//! Pure logic with an explicit clock, so the bounds are tested without DDS.

use launch_config::bridge::TargetPoseLimits;
use msgs::Pose;

/// A previously accepted target stops being the jump reference after this long without a
/// new one, s: physics releases the probe back to the device after 0.5 s, so the reference
/// is then the probe itself.
const REFERENCE_HOLD_S: f64 = 0.5;

/// Why a target was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// `accept_target_pose = false`.
    Disabled,
    /// Not finite, or the quaternion is far from unit length.
    Malformed,
    /// Outside the workspace box (or no box known yet).
    Workspace,
    /// Too far from the reference position.
    Jump,
    /// Faster than the rate limit.
    Rate,
}

impl Refusal {
    pub const ALL: [Refusal; 5] = [
        Refusal::Disabled,
        Refusal::Malformed,
        Refusal::Workspace,
        Refusal::Jump,
        Refusal::Rate,
    ];

    /// Key suffix in `/diagnostics`.
    pub fn name(self) -> &'static str {
        match self {
            Refusal::Disabled => "disabled",
            Refusal::Malformed => "malformed",
            Refusal::Workspace => "outside_workspace",
            Refusal::Jump => "jump",
            Refusal::Rate => "rate",
        }
    }
}

/// Axis-aligned box, world m.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Workspace {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Workspace {
    pub fn contains(&self, p: &[f64; 3]) -> bool {
        (0..3).all(|k| p[k] >= self.min[k] && p[k] <= self.max[k])
    }

    /// Bounds of `points` grown by `margin` on every side (None for no finite point).
    pub fn around(points: impl Iterator<Item = [f64; 3]>, margin: f64) -> Option<Workspace> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut any = false;
        for p in points.filter(|p| p.iter().all(|v| v.is_finite())) {
            any = true;
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        any.then(|| Workspace {
            min: lo.map(|v| v - margin),
            max: hi.map(|v| v + margin),
        })
    }
}

/// The gate's state.
#[derive(Debug)]
pub struct TargetGate {
    accept: bool,
    limits: TargetPoseLimits,
    workspace: Option<Workspace>,
    /// Newest probe position physics reported (contact frames), world m.
    probe: Option<[f64; 3]>,
    /// Last accepted target: position and time, s.
    last: Option<([f64; 3], f64)>,
    refused: [u64; 5],
    accepted: u64,
}

impl TargetGate {
    pub fn new(accept: bool, limits: &TargetPoseLimits) -> TargetGate {
        let workspace = match (limits.workspace_min, limits.workspace_max) {
            (Some(min), Some(max)) => Some(Workspace { min, max }),
            _ => None,
        };
        TargetGate {
            accept,
            limits: limits.clone(),
            workspace,
            probe: None,
            last: None,
            refused: [0; 5],
            accepted: 0,
        }
    }

    /// True when the workspace still has to come from the scene (no box configured, none
    /// derived yet).
    pub fn needs_workspace(&self) -> bool {
        self.workspace.is_none()
    }

    /// Derives the workspace from the scene's surface points (first surface frame), unless a
    /// box was configured or already derived.
    pub fn set_scene_points(&mut self, points: impl Iterator<Item = [f64; 3]>) {
        if self.workspace.is_none() {
            self.workspace = Workspace::around(points, self.limits.workspace_margin_m);
            if let Some(w) = &self.workspace {
                tracing::info!(min = ?w.min, max = ?w.max, "target-pose workspace from the scene");
            }
        }
    }

    pub fn workspace(&self) -> Option<Workspace> {
        self.workspace
    }

    /// The probe's current position (from physics).
    pub fn set_probe_position(&mut self, p: [f64; 3]) {
        if p.iter().all(|v| v.is_finite()) {
            self.probe = Some(p);
        }
    }

    /// Decides on one target received at `now_s`; the pose is returned normalised when
    /// accepted. A refusal leaves the references untouched (a refused jump does not move
    /// the reference, so a sequence of small refused steps cannot walk the probe away).
    pub fn check(&mut self, pose: &Pose, now_s: f64) -> Result<Pose, Refusal> {
        let r = self.decide(pose, now_s);
        match &r {
            Ok(p) => {
                self.accepted += 1;
                self.last = Some((p.position, now_s));
            }
            Err(why) => self.refused[*why as usize] += 1,
        }
        r
    }

    fn decide(&self, pose: &Pose, now_s: f64) -> Result<Pose, Refusal> {
        if !self.accept {
            return Err(Refusal::Disabled);
        }
        let norm: f64 = pose.orientation.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !pose.is_finite() || (norm - 1.0).abs() > 1e-3 {
            return Err(Refusal::Malformed);
        }
        match &self.workspace {
            Some(w) if w.contains(&pose.position) => {}
            _ => return Err(Refusal::Workspace),
        }
        let recent = self
            .last
            .filter(|(_, t)| now_s - *t < REFERENCE_HOLD_S && now_s >= *t);
        if let Some((_, t)) = recent {
            if now_s - t < 1.0 / self.limits.max_rate_hz {
                return Err(Refusal::Rate);
            }
        }
        let reference = match (recent, self.probe) {
            (Some((p, _)), _) => p,
            (None, Some(p)) => p,
            // Nothing known about where the probe is: no jump can be bounded.
            (None, None) => return Err(Refusal::Jump),
        };
        let d: f64 = (0..3)
            .map(|k| (pose.position[k] - reference[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        if d > self.limits.max_jump_m {
            return Err(Refusal::Jump);
        }
        let mut out = *pose;
        for q in &mut out.orientation {
            *q /= norm;
        }
        Ok(out)
    }

    pub fn refused(&self, why: Refusal) -> u64 {
        self.refused[why as usize]
    }

    pub fn refused_total(&self) -> u64 {
        self.refused.iter().sum()
    }

    pub fn accepted(&self) -> u64 {
        self.accepted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(x: f64, y: f64, z: f64) -> Pose {
        Pose {
            position: [x, y, z],
            orientation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    fn gate() -> TargetGate {
        let mut g = TargetGate::new(true, &TargetPoseLimits::default());
        g.set_scene_points([[-0.02, -0.02, 0.0], [0.02, 0.02, 0.01]].into_iter());
        g.set_probe_position([0.0, 0.0, 0.02]);
        g
    }

    #[test]
    fn refused_when_disabled_whatever_the_pose() {
        let mut g = TargetGate::new(false, &TargetPoseLimits::default());
        g.set_scene_points([[0.0; 3]].into_iter());
        g.set_probe_position([0.0; 3]);
        assert_eq!(g.check(&at(0.0, 0.0, 0.0), 0.0), Err(Refusal::Disabled));
        assert_eq!(g.refused(Refusal::Disabled), 1);
        assert_eq!(g.accepted(), 0);
    }

    #[test]
    fn malformed_far_jumping_and_fast_targets_are_refused_and_counted() {
        let mut g = gate();
        assert_eq!(
            g.check(&at(f64::NAN, 0.0, 0.0), 0.0),
            Err(Refusal::Malformed)
        );
        let mut q = at(0.0, 0.0, 0.02);
        q.orientation = [0.0, 0.0, 0.0, 2.0];
        assert_eq!(g.check(&q, 0.0), Err(Refusal::Malformed));
        // 875 mm away: outside the box (scene ±20 mm grown by 20 mm).
        assert_eq!(g.check(&at(0.875, 0.0, 0.0), 0.0), Err(Refusal::Workspace));
        // Inside the box but 30 mm from the probe.
        assert_eq!(g.check(&at(0.0, 0.0, -0.01), 0.0), Err(Refusal::Jump));
        // A small step is accepted; another one 1 ms later is too fast.
        assert!(g.check(&at(0.0, 0.0, 0.018), 0.0).is_ok());
        assert_eq!(g.check(&at(0.0, 0.0, 0.017), 0.001), Err(Refusal::Rate));
        assert!(g.check(&at(0.0, 0.0, 0.016), 0.011).is_ok());
        // Refused jumps do not move the reference: walking in 4 mm steps stops at the first
        // step past the limit from the last accepted target.
        assert_eq!(g.check(&at(0.0, 0.0, 0.010), 0.03), Err(Refusal::Jump));
        assert_eq!(g.refused(Refusal::Malformed), 2);
        assert_eq!(g.refused(Refusal::Workspace), 1);
        assert_eq!(g.refused(Refusal::Jump), 2);
        assert_eq!(g.refused(Refusal::Rate), 1);
        assert_eq!(g.accepted(), 2);
        assert_eq!(g.refused_total(), 6);
    }

    #[test]
    fn no_workspace_or_probe_known_refuses() {
        let mut g = TargetGate::new(true, &TargetPoseLimits::default());
        assert_eq!(g.check(&at(0.0, 0.0, 0.0), 0.0), Err(Refusal::Workspace));
        g.set_scene_points([[0.0; 3]].into_iter());
        assert_eq!(g.check(&at(0.0, 0.0, 0.0), 0.0), Err(Refusal::Jump));
        g.set_probe_position([0.0, 0.0, 0.001]);
        assert!(g.check(&at(0.0, 0.0, 0.0), 0.0).is_ok());
    }

    #[test]
    fn configured_box_wins_over_the_scene() {
        let limits = TargetPoseLimits {
            workspace_min: Some([-0.001; 3]),
            workspace_max: Some([0.001; 3]),
            ..TargetPoseLimits::default()
        };
        let mut g = TargetGate::new(true, &limits);
        g.set_scene_points([[-1.0; 3], [1.0; 3]].into_iter());
        g.set_probe_position([0.0; 3]);
        assert_eq!(g.check(&at(0.002, 0.0, 0.0), 0.0), Err(Refusal::Workspace));
        assert!(g.check(&at(0.0005, 0.0, 0.0), 0.0).is_ok());
    }
}
