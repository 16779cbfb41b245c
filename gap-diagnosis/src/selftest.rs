//! `gap selftest`: generated cases (each effect alone, some pairs, none) diagnosed blind.
use super::experiment::load_experiment;
use super::model::{ForceModel, Variant};
use super::reality::{
    stiffness_offset, write_experiment_with, Injected, RealitySpec, Site, TruthMesh,
    STIFFNESS_OFFSET,
};
use super::recovery::{recovery, Recovery, RECOVERY_TOLERANCE};
use super::sim_model::SimForceModel;
use super::{diagnose, GapError, Options};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// The case cycle: none, every effect alone, then pairs.
pub const CASES: [&str; 14] = [
    "none",
    "modulus",
    "hardening",
    "viscoelastic",
    "friction",
    "tilt",
    "device",
    "support",
    "mesh",
    "sensor",
    "modulus+sensor",
    "friction+device",
    "viscoelastic+tilt",
    "hardening+friction",
];

#[derive(Debug, Clone)]
pub struct SelftestOptions {
    pub diagnose: Options,
    pub probings_per_region: usize,
    pub noise_sigma: f64,
    /// Keep the generated folders here (else a temporary folder, removed afterwards).
    pub keep_dir: Option<PathBuf>,
    /// Print one line per case on stderr.
    pub verbose: bool,
    /// Restrict the case cycle (labels as in [`CASES`]).
    pub cases: Option<Vec<String>>,
    /// Largest systematic stiffness offset of a case's truth, either way (uniform, drawn per
    /// case from the seed; [`crate::reality::stiffness_offset`]). Default ±15%, in every case:
    /// no model is the specimen. 0 is the old self-consistent mode (the truth is the replay
    /// model itself), kept as a fast check of the statistics.
    pub stiffness_offset: f64,
    /// How the truth discretises the specimen: by default its mesh refined once
    /// ([`TruthMesh::RefinedOnce`], what [`selftest`] builds); [`TruthMesh::Replay`] with no
    /// offset is the exact mode. [`selftest_with`] takes the caller's truth model and records
    /// this in each case's truth file.
    pub truth_mesh: TruthMesh,
}

impl SelftestOptions {
    /// The old self-consistent mode: the truth is the replay model itself, no stiffness
    /// offset (a fast check of the statistics).
    pub fn exact(self) -> SelftestOptions {
        SelftestOptions {
            stiffness_offset: 0.0,
            truth_mesh: TruthMesh::Replay,
            ..self
        }
    }
}

