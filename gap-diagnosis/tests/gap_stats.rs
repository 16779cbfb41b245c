//! Statistics of the gap diagnosis against an analytic stand-in force model (Hertz contact on
//! the tangent plane of the nearest probing site). The stand-in exists only here, to test
//! fitting, cross-validation and the verdict independently of the FE model.
use gap_diagnosis::model::{ForceModel, ProbePath, Variant};
use gap_diagnosis::reality::Site;
use gap_diagnosis::reality::{write_experiment_with, RealitySpec, TruthMesh};
use gap_diagnosis::selftest::{selftest_with, SelftestOptions};
use gap_diagnosis::{diagnose, load_experiment, Experiment, GapError, Options, Region};

/// What the offset self-test reaches (seed 3, 14 cases, the study's 0.5–1.2 mm presses):
/// 12/14 (0.857), mean held-out shrink 83.9% (README).
const ACCURACY_REACHED: f64 = 0.85;
const SHRINK_REACHED: f64 = 0.8;

struct Hertz {
    sites: Vec<Site>,
    e: f64,
    /// The Hertz sphere: the protocol's tip ball (`[scene.probe] tip_radius`).
    tip_radius: f64,
}

fn sites() -> Vec<Site> {
    let mut v = Vec::new();
    for (ri, r) in Region::ALL.into_iter().enumerate() {
        for j in 0..5 {
            let a = 0.6 + 1.0 * ri as f64 + 0.12 * j as f64;
            let (x, y) = (0.016 * a.cos(), 0.016 * a.sin());
            let tilt = 0.25 * (j as f64 - 2.0) / 2.0;
            let n = [tilt * a.cos(), tilt * a.sin(), 1.0];
            let m = (n[0] * n[0] + n[1] * n[1] + 1.0).sqrt();
            v.push(Site {
                region: r,
                point: [x, y, 0.005 + 0.001 * j as f64],
                normal: [n[0] / m, n[1] / m, n[2] / m],
            });
        }
    }
    v
}

impl Hertz {
    fn normal_force(&self, v: &Variant, delta: f64) -> f64 {
        let r = self.tip_radius;
        let es = self.e * v.modulus_scale / (1.0 - 0.29f64 * 0.29);
        let hertz = |d: f64| {
            if d <= 0.0 {
                return 0.0;
            }
            let mut f = 4.0 / 3.0 * es * r.sqrt() * d.powf(1.5);
            if v.neo_hookean {
                f *= 1.0 + 0.1 * d * 1e3;
            }
            if v.fine_mesh {
                f *= 0.9 * (1.0 + 0.05 * d * 1e3);
            }
            f
        };
        if v.support_stiffness > 0.0 {
            // series compliance of ~6 supporting nodes: solve F = hertz(δ − F c) by bisection
            let c = 1.0 / (6.0 * v.support_stiffness);
            let (mut lo, mut hi) = (0.0, hertz(delta));
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                if hertz(delta - mid * c) > mid {
                    lo = mid
                } else {
                    hi = mid
                }
            }
            0.5 * (lo + hi)
        } else {
            hertz(delta)
        }
    }
}

impl ForceModel for Hertz {
    fn replay_untilted(&self, v: &Variant, path: &ProbePath) -> Result<Vec<[f64; 3]>, GapError> {
        let mut out = Vec::with_capacity(path.poses.len());
        for (k, pose) in path.poses.iter().enumerate() {
            let p = pose.position;
            let s = self
                .sites
                .iter()
                .min_by(|a, b| {
                    let da = (a.point[0] - p[0]).powi(2) + (a.point[1] - p[1]).powi(2);
                    let db = (b.point[0] - p[0]).powi(2) + (b.point[1] - p[1]).powi(2);
                    da.total_cmp(&db)
                })
                .unwrap();
            let n = s.normal;
            // the pose is the tip ball's centre, which the protocol keeps a tip radius above
            // the surface at first touch (measured from the centre, the study's 0.5–1.2 mm
            // presses never touched)
            let d = self.tip_radius
                - ((p[0] - s.point[0]) * n[0]
                    + (p[1] - s.point[1]) * n[1]
                    + (p[2] - s.point[2]) * n[2]);
            let fnorm = self.normal_force(v, d);
            let mut f = [fnorm * n[0], fnorm * n[1], fnorm * n[2]];
            if v.friction > 0.0 && fnorm > 0.0 && k > 0 {
                let q = path.poses[k - 1].position;
                let mut vel = [
                    (p[0] - q[0]) / path.dt,
                    (p[1] - q[1]) / path.dt,
                    (p[2] - q[2]) / path.dt,
                ];
                let vn = vel[0] * n[0] + vel[1] * n[1] + vel[2] * n[2];
                for i in 0..3 {
                    vel[i] -= vn * n[i];
                }
                let vt = (vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2]).sqrt();
                if vt > 1e-9 {
                    let g = v.friction * fnorm * (vt / 5e-4).tanh() / vt;
                    for i in 0..3 {
                        f[i] -= g * vel[i];
                    }
                }
            }
            out.push(f);
        }
        Ok(out)
    }
    fn describe(&self) -> String {
        "analytic Hertz stand-in (tests only)".into()
    }
}

