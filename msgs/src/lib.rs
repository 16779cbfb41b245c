//! Every type that crosses a process boundary in arthrosim, and the one place where the
//! shared-memory services that carry them are opened.
//!
//! Payloads are `#[repr(C)]`, fixed capacity, plain old data (any bit pattern is a valid
//! value, so a torn or corrupted sample can be checked, never UB) and carry a stable
//! `type_name`, so every process that links this crate opens the same iceoryx2 service.
//! Modules are named by direction of flow.
//!
//! Data flows physics → haptic (`physics_to_haptic`: contact frames), haptic → physics
//! (`haptic_to_physics`: device states), physics → viewers (`physics_to_viz`: the deformed
//! surface) and haptic → monitor (`haptic_to_monitor`: loop statistics); [`protocol`] defines
//! the probing protocol's region and phase codes; [`ros`] the ROS 2 messages. Beside them, the
//! measurement definitions every process and benchmark shares: [`timing`] (the one latency
//! histogram) and [`host_load`] (load and the hypervisor's steal over a measurement).
//!
//! Units: SI (m, s, N, kg), world frame z-up (REP-103). Quaternions are `[x, y, z, w]`.

pub mod clock;
pub mod csv_input;
pub mod host_load;
pub mod ipc;
pub mod lifecycle;
pub mod protocol;
pub mod ros;
pub mod ros_mapping;
pub mod timing;

use iceoryx2::prelude::ZeroCopySend;

/// Maximum number of probe–tissue contacts published per physics step.
pub const MAX_CONTACTS: usize = 32;
/// Constraint rows per contact: normal, tangent 1, tangent 2.
pub const ROWS_PER_CONTACT: usize = 3;
/// Maximum number of constraint rows (size of the published compliance W).
pub const MAX_ROWS: usize = MAX_CONTACTS * ROWS_PER_CONTACT;
/// Capacity of the deformed-surface stream (visual model), vertices.
pub const MAX_SURFACE_VERTICES: usize = 16_384;
/// Capacity of the deformed-surface stream, triangles.
pub const MAX_SURFACE_TRIANGLES: usize = 32_768;

/// A rigid pose: position in metres and unit quaternion `[x, y, z, w]`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("arthrosim::Pose")]
pub struct Pose {
    pub position: [f64; 3],
    pub orientation: [f64; 4],
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        position: [0.0; 3],
        orientation: [0.0, 0.0, 0.0, 1.0],
    };

    /// True when every component is finite (quarantine check for incoming poses).
    pub fn is_finite(&self) -> bool {
        self.position
            .iter()
            .chain(self.orientation.iter())
            .all(|v| v.is_finite())
    }
}

impl Default for Pose {
    fn default() -> Self {
        Pose::IDENTITY
    }
}

/// Contract of a payload carried by one shared-memory service.
pub trait Topic: ZeroCopySend + core::fmt::Debug + 'static {
    /// Service name below the session prefix.
    const SERVICE: &'static str;
    /// Samples kept for late subscribers (1 = newest only).
    const HISTORY: usize;
    /// Largest per-subscriber queue the service allows; a reader that must see every sample
    /// (the recorder) asks for all of it, a reader that wants the newest asks for little.
    const MAX_BUFFER: usize;
    /// Most subscribers the service admits at once. The publisher's shared memory holds
    /// `MAX_SUBSCRIBERS × (MAX_BUFFER + 4) + HISTORY` samples, so a large payload with a deep
    /// queue admits fewer readers.
    const MAX_SUBSCRIBERS: usize = 16;

    /// An all-zero value. Every payload is plain old data (numbers and fixed arrays), so the
    /// zero bit pattern is a valid value; used to fill shared memory in place without a
    /// large stack copy.
    fn zeroed_in(slot: &mut core::mem::MaybeUninit<Self>) -> &mut Self
    where
        Self: Sized,
    {
        // SAFETY: all payload types are repr(C) compositions of integers, floats and arrays
        // thereof, for which all-zero bits are a valid value.
        unsafe {
            core::ptr::write_bytes(slot.as_mut_ptr(), 0, 1);
            slot.assume_init_mut()
        }
    }
}

pub mod physics_to_haptic {
    //! What the physics node publishes every step: the contact problem in constraint space.
    use super::*;

