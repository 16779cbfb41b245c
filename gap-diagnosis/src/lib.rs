//! Sim-to-real gap diagnosis and offline re-simulation: where the simulated and measured
//! probe forces differ, which unmodelled effect explains it, and how far the gap shrinks on
//! held-out trials.
//!
//! Data comes in from experiment folders (`experiment.toml` + trial CSVs), force–displacement
//! tables and session recordings (read through `recordings`); it is replayed through the
//! physics node's `Simulation` driven kinematically ([`SimForceModel`], [`replay`]) and goes out
//! as `report.json` + `report.html`. This is the last stage of the data path
//! physics → haptic → bridge / recorder → gap.
//!
//! # API the CLI wires (no clap types here; every function returns `Result<_, GapError>`)
//! ```text
//! arthrosim gap EXPERIMENT_DIR --out REPORT_DIR [--dt S]
//!     let report = gap_diagnosis::diagnose_dir(dir, &gap_diagnosis::Options { progress: true, ..Default::default() })?;
//!     gap_diagnosis::write_report(&report, out_dir)?;            // report.json + report.html
//!     println!("{}", report.verdict.effect);
//! arthrosim gap SESSION.mcap --out REPORT_DIR     (or a folder holding one .mcap, no experiment.toml)
//!     let report = gap_diagnosis::diagnose_dir(path, &opts)?;     // → diagnose_session: probings as trials,
//!                                                       //   report.rendering_gap from the device ticks
//! arthrosim gap EXPERIMENT_DIR --session SESSION.mcap --out REPORT_DIR
//!     report.rendering_gap = Some(gap_diagnosis::session_rendering_gap(mcap)?);  // checked before the replays
//! arthrosim gap --force-displacement FILE.csv --out REPORT_DIR
//!     let report = gap_diagnosis::diagnose_force_displacement(file, &opts)?; gap_diagnosis::write_report(&report, out)?;
//! arthrosim gap selftest --cases N --seed S [--json]
//!     let r = gap_diagnosis::selftest::selftest(n, seed, &gap_diagnosis::selftest::SelftestOptions { verbose: true, ..Default::default() })?;
//!     print!("{}", r.table());                          // per-case lines + confusion matrix
//!     if json { println!("{}", serde_json::to_string(&r.summary())?) }  // cases, correct, accuracy, heldout_shrink_mean
//! arthrosim gap bench [--effect NAME] [--seed S]       // one JSON line with diagnose_s
//!     println!("{}", gap_diagnosis::selftest::bench("hardening", seed, None, &gap_diagnosis::Options::default())?);
//! arthrosim gap INPUT … --out REPORT_DIR --calibrate OUT.toml [--launch BASE.toml]
//!     calibrate::check_out_path(out)?;                  // before the replays
//!     let (report, cal) = calibrate::calibrate_input(&input, base, &opts)?;
//!     calibrate::write_launch(&cal, out)?;              // the verdict as scene keys, validated
//! arthrosim reality --effect NAME[=STRENGTH] [--effect ...] --seed S --out DIR --truth FILE
//!     let spec = gap_diagnosis::reality::RealitySpec::from_effects(&["friction=0.3", "sensor"], seed)?;
//!     gap_diagnosis::reality::write_experiment(&spec, dir, truth_file)?;   // truth file must lie outside DIR
//! ```
//! Lower level: `load_experiment(dir, &data_dir())`, `SimForceModel::for_experiment(&exp, &data_dir())`,
//! `diagnose(&exp, &model, &opts)` with any [`ForceModel`].
//! The replay model is [`SimForceModel`] (the physics node's `Simulation` driven kinematically);
//! statistics and effects are written against the [`ForceModel`] trait.

pub mod calibrate;
pub mod centres;
pub mod dataset;
pub mod effects;
pub mod experiment;
pub mod fd;
pub mod fit;
pub mod html;
pub mod level;
pub mod metrics;
pub mod model;
pub mod patch_anchor;
pub mod reality;
pub mod recovery;
pub mod replay;
pub mod selftest;
pub mod separability;
pub mod session;
pub mod signal;
pub mod strength;

pub use effects::{Candidate, Effect};
pub use experiment::{
    load_experiment, read_force_displacement, Experiment, ExperimentSpec, Region, Trial,
};
pub use fd::{diagnose_force_displacement, diagnose_force_displacement_at};
pub use model::{ForceModel, ProbePath, Variant};

