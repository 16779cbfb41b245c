//! Calibration (issue 13, point 2): the diagnosis' verdict written back as a launch file whose
//! scene carries the fitted effect as physics (scene keys the FEM, contact and support read),
//! never as a reshaping of the output force.
//!
//! ```text
//! arthrosim gap INPUT … --out REPORT_DIR --calibrate OUT.toml [--launch BASE.toml]
//!     gap::calibrate::check_out_path(out)?;                        // before minutes of replays
//!     let (report, cal) = gap::calibrate::calibrate_input(&input, base, &opts)?;
//!     gap::calibrate::write_launch(&cal, out)?;                     // written, re-loaded, validated
//! ```
//!
//! The one place that maps an effect to launch keys is [`apply_effect`]; [`TISSUE_KEYS`] lists
//! the keys it can write (a force–displacement table is calibrated from a scene with them
//! reset, so the result does not depend on what the base launch file already holds).
use super::dataset::TrialData;
use super::effects::Effect;
use super::fit::FittedParam;
use super::model::ForceModel;
use super::sim_model::{refined_spec, SimForceModel};
use super::{GapError, Options, Region, Report};
use launch_config::{LaunchFile, SceneConfig};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Above this support stiffness (N/m per node) the fitted support is a held node: the
/// re-simulated knots are 1000 and 4000 N/m and the interpolation between the rigid baseline
/// and 4000 N/m cannot tell 10⁷ N/m from rigid.
pub const RIGID_SUPPORT_N_PER_M: f64 = 1.0e7;

/// One change the calibration makes to a scene, or a note on an effect it cannot express
/// as scene physics.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum SceneChange {
    /// A launch key set from a fitted parameter.
    Set {
        effect: String,
        /// Dotted launch key, e.g. `scene.material.modulus_scale`.
        key: String,
        before: String,
        after: String,
        /// The fitted parameter(s) it comes from.
        from: String,
    },
    /// An effect (or a part of one) with no scene key: written as a comment.
    Note { effect: String, text: String },
}

impl SceneChange {
    pub fn line(&self) -> String {
        match self {
            SceneChange::Set {
                effect,
                key,
                before,
                after,
                from,
            } => format!("{effect}: {key} = {after} (was {before}; from {from})"),
            SceneChange::Note { effect, text } => format!("{effect}: not written: {text}"),
        }
    }
}

/// The scene keys [`apply_effect`] writes for the tissue effects, with their neutral values
/// (what a scene without any calibration has).
pub const TISSUE_KEYS: &[&str] = &[
    "scene.material.modulus_scale",
    "scene.meniscus.support_stiffness",
    "scene.material.strain_stiffening",
];

/// The key [`apply_contact_nuisance`] writes.
pub const CONTACT_LAYER_KEY: &str = "scene.contact.interface_compliance";

/// `scene` with every key of [`TISSUE_KEYS`] at its neutral value.
pub fn neutral_tissue(scene: &SceneConfig) -> SceneConfig {
    let mut s = scene.clone();
    s.material.modulus_scale = 1.0;
    s.meniscus.support_stiffness = 0.0;
    s.material.strain_stiffening = 0.0;
    s
}

fn value_of(params: &[FittedParam], effect: Effect, name: &str) -> f64 {
    params
        .iter()
        .find(|p| p.effect == effect.name() && p.name == name)
        .map(|p| p.value)
        .or_else(|| {
            effect
                .params()
                .iter()
                .find(|s| s.name == name)
                .map(|s| s.neutral)
        })
        .unwrap_or(0.0)
}

fn fmt_param(params: &[FittedParam], effect: Effect, name: &str) -> String {
    match params
        .iter()
        .find(|p| p.effect == effect.name() && p.name == name)
    {
        Some(p) if p.std.is_finite() && p.std > 0.0 => {
            format!("{name} {:.6} ± {:.2e} {}", p.value, p.std, p.unit)
                .trim_end()
                .to_string()
        }
        Some(p) => format!("{name} {:.6} {}", p.value, p.unit)
            .trim_end()
            .to_string(),
        None => format!("{name} (not fitted)"),
    }
}

/// Rotation matrix of extrinsic x, then y, then z rotations (degrees), the convention of
/// `TransformConfig::rotation_deg`.
fn rot_xyz(deg: [f64; 3]) -> nalgebra::Rotation3<f64> {
    let [a, b, c] = deg.map(f64::to_radians);
    nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), c)
        * nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::y_axis(), b)
        * nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::x_axis(), a)
}