    /// One physics step's contact problem, as the haptic node needs it to re-solve the LCP
    /// for the device's current position (Peterlik et al. 2011, SOFA's LCPForceFeedback).
    ///
    /// Rows are grouped by contact: row `3k` is the normal of contact `k` (pointing out of the
    /// tissue, onto the probe), rows `3k+1`, `3k+2` its tangents.
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::ContactFrame")]
    pub struct ContactFrame {
        /// Random per physics process start; a change means a new physics instance.
        pub instance_id: u64,
        /// Step counter, starts at 1 for each instance.
        pub sequence: u64,
        /// Monotonic clock (CLOCK_MONOTONIC, ns) when the frame was published.
        pub publish_ns: u64,
        /// Simulation time at the end of the step, s.
        pub sim_time_s: f64,
        /// Time step, s (force = Hᵀλ / dt).
        pub dt_s: f64,
        /// Wall time the step took, ns.
        pub step_duration_ns: u64,
        /// Monotonic clock (ns) at which the publisher starts its next step on its schedule of
        /// absolute deadlines: no frame can come before it. Equals `publish_ns` when the
        /// publisher runs behind real time; 0 when it keeps no schedule (replays).
        pub next_step_ns: u64,
        /// Number of active contacts (≤ MAX_CONTACTS).
        pub contact_count: u32,
        /// Number of active constraint rows (= 3 × contact_count).
        pub row_count: u32,
        /// Coulomb friction coefficient used for these contacts.
        pub friction_mu: f64,
        /// Iterations and final residual of the physics-side LCP.
        pub lcp_iterations: u32,
        /// CPU the publisher sent this frame from, plus one (0: not known). A consumer that
        /// busy-waits for the next frame keeps off it: that is where the publisher wakes.
        pub publisher_cpu_plus_one: u32,
        pub lcp_residual: f64,
        /// Sequence of the device state this step consumed (0: none yet).
        pub device_sequence_used: u64,
        /// Instance of the haptic process whose device state this step consumed (0: none,
        /// or the probe was driven by an external target): a haptic node renders force only
        /// from frames computed for its own device.
        pub device_instance_used: u64,
        /// [`physics_fault`] bits of this step (0: a good step). A faulty step is published
        /// for the record and must not be rendered.
        pub physics_faults: u32,
        /// [`drive`] bits: what drove the probe in this step.
        pub drive: u32,
        /// Proxy pose (device) this step was driven toward.
        pub proxy_pose: Pose,
        /// Probe pose after free motion (before contact correction): the linearisation point.
        pub probe_free_pose: Pose,
        /// Probe pose after contact correction.
        pub probe_pose: Pose,
        /// Contact points on the tissue surface, world frame, m.
        pub contact_points: [[f64; 3]; MAX_CONTACTS],
        /// Rows of H for the probe: `[linear x, y, z, angular x, y, z]` in world frame, with
        /// the angular part taken about the probe's free position.
        pub constraint_directions: [[f64; 6]; MAX_ROWS],
        /// Free-motion violation δ_free per row, m (negative = interpenetration).
        pub free_violation: [f64; MAX_ROWS],
        /// Contact compliance W = H A⁻¹ Hᵀ (tissue + probe), row-major with stride MAX_ROWS,
        /// m/N·s (so that δ = δ_free + W λ with λ an impulse, N·s).
        pub compliance: [f64; MAX_ROWS * MAX_ROWS],
        /// Constraint impulses λ solved by the physics node, N·s.
        pub lambda: [f64; MAX_ROWS],
        /// Contact force on the probe, world frame, N: f = Hᵀλ/dt summed over contacts.
        pub contact_force: [f64; 3],
        /// Contact torque on the probe about its position, N·m.
        pub contact_torque: [f64; 3],
    }

    /// Bits of [`ContactFrame::physics_faults`]: the checks a physics step failed.
    pub mod physics_fault {
        /// Tissue energy grew without input (no contact, no external load).
        pub const ENERGY_GROWTH: u32 = 1 << 0;
        /// Contact force beyond the scene's physical bound.
        pub const FORCE_BOUND: u32 = 1 << 1;
        /// Probe penetration after the contact correction deeper than the bound.
        pub const PENETRATION: u32 = 1 << 2;
        /// The contact LCP did not converge (residual far above its tolerance).
        pub const LCP_NOT_CONVERGED: u32 = 1 << 3;
        /// The free-motion CG did not converge (residual far above its bound).
        pub const CG_NOT_CONVERGED: u32 = 1 << 4;
        /// A solver error or a non-finite force or position.
        pub const NUMERICAL: u32 = 1 << 5;

