//! Development harness: re-diagnose kept self-test folders with the replays cached on disk
//! (`caseNNN_cache.json` beside each folder), so the statistics can be iterated on in seconds
//! instead of re-running the physics.
//! `cargo run --release -p gap-diagnosis --example gap_dev -- DIR [rediagnose|phase-table]`
//! (`DIR` is a `--keep` folder of `arthrosim gap selftest`; `GAP_DEV_CASES=case005,…`
//! restricts `rediagnose`; `phase-table` prints the held-out RMSE per phase). `rediagnose`
//! also reads folders an outside code wrote (`tools/independent_fe`, its `caseNNN_truth.json`
//! naming its effects), and grades their verdicts by name only.
//! `gap_dev DIR contact-layer-cases SEED [MESH]` writes, in the same layout, the hidden sets'
//! 18 cases (their single effects and pairs) with the same-mesh penalty-contact truth
//! (`reality::write_experiment_with_contact_layer`, 4 µm/N, the study's 5 probings per
//! region) on MESH (default `study:lateral`, the mesh the hidden cases were handed), seeds
//! SEED…SEED+17, to be diagnosed by `rediagnose`; `GAP_DEV_CASE_LIST=friction=0.18,none,…`
//! writes those cases instead (a strength after `=`, as `arthrosim reality --effect`).
//! `gap_dev DIR eval CANDIDATE θ…` scores one candidate at given parameters on the kept
//! cases (see [`eval_at`]); `GAP_DEV_TOP=N` prints N ranked candidates in `rediagnose`.
//! `GAP_DEV_TRUTH_PATCH=1` spreads `contact-layer-cases`' truth's balls over their anchored
//! Hertz patch (`patch_anchor`); `GAP_DEV_HERTZ_PATCH=anchor` (or a modulus scale) replays
//! `rediagnose`'s cases with the patch, cached apart.
//! `gap_dev DIR export-specimen [MESH [refined]]` writes MESH (default `study:lateral`) in the
//! diagnosis' specimen frame as `specimen.msh` and `specimen_fixed.txt`, for an outside code
//! (`tools/independent_fe`) to model the same specimen.
//! `gap_dev FRICTIONLESS friction-share FRICTIONAL MU` compares what friction adds in an outside
//! code with what it adds in the replay (see [`friction_share`]).
use anyhow::{bail, Context};
use gap_diagnosis::effects::Effect;
use gap_diagnosis::model::{ForceModel, ProbePath, Replayed, Variant};
use gap_diagnosis::{self as gap, GapError, SimForceModel};
use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

struct Cached<'a> {
    inner: &'a dyn ForceModel,
    map: Mutex<HashMap<u64, CachedReplay>>,
    dirty: Mutex<bool>,
}

/// A replay's forces and its faulty steps; `None` from a cache written before the faults
/// were kept, which is replayed again once (the diagnosis sets a faulty replay aside, and a
/// cache that answered 0 for every replay read tilts the CLI names as `none`).
type CachedReplay = (Vec<[f64; 3]>, Option<u64>);

fn key(v: &Variant, p: &ProbePath) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    // caches kept before the contact knot existed name variants without its field
    let name = format!("{v:?}");
    if v.interface_compliance == 0.0 {
        name.replace(", interface_compliance: 0.0", "").hash(&mut h);
    } else {
        name.hash(&mut h);
    }
    p.t0.to_bits().hash(&mut h);
    p.dt.to_bits().hash(&mut h);
    for q in &p.poses {
        for x in q.position.iter().chain(q.orientation.iter()) {
            x.to_bits().hash(&mut h);
        }
    }
    h.finish()
}