/// Extrinsic x-y-z angles (degrees) of a rotation matrix (R = Rz Ry Rx).
fn xyz_deg(r: &nalgebra::Rotation3<f64>) -> [f64; 3] {
    let m = r.matrix();
    let b = (-m[(2, 0)]).clamp(-1.0, 1.0).asin();
    let (a, c) = if m[(2, 0)].abs() < 1.0 - 1e-12 {
        (m[(2, 1)].atan2(m[(2, 2)]), m[(1, 0)].atan2(m[(0, 0)]))
    } else {
        // gimbal lock: put everything in x
        ((-m[(1, 2)]).atan2(m[(1, 1)]), 0.0)
    };
    [a, b, c].map(f64::to_degrees)
}

/// THE mapping from a gap effect to launch keys: applies `effect` with its fitted `params` to
/// `scene` and returns what it changed and what it could not express.
///
/// Tissue physics becomes scene keys: `modulus` → `[scene.material] modulus_scale`;
/// `support` → `[scene.meniscus] support_stiffness` (1 / the fitted compliance); `hardening`
/// → its small-strain scale on `modulus_scale` (the scene has no strain-stiffening law yet:
/// the rate is a note); `friction` → `[scene.contact] friction`; `tilt` → the specimen's
/// `[scene.meniscus.transform]` (a `.msh` specimen; built-in meshes ignore the transform: a
/// note); `mesh` → the refined `[scene.meniscus] mesh`. `viscoelastic`, `device` and `sensor`
/// are not tissue physics the scene models: notes.
pub fn apply_effect(
    scene: &mut SceneConfig,
    effect: Effect,
    params: &[FittedParam],
) -> Vec<SceneChange> {
    let v = |name: &str| value_of(params, effect, name);
    let from = |names: &[&str]| {
        names
            .iter()
            .map(|n| fmt_param(params, effect, n))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let set = |key: &str, before: String, after: String, from: String| SceneChange::Set {
        effect: effect.name().into(),
        key: key.into(),
        before,
        after,
        from,
    };
    let note = |text: String| SceneChange::Note {
        effect: effect.name().into(),
        text,
    };
    match effect {
        Effect::Modulus => {
            // the replay scales the scene's modulus (SimForceModel::scene_for): so does this
            let before = scene.material.modulus_scale;
            scene.material.modulus_scale = before * v("modulus_scale");
            vec![set(
                "scene.material.modulus_scale",
                format!("{before}"),
                format!("{}", scene.material.modulus_scale),
                from(&["modulus_scale"]),
            )]
        }
        Effect::Hardening => {
            // force × s · exp(rate · depth): s is a modulus scale at small strain, the rate a
            // stiffening with depth that needs a strain-stiffening material law
            let before = scene.material.modulus_scale;
            scene.material.modulus_scale = before * v("small_strain_scale");
            let mut out = vec![set(
                "scene.material.modulus_scale",
                format!("{before}"),
                format!("{}", scene.material.modulus_scale),
                from(&["small_strain_scale"]),
            )];
            out.push(note(format!(
                "{} (force × exp(rate · depth in mm)): the scene has no strain-stiffening \
                 material law with a launch key, so the stiffening is not rendered",
                from(&["stiffening_rate"])
            )));
            out
        }
        Effect::Support => {
            let c = v("support_compliance");
            let before = scene.meniscus.support_stiffness;
            let k = if c > 0.0 && 1.0 / c < RIGID_SUPPORT_N_PER_M {
                1.0 / c
            } else {
                0.0
            };
            scene.meniscus.support_stiffness = k;
            vec![set(
                "scene.meniscus.support_stiffness",
                format!("{before}"),
                format!("{k}"),
                format!(
                    "{}; stiffness = 1 / compliance{}",
                    from(&["support_compliance"]),
                    if k == 0.0 {
                        ", above 1e7 N/m: held rigidly (0)"
                    } else {
                        ""
                    }
                ),
            )]
        }
        Effect::Friction => {
            // the replay adds μ to the scene's friction (SimForceModel::scene_for)
            let before = scene.contact.friction;
            scene.contact.friction = before + v("mu");
            vec![set(
                "scene.contact.friction",
                format!("{before}"),
                format!("{}", scene.contact.friction),
                from(&["mu"]),
            )]
        }
        Effect::Tilt => {
            let (tx, ty) = (v("tilt_x"), v("tilt_y"));
            if launch_config::load::is_builtin_spec(&scene.meniscus.mesh) {
                return vec![note(format!(
                    "{}: the specimen mesh {} is built in, and built-in meshes ignore \
                     [scene.meniscus.transform]; tilt a .msh specimen instead",
                    from(&["tilt_x", "tilt_y"]),
                    scene.meniscus.mesh
                ))];
            }
            // the replay rotates the specimen about the world origin, x then y (quat_tilt):
            // x' = T (R s x + t) = (T R) s x + T t
            let t = rot_xyz([tx, ty, 0.0]);
            let tr = &mut scene.meniscus.transform;
            let (r_before, t_before) = (tr.rotation_deg, tr.translation);
            let r = t * rot_xyz(tr.rotation_deg);
            tr.rotation_deg = xyz_deg(&r);
            let tt = t * nalgebra::Vector3::from(tr.translation);
            tr.translation = [tt.x, tt.y, tt.z];
            vec![
                set(
                    "scene.meniscus.transform.rotation_deg",
                    format!("{r_before:?}"),
                    format!("{:?}", tr.rotation_deg),
                    from(&["tilt_x", "tilt_y"]),
                ),
                set(
                    "scene.meniscus.transform.translation",
                    format!("{t_before:?}"),
                    format!("{:?}", tr.translation),
                    "the tilt is about the world origin".into(),
                ),
            ]
        }
        Effect::Mesh => match refined_spec(&scene.meniscus.mesh) {
            Some(fine) => {
                let before = std::mem::replace(&mut scene.meniscus.mesh, fine.clone());
                vec![set(
                    "scene.meniscus.mesh",
                    before,
                    fine,
                    "the refined discretisation".into(),
                )]
            }
            None => vec![note(format!(
                "no refined spec of {} is known",
                scene.meniscus.mesh
            ))],
        },
        Effect::Viscoelastic => vec![note(format!(
            "{}: a hereditary (QLV) relaxation; the scene's material is elastic with Rayleigh \
             damping only, which does not relax under a hold",
            from(&["prony_g1", "prony_tau1", "prony_g2", "prony_tau2"])
        ))],
        Effect::Device => vec![note(format!(
            "{}: a bias and an inertia of the measuring device, not of the tissue",
            from(&["bias_x", "bias_y", "bias_z", "tool_mass"])
        ))],
        Effect::Sensor => vec![note(format!(
            "{}: the force sensor's delay and low-pass, not of the tissue",
            from(&["delay", "lowpass_tau"])
        ))],
    }
}

/// A calibrated launch file and how it was made.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// The launch file to write: the base with the calibrated scene.
    pub launch: LaunchFile,
    /// The scene the diagnosis replayed (what the effect was fitted against).
    pub input_scene: SceneConfig,
    pub changes: Vec<SceneChange>,
    /// The verdict (`none`, an effect or a `+`-joined pair).
    pub verdict: String,
    /// What the input was.
    pub source: String,
    /// Held-out RMSE the report promised for the verdict, and the baseline's, N.
    pub promised_heldout_rmse: f64,
    pub baseline_heldout_rmse: f64,
    /// Re-simulations added at fitted values before the final fit ([`refine`]).
    pub refined: Vec<String>,
    /// For a force–displacement table: the probe-curve fit that set the tissue keys, whose
    /// error (not the diagnosis' held-out RMSE of its replay) is what the written scene renders.
    pub table_fit: Option<TableFitError>,
}

