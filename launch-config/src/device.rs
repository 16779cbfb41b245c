//! `[device]`: the haptic node's device backend, servo loop and safety limits. Owned by
//! haptic-node. SI units throughout (N, m, s); every field has a default so an empty
//! launch file runs the emulated Touch.
pub use crate::choices::{DeviceBackend, DisplacementReference, SiteSource};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeviceConfig {
    /// `touch` (3D Systems Touch through OpenHaptics libHD), `emulated` (Touch emulator driven
    /// by an operator model) or `replay` (proxy pose trajectory from a CSV file).
    pub backend: DeviceBackend,
    /// Servo loop rate, Hz.
    pub rate_hz: f64,
    /// Multiplies the contact force Hᵀλ/dt before clamping (1 = physical).
    pub force_scale: f64,
    /// Peak force the device may render, N (Touch: 3.3 N).
    pub peak_force_n: f64,
    /// Continuous force limit, N: the RMS force over `continuous_window_s` stays below it
    /// (Touch: 0.88 N).
    pub continuous_force_n: f64,
    /// Window of the continuous force limit, s (≤ 10 s).
    pub continuous_window_s: f64,
    /// Largest change of the rendered force, N/s (vector norm of the step per tick / tick).
    /// 400 N/s lets the 10 ms stale ramp bring even the peak force to zero without
    /// exceeding it.
    pub max_force_rate_n_per_s: f64,
    /// A contact frame older than this is stale, s.
    pub stale_frame_s: f64,
    /// On a stale frame the force ramps linearly to zero within this time, s.
    pub stale_ramp_s: f64,
    /// Gauss–Seidel sweep cap of the haptic-side LCP.
    pub lcp_max_iterations: u32,
    /// Relative impulse-change tolerance of the haptic-side LCP.
    pub lcp_tolerance: f64,
    /// Time budget of the LCP per tick, s (the solve keeps its best feasible answer).
    pub lcp_budget_s: f64,
    /// Update the violation with the proxy's rotation as well as its translation.
    pub use_rotation: bool,
    /// Reference pose of the displacement Δx in δ = δ_free + H·Δx: `proxy` (the proxy pose
    /// the physics step was driven toward: reproduces the physics force exactly at the same
    /// proxy position) or `probe_free` (the probe's free pose).
    pub displacement_reference: DisplacementReference,
    /// Ask for SCHED_FIFO and locked memory (logged when the OS refuses).
    pub realtime: bool,
    /// SCHED_FIFO priority (1–99).
    pub realtime_priority: i32,
    /// The servo loop sleeps until this long before each tick's deadline and waits out the
    /// rest on the clock (a bounded spin), s: the OS's wake-up latency (tens of µs, more on a
    /// virtual machine) then no longer lands on the tick period. 0 = sleep to the deadline.
    pub servo_spin_s: f64,
    /// Rate of the HapticStats messages, Hz.
    pub stats_rate_hz: f64,
    /// Maps device coordinates into the scene: scene = offset + scale · device (after the
    /// backend's own axis conversion to z-up metres).
    pub workspace_scale: f64,
    pub workspace_offset_m: [f64; 3],
    pub touch: TouchConfig,
    pub emulated: EmulatedConfig,
    pub replay: ReplayConfig,
}

impl Default for DeviceConfig {
    fn default() -> Self {
        DeviceConfig {
            backend: DeviceBackend::Emulated,
            rate_hz: 1000.0,
            force_scale: 1.0,
            peak_force_n: 3.3,
            continuous_force_n: 0.88,
            continuous_window_s: 1.0,
            max_force_rate_n_per_s: 400.0,
            stale_frame_s: 0.020,
            stale_ramp_s: 0.010,
            lcp_max_iterations: 50,
            lcp_tolerance: 1e-3,
            lcp_budget_s: 200e-6,
            use_rotation: false,
            displacement_reference: DisplacementReference::Proxy,
            realtime: true,
            realtime_priority: 80,
            servo_spin_s: 150e-6,
            stats_rate_hz: 10.0,
            workspace_scale: 1.0,
            workspace_offset_m: [0.0; 3],
            touch: TouchConfig::default(),
            emulated: EmulatedConfig::default(),
            replay: ReplayConfig::default(),
        }
    }
}

