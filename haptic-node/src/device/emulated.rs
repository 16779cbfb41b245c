//! Touch emulator: the stylus end effector as a point mass with linkage friction and damping,
//! motor saturation, workspace stops and encoder quantisation, held by an operator's hand
//! through a grip spring–damper. The hand follows the probing protocol ([`Protocol`]).
//!
//! Because the hand presses through the grip, a steady contact with the stylus at rest
//! carries the grip force on top of the instrument's weight: the device reads more than the
//! probe's m·g, as the study saw. The emulated Touch is counterbalanced (as the real one is),
//! so gravity does not act on the end-effector mass; the emulator has no linkage
//! kinematics, so joint angles are reported as zero.

use super::operator::{HandState, Protocol};
use super::{Device, DeviceError, DeviceSample};
use launch_config::device::EmulatedConfig;
use msgs::haptic_to_physics::DeviceKind;
use msgs::Pose;

/// Integration step of the emulated mechanics, s (finer than the servo tick for the stiff
/// grip and contact).
const SUBSTEP_S: f64 = 0.000_25;
/// Longest gap integrated at once; a longer stall is not caught up (the hand just moves on).
const MAX_CATCH_UP_S: f64 = 0.05;
/// Velocity below which linkage friction is smoothed (avoids chatter at rest), m/s.
const FRICTION_SMOOTHING_M_PER_S: f64 = 0.002;

pub struct EmulatedTouch {
    c: EmulatedConfig,
    protocol: Protocol,
    start_ns: u64,
    last_ns: u64,
    position: [f64; 3],
    velocity: [f64; 3],
    /// Motor force commanded (after saturation), held between ticks.
    force: [f64; 3],
    hand: HandState,
}

impl EmulatedTouch {
    pub fn new(
        c: &EmulatedConfig,
        mut protocol: Protocol,
        start_ns: u64,
    ) -> Result<EmulatedTouch, DeviceError> {
        for (v, name) in [
            (c.mass_kg, "mass_kg"),
            (c.saturation_n, "saturation_n"),
            (c.grip_stiffness_n_per_m, "grip_stiffness_n_per_m"),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(DeviceError::Emulated(format!(
                    "[device.emulated] {name} = {v} must be > 0"
                )));
            }
        }
        for (v, name) in [
            (c.friction_n, "friction_n"),
            (c.damping_n_s_per_m, "damping_n_s_per_m"),
            (c.quantisation_m, "quantisation_m"),
            (c.grip_damping_n_s_per_m, "grip_damping_n_s_per_m"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(DeviceError::Emulated(format!(
                    "[device.emulated] {name} = {v} must be ≥ 0"
                )));
            }
        }
        if (0..3).any(|k| !(c.workspace_min_m[k] < c.workspace_max_m[k])) {
            return Err(DeviceError::Emulated(
                "[device.emulated] workspace_min_m must be below workspace_max_m".into(),
            ));
        }
        let hand = protocol.hand(0.0);
        Ok(EmulatedTouch {
            c: c.clone(),
            position: hand.position,
            velocity: [0.0; 3],
            force: [0.0; 3],
            hand,
            protocol,
            start_ns,
            last_ns: start_ns,
        })
    }

    /// The hand (operator model) at the last sample.
    pub fn hand(&self) -> &HandState {
        &self.hand
    }

    /// True end-effector position (not quantised).
    pub fn true_position(&self) -> [f64; 3] {
        self.position
    }

    pub fn true_velocity(&self) -> [f64; 3] {
        self.velocity
    }

    /// Advances the mechanics to `now_ns` under the held motor force.
    fn advance(&mut self, now_ns: u64) {
        let mut remaining = (now_ns.saturating_sub(self.last_ns) as f64 * 1e-9).min(MAX_CATCH_UP_S);
        let mut t = self.last_ns.saturating_sub(self.start_ns) as f64 * 1e-9;
        self.last_ns = now_ns.max(self.last_ns);
        while remaining > 1e-12 {
            let h = remaining.min(SUBSTEP_S);
            remaining -= h;
            t += h;
            // The hand presses by what it feels: the motor force along the site normal.
            let n = self.protocol.normal();
            let felt = self.force[0] * n[0] + self.force[1] * n[1] + self.force[2] * n[2];
            self.hand = self.protocol.hand_feeling(t, felt);
            let c = &self.c;
            let mut f = self.force;
            for k in 0..3 {
                let v = self.velocity[k];
                f[k] += c.grip_stiffness_n_per_m * (self.hand.position[k] - self.position[k])
                    + c.grip_damping_n_s_per_m * (self.hand.velocity[k] - v)
                    - c.damping_n_s_per_m * v;
            }
            let speed = (self.velocity.iter().map(|v| v * v).sum::<f64>()).sqrt();
            if speed > 0.0 {
                // Coulomb friction opposing motion, smoothed near rest.
                let mag = c.friction_n * (speed / FRICTION_SMOOTHING_M_PER_S).tanh() / speed;
                for k in 0..3 {
                    f[k] -= mag * self.velocity[k];
                }
            }
            // Semi-implicit Euler.
            for k in 0..3 {
                self.velocity[k] += h * f[k] / c.mass_kg;
                self.position[k] += h * self.velocity[k];
                // Workspace stops: the linkage hits its limit and stops there.
                if self.position[k] < c.workspace_min_m[k] {
                    self.position[k] = c.workspace_min_m[k];
                    self.velocity[k] = self.velocity[k].max(0.0);
                } else if self.position[k] > c.workspace_max_m[k] {
                    self.position[k] = c.workspace_max_m[k];
                    self.velocity[k] = self.velocity[k].min(0.0);
                }
            }
        }
    }

    fn quantise(&self, x: f64) -> f64 {
        let q = self.c.quantisation_m;
        if q > 0.0 {
            (x / q).round() * q
        } else {
            x
        }
    }
}