/// How closely the written scene's probe curve meets a force–displacement table.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct TableFitError {
    /// Largest error at a table point, N.
    pub max_error_n: f64,
    /// The same, in % of the table's peak force.
    pub max_error_percent_of_peak: f64,
}

impl Calibration {
    /// True when the verdict is `none`: the launch file's scene is the input scene.
    pub fn unchanged(&self) -> bool {
        self.verdict == "none"
    }
    /// The changes that are not written as keys.
    pub fn notes(&self) -> impl Iterator<Item = &SceneChange> {
        self.changes
            .iter()
            .filter(|c| matches!(c, SceneChange::Note { .. }))
    }
}

/// Applies a report's verdict to `scene` (the scene the diagnosis replayed) inside `base`.
pub fn calibrate_report(
    report: &Report,
    scene: &SceneConfig,
    base: &LaunchFile,
) -> Result<Calibration, GapError> {
    let mut out = scene.clone();
    let mut changes = Vec::new();
    if report.verdict.effect != "none" {
        for name in report.verdict.effect.split('+') {
            let e = Effect::parse(name).ok_or_else(|| {
                GapError::Other(format!("verdict names an unknown effect {name:?}"))
            })?;
            changes.extend(apply_effect(&mut out, e, &report.verdict.params));
        }
        if let Some(s) = report.verdict.nuisance_scale {
            changes.extend(apply_nuisance(&mut out, s));
        }
        if let Some(c) = report.verdict.contact_compliance {
            let scaled = out.material.modulus_scale / scene.material.modulus_scale;
            changes.extend(apply_contact_nuisance(&mut out, c, scaled));
        }
    }
    let mut launch = base.clone();
    launch.scene = out;
    Ok(Calibration {
        launch,
        input_scene: scene.clone(),
        changes,
        verdict: report.verdict.effect.clone(),
        source: report.input.clone(),
        promised_heldout_rmse: report.heldout.winner_rmse,
        baseline_heldout_rmse: report.heldout.baseline_rmse,
        refined: Vec::new(),
        table_fit: None,
    })
}

