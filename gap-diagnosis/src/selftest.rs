//! `gap selftest`: generated cases (each effect alone, some pairs, none) diagnosed blind.
use super::experiment::load_experiment;
use super::model::ForceModel;
use super::reality::{truth_model, write_experiment_with, Fidelity, RealitySpec, Site};
use super::sim_model::SimForceModel;
use super::{diagnose, GapError, Options};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// The case cycle of the `Reality` fidelity: none (twice: the stiffness offset alone is the
/// commonest real case), every effect but `mesh` alone (the truth is always on a refined
/// mesh), then the pairs of the hidden sets.
pub const REALITY_CASES: [&str; 18] = [
    "none",
    "modulus",
    "hardening",
    "viscoelastic",
    "friction",
    "tilt",
    "device",
    "support",
    "sensor",
    "none",
    "modulus+sensor",
    "modulus+friction",
    "hardening+friction",
    "hardening+viscoelastic",
    "support+device",
    "support+tilt",
    "friction+device",
    "viscoelastic+tilt",
];

/// The case cycle of the `SelfConsistent` fidelity: none, every effect alone, then pairs.
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
    /// Restrict the case cycle (labels as in [`REALITY_CASES`] / [`CASES`]).
    pub cases: Option<Vec<String>>,
    /// How the truth departs from the replay model.
    pub fidelity: Fidelity,
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
            fidelity: Fidelity::default(),
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CaseResult {
    pub case: usize,
    pub truth: String,
    pub found: String,
    pub correct: bool,
    /// Held-out shrink the diagnosis reports for its verdict.
    pub heldout_shrink: f64,
    /// Held-out shrink of the true candidate (None for `none` or when not ranked).
    pub true_candidate_shrink: Option<f64>,
    /// The truth's systematic stiffness offset (1: none).
    #[serde(default)]
    pub stiffness_offset: f64,
    /// Candidates the verdict could not tell apart (empty: none).
    #[serde(default)]
    pub indistinguishable: Vec<String>,
    pub elapsed_s: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SelftestResult {
    pub seed: u64,
    pub cases: Vec<CaseResult>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SelftestSummary {
    pub cases: usize,
    pub correct: usize,
    pub accuracy: f64,
    /// Mean held-out shrink of the verdicts over cases with an injected effect.
    pub heldout_shrink_mean: f64,
    pub seed: u64,
    pub elapsed_s: f64,
}

impl SelftestResult {
    pub fn summary(&self) -> SelftestSummary {
        let correct = self.cases.iter().filter(|c| c.correct).count();
        let eff: Vec<&CaseResult> = self.cases.iter().filter(|c| c.truth != "none").collect();
        SelftestSummary {
            cases: self.cases.len(),
            correct,
            accuracy: correct as f64 / self.cases.len().max(1) as f64,
            heldout_shrink_mean: eff.iter().map(|c| c.heldout_shrink).sum::<f64>()
                / eff.len().max(1) as f64,
            seed: self.seed,
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
                "case {:3}  truth {:20} found {:20} {}  held-out shrink {:5.1}%  stiffness ×{:.3}{}  ({:.1} s)",
                c.case,
                c.truth,
                c.found,
                if c.correct { "ok " } else { "MISS" },
                100.0 * c.heldout_shrink,
                c.stiffness_offset,
                if c.indistinguishable.len() > 1 {
                    format!("  indistinguishable: {}", c.indistinguishable.join(" ~ "))
                } else {
                    String::new()
                },
                c.elapsed_s
            );
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
            "\n{}/{} correct ({:.0}%), mean held-out shrink {:.1}%",
            sm.correct,
            sm.cases,
            100.0 * sm.accuracy,
            100.0 * sm.heldout_shrink_mean
        );
        s
    }
}

/// Labels of the first `n` cases.
pub fn case_labels(n: usize, opts: &SelftestOptions) -> Vec<String> {
    let default: &[&str] = match opts.fidelity {
        Fidelity::Reality => &REALITY_CASES,
        Fidelity::SelfConsistent => &CASES,
    };
    let cycle: Vec<String> = opts
        .cases
        .clone()
        .unwrap_or_else(|| default.iter().map(|s| s.to_string()).collect());
    (0..n).map(|i| cycle[i % cycle.len()].clone()).collect()
}

/// The shipped self-test: truth and diagnosis through the physics model; the truth per
/// case on the model its spec names ([`truth_model`]: at the `Reality` fidelity a refined
/// mesh and a ball tip).
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
    // the nominal match is a property of the two models, not of a case: computed once
    let match_cache = std::sync::Mutex::new(None::<f64>);
    let truth_for = |spec: &RealitySpec| -> Result<Box<dyn ForceModel>, GapError> {
        Ok(Box::new(truth_model(spec, &data)))
    };
    let nominal = |spec: &RealitySpec, truth: &dyn ForceModel| -> Result<f64, GapError> {
        if spec.fidelity != Fidelity::Reality {
            return Ok(1.0);
        }
        let mut c = match_cache.lock().unwrap();
        if let Some(v) = *c {
            return Ok(v);
        }
        let replay = super::reality::replay_model(spec, &data);
        let v = super::reality::nominal_match(truth, &replay, &sites, spec)?;
        *c = Some(v);
        Ok(v)
    };
    run_cases(cases, seed, opts, &truth_for, &nominal, &sites, &|exp| {
        SimForceModel::for_experiment(exp, &data).map(|m| Box::new(m) as Box<dyn ForceModel>)
    })
}

type ModelFor<'a> = dyn Fn(&super::Experiment) -> Result<Box<dyn ForceModel>, GapError> + 'a;
type TruthFor<'a> = dyn Fn(&RealitySpec) -> Result<Box<dyn ForceModel + 'a>, GapError> + 'a;

