//! Semantic checks of a parsed launch file: values in range, specs well formed, files present.
//! Each problem is an [`Issue`] naming the dotted key and what is allowed; [`crate::load`]
//! adds the line and column.
//!
//! Paths are checked as they are in the given [`LaunchFile`]; after [`crate::load`] they are
//! absolute (resolved against the launch file's folder).

use crate::choices::{DeviceBackend, MaterialPreset};
use crate::load::{is_builtin_spec, Issue};
use crate::scene::TransformConfig;
use crate::LaunchFile;
use std::path::Path;

/// Largest stiffness re-rotation tolerance, rad: the default fine mesh stayed stable at
/// 0.03 under the bench's sliding probe, and diverged with a matrix that never re-rotates.
pub const MAX_STIFFNESS_ROTATION_TOLERANCE: f64 = 0.05;

/// Files a `study:` mesh spec needs in the data folder.
pub fn study_files(side: &str) -> Option<&'static [&'static str]> {
    match side {
        "lateral" => Some(&[
            "meniscus/lateral_meniscus_computation.msh",
            "meniscus/lateral_meniscus_fixed_nodes.txt",
        ]),
        "medial" => Some(&["meniscus/medial_meniscus_computation.msh"]),
        _ => None,
    }
}

/// Collects every semantic problem of `file` (empty: valid).
pub fn validate(file: &LaunchFile) -> Vec<Issue> {
    let mut v = Checks::default();

    // [session]
    if msgs::ipc::session_name(Some(&file.session.name)).is_err() {
        v.push(
            "session.name",
            format!(
                "{:?} is not a valid session name; allowed: 1–64 characters of A–Z, a–z, 0–9, `_`, `-`",
                file.session.name
            ),
        );
    }
    v.non_negative(
        "session.seconds",
        file.session.seconds,
        "s; 0 runs until Ctrl-C",
    );

    // [nodes]
    let n = &file.nodes;
    if !(n.physics || n.haptic || n.bridge || n.recorder) {
        v.push(
            "nodes",
            "no node is enabled; enable at least one of physics, haptic, bridge, recorder",
        );
    }

    // [launcher]
    let l = &file.launcher;
    v.non_negative("launcher.restart_backoff_s", l.restart_backoff_s, "s");
    v.positive("launcher.ready_timeout_s", l.ready_timeout_s, "s");
    v.positive("launcher.stop_grace_s", l.stop_grace_s, "s");
    v.positive("launcher.status_period_s", l.status_period_s, "s");

    // [scene]
    let s = &file.scene;
    v.positive("scene.dt", s.dt, "s (the study uses 0.01)");
    v.finite_array("scene.gravity", &s.gravity, "m/s²");

    let m = &s.meniscus;
    check_mesh_spec(&mut v, "scene.meniscus.mesh", &m.mesh);
    v.transform("scene.meniscus.transform", &m.transform);
    v.transform("scene.meniscus.visual_transform", &m.visual_transform);
    if let Some(visual) = &m.visual {
        v.existing_file(
            "scene.meniscus.visual",
            visual,
            &["obj", "stl"],
            "a path to an OBJ or STL surface (relative to the launch file's folder)",
        );
    }
    if !matches!(m.fixed.as_str(), "inferior" | "none") {
        v.existing_file(
            "scene.meniscus.fixed",
            &m.fixed,
            &[],
            "`inferior`, `none`, or a path to a file of 0-based node indices",
        );
    }
    let max_support = crate::scene::MAX_SUPPORT_STIFFNESS;
    if !(m.support_stiffness.is_finite() && (0.0..=max_support).contains(&m.support_stiffness)) {
        v.push(
            "scene.meniscus.support_stiffness",
            format!(
                "{} is out of range; allowed: 0 ≤ k ≤ {max_support:e} N/m per node (0 holds the fixed nodes rigidly)",
                m.support_stiffness
            ),
        );
    }

    let mat = &s.material;
    // Choices (preset, model, solver kind, rotation, CG matrix, device backend, displacement
    // reference, emulated sites) are enums checked when the file is parsed (`crate::load`).
    if mat.preset == MaterialPreset::Custom {
        if mat.youngs_modulus.is_none() {
            v.push(
                "scene.material.youngs_modulus",
                "preset `custom` needs youngs_modulus (Pa, > 0)",
            );
        }
        if mat.poisson_ratio.is_none() {
            v.push(
                "scene.material.poisson_ratio",
                "preset `custom` needs poisson_ratio (0 ≤ ν < 0.5)",
            );
        }
    }
    if let Some(e) = mat.youngs_modulus {
        v.positive(
            "scene.material.youngs_modulus",
            e,
            "Pa (lateral meniscus 3.5e6)",
        );
    }
    if let Some(nu) = mat.poisson_ratio {
        if !(nu.is_finite() && (0.0..0.5).contains(&nu)) {
            v.push(
                "scene.material.poisson_ratio",
                format!("{nu} is out of range; allowed: 0 ≤ ν < 0.5"),
            );
        }
    }
    v.positive(
        "scene.material.density",
        mat.density,
        "kg/m³ (meniscus 1090)",
    );
    if !(mat.degeneration_grade.is_finite() && (0.0..=2.0).contains(&mat.degeneration_grade)) {
        v.push(
            "scene.material.degeneration_grade",
            format!(
                "{} is out of range; allowed: 0 ≤ grade ≤ 2",
                mat.degeneration_grade
            ),
        );
    }
    v.positive(
        "scene.material.modulus_scale",
        mat.modulus_scale,
        "(1 = nominal)",
    );
    let max_k = crate::scene::MAX_STRAIN_STIFFENING;
    if !(mat.strain_stiffening.is_finite() && (0.0..=max_k).contains(&mat.strain_stiffening)) {
        v.push(
            "scene.material.strain_stiffening",
            format!(
                "{} is out of range; allowed: 0 ≤ rate ≤ {max_k} (per unit strain; 0 = linear)",
                mat.strain_stiffening
            ),
        );
    }
    v.non_negative("scene.material.rayleigh_mass", mat.rayleigh_mass, "1/s");
    v.non_negative(
        "scene.material.rayleigh_stiffness",
        mat.rayleigh_stiffness,
        "s",
    );

    let sol = &s.solver;
    v.non_negative(
        "scene.solver.stiffness_rotation_tolerance",
        sol.stiffness_rotation_tolerance,
        "rad",
    );
    if sol.stiffness_rotation_tolerance > MAX_STIFFNESS_ROTATION_TOLERANCE {
        v.push(
            "scene.solver.stiffness_rotation_tolerance",
            format!(
                "{} rad is too lax: at most {MAX_STIFFNESS_ROTATION_TOLERANCE} (a stiffness \
                 matrix that never follows the rotations makes the implicit step diverge)",
                sol.stiffness_rotation_tolerance
            ),
        );
    }
    if sol.cg_iterations == 0 {
        v.push(
            "scene.solver.cg_iterations",
            "must be > 0 (the study uses 25)",
        );
    }
    v.positive("scene.solver.cg_tolerance", sol.cg_tolerance, "");
    if let Some(p) = sol.offline_tolerance_problem() {
        v.push("scene.solver.offline_tolerance", p);
    }

    let c = &s.contact;
    v.positive("scene.contact.alarm_distance", c.alarm_distance, "m");
    v.non_negative("scene.contact.contact_distance", c.contact_distance, "m");
    if c.contact_distance.is_finite()
        && c.alarm_distance.is_finite()
        && c.contact_distance >= c.alarm_distance
    {
        v.push(
            "scene.contact.contact_distance",
            format!(
                "{} m is not below alarm_distance {} m; allowed: 0 ≤ contact_distance < alarm_distance",
                c.contact_distance, c.alarm_distance
            ),
        );
    }
    v.non_negative("scene.contact.friction", c.friction, "(Coulomb μ)");
    v.non_negative(
        "scene.contact.interface_compliance",
        c.interface_compliance,
        "m/N",
    );
    v.positive("scene.contact.lcp_tolerance", c.lcp_tolerance, "");
    if c.lcp_max_iterations == 0 {
        v.push("scene.contact.lcp_max_iterations", "must be > 0");
    }
    if c.max_contacts == 0 || c.max_contacts as usize > msgs::MAX_CONTACTS {
        v.push(
            "scene.contact.max_contacts",
            format!(
                "{} is out of range; allowed: 1..={}",
                c.max_contacts,
                msgs::MAX_CONTACTS
            ),
        );
    }

    let fc = &s.faults;
    v.positive(
        "scene.faults.max_contact_force_n",
        fc.max_contact_force_n,
        "N (a physical bound for the scene's contact force)",
    );
    v.positive("scene.faults.max_penetration_m", fc.max_penetration_m, "m");
    v.positive("scene.faults.max_cg_residual", fc.max_cg_residual, "");
    v.non_negative("scene.faults.energy_tolerance", fc.energy_tolerance, "");
    if fc.rest_after_faults == 0 {
        v.push("scene.faults.rest_after_faults", "must be > 0");
    }
    v.positive(
        "scene.material_change_interval_s",
        s.material_change_interval_s,
        "s (material changes are rate-limited)",
    );
    if s.material_change_interval_s > 3600.0 {
        v.push(
            "scene.material_change_interval_s",
            format!(
                "{} s is too long; at most 3600 s",
                s.material_change_interval_s
            ),
        );
    }

    let p = &s.probe;
    if !crate::scene::BUILTIN_PROBE_MODELS.contains(&p.model.as_str()) {
        v.existing_file(
            "scene.probe.model",
            &p.model,
            &["obj"],
            "`default` (the hook), `hook`, `sphere` (the tip ball alone) or a path to an OBJ \
             collision model",
        );
    }
    v.transform("scene.probe.transform", &p.transform);
    v.positive("scene.probe.mass", p.mass, "kg (the study's probe: 0.035)");
    v.positive("scene.probe.tip_radius", p.tip_radius, "m");
    v.positive(
        "scene.probe.coupling_stiffness",
        p.coupling_stiffness,
        "N/m",
    );
    v.positive(
        "scene.probe.coupling_angular_stiffness",
        p.coupling_angular_stiffness,
        "N·m/rad",
    );
    v.non_negative("scene.probe.coupling_damping", p.coupling_damping, "N·s/m");
    v.non_negative(
        "scene.probe.coupling_angular_damping",
        p.coupling_angular_damping,
        "N·m·s/rad",
    );
    v.finite_array("scene.probe.initial_position", &p.initial_position, "m");
    v.unit_quaternion("scene.probe.initial_orientation", &p.initial_orientation);

    // [device]
    let d = &file.device;
    v.positive(
        "device.rate_hz",
        d.rate_hz,
        "Hz (the Touch servo loop runs at 1000)",
    );
    if !(d.servo_spin_s.is_finite() && (0.0..=0.5 / d.rate_hz.max(1.0)).contains(&d.servo_spin_s)) {
        v.push(
            "device.servo_spin_s",
            format!(
                "{} s: allowed 0 ≤ servo_spin_s ≤ half the servo period",
                d.servo_spin_s
            ),
        );
    }
    if !(d.force_scale.is_finite() && (0.0..=1.0).contains(&d.force_scale)) {
        v.push(
            "device.force_scale",
            format!(
                "{} is not allowed; must be within 0..=1 (0 = automatic from the tissue \
                 reference and the device limits, 1 = physical; the device never amplifies \
                 the tissue force)",
                d.force_scale
            ),
        );
    }
    v.positive("device.peak_force_n", d.peak_force_n, "N (Touch: 3.3)");
    v.positive(
        "device.continuous_force_n",
        d.continuous_force_n,
        "N (Touch: 0.88)",
    );
    v.positive("device.continuous_window_s", d.continuous_window_s, "s");
    v.positive(
        "device.max_force_rate_n_per_s",
        d.max_force_rate_n_per_s,
        "N/s",
    );
    v.positive(
        "device.max_stiffness_n_per_m",
        d.max_stiffness_n_per_m,
        "N/m (Touch: 1000)",
    );
    if !(d.position_hysteresis_m.is_finite() && (0.0..=1e-3).contains(&d.position_hysteresis_m)) {
        v.push(
            "device.position_hysteresis_m",
            format!(
                "{} m is out of range; allowed: 0 ≤ position_hysteresis_m ≤ 0.001 m (Touch: 3.3e-5)",
                d.position_hysteresis_m
            ),
        );
    }
    // Device limits are invariants: lowering is allowed, raising never.
    for raise in d.limit_raises() {
        v.push(raise.key, raise.to_string());
    }
    v.positive(
        "device.tissue_force_range_n",
        d.tissue_force_range_n,
        "N (cadaver table: 7.2)",
    );
    v.positive(
        "device.tissue_stiffness_n_per_m",
        d.tissue_stiffness_n_per_m,
        "N/m (cadaver table: 3100)",
    );
    let (lo, hi) = crate::device::SERVO_WATCHDOG_RANGE_S;
    let wd = d.touch.servo_watchdog_s;
    if !(wd.is_finite() && (lo..=hi).contains(&wd)) {
        v.push(
            "device.touch.servo_watchdog_s",
            format!("{wd} s is out of range; allowed: {lo} ≤ servo_watchdog_s ≤ {hi} s"),
        );
    }
    v.positive("device.stale_frame_s", d.stale_frame_s, "s");
    v.non_negative("device.stale_ramp_s", d.stale_ramp_s, "s");
    v.positive("device.stats_rate_hz", d.stats_rate_hz, "Hz");
    v.positive("device.workspace_scale", d.workspace_scale, "");
    v.finite_array("device.workspace_offset_m", &d.workspace_offset_m, "m");
    let e = &d.emulated;
    if e.probings_per_region == 0 {
        v.push(
            "device.emulated.probings_per_region",
            "must be ≥ 1 (the study: 5)",
        );
    }
    v.positive(
        "device.emulated.approach_speed_m_per_s",
        e.approach_speed_m_per_s,
        "m/s",
    );
    v.positive(
        "device.emulated.press_speed_m_per_s",
        e.press_speed_m_per_s,
        "m/s",
    );
    v.non_negative("device.emulated.hover_m", e.hover_m, "m");
    v.non_negative("device.emulated.press_depth_m", e.press_depth_m, "m");
    v.non_negative(
        "device.emulated.press_force_n",
        e.press_force_n,
        "N at the tissue (0 = press to press_depth_m; the study: 4.16)",
    );
    v.non_negative("device.emulated.hold_s", e.hold_s, "s");
    if d.backend == DeviceBackend::Replay {
        if d.replay.path.is_empty() {
            v.push(
                "device.replay.path",
                "backend `replay` needs a CSV trajectory (header t_s,px_m,py_m,pz_m,qx,qy,qz,qw) \
                 or a session recording (.mcap)",
            );
        } else {
            v.existing_file(
                "device.replay.path",
                &d.replay.path,
                &["csv", "mcap"],
                "a path to a CSV trajectory or a session recording (.mcap), relative to the \
                 launch file's folder",
            );
        }
    }
    v.positive(
        "device.replay.time_scale",
        d.replay.time_scale,
        "(1 = recorded speed)",
    );

    // [bridge] and [recording]: their owners' checks; the key leads each message.
    if let Err(e) = file.bridge.validate() {
        v.push_owned("bridge", e.to_string());
    }
    if let Err(e) = file.recording.validate() {
        v.push_owned("recording", e.to_string());
    }
    if let Err(e) = file.viewer.validate() {
        v.push_owned("viewer", e.to_string());
    }
    if let Err(e) = file.training.validate() {
        v.push_owned("training", e.to_string());
    }

    check_upper_bounds(&mut v, file);
    v.issues
}