/// The stiffness nuisance fitted with the verdict ([`crate::fit::Nuisance`]) as scene physics:
/// the prediction scales the tissue's whole force by it, which is the modulus and the support
/// scaled together (the replay is linear in both). Written so the scene renders what the
/// report promises; a verdict of `none` writes nothing, nuisance included (the input scene
/// within an unrelated offset is what `none` says).
pub fn apply_nuisance(scene: &mut SceneConfig, s: f64) -> Vec<SceneChange> {
    if s == 1.0 || !s.is_finite() || s <= 0.0 {
        return Vec::new();
    }
    let set = |key: &str, before: f64, after: f64| SceneChange::Set {
        effect: "nuisance".into(),
        key: key.into(),
        before: format!("{before}"),
        after: format!("{after}"),
        from: format!("stiffness_scale = {s:.4} (the global stiffness nuisance)"),
    };
    let before = scene.material.modulus_scale;
    scene.material.modulus_scale = before * s;
    let mut out = vec![set(
        "scene.material.modulus_scale",
        before,
        scene.material.modulus_scale,
    )];
    let k = scene.meniscus.support_stiffness;
    if k > 0.0 {
        scene.meniscus.support_stiffness = k * s;
        out.push(set(
            "scene.meniscus.support_stiffness",
            k,
            scene.meniscus.support_stiffness,
        ));
    }
    out
}

/// The contact nuisance fitted with the verdict (`c`, m/N per probe ball, [`crate::fit`]'s
/// `CONTACT_KNOT`) as scene physics: a penalty layer in series under the probe,
/// `[scene.contact] interface_compliance`. The prediction scales the tissue with the layer by
/// the calibrated modulus factor `scaled`; a penalty layer follows the modulus in the replay
/// (`SimForceModel::scene_for`), so the scene gets the layer divided by that factor, which
/// renders the same force. Like [`apply_nuisance`], written only with an effect.
pub fn apply_contact_nuisance(scene: &mut SceneConfig, c: f64, scaled: f64) -> Vec<SceneChange> {
    if !(c.is_finite() && c > 0.0 && scaled.is_finite() && scaled > 0.0) {
        return Vec::new();
    }
    let before = scene.contact.interface_compliance;
    scene.contact.interface_compliance = (before + c) / scaled;
    vec![SceneChange::Set {
        effect: "nuisance".into(),
        key: CONTACT_LAYER_KEY.into(),
        before: format!("{before}"),
        after: format!("{}", scene.contact.interface_compliance),
        from: format!(
            "contact_compliance = {:.2} µm/N (the contact nuisance), over the modulus factor {scaled:.4}",
            1e6 * c
        ),
    }]
}

/// The embedded default launch file (the base when none is given).
pub fn default_launch() -> Result<LaunchFile, GapError> {
    launch_config::load_str(
        launch_config::DEFAULT_LAUNCH,
        launch_config::DEFAULT_LAUNCH_ORIGIN,
    )
    .map_err(|e| GapError::Other(format!("the embedded default launch file: {e}")))
}

/// Loads a base launch file (its errors name the file and line).
pub fn load_base(path: &Path) -> Result<LaunchFile, GapError> {
    launch_config::load(path).map_err(|e| GapError::Input {
        file: path.to_path_buf(),
        msg: format!("base launch file: {e}"),
    })
}

/// What a calibration input is.
#[derive(Debug, Clone)]
pub enum Input {
    /// An experiment folder, a session recording, or a folder holding one.
    Path(PathBuf),
    /// A force–displacement table (CSV), pressed at the middle protocol site of `site`.
    Table { file: PathBuf, site: Region },
}

/// Relative spacing of the knots [`refine`] adds either side of a settled fit.
pub const REFINE_BRACKET: f64 = 0.1;

/// Rounds of [`refine`] at most (each re-simulates every trial once per refined effect).
/// Each round adds a knot at the new fit, so the fit walks towards the value like a secant
/// iteration; on the tip-first hook over the coarse mesh the force is rough in the support
/// stiffness and five rounds stopped 1% short (fit 1501 N/m, last knot 1485 N/m), leaving
/// the written scene 45% worse than the interpolated promise.
pub const MAX_REFINE_ROUNDS: usize = 8;