use dataset::{BuildOptions, TrialData};
use fit::{make_folds, score_candidate, shrink, Baseline, CandidateScore, Nuisance};
use metrics::{
    band_label, band_of, region_label, trial_metrics, Acc, GroupResidual, Phase, TrialMetrics,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use signal::{dot, lag_by_xcorr, noise_sigma, sub};
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum GapError {
    #[error("{}: {msg}", file.display())]
    Input { file: PathBuf, msg: String },
    #[error("{}:{line}: {msg}", file.display())]
    Line {
        file: PathBuf,
        line: usize,
        msg: String,
    },
    #[error("{path}: {err}", path = .0.display(), err = .1)]
    Io(PathBuf, std::io::Error),
    #[error("simulation: {0}")]
    Sim(String),
    /// The scene's offline solver setting is out of bounds.
    #[error(transparent)]
    Solver(#[from] launch_config::scene::SolverConfigError),
    /// Reading a session recording (the error names the file).
    #[error(transparent)]
    Recording(#[from] recordings::RecordingError),
    #[error("{0}")]
    Other(String),
}

impl From<msgs::csv_input::CsvError> for GapError {
    fn from(e: msgs::csv_input::CsvError) -> Self {
        GapError::Line {
            file: e.file,
            line: e.line,
            msg: e.problem,
        }
    }
}

/// Study data folder: the one definition, [`launch_config::data_dir`] (`ARTHROSIM_DATA`, else
/// `../shared/data` beside the workspace).
pub fn data_dir() -> PathBuf {
    launch_config::data_dir()
}

#[derive(Debug, Clone)]
pub struct Options {
    /// Replay step, s.
    pub dt: f64,
    pub progress: bool,
    /// Candidate effects considered (default: all nine).
    pub effects: Vec<Effect>,
    /// Consider pairs of effects.
    pub pairs: bool,
    /// Minimum held-out shrink, against the nuisance floor, for an effect to count as
    /// identified.
    pub min_shrink: f64,
    /// Fit the global stiffness nuisance ([`fit::Nuisance`]) with the baseline and every
    /// candidate (default). Off: the scale is held at 1 and no contact term is fitted, as
    /// before issue 15 (for comparison).
    pub nuisance: bool,
    /// With `nuisance`: also fit the contact nuisance, a compliance in series under the probe
    /// ([`fit::CONTACT_KNOT`]; one more replay per trial). Default on (README, "A contact
    /// nuisance beside it").
    pub contact_nuisance: bool,
    /// With `nuisance`: also fit the material nuisance, a mixture of the replay's corotational
    /// law and the stable neo-Hookean one ([`fit::MATERIAL_WEIGHT_MAX`]; one more replay per
    /// trial). Default on (README, "A second constitutive law beside it").
    pub material_nuisance: bool,
    /// Re-simulate every trial once more at the support the whole experiment fits, when its
    /// compliance is at least [`centres::MIN_CENTRE_SUPPORT`], at the tilt, when it is at
    /// least [`centres::MIN_CENTRE_DEG`], and at the tilt+support pair's fit ([`centres`]; up
    /// to [`centres::ROUNDS`] replays per trial for each single effect, and
    /// [`centres::PAIR_ROUNDS`] centres of four replays each, with their slopes, for the
    /// pair). Default on.
    pub centres: bool,
    /// The nuisances' level band, [lo, hi] ([`fit::LEVEL_MIN`], [`fit::LEVEL_MAX`], the
    /// default).
    pub level_band: (f64, f64),
    /// Replay an experiment's probe balls spread over their Hertz patch, the tissue held at
    /// the closest points' level ([`patch_anchor`]; README, "The Hertz patch in the
    /// replay"). Off by default: the closest points.
    pub hertz_patch: bool,
}

impl Options {
    /// Checks the bounds every diagnosis needs. The replay steps at `dt` (it becomes the
    /// replayed scene's `dt`), so it has `[scene] dt`'s bounds: below them the replay grid of a
    /// long trial overflowed or asked for hundreds of GB (1e-300 s: an add overflow panic;
    /// 1e-9 s: a 564 GB allocation).
    pub fn check(&self) -> Result<(), GapError> {
        let (lo, hi) = (
            launch_config::validate::MIN_DT_S,
            launch_config::validate::MAX_DT_S,
        );
        if !(self.dt.is_finite() && (lo..=hi).contains(&self.dt)) {
            return Err(GapError::Other(format!(
                "replay step dt = {} s: must be from {lo} to {hi} s (bounded like [scene] dt)",
                self.dt
            )));
        }
        if !(self.min_shrink.is_finite() && (0.0..1.0).contains(&self.min_shrink)) {
            return Err(GapError::Other(format!(
                "min_shrink = {}: must be in [0, 1) (a fraction of the held-out error)",
                self.min_shrink
            )));
        }
        let (lo, hi) = self.level_band;
        if !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= 1.0 && 1.0 <= hi) {
            return Err(GapError::Other(format!(
                "level band [{lo}, {hi}]: must hold 1 with a positive lower end"
            )));
        }
        Ok(())
    }
    /// A level band written `LO,HI` (the CLI's `--level-band`); its bounds are
    /// [`Options::check`]'s.
    pub fn parse_level_band(text: &str) -> Result<(f64, f64), GapError> {
        let parsed = text
            .split_once(',')
            .map(|(lo, hi)| (lo.trim().parse::<f64>(), hi.trim().parse::<f64>()));
        match parsed {
            Some((Ok(lo), Ok(hi))) => Ok((lo, hi)),
            _ => Err(GapError::Other(format!(
                "level band {text:?}: give two numbers LO,HI (e.g. 0.696,1.15)"
            ))),
        }
    }
    /// The nuisances these options fit ([`fit::Nuisance`]).
    pub fn nuisance_band(&self) -> Nuisance {
        if !self.nuisance {
            return Nuisance::OFF;
        }
        Nuisance {
            contact_max: if self.contact_nuisance {
                fit::CONTACT_WEIGHT_MAX
            } else {
                0.0
            },
            material_max: if self.material_nuisance {
                fit::MATERIAL_WEIGHT_MAX
            } else {
                0.0
            },
            level_lo: self.level_band.0,
            level_hi: self.level_band.1,
            ..Nuisance::STIFFNESS
        }
    }
    /// The model an input is replayed with: `points` (the closest-point replay of its scene)
    /// as it is, or with [`Options::hertz_patch`] its balls spread over their Hertz patch and
    /// its tissue anchored ([`patch_anchor::anchored_patch`]).
    pub fn replay_model(&self, points: SimForceModel) -> Result<SimForceModel, GapError> {
        if self.hertz_patch {
            Ok(patch_anchor::anchored_patch(&points)?.model)
        } else {
            Ok(points)
        }
    }
    /// The replays the dataset needs for these options' nuisances.
    pub fn build_options(&self) -> BuildOptions {
        BuildOptions {
            dt: self.dt,
            progress: self.progress,
            contact_knot: self.nuisance_band().contact_fitted(),
            material_knot: self.nuisance_band().material_fitted(),
        }
    }
}

impl Default for Options {
    fn default() -> Self {
        Options {
            dt: 0.02,
            progress: false,
            effects: Effect::ALL.to_vec(),
            pairs: true,
            min_shrink: 0.08,
            nuisance: true,
            contact_nuisance: true,
            material_nuisance: true,
            centres: true,
            level_band: (fit::LEVEL_MIN, fit::LEVEL_MAX),
            hertz_patch: false,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Heatmap {
    pub phases: Vec<String>,
    pub regions: Vec<String>,
    /// rmse[phase][region], N (null where no samples).
    pub rmse: Vec<Vec<Option<f64>>>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Localisation {
    pub overall: GroupResidual,
    pub by_axis: Vec<GroupResidual>,
    pub by_phase: Vec<GroupResidual>,
    pub by_region: Vec<GroupResidual>,
    pub by_depth_band: Vec<GroupResidual>,
    pub heatmap: Heatmap,
    pub worst_axis: String,
    pub worst_phase: String,
    pub worst_region: String,
    pub worst_depth_band: String,
    /// The study's metric over all contact samples: mean normal force, N.
    pub mean_normal_force_measured: f64,
    pub mean_normal_force_simulated: f64,
    pub summary: String,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Series {
    pub t: Vec<f64>,
    pub measured: Vec<[f64; 3]>,
    pub baseline: Vec<[f64; 3]>,
    /// Held-out prediction with the winning effect (baseline when the verdict is none).
    pub winner: Vec<[f64; 3]>,
    pub depth_mm: Vec<f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrialReport {
    pub name: String,
    pub region: Option<Region>,
    pub samples: usize,
    /// Lag of the measured force behind the simulated one (cross-correlation), s.
    pub lag_s: Option<f64>,
    pub before: TrialMetrics,
    pub after: TrialMetrics,
    pub series: Series,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Heldout {
    pub scheme: String,
    /// The replay as it is (no parameter fitted), N.
    pub baseline_rmse: f64,
    pub winner_rmse: f64,
    /// Shrink of `winner_rmse` against `baseline_rmse`.
    pub shrink: f64,
    pub baseline_study_error: f64,
    pub winner_study_error: f64,
    /// The global stiffness nuisance ([`fit::Nuisance`]) fitted to the baseline on all trials:
    /// how much stiffer (> 1) or softer the measured tissue answers than the replay, within
    /// the band no effect is needed for. Absent when the nuisance is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nuisance_scale: Option<f64>,
    /// The contact nuisance fitted to the baseline on all trials: a compliance in series with
    /// the tissue under each probe ball, m/N ([`fit::CONTACT_KNOT`]). Absent when it is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_compliance: Option<f64>,
    /// The material nuisance fitted to the baseline on all trials: the weight of the stable
    /// neo-Hookean law against the corotational one (0…1). Absent when it is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material_weight: Option<f64>,
    /// The baseline's response level with those nuisances ([`fit::Nuisance::level`]): its
    /// mean normal force as a fraction of the replay's, within `level_band` (by default
    /// [0.696, 1.15]: [`fit::LEVEL_MIN`], [`fit::LEVEL_MAX`]). Absent when the nuisance is off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level: Option<f64>,
    /// The level band the nuisances were held to, [lo, hi] ([`Options::level_band`]). Absent
    /// when the nuisance is off, and in reports written before it was an option (their
    /// ceiling was ×1.44; report.html shows them today's default).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level_band: Option<(f64, f64)>,
    /// The measured normal force over the replay's where the replay presses, pooled over the
    /// trials ([`level::data_level`]): the response level the data show, with no model.
    /// Absent with fewer than [`level::MIN_LEVEL_TRIALS`] trials in contact.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_level: Option<f64>,
    /// Its between-trial standard error (delete-one jackknife, within the probing regions where
    /// every region has [`level::MIN_STRATUM_TRIALS`] trials in contact: [`level::data_level`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_level_se: Option<f64>,
    /// The nuisance floor: held-out RMSE of the baseline with the nuisance fitted per fold, N.
    /// An effect must shrink this, significantly, to be named.
    #[serde(default)]
    pub nuisance_rmse: f64,
    /// Shrink of `winner_rmse` against `nuisance_rmse` (0 for `none`).
    #[serde(default)]
    pub shrink_over_nuisance: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Verdict {
    /// A candidate's name, a `+`-joined pair, or `none`.
    pub effect: String,
    /// Held-out RMSE shrink of the winner, fraction.
    pub heldout_shrink: f64,
    /// The winner's fitted strengths; a `modulus`'s scale at its response level
    /// ([`fit::CandidateScore::report_modulus_as_level`]).
    pub params: Vec<fit::FittedParam>,
    pub reason: String,
    /// Candidates the held-out data cannot tell apart from `effect` within its between-trial
    /// scatter ([`separability`]): `effect` first, then each rival, best first (read as
    /// `support ~ modulus`). Empty when every rival is told apart, or the verdict is `none`.
    #[serde(default)]
    pub indistinguishable: Vec<String>,
    /// Per rival (`indistinguishable[1..]`): what kind of trial would separate it from `effect`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub separate_by: Vec<String>,
    /// The stiffness nuisance fitted with `effect` (for `none`: with the baseline). Absent
    /// where the effect's own scale is the total (`hardening`) or the nuisance is off; for
    /// `modulus`, the tissue scale its contact and material terms need over its level (the
    /// modulus's reported scale). Calibration writes it as a scale of the whole tissue
    /// (modulus and support).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nuisance_scale: Option<f64>,
    /// The contact nuisance fitted with `effect` (for `none`: with the baseline), m/N per
    /// probe ball. Calibration writes it as `[scene.contact] interface_compliance`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_compliance: Option<f64>,
    /// The material nuisance fitted with `effect` (for `none`: with the baseline): the weight
    /// of the stable neo-Hookean law against the corotational one, 0…1. Calibration does not
    /// write it (a scene has one law); it says how far the specimen's response is from the
    /// replay's law.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub material_weight: Option<f64>,
    /// The response level fitted with `effect` (for `none`: with the baseline;
    /// [`fit::Nuisance::level`]): the stiffness nuisance's scale, or `modulus`'s own, times
    /// the contact and material terms' change of the normal force. What a modulus is judged
    /// by beside its scale ([`strength::negligible`]). Absent for `hardening` and with the
    /// nuisance off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub level: Option<f64>,
    /// The held-out RMSE the verdict's model leaves (for `none`: the baseline with its
    /// nuisances), as a fraction of the measured force's RMS over the same samples and axes:
    /// 1 is no better than predicting no force. At [`UNEXPLAINED_FRACTION`] or above the
    /// replay does not reproduce the experiment, and `reason` says so.
    #[serde(default)]
    pub residual_fraction: f64,
}

/// A verdict's [`Verdict::residual_fraction`] at or above which the replay is reported as not
/// reproducing the experiment, whatever the verdict names. Measured: a no-effect case of
/// the study mesh replayed on it leaves 0.017 (floor 0.21 N of 12.5 N); the self-test's
/// refined truth, a tissue ×1.6 stiffer than the replay, 0.17–0.20; poses probed on the lateral
/// mesh and replayed on the medial one 0.96–1.12, where the verdict read `none` with nothing
/// to say that the model and the measurement had nothing in common.
pub const UNEXPLAINED_FRACTION: f64 = 0.5;

/// The measured force's RMS per axis over every sample of every trial: the scale
/// [`Verdict::residual_fraction`] measures the held-out RMSE against, by the same measure
/// ([`fit::PhaseSse::rmse`], the residual of predicting no force).
fn measured_rms(data: &[TrialData]) -> f64 {
    let mut acc = fit::PhaseSse::default();
    for d in data {
        for (&group, f) in d.var_group.iter().zip(&d.f) {
            acc.push(group, *f);
        }
    }
    acc.rmse()
}

/// Sets `verdict.residual_fraction` from the held-out RMSE its model leaves and, at or above
/// [`UNEXPLAINED_FRACTION`], says in its reason that the replay does not reproduce the
/// experiment and what to check.
fn weigh_residual(verdict: &mut Verdict, residual: f64, data: &[TrialData]) {
    let rms = measured_rms(data);
    verdict.residual_fraction = if rms > 0.0 { residual / rms } else { 0.0 };
    if verdict.residual_fraction >= UNEXPLAINED_FRACTION {
        verdict.reason.push_str(&format!(
            "; but the model still leaves {residual:.4} N held-out RMSE, {:.0}% of the measured \
             force's RMS ({rms:.4} N): the replay does not reproduce this experiment, and no \
             effect can be read from it. Check the specimen mesh and its fixed nodes, the \
             probe poses' frame against the mesh, and the probe's geometry",
            100.0 * verdict.residual_fraction
        ));
    }
}

/// Wall time of a diagnosis' stages, s: the replays (baseline, knots, the contact nuisance's
/// knot), the second stage ([`centres`]) and the fits with their held-out folds; and how many
/// replays the first two made (a trial replayed at one variant is one).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTimes {
    pub replays_s: f64,
    pub centres_s: f64,
    pub fits_s: f64,
    /// Replays of the first stage: every trial at the baseline, each effect's knots and the
    /// nuisances' knots.
    #[serde(default)]
    pub replays: usize,
    /// Replays of the second stage: the centres and their slopes.
    #[serde(default)]
    pub centre_replays: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    pub input: String,
    pub model: String,
    pub trials: usize,
    pub samples: usize,
    /// Measurement noise estimated from the data, N.
    pub noise_sigma: f64,
    pub lag_median_s: Option<f64>,
    pub localisation: Localisation,
    pub ranking: Vec<CandidateScore>,
    pub heldout: Heldout,
    pub verdict: Verdict,
    pub elapsed_s: f64,
    /// Where `elapsed_s` went (a diagnosis from replays: absent when the trials came prepared).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stages: Option<StageTimes>,
    pub trial_reports: Vec<TrialReport>,
    /// Re-simulations left out as diverged (`trial: variant`); the effects needing them
    /// interpolate through their other knots.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub diverged_replays: Vec<String>,
    /// The re-simulations at fitted parameters, the second stage ([`centres`]): e.g.
    /// `tilt at tilt_x 4.19 deg, tilt_y 2.05 deg (15 of 15 trials)`. Empty when neither a
    /// tilt of at least [`centres::MIN_CENTRE_DEG`] nor a support of at least
    /// [`centres::MIN_CENTRE_SUPPORT`] was fitted, or the option was off.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub centres: Vec<String>,
    /// Device-rendered vs model force, when a session recording was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rendering_gap: Option<session::RenderingGap>,
}

/// Load an experiment folder and diagnose it against the physics model. A session
/// recording (an `.mcap` file, or a folder without `experiment.toml` holding one) is
/// diagnosed with [`diagnose_session`].
pub fn diagnose_dir(dir: &Path, opts: &Options) -> Result<Report, GapError> {
    opts.check()?;
    if let Some(mcap) = session::session_file(dir)? {
        return diagnose_session(&mcap, opts);
    }
    let data = data_dir();
    let exp = load_experiment(dir, &data)?;
    let model = opts.replay_model(sim_model::SimForceModel::for_experiment(&exp, &data)?)?;
    diagnose(&exp, &model, opts)
}

pub use sim_model::SimForceModel;
pub mod sim_model;

/// Diagnose an arthrosim session recording: its probings are the trials, its scene the
/// model; with device ticks, the report also carries the rendering gap.
pub fn diagnose_session(mcap: &Path, opts: &Options) -> Result<Report, GapError> {
    opts.check()?;
    let rec = session::read_session(mcap)?;
    diagnose_recording(&rec, opts)
}

/// [`diagnose_session`] on a recording already read.
pub fn diagnose_recording(
    rec: &session::SessionRecording,
    opts: &Options,
) -> Result<Report, GapError> {
    let exp = session::experiment_from_session(rec)?;
    // the rendering gap is cheap: computed first so its input errors come before the replays
    let rendering = if rec.ticks.is_empty() {
        None
    } else {
        Some(session::rendering_gap(rec)?)
    };
    let model = opts.replay_model(SimForceModel::for_session(rec, &data_dir())?)?;
    let mut report = diagnose(&exp, &model, opts)?;
    report.rendering_gap = rendering;
    Ok(report)
}

/// The rendering gap of a haptic session recording (`--session FILE.mcap` beside an
/// experiment).
pub fn session_rendering_gap(mcap: &Path) -> Result<session::RenderingGap, GapError> {
    let file = session::session_file(mcap)?.ok_or_else(|| GapError::Input {
        file: mcap.to_path_buf(),
        msg: "not an MCAP session recording (expected an .mcap file)".into(),
    })?;
    session::rendering_gap(&session::read_session(&file)?)
}

/// Add the rendering gap of a session recording to a report.
pub fn attach_session(report: &mut Report, mcap: &Path) -> Result<(), GapError> {
    report.rendering_gap = Some(session_rendering_gap(mcap)?);
    Ok(())
}

/// Diagnose an experiment with a given force model.
pub fn diagnose(
    exp: &Experiment,
    model: &dyn ForceModel,
    opts: &Options,
) -> Result<Report, GapError> {
    opts.check()?;
    let start = std::time::Instant::now();
    let effects = candidate_effects(exp, model, opts);
    let (data, mut stages) = prepare_dataset_timed(exp, model, &effects, opts)?;
    let mut report = diagnose_data(
        exp.dir.display().to_string(),
        model.describe(),
        &data,
        &effects,
        opts,
        start,
    )?;
    stages.fits_s = (report.elapsed_s - stages.replays_s - stages.centres_s).max(0.0);
    report.stages = Some(stages);
    Ok(report)
}

/// Every replay the diagnosis of `exp` with `effects` needs: the baseline, each effect's
/// re-simulations and the nuisance's knot ([`dataset::build`]), then the second stage
/// ([`centres::add_centres`]) when `opts.centres`.
pub fn prepare_dataset(
    exp: &Experiment,
    model: &dyn ForceModel,
    effects: &[Effect],
    opts: &Options,
) -> Result<Vec<dataset::TrialData>, GapError> {
    prepare_dataset_timed(exp, model, effects, opts).map(|(data, _)| data)
}

/// [`prepare_dataset`] with the wall time of its two stages (`fits_s` left 0).
pub fn prepare_dataset_timed(
    exp: &Experiment,
    model: &dyn ForceModel,
    effects: &[Effect],
    opts: &Options,
) -> Result<(Vec<dataset::TrialData>, StageTimes), GapError> {
    let model = model::Counting::new(model);
    let t0 = std::time::Instant::now();
    let mut data = dataset::build(exp, &model, effects, &opts.build_options())?;
    let replays_s = t0.elapsed().as_secs_f64();
    let replays = model.made();
    if opts.centres {
        centres::add_centres(&mut data, &model, opts.nuisance_band())?;
    }
    let centres_s = t0.elapsed().as_secs_f64() - replays_s;
    Ok((
        data,
        StageTimes {
            replays_s,
            centres_s,
            fits_s: 0.0,
            replays,
            centre_replays: model.made() - replays,
        },
    ))
}

/// The candidate effects [`diagnose`] considers for `exp` with `model`.
pub fn candidate_effects(exp: &Experiment, model: &dyn ForceModel, opts: &Options) -> Vec<Effect> {
    opts.effects
        .iter()
        .copied()
        .filter(|&e| {
            fit::applicable(e, exp.quasi_static) && (e != Effect::Mesh || model.has_refinement())
        })
        .collect()
}

fn baseline_study_error(data: &[TrialData]) -> f64 {
    data.iter()
        .map(|d| {
            let (m, p) = fit::study_metric(d, &d.base_at_t);
            (p - m).abs()
        })
        .sum::<f64>()
        / data.len().max(1) as f64
}

/// Diagnosis on prepared trials (replays done).
pub fn diagnose_data(
    input: String,
    model: String,
    data: &[TrialData],
    effects: &[Effect],
    opts: &Options,
    start: std::time::Instant,
) -> Result<Report, GapError> {
    if data.is_empty() {
        return Err(GapError::Other("no trials".into()));
    }
    let samples: usize = data.iter().map(|d| d.t.len()).sum();
    // noise: robust per trial and axis, pooled by median
    let mut sig: Vec<f64> = data
        .iter()
        .map(|d| {
            let s2: f64 = (0..3)
                .map(|k| noise_sigma(&d.f.iter().map(|f| f[k]).collect::<Vec<_>>()).powi(2))
                .sum();
            (s2 / 3.0).sqrt()
        })
        .collect();
    let noise = signal::median(&mut sig);
    let lags: Vec<Option<f64>> = data
        .iter()
        .map(|d| {
            let m: Vec<f64> = d.f.iter().map(|f| dot(*f, d.normal)).collect();
            let b: Vec<f64> = d.base_at_t.iter().map(|f| dot(*f, d.normal)).collect();
            lag_by_xcorr(&d.t, &b, &d.t, &m, 0.5, 0.005)
                .filter(|(_, c)| *c > 0.5)
                .map(|(l, _)| l)
        })
        .collect();
    let mut lv: Vec<f64> = lags.iter().flatten().copied().collect();
    let lag_median = (!lv.is_empty()).then(|| signal::median(&mut lv));
    let localisation = localise(data);
    let (scheme, folds) = make_folds(data);
    let base = Baseline::of(data);
    let (r0, study0) = (base.rmse, baseline_study_error(data));
    let nuisance = opts.nuisance_band();
    // the floor every effect must beat: the baseline with only the nuisance fitted
    let floor = score_candidate(&Candidate(Vec::new()), data, &folds, &base, &[], nuisance);

    let usable: Vec<Effect> = effects
        .iter()
        .copied()
        .filter(|&e| data.iter().all(|d| d.has_resims(e)))
        .collect();
    let bar = dataset::progress_bar(opts.progress, usable.len() as u64, "fitting");
    let mut singles: Vec<CandidateScore> = usable
        .par_iter()
        .map(|&e| {
            let s = score_candidate(&Candidate::single(e), data, &folds, &base, &[], nuisance);
            if let Some(b) = &bar {
                b.inc(1);
            }
            s
        })
        .collect();
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    singles
        .iter_mut()
        .for_each(|c| against_floor(c, &floor, data));
    singles.sort_by(|a, b| a.score.total_cmp(&b.score));
    let mut ranking = singles.clone();
    if opts.pairs {
        // every pair: a second effect can be invisible alone while the first dominates the
        // residual, and two can hide each other (a tilt's extra force under a relaxation's
        // loss: neither alone beat the baseline)
        let top: Vec<&CandidateScore> = singles.iter().collect();
        let mut pairs: Vec<(Candidate, Vec<f64>)> = Vec::new();
        for t in &top {
            let a = Effect::parse(&t.effect).unwrap();
            for o in &singles {
                let b = Effect::parse(&o.effect).unwrap();
                if !fit::pair_allowed(a, b) {
                    continue;
                }
                let c = Candidate::pair(a, b);
                if pairs.iter().any(|(p, _)| *p == c) {
                    continue;
                }
                let theta_of = |e: Effect| {
                    if e == a {
                        t.theta.clone()
                    } else {
                        o.theta.clone()
                    }
                };
                let init: Vec<f64> = c.0.iter().flat_map(|&e| theta_of(e)).collect();
                pairs.push((c, init));
            }
        }
        let bar = dataset::progress_bar(opts.progress, pairs.len() as u64, "pairs");
        let scored: Vec<CandidateScore> = pairs
            .par_iter()
            .map(|(c, init)| {
                let s =
                    score_candidate(c, data, &folds, &base, std::slice::from_ref(init), nuisance);
                if let Some(b) = &bar {
                    b.inc(1);
                }
                s
            })
            .collect();
        if let Some(b) = bar {
            b.finish_and_clear();
        }
        ranking.extend(scored.into_iter().map(|mut c| {
            against_floor(&mut c, &floor, data);
            c
        }));
    }
    ranking.sort_by(|a, b| a.score.total_cmp(&b.score));
    beside_gains(&mut ranking, data);

    let measured_level = level::data_level(data);
    // two effects need several independent trials to be told apart (not one table)
    let mut verdict = decide(
        &singles,
        &ranking,
        &floor,
        &Weighing {
            noise,
            min_shrink: opts.min_shrink,
            band: nuisance.for_data(data),
            pairs_allowed: data.len() >= 3,
            paired: data.len() >= separability::MIN_TRIALS,
            measured_rms: measured_rms(data),
            level: measured_level,
        },
    );
    if let Some(set) = separability::indistinguishable(&verdict.effect, &ranking, data) {
        let rivals: Vec<String> = set.candidates[1..]
            .iter()
            .zip(set.gain.iter().zip(&set.gain_se))
            .map(|(c, (g, se))| {
                if *se > 0.0 {
                    format!(
                        "{c} (paired gain over it {:.1} SE: {g:+.3} ± {se:.3})",
                        g / se
                    )
                } else {
                    format!("{c} (their held-out predictions differ in fewer than two trials)")
                }
            })
            .collect();
        verdict.reason.push_str(&format!(
            "; on held-out trials it cannot be told apart from {} ({})",
            rivals.join(", "),
            set.label()
        ));
        verdict.indistinguishable = set.candidates;
        verdict.separate_by = set.separate_by;
    }
    ranking
        .iter_mut()
        .for_each(CandidateScore::report_modulus_as_level);
    let winner = ranking.iter().find(|c| c.effect == verdict.effect);
    if let Some(w) = winner {
        verdict.params = w.params.clone();
    }
    let fitted_with = winner.unwrap_or(&floor);
    verdict.nuisance_scale = fitted_with.nuisance_scale;
    verdict.contact_compliance = fitted_with.contact_compliance;
    verdict.material_weight = fitted_with.material_weight;
    verdict.level = fitted_with.level;
    weigh_residual(&mut verdict, fitted_with.heldout_rmse, data);
    let heldout = Heldout {
        scheme,
        baseline_rmse: r0,
        winner_rmse: winner.map(|w| w.heldout_rmse).unwrap_or(r0),
        shrink: winner.map(|w| w.heldout_shrink).unwrap_or(0.0),
        baseline_study_error: study0,
        winner_study_error: winner.map(|w| w.heldout_study_error).unwrap_or(study0),
        nuisance_scale: floor.nuisance_scale,
        contact_compliance: floor.contact_compliance,
        material_weight: floor.material_weight,
        level: floor.level,
        level_band: nuisance.stiffness_fitted().then(|| nuisance.level_band()),
        measured_level: measured_level.map(|l| l.ratio),
        measured_level_se: measured_level.map(|l| l.se),
        nuisance_rmse: floor.heldout_rmse,
        shrink_over_nuisance: winner
            .map(|w| shrink(w.heldout_rmse, floor.heldout_rmse))
            .unwrap_or(0.0),
    };
    let trial_reports = data
        .iter()
        .enumerate()
        .map(|(i, d)| {
            let after_pred = winner
                .map(|w| w.heldout_pred[i].clone())
                .unwrap_or_else(|| d.base_at_t.clone());
            TrialReport {
                name: d.name.clone(),
                region: d.region,
                samples: d.t.len(),
                lag_s: lags[i],
                before: trial_metrics(&d.f, &d.base_at_t, d.normal, &d.depth, &d.phase),
                after: trial_metrics(&d.f, &after_pred, d.normal, &d.depth, &d.phase),
                series: Series {
                    t: d.t.clone(),
                    measured: d.f.clone(),
                    baseline: d.base_at_t.clone(),
                    winner: after_pred,
                    depth_mm: d.depth.clone(),
                },
            }
        })
        .collect();
    Ok(Report {
        input,
        model,
        trials: data.len(),
        samples,
        noise_sigma: noise,
        lag_median_s: lag_median,
        localisation,
        ranking,
        heldout,
        verdict,
        elapsed_s: start.elapsed().as_secs_f64(),
        stages: None,
        trial_reports,
        diverged_replays: data.iter().flat_map(|d| d.diverged_labels()).collect(),
        centres: centres::describe(data),
        rendering_gap: None,
    })
}

/// The nuisances fitted to the floor, as the verdict's reason names them.
fn nuisance_note(floor: &CandidateScore) -> String {
    // a weight the solve left at 1e-17 is none: it printed "a neo-Hookean weight of 0.00"
    let contact = floor.contact_compliance.filter(|&c| c >= 0.05e-6);
    let material = floor.material_weight.filter(|&m| m >= 0.005);
    let mut parts = Vec::new();
    if let Some(s) = floor.nuisance_scale {
        parts.push(format!("a stiffness nuisance ×{s:.3}"));
    }
    if let Some(c) = contact {
        parts.push(format!("a contact compliance of {:.1} µm/N", 1e6 * c));
    }
    if let Some(m) = material {
        parts.push(format!("a neo-Hookean weight of {m:.2}"));
    }
    // the level differs from the scale only where a knot's term is taken
    if let Some(l) = floor
        .level
        .filter(|_| contact.is_some() || material.is_some())
    {
        parts.push(format!("the response at ×{l:.3} of the replay's level"));
    }
    if parts.is_empty() {
        String::new()
    } else {
        format!(" after {}", parts.join(" and "))
    }
}

/// Sets every `modulus`+X pair's paired held-out gain over X alone
/// ([`CandidateScore::stiffness_gain_z`]), and every `sensor`+X pair's
/// ([`CandidateScore::sensor_gain_z`]).
fn beside_gains(ranking: &mut [CandidateScore], data: &[TrialData]) {
    for i in 0..ranking.len() {
        for partner in [Effect::Modulus, Effect::Sensor] {
            let Some(other) = other_than(&ranking[i].effect, partner.name()) else {
                continue;
            };
            let Some(single) = ranking.iter().find(|c| c.effect == other) else {
                continue;
            };
            let z =
                separability::gain_over(single, &ranking[i], data).map(|(m, se)| z_score(m, se));
            match partner {
                Effect::Sensor => ranking[i].sensor_gain_z = z,
                _ => ranking[i].stiffness_gain_z = z,
            }
        }
    }
}

/// The pair `candidate`'s effect other than `partner`, if it is a pair with `partner`.
fn other_than<'a>(candidate: &'a str, partner: &str) -> Option<&'a str> {
    let (a, b) = candidate.split_once('+')?;
    if b.contains('+') {
        return None;
    }
    match (a == partner, b == partner) {
        (true, false) => Some(b),
        (false, true) => Some(a),
        _ => None,
    }
}

/// Sets `c`'s standing against the nuisance floor: its held-out shrink and the significance
/// of its paired per-trial gain ([`separability::gain_over`]).
fn against_floor(c: &mut CandidateScore, floor: &CandidateScore, data: &[TrialData]) {
    c.floor_shrink = shrink(c.heldout_weighted_rmse, floor.heldout_weighted_rmse)
        .max(shrink(c.heldout_rmse, floor.heldout_rmse));
    c.floor_gain_z = separability::gain_over(floor, c, data)
        .map(|(mean, se)| z_score(mean, se))
        .unwrap_or(0.0);
}

/// Evidence (in −2 log-likelihood, penalised) an effect must add over the nuisance floor,
/// in-sample (BIC) and held-out (score): "very strong" on the usual BIC scale.
const STRONG_EVIDENCE: f64 = 10.0;

/// What a candidate with one more effect or parameter must remove of the simpler one's
/// held-out residual (phase-weighted or plain) to be named instead of it: a pair over its best
/// single, `hardening` over `modulus`.
const RICHER_GAIN: f64 = 0.2;

/// Largest |z| reported: a gain identical on every trial has no scatter (se 0).
const MAX_Z: f64 = 1.0e6;

fn z_score(mean: f64, se: f64) -> f64 {
    if se > 0.0 {
        (mean / se).clamp(-MAX_Z, MAX_Z)
    } else if mean > 0.0 {
        MAX_Z
    } else if mean < 0.0 {
        -MAX_Z
    } else {
        0.0
    }
}

/// What a verdict weighs the candidates with, beside their scores ([`decide`]).
#[derive(Debug, Clone, Copy)]
struct Weighing {
    /// The sensor noise, N: a floor within 15% of it leaves nothing to explain.
    noise: f64,
    /// Held-out shrink over the floor an effect must reach ([`Options::min_shrink`]).
    min_shrink: f64,
    /// The nuisances fitted: a modulus inside their stiffness band is no effect
    /// ([`strength::negligible`]).
    band: Nuisance,
    /// Enough trials to weigh pairs.
    pairs_allowed: bool,
    /// Enough trials for the per-trial paired gain.
    paired: bool,
    /// The measured force's RMS over every sample and axis, N ([`measured_rms`]): a model
    /// that leaves as much held out does no better than predicting no force, and names nothing.
    measured_rms: f64,
    /// The measured response's level against the replay's, trial by trial
    /// ([`level::data_level`]; None with too few trials).
    level: Option<level::DataLevel>,
}

/// The verdict: the best-ranked candidate if it beats the nuisance floor (the baseline with
/// the stiffness nuisance fitted, [`fit::Nuisance`]) clearly and significantly; a pair only
/// when the best single leaves a residual well above noise and the pair removes much of it
/// (the best pair by held-out score that does). Candidates are weighed at strengths worth
/// naming only ([`strength`]).
///
/// An effect is identified when, against the floor, (a) its held-out shrink is at least
/// `min_shrink`, phase-weighted or plain; (b) its penalised fit on all trials is better by
/// [`STRONG_EVIDENCE`] in BIC; (c) its held-out score (the phase-variance likelihood of the
/// held-out residuals on effective values, with the parameter penalty: a held-out likelihood
/// ratio) is better by [`STRONG_EVIDENCE`] too; and (d) with `paired` (enough trials), its
/// per-trial held-out gain ([`separability::gain_over`]) holds across the trials, not on a
/// few against the rest ([`holds_trial_by_trial`]); and (e) every
/// effect it names has a fitted strength worth naming ([`strength::negligible`]: a modulus
/// scale outside the nuisance's band, a Prony g1 of 5% or more, …), so a pair is not named
/// for a second effect the nuisances and the model error leave room for; and (f) it leaves
/// less held out than the measured force's RMS (a model no better than no force explains
/// nothing, whatever it gains on a floor that does worse). Without the
/// floor a persistent stiffness offset, which every model has against a real specimen, was
/// read as `support` or `modulus`.
///
/// (g) Where nothing is identified, a `modulus` is named when the measured response's level
/// lies beyond the nuisances' level band by [`separability::SEPARATION_SE`] of its
/// between-trial error ([`level::DataLevel::beyond`]), its own fitted level lies beyond it on
/// that side, and it passes (b), (c), (e) and (f) with any positive gain for (a) and (d): the
/// floor stops at the band's bound, so what is left for the modulus to remove is the level
/// beyond it, small beside a model error that differs from trial to trial, while every
/// trial reads the level. The independent P2 code's modulus ×1.7 case read `none` with the
/// modulus 36% over the floor at 1.8 SE; its measured level is ×1.77 ± 0.11, 2.9 SE beyond
/// ×1.44, and the modulus fits ×1.71 (README, "A level beyond the nuisances' reach").
///
/// (h) Beside an identified single X, `X+sensor` is named on a lower bar than a pair's
/// [`RICHER_GAIN`]: a sensor only delays and smooths, so what it removes is the onsets' share
/// of a residual the model error sets (see [`sensor_beside`]).
///
/// (i) Beside an identified single that changes no stiffness, `modulus`+single is named where
/// the trials' measured level lies beyond the level band and the single's nuisances took it
/// there (see [`level_beside`]).
///
/// The held-out likelihood ratio (c) is the significance over all samples; (d) guards it
/// against a gain carried by the largest trials' model error.
///
/// Shrinks and gains are weighed on the phase-weighted RMSE (one residual variance per phase,
/// see [`fit::PhaseSse`]): a sensor bias of tenths of a newton is invisible in the plain RMSE
/// under tens of newtons of contact force and a coarse mesh's model error, but is the whole
/// residual before the tip touches, where the model is exact.
fn decide(
    singles: &[CandidateScore],
    ranking: &[CandidateScore],
    floor: &CandidateScore,
    weighing: &Weighing,
) -> Verdict {
    let Weighing {
        noise,
        min_shrink,
        band,
        pairs_allowed,
        paired,
        measured_rms,
        level,
    } = *weighing;
    let none = |reason: String| Verdict {
        effect: "none".into(),
        heldout_shrink: 0.0,
        params: vec![],
        ..named(floor, reason)
    };
    let nuisance_note = nuisance_note(floor);
    let r0 = floor.heldout_rmse;
    if r0 <= 1.15 * noise {
        return none(format!(
            "held-out residual {r0:.4} N{nuisance_note} is within noise ({noise:.4} N)"
        ));
    }
    // the best single at a strength worth naming: a hardening fitted at a negligible rate is
    // the modulus below it, not a reason to name nothing
    let best = match singles
        .iter()
        .find(|c| !strength::any_negligible(&c.effect, &c.params, band, c.level))
        .or(singles.first())
    {
        Some(b) => b,
        None => return none("no candidate could be assessed".into()),
    };
    // (e): every effect it names at a strength worth naming ([`strength`]); (f): it leaves
    // less than the measured force itself held out. Where the replay does not reproduce the
    // experiment (a tilt whose presses miss a region and press others 100 N deep), an effect
    // that only lowers every force (a modulus ×0.02, a Prony g1 of 0.9 relaxing in 50 ms)
    // beat the floor and was named while predicting no better than no force at all. A
    // modulus at its range's end is not refused as such: a table pressed on a scene 50×
    // too stiff reads `modulus` ×0.02 and leaves 0.57 N of 2.7 N, and calibration takes it
    // from there ("A probe that crushes the tissue to its far face").
    let identified = |c: &CandidateScore| {
        c.heldout_rmse < measured_rms
            && c.floor_shrink >= min_shrink
            && c.bic - floor.bic <= -STRONG_EVIDENCE
            && c.score - floor.score <= -STRONG_EVIDENCE
            && (!paired || holds_trial_by_trial(c))
            && !strength::any_negligible(&c.effect, &c.params, band, c.level)
    };
    // Rule (g)'s modulus: the trials' level lies beyond the level band and `c`, a modulus,
    // reaches it, gaining on the floor in every other respect as an identified effect does.
    let beyond = level
        .filter(|_| band.stiffness_fitted())
        .and_then(|l| l.beyond(band).map(|side| (l, side)));
    let reaches_the_level = |c: &CandidateScore| {
        beyond.is_some_and(|(l, side)| {
            c.effect == Effect::Modulus.name()
                && c.level.is_some_and(|v| side.holds(v, band))
                && c.heldout_rmse < measured_rms
                && c.floor_shrink > 0.0
                && (c.floor_gain_z > 0.0 || l.beyond_se(band) >= LEVEL_ALONE_SE)
                && c.bic - floor.bic <= -STRONG_EVIDENCE
                && c.score - floor.score <= -STRONG_EVIDENCE
                && !strength::any_negligible(&c.effect, &c.params, band, c.level)
        })
    };
    let evidence = |c: &CandidateScore| {
        format!(
            "{:.1}% against the floor{nuisance_note}, held-out score {:+.1}, paired gain {:.1} SE, \
             ΔBIC {:.1}",
            100.0 * c.floor_shrink,
            c.score - floor.score,
            c.floor_gain_z,
            c.bic - floor.bic
        )
    };
    // Pairs best first by held-out score, each at strengths worth naming. A pair is named
    // when it passes; the best-scored one may fail where the next passes: on the refined
    // truth a friction+device case's best pair was hardening+device, 12% over `device` (the
    // truth's other discretisation taken up as a stiffening), and friction+device, 22% over
    // it and second in score, was never weighed.
    let pairs_by_score = || {
        let mut pairs: Vec<&CandidateScore> = ranking
            .iter()
            .filter(|c| {
                c.effect.contains('+')
                    && !strength::any_negligible(&c.effect, &c.params, band, c.level)
            })
            .collect();
        pairs.sort_by(|a, b| a.score.total_cmp(&b.score));
        pairs
    };
    // what a pair removes of the best single's residual, phase-weighted or plain
    let gain_over_best = |pair: &CandidateScore| gain_over(pair, best);
    if !identified(best) {
        // two effects that hide each other: the best pair, identified on its own and well
        // ahead of every single
        let passing = pairs_by_score().into_iter().find(|pair| {
            identified(pair) && gain_over_best(pair) > RICHER_GAIN && pair.score < best.score
        });
        if let Some(pair) = passing.filter(|_| pairs_allowed) {
            return named(
                pair,
                format!(
                    "no single effect shrinks the held-out RMSE clearly (best {}: {}); \
                     the pair {} does: {:.4} → {:.4} N ({})",
                    best.effect,
                    evidence(best),
                    pair.effect,
                    r0,
                    pair.heldout_rmse,
                    evidence(pair)
                ),
            );
        }
        // (g) a response level beyond the nuisances' reach, read trial by trial: a modulus
        // there needs only to gain on the floor, in every other respect as identified; trial
        // by trial too, unless the level lies [`LEVEL_ALONE_SE`] beyond the band. The
        // grade-2 case of the P2 code (×0.59) measures ×0.580 ± 0.065, 1.8 SE under ×0.696:
        // the trials disagree too much for it, and it still reads `none`.
        // Only a modulus: the other candidates' levels are the nuisances', inside the band.
        let reaching = beyond.and_then(|(l, _)| {
            singles
                .iter()
                .find(|c| reaches_the_level(c))
                .map(|c| (l, c))
        });
        if let Some((l, c)) = reaching {
            let (lo, hi) = band.level_band();
            return named(
                c,
                format!(
                    "the measured response lies at ×{:.3} ± {:.3} of the replay's over {} \
                     trials{}, {:.1} SE beyond what the nuisances may take (×{:.3}–×{:.3}), and \
                     {} reaches it (×{:.3}): {:.4} → {:.4} N ({}){}",
                    l.ratio,
                    l.se,
                    l.trials,
                    l.error_basis(),
                    l.beyond_se(band),
                    lo,
                    hi,
                    c.effect,
                    c.level.unwrap_or(f64::NAN),
                    r0,
                    c.heldout_rmse,
                    evidence(c),
                    if std::ptr::eq(c, best) {
                        String::new()
                    } else {
                        format!(
                            "; the best-scored single, {}: {}",
                            best.effect,
                            evidence(best)
                        )
                    }
                ),
            );
        }
        return none(format!(
            "best candidate {} does not beat the nuisance floor {r0:.4} N: {}{}",
            best.effect,
            evidence(best),
            level
                .map(|l| format!(
                    "; the measured response lies at ×{:.3} ± {:.3} of the replay's{}",
                    l.ratio,
                    l.se,
                    l.error_basis()
                ))
                .unwrap_or_default()
        ));
    }
    let mut win = best;
    let mut reason = format!(
        "{} shrinks held-out RMSE {:.4} → {:.4} N ({})",
        best.effect,
        r0,
        best.heldout_rmse,
        evidence(best)
    );
    if pairs_allowed && best.heldout_rmse > 1.3 * noise {
        let passing = pairs_by_score()
            .into_iter()
            .find(|pair| gain_over_best(pair) > RICHER_GAIN && pair.score < best.score);
        if let Some(pair) = passing {
            let gain = gain_over_best(pair);
            reason = format!(
                "{} leaves {:.4} N phase-weighted ({:.4} N plain, noise {:.4} N); the pair {} \
                 removes {:.0}% more ({:.4} N phase-weighted, {:.4} N plain)",
                best.effect,
                best.heldout_weighted_rmse,
                best.heldout_rmse,
                noise,
                pair.effect,
                100.0 * gain,
                pair.heldout_weighted_rmse,
                pair.heldout_rmse
            );
            win = pair;
        }
    }
    if std::ptr::eq(win, best) && pairs_allowed && paired {
        if let Some(pair) = stiffness_beyond_the_band(best, ranking, band, min_shrink) {
            reason = format!(
                "{reason}; its stiffness nuisance sits at the band's bound ×{:.3}, and {} \
                 removes {:.0}% more ({:.4} → {:.4} N plain), {:.1} SE trial by trial, with a \
                 modulus ×{:.3} in level beyond the band",
                best.nuisance_scale.unwrap_or(1.0),
                pair.effect,
                100.0 * gain_over(pair, best),
                best.heldout_rmse,
                pair.heldout_rmse,
                pair.stiffness_gain_z.unwrap_or(0.0),
                pair.level.unwrap_or(f64::NAN)
            );
            win = pair;
        }
    }
    // (i) a stiffness the trials' level reads beyond the band, beside a single without one
    if std::ptr::eq(win, best) && pairs_allowed {
        if let Some((pair, l)) = level_beside(best, ranking, band, level) {
            reason = format!(
                "{reason}; the measured response lies at ×{:.3} ± {:.3} of the replay's{}, {:.1} \
                 SE beyond what the nuisances may take, where {} stands at ×{:.3} on them, and \
                 {} reaches it (×{:.3}, held out {:.4} N against {:.4} N)",
                l.ratio,
                l.se,
                l.error_basis(),
                l.beyond_se(band),
                best.effect,
                best.level.unwrap_or(f64::NAN),
                pair.effect,
                pair.level.unwrap_or(f64::NAN),
                pair.heldout_rmse,
                best.heldout_rmse
            );
            win = pair;
        }
    }
    // (h) a sensor's lag beside the single
    if std::ptr::eq(win, best) && pairs_allowed && paired {
        if let Some(pair) = sensor_beside(best, ranking, band, min_shrink) {
            reason = format!(
                "{reason}; {} removes {:.0}% more ({:.4} → {:.4} N phase-weighted), {:.1} SE \
                 trial by trial: a sensor's lag beside it",
                pair.effect,
                100.0 * gain_over(pair, best),
                best.heldout_weighted_rmse,
                pair.heldout_weighted_rmse,
                pair.sensor_gain_z.unwrap_or(0.0),
            );
            win = pair;
        }
    }
    // `hardening` is `modulus` with one more parameter (its stiffening rate; at 0 they are
    // the same model), and the material nuisance's softer law at depth gives the rate room
    // to move fold by fold: a modulus case read `hardening` at 0.006/mm (11% over `modulus`
    // phase-weighted, 4% plain). Like a pair over its single, it is named only when it
    // removes [`RICHER_GAIN`] of the simpler model's residual. A modulus that reaches a level
    // beyond the band (rule (g)) is as identified here: on the independent code's linear
    // elements a modulus ×1.42 and ×1.7 read `hardening` at 8% and 3% over `modulus`, whose
    // paired gain on the floor (at the band's ×1.25, nearer on the light presses) was below
    // zero while the trials measured ×1.52 ± 0.06 and ×1.80 ± 0.07 (README, "A modulus beyond
    // the band is not a hardening").
    if let Some(simpler) =
        nested_simpler(win, ranking).filter(|c| identified(c) || reaches_the_level(c))
    {
        let gain = gain_over(win, simpler);
        if gain <= RICHER_GAIN {
            reason = format!(
                "{reason}; {} removes only {:.0}% more than {} ({:.4} → {:.4} N phase-weighted), \
                 under the {:.0}% one more parameter needs: {}",
                win.effect,
                100.0 * gain.max(0.0),
                simpler.effect,
                simpler.heldout_weighted_rmse,
                win.heldout_weighted_rmse,
                100.0 * RICHER_GAIN,
                simpler.effect
            );
            win = simpler;
        }
    }
    named(win, reason)
}

/// How many of its errors the trials' level must lie beyond the level band for rule (g) to
/// name a modulus that reaches it without its held-out gain holding trial by trial. On the
/// independent code's linear elements, a modulus ×1.42 (offset ×0.95) measured ×1.424 ± 0.040,
/// 6.8 SE over the band; `modulus` fitted ×1.421 in level and held out 14.7% less than the
/// floor, but its paired gain was −1.0 SE (the floor, at the band's ×1.25, is nearer on the
/// light presses), and the case read `none`. The no-effect cases stand within 1.4 SE of the
/// band (README, "A level far beyond the band").
pub const LEVEL_ALONE_SE: f64 = 4.0;

/// The verdict naming `c` for `reason`; the nuisances, the level and the residual fraction are
/// set after [`decide`], from the winner's fit.
fn named(c: &CandidateScore, reason: String) -> Verdict {
    Verdict {
        effect: c.effect.clone(),
        heldout_shrink: c.heldout_shrink,
        params: c.params.clone(),
        reason,
        indistinguishable: Vec::new(),
        separate_by: Vec::new(),
        nuisance_scale: None,
        contact_compliance: None,
        material_weight: None,
        level: None,
        residual_fraction: 0.0,
    }
}

/// Rule (d) of [`decide`]: `c`'s paired held-out gain over the floor holds trial by trial.
///
/// Where every effect of `c` changes every probing ([`Effect::acts_on_every_probing`]: a
/// stiffness, a support, a tilt, …), every trial can show it, and the gain must be
/// significant over them: [`separability::SEPARATION_SE`] standard errors, the test that tells
/// two candidates apart. The refined truth's no-effect case at CI size read `modulus` on a
/// paired gain of 0.3 SE (12% over the floor, better than the band's ×1.25 on some trials and
/// worse on others): the other discretisation's shape, not an effect of the specimen. On the
/// protocol's fifteen trials every verdict of this kind that a proxy set or the refined cycle
/// names right stands at 2.5 SE or more (104 of nine sets' 158 cases, 2026-11-30).
///
/// Friction acts only where the probe slides (six of the protocol's fifteen probings) and a
/// mesh effect only near some sites; their gain has those few trials to show on, and must
/// only be positive on average: the refined cycle's friction case, named right, stands at
/// 1.2 SE.
fn holds_trial_by_trial(c: &CandidateScore) -> bool {
    let every_probing = Effect::of_candidate(&c.effect).all(Effect::acts_on_every_probing);
    if every_probing {
        c.floor_gain_z >= separability::SEPARATION_SE
    } else {
        c.floor_gain_z > 0.0
    }
}

/// A stiffness beside `best` that the nuisance cannot take: `best`'s stiffness nuisance sits
/// at a bound of its band, or its response level at a bound of the level's
/// ([`fit::LEVEL_MAX`]), and the pair `modulus`+`best` (a) removes at least `min_shrink` of
/// `best`'s held-out residual, the bar an effect meets against the floor, not a pair's
/// [`RICHER_GAIN`], (b) does so trial by trial by [`separability::SEPARATION_SE`]
/// ([`CandidateScore::stiffness_gain_z`]), (c) scores better, and (d) fits a modulus
/// outside the band ([`strength`]).
///
/// Why a pair's 20% is too much here: the nuisance is fitted with `best` and takes the
/// modulus up to the bound, so what is left for the pair to remove is only the part of the
/// stiffness beyond it. A coarse-mesh proxy case of modulus ×1.62 with friction μ 0.24 read
/// `friction` with the nuisance at ×1.25: `modulus+friction` removed 9.7% more at 2.7 SE,
/// with the modulus at ×1.51. On the refined truth, whose shape reads as ×1.6 behind the
/// contact nuisance in every case, a device case's `modulus+device` removed 10.0% at 1.99 SE
/// and a viscoelastic case's pair 6.9% at 2.1 SE: neither is named (README, "A stiffness
/// beyond the band").
fn stiffness_beyond_the_band<'a>(
    best: &'a CandidateScore,
    ranking: &'a [CandidateScore],
    band: Nuisance,
    min_shrink: f64,
) -> Option<&'a CandidateScore> {
    let at_bound = best
        .nuisance_scale
        .is_some_and(|s| band.lo < band.hi && (s <= band.lo * 1.001 || s >= band.hi * 0.999))
        || best.nuisance_scale.is_some()
            && best
                .level
                .is_some_and(|l| l <= 1.001 * band.level_lo || l >= 0.999 * band.level_hi);
    if !at_bound {
        return None;
    }
    pairs_beside(best, ranking, Effect::Modulus, band, min_shrink, |pair| {
        pair.stiffness_gain_z
    })
    .find(|pair| pair.score < best.score)
}

/// Rule (i) of [`decide`]: `modulus`+`best` where the trials' measured level lies beyond the
/// nuisances' level band by [`separability::SEPARATION_SE`] of its error
/// ([`level::DataLevel::beyond`]) and `best`, an effect that changes no stiffness, stands on
/// nuisances that took the level beyond the band on that side: the pair's own level lies
/// beyond it on the same side, its modulus is worth naming, and it holds out no worse than
/// `best` by more than [`LEVEL_PAIR_SLACK`].
///
/// Why the level and not a held-out gain: with `best` the stiffness nuisance takes the
/// stiffness up to its bound (×1.25), so what is left for the modulus to remove held out is
/// the small part beyond it, under a model error that differs from trial to trial, while
/// every trial reads the level (rule (g), for the same reason where nothing is identified).
/// The independent code's linear elements, modulus ×1.42 with a sensor's 25 ms delay and
/// 25 ms low-pass (at an offset ×0.90), read `sensor`: its level stood at ×1.250 on the
/// nuisances, the trials measured ×1.359 ± 0.040 (5.2 SE over ×1.15), and `modulus+sensor`
/// fitted ×1.340 in level, a modulus ×1.45, held out 0.4% worse (README, "A stiffness the
/// level reads beside another effect").
fn level_beside<'a>(
    best: &'a CandidateScore,
    ranking: &'a [CandidateScore],
    band: Nuisance,
    level: Option<level::DataLevel>,
) -> Option<(&'a CandidateScore, level::DataLevel)> {
    let l = level.filter(|_| band.stiffness_fitted())?;
    let side = l.beyond(band)?;
    let stiffness = [Effect::Modulus, Effect::Hardening, Effect::Support];
    if Effect::of_candidate(&best.effect).any(|e| stiffness.contains(&e))
        || !best.level.is_some_and(|v| side.holds(v, band))
    {
        return None;
    }
    ranking
        .iter()
        .find(|pair| {
            other_than(&pair.effect, Effect::Modulus.name()) == Some(best.effect.as_str())
                && pair.level.is_some_and(|v| side.holds(v, band))
                && gain_over(pair, best) >= -LEVEL_PAIR_SLACK
                && !strength::any_negligible(&pair.effect, &pair.params, band, pair.level)
        })
        .map(|pair| (pair, l))
}

/// How much more a pair that reaches the measured level may leave held out than the single
/// it joins (rule (i), [`level_beside`]): 2%, a tenth of a pair's [`RICHER_GAIN`]. The level
/// is the evidence; this only keeps a pair that fits the rest worse from being named for it.
pub const LEVEL_PAIR_SLACK: f64 = 0.02;

/// The pairs of `partner` beside `best` that remove at least `min_shrink` of its held-out
/// residual, trial by trial by [`separability::SEPARATION_SE`] (`gain_z`: the pair's paired
/// gain over `best`, [`beside_gains`]), at strengths worth naming.
fn pairs_beside<'a>(
    best: &'a CandidateScore,
    ranking: &'a [CandidateScore],
    partner: Effect,
    band: Nuisance,
    min_shrink: f64,
    gain_z: impl Fn(&CandidateScore) -> Option<f64> + 'a,
) -> impl Iterator<Item = &'a CandidateScore> + 'a {
    ranking.iter().filter(move |pair| {
        other_than(&pair.effect, partner.name()) == Some(best.effect.as_str())
            && gain_over(pair, best) >= min_shrink
            && gain_z(pair).is_some_and(|z| z >= separability::SEPARATION_SE)
            && !strength::any_negligible(&pair.effect, &pair.params, band, pair.level)
    })
}

/// A sensor beside `best`: the pair `best`+`sensor` (a) removes at least `min_shrink` of
/// `best`'s held-out residual, the bar an effect meets against the floor, not a pair's
/// [`RICHER_GAIN`], (b) does so trial by trial by [`separability::SEPARATION_SE`]
/// ([`CandidateScore::sensor_gain_z`]), (c) is better by [`STRONG_EVIDENCE`] in BIC and in
/// held-out score, and (d) fits a delay or a low-pass worth naming ([`strength`]).
///
/// Why a pair's 20% is too much here: a sensor only delays and smooths the force, and what
/// that leaves to remove is the onsets' share of a residual the model error sets elsewhere.
/// On the independent P2 code, a device bias with a 40 ms delay and a 10 ms low-pass read
/// `device`: `device+sensor` ranked first and removed 14.7% more (51 ms of lag in all for
/// 50); a modulus ×1.6 with a sensor read `modulus`, the pair 15.6% more. Where the same code
/// had no sensor, the sensor beside the best single removed 0–2.4% (README, "Signal effects on
/// the independent code").
fn sensor_beside<'a>(
    best: &'a CandidateScore,
    ranking: &'a [CandidateScore],
    band: Nuisance,
    min_shrink: f64,
) -> Option<&'a CandidateScore> {
    pairs_beside(best, ranking, Effect::Sensor, band, min_shrink, |pair| {
        pair.sensor_gain_z
    })
    .find(|pair| {
        pair.bic - best.bic <= -STRONG_EVIDENCE && pair.score - best.score <= -STRONG_EVIDENCE
    })
}

/// What `richer` removes of `simpler`'s held-out residual, phase-weighted or plain.
fn gain_over(richer: &CandidateScore, simpler: &CandidateScore) -> f64 {
    shrink(richer.heldout_weighted_rmse, simpler.heldout_weighted_rmse)
        .max(shrink(richer.heldout_rmse, simpler.heldout_rmse))
}

/// The candidate `c` is with `hardening` read as `modulus` (its rate at 0), where ranked.
fn nested_simpler<'a>(
    c: &CandidateScore,
    ranking: &'a [CandidateScore],
) -> Option<&'a CandidateScore> {
    let (richer, simpler) = (Effect::Hardening.name(), Effect::Modulus.name());
    let parts: Vec<&str> = c.effect.split('+').collect();
    if !parts.contains(&richer) || parts.contains(&simpler) {
        return None;
    }
    let name = parts
        .iter()
        .map(|p| if *p == richer { simpler } else { p })
        .collect::<Vec<_>>()
        .join("+");
    ranking.iter().find(|r| r.effect == name)
}