/// Longest bounded session, s (30 days): longer runs use `seconds = 0` (until stopped).
/// Durations beyond what a `Duration` or a lab day can hold never reach the launcher.
pub const MAX_SESSION_S: f64 = 30.0 * 86_400.0;
/// Largest physics step, s: above this the implicit step and the haptic transport (which
/// re-solves the frame of the last step) are far outside what the model was built for.
pub const MAX_DT_S: f64 = 0.1;
/// Smallest physics step, s (the physics cannot keep real time below it on any mesh here).
pub const MIN_DT_S: f64 = 1.0e-5;
/// Largest launcher waits, s.
pub const MAX_LAUNCHER_WAIT_S: f64 = 3_600.0;
/// Largest device servo rate, Hz (the Touch runs at 1 kHz).
pub const MAX_DEVICE_RATE_HZ: f64 = 10_000.0;
/// Largest queue / history depth of a bridge stream: bounds what the bridge allocates.
pub const MAX_BRIDGE_DEPTH: usize = 1 << 16;
/// Largest recording chunk, bytes (the reader refuses larger chunks).
pub const MAX_CHUNK_SIZE_BYTES: u64 = 256 << 20;

/// Upper bounds of every duration, rate and step (the lower bounds are checked with each
/// key above). Each problem names the key; [`crate::load`] adds line and column.
fn check_upper_bounds(v: &mut Checks, file: &LaunchFile) {
    v.at_most(
        "session.seconds",
        file.session.seconds,
        MAX_SESSION_S,
        "s",
        "30 days; 0 runs until Ctrl-C",
    );
    let l = &file.launcher;
    for (key, value) in [
        ("launcher.restart_backoff_s", l.restart_backoff_s),
        ("launcher.ready_timeout_s", l.ready_timeout_s),
        ("launcher.stop_grace_s", l.stop_grace_s),
    ] {
        v.at_most(key, value, MAX_LAUNCHER_WAIT_S, "s", "one hour");
    }
    v.at_most(
        "launcher.status_period_s",
        l.status_period_s,
        60.0,
        "s",
        "a status line at least every minute",
    );
    v.at_most(
        "scene.dt",
        file.scene.dt,
        MAX_DT_S,
        "s",
        "the study uses 0.01",
    );
    let dt = file.scene.dt;
    if dt.is_finite() && dt > 0.0 && dt < MIN_DT_S {
        v.push(
            "scene.dt",
            format!("{dt} s is too small; at least {MIN_DT_S} s (the study uses 0.01)"),
        );
    }
    let d = &file.device;
    v.at_most(
        "device.rate_hz",
        d.rate_hz,
        MAX_DEVICE_RATE_HZ,
        "Hz",
        "the Touch servo runs at 1 kHz",
    );
    v.at_most(
        "device.continuous_window_s",
        d.continuous_window_s,
        600.0,
        "s",
        "ten minutes",
    );
    v.at_most("device.stale_frame_s", d.stale_frame_s, 10.0, "s", "");
    v.at_most("device.stale_ramp_s", d.stale_ramp_s, 10.0, "s", "");
    v.at_most(
        "device.lcp_budget_s",
        d.lcp_budget_s,
        0.01,
        "s",
        "ten servo ticks",
    );
    v.at_most(
        "device.stats_rate_hz",
        d.stats_rate_hz,
        MAX_DEVICE_RATE_HZ,
        "Hz",
        "at most once per servo tick",
    );
    v.at_most(
        "device.emulated.hold_s",
        d.emulated.hold_s,
        MAX_LAUNCHER_WAIT_S,
        "s",
        "one hour",
    );
    for (key, value) in [
        (
            "device.emulated.approach_speed_m_per_s",
            d.emulated.approach_speed_m_per_s,
        ),
        (
            "device.emulated.press_speed_m_per_s",
            d.emulated.press_speed_m_per_s,
        ),
    ] {
        v.at_most(key, value, 1.0, "m/s", "a hand moves the stylus slower");
    }
    v.at_most(
        "device.replay.time_scale",
        d.replay.time_scale,
        100.0,
        "",
        "replays at most 100× the recorded speed",
    );
    let r = &file.recording;
    // Any rate above the physics step rate records every frame (a test that compares the
    // recording with the live bridge asks for 1e9 Hz: frames of a catch-up burst are
    // microseconds apart); the bound only keeps the pacing period a finite, positive time.
    v.at_most(
        "recording.mesh_rate_hz",
        r.mesh_rate_hz,
        1.0e9,
        "Hz",
        "a pacing period of 1 ns; above the physics rate every frame is recorded anyway",
    );
    if r.chunk_size_bytes > MAX_CHUNK_SIZE_BYTES {
        v.push(
            "recording.chunk_size_bytes",
            format!(
                "{} is too large; at most {MAX_CHUNK_SIZE_BYTES} bytes",
                r.chunk_size_bytes
            ),
        );
    }
    let b = &file.bridge;
    if b.queue_depth > MAX_BRIDGE_DEPTH {
        v.push(
            "bridge.queue_depth",
            format!("{} is too large; at most {MAX_BRIDGE_DEPTH}", b.queue_depth),
        );
    }
    for (name, stream) in b.streams.named() {
        if stream.depth > MAX_BRIDGE_DEPTH {
            v.push(
                &format!("bridge.streams.{name}.depth"),
                format!("{} is too large; at most {MAX_BRIDGE_DEPTH}", stream.depth),
            );
        }
        if stream.rate_hz.is_finite() && stream.rate_hz > MAX_DEVICE_RATE_HZ {
            v.push(
                &format!("bridge.streams.{name}.rate_hz"),
                format!(
                    "{} Hz is too large; at most {MAX_DEVICE_RATE_HZ} Hz (0: every sample)",
                    stream.rate_hz
                ),
            );
        }
    }
}