/// Diagnoses `input` and applies the verdict.
///
/// - Experiment folder: its specimen scene (as the diagnosis builds it) replaces the base's.
/// - Session recording: the recorded scene; the base is the recorded launch file unless one
///   is given.
/// - Force–displacement table: the base's scene with [`TISSUE_KEYS`] reset, pressed at the
///   middle protocol site of the input's region (the mid body by default), displacement as measured, first row's force as the offset
///   ([`super::fd::TableConvention::as_measured`]).
///
/// The diagnosis is the plain one, then [`refine`]d: a re-simulated effect in the verdict is
/// re-simulated at its fitted value and refitted, so the held-out error the report promises is
/// the error of the scene written, not of an interpolation between distant knots.
/// `base` = None: the embedded default launch file.
pub fn calibrate_input(
    input: &Input,
    base: Option<LaunchFile>,
    opts: &Options,
) -> Result<(Report, Calibration), GapError> {
    let data_dir = super::data_dir();
    let (exp, model, label, base, rendering) = match input {
        Input::Table { file, site } => {
            let base = match base {
                Some(b) => b,
                None => default_launch()?,
            };
            let scene = neutral_tissue(&base.scene);
            let conv = super::fd::TableConvention {
                region: *site,
                ..super::fd::TableConvention::as_measured(&scene.meniscus.mesh)
            };
            let model = SimForceModel::from_scene(scene, &data_dir);
            let site = super::fd::mid_site(file, &conv, &model)?;
            let (exp, label) =
                super::fd::table_experiment(file, &conv, &model, site.point, site.normal, opts.dt)?;
            (exp, model, label, base, None)
        }
        Input::Path(path) => match super::session::session_file(path)? {
            Some(mcap) => {
                let rec = super::session::read_session(&mcap)?;
                let exp = super::session::experiment_from_session(&rec)?;
                let rendering = if rec.ticks.is_empty() {
                    None
                } else {
                    Some(super::session::rendering_gap(&rec)?)
                };
                let model = SimForceModel::for_session(&rec, &data_dir)?;
                let base = match (base, rec.launch) {
                    (Some(b), _) => b,
                    (None, Some(l)) => l,
                    (None, None) => default_launch()?,
                };
                let label = exp.dir.display().to_string();
                (exp, model, label, base, rendering)
            }
            None => {
                let exp = super::load_experiment(path, &data_dir)?;
                let model = SimForceModel::for_experiment(&exp, &data_dir)?;
                let base = match base {
                    Some(b) => b,
                    None => default_launch()?,
                };
                let label = exp.dir.display().to_string();
                (exp, model, label, base, None)
            }
        },
    };
    // the scene written then carries the patch and the anchored tissue the diagnosis replayed
    let model = opts.replay_model(model)?;
    let start = std::time::Instant::now();
    let effects = super::candidate_effects(&exp, &model, opts);
    let mut data = super::prepare_dataset(&exp, &model, &effects, opts)?;
    let diagnose = |data: &[TrialData]| {
        super::diagnose_data(label.clone(), model.describe(), data, &effects, opts, start)
    };
    let mut report = diagnose(&data)?;
    let mut refined = Vec::new();
    for _ in 0..MAX_REFINE_ROUNDS {
        let added = refine(&report, &model, &mut data)?;
        if added.is_empty() {
            break;
        }
        refined.extend(added);
        report = diagnose(&data)?;
    }
    report.rendering_gap = rendering;
    let mut cal = calibrate_report(&report, &model.scene, &base)?;
    cal.refined = refined;
    if let Input::Table { file, site } = input {
        apply_table_fit(&mut cal, file, *site, &data_dir)?;
    }
    Ok((report, cal))
}