impl Device for EmulatedTouch {
    fn kind(&self) -> DeviceKind {
        DeviceKind::Emulated
    }

    fn sample(&mut self, now_ns: u64, out: &mut DeviceSample) -> Result<(), DeviceError> {
        self.advance(now_ns);
        out.pose = Pose {
            position: [
                self.quantise(self.position[0]),
                self.quantise(self.position[1]),
                self.quantise(self.position[2]),
            ],
            orientation: [0.0, 0.0, 0.0, 1.0],
        };
        out.velocity = [
            self.velocity[0],
            self.velocity[1],
            self.velocity[2],
            0.0,
            0.0,
            0.0,
        ];
        out.joint_angles = [0.0; 6];
        let h = &self.hand;
        // Button 1 held while the operator presses and holds (as a trigger marking the probing).
        out.buttons = matches!(
            h.phase,
            super::operator::Phase::Press | super::operator::Phase::Hold
        ) as u32;
        out.probing_index = h.probing;
        out.region = h.region;
        out.phase = h.phase as u32;
        Ok(())
    }

    fn command_force(&mut self, _now_ns: u64, force: [f64; 3]) -> Result<(), DeviceError> {
        let f = if force.iter().all(|v| v.is_finite()) {
            force
        } else {
            [0.0; 3]
        };
        let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        let s = if n > self.c.saturation_n {
            self.c.saturation_n / n
        } else {
            1.0
        };
        self.force = [f[0] * s, f[1] * s, f[2] * s];
        Ok(())
    }

    fn zero_force(&mut self) {
        self.force = [0.0; 3];
    }

    fn finished(&self) -> bool {
        self.hand.finished
    }
}

#[cfg(test)]
mod tests {
    use super::super::operator::{plane_sites, Phase};
    use super::*;

    const MS: u64 = 1_000_000;

    fn emulator(c: &EmulatedConfig) -> EmulatedTouch {
        let p = Protocol::new(c, &plane_sites(0.0, 5)).unwrap();
        EmulatedTouch::new(c, p, 0).unwrap()
    }

    #[test]
    fn steady_contact_at_rest_reads_more_than_the_probe_weight() {
        // Stylus on a stiff elastic half-space z < 0 (5 kN/m, like the meniscus body at
        // shallow depth), force rendered directly each tick from the quantised position (so
        // the stylus dithers by one encoder step, as a real Touch does); the hand presses to
        // a 2 mm depth.
        let c = EmulatedConfig {
            press_depth_m: 0.002,
            ..EmulatedConfig::default()
        };
        let mut dev = emulator(&c);
        let mut s = DeviceSample::default();
        let k = 5000.0;
        // Per hold: (first z, last z, force sum, samples), after 200 ms of settling.
        let mut holds: Vec<(f64, f64, f64, u32)> = Vec::new();
        let mut hold_ticks = 0;
        for i in 1..12_000u64 {
            dev.sample(i * MS, &mut s).unwrap();
            let z = s.pose.position[2];
            let f = if z < 0.0 { -k * z } else { 0.0 };
            dev.command_force(i * MS, [0.0, 0.0, f]).unwrap();
            if dev.hand().phase == Phase::Hold {
                hold_ticks += 1;
                if hold_ticks == 200 {
                    holds.push((dev.true_position()[2], 0.0, 0.0, 0));
                }
                if hold_ticks > 200 {
                    let h = holds.last_mut().unwrap();
                    h.1 = dev.true_position()[2];
                    h.2 += f;
                    h.3 += 1;
                }
            } else {
                hold_ticks = 0;
            }
        }
        assert!(holds.len() >= 3, "several holds in 12 s: {}", holds.len());
        let probe_weight = 0.035 * 9.81;
        for (z0, z1, sum, n) in holds {
            let mean = sum / n as f64;
            assert!(
                (z1 - z0).abs() < 0.2e-3,
                "stylus at rest while holding: {z0} → {z1}"
            );
            assert!(
                mean > probe_weight,
                "steady contact force {mean} N must exceed m·g = {probe_weight} N"
            );
            assert!(mean < c.saturation_n);
        }
    }

    #[test]
    fn saturation_workspace_and_quantisation() {
        // Ceiling 1 mm above the first hover point; a saturated upward force (3.3 N against
        // the 400 N/m grip would lift the stylus 8 mm) stops there.
        let c = EmulatedConfig {
            workspace_max_m: [0.08, 0.08, 0.011],
            ..EmulatedConfig::default()
        };
        let mut dev = emulator(&c);
        let mut s = DeviceSample::default();
        dev.command_force(0, [0.0, 0.0, 100.0]).unwrap();
        assert!((dev.force[2] - 3.3).abs() < 1e-12);
        let mut top: f64 = 0.0;
        for i in 1..300u64 {
            dev.sample(i * MS, &mut s).unwrap();
            top = top.max(dev.true_position()[2]);
            assert!(dev.true_position()[2] <= 0.011 + 1e-12);
            let q = s.pose.position[0] / c.quantisation_m;
            assert!((q - q.round()).abs() < 1e-6);
        }
        assert!((top - 0.011).abs() < 1e-12, "reached the stop: {top}");
        dev.command_force(0, [f64::NAN, 0.0, 0.0]).unwrap();
        assert_eq!(dev.force, [0.0; 3]);
    }
}