/// Residual of the baseline broken down by axis, phase, region and depth band.
pub fn localise(data: &[TrialData]) -> Localisation {
    let mut overall = Acc::default();
    let mut phase: Vec<Acc> = vec![Acc::default(); Phase::ALL.len()];
    let mut region: std::collections::BTreeMap<String, Acc> = Default::default();
    let mut band: Vec<Acc> = vec![Acc::default(); metrics::DEPTH_BANDS_MM.len()];
    let regions: Vec<&str> = {
        let mut r: Vec<&str> = data.iter().map(|d| region_label(d.region)).collect();
        r.sort_by_key(|s| {
            ["posterior", "mid", "anterior", "unlabelled"]
                .iter()
                .position(|x| x == s)
        });
        r.dedup();
        r
    };
    let mut heat: Vec<Vec<Acc>> = vec![vec![Acc::default(); regions.len()]; Phase::ALL.len()];
    let (mut sm, mut ss, mut sc) = (0.0, 0.0, 0usize);
    for d in data {
        let rl = region_label(d.region);
        let ri = regions.iter().position(|r| *r == rl).unwrap();
        for j in 0..d.t.len() {
            let r = sub(d.base_at_t[j], d.f[j]);
            overall.push(r, d.normal);
            let pi = Phase::ALL.iter().position(|p| *p == d.phase[j]).unwrap();
            phase[pi].push(r, d.normal);
            heat[pi][ri].push(r, d.normal);
            region.entry(rl.to_string()).or_default().push(r, d.normal);
            if d.phase[j] != Phase::Approach {
                if let Some(b) = band_of(d.depth[j]) {
                    band[b].push(r, d.normal);
                }
                sm += dot(d.f[j], d.normal);
                ss += dot(d.base_at_t[j], d.normal);
                sc += 1;
            }
        }
    }
    let ov = overall.summary("all".into());
    let by_axis = vec![
        GroupResidual {
            group: "normal".into(),
            samples: ov.samples,
            rmse: ov.rmse_normal,
            bias_normal: ov.bias_normal,
            rmse_normal: ov.rmse_normal,
            rmse_tangential: f64::NAN,
        },
        GroupResidual {
            group: "tangential".into(),
            samples: ov.samples,
            rmse: ov.rmse_tangential,
            bias_normal: f64::NAN,
            rmse_normal: f64::NAN,
            rmse_tangential: ov.rmse_tangential,
        },
    ];
    let by_phase: Vec<GroupResidual> = Phase::ALL
        .iter()
        .zip(&phase)
        .filter(|(_, a)| a.n > 0)
        .map(|(p, a)| a.summary(p.name().into()))
        .collect();
    let by_region: Vec<GroupResidual> = regions
        .iter()
        .map(|r| region[*r].summary(r.to_string()))
        .collect();
    let by_depth_band: Vec<GroupResidual> = band
        .iter()
        .enumerate()
        .filter(|(_, a)| a.n > 0)
        .map(|(i, a)| a.summary(band_label(i)))
        .collect();
    let worst = |v: &[GroupResidual]| {
        v.iter()
            .filter(|g| g.rmse.is_finite())
            .max_by(|a, b| a.rmse.total_cmp(&b.rmse))
            .map(|g| g.group.clone())
            .unwrap_or_default()
    };
    let worst_axis = if ov.rmse_normal >= ov.rmse_tangential {
        "normal"
    } else {
        "tangential"
    }
    .to_string();
    let heatmap = Heatmap {
        phases: Phase::ALL.iter().map(|p| p.name().to_string()).collect(),
        regions: regions.iter().map(|r| r.to_string()).collect(),
        rmse: heat
            .iter()
            .map(|row| row.iter().map(|a| (a.n > 0).then(|| a.rmse())).collect())
            .collect(),
    };
    let (wp, wr, wb) = (worst(&by_phase), worst(&by_region), worst(&by_depth_band));
    let mn_m = if sc > 0 { sm / sc as f64 } else { 0.0 };
    let mn_s = if sc > 0 { ss / sc as f64 } else { 0.0 };
    let summary = format!(
        "largest residual along the {worst_axis} axis, in the {wp} phase, {wr} region, depth band {wb}; \
         mean normal force in contact: simulated {mn_s:.3} N vs measured {mn_m:.3} N"
    );
    Localisation {
        overall: ov,
        by_axis,
        by_phase,
        by_region,
        by_depth_band,
        heatmap,
        worst_axis,
        worst_phase: wp,
        worst_region: wr,
        worst_depth_band: wb,
        mean_normal_force_measured: mn_m,
        mean_normal_force_simulated: mn_s,
        summary,
    }
}