/// A force–displacement table carries the tissue's normal response alone, and the scene can
/// render it as physics: the support stiffness and stiffening rate are fitted to the table
/// by probe curves of the scene itself (`physics_node::tissue_fit` at `site`, the mid body
/// unless the user chose another region; displacement as measured, first row the offset),
/// and replace what the verdict's effects set for the tissue keys (its contact nuisance
/// layer too: the base's `interface_compliance` is kept). The diagnosis' `hardening` is a
/// force × exp(rate · depth) fit in the replay, not a scene key; the fit is what makes the
/// written scene reproduce the table.
fn apply_table_fit(
    cal: &mut Calibration,
    file: &Path,
    site: Region,
    data_dir: &Path,
) -> Result<(), GapError> {
    use physics_node::probe_curve::ForceTable;
    let bad = |msg: String| GapError::Input {
        file: file.to_path_buf(),
        msg,
    };
    let table = ForceTable::load(file).map_err(|e| bad(e.to_string()))?;
    // The verdict's contact nuisance is superseded as its stiffness nuisance is: both say how
    // stiff the tissue feels under the probe, and the table fit decides that. Left in, it is
    // the nuisance over the replay's modulus factor (near its 0.01 bound on a stiff scene
    // against the table): a 70 µm/N layer the table does not ask for.
    cal.launch.scene.contact.interface_compliance = cal.input_scene.contact.interface_compliance;
    let scene = neutral_tissue(&cal.launch.scene);
    let fit = physics_node::tissue_fit::fit_table(&scene, data_dir, &table, site)
        .map_err(|e| bad(format!("fitting the scene's tissue to the table: {e}")))?;
    let from = format!(
        "probe curves of the scene fitted to the table at the {} site: largest error {:.3} N \
         = {:.1}% of the table's peak ({} curves)",
        site.name(),
        fit.max_error_n,
        fit.max_error_percent_of_peak,
        fit.evaluations
    );
    cal.table_fit = Some(TableFitError {
        max_error_n: fit.max_error_n,
        max_error_percent_of_peak: fit.max_error_percent_of_peak,
    });
    let before = cal.launch.scene.clone();
    let out = &mut cal.launch.scene;
    out.material.modulus_scale = scene.material.modulus_scale;
    out.meniscus.support_stiffness = fit.support_stiffness;
    out.material.strain_stiffening = fit.strain_stiffening;
    // The verdict's own tissue changes (and its notes on hardening) are superseded.
    cal.changes.retain(|c| match c {
        SceneChange::Set { key, .. } => {
            !TISSUE_KEYS.contains(&key.as_str()) && key != CONTACT_LAYER_KEY
        }
        SceneChange::Note { effect, .. } => effect != Effect::Hardening.name(),
    });
    let set = |key: &str, before: f64, after: f64| SceneChange::Set {
        effect: "table".into(),
        key: key.into(),
        before: format!("{before}"),
        after: format!("{after}"),
        from: from.clone(),
    };
    cal.changes.extend([
        set(
            "scene.material.modulus_scale",
            before.material.modulus_scale,
            out.material.modulus_scale,
        ),
        set(
            "scene.meniscus.support_stiffness",
            before.meniscus.support_stiffness,
            out.meniscus.support_stiffness,
        ),
        set(
            "scene.material.strain_stiffening",
            before.material.strain_stiffening,
            out.material.strain_stiffening,
        ),
    ]);
    Ok(())
}

/// Adds a re-simulated knot at the fitted value of every piecewise-linear effect of the
/// verdict (`support`, `friction`) that is not already close to one; returns what it did.
///
/// Why: the diagnosis interpolates these effects between re-simulations at fixed knots
/// (support at 1000 and 4000 N/m); between them the interpolation is off by a large share of
/// the effect (a 1500 N/m support read as 1270 N/m), so a scene written from it would not
/// render what the report promised.
pub fn refine(
    report: &Report,
    model: &dyn ForceModel,
    data: &mut [TrialData],
) -> Result<Vec<String>, GapError> {
    let mut done = Vec::new();
    if report.verdict.effect == "none" {
        return Ok(done);
    }
    for name in report.verdict.effect.split('+') {
        let Some(e) = Effect::parse(name) else {
            continue;
        };
        let Some(spec) = e.params().into_iter().next() else {
            continue;
        };
        let x = value_of(&report.verdict.params, e, spec.name);
        let Some(first) = data.first() else {
            continue;
        };
        if !data.iter().all(|d| d.has_resims(e)) {
            continue;
        }
        // a knot within 1% of a value: the interpolation is exact enough there
        let have = |v: f64| {
            let near = |k: f64| (k - v).abs() <= 0.01 * k.abs().max(v.abs());
            e.default_knots().iter().copied().any(near)
                || first
                    .extra_knots
                    .get(&e)
                    .is_some_and(|ks| ks.iter().any(|(k, _)| near(*k)))
        };
        // the fitted value, and knots REFINE_BRACKET either side of it: the held-out score
        // fits every fold on its own, and those fits land near, not at, the overall one
        let wanted: Vec<f64> = [x, x * (1.0 - REFINE_BRACKET), x * (1.0 + REFINE_BRACKET)]
            .into_iter()
            .filter(|&v| v > 0.0 && v <= spec.hi && !have(v))
            .collect();
        // the bracket only once the fit has settled on a knot
        let wanted: Vec<f64> = if wanted.contains(&x) { vec![x] } else { wanted };
        for v in wanted {
            let Some(variant) = e.knot_variant(v) else {
                continue;
            };
            let forces = super::dataset::replay_trials(data, model, &variant);
            let mut kept = 0;
            for (d, f) in data.iter_mut().zip(forces) {
                let f = f?;
                // a step the physics flagged as faulty is no solution (the fault flag, not a
                // force heuristic, as in the diagnosis's own re-simulations)
                if f.diverged() {
                    continue;
                }
                d.extra_knots.entry(e).or_default().push((v, f.forces));
                // a centre's correction is against the interpolation it was made on: with a
                // knot near it the interpolation is already the replay there, and the centre
                // would add its correction a second time (a support calibrated with both
                // re-simulated 0.12 N off the 0.02 N it promised)
                d.centres.retain(|k| !k.effects.contains(&e));
                kept += 1;
            }
            done.push(format!(
                "{}: re-simulated at {} = {v:.6} {} ({}; {kept} of {} trials usable)",
                e.name(),
                spec.name,
                spec.unit,
                variant.label(),
                data.len()
            ));
        }
    }
    Ok(done)
}