        /// Names of the set bits, for logs and reports.
        pub fn names(bits: u32) -> impl Iterator<Item = &'static str> {
            [
                (ENERGY_GROWTH, "energy growth without input"),
                (FORCE_BOUND, "contact force beyond the scene bound"),
                (PENETRATION, "probe penetration beyond the bound"),
                (LCP_NOT_CONVERGED, "contact LCP not converged"),
                (CG_NOT_CONVERGED, "free-motion CG not converged"),
                (NUMERICAL, "numerical failure"),
            ]
            .into_iter()
            .filter(move |(b, _)| bits & b != 0)
            .map(|(_, n)| n)
        }
    }

    /// Bits of [`ContactFrame::drive`].
    pub mod drive {
        /// The probe followed an external target (bridge), not the haptic device: no haptic
        /// node may render force from this frame.
        pub const EXTERNAL_TARGET: u32 = 1 << 0;
        /// The state was rolled back after a faulty step and is coming back under a ramp.
        pub const ROLLED_BACK: u32 = 1 << 1;
    }

    impl ContactFrame {
        /// W(i, j).
        #[inline]
        pub fn w(&self, i: usize, j: usize) -> f64 {
            self.compliance[i * MAX_ROWS + j]
        }

        /// True when every number the haptic loop reads is finite and the counts are in range.
        pub fn is_valid(&self) -> bool {
            let rows = self.row_count as usize;
            if self.contact_count as usize > MAX_CONTACTS
                || rows != self.contact_count as usize * ROWS_PER_CONTACT
                || !(self.dt_s.is_finite() && self.dt_s > 0.0)
                || !self.friction_mu.is_finite()
                || !self.probe_free_pose.is_finite()
            {
                return false;
            }
            (0..rows).all(|i| {
                self.free_violation[i].is_finite()
                    && self.constraint_directions[i].iter().all(|v| v.is_finite())
                    && (0..rows).all(|j| self.w(i, j).is_finite())
            })
        }
    }

    impl Topic for ContactFrame {
        const SERVICE: &'static str = "physics_to_haptic/contact_frame";
        /// The last 1.6 s (at 100 Hz) are kept for late subscribers: a recorder restarted
        /// after a crash is down ~1.1 s and its predecessor's last ≤ 0.5 s were never
        /// flushed, so it recovers every step (skipping what its earlier part holds). Below
        /// the queue size, so steps arriving before the first drain do not push history out.
        const HISTORY: usize = 160;
        const MAX_BUFFER: usize = 192;
        /// Frames are ~80 KB: 8 readers (a session has at most 6: haptic node, recorder,
        /// bridge, launcher status, viewer, training driver) keep the publisher's shared
        /// memory at 8 × 196 + 160 samples, ~140 MB, instead of ~290 MB for 16.
        const MAX_SUBSCRIBERS: usize = 8;
    }
}

pub mod haptic_to_physics {
    //! What the haptic node publishes every servo tick: the device state.
    use super::*;

    /// Which device backend produced a [`DeviceState`].
    #[repr(u32)]
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum DeviceKind {
        Unknown = 0,
        Touch = 1,
        Emulated = 2,
        Replay = 3,
        External = 4,
    }

    /// Fault bits in [`DeviceState::faults`].
    pub mod fault {
        /// Newest contact frame older than the staleness limit.
        pub const STALE_FRAME: u32 = 1 << 0;
        /// A non-finite device position or velocity was quarantined.
        pub const NONFINITE_DEVICE: u32 = 1 << 1;
        /// A contact frame with non-finite or out-of-range content was quarantined.
        pub const INVALID_FRAME: u32 = 1 << 2;
        /// A non-finite force was quarantined.
        pub const NONFINITE_FORCE: u32 = 1 << 3;
        /// Force was limited by the peak or continuous clamp.
        pub const FORCE_CLAMPED: u32 = 1 << 4;
        /// Force was limited by the rate limit.
        pub const RATE_LIMITED: u32 = 1 << 5;
        /// The device reported an error.
        pub const DEVICE_ERROR: u32 = 1 << 6;
        /// The frame was not computed for this device's state (another haptic instance, an
        /// external target, or a device sample from the future): not rendered, ramp to zero.
        pub const FOREIGN_FRAME: u32 = 1 << 7;
        /// The frame carries a physics fault flag: not rendered, ramp to zero.
        pub const PHYSICS_FAULT: u32 = 1 << 8;
    }