/// `[device.touch]`: the real device through OpenHaptics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TouchConfig {
    /// libHD to load (a file name searched by the dynamic loader, or a path).
    pub library: String,
    /// OpenHaptics device name (`Default Device` picks the configured one).
    pub device_name: String,
    /// Run the automatic calibration update when the device asks for one.
    pub auto_calibrate: bool,
    /// If the servo callback sees no new force from the node loop for this long, it ramps
    /// the force to zero on its own, s.
    pub servo_watchdog_s: f64,
}

impl Default for TouchConfig {
    fn default() -> Self {
        TouchConfig {
            library: "libHD.so".into(),
            device_name: "Default Device".into(),
            auto_calibrate: true,
            servo_watchdog_s: 0.010,
        }
    }
}

/// `[device.emulated]`: the Touch emulator and the operator model that drives it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmulatedConfig {
    /// Apparent end-effector mass, kg (Touch ≈ 45 g).
    pub mass_kg: f64,
    /// Coulomb friction of the linkage, N.
    pub friction_n: f64,
    /// Viscous damping of the linkage, N·s/m.
    pub damping_n_s_per_m: f64,
    /// Motor force saturation, N.
    pub saturation_n: f64,
    /// Position quantisation of the encoders, m (Touch ≈ 0.055 mm).
    pub quantisation_m: f64,
    /// Workspace box in the scene, m (the end effector stops at its faces).
    pub workspace_min_m: [f64; 3],
    pub workspace_max_m: [f64; 3],
    /// Grip: spring and damper between the operator's hand and the stylus.
    pub grip_stiffness_n_per_m: f64,
    pub grip_damping_n_s_per_m: f64,
    /// Operator protocol: probings per region (posterior, mid, anterior).
    pub probings_per_region: u32,
    /// Start height above each probing site along its normal, m.
    pub hover_m: f64,
    /// Hand travel speed between sites and during approach/release, m/s.
    pub approach_speed_m_per_s: f64,
    /// How far the hand pushes past the undeformed surface, m.
    pub press_depth_m: f64,
    /// Speed of the hand while pressing, m/s.
    pub press_speed_m_per_s: f64,
    /// Time the hand holds the pressed position, s.
    pub hold_s: f64,
    /// Repeat the protocol when it ends (otherwise the hand rests at the last hover point).
    pub repeat: bool,
    /// Where the probing sites come from: `scene` (the physics library's sites on the
    /// `[scene]` meniscus) or `plane` (a row of sites on the plane z = `plane_height_m`, for
    /// runs against an analytic half-space).
    pub sites: SiteSource,
    pub plane_height_m: f64,
}

impl Default for EmulatedConfig {
    fn default() -> Self {
        EmulatedConfig {
            mass_kg: 0.045,
            friction_n: 0.02,
            damping_n_s_per_m: 0.5,
            saturation_n: 3.3,
            quantisation_m: 0.055e-3,
            workspace_min_m: [-0.08, -0.08, -0.02],
            workspace_max_m: [0.08, 0.08, 0.12],
            grip_stiffness_n_per_m: 400.0,
            grip_damping_n_s_per_m: 4.0,
            probings_per_region: 5,
            hover_m: 0.010,
            approach_speed_m_per_s: 0.02,
            press_depth_m: 0.002,
            press_speed_m_per_s: 0.004,
            hold_s: 1.0,
            repeat: true,
            sites: SiteSource::Scene,
            plane_height_m: 0.0,
        }
    }
}

/// `[device.replay]`: a recorded proxy trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// CSV with header `t_s,px_m,py_m,pz_m,qx,qy,qz,qw`, world frame.
    pub path: String,
    /// Start again from the beginning at the end (otherwise hold the last pose).
    pub looped: bool,
    /// Playback speed (1 = recorded speed).
    pub time_scale: f64,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        ReplayConfig {
            path: String::new(),
            looped: false,
            time_scale: 1.0,
        }
    }
}