/// Checks that `out` can be written before any replay runs: its folder exists and it is not
/// a folder itself.
pub fn check_out_path(out: &Path) -> Result<(), GapError> {
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !parent.is_dir() {
        return Err(GapError::Input {
            file: out.to_path_buf(),
            msg: format!(
                "cannot write the calibrated launch file: folder {} does not exist",
                parent.display()
            ),
        });
    }
    if out.is_dir() {
        return Err(GapError::Input {
            file: out.to_path_buf(),
            msg: "is a folder; give the launch file to write (e.g. calibrated.toml)".into(),
        });
    }
    Ok(())
}

fn comment(text: &str) -> String {
    let mut s = String::new();
    for line in text.lines() {
        s.push_str("# ");
        s.push_str(line);
        s.push('\n');
    }
    s
}

/// The launch file's text: a header saying where it comes from, what was set and what was
/// left out, then the whole launch file (every key written, so it runs the same even if the
/// defaults change).
pub fn render(cal: &Calibration) -> Result<String, GapError> {
    let mut head = String::new();
    head.push_str(&format!(
        "Calibrated by `arthrosim gap --calibrate` from {}.\n",
        cal.source
    ));
    if cal.unchanged() {
        head.push_str(
            "Verdict none: no effect explains the gap beyond the noise, so this scene is the \
             input scene unchanged.\n",
        );
    } else {
        head.push_str(&match cal.table_fit {
            // The tissue keys come from the table fit, so its error is what this scene renders.
            Some(t) => format!(
                "Verdict {}; the tissue keys are fitted to the table: largest error {:.3} N = \
                 {:.1}% of its peak (the diagnosis' held-out RMSE {:.4} N was for its replay \
                 fit, not for this scene).\n",
                cal.verdict, t.max_error_n, t.max_error_percent_of_peak, cal.promised_heldout_rmse
            ),
            None => format!(
                "Verdict {}: held-out RMSE {:.4} N (baseline {:.4} N).\n",
                cal.verdict, cal.promised_heldout_rmse, cal.baseline_heldout_rmse
            ),
        });
        let set: Vec<String> = cal
            .changes
            .iter()
            .filter(|c| matches!(c, SceneChange::Set { .. }))
            .map(|c| format!("  {}", c.line()))
            .collect();
        if !set.is_empty() {
            head.push_str("Set:\n");
            head.push_str(&set.join("\n"));
            head.push('\n');
        }
        if !cal.refined.is_empty() {
            head.push_str("Refined:\n");
            for r in &cal.refined {
                head.push_str(&format!("  {r}\n"));
            }
        }
        let notes: Vec<String> = cal.notes().map(|c| format!("  {}", c.line())).collect();
        if !notes.is_empty() {
            head.push_str("Left out (no scene key for it; comments only):\n");
            head.push_str(&notes.join("\n"));
            head.push('\n');
        }
    }
    let body = toml::to_string(&cal.launch)
        .map_err(|e| GapError::Other(format!("serialising the calibrated launch file: {e}")))?;
    Ok(format!("{}\n{body}", comment(&head)))
}

