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
    /// Multiplies the tissue contact force Hᵀλ/dt before clamping (1 = physical, at most 1).
    /// 0 = automatic: chosen from the tissue reference below and the device's continuous
    /// force and stiffness limits (see [`DeviceConfig::rendering`]).
    pub force_scale: f64,
    /// Peak force the device may render, N (Touch: 3.3 N; may be lowered, never raised).
    pub peak_force_n: f64,
    /// Continuous force limit, N: the RMS force over `continuous_window_s` stays below it
    /// (Touch: 0.88 N; may be lowered, never raised).
    pub continuous_force_n: f64,
    /// Largest felt stiffness, N/m: the rendered force changes by at most this much per metre
    /// of stylus travel, whatever the tissue (a virtual coupling in series with the contact
    /// compliance). Touch: 1000 N/m by default; the datasheet's smallest axis figure (z,
    /// 1.02 N/mm) is the device limit, because the bound holds in every direction.
    pub max_stiffness_n_per_m: f64,
    /// Play of the stylus position the renderer uses, per axis, m: it follows the device's
    /// reading only once that moved more than this away, so a reading dithering between two
    /// neighbouring encoder quanta (an arm at rest on a quantum boundary) renders one force,
    /// not a chatter of two. Just over half the Touch's 0.055 mm resolution absorbs a
    /// one-quantum reversal; 0 renders every reading.
    pub position_hysteresis_m: f64,
    /// Tissue force range the device's continuous force should represent with the automatic
    /// force scale, N: the cadaver probing table's 7.51 N − 0.31 N offset over 7.6 mm of
    /// probe displacement (`empirical/cadaver_probing_force_displacement.csv`).
    pub tissue_force_range_n: f64,
    /// Steepest tissue stiffness under the probe the automatic scale must render without
    /// the coupling dominating, N/m: the table's last segment, (7.51 − 7.20) N / 0.10 mm.
    pub tissue_stiffness_n_per_m: f64,
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
            force_scale: 0.0,
            peak_force_n: TOUCH_LIMITS.peak_force_n,
            continuous_force_n: TOUCH_LIMITS.continuous_force_n,
            max_stiffness_n_per_m: 1000.0,
            position_hysteresis_m: 0.6 * 0.055e-3,
            tissue_force_range_n: CADAVER_FORCE_RANGE_N,
            tissue_stiffness_n_per_m: CADAVER_MAX_STIFFNESS_N_PER_M,
            continuous_window_s: 1.0,
            max_force_rate_n_per_s: TOUCH_LIMITS.max_force_rate_n_per_s,
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

/// Bounds of `[device.touch] servo_watchdog_s`, s: at least two servo ticks (one late tick
/// must not fade the force), at most 100 ms (a stalled node loop must not hold a force
/// longer than a hand takes to react).
pub const SERVO_WATCHDOG_RANGE_S: (f64, f64) = (0.002, 0.1);

/// Cadaver probing table: force range above the first row's 0.31 N offset, N.
pub const CADAVER_FORCE_RANGE_N: f64 = 7.51 - 0.31;
/// Cadaver probing table: steepest segment, (7.51 − 7.20) N over (7.62 − 7.52) mm, N/m.
pub const CADAVER_MAX_STIFFNESS_N_PER_M: f64 = 0.31 / 0.10e-3;

/// How many times stiffer than the steepest tissue the automatic scale makes the virtual
/// coupling (see [`DeviceConfig::rendering`]).
pub const COUPLING_MARGIN: f64 = 4.0;

/// Hard limits of a device kind, built into the code: a launch file may lower each of them,
/// never raise it (`arthrosim validate` names the key, the value and the limit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceLimits {
    pub device: &'static str,
    /// Peak force, N.
    pub peak_force_n: f64,
    /// Continuous force, N.
    pub continuous_force_n: f64,
    /// Rate of change of the force, N/s.
    pub max_force_rate_n_per_s: f64,
    /// Felt stiffness rendered stably in every direction, N/m.
    pub max_stiffness_n_per_m: f64,
}

/// The 3D Systems Touch (datasheet): 3.3 N peak, 0.88 N continuous, stiffness x 1.26,
/// y 2.31, z 1.02 N/mm (the smallest bounds a direction-independent limit). Force rate:
/// 400 N/s, enough to fade the peak force to zero within the 10 ms stale ramp, and a
/// step of 0.4 N per 1 ms tick at most.
pub const TOUCH_LIMITS: DeviceLimits = DeviceLimits {
    device: "3D Systems Touch",
    peak_force_n: 3.3,
    continuous_force_n: 0.88,
    max_force_rate_n_per_s: 400.0,
    max_stiffness_n_per_m: 1020.0,
};