fn check_mesh_spec(v: &mut Checks, key: &str, spec: &str) {
    const ALLOWED: &str =
        "allowed: `default:lateral|medial:coarse|fine|finest|ARCxRADIALxVERTICAL`, \
        `study:lateral|medial` (from ARTHROSIM_DATA), or a path to a Gmsh 4.1 `.msh` file \
        (relative to the launch file's folder)";
    if let Some(rest) = spec.strip_prefix("default:") {
        let parts: Vec<&str> = rest.split(':').collect();
        let ok = parts.len() == 2
            && matches!(parts[0], "lateral" | "medial")
            && crate::scene::is_mesh_resolution(parts[1]);
        if !ok {
            v.push(key, format!("{spec:?} is not a mesh spec; {ALLOWED}"));
        }
    } else if let Some(side) = spec.strip_prefix("study:") {
        match study_files(side) {
            None => v.push(key, format!("{spec:?} is not a mesh spec; {ALLOWED}")),
            Some(files) => {
                let dir = crate::data_dir();
                let missing: Vec<String> = files
                    .iter()
                    .map(|f| dir.join(f))
                    .filter(|p| !p.is_file())
                    .map(|p| p.display().to_string())
                    .collect();
                if !missing.is_empty() {
                    v.push(
                        key,
                        format!(
                            "{spec:?} needs the study's data, but {} is missing; set \
                             ARTHROSIM_DATA to the folder holding meniscus/ (default ../shared/data)",
                            missing.join(", ")
                        ),
                    );
                }
            }
        }
    } else {
        v.existing_file(key, spec, &["msh"], ALLOWED);
    }
}