/// Writes the calibrated launch file to `out`, loads it back and validates it (an invalid one
/// is an error, not a file left for `arthrosim run` to reject).
pub fn write_launch(cal: &Calibration, out: &Path) -> Result<LaunchFile, GapError> {
    check_out_path(out)?;
    let text = render(cal)?;
    std::fs::write(out, text).map_err(|e| GapError::Io(out.to_path_buf(), e))?;
    let loaded = launch_config::load(out).map_err(|e| GapError::Input {
        file: out.to_path_buf(),
        msg: format!("the calibrated launch file does not validate: {e}"),
    })?;
    if loaded.scene != cal.launch.scene {
        return Err(GapError::Input {
            file: out.to_path_buf(),
            msg: "the calibrated scene did not survive writing and reading back".into(),
        });
    }
    Ok(loaded)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn param(e: Effect, name: &str, value: f64) -> FittedParam {
        FittedParam::given(e.name(), name, value)
    }

    /// The contact nuisance is written as a penalty layer scaled back by the calibrated modulus
    /// factor (the replay scales a layer with the modulus), added to the scene's own; nothing
    /// is written for no layer or a value that is not one.
    #[test]
    fn the_contact_nuisance_is_written_as_an_interface_compliance() {
        let mut s = SceneConfig::default();
        s.contact.interface_compliance = 1.0e-6;
        let ch = apply_contact_nuisance(&mut s, 5.0e-6, 1.2);
        assert_eq!(ch.len(), 1);
        assert!((s.contact.interface_compliance - 6.0e-6 / 1.2).abs() < 1e-15);
        for (c, factor) in [(0.0, 1.0), (-1e-6, 1.0), (f64::NAN, 1.0), (1e-6, 0.0)] {
            let mut s = SceneConfig::default();
            assert!(apply_contact_nuisance(&mut s, c, factor).is_empty());
            assert_eq!(s, SceneConfig::default());
        }
    }

    #[test]
    fn every_effect_maps_to_keys_or_a_note() {
        for e in Effect::ALL {
            let mut s = SceneConfig::default();
            let params: Vec<FittedParam> = e
                .params()
                .iter()
                .map(|p| param(e, p.name, 0.5 * (p.lo + p.hi)))
                .collect();
            let ch = apply_effect(&mut s, e, &params);
            assert!(!ch.is_empty(), "{}", e.name());
            let tissue = matches!(
                e,
                Effect::Modulus | Effect::Support | Effect::Friction | Effect::Mesh
            );
            if tissue {
                assert_ne!(s, SceneConfig::default(), "{} changed nothing", e.name());
                assert!(ch.iter().all(|c| matches!(c, SceneChange::Set { .. })));
            }
            if matches!(e, Effect::Viscoelastic | Effect::Device | Effect::Sensor) {
                assert_eq!(s, SceneConfig::default(), "{} changed the scene", e.name());
            }
        }
    }

    #[test]
    fn support_compliance_becomes_stiffness_and_modulus_multiplies() {
        let mut s = SceneConfig::default();
        s.material.modulus_scale = 0.5;
        apply_effect(
            &mut s,
            Effect::Modulus,
            &[param(Effect::Modulus, "modulus_scale", 1.4)],
        );
        assert!((s.material.modulus_scale - 0.7).abs() < 1e-12);
        apply_effect(
            &mut s,
            Effect::Support,
            &[param(Effect::Support, "support_compliance", 5.0e-4)],
        );
        assert!((s.meniscus.support_stiffness - 2000.0).abs() < 1e-9);
        apply_effect(
            &mut s,
            Effect::Support,
            &[param(Effect::Support, "support_compliance", 1.0e-9)],
        );
        assert_eq!(s.meniscus.support_stiffness, 0.0, "stiffer than 1e7: held");
    }

    #[test]
    fn tilt_composes_with_the_specimen_transform() {
        let mut s = SceneConfig::default();
        s.meniscus.mesh = "/x/specimen.msh".into();
        s.meniscus.transform.rotation_deg = [10.0, 0.0, 30.0];
        s.meniscus.transform.translation = [0.01, 0.0, 0.0];
        let r0 = rot_xyz([10.0, 0.0, 30.0]);
        apply_effect(
            &mut s,
            Effect::Tilt,
            &[
                param(Effect::Tilt, "tilt_x", 5.0),
                param(Effect::Tilt, "tilt_y", -3.0),
            ],
        );
        // same as the replay's tilt quaternion (x then y, about the world origin)
        let q = super::super::signal::quat_tilt(5f64.to_radians(), (-3f64).to_radians());
        let qt = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
            q[3], q[0], q[1], q[2],
        ));
        let want = qt.to_rotation_matrix() * r0;
        let got = rot_xyz(s.meniscus.transform.rotation_deg);
        assert!((want.matrix() - got.matrix()).norm() < 1e-12);
        let tt = qt * nalgebra::Vector3::new(0.01, 0.0, 0.0);
        for k in 0..3 {
            assert!((s.meniscus.transform.translation[k] - tt[k]).abs() < 1e-15);
        }
        // a built-in mesh ignores the transform: a note, nothing changed
        let mut b = SceneConfig::default();
        let ch = apply_effect(&mut b, Effect::Tilt, &[param(Effect::Tilt, "tilt_x", 5.0)]);
        assert_eq!(b, SceneConfig::default());
        assert!(matches!(ch[0], SceneChange::Note { .. }));
    }
}