impl ForceModel for Cached<'_> {
    fn replay_untilted(&self, v: &Variant, p: &ProbePath) -> Result<Vec<[f64; 3]>, GapError> {
        self.replay_untilted_checked(v, p).map(|r| r.forces)
    }
    fn replay_untilted_checked(&self, v: &Variant, p: &ProbePath) -> Result<Replayed, GapError> {
        let k = key(v, p);
        if let Some((forces, Some(faulty_steps))) = self.map.lock().unwrap().get(&k) {
            return Ok(Replayed {
                forces: forces.clone(),
                faulty_steps: *faulty_steps,
            });
        }
        let r = self.inner.replay_untilted_checked(v, p)?;
        self.map
            .lock()
            .unwrap()
            .insert(k, (r.forces.clone(), Some(r.faulty_steps)));
        *self.dirty.lock().unwrap() = true;
        Ok(r)
    }
    fn describe(&self) -> String {
        self.inner.describe()
    }
    fn has_refinement(&self) -> bool {
        self.inner.has_refinement()
    }
    fn support_scale(&self) -> f64 {
        self.inner.support_scale()
    }
}

/// The cache at `p`: entries with their faulty steps, or (written before those were kept)
/// without them.
fn load_cache(p: &Path) -> HashMap<u64, CachedReplay> {
    let Ok(text) = std::fs::read_to_string(p) else {
        return HashMap::new();
    };
    if let Ok(v) = serde_json::from_str::<Vec<(u64, Vec<[f64; 3]>, u64)>>(&text) {
        return v.into_iter().map(|(k, f, n)| (k, (f, Some(n)))).collect();
    }
    serde_json::from_str::<Vec<(u64, Vec<[f64; 3]>)>>(&text)
        .map(|v| v.into_iter().map(|(k, f)| (k, (f, None))).collect())
        .unwrap_or_default()
}

/// Writes `map` to `p` with every entry's faulty steps (entries never replayed again stay
/// out: they are replayed on the next run).
fn save_cache(p: &Path, map: HashMap<u64, CachedReplay>) -> anyhow::Result<()> {
    let v: Vec<(u64, Vec<[f64; 3]>, u64)> = map
        .into_iter()
        .filter_map(|(k, (f, n))| n.map(|n| (k, f, n)))
        .collect();
    std::fs::write(p, serde_json::to_string(&v)?)
        .with_context(|| format!("writing {}", p.display()))
}

/// One kept case folder: its name, ground truth, experiment, physics model and replay cache.
struct Case {
    name: String,
    truth: serde_json::Value,
    exp: gap::Experiment,
    sim: SimForceModel,
    cache_file: PathBuf,
}

impl Case {
    fn open(root: &Path, dir: &Path, data: &Path) -> anyhow::Result<Case> {
        let name = dir.file_name().unwrap().to_string_lossy().to_string();
        let truth_file = root.join(format!("{name}_truth.json"));
        let truth: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(&truth_file)
                .with_context(|| format!("reading {}", truth_file.display()))?,
        )?;
        let exp = gap::load_experiment(dir, data)?;
        let mut sim = SimForceModel::for_experiment(&exp, data)?;
        // GAP_DEV_HERTZ_PATCH=S: the replay's probe balls spread over their Hertz patch
        // (`[scene.contact] hertz_patch`), the tissue's modulus scaled by S (1: as it is;
        // `anchor`: by `patch_anchor::anchor`); its replays are cached apart
        let patch = match std::env::var("GAP_DEV_HERTZ_PATCH").as_deref() {
            Ok("anchor") => {
                let a = gap::patch_anchor::anchored_patch(&sim)?;
                eprintln!("{name}: Hertz patch anchored at x{:.4}", a.scale);
                sim = a.model;
                "_patch_anchored".to_string()
            }
            Ok(s) => {
                let scale: f64 = s.parse().context("GAP_DEV_HERTZ_PATCH: a modulus scale")?;
                sim.scene.contact.hertz_patch = true;
                sim.scene.material.modulus_scale *= scale;
                if scale == 1.0 {
                    "_patch".to_string()
                } else {
                    format!("_patch{scale}")
                }
            }
            Err(_) => String::new(),
        };
        let cache_file = root.join(format!("{name}{patch}_cache.json"));
        Ok(Case {
            name,
            truth,
            exp,
            sim,
            cache_file,
        })
    }

    /// The default diagnosis' candidate effects, and the trials with every replay it makes
    /// (at 0.02 s), through `model`.
    fn dataset(
        &self,
        model: &dyn ForceModel,
    ) -> anyhow::Result<(Vec<Effect>, Vec<gap_diagnosis::dataset::TrialData>)> {
        let opts = gap::Options {
            centres: std::env::var_os("GAP_DEV_NO_CENTRES").is_none(),
            ..gap::Options::default()
        };
        let effects = gap::candidate_effects(&self.exp, model, &opts);
        let td = gap::prepare_dataset(&self.exp, model, &effects, &opts)?;
        Ok((effects, td))
    }

    /// The physics model behind the on-disk replay cache.
    fn cached_model(&self) -> Cached<'_> {
        Cached {
            inner: &self.sim,
            map: Mutex::new(load_cache(&self.cache_file)),
            dirty: Mutex::new(false),
        }
    }
}