fn stand_in() -> Hertz {
    Hertz {
        sites: sites(),
        e: 3.5e6,
        tip_radius: launch_config::SceneConfig::default().probe.tip_radius,
    }
}

/// Writes the experiment `spec` describes with the stand-in as its truth under `dir` (the
/// truth file beside it) and loads it back.
fn experiment(
    spec: &RealitySpec,
    model: &Hertz,
    sites: &[Site],
    dir: &std::path::Path,
) -> (Experiment, gap_diagnosis::reality::Truth) {
    let truth = write_experiment_with(
        spec,
        model,
        sites,
        &dir.join("exp"),
        &dir.join("truth.json"),
    )
    .unwrap();
    let exp = load_experiment(&dir.join("exp"), &gap_diagnosis::data_dir()).unwrap();
    (exp, truth)
}

/// The centre tests' experiment: `effects` drawn from `seed`, the stand-in's replay as the
/// truth, two probings per region, `adjust` setting what the test needs (its strengths, the
/// offset); written under a scratch folder named after `name`, loaded back and removed.
fn replay_experiment(
    model: &Hertz,
    name: &str,
    effects: &[&str],
    seed: u64,
    adjust: impl FnOnce(&mut RealitySpec),
) -> (Experiment, gap_diagnosis::reality::Truth) {
    let dir = std::env::temp_dir().join(format!("gap_stats_{name}_{}", std::process::id()));
    let mut spec = RealitySpec::from_effects(effects, seed).unwrap();
    spec.truth_mesh = TruthMesh::Replay;
    spec.probings_per_region = 2;
    adjust(&mut spec);
    let out = experiment(&spec, model, &model.sites, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    out
}

fn run(cases: usize, seed: u64, stiffness_offset: f64) -> gap_diagnosis::selftest::SelftestResult {
    let model = stand_in();
    let opts = SelftestOptions {
        verbose: true,
        stiffness_offset,
        // the stand-in is its own truth: it has no other discretisation
        truth_mesh: TruthMesh::Replay,
        ..Default::default()
    };
    let s = model.sites.clone();
    let factory =
        |_: &Experiment| -> Result<Box<dyn ForceModel>, GapError> { Ok(Box::new(stand_in())) };
    selftest_with(cases, seed, &opts, &model, &s, &factory).unwrap()
}

/// The self-test as issue 15 asks for it: every case's truth carries a systematic stiffness
/// offset (uniform within ±15%, modulus and support together), which the diagnosis must not
/// read as an effect nor let hide one.
#[test]
fn statistics_identify_effects_through_a_stiffness_offset() {
    let r = run(14, 3, gap_diagnosis::reality::STIFFNESS_OFFSET);
    eprintln!("{}", r.table());
    let s = r.summary();
    // reached: see the README ("A stiffness nuisance in every fit")
    assert!(s.accuracy >= ACCURACY_REACHED, "accuracy {}", s.accuracy);
    assert!(
        s.heldout_shrink_mean >= SHRINK_REACHED,
        "shrink {}",
        s.heldout_shrink_mean
    );
    let none = r.cases.iter().find(|c| c.truth == "none").unwrap();
    assert_eq!(none.found, "none", "an offset alone is no effect");
}

/// A persistent stiffness offset of ±14% alone (what another discretisation of the same
/// specimen gives) is `none` with the nuisance fitted, and its fitted scale is the offset;
/// without the nuisance the same data name an effect (what made this test necessary).
#[test]
fn a_persistent_stiffness_offset_is_not_an_effect() {
    let model = stand_in();
    let sites = model.sites.clone();
    for (k, scale) in [0.86, 1.14].into_iter().enumerate() {
        let dir = std::env::temp_dir().join(format!("gap_stats_offset_{}_{k}", std::process::id()));
        let mut spec = RealitySpec::from_effects(&["none"], 21 + k as u64).unwrap();
        spec.stiffness_scale = scale;
        spec.truth_mesh = TruthMesh::Replay;
        spec.probings_per_region = 3;
        let (exp, _) = experiment(&spec, &model, &sites, &dir);
        // every replay the diagnosis makes is in its stages' counts
        let counted = gap_diagnosis::model::Counting::new(&model);
        let with = diagnose(&exp, &counted, &Options::default()).unwrap();
        let stages = with.stages.unwrap();
        assert_eq!(stages.replays + stages.centre_replays, counted.made());
        assert!(stages.replays > 0 && stages.replays.is_multiple_of(exp.trials.len()));
        let without = diagnose(
            &exp,
            &model,
            &Options {
                nuisance: false,
                ..Options::default()
            },
        )
        .unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        eprintln!(
            "offset ×{scale}: with the nuisance {} (×{:?}; {}), without {} ({})",
            with.verdict.effect,
            with.heldout.nuisance_scale,
            with.verdict.reason,
            without.verdict.effect,
            without.verdict.reason
        );
        assert_eq!(with.verdict.effect, "none", "{}", with.verdict.reason);
        let fitted = with.heldout.nuisance_scale.unwrap();
        assert!((fitted / scale - 1.0).abs() < 0.01, "fitted ×{fitted}");
        assert_ne!(without.verdict.effect, "none", "{}", without.verdict.reason);
    }
}

/// The tilt's second stage ([`gap_diagnosis::centres`]): a tilt moves where the probe
/// first touches, which the quadratic between the ±6° knots cannot follow (what made a
/// study-mesh tilt case read `none`). With the re-simulation at the fitted angles the tilt
/// candidate is the replay there, still the baseline at 0°, and it fits the tilted truth
/// better than the interpolation alone.
#[test]
fn a_tilt_centre_makes_the_tilt_exact_at_the_fitted_angles() {
    use gap_diagnosis::effects::{centre_weight, Candidate, Effect};
    use gap_diagnosis::fit::{self, NuisanceFit};
    let model = stand_in();
    let (exp, truth) = replay_experiment(&model, "tilt_centre", &["tilt"], 7, |_| {});
    let tilt = Candidate::single(Effect::Tilt);
    let effects = [Effect::Tilt];
    let with = |centre: bool| {
        let opts = Options {
            centres: centre,
            ..Options::default()
        };
        gap_diagnosis::prepare_dataset(&exp, &model, &effects, &opts).unwrap()
    };
    let (plain, centred) = (with(false), with(true));
    let centre = centred[0]
        .centres
        .iter()
        .find(|k| k.effects == [Effect::Tilt])
        .expect("a tilted truth is fitted a tilt of at least 1°");
    let c = [centre.theta[0], centre.theta[1]];
    assert!(plain.iter().all(|d| d.centres.is_empty()));
    // what the report lists: the candidate, its angles and the trials with a usable replay
    let listed = gap_diagnosis::centres::describe(&centred);
    let n = centred.len();
    assert!(
        listed[0].starts_with("tilt at tilt_x ")
            && listed[0].ends_with(&format!("({n} of {n} trials)")),
        "{listed:?}"
    );
    let true_angles = [
        truth.spec.injected[0].params["tilt_x"],
        truth.spec.injected[0].params["tilt_y"],
    ];
    eprintln!("true tilt {true_angles:?}, centre {c:?}");
    let units = [6.0, 6.0];
    assert!(
        centre_weight(&c, &c, &units, 1.0) == 1.0
            && centre_weight(&[0.0; 2], &c, &units, 1.0) == 0.0
    );
    let variant = gap_diagnosis::model::Variant {
        tilt: [c[0].to_radians(), c[1].to_radians()],
        ..Default::default()
    };
    exact_at_the_centre(&model, &tilt, &c, &[0.0, 0.0], &variant, &centred);
    // at the true angles the centred candidate is nearer the truth than the interpolation
    let all: Vec<Vec<bool>> = centred.iter().map(|d| vec![true; d.t.len()]).collect();
    let rmse = |data: &[gap_diagnosis::dataset::TrialData]| {
        fit::phase_sse(&tilt, &true_angles, NuisanceFit::NEUTRAL, data, &all).rmse()
    };
    let (e_plain, e_centred) = (rmse(&plain), rmse(&centred));
    eprintln!(
        "RMSE at the true tilt: interpolation {e_plain:.4} N, with the centre {e_centred:.4} N"
    );
    assert!(
        e_centred < 0.5 * e_plain,
        "centre {e_centred} N against {e_plain} N"
    );
}

/// Regression: a tilt of 6–8° was centred a degree or more short. Its rounds fitted through
/// the interpolation with each centre's correction fading away from it, and crept towards the
/// fit: on the study mesh a tilt+device proxy's centre stood at 4.0°, −3.3° for 6.4°, −4.6°
/// after its three rounds, and the pairs leaving it stopped short too (`tilt`, the device
/// unnamed). Searched on the replay's tangent as a pair's rounds are, the centre stands at the
/// tilt, with the replay's slopes for the pairs that leave it.
#[test]
fn a_tilt_beyond_its_knots_is_centred_at_it_by_the_tangent_search() {
    use gap_diagnosis::effects::Effect;
    let model = stand_in();
    let truth = [6.4, -4.6];
    let (exp, _) = replay_experiment(&model, "tilt_search", &["tilt"], 5, |spec| {
        spec.stiffness_scale = 1.0;
        // the study's five per region: the search runs on two of them and the rest join it
        spec.probings_per_region = 5;
        let tilt = &mut spec.injected[0].params;
        tilt.insert("tilt_x".into(), truth[0]);
        tilt.insert("tilt_y".into(), truth[1]);
    });
    let data =
        gap_diagnosis::prepare_dataset(&exp, &model, &[Effect::Tilt], &Options::default()).unwrap();
    let centre = data[0]
        .centres
        .iter()
        .find(|k| k.effects == [Effect::Tilt])
        .expect("a 7.9° tilt gets a centre")
        .clone();
    let miss = (centre.theta[0] - truth[0]).hypot(centre.theta[1] - truth[1]);
    eprintln!(
        "tilt centre {:?} for {truth:?}: {miss:.3}° off",
        centre.theta
    );
    // the earlier rounds left it 0.44° off here, 0.03° on the tangent
    assert!(miss < 0.2, "centre {:?} for {truth:?}", centre.theta);
    assert_eq!(
        centre.slopes.len(),
        2,
        "the pairs leave it along the replay's slopes"
    );
    assert!(
        !centre.linear,
        "the search is over: the centre fades as made"
    );
    for d in &data {
        let own = d.centres.iter().find(|k| k.effects == [Effect::Tilt]);
        assert_eq!(
            own.map(|k| &k.theta),
            Some(&centre.theta),
            "{}: every trial on the same centre",
            d.name
        );
    }
}

/// The support's centre ([`gap_diagnosis::centres`]): a support is a spring in series with
/// the tissue, so the force is convex in its compliance and the chord between two knots lies
/// above it. Interpolated, a support between the knots is too stiff, and the fit took a
/// softer one (the study-mesh proxies' supports were fitted 18–19% soft). With the
/// re-simulation at the fitted compliance the candidate is the replay there, still the
/// baseline at 0, nearer the truth at the true compliance, and the fitted support nearer it.
#[test]
fn a_support_between_its_knots_is_fitted_at_its_own_replay() {
    use gap_diagnosis::effects::{Candidate, Effect};
    use gap_diagnosis::fit::{self, NuisanceFit};
    let model = stand_in();
    let (exp, _) = replay_experiment(&model, "support_centre", &["support"], 5, |spec| {
        // no stiffness offset: the truth is then exactly the replay at its support
        spec.stiffness_scale = 1.0;
        // between the 2000 and 1000 N/m knots, where the chord errs most
        spec.injected[0]
            .params
            .insert("support_stiffness".into(), 1400.0);
    });
    let support = Candidate::single(Effect::Support);
    let with = |centre: bool| {
        let opts = Options {
            centres: centre,
            ..Options::default()
        };
        gap_diagnosis::prepare_dataset(&exp, &model, &[Effect::Support], &opts).unwrap()
    };
    let (plain, centred) = (with(false), with(true));
    assert!(plain.iter().all(|d| d.centres.is_empty()));
    let centre = centred[0]
        .centres
        .iter()
        .find(|k| k.effects == [Effect::Support])
        .expect("a support of 1400 N/m is fitted a compliance above the centre's threshold");
    let c = centre.theta[0];
    let listed = gap_diagnosis::centres::describe(&centred);
    let n = centred.len();
    assert!(
        listed[0].starts_with("support at support_compliance ")
            && listed[0].ends_with(&format!("({n} of {n} trials)")),
        "{listed:?}"
    );
    let truth = 1.0 / 1400.0;
    eprintln!("true compliance {truth:.3e} m/N, centre {c:.3e}");
    let variant = gap_diagnosis::model::Variant {
        support_stiffness: 1.0 / c,
        ..Default::default()
    };
    exact_at_the_centre(&model, &support, &[c], &[0.0], &variant, &centred);
    let all: Vec<Vec<bool>> = centred.iter().map(|d| vec![true; d.t.len()]).collect();
    let rmse = |data: &[gap_diagnosis::dataset::TrialData]| {
        fit::phase_sse(&support, &[truth], NuisanceFit::NEUTRAL, data, &all).rmse()
    };
    let (e_plain, e_centred) = (rmse(&plain), rmse(&centred));
    // the fitted support with and without the centre, over every trial, no nuisance
    let fitted = |data: &[gap_diagnosis::dataset::TrialData]| {
        let th = fit::fit(
            &support,
            data,
            &all,
            &[],
            &fit::default_free(&support),
            fit::Nuisance::OFF,
        )
        .theta[0];
        1.0 / th
    };
    let (k_plain, k_centred) = (fitted(&plain), fitted(&centred));
    eprintln!(
        "RMSE at the true support: interpolation {e_plain:.4} N, with the centre \
         {e_centred:.4} N; fitted {k_plain:.0} and {k_centred:.0} N/m for 1400"
    );
    // the centre stands at the fit with the nuisances (a stiffness scale trades with a
    // support), 1198 N/m here, so at the truth its weight is below 1: measured 0.78×
    assert!(
        e_centred < 0.9 * e_plain,
        "centre {e_centred} N against {e_plain} N"
    );
    let err = |k: f64| (k / 1400.0 - 1.0).abs();
    assert!(
        err(k_centred) < 0.05 && err(k_centred) < 0.5 * err(k_plain),
        "fitted {k_centred:.0} N/m with the centre, {k_plain:.0} without, for 1400"
    );
}

/// A centred candidate `c` is the replay itself at the centre `at` (to 10⁻⁹ N) and exactly
/// the baseline at its neutral parameters `neutral`, in every trial of `data`.
fn exact_at_the_centre(
    model: &Hertz,
    c: &gap_diagnosis::effects::Candidate,
    at: &[f64],
    neutral: &[f64],
    variant: &Variant,
    data: &[gap_diagnosis::dataset::TrialData],
) {
    use gap_diagnosis::effects::predict;
    use gap_diagnosis::fit::NuisanceFit;
    let (mut grid, mut out) = (Vec::new(), Vec::new());
    for d in data {
        predict(c, at, d, NuisanceFit::NEUTRAL, &mut grid, &mut out);
        let replayed = gap_diagnosis::model::replay_checked(model, variant, &d.path)
            .unwrap()
            .forces;
        let worst = grid
            .iter()
            .zip(&replayed)
            .flat_map(|(a, b)| (0..3).map(move |q| (a[q] - b[q]).abs()))
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-9,
            "{}: {worst} N off the replay at the centre",
            d.name
        );
        predict(c, neutral, d, NuisanceFit::NEUTRAL, &mut grid, &mut out);
        assert_eq!(
            grid, d.base,
            "{}: the neutral candidate is the baseline",
            d.name
        );
    }
}