#[derive(Default)]
struct Checks {
    issues: Vec<Issue>,
}

impl Checks {
    fn push(&mut self, key: &str, message: impl Into<String>) {
        self.issues.push(Issue::at_key(key, message));
    }

    /// A section owner's message that starts with its dotted key (`bridge.domain_id = 300:
    /// …`): the key is taken from the message, else the section.
    fn push_owned(&mut self, section: &str, message: String) {
        let lead: String = message
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '[' | ']'))
            .collect();
        let key = if lead.starts_with(&format!("{section}.")) {
            lead
        } else {
            section.to_string()
        };
        self.issues.push(Issue::at_key(key, message));
    }

    fn positive(&mut self, key: &str, value: f64, unit: &str) {
        if !(value.is_finite() && value > 0.0) {
            self.push(
                key,
                format!("{value} is not allowed; must be finite and > 0 {unit}"),
            );
        }
    }

    /// Upper bound (NaN and ±inf are reported by the lower-bound checks).
    fn at_most(&mut self, key: &str, value: f64, max: f64, unit: &str, why: &str) {
        if value.is_finite() && value > max {
            let why = if why.is_empty() {
                String::new()
            } else {
                format!(" ({why})")
            };
            self.push(
                key,
                format!("{value} {unit} is too large; at most {max} {unit}{why}"),
            );
        }
    }

    fn non_negative(&mut self, key: &str, value: f64, unit: &str) {
        if !(value.is_finite() && value >= 0.0) {
            self.push(
                key,
                format!("{value} is not allowed; must be finite and ≥ 0 {unit}"),
            );
        }
    }

    fn finite_array(&mut self, key: &str, values: &[f64], unit: &str) {
        for (i, x) in values.iter().enumerate() {
            if !x.is_finite() {
                self.push(
                    &format!("{key}[{i}]"),
                    format!("{x} is not allowed; must be finite ({unit})"),
                );
            }
        }
    }

    fn transform(&mut self, key: &str, t: &TransformConfig) {
        self.positive(&format!("{key}.scale"), t.scale, "");
        self.finite_array(&format!("{key}.rotation_deg"), &t.rotation_deg, "degrees");
        self.finite_array(&format!("{key}.translation"), &t.translation, "m");
    }

    fn unit_quaternion(&mut self, key: &str, q: &[f64; 4]) {
        let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
        if !(norm.is_finite() && (norm - 1.0).abs() < 1e-3) {
            self.push(
                key,
                format!("{q:?} is not a unit quaternion [x, y, z, w] (norm {norm:.4}); allowed: norm 1 ± 1e-3"),
            );
        }
    }

    fn existing_file(&mut self, key: &str, path: &str, extensions: &[&str], allowed: &str) {
        if is_builtin_spec(path) && !extensions.contains(&"msh") {
            self.push(key, format!("{path:?} is not a file path; {allowed}"));
            return;
        }
        let p = Path::new(path);
        if !extensions.is_empty() {
            let ext = p
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase)
                .unwrap_or_default();
            if !extensions.contains(&ext.as_str()) {
                let list: Vec<String> = extensions.iter().map(|e| format!(".{e}")).collect();
                self.push(
                    key,
                    format!("{path:?} does not end in {}; {allowed}", list.join(" or ")),
                );
                return;
            }
        }
        if !p.is_file() {
            self.push(
                key,
                format!("file {} does not exist; {allowed}", p.display()),
            );
        }
    }
}