/// One launch-file value above its device limit.
#[derive(Debug, Clone, PartialEq)]
pub struct LimitRaise {
    /// Dotted key (`device.peak_force_n`).
    pub key: &'static str,
    pub value: f64,
    pub limit: f64,
    pub unit: &'static str,
    pub device: &'static str,
}

impl std::fmt::Display for LimitRaise {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} = {} {} is above the {} limit of {} {}; a launch file may lower a device limit, never raise it",
            self.key, self.value, self.unit, self.device, self.limit, self.unit
        )
    }
}

/// How the contact force becomes the felt force: the scale, and the virtual coupling (a
/// spring of `coupling_stiffness_n_per_m`, in tissue-force units, in series with the
/// contact compliance) that bounds the felt stiffness by
/// `force_scale × coupling_stiffness_n_per_m = felt_stiffness_limit_n_per_m`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Rendering {
    pub force_scale: f64,
    /// The scale was chosen automatically (`force_scale = 0`).
    pub automatic: bool,
    pub coupling_stiffness_n_per_m: f64,
    pub felt_stiffness_limit_n_per_m: f64,
}

impl DeviceConfig {
    /// The hard limits of this configuration's device. The emulator and trajectory replay
    /// stand in for a Touch, so every backend has the Touch's.
    pub fn device_limits(&self) -> &'static DeviceLimits {
        &TOUCH_LIMITS
    }

    /// Every limit this file raises above its device's (empty: none).
    pub fn limit_raises(&self) -> Vec<LimitRaise> {
        let d = self.device_limits();
        [
            (
                "device.peak_force_n",
                self.peak_force_n,
                d.peak_force_n,
                "N",
            ),
            (
                "device.continuous_force_n",
                self.continuous_force_n,
                d.continuous_force_n,
                "N",
            ),
            (
                "device.max_force_rate_n_per_s",
                self.max_force_rate_n_per_s,
                d.max_force_rate_n_per_s,
                "N/s",
            ),
            (
                "device.max_stiffness_n_per_m",
                self.max_stiffness_n_per_m,
                d.max_stiffness_n_per_m,
                "N/m",
            ),
        ]
        .into_iter()
        .filter(|(_, v, limit, _)| v > limit)
        .map(|(key, value, limit, unit)| LimitRaise {
            key,
            value,
            limit,
            unit,
            device: d.device,
        })
        .collect()
    }

    /// The force scale and virtual coupling this configuration renders with. Automatic
    /// scale (`force_scale = 0`): the smaller of
    /// - continuous force / tissue force range: the table's whole range stays inside the
    ///   device's continuous range;
    /// - stiffness limit / ([`COUPLING_MARGIN`] × steepest tissue stiffness): the coupling
    ///   k_c = limit / scale is then at least that many times stiffer than the tissue, so
    ///   the series spring changes felt force ratios (a degenerated meniscus against a
    ///   healthy one at equal depth) by at most 0.41 k/(0.59 k + k_c) ≈ 9% at the table's
    ///   steepest and ≈ 5% at its typical 1.7 N/mm;
    ///
    /// never above 1. Limits above the device's are taken at the device's (validation
    /// rejects such files; this keeps the numbers safe regardless).
    pub fn rendering(&self) -> Rendering {
        let d = self.device_limits();
        let limit = self.max_stiffness_n_per_m.min(d.max_stiffness_n_per_m);
        let continuous = self.continuous_force_n.min(d.continuous_force_n);
        let automatic = !(self.force_scale > 0.0);
        let force_scale = if automatic {
            (continuous / self.tissue_force_range_n)
                .min(limit / (COUPLING_MARGIN * self.tissue_stiffness_n_per_m))
                .min(1.0)
        } else {
            self.force_scale
        };
        Rendering {
            force_scale,
            automatic,
            coupling_stiffness_n_per_m: limit / force_scale,
            felt_stiffness_limit_n_per_m: limit,
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
    /// the force to zero on its own, s ([`SERVO_WATCHDOG_RANGE_S`]).
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
    /// Force the operator presses to, at the tissue, N, as the study's examiner does (the
    /// study: −4.16 N mean normal force simulated, −4.0 N measured). The hand feels only the
    /// rendered force, so it presses until it feels this times the force scale. 0: press to
    /// `press_depth_m` instead.
    pub press_force_n: f64,
    /// How far the hand pushes past the undeformed surface, m: the press depth, or with
    /// `press_force_n` the deepest the hand goes when it never feels the target.
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
            press_force_n: 4.16,
            press_depth_m: 0.012,
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
