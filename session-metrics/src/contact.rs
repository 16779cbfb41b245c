//! When the probe is in contact, and its normal force: derived once from a physics step.

use msgs::physics_to_haptic::ContactFrame;

/// The part of one physics step every session quantity needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactSample {
    pub instance_id: u64,
    pub sequence: u64,
    pub publish_ns: u64,
    pub sim_time_s: f64,
    pub dt_s: f64,
    pub step_duration_ns: u64,
    /// Constraints within the alarm distance (touching or merely near).
    pub contact_count: u32,
    /// Sequence of the device state the step used (0: none yet): the step↔tick matching.
    pub device_sequence_used: u64,
    /// Unit outward tissue normal (zero without contact).
    pub normal: [f64; 3],
    /// Some constraint carries a normal impulse (the probe touches, not just near).
    pub touching: bool,
    /// Eq. (1) contact force on the probe, world frame, N.
    pub contact_force: [f64; 3],
    /// Probe position after contact correction, m.
    pub probe_position: [f64; 3],
    /// `physics_fault` bits of the step (0: good). A faulty step is counted, never taken as
    /// contact.
    pub physics_faults: u32,
}

impl ContactSample {
    /// The session's view of a published frame: the one place where "touching" and the
    /// contact normal are derived from the constraint impulses λ and directions H.
    pub fn from_frame(frame: &ContactFrame) -> ContactSample {
        let contacts = (frame.contact_count as usize).min(msgs::MAX_CONTACTS);
        let mut weighted = [0.0f64; 3];
        for k in 0..contacts {
            let row = k * msgs::ROWS_PER_CONTACT;
            let w = frame.lambda[row].max(0.0);
            for (a, n) in weighted
                .iter_mut()
                .zip(&frame.constraint_directions[row][..3])
            {
                *a += w * n;
            }
        }
        let mut normal = unit(weighted);
        let touching = normal != [0.0; 3];
        if !touching && contacts > 0 {
            // No impulse (near, not touching): first constraint's normal, for viewers.
            let r = &frame.constraint_directions[0];
            normal = unit([r[0], r[1], r[2]]);
        }
        ContactSample {
            instance_id: frame.instance_id,
            sequence: frame.sequence,
            publish_ns: frame.publish_ns,
            sim_time_s: frame.sim_time_s,
            dt_s: frame.dt_s,
            step_duration_ns: frame.step_duration_ns,
            contact_count: contacts as u32,
            device_sequence_used: frame.device_sequence_used,
            normal,
            touching,
            contact_force: frame.contact_force,
            probe_position: frame.probe_pose.position,
            physics_faults: frame.physics_faults,
        }
    }

    /// In contact: at least one constraint carries a normal impulse (λn > 0). Constraints
    /// inside the alarm distance that carry nothing (the probe near, not touching) do not
    /// count. The one definition the summary, the export and the gap diagnosis use.
    pub fn in_contact(&self) -> bool {
        // `touching` implies a non-zero (impulse-weighted) normal. A faulty step's force is
        // not physical: it is counted in `physics_faults`, never averaged.
        self.contact_count > 0 && self.touching && self.physics_faults == 0
    }

    /// Normal force F_n = −f·n, N: negative in compression, the sign the study reports.
    pub fn normal_force(&self) -> f64 {
        -dot(self.contact_force, self.normal)
    }
}

pub(crate) fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = dot(v, v).sqrt();
    if n.is_finite() && n > 1e-12 {
        [v[0] / n, v[1] / n, v[2] / n]
    } else {
        [0.0; 3]
    }
}

pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