/// Write `report.json` and `report.html` into `out_dir` (created).
pub fn write_report(report: &Report, out_dir: &Path) -> Result<(), GapError> {
    std::fs::create_dir_all(out_dir).map_err(|e| GapError::Io(out_dir.to_path_buf(), e))?;
    let jp = out_dir.join("report.json");
    let json = serde_json::to_string_pretty(report)
        .map_err(|e| GapError::Other(format!("report.json: {e}")))?;
    std::fs::write(&jp, json).map_err(|e| GapError::Io(jp.clone(), e))?;
    let hp = out_dir.join("report.html");
    std::fs::write(&hp, html::render(report)).map_err(|e| GapError::Io(hp.clone(), e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scored(effect: &str, heldout: f64, weighted: f64, evidence: f64) -> CandidateScore {
        serde_json::from_value(serde_json::json!({
            "effect": effect, "n_params": 1, "params": [], "fit_rmse": heldout, "bic": -evidence,
            "delta_bic": -evidence, "heldout_rmse": heldout, "heldout_shrink": 1.0 - heldout,
            "heldout_weighted_rmse": weighted, "heldout_weighted_shrink": 1.0 - 2.0 * weighted,
            "heldout_study_error": 0.0, "score": -evidence, "floor_shrink": 1.0 - heldout,
            "floor_gain_z": 5.0
        }))
        .unwrap()
    }

    /// Regression: with the material nuisance, a modulus case (study mesh, seed 301) read
    /// `hardening` at a rate of 0.006/mm: 11% better than `modulus` phase-weighted, 4% plain,
    /// and ahead in score. One more parameter must remove what a pair must.
    #[test]
    fn hardening_at_a_negligible_rate_reads_as_modulus() {
        let floor = scored("none", 1.0, 0.5, 0.0);
        let modulus = scored("modulus", 0.1699, 0.0516, 4729.0);
        let decide_between = |hardening: CandidateScore| {
            let singles = vec![hardening, modulus.clone()];
            decide(&singles, &singles, &floor, &weighing(0.02))
        };
        let v = decide_between(scored("hardening", 0.1633, 0.0457, 4916.0));
        assert_eq!(v.effect, "modulus", "{}", v.reason);
        assert!(v.reason.contains("one more parameter"), "{}", v.reason);
        // a stiffening that removes 30% of modulus's residual is named
        let v = decide_between(scored("hardening", 0.7489 / 1.0739 * 0.1699, 0.04, 4916.0));
        assert_eq!(v.effect, "hardening", "{}", v.reason);
        // a pair likewise: hardening+friction against modulus+friction
        let pair = scored("hardening+friction", 0.159, 0.0446, 4950.0);
        let simpler = scored("modulus+friction", 0.1594, 0.0446, 4940.0);
        assert_eq!(
            nested_simpler(&pair, std::slice::from_ref(&simpler)).map(|c| c.effect.as_str()),
            Some("modulus+friction")
        );
        assert!(nested_simpler(&simpler, &[pair]).is_none());
    }

    /// Regression: the refined truth's no-effect case at CI size (seed 1) read `modulus`, 12.1%
    /// over the floor (nuisance at ×1.25) on a paired gain of 0.3 SE: better than the floor on
    /// some trials and worse on others. A modulus acts on every press, so its gain must hold
    /// trial by trial.
    #[test]
    fn a_modulus_better_on_some_trials_only_is_no_effect() {
        let mut floor = scored("none", 3.5774, 0.5, 0.0);
        floor.nuisance_scale = Some(1.25);
        let modulus = |z: f64| {
            let c = scored("modulus", 3.1461, 0.44, 356.9);
            against(fitted(c, &[("modulus", "modulus_scale", 1.4)]), 0.121, z)
        };
        let v = decide_singles(vec![modulus(0.3)], &floor, 0.0292);
        assert_eq!(v.effect, "none", "{}", v.reason);
        assert!(v.reason.contains("paired gain 0.3 SE"), "{}", v.reason);
        assert_eq!(
            decide_singles(vec![modulus(2.5)], &floor, 0.0292).effect,
            "modulus"
        );
        // with too few trials for the paired gain, it is not weighed
        let singles = vec![modulus(0.3)];
        let few = Weighing {
            paired: false,
            ..weighing(0.0292)
        };
        assert_eq!(decide(&singles, &singles, &floor, &few).effect, "modulus");
    }

    /// Friction acts only where the probe slides: a gain positive on average over the slid
    /// trials is enough (the refined cycle's friction case is named at 1.2 SE). Beside a global
    /// effect in a pair it is weighed as friction is.
    #[test]
    fn friction_needs_only_a_positive_gain_over_its_slides() {
        let floor = scored("none", 5.6054, 0.5, 0.0);
        let friction = |z: f64| {
            let c = scored("friction", 3.78, 0.35, 900.0);
            vec![against(fitted(c, &[("friction", "mu", 0.3)]), 0.2, z)]
        };
        assert_eq!(
            decide_singles(friction(1.2), &floor, 0.0275).effect,
            "friction"
        );
        assert_eq!(
            decide_singles(friction(-0.1), &floor, 0.0275).effect,
            "none"
        );
        let mut c = scored("x", 1.0, 1.0, 0.0);
        for (effect, z, holds) in [
            ("friction+device", 1.0, true),
            ("modulus+sensor", 1.0, false),
            ("modulus+sensor", 2.0, true),
            ("tilt", 1.9, false),
            ("mesh", 0.1, true),
        ] {
            c.effect = effect.into();
            c.floor_gain_z = z;
            assert_eq!(holds_trial_by_trial(&c), holds, "{effect} at {z} SE");
        }
    }

    /// Regression: the refined cycle's hardening case (seed 1, rate 0.28 /mm) read `modulus`:
    /// hardening removed 5% more than modulus, under the 20% one more parameter needs, but
    /// the modulus's own gain held on 1.3 SE trial by trial where the hardening's held on 4.9.
    /// The simpler model replaces the richer one only when it is an effect itself.
    #[test]
    fn a_hardening_is_not_replaced_by_a_modulus_that_does_not_hold() {
        let mut floor = scored("none", 5.0792, 0.48, 0.0);
        floor.nuisance_scale = Some(1.25);
        let hardening = fitted(
            scored("hardening", 4.0667, 0.3866, 2429.2),
            &[
                ("hardening", "small_strain_scale", 1.386),
                ("hardening", "stiffening_rate", 0.474),
            ],
        );
        let hardening = against(hardening, 0.199, 4.9);
        let modulus = |z: f64| {
            let c = scored("modulus", 4.1057, 0.4084, 2000.0);
            against(fitted(c, &[("modulus", "modulus_scale", 2.046)]), 0.192, z)
        };
        let v = decide_singles(vec![hardening.clone(), modulus(1.3)], &floor, 0.0289);
        assert_eq!(v.effect, "hardening", "{}", v.reason);
        let v = decide_singles(vec![hardening, modulus(2.6)], &floor, 0.0289);
        assert_eq!(v.effect, "modulus", "{}", v.reason);
    }

    /// `c` with its standing against the floor: held-out shrink over it and paired gain.
    fn against(mut c: CandidateScore, floor_shrink: f64, gain_z: f64) -> CandidateScore {
        c.floor_shrink = floor_shrink;
        c.floor_gain_z = gain_z;
        c
    }

    /// The verdict when only single effects are ranked.
    fn decide_singles(singles: Vec<CandidateScore>, floor: &CandidateScore, noise: f64) -> Verdict {
        decide(&singles, &singles, floor, &weighing(noise))
    }

    /// Regression: on the independent code's tilt (5°, −3°), whose presses miss the mid
    /// region and press the anterior one 91–144 N deep, a Prony g1 of 0.9 relaxing in 50 ms
    /// (both at their range's ends) beat the floor held out and was named, while leaving
    /// more than the measured force's RMS: no better than predicting no force.
    #[test]
    fn an_effect_that_does_no_better_than_no_force_is_not_named() {
        let floor = scored("none", 20.4178, 11.86, 0.0);
        let relaxation = against(
            fitted(
                scored("viscoelastic", 19.2, 9.0, 2000.0),
                &[
                    ("viscoelastic", "prony_g1", 0.9),
                    ("viscoelastic", "prony_tau1", 0.05),
                ],
            ),
            0.2,
            3.0,
        );
        let v = decide_singles(vec![relaxation.clone()], &floor, 0.0225);
        assert_eq!(v.effect, "viscoelastic", "{}", v.reason);
        let rms = Weighing {
            measured_rms: 18.2,
            ..weighing(0.0225)
        };
        let singles = vec![relaxation];
        assert_eq!(decide(&singles, &singles, &floor, &rms).effect, "none");
    }

    /// Regression: the independent P2 code's modulus ×1.7 case read `none`: the floor stopped
    /// at the level band's ×1.44, and the modulus (×1.71 in level) removed 36% more held out
    /// at 1.8 SE, the trials' model error differing too much for 2. Its trials measure the
    /// level at ×1.77 ± 0.11, 2.9 SE beyond that band and 5.5 SE beyond today's ×1.15.
    #[test]
    fn a_stiffer_tissue_than_the_level_band_is_named_from_the_measured_level() {
        let floor = scored("none", 9.6903, 1.0, 0.0);
        let modulus_at = |level: f64| {
            modulus_of_level(
                scored("modulus", 6.1696, 0.8, 3420.0),
                2.645,
                0.363,
                1.8,
                level,
            )
        };
        let measured = |ratio: f64, se: f64| measured_level(ratio, se, 0.0283);
        let decide_with = |c: CandidateScore, w: &Weighing| decide_alone(c, &floor, w);
        assert_eq!(
            decide_singles(vec![modulus_at(1.711)], &floor, 0.0283).effect,
            "none"
        );
        let v = decide_with(modulus_at(1.711), &measured(1.769, 0.113));
        assert_eq!(v.effect, "modulus", "{}", v.reason);
        assert!(v.reason.contains("5.5 SE beyond"), "{}", v.reason);
        // the trials disagree too much (1.8 SE), or the modulus stays inside the band
        assert_eq!(
            decide_with(modulus_at(1.711), &measured(1.769, 0.35)).effect,
            "none"
        );
        assert_eq!(
            decide_with(modulus_at(1.1), &measured(1.769, 0.113)).effect,
            "none"
        );
        // beyond on the other side: a softer level says nothing for a stiffer modulus
        assert_eq!(
            decide_with(modulus_at(1.711), &measured(0.4, 0.05)).effect,
            "none"
        );
        // with the nuisances off there is no band for the level to lie beyond
        let off = Weighing {
            band: Nuisance::OFF,
            ..measured(1.769, 0.113)
        };
        assert_eq!(decide_with(modulus_at(1.711), &off).effect, "none");
        // (f) still holds, and a modulus that does worse than the floor trial by trial is not
        // named where the level lies less than [`LEVEL_ALONE_SE`] beyond the band (3.1 SE)
        let no_force = Weighing {
            measured_rms: 6.0,
            ..measured(1.769, 0.113)
        };
        assert_eq!(decide_with(modulus_at(1.711), &no_force).effect, "none");
        let losing = against(modulus_at(1.711), 0.363, -0.5);
        assert_eq!(
            decide_with(losing.clone(), &measured(1.769, 0.2)).effect,
            "none"
        );
        // 5.5 SE beyond, the level alone carries it
        assert_eq!(
            decide_with(losing, &measured(1.769, 0.113)).effect,
            "modulus"
        );
    }

    /// Regression: on the independent code's linear elements a modulus ×1.42 (offset ×0.95,
    /// seed 4503's poses) read `none`. Its trials measure ×1.424 ± 0.040, 6.8 SE over the
    /// band, and `modulus` (×1.421 in level) held out 14.7% less than the floor, but at −1.0
    /// SE trial by trial. A no-effect case of the same set measures ×1.220 ± 0.049 (1.4 SE
    /// over) with as good a modulus, and stays `none`.
    #[test]
    fn a_level_far_beyond_the_band_names_a_modulus_that_loses_trial_by_trial() {
        let floor = scored("none", 4.9872, 1.0, 0.0);
        let modulus = modulus_of_level(
            scored("modulus", 4.2522, 0.8, 1016.0),
            1.6835,
            0.147,
            -1.0,
            1.421,
        );
        let measured = |ratio: f64, se: f64| measured_level(ratio, se, 0.0273);
        let v = decide_alone(modulus.clone(), &floor, &measured(1.4239, 0.0404));
        assert_eq!(v.effect, "modulus", "{}", v.reason);
        assert!(v.reason.contains("6.8 SE beyond"), "{}", v.reason);
        let v = decide_alone(modulus, &floor, &measured(1.220, 0.049));
        assert_eq!(v.effect, "none", "{}", v.reason);
    }

    /// Regression: on the independent code's linear elements a modulus ×1.42 (seed 4702's
    /// poses) read `hardening`: 7.9% plain and 8.4% phase-weighted over `modulus`, under the
    /// 20% one more parameter needs, but `modulus` (×1.517 in level) was not identified, its
    /// paired gain on the floor at −0.6 SE. Its trials measure ×1.523 ± 0.063, 5.9 SE over the
    /// band: rule (g)'s modulus, which the nested rule now counts as identified.
    #[test]
    fn a_modulus_beyond_the_band_is_not_read_as_hardening_for_less_than_a_pair_s_gain() {
        let floor = scored("none", 7.6674, 0.5212, 0.0);
        let hardening = |heldout: f64, weighted: f64| {
            against(
                fitted(
                    scored("hardening", heldout, weighted, 3652.7),
                    &[
                        ("hardening", "small_strain_scale", 1.396),
                        ("hardening", "stiffening_rate", 0.4577),
                    ],
                ),
                0.273,
                4.3,
            )
        };
        let modulus = modulus_of_level(
            scored("modulus", 6.0545, 0.4803, 1695.0),
            1.7106,
            0.21,
            -0.6,
            1.517,
        );
        let decide_with = |h: CandidateScore, w: &Weighing| {
            let singles = vec![h, modulus.clone()];
            decide(&singles, &singles, &floor, w)
        };
        let measured = |ratio: f64| measured_level(ratio, 0.063, 0.0279);
        let v = decide_with(hardening(5.5757, 0.4401), &measured(1.523));
        assert_eq!(v.effect, "modulus", "{}", v.reason);
        assert!(v.reason.contains("removes only 8%"), "{}", v.reason);
        // a level the nuisances may take leaves the modulus unidentified, and the hardening
        assert_eq!(
            decide_with(hardening(5.5757, 0.4401), &measured(1.10)).effect,
            "hardening"
        );
        // a stiffening that removes a pair's share of the modulus's residual is named
        assert_eq!(
            decide_with(hardening(4.2, 0.35), &measured(1.523)).effect,
            "hardening"
        );
    }

    /// Regression: the independent P2 code's modulus ×1.6 (seed 4216's poses, no offset) read
    /// `none`: its trials measure ×1.598 ± 0.101 of the replay's level, 1.6 SE over a ceiling
    /// of ×1.44 (the scale's ×1.25 widened by 15%), and `modulus` (×1.538 in level, 29.7% over
    /// the floor) held at 1.2 SE trial by trial. Every reference is softer than the replay, so
    /// above it only the specimen's offset (+15%) is left to the nuisances: 4.4 SE over
    /// [`fit::LEVEL_MAX`]. A softer level by as much stays inside the floor's reach.
    #[test]
    fn a_level_above_a_specimen_s_offset_is_a_modulus() {
        let floor = scored("none", 8.0198, 1.0, 0.0);
        let modulus = |level: f64| {
            modulus_of_level(
                scored("modulus", 5.6371, 0.4514, 2746.5),
                2.3743,
                0.297,
                1.2,
                level,
            )
        };
        let measured = |ratio: f64| measured_level(ratio, 0.101, 0.0271);
        let decide_with = |c: CandidateScore, w: &Weighing| decide_alone(c, &floor, w);
        let v = decide_with(modulus(1.538), &measured(1.598));
        assert_eq!(v.effect, "modulus", "{}", v.reason);
        assert!(v.reason.contains("4.4 SE beyond"), "{}", v.reason);
        // the same distance below the replay's level (×1/1.598) lies within the floor's reach
        // once the trials' error is counted
        let below = decide_with(modulus(1.0 / 1.538), &measured(1.0 / 1.598));
        assert_eq!(below.effect, "none", "{}", below.reason);
    }

    /// A `modulus` scored as `c`, fitted at `scale`, `floor_shrink` over the floor at `gain_z`
    /// trial by trial, its response at `level` of the replay's.
    fn modulus_of_level(
        c: CandidateScore,
        scale: f64,
        floor_shrink: f64,
        gain_z: f64,
        level: f64,
    ) -> CandidateScore {
        let mut c = against(
            fitted(c, &[("modulus", "modulus_scale", scale)]),
            floor_shrink,
            gain_z,
        );
        c.level = Some(level);
        c
    }

    /// The default weighing with the trials' measured level at `ratio` ± `se` (15 trials).
    fn measured_level(ratio: f64, se: f64, noise: f64) -> Weighing {
        Weighing {
            level: Some(level::DataLevel {
                ratio,
                se,
                trials: 15,
                strata: 3,
            }),
            ..weighing(noise)
        }
    }

    /// The verdict with `c` the only candidate.
    fn decide_alone(c: CandidateScore, floor: &CandidateScore, w: &Weighing) -> Verdict {
        let singles = vec![c];
        decide(&singles, &singles, floor, w)
    }

    /// The default weighing with enough trials for pairs and paired gains.
    fn weighing(noise: f64) -> Weighing {
        Weighing {
            noise,
            min_shrink: 0.08,
            band: Nuisance::ALL,
            pairs_allowed: true,
            paired: true,
            measured_rms: f64::INFINITY,
            level: None,
        }
    }

    fn fitted(mut c: CandidateScore, params: &[(&str, &str, f64)]) -> CandidateScore {
        c.params = params
            .iter()
            .map(|&(e, n, v)| fit::FittedParam::given(e, n, v))
            .collect();
        c
    }

    /// Regression: the independent P2 code's grade-2 case (modulus ×0.59) was named right
    /// with `modulus_scale` 0.890 in the report, 51% off: the contact layer beside it (at its
    /// knot) took the level to ×0.578, and the scale sat above it by what the layer took.
    /// The report carries the level; calibration still writes the fit's tissue and layer.
    #[test]
    fn a_modulus_beside_a_contact_layer_reports_its_level() {
        let mut c = fitted(
            scored("modulus", 1.98, 0.25, 2000.0),
            &[("modulus", "modulus_scale", 0.8896)],
        );
        c.params[0].std = 0.01;
        c.level = Some(0.5775);
        c.contact_compliance = Some(1e-5);
        c.report_modulus_as_level();
        let scale = recovery::fitted_strength(&c.params, "modulus", "modulus_scale").unwrap();
        assert!((scale - 0.5775).abs() < 1e-12, "{:?}", c.params);
        assert!((c.params[0].std - 0.01 * 0.5775 / 0.8896).abs() < 1e-12);
        let carried = c
            .nuisance_scale
            .expect("the tissue's part beside the layer");
        let mut scene = launch_config::SceneConfig::default();
        calibrate::apply_effect(&mut scene, Effect::Modulus, &c.params);
        calibrate::apply_nuisance(&mut scene, carried);
        assert!((scene.material.modulus_scale - 0.8896).abs() < 1e-12);
        // reported once: a second pass changes nothing
        let values = |c: &CandidateScore| c.params.iter().map(|p| p.value).collect::<Vec<_>>();
        let once = c.clone();
        c.report_modulus_as_level();
        assert_eq!(values(&c), values(&once));
        assert_eq!(c.nuisance_scale, once.nuisance_scale);
        // a candidate with a stiffness nuisance of its own, or without a level, is as fitted
        let mut friction = fitted(
            scored("modulus+friction", 2.0, 0.3, 1900.0),
            &[("modulus", "modulus_scale", 1.4), ("friction", "mu", 0.2)],
        );
        friction.nuisance_scale = Some(1.1);
        friction.level = Some(1.2);
        let before = values(&friction);
        friction.report_modulus_as_level();
        assert_eq!(values(&friction), before);
        let mut hardening = fitted(
            scored("hardening", 2.0, 0.3, 1900.0),
            &[("hardening", "small_strain_scale", 1.3)],
        );
        hardening.report_modulus_as_level();
        assert_eq!(hardening.nuisance_scale, None);
    }

    /// Regression: a coarse-mesh proxy case of modulus ×1.62 with friction μ 0.24 (seed 213)
    /// read `friction`: its stiffness nuisance took the modulus up to the band's ×1.25, and
    /// `modulus+friction` (×1.51, μ 0.23) removed 9.7% more, under a pair's 20%, at 2.7 SE.
    #[test]
    fn a_modulus_beyond_the_nuisance_band_beside_friction_is_named() {
        let floor = scored("none", 8.2931, 0.9, 0.0);
        let mut friction = fitted(
            scored("friction", 2.5033, 0.3101, 1837.1),
            &[("friction", "mu", 0.2521)],
        );
        friction.floor_shrink = 0.565;
        friction.nuisance_scale = Some(1.25);
        let pair = |modulus: f64, z: f64| {
            let mut c = fitted(
                scored("modulus+friction", 2.2599, 0.2865, 1962.9),
                &[
                    ("modulus", "modulus_scale", modulus),
                    ("friction", "mu", 0.23),
                ],
            );
            c.floor_shrink = 0.61;
            c.stiffness_gain_z = Some(z);
            c
        };
        let decide_with = |single: &CandidateScore, pair: CandidateScore| {
            let singles = vec![single.clone()];
            let ranking = vec![pair, single.clone()];
            decide(&singles, &ranking, &floor, &weighing(0.0284))
        };
        let v = decide_with(&friction, pair(1.515, 2.70));
        assert_eq!(v.effect, "modulus+friction", "{}", v.reason);
        assert!(v.reason.contains("band's bound"), "{}", v.reason);
        // not trial by trial (the refined truth's device case: 1.99 SE)
        assert_eq!(decide_with(&friction, pair(1.515, 1.99)).effect, "friction");
        // a modulus the nuisance's band holds is no effect
        assert_eq!(decide_with(&friction, pair(1.2, 2.70)).effect, "friction");
        // a nuisance inside its band has taken all the stiffness there is
        let mut inside = friction.clone();
        inside.nuisance_scale = Some(1.19);
        assert_eq!(decide_with(&inside, pair(1.515, 2.70)).effect, "friction");
    }

    /// Regression: the independent code's linear elements, modulus ×1.42 with a sensor (25 ms
    /// delay, 25 ms low-pass; seed 4284's poses at an offset ×0.90), read `sensor`: the
    /// nuisances took its level to ×1.250, beyond the band's ×1.15, while the trials measured
    /// ×1.359 ± 0.040. `modulus+sensor` (×1.340 in level, a modulus ×1.45) held out 0.4% worse
    /// and scored worse, so neither a pair's gain nor the band's bound named it.
    #[test]
    fn a_stiffness_the_level_reads_beside_a_sensor_is_named() {
        let floor = scored("none", 8.1958, 0.60, 0.0);
        let lag = [
            ("sensor", "delay", 0.0172),
            ("sensor", "lowpass_tau", 0.0270),
        ];
        let mut sensor = fitted(scored("sensor", 5.2031, 0.4082, 6299.3), &lag);
        sensor.floor_shrink = 0.195;
        sensor.floor_gain_z = 4.4;
        sensor.nuisance_scale = Some(1.25);
        sensor.level = Some(1.250);
        let pair = |level: f64, heldout: f64| {
            let mut params = vec![("modulus", "modulus_scale", 1.4498)];
            params.extend(lag);
            let mut c = fitted(scored("modulus+sensor", heldout, 0.4178, 6713.2), &params);
            c.level = Some(level);
            c
        };
        let decide_with = |single: &CandidateScore, pair: CandidateScore, w: &Weighing| {
            let singles = vec![single.clone()];
            let ranking = vec![single.clone(), pair];
            decide(&singles, &ranking, &floor, w)
        };
        let measured = measured_level(1.359, 0.040, 0.0264);
        let v = decide_with(&sensor, pair(1.340, 5.2245), &measured);
        assert_eq!(v.effect, "modulus+sensor", "{}", v.reason);
        assert!(v.reason.contains("5.2 SE beyond"), "{}", v.reason);
        // without the trials' level, or with one inside the band's reach, the single stands
        assert_eq!(
            decide_with(&sensor, pair(1.340, 5.2245), &weighing(0.0264)).effect,
            "sensor"
        );
        let near = measured_level(1.20, 0.040, 0.0264);
        assert_eq!(
            decide_with(&sensor, pair(1.340, 5.2245), &near).effect,
            "sensor"
        );
        // a pair whose level does not reach beyond the band, or that holds out 3% worse
        assert_eq!(
            decide_with(&sensor, pair(1.10, 5.2245), &measured).effect,
            "sensor"
        );
        assert_eq!(
            decide_with(&sensor, pair(1.340, 5.36), &measured).effect,
            "sensor"
        );
        // the single's nuisances kept its level inside the band: nothing was taken from it
        let mut inside = sensor.clone();
        inside.level = Some(1.12);
        assert_eq!(
            decide_with(&inside, pair(1.340, 5.2245), &measured).effect,
            "sensor"
        );
    }

    /// Regression: the independent P2 code's device bias (0.2, −0.1, 0.25) N with a sensor
    /// (40 ms delay, 10 ms low-pass) read `device`: `device+sensor` ranked first and removed
    /// 14.7% more phase-weighted, under a pair's 20%.
    #[test]
    fn a_sensor_beside_a_device_bias_is_named() {
        let floor = scored("none", 3.9505, 1.1236, 0.0);
        let bias = [
            ("device", "bias_x", 0.2),
            ("device", "bias_y", -0.1),
            ("device", "bias_z", 0.25),
        ];
        let mut device = fitted(scored("device", 3.8582, 0.4230, 17693.9), &bias);
        device.floor_shrink = 0.624;
        let pair = |delay: f64, weighted: f64, z: f64| {
            let mut params = bias.to_vec();
            params.extend([
                ("sensor", "delay", delay),
                ("sensor", "lowpass_tau", 0.0219),
            ]);
            let mut c = fitted(scored("device+sensor", 3.6717, weighted, 20293.7), &params);
            c.sensor_gain_z = Some(z);
            c
        };
        let decide_with = |pair: CandidateScore| {
            let singles = vec![device.clone()];
            let ranking = vec![pair, device.clone()];
            decide(&singles, &ranking, &floor, &weighing(0.0259))
        };
        let v = decide_with(pair(0.0293, 0.3607, 3.0));
        assert_eq!(v.effect, "device+sensor", "{}", v.reason);
        assert!(v.reason.contains("a sensor's lag"), "{}", v.reason);
        // not trial by trial
        assert_eq!(decide_with(pair(0.0293, 0.3607, 1.9)).effect, "device");
        // removing less than an effect must of the floor (the no-sensor cases: 0-2.4%)
        assert_eq!(decide_with(pair(0.0293, 0.41, 3.0)).effect, "device");
        // a lag too short to name
        let mut short = pair(0.001, 0.3607, 3.0);
        short.params[4].value = 0.001;
        let singles = vec![device.clone()];
        let v = decide(
            &singles,
            &[short, device.clone()],
            &floor,
            &weighing(0.0259),
        );
        assert_eq!(v.effect, "device", "{}", v.reason);
    }

    /// Regression: a `hardening` case of the study-mesh proxy set (seed 300, case 2) read
    /// `hardening+viscoelastic` through a Prony term of g1 0.017 at τ1's 50 ms bound, which
    /// removed 29% of hardening's held-out residual.
    #[test]
    fn a_pair_is_not_named_for_a_negligible_second_effect() {
        let floor = scored("none", 3.4569, 0.33, 0.0);
        let hardening = fitted(
            scored("hardening", 0.6995, 0.1381, 3158.4),
            &[("hardening", "stiffening_rate", 0.2442)],
        );
        let pair_with = |g1: f64| {
            fitted(
                scored("hardening+viscoelastic", 0.4966, 0.1138, 3456.4),
                &[
                    ("hardening", "stiffening_rate", 0.2442),
                    ("viscoelastic", "prony_g1", g1),
                    ("viscoelastic", "prony_tau1", 0.05),
                ],
            )
        };
        let decide_with = |pair: CandidateScore| {
            let singles = vec![hardening.clone()];
            let ranking = vec![pair, hardening.clone()];
            decide(&singles, &ranking, &floor, &weighing(0.025))
        };
        let v = decide_with(pair_with(0.0169));
        assert_eq!(v.effect, "hardening", "{}", v.reason);
        // a relaxation of a fifth of the force is named
        let v = decide_with(pair_with(0.2));
        assert_eq!(v.effect, "hardening+viscoelastic", "{}", v.reason);
    }

    /// Regression: with negligible strengths not named, a `modulus` case of the study-mesh
    /// proxy set (seed 300, case 1) read `none`: its best single was `hardening` at a rate of
    /// 0.006/mm, and `modulus` ×0.567 behind it was never weighed.
    #[test]
    fn a_single_at_a_negligible_strength_gives_way_to_the_next() {
        let floor = scored("none", 0.8615, 0.33, 0.0);
        let hardening = fitted(
            scored("hardening", 0.1633, 0.0457, 4916.3),
            &[
                ("hardening", "small_strain_scale", 0.565),
                ("hardening", "stiffening_rate", 0.0057),
            ],
        );
        let modulus = fitted(
            scored("modulus", 0.1699, 0.0516, 4729.0),
            &[("modulus", "modulus_scale", 0.567)],
        );
        let singles = vec![hardening, modulus];
        let v = decide(&singles, &singles, &floor, &weighing(0.0235));
        assert_eq!(v.effect, "modulus", "{}", v.reason);
        // inside the stiffness nuisance's band a modulus is not named either
        let inside = fitted(
            scored("modulus", 0.1699, 0.0516, 4729.0),
            &[("modulus", "modulus_scale", 1.1)],
        );
        let singles = vec![singles[0].clone(), inside];
        let v = decide(&singles, &singles, &floor, &weighing(0.0235));
        assert_eq!(v.effect, "none", "{}", v.reason);
    }

    /// Regression: a friction+device case of the refined truth (seed 1, case 11) read `device`.
    /// Its best pair by score, hardening+device, removed 12% of device's residual (under the
    /// 20% a pair needs); friction+device, second in score, removed 22% and was never weighed.
    #[test]
    fn a_pair_that_passes_behind_one_that_fails_is_named() {
        let floor = scored("none", 5.1554, 0.6, 0.0);
        let bias = [
            ("device", "bias_x", -0.111),
            ("device", "bias_y", 0.439),
            ("device", "bias_z", -0.205),
        ];
        let device = fitted(scored("device", 4.8103, 0.4376, 1277.6), &bias);
        let stiffening = fitted(
            scored("hardening+device", 4.2505, 0.3817, 1490.1),
            &[&[("hardening", "stiffening_rate", 0.447)][..], &bias].concat(),
        );
        let friction = fitted(
            scored("friction+device", 3.7558, 0.3857, 1473.4),
            &[&[("friction", "mu", 0.117)][..], &bias].concat(),
        );
        // against the floor phase-weighted, as reported
        let against = |mut c: CandidateScore, shrink: f64| {
            c.floor_shrink = shrink;
            c
        };
        let (device, stiffening, friction) = (
            against(device, 0.684),
            against(stiffening, 0.732),
            against(friction, 0.730),
        );
        let singles = vec![device.clone()];
        let ranking = vec![stiffening, friction, device];
        let v = decide(&singles, &ranking, &floor, &weighing(0.029));
        assert_eq!(v.effect, "friction+device", "{}", v.reason);
    }
}