    /// One haptic tick: the proxy (device end-effector mapped into the scene) and forces.
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::DeviceState")]
    pub struct DeviceState {
        /// Random per haptic process start.
        pub instance_id: u64,
        /// Tick counter, starts at 1.
        pub sequence: u64,
        /// Monotonic clock (ns) when the tick sampled the device.
        pub publish_ns: u64,
        /// `DeviceKind` as u32.
        pub device_kind: u32,
        /// Button bit mask.
        pub buttons: u32,
        /// Proxy pose in the scene (world frame, m).
        pub proxy_pose: Pose,
        /// Proxy twist: linear m/s then angular rad/s, world frame.
        pub proxy_velocity: [f64; 6],
        /// Device joint angles (3 base joints + 3 gimbal), rad; for joint_states.
        pub joint_angles: [f64; 6],
        /// Force the LCP asked for, world frame, N (before clamping).
        pub commanded_force: [f64; 3],
        /// Force sent to the device after clamping and rate limiting, world frame, N.
        pub rendered_force: [f64; 3],
        /// Sequence and instance of the contact frame this tick used (0: none).
        pub frame_sequence_used: u64,
        pub frame_instance_used: u64,
        /// Age of that frame at the tick, ns.
        pub frame_age_ns: u64,
        /// Active contacts in the frame used.
        pub contact_count: u32,
        /// `fault` bits.
        pub faults: u32,
        /// LCP iterations this tick.
        pub lcp_iterations: u32,
        pub _pad0: u32,
        /// Operator protocol annotations (emulated/replay devices): probing index (0: none)
        /// and region code (0 none, 1 posterior, 2 mid, 3 anterior), phase code.
        pub probing_index: u32,
        pub region: u32,
        pub phase: u32,
        pub _pad1: u32,
    }

    impl Topic for DeviceState {
        const SERVICE: &'static str = "haptic_to_physics/device_state";
        /// The last 1.8 s (at 1 kHz) are kept for late subscribers: a recorder restarted
        /// after a crash is down ~1.1 s and its predecessor's last ≤ 0.5 s were never
        /// flushed, so it recovers every tick (skipping what its earlier part holds). Below
        /// the queue size, so ticks arriving before the first drain do not push history out.
        const HISTORY: usize = 1800;
        const MAX_BUFFER: usize = 2048;
    }
}

pub mod haptic_to_monitor {
    //! Low-rate statistics of the haptic loop, for the launcher, the bridge and the recorder.
    use super::*;

    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::HapticStats")]
    pub struct HapticStats {
        pub instance_id: u64,
        pub sequence: u64,
        pub publish_ns: u64,
        pub ticks: u64,
        pub tick_hz: f64,
        pub period_err_p50_us: f64,
        pub period_err_p99_us: f64,
        pub period_err_max_us: f64,
        pub lcp_p50_us: f64,
        pub lcp_p99_us: f64,
        pub lcp_iterations_mean: f64,
        pub frame_age_p50_us: f64,
        pub frame_age_p99_us: f64,
        pub transport_p50_us: f64,
        pub transport_p99_us: f64,
        pub rendered_force_norm_n: f64,
        pub fault_count: u64,
        pub faults: u32,
        /// 1 when real-time scheduling was granted.
        pub realtime: u32,
    }

    impl Topic for HapticStats {
        const SERVICE: &'static str = "haptic_to_monitor/stats";
        const HISTORY: usize = 1;
        const MAX_BUFFER: usize = 16;
    }
}

pub mod physics_to_viz {
    //! The deformed visual surface, at a viewer rate.
    use super::*;

    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::SurfaceFrame")]
    pub struct SurfaceFrame {
        pub instance_id: u64,
        pub sequence: u64,
        pub publish_ns: u64,
        pub sim_time_s: f64,
        pub vertex_count: u32,
        pub triangle_count: u32,
        /// World-frame vertex positions, m.
        pub positions: [[f32; 3]; MAX_SURFACE_VERTICES],
        /// Vertex indices, counter-clockwise seen from outside.
        pub triangles: [[u32; 3]; MAX_SURFACE_TRIANGLES],
    }

    impl Topic for SurfaceFrame {
        const SERVICE: &'static str = "physics_to_viz/surface";
        const HISTORY: usize = 1;
        const MAX_BUFFER: usize = 4;
    }
}

pub mod bridge_to_physics {
    //! Commands from outside (ROS 2 tools through the bridge, or the launcher) to physics.
    use super::*;