impl Default for SelftestOptions {
    fn default() -> Self {
        SelftestOptions {
            diagnose: Options::default(),
            probings_per_region: 5,
            noise_sigma: 0.02,
            keep_dir: None,
            verbose: false,
            cases: None,
            stiffness_offset: STIFFNESS_OFFSET,
            truth_mesh: TruthMesh::RefinedOnce,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CaseResult {
    pub case: usize,
    pub truth: String,
    pub found: String,
    pub correct: bool,
    /// The truth's systematic stiffness offset (1: none).
    #[serde(default = "one")]
    pub stiffness_scale: f64,
    /// The stiffness nuisance the diagnosis fitted with its verdict (absent for `modulus`,
    /// `hardening`, whose scale is the total, and with the nuisance off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nuisance_scale: Option<f64>,
    /// Held-out shrink the diagnosis reports for its verdict.
    pub heldout_shrink: f64,
    /// Held-out shrink of the true candidate (None for `none` or when not ranked).
    pub true_candidate_shrink: Option<f64>,
    /// Each strength of an injected effect the verdict names, against its fit
    /// ([`crate::recovery`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub recovery: Vec<Recovery>,
    /// Probings whose first draw the truth's physics flagged as faulty, drawn again
    /// ([`crate::reality::Truth::redrawn`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub redrawn: Vec<String>,
    pub elapsed_s: f64,
}

fn one() -> f64 {
    1.0
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SelftestResult {
    pub seed: u64,
    /// [`SelftestOptions::stiffness_offset`] of the run (0: the exact mode).
    #[serde(default)]
    pub stiffness_offset: f64,
    /// [`SelftestOptions::truth_mesh`] of the run.
    #[serde(default)]
    pub truth_mesh: TruthMesh,
    pub cases: Vec<CaseResult>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SelftestSummary {
    pub cases: usize,
    pub correct: usize,
    pub accuracy: f64,
    /// Mean held-out shrink of the verdicts over cases with an injected effect.
    pub heldout_shrink_mean: f64,
    /// Injected strengths graded ([`crate::recovery`]: those of effects the verdict names)
    /// and how many of them were fitted within [`RECOVERY_TOLERANCE`] of the truth.
    #[serde(default)]
    pub params_graded: usize,
    #[serde(default)]
    pub params_within_tolerance: usize,
    pub seed: u64,
    /// [`SelftestOptions::stiffness_offset`] of the run (0: the exact mode).
    #[serde(default)]
    pub stiffness_offset: f64,
    /// [`SelftestOptions::truth_mesh`] of the run.
    #[serde(default)]
    pub truth_mesh: TruthMesh,
    pub elapsed_s: f64,
}

impl SelftestResult {
    pub fn summary(&self) -> SelftestSummary {
        let correct = self.cases.iter().filter(|c| c.correct).count();
        let eff: Vec<&CaseResult> = self.cases.iter().filter(|c| c.truth != "none").collect();
        let graded = self.cases.iter().flat_map(|c| &c.recovery);
        SelftestSummary {
            params_graded: graded.clone().count(),
            params_within_tolerance: graded.filter(|r| r.within_tolerance()).count(),
            cases: self.cases.len(),
            correct,
            accuracy: correct as f64 / self.cases.len().max(1) as f64,
            heldout_shrink_mean: eff.iter().map(|c| c.heldout_shrink).sum::<f64>()
                / eff.len().max(1) as f64,
            seed: self.seed,
            stiffness_offset: self.stiffness_offset,
            truth_mesh: self.truth_mesh,
            elapsed_s: self.cases.iter().map(|c| c.elapsed_s).sum(),
        }
    }

    /// Per-case lines and the confusion matrix (rows: truth, columns: verdict).
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        for c in &self.cases {
            let _ = writeln!(
                s,
                "case {:3}  truth {:20} found {:20} {}  held-out shrink {:5.1}%  stiffness ×{:.3} \
                 (fitted {})  ({:.1} s)",
                c.case,
                c.truth,
                c.found,
                if c.correct { "ok " } else { "MISS" },
                100.0 * c.heldout_shrink,
                c.stiffness_scale,
                c.nuisance_scale
                    .map_or("–".to_string(), |v| format!("×{v:.3}")),
                c.elapsed_s
            );
            for r in &c.recovery {
                let _ = writeln!(s, "          {r:#}");
            }
        }
        let mut labels: Vec<String> = self
            .cases
            .iter()
            .flat_map(|c| [c.truth.clone(), c.found.clone()])
            .collect();
        labels.sort();
        labels.dedup();
        let mut m: BTreeMap<(String, String), usize> = BTreeMap::new();
        for c in &self.cases {
            *m.entry((c.truth.clone(), c.found.clone())).or_default() += 1;
        }
        let w = labels.iter().map(|l| l.len()).max().unwrap_or(4).max(10);
        let _ = write!(
            s,
            "\nconfusion (rows truth, columns verdict)\n{:w$}",
            "",
            w = w + 2
        );
        for l in &labels {
            let _ = write!(s, " {:>w$}", l, w = l.len().max(3));
        }
        s.push('\n');
        for r in &labels {
            let _ = write!(s, "{:w$}  ", r, w = w);
            for c in &labels {
                let v = m.get(&(r.clone(), c.clone())).copied().unwrap_or(0);
                let _ = write!(s, " {:>w$}", v, w = c.len().max(3));
            }
            s.push('\n');
        }
        let sm = self.summary();
        let _ = writeln!(
            s,
            "\n{}/{} correct ({:.0}%), mean held-out shrink {:.1}%, fitted strengths within {:.0}% \
             of the truth {}/{}, stiffness offset ±{:.0}%, truth mesh {}",
            sm.correct,
            sm.cases,
            100.0 * sm.accuracy,
            100.0 * sm.heldout_shrink_mean,
            100.0 * RECOVERY_TOLERANCE,
            sm.params_within_tolerance,
            sm.params_graded,
            100.0 * sm.stiffness_offset,
            match sm.truth_mesh {
                TruthMesh::Replay => "the replay's",
                TruthMesh::RefinedOnce => "refined once",
            }
        );
        s
    }
}

/// The injected strengths as the truth model applied them, in the replay's units: a levelled
/// truth's support is its injected stiffness × the levelling ([`ForceModel::support_scale`]),
/// which is what a diagnosis of it should fit.
fn as_applied(injected: &[Injected], truth_model: &dyn ForceModel) -> Vec<Injected> {
    let mut out = injected.to_vec();
    for inj in &mut out {
        if let Some(k) = inj.params.get_mut("support_stiffness") {
            *k *= truth_model.support_scale();
        }
    }
    out
}

/// Labels of the first `n` cases.
pub fn case_labels(n: usize, opts: &SelftestOptions) -> Vec<String> {
    let cycle: Vec<String> = opts
        .cases
        .clone()
        .unwrap_or_else(|| CASES.iter().map(|s| s.to_string()).collect());
    (0..n).map(|i| cycle[i % cycle.len()].clone()).collect()
}

/// The shipped self-test: truth and diagnosis through the physics model, the truth on the
/// mesh `opts.truth_mesh` says.
pub fn selftest(
    cases: usize,
    seed: u64,
    opts: &SelftestOptions,
) -> Result<SelftestResult, GapError> {
    let data = super::data_dir();
    let mut scene = launch_config::SceneConfig::default();
    scene.meniscus.mesh = "default:lateral:coarse".into();
    let model = SimForceModel::from_scene(scene, &data);
    let sites = model.sites()?;
    // the diagnosis replays with its own options' contact (`Options::replay_model`)
    let model_for = |exp: &super::Experiment| {
        opts.diagnose
            .replay_model(SimForceModel::for_experiment(exp, &data)?)
            .map(|m| Box::new(m) as Box<dyn ForceModel>)
    };
    let truth = opts.truth_mesh.model(&model)?;
    selftest_with(cases, seed, opts, truth.as_ref(), &sites, &model_for)
}

type ModelFor<'a> = dyn Fn(&super::Experiment) -> Result<Box<dyn ForceModel>, GapError> + 'a;

/// Most cases one self-test may generate. A case is a generated experiment and its full
/// diagnosis (seconds to minutes each), so 1,000 is already days; the labels are built up
/// front, and an unbounded count panicked on a capacity overflow or aborted out of memory.
pub const MAX_SELFTEST_CASES: usize = 1000;

/// Upper bound (exclusive) of [`SelftestOptions::stiffness_offset`]: at 1 the softest truth
/// would have no stiffness at all.
pub const MAX_STIFFNESS_OFFSET: f64 = 0.5;

/// Self-test with a given truth model and a factory for the diagnosis model of a folder.
pub fn selftest_with(
    cases: usize,
    seed: u64,
    opts: &SelftestOptions,
    truth_model: &dyn ForceModel,
    sites: &[Site],
    model_for: &ModelFor,
) -> Result<SelftestResult, GapError> {
    if !(1..=MAX_SELFTEST_CASES).contains(&cases) {
        return Err(GapError::Other(format!(
            "self-test of {cases} cases: from 1 to {MAX_SELFTEST_CASES}"
        )));
    }
    if !(0.0..MAX_STIFFNESS_OFFSET).contains(&opts.stiffness_offset) {
        return Err(GapError::Other(format!(
            "stiffness offset {}: from 0 to below {MAX_STIFFNESS_OFFSET} (a fraction either way)",
            opts.stiffness_offset
        )));
    }
    let root = match &opts.keep_dir {
        Some(d) => d.clone(),
        None => std::env::temp_dir().join(format!(
            "arthrosim_gap_selftest_{}_{}",
            std::process::id(),
            seed
        )),
    };
    let mut out = Vec::new();
    for (i, label) in case_labels(cases, opts).into_iter().enumerate() {
        let start = std::time::Instant::now();
        let effects: Vec<&str> = label.split('+').collect();
        let case_seed = seed.wrapping_mul(1_000_003).wrapping_add(i as u64);
        let mut spec = RealitySpec::from_effects(&effects, case_seed)?;
        spec.stiffness_scale = stiffness_offset(case_seed, opts.stiffness_offset);
        spec.truth_mesh = opts.truth_mesh;
        spec.probings_per_region = opts.probings_per_region;
        spec.noise_sigma = opts.noise_sigma;
        let dir = root.join(format!("case{i:03}"));
        let truth_file = root.join(format!("case{i:03}_truth.json"));
        let truth = write_experiment_with(&spec, truth_model, sites, &dir, &truth_file)?;
        let exp = load_experiment(&dir, &super::data_dir())?;
        let model = model_for(&exp)?;
        let report = diagnose(&exp, model.as_ref(), &opts.diagnose)?;
        let found = report.verdict.effect.clone();
        let true_shrink = report
            .ranking
            .iter()
            .find(|c| c.effect == truth.label)
            .map(|c| c.heldout_shrink);
        let r = CaseResult {
            case: i,
            correct: found == truth.label,
            stiffness_scale: spec.stiffness_scale,
            nuisance_scale: report.verdict.nuisance_scale,
            truth: truth.label,
            redrawn: truth.redrawn,
            found,
            heldout_shrink: report.verdict.heldout_shrink,
            true_candidate_shrink: true_shrink,
            recovery: recovery(
                &as_applied(&spec.injected, truth_model),
                &report.verdict.params,
            ),
            elapsed_s: start.elapsed().as_secs_f64(),
        };
        if opts.verbose {
            eprintln!(
                "case {:3}  truth {:20} found {:20} {} shrink {:5.1}%  stiffness ×{:.3}  ({:.1} s{})  {}",
                r.case,
                r.truth,
                r.found,
                if r.correct { "ok " } else { "MISS" },
                100.0 * r.heldout_shrink,
                r.stiffness_scale,
                r.elapsed_s,
                if r.redrawn.is_empty() {
                    String::new()
                } else {
                    format!("; redrawn {}", r.redrawn.join(", "))
                },
                report.verdict.reason
            );
            eprintln!(
                "           floor (nuisance {}) held {:.4}",
                report
                    .heldout
                    .nuisance_scale
                    .map_or("off".to_string(), |v| format!("×{v:.3}")),
                report.heldout.nuisance_rmse
            );
            // the six best, and every single effect (what rule (d) weighs, `decide`)
            for c in report
                .ranking
                .iter()
                .enumerate()
                .filter(|(i, c)| *i < 6 || !c.effect.contains('+'))
                .map(|(_, c)| c)
            {
                eprintln!(
                    "           {:24} held {:.4} shrink {:5.1}% over floor {:5.1}% z {:6.1} score {:10.1}",
                    c.effect,
                    c.heldout_rmse,
                    100.0 * c.heldout_shrink,
                    100.0 * c.floor_shrink,
                    c.floor_gain_z,
                    c.score
                );
            }
        }
        out.push(r);
    }
    if opts.keep_dir.is_none() {
        let _ = std::fs::remove_dir_all(&root);
    }
    Ok(SelftestResult {
        seed,
        stiffness_offset: opts.stiffness_offset,
        truth_mesh: opts.truth_mesh,
        cases: out,
    })
}

/// Benchmark: a generated 15-trial experiment (the study protocol) diagnosed end to end with
/// the physics model; returns the JSON line (`trials`, `diagnose_s`, `generate_s`, `verdict`).
///
/// `mesh`: the specimen (a mesh spec; None: the generated experiments' default, the coarse
/// parametric mesh). Issue 15's speed target is for a ~1,400-node specimen
/// (`default:lateral:40x6x4`, 1,435 nodes).
pub fn bench(
    effect: &str,
    seed: u64,
    mesh: Option<&str>,
    opts: &Options,
) -> Result<serde_json::Value, GapError> {
    let root = std::env::temp_dir().join(format!(
        "arthrosim_gap_bench_{}_{}",
        std::process::id(),
        seed
    ));
    // a pair as `tilt+support`
    let effects: Vec<&str> = effect.split('+').collect();
    let mut spec = RealitySpec::from_effects(&effects, seed)?;
    if let Some(m) = mesh {
        spec.mesh = m.to_string();
    }
    // The bench times the diagnosis, whose work does not depend on how the truth was made;
    // a refined truth of a ~1,400-node specimen is ~10,000 nodes solved directly, minutes of
    // generation for nothing measured.
    spec.truth_mesh = TruthMesh::Replay;
    let host = msgs::host_load::HostLoad::start();
    let t0 = std::time::Instant::now();
    let truth =
        super::reality::write_experiment(&spec, &root.join("exp"), &root.join("truth.json"))?;
    let generate_s = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    let report = super::diagnose_dir(&root.join("exp"), opts)?;
    let diagnose_s = t1.elapsed().as_secs_f64();
    let host = host.finish();
    let data_dir = super::data_dir();
    let nodes =
        SimForceModel::for_experiment(&load_experiment(&root.join("exp"), &data_dir)?, &data_dir)?
            .simulation(&Variant::default(), opts.dt)?
            .node_count();
    let _ = std::fs::remove_dir_all(&root);
    Ok(serde_json::json!({
        "bench": "gap_diagnose",
        "trials": report.trials,
        "samples": report.samples,
        "threads": rayon::current_num_threads(),
        "specimen": spec.mesh,
        "specimen_nodes": nodes,
        "hertz_patch": opts.hertz_patch,
        "generate_s": generate_s,
        "diagnose_s": diagnose_s,
        "replays_s": report.stages.map(|s| s.replays_s),
        "centres_s": report.stages.map(|s| s.centres_s),
        "fits_s": report.stages.map(|s| s.fits_s),
        // the time is almost all replays: how many each stage made
        "replays": report.stages.map(|s| s.replays),
        "centre_replays": report.stages.map(|s| s.centre_replays),
        "truth": spec.label(),
        // the injected strengths and the fitted ones, so a reader sees how near the fit came
        "injected": spec.injected,
        // probings the truth's physics flagged as faulty, drawn again elsewhere
        "redrawn": truth.redrawn,
        "verdict": report.verdict.effect,
        "fitted": report
            .verdict
            .params
            .iter()
            .map(|p| (format!("{}.{}", p.effect, p.name), p.value))
            .collect::<std::collections::BTreeMap<_, _>>(),
        "heldout_shrink": report.verdict.heldout_shrink,
        "loadavg_1m_before": host.loadavg_1m_before,
        "loadavg_1m_after": host.loadavg_1m_after,
        "host_steal_fraction": host.host_steal_fraction,
    }))
}