/// Self-test with a given truth model (every case) and a factory for the diagnosis model of
/// a folder.
pub fn selftest_with(
    cases: usize,
    seed: u64,
    opts: &SelftestOptions,
    truth_model: &dyn ForceModel,
    sites: &[Site],
    model_for: &ModelFor,
) -> Result<SelftestResult, GapError> {
    struct Borrowed<'a>(&'a dyn ForceModel);
    impl ForceModel for Borrowed<'_> {
        fn replay_untilted(
            &self,
            v: &super::model::Variant,
            p: &super::model::ProbePath,
        ) -> Result<Vec<[f64; 3]>, GapError> {
            self.0.replay_untilted(v, p)
        }
        fn replay_untilted_checked(
            &self,
            v: &super::model::Variant,
            p: &super::model::ProbePath,
        ) -> Result<super::model::Replayed, GapError> {
            self.0.replay_untilted_checked(v, p)
        }
        fn describe(&self) -> String {
            self.0.describe()
        }
        fn has_refinement(&self) -> bool {
            self.0.has_refinement()
        }
    }
    let truth_for = |_: &RealitySpec| -> Result<Box<dyn ForceModel + '_>, GapError> {
        Ok(Box::new(Borrowed(truth_model)))
    };
    // a given truth model is taken as it is (its nominal stiffness is the caller's)
    run_cases(
        cases,
        seed,
        opts,
        &truth_for,
        &|_, _| Ok(1.0),
        sites,
        model_for,
    )
}

fn run_cases(
    cases: usize,
    seed: u64,
    opts: &SelftestOptions,
    truth_for: &TruthFor,
    nominal: &dyn Fn(&RealitySpec, &dyn ForceModel) -> Result<f64, GapError>,
    sites: &[Site],
    model_for: &ModelFor,
) -> Result<SelftestResult, GapError> {
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
        let mut spec = RealitySpec::from_effects_with(&effects, case_seed, opts.fidelity)?;
        spec.probings_per_region = opts.probings_per_region;
        spec.noise_sigma = opts.noise_sigma;
        let dir = root.join(format!("case{i:03}"));
        let truth_file = root.join(format!("case{i:03}_truth.json"));
        let truth_model = truth_for(&spec)?;
        spec.nominal_match = nominal(&spec, truth_model.as_ref())?;
        let truth = write_experiment_with(&spec, truth_model.as_ref(), sites, &dir, &truth_file)?;
        let exp = load_experiment(&dir, &super::data_dir())?;
        let model = model_for(&exp)?;
        // A `Reality` truth is always on a refined mesh: offering `mesh` would name the
        // discretisation itself (the label says no effect). The study's own meshes have no
        // refinement either, so the hidden cases never offer it.
        let mut dopts = opts.diagnose.clone();
        if spec.fidelity == Fidelity::Reality {
            dopts.effects.retain(|&e| e != super::effects::Effect::Mesh);
        }
        let report = diagnose(&exp, model.as_ref(), &dopts)?;
        let found = report.verdict.effect.clone();
        let true_shrink = report
            .ranking
            .iter()
            .find(|c| c.effect == truth.label)
            .map(|c| c.heldout_shrink);
        let r = CaseResult {
            case: i,
            correct: found == truth.label,
            truth: truth.label,
            found,
            heldout_shrink: report.verdict.heldout_shrink,
            true_candidate_shrink: true_shrink,
            stiffness_offset: spec.stiffness_offset,
            indistinguishable: report.verdict.indistinguishable.clone(),
            elapsed_s: start.elapsed().as_secs_f64(),
        };
        if opts.verbose {
            eprintln!(
                "case {:3}  truth {:20} found {:20} {} shrink {:5.1}%  ({:.1} s)  {}",
                r.case,
                r.truth,
                r.found,
                if r.correct { "ok " } else { "MISS" },
                100.0 * r.heldout_shrink,
                r.elapsed_s,
                report.verdict.reason
            );
            for c in report.ranking.iter().take(6) {
                eprintln!(
                    "           {:24} held {:.4} shrink {:5.1}% score {:10.1}",
                    c.effect,
                    c.heldout_rmse,
                    100.0 * c.heldout_shrink,
                    c.score
                );
            }
        }
        out.push(r);
    }
    if opts.keep_dir.is_none() {
        let _ = std::fs::remove_dir_all(&root);
    }
    Ok(SelftestResult { seed, cases: out })
}

/// Benchmark: a generated 15-trial experiment (the study protocol) diagnosed end to end with
/// the physics model; returns the JSON line (`trials`, `diagnose_s`, `generate_s`, `verdict`).
pub fn bench(effect: &str, seed: u64, opts: &Options) -> Result<serde_json::Value, GapError> {
    let root = std::env::temp_dir().join(format!(
        "arthrosim_gap_bench_{}_{}",
        std::process::id(),
        seed
    ));
    let spec = RealitySpec::from_effects(&[effect], seed)?;
    let t0 = std::time::Instant::now();
    super::reality::write_experiment(&spec, &root.join("exp"), &root.join("truth.json"))?;
    let generate_s = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    let report = super::diagnose_dir(&root.join("exp"), opts)?;
    let diagnose_s = t1.elapsed().as_secs_f64();
    let _ = std::fs::remove_dir_all(&root);
    Ok(serde_json::json!({
        "bench": "gap_diagnose",
        "trials": report.trials,
        "samples": report.samples,
        "threads": rayon::current_num_threads(),
        "generate_s": generate_s,
        "diagnose_s": diagnose_s,
        "truth": spec.label(),
        "verdict": report.verdict.effect,
        "heldout_shrink": report.verdict.heldout_shrink,
    }))
}