/// The kept case folders under `root`, sorted.
fn case_dirs(root: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(root)
        .with_context(|| format!("reading {}", root.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    Ok(dirs)
}

fn rediagnose_kept_cases(root: &Path) -> anyhow::Result<()> {
    let only: Option<Vec<String>> = std::env::var("GAP_DEV_CASES")
        .ok()
        .map(|s| s.split(',').map(|x| x.to_string()).collect());
    let dirs = case_dirs(root)?;
    let data = gap::data_dir();
    let (mut ok, mut n, mut shrink, mut neff) = (0, 0, 0.0, 0);
    let (mut graded, mut within) = (0, 0);
    let t_all = std::time::Instant::now();
    for dir in dirs {
        let name = dir.file_name().unwrap().to_string_lossy().to_string();
        if let Some(o) = &only {
            if !o.iter().any(|x| name.ends_with(x.as_str())) {
                continue;
            }
        }
        let case = Case::open(root, &dir, &data)?;
        let (exp, truth, cache_file) = (&case.exp, &case.truth, &case.cache_file);
        // an outside code's truth lists its effects by name (`none` when it has none)
        let label = match (truth["label"].as_str(), truth["effects"].as_object()) {
            (Some(l), _) => l.to_string(),
            (None, Some(e)) if e.is_empty() => "none".to_string(),
            (None, Some(e)) => e.keys().cloned().collect::<Vec<_>>().join("+"),
            (None, None) => "?".to_string(),
        };
        let model = case.cached_model();
        let t0 = std::time::Instant::now();
        // GAP_DEV_NO_CONTACT=1: without the contact nuisance
        let opts = gap::Options {
            contact_nuisance: std::env::var_os("GAP_DEV_NO_CONTACT").is_none(),
            // GAP_DEV_NO_MATERIAL=1: without the material nuisance
            material_nuisance: std::env::var_os("GAP_DEV_NO_MATERIAL").is_none(),
            centres: std::env::var_os("GAP_DEV_NO_CENTRES").is_none(),
            // GAP_DEV_LEVEL_BAND=0.69,1.15: another level band for the nuisances
            level_band: match std::env::var("GAP_DEV_LEVEL_BAND") {
                Ok(v) => gap::Options::parse_level_band(&v).context("GAP_DEV_LEVEL_BAND")?,
                Err(_) => gap::Options::default().level_band,
            },
            ..gap::Options::default()
        };
        let r = gap::diagnose(exp, &model, &opts)?;
        let el = t0.elapsed().as_secs_f64();
        if *model.dirty.lock().unwrap() {
            save_cache(cache_file, model.map.into_inner().unwrap())?;
        }
        n += 1;
        // a pair's order is the diagnosis' own
        let names = |e: &str| {
            let mut v: Vec<String> = e.split('+').map(str::to_string).collect();
            v.sort();
            v
        };
        let good = names(&r.verdict.effect) == names(&label);
        ok += good as usize;
        if label != "none" {
            shrink += r.verdict.heldout_shrink;
            neff += 1;
        }
        eprintln!(
            "{name} truth {label:20} found {:20} {} shrink {:5.1}% noise {:.4} r0 {:.4} ({el:.1} s)\n    {}",
            r.verdict.effect,
            if good { "ok  " } else { "MISS" },
            100.0 * r.verdict.heldout_shrink,
            r.noise_sigma,
            r.heldout.baseline_rmse,
            r.verdict.reason
        );
        if !r.centres.is_empty() {
            eprintln!("    centres: {:?}", r.centres);
        }
        if !r.diverged_replays.is_empty() {
            eprintln!("    diverged: {:?}", r.diverged_replays);
        }
        // an outside code's truth (`tools/independent_fe`) names its effects in its own terms,
        // which `recovery` does not grade
        let injected: Vec<gap::reality::Injected> = match &truth["spec"]["injected"] {
            serde_json::Value::Null => {
                eprintln!("    truth effects (outside code): {}", truth["effects"]);
                Vec::new()
            }
            listed => {
                eprintln!("    truth params: {listed}");
                serde_json::from_value(listed.clone())?
            }
        };
        // The parameter goal, graded as `gap selftest` grades it (these truths apply
        // their support as injected: no levelling).
        for g in gap::recovery::recovery(&injected, &r.verdict.params) {
            graded += 1;
            within += g.within_tolerance() as usize;
            eprintln!("    recovery {g}");
        }
        eprintln!(
            "    verdict params: {} (level {}; stiffness {:?}, contact {:?} m/N, material {:?})",
            r.verdict
                .params
                .iter()
                .map(|p| format!("{}={:.4e}", p.name, p.value))
                .collect::<Vec<_>>()
                .join(" "),
            r.verdict
                .level
                .map_or("none".to_string(), |l| format!("{l:.4}"))
                + &r.heldout
                    .measured_level
                    .zip(r.heldout.measured_level_se)
                    .map(|(l, se)| format!(", measured {l:.4} ± {se:.4}"))
                    .unwrap_or_default(),
            r.verdict.nuisance_scale,
            r.verdict.contact_compliance,
            r.verdict.material_weight,
        );
        // GAP_DEV_TOP=N: how many ranked candidates to print (10)
        let top = std::env::var("GAP_DEV_TOP")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(10);
        for c in r.ranking.iter().take(top) {
            eprintln!(
                "    {:24} held {:.4} shrink {:6.1}% w {:.4} {:6.1}% dBIC {:9.1} score {:9.1} fz {:5.1}{} {}",
                c.effect,
                c.heldout_rmse,
                100.0 * c.heldout_shrink,
                c.heldout_weighted_rmse,
                100.0 * c.heldout_weighted_shrink,
                c.delta_bic,
                c.score,
                c.floor_gain_z,
                c.stiffness_gain_z
                    .map(|z| format!(" z {z:.2}"))
                    .unwrap_or_default()
                    + &c.sensor_gain_z
                        .map(|z| format!(" zs {z:.2}"))
                        .unwrap_or_default()
                    + &c.nuisance_scale
                        .map(|s| format!(" nu {s:.3}"))
                        .unwrap_or_default()
                    + &c.contact_compliance
                        .map(|w| format!(" cc {:.1}", 1e6 * w))
                        .unwrap_or_default()
                    + &c.level.map(|l| format!(" lvl {l:.3}")).unwrap_or_default()
                    + &format!(" fs {:.1}%", 100.0 * c.floor_shrink),
                c.params
                    .iter()
                    .map(|p| format!("{}={:.4e}", p.name, p.value))
                    .collect::<Vec<_>>()
                    .join(" ")
            );
        }
    }
    eprintln!(
        "{ok}/{n} correct, mean shrink {:.1}%, fitted strengths within 15% {within}/{graded} ({:.1} s)",
        100.0 * shrink / neff.max(1) as f64,
        t_all.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Per-phase held-out RMSE of the ranked candidates (pair-rule design).
fn phase_table(root: &Path) -> anyhow::Result<()> {
    use gap_diagnosis::metrics::Phase;
    let dirs = case_dirs(root)?;
    let data = gap::data_dir();
    let only = std::env::var("GAP_DEV_CASES").unwrap_or_default();
    for dir in dirs {
        if !dir.to_string_lossy().ends_with(only.as_str()) {
            continue;
        }
        let case = Case::open(root, &dir, &data)?;
        let (name, truth) = (&case.name, &case.truth);
        let model = case.cached_model();
        let (effects, td) = case.dataset(&model)?;
        let r = gap::diagnose_data(
            name.clone(),
            String::new(),
            &td,
            &effects,
            &gap::Options::default(),
            std::time::Instant::now(),
        )?;
        eprintln!(
            "{name} truth {} found {}",
            truth["label"].as_str().unwrap_or("?"),
            r.verdict.effect
        );
        let row = |label: &str, pred: &dyn Fn(usize) -> Vec<[f64; 3]>| {
            let mut s = [(0.0, 0usize); 5];
            for (i, d) in td.iter().enumerate() {
                let p = pred(i);
                for j in 0..d.t.len() {
                    let g = Phase::ALL.iter().position(|x| *x == d.phase[j]).unwrap();
                    for k in 0..3 {
                        s[g].0 += (p[j][k] - d.f[j][k]).powi(2);
                        s[g].1 += 1;
                    }
                }
            }
            eprintln!(
                "    {label:24} {}",
                s.iter()
                    .zip(Phase::ALL)
                    .map(|((a, n), ph)| format!(
                        "{}:{:8.4}({:4})",
                        &ph.name()[..4],
                        (a / (*n).max(1) as f64).sqrt(),
                        n
                    ))
                    .collect::<Vec<_>>()
                    .join(" ")
            );
        };
        row("baseline", &|i| td[i].base_at_t.clone());
        for c in r.ranking.iter().take(8) {
            row(&c.effect, &|i| c.heldout_pred[i].clone());
        }
    }
    Ok(())
}

/// The hidden sets' cases (issue 15): each single effect, then the second set's pairs.
const HIDDEN_LIKE_CASES: [&str; 18] = [
    "none",
    "modulus",
    "hardening",
    "support",
    "tilt",
    "friction",
    "device",
    "sensor",
    "viscoelastic",
    "none",
    "friction",
    "sensor",
    "modulus+sensor",
    "modulus+friction",
    "hardening+friction",
    "hardening+viscoelastic",
    "support+device",
    "support+tilt",
];

fn write_contact_layer_cases(root: &Path, seed0: u64, mesh: &str) -> anyhow::Result<()> {
    std::fs::create_dir_all(root)?;
    // GAP_DEV_CASE_LIST=a,b+c=0.3,…: other cases than the hidden sets' (an effect's strength
    // after `=`, as `arthrosim reality --effect` takes it)
    let listed = std::env::var("GAP_DEV_CASE_LIST").ok();
    let cases: Vec<&str> = match &listed {
        Some(l) => l.split(',').map(str::trim).collect(),
        None => HIDDEN_LIKE_CASES.to_vec(),
    };
    for (i, case) in cases.iter().enumerate() {
        // `none` is read as no effect
        let effects: Vec<&str> = case.split('+').collect();
        let mut spec = gap::reality::RealitySpec::from_effects(&effects, seed0 + i as u64)?;
        spec.mesh = mesh.to_string();
        let name = format!("case{i:03}");
        let t0 = std::time::Instant::now();
        if std::env::var_os("GAP_DEV_TRUTH_PATCH").is_some() {
            // GAP_DEV_TRUTH_PATCH=1: the truth's balls spread over their Hertz patch, anchored
            // at the closest points' level (`patch_anchor`), beside the same 4 µm/N layer
            let scene = gap::reality::specimen_scene(&spec);
            let replay = SimForceModel::from_scene(scene, &gap::data_dir());
            let mut truth = gap::patch_anchor::anchored_patch(&replay)?.model;
            truth.scene.contact.interface_compliance = 4e-6;
            gap::reality::write_experiment_with(
                &spec,
                &truth,
                &replay.sites()?,
                &root.join(&name),
                &root.join(format!("{name}_truth.json")),
            )?;
        } else {
            gap::reality::write_experiment_with_contact_layer(
                &spec,
                4e-6,
                &root.join(&name),
                &root.join(format!("{name}_truth.json")),
            )?;
        }
        eprintln!(
            "{name} {} (×{:.3}) written in {:.1} s",
            spec.label(),
            spec.stiffness_scale,
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// Writes MESH's specimen files into DIR ([`gap::reality::export_specimen`]).
fn export_specimen(root: &Path, mesh: &str, refined: bool) -> anyhow::Result<()> {
    let files = gap::reality::export_specimen(mesh, root, refined)?;
    eprintln!(
        "{mesh}{}: {} nodes, {} tets, written to {} and {}",
        if refined { " refined once" } else { "" },
        files.nodes,
        files.tets,
        files.msh.display(),
        files.fixed.display()
    );
    Ok(())
}

/// One candidate at given parameters, `θ` as `a,b,…` in the candidate's order: the RMSE,
/// phase-weighted RMSE, the likelihood's Σ n ln(MSE) and the RMS per variance group (free,
/// near contact, loading, hold, unloading, sliding), at the nuisance `GAP_DEV_NUISANCE=s,w`
/// (scale, contact weight; default `1,0`). With `GAP_DEV_FOLDS=1`, each held-out fold's own
/// fit, with and without the nuisances, first.
fn eval_at(root: &Path, cand: &str, thetas: &[String]) -> anyhow::Result<()> {
    use gap_diagnosis::effects::Candidate;
    use gap_diagnosis::fit::{self, Nuisance, NuisanceFit, PhaseSse};
    let numbers = |s: &str| -> anyhow::Result<Vec<f64>> {
        s.split(',')
            .map(|x| {
                x.parse::<f64>()
                    .with_context(|| format!("number {x:?} in {s:?}"))
            })
            .collect()
    };
    let c = Candidate(
        cand.split('+')
            .map(|e| Effect::parse(e).with_context(|| format!("unknown effect {e:?}")))
            .collect::<anyhow::Result<_>>()?,
    );
    let thetas: Vec<Vec<f64>> = thetas
        .iter()
        .map(|t| numbers(t))
        .collect::<anyhow::Result<_>>()?;
    let np = c.params().len();
    if let Some(t) = thetas.iter().find(|t| t.len() != np) {
        bail!("{cand} has {np} parameters, θ {t:?} gives {}", t.len());
    }
    let nu = match numbers(&std::env::var("GAP_DEV_NUISANCE").unwrap_or("1,0".into()))?[..] {
        [stiffness, contact] => NuisanceFit {
            stiffness,
            contact,
            material: 0.0,
        },
        [stiffness, contact, material] => NuisanceFit {
            stiffness,
            contact,
            material,
        },
        _ => bail!("GAP_DEV_NUISANCE is `scale,contact_weight[,material_weight]`"),
    };
    let show = |acc: &PhaseSse| {
        let groups: Vec<String> = acc
            .group_mse()
            .iter()
            .map(|m| format!("{:.3}", m.sqrt()))
            .collect();
        format!(
            "rmse {:.4} weighted {:.4} Σn·ln(mse) {:.1} per group [{}]",
            acc.rmse(),
            acc.weighted_rmse(),
            acc.log_mse_sum(acc.total().1 as f64),
            groups.join(", ")
        )
    };
    let folds_too = std::env::var_os("GAP_DEV_FOLDS").is_some();
    let only = std::env::var("GAP_DEV_CASES").unwrap_or_default();
    let data = gap::data_dir();
    for dir in case_dirs(root)? {
        if !dir.to_string_lossy().ends_with(only.as_str()) {
            continue;
        }
        let case = Case::open(root, &dir, &data)?;
        let model = case.cached_model();
        let opts = gap::Options::default();
        let (_, td) = case.dataset(&model)?;
        if folds_too {
            let (_, folds) = fit::make_folds(&td);
            let band = opts.nuisance_band().for_candidate(&c).for_data(&td);
            let free = fit::default_free(&c);
            for f in &folds {
                for (label, nb) in [("with nuisances", band), ("without", Nuisance::OFF)] {
                    let ff = fit::fit(&c, &td, &f.calib, &[], &free, nb);
                    let calib = fit::phase_sse(&c, &ff.theta, ff.nuisance, &td, &f.calib);
                    let held = fit::phase_sse(&c, &ff.theta, ff.nuisance, &td, &f.held);
                    eprintln!(
                        "{} fold {} {label}: θ {:.3?} nuisance ×{:.3} w {:.2}\n    calib {}\n    held  {}",
                        case.name,
                        f.label,
                        ff.theta,
                        ff.nuisance.stiffness,
                        ff.nuisance.contact,
                        show(&calib),
                        show(&held)
                    );
                }
            }
        }
        let all: Vec<Vec<bool>> = td.iter().map(|d| vec![true; d.t.len()]).collect();
        for theta in &thetas {
            let acc = fit::phase_sse(&c, theta, nu, &td, &all);
            eprintln!("{} {cand} θ {theta:?}: {}", case.name, show(&acc));
        }
    }
    Ok(())
}

/// What friction adds, in an outside code and in the replay, on the same probings.
///
/// `frictionless` and `frictional` are one experiment's folders written by an outside code
/// from the same poses (and the same sensor noise), without and with friction μ. Per trial,
/// over the samples in contact: the mean of |F_μ − F_0| / |F_0|, and, where the probe moves,
/// the mean of (F_μ − F_0)·v̂ / |F_0| along its motion v̂ (negative: friction resists). The
/// replay's two figures come from its own replays of the trial at μ and at 0, on the
/// frictionless folder's specimen and probe. If the replay's friction adds what the outside
/// code's adds, the two columns agree; a fit of μ scales the replay's column to the outside
/// one's, so their ratio is what a fitted μ is short by.
///
/// It also audits the work each code's forces do over the trial (the probe starts and ends
/// out of contact): without friction an elastic contact returns it all, and friction adds
/// what it dissipates (`signal::net_work`; the replay is held to both in `tests/gap_work.rs`).
fn friction_share(frictionless: &Path, frictional: &Path, mu: f64) -> anyhow::Result<()> {
    let data = gap::data_dir();
    let plain = gap::experiment::load_experiment(frictionless, &data)?;
    let rough = gap::experiment::load_experiment(frictional, &data)?;
    let model = SimForceModel::for_experiment(&plain, &data)?;
    let dt = gap::Options::default().dt;
    use gap::signal::{dot, net_work, norm, sub as diff};
    let mut totals = [0.0; 4];
    // net work without friction and what friction adds, outside and in the replay; then the
    // scales Σ|F||dx| of the two
    let mut work = [0.0; 6];
    let (mut trials, mut sliding) = (0usize, 0usize);
    println!("trial: mean |ΔF|/|F| outside, replay; along the motion outside, replay");
    for t0 in &plain.trials {
        let t1 = rough
            .trials
            .iter()
            .find(|t| t.name == t0.name && t.t == t0.t)
            .with_context(|| {
                format!(
                    "{}: no trial {} at the same times",
                    frictional.display(),
                    t0.name
                )
            })?;
        let path = gap::dataset::grid_path(t0, dt);
        let at = |forces: &[[f64; 3]], t: f64| -> [f64; 3] {
            let k = ((t - path.t0) / dt)
                .round()
                .clamp(0.0, (forces.len() - 1) as f64) as usize;
            forces[k]
        };
        let replay = |m: f64| {
            let v = Variant {
                friction: m,
                ..Variant::default()
            };
            model.replay_untilted(&v, &path)
        };
        let (r0, r1) = (replay(0.0)?, replay(mu)?);
        let poses: Vec<[f64; 3]> = t0.pose.iter().map(|p| p.position).collect();
        let grid: Vec<[f64; 3]> = path.poses.iter().map(|p| p.position).collect();
        let (w0, scale) = net_work(&poses, &t0.force);
        let (w1, _) = net_work(&poses, &t1.force);
        let (v0, replay_scale) = net_work(&grid, &r0);
        let (v1, _) = net_work(&grid, &r1);
        work[0] += w0;
        work[1] += w1 - w0;
        work[2] += v0;
        work[3] += v1 - v0;
        work[4] += scale;
        work[5] += replay_scale;
        let (mut share, mut along) = ([0.0; 2], [0.0; 2]);
        let (mut n, mut moving) = (0usize, 0usize);
        for i in 1..t0.t.len() {
            let (f0, f1) = (t0.force[i], t1.force[i]);
            let (g0, g1) = (at(&r0, t0.t[i]), at(&r1, t0.t[i]));
            // in contact in both codes, well above the sensor's noise
            if norm(f0) < 1.0 || norm(g0) < 1.0 {
                continue;
            }
            n += 1;
            share[0] += norm(diff(f1, f0)) / norm(f0);
            share[1] += norm(diff(g1, g0)) / norm(g0);
            let step = diff(t0.pose[i].position, t0.pose[i - 1].position);
            let speed = norm(step) / (t0.t[i] - t0.t[i - 1]);
            // a hold is not a motion: 0.1 mm/s against the protocol's 1–3 mm/s
            if speed > 1e-4 {
                let unit = step.map(|x| x / norm(step));
                moving += 1;
                along[0] += dot(diff(f1, f0), unit) / norm(f0);
                along[1] += dot(diff(g1, g0), unit) / norm(g0);
            }
        }
        if n == 0 {
            println!("{}: no sample in contact", t0.name);
            continue;
        }
        let m = moving.max(1) as f64;
        println!(
            "{}: {:.3} {:.3}; {:+.3} {:+.3}; frictionless net work {:+.2} mJ of {:.1} (replay \
             {:+.2} of {:.1}); friction adds {:+.2} mJ (replay {:+.2})",
            t0.name,
            share[0] / n as f64,
            share[1] / n as f64,
            along[0] / m,
            along[1] / m,
            w0 * 1e3,
            scale * 1e3,
            v0 * 1e3,
            replay_scale * 1e3,
            (w1 - w0) * 1e3,
            (v1 - v0) * 1e3
        );
        trials += 1;
        totals[0] += share[0] / n as f64;
        totals[1] += share[1] / n as f64;
        // a slide is a trial whose friction resists its motion by more than 1% in either code
        if along[0] / m < -0.01 || along[1] / m < -0.01 {
            sliding += 1;
            totals[2] += along[0] / m;
            totals[3] += along[1] / m;
        }
    }
    let (nt, ns) = (trials.max(1) as f64, sliding.max(1) as f64);
    println!(
        "{trials} trials: |ΔF|/|F| outside {:.3}, replay {:.3} (×{:.2}); {sliding} sliding: along the motion outside {:+.3}, replay {:+.3} (×{:.2})",
        totals[0] / nt,
        totals[1] / nt,
        totals[1] / totals[0],
        totals[2] / ns,
        totals[3] / ns,
        totals[3] / totals[2]
    );
    println!(
        "work: frictionless outside {:+.1} mJ of Σ|F||dx| {:.1} mJ, replay {:+.1} of {:.1}; \
         friction adds outside {:+.1} mJ, replay {:+.1} mJ",
        work[0] * 1e3,
        work[4] * 1e3,
        work[2] * 1e3,
        work[5] * 1e3,
        work[1] * 1e3,
        work[3] * 1e3
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(root) = args.first() else {
        bail!("usage: gap_dev DIR [rediagnose|phase-table]");
    };
    let root = PathBuf::from(root);
    match args.get(1).map(String::as_str) {
        None | Some("rediagnose") => rediagnose_kept_cases(&root),
        Some("phase-table") => phase_table(&root),
        Some("contact-layer-cases") => {
            let seed = args.get(2).map_or(Ok(200), |s| s.parse::<u64>())?;
            let mesh = args.get(3).map_or("study:lateral", String::as_str);
            write_contact_layer_cases(&root, seed, mesh)
        }
        Some("eval") if args.len() >= 3 => eval_at(&root, &args[2], &args[3..]),
        Some("friction-share") if args.len() == 4 => {
            let mu = args[3]
                .parse::<f64>()
                .with_context(|| format!("μ {:?} is not a number", args[3]))?;
            friction_share(&root, Path::new(&args[2]), mu)
        }
        Some("export-specimen") => {
            let mesh = args.get(2).map_or("study:lateral", String::as_str);
            export_specimen(
                &root,
                mesh,
                args.get(3).map(String::as_str) == Some("refined"),
            )
        }
        Some(other) => bail!(
            "unknown mode {other:?} (expected rediagnose, phase-table, contact-layer-cases, \
             export-specimen [MESH [refined]], eval CANDIDATE θ… or friction-share DIR μ)"
        ),
    }
}