/// A pair's centre carries the replay's slopes ([`gap_diagnosis::dataset::Centre::slopes`]):
/// the pair's interpolation adds the tilt's delta, replayed on the fixed base, to the
/// support's, replayed untilted, so away from its centre it was as wrong as without one (a
/// study-mesh tilt+support case whose centre stood at tilt_y −0.47° was 5.1 N RMS off at the
/// true −1.80°, where a replay is 0.44 N off, and its tilt was fitted 24% short). With the
/// slopes the candidate is still the replay at the centre and the baseline at 0, and a step
/// from the centre follows the replay to first order.
#[test]
fn a_tilt_on_a_support_leaves_its_centre_along_the_replay_s_slopes() {
    use gap_diagnosis::effects::{predict, Candidate, Effect};
    use gap_diagnosis::fit::NuisanceFit;
    use gap_diagnosis::model::replay_checked;
    let model = stand_in();
    let (exp, _) = replay_experiment(&model, "pair_slopes", &["tilt", "support"], 11, |spec| {
        spec.stiffness_scale = 1.0;
        // the study's five per region: the pair's rounds search on two of them
        // (`centres::search_trials`) and the rest join after
        spec.probings_per_region = 5;
        for i in &mut spec.injected {
            match i.effect.as_str() {
                "tilt" => {
                    i.params.insert("tilt_x".into(), 5.0);
                    i.params.insert("tilt_y".into(), -2.0);
                }
                _ => {
                    i.params.insert("support_stiffness".into(), 1500.0);
                }
            }
        }
    });
    let pair = Candidate::pair(Effect::Tilt, Effect::Support);
    let data = gap_diagnosis::prepare_dataset(
        &exp,
        &model,
        &[Effect::Tilt, Effect::Support],
        &Options::default(),
    )
    .unwrap();
    let centre = data[0]
        .centres
        .iter()
        .find(|k| k.effects == [Effect::Tilt, Effect::Support])
        .expect("a tilt of 5.4° on a support of 1500 N/m gets a pair centre")
        .clone();
    assert_eq!(centre.slopes.len(), 3, "one slope per parameter");
    // searched on two trials per region, then made for the rest where the search settled:
    // every trial stands on the same centre
    assert!(
        data.len() > 6,
        "{} trials: the search would see them all",
        data.len()
    );
    for d in &data {
        let own = d
            .centres
            .iter()
            .find(|k| k.effects == [Effect::Tilt, Effect::Support])
            .unwrap_or_else(|| panic!("{}: no pair centre", d.name));
        assert_eq!(own.theta, centre.theta, "{}: another pair centre", d.name);
    }
    let c = centre.theta.clone();
    let variant_at = |th: &[f64]| Variant {
        tilt: [th[0].to_radians(), th[1].to_radians()],
        support_stiffness: 1.0 / th[2],
        ..Default::default()
    };
    exact_at_the_centre(&model, &pair, &c, &[0.0; 3], &variant_at(&c), &data);
    // half the slopes' own steps across and in the support (0.3°, 5·10⁻⁵ m/N): the candidate
    // with and without its slopes
    // against a replay there
    let step = [c[0], c[1] + 0.3, c[2] + 5e-5];
    let replayed: Vec<_> = data
        .iter()
        .map(|d| {
            replay_checked(&model, &variant_at(&step), &d.path)
                .unwrap()
                .forces
        })
        .collect();
    let mut flat = data.clone();
    for d in &mut flat {
        d.centres.iter_mut().for_each(|k| k.slopes.clear());
    }
    let rms_off = |data: &[gap_diagnosis::dataset::TrialData]| {
        let (mut grid, mut out) = (Vec::new(), Vec::new());
        let (mut sum, mut n) = (0.0, 0usize);
        for (d, r) in data.iter().zip(&replayed) {
            predict(&pair, &step, d, NuisanceFit::NEUTRAL, &mut grid, &mut out);
            for (a, b) in grid.iter().zip(r) {
                sum += (0..3).map(|q| (a[q] - b[q]).powi(2)).sum::<f64>();
                n += 3;
            }
        }
        (sum / n as f64).sqrt()
    };
    let (with, without) = (rms_off(&data), rms_off(&flat));
    eprintln!(
        "centre {c:.4?}; a step away the candidate is {with:.4} N RMS off a replay with its \
         slopes, {without:.4} N without"
    );
    // measured 0.45× (0.063 against 0.142 N); what is left is the replay's curvature over
    // the slopes' steps and the cross term between tilt and support
    assert!(
        with < 0.6 * without,
        "{with} N with the slopes against {without} N without"
    );
}