    /// Drive the probe from an external target instead of the haptic device.
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::ProbeTarget")]
    pub struct ProbeTarget {
        pub sequence: u64,
        pub publish_ns: u64,
        /// Target pose for the probe (world, m).
        pub pose: Pose,
    }

    impl Topic for ProbeTarget {
        const SERVICE: &'static str = "bridge_to_physics/probe_target";
        const HISTORY: usize = 1;
        const MAX_BUFFER: usize = 8;
    }

    /// Change the tissue material between probings.
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::MaterialCommand")]
    pub struct MaterialCommand {
        pub sequence: u64,
        pub publish_ns: u64,
        /// Degeneration grade 0..=2 (fractional values interpolate).
        pub degeneration_grade: f64,
    }

    impl Topic for MaterialCommand {
        const SERVICE: &'static str = "bridge_to_physics/material";
        const HISTORY: usize = 1;
        const MAX_BUFFER: usize = 8;
    }
}

pub mod training {
    //! Blinded grade training (`arthrosim train`): the driver's prompt to the viewer page, and
    //! the trainee's answer from the page back to the driver. The grade itself is never sent
    //! before the answer.
    use super::*;

    /// Training states in [`TrainingPrompt::state`].
    pub mod state {
        /// No training running (plain session).
        pub const IDLE: u32 = 0;
        /// A specimen is loaded; probe it, then answer.
        pub const PROBING: u32 = 1;
        /// The answer of the current case is stored; the next specimen is being loaded.
        pub const ANSWERED: u32 = 2;
        /// All cases answered; `correct` holds the score.
        pub const FINISHED: u32 = 3;
    }

    /// Published by the training driver whenever its state changes (and once a second).
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::TrainingPrompt")]
    pub struct TrainingPrompt {
        pub sequence: u64,
        pub publish_ns: u64,
        /// Case number, 1-based (0: none yet).
        pub case_index: u32,
        pub case_count: u32,
        /// `state::*`.
        pub state: u32,
        /// Grades the trainee may answer: 0..grade_count.
        pub grade_count: u32,
        /// Probings counted in the current case.
        pub probings: u32,
        /// Correct answers so far (shown only when FINISHED).
        pub correct: u32,
        /// Answered cases so far.
        pub answered: u32,
        pub _pad: u32,
    }

    impl Topic for TrainingPrompt {
        const SERVICE: &'static str = "training/prompt";
        const HISTORY: usize = 1;
        const MAX_BUFFER: usize = 8;
    }

    /// Where an answer came from.
    pub mod source {
        pub const PAGE: u32 = 1;
        pub const BUTTONS: u32 = 2;
    }

    /// The trainee's answer for one case, from the viewer page.
    #[repr(C)]
    #[derive(Debug, Clone, Copy, ZeroCopySend)]
    #[type_name("arthrosim::TrainingAnswer")]
    pub struct TrainingAnswer {
        pub sequence: u64,
        pub publish_ns: u64,
        /// The case answered (must match the prompt's `case_index`, else it is ignored).
        pub case_index: u32,
        pub grade: u32,
        /// `source::*`.
        pub source: u32,
        pub _pad: u32,
    }

    impl Topic for TrainingAnswer {
        const SERVICE: &'static str = "training/answer";
        const HISTORY: usize = 1;
        const MAX_BUFFER: usize = 8;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payload_sizes_are_fixed_and_aligned() {
        assert_eq!(core::mem::size_of::<Pose>(), 56);
        assert_eq!(
            core::mem::size_of::<physics_to_haptic::ContactFrame>() % 8,
            0
        );
        assert_eq!(
            core::mem::size_of::<haptic_to_physics::DeviceState>() % 8,
            0
        );
    }

    #[test]
    fn zeroed_frame_is_valid_only_with_positive_dt() {
        let mut slot =
            Box::new(core::mem::MaybeUninit::<physics_to_haptic::ContactFrame>::uninit());
        let frame = physics_to_haptic::ContactFrame::zeroed_in(&mut slot);
        frame.probe_free_pose = Pose::IDENTITY;
        assert!(!frame.is_valid(), "dt = 0 must be rejected");
        frame.dt_s = 0.01;
        assert!(frame.is_valid());
        frame.contact_count = 1;
        frame.row_count = 3;
        frame.free_violation[1] = f64::NAN;
        assert!(!frame.is_valid(), "NaN violation must be rejected");
    }
}
