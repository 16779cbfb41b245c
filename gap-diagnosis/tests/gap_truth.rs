//! The self-test as issue 15 (point 4) asks for it: every case's truth differs from the replay
//! as an independent FE code of the same specimen would. The truth is the specimen mesh
//! refined once (four times the contact facets, its new boundary nodes on the smooth surface
//! through the specimen's vertices, a direct solve; `RefinedTruth`) with a
//! penalty contact where the replay's is hard (`TRUTH_INTERFACE_COMPLIANCE`), its
//! modulus and support scaled by a stiffness offset drawn within ±15%, pressed at the study's
//! 0.5–1.2 mm; the diagnosis replays the coarse mesh as it would a real experiment. This test
//! reports what the diagnosis reaches on such data (the confusion matrix is printed) and
//! fails when it gets worse; the reached numbers are in the README ("A self-test on another
//! discretisation").
//!
//! CI-sized: five cases of seed 1 (no effect, three single effects, one pair), two probings
//! per region (one pressed, one pressed and slid), the default diagnosis.
use gap_diagnosis::model::{replay, ForceModel, Variant};
use gap_diagnosis::reality::{
    protocol_path, write_experiment_with_contact_layer, RealitySpec, TruthMesh, STUDY_PRESS_DEPTHS,
};
use gap_diagnosis::selftest::{selftest, SelftestOptions};
use gap_diagnosis::signal::dot;
use gap_diagnosis::sim_model::{no_effect_force_ratio, RefinedTruth};
use gap_diagnosis::{Region, SimForceModel};

/// The cases, chosen before any was run: no effect, the three the hidden cases of issue 15
/// missed or confused (an offset read as `support` or `modulus`, friction never found), and a
/// pair.
const CASES: [&str; 5] = ["none", "modulus", "friction", "support", "modulus+sensor"];

/// What the diagnosis reaches on these cases (README): 3 of 5 right since a modulus is named
/// where the trials measure a level beyond the nuisances' reach (README, "A level beyond the
/// nuisances' reach"): none, modulus (its trials measure ×1.975 ± 0.132 of the replay's, 4.1
/// SE over the band's ×1.44, the modulus ×1.93 in level) and modulus+sensor; friction read as
/// hardening+friction, support as modulus; mean held-out shrink 65.2%. Before, 2 of 5 since
/// the nuisances' level has a band (README, "A level band for the nuisances"), 50.1%: none
/// and modulus+sensor right, support read as `modulus`, the modulus case `none`. Before that,
/// 2 of 5 since an effect that
/// changes every probing must gain trial by trial (none and support; modulus read as none,
/// friction as hardening+friction, modulus+sensor as sensor), mean held-out shrink 50.3%
/// (README, "A gain that holds trial by trial"). The modulus case's gain over the floor, 51%
/// held-out, held on 0.2 SE trial by trial (hardening 1.1 SE), the no-effect case's `modulus`
/// on 0.3 SE. Before, 2 of 5 since a face contact pushes along the bisector of its last two
/// normals (modulus and support; none read as modulus), mean held-out shrink 65.4%. The
/// friction case is on the edge of naming: it read `friction` with the start-of-step
/// normal (friction alone 15.0% over the floor), `hardening+friction` with the bisector
/// (friction alone 9.8%, paired gain 1.6 SE) and `none` with the bisector taken only where a
/// normal turned back; its truth made with either normal gives the same verdict, so the
/// replay's normal decides it (README, "A hook held still in a dent"). Before, 3 of 5 since
/// the truth's new boundary nodes lie on the smooth surface (modulus, friction and support),
/// mean held-out shrink 63.9%. With them on the facets, 2
/// of 5 (modulus and support; friction read as modulus too), 67.2%; before the material
/// nuisance and `hardening` held to what it adds over `modulus`, 1 of 5 (support; none,
/// modulus and friction read as hardening), 67.8%. Without the contact nuisance it was 3 of 5
/// (none, friction, support), 67.7%: the levelled refined truth is a tissue 2.7× stiffer in
/// modulus behind a contact 2.7× softer than the replay's, beyond both nuisances' bands, and
/// `hardening` (a scale without a band) fits it best (README, "A contact nuisance beside
/// it"). (Before the truth was levelled with the replay, 1 of 5.)
const CORRECT_REACHED: usize = 3;
const SHRINK_REACHED: f64 = 0.6;

/// The refined truth's mean normal force over the replay's, no effect: measured ×0.331 with its
/// penalty contact and its boundary midpoints on the smooth surface (×0.366 on the facets,
/// ×0.411 with a hard contact), held to ±10%.
const RATIO_REACHED: [f64; 2] = [0.30, 0.365];

#[test]
fn selftest_on_a_refined_truth() {
    let opts = SelftestOptions {
        probings_per_region: 2,
        verbose: true,
        cases: Some(CASES.iter().map(|c| c.to_string()).collect()),
        ..Default::default()
    };
    assert_eq!(opts.truth_mesh, TruthMesh::RefinedOnce, "the default truth");
    let start = std::time::Instant::now();
    let r = selftest(CASES.len(), 1, &opts).unwrap();
    eprintln!("{}", r.table());
    eprintln!("{:.0} s", start.elapsed().as_secs_f64());
    let s = r.summary();
    assert_eq!(s.truth_mesh, TruthMesh::RefinedOnce);
    assert!(
        s.correct >= CORRECT_REACHED,
        "{} of {} right (reached {CORRECT_REACHED})",
        s.correct,
        s.cases
    );
    assert!(
        s.heldout_shrink_mean >= SHRINK_REACHED,
        "mean held-out shrink {:.3} (reached 0.652)",
        s.heldout_shrink_mean
    );
    // Every effect named right is graded on its strengths (`gap_diagnosis::recovery`): the
    // truth's parameter names must meet the fit's, or the 15% goal goes unmeasured.
    for c in r.cases.iter().filter(|c| c.correct && c.truth != "none") {
        for e in c
            .truth
            .split('+')
            .filter(|e| gap_diagnosis::recovery::grades(e))
        {
            assert!(
                c.recovery.iter().any(|g| g.effect == e),
                "case {} ({}): {e} is named but its strength is not graded: {:?}",
                c.case,
                c.truth,
                c.recovery
            );
        }
        assert!(
            c.recovery.iter().all(|g| g.relative_error.is_finite()),
            "case {}: {:?}",
            c.case,
            c.recovery
        );
    }
    eprintln!(
        "fitted strengths within 15% of the truth: {} of {}",
        s.params_within_tolerance, s.params_graded
    );
}

/// How far the refined truth is from the replay with no effect and no offset, before and
/// after it is levelled: the mean normal force of one probing per region at the study's
/// depths (`sim_model::no_effect_force_ratio`), the coarse mesh as the diagnosis replays it
/// against the same specimen refined once. This is the floor every case of the self-test
/// above stands on.
#[test]
fn refined_truth_against_the_replay() {
    let data = gap_diagnosis::data_dir();
    let mut scene = launch_config::SceneConfig::default();
    scene.meniscus.mesh = "default:lateral:coarse".into();
    let replay_model = SimForceModel::from_scene(scene.clone(), &data);
    let truth = RefinedTruth::new(&replay_model).unwrap();
    let raw = truth.raw_ratio();
    let levelled = no_effect_force_ratio(&truth, &replay_model).unwrap();
    eprintln!(
        "{}: levelled truth / replay ×{levelled:.4}",
        truth.describe()
    );
    assert!(
        (RATIO_REACHED[0]..=RATIO_REACHED[1]).contains(&raw),
        "the refined mesh's force is ×{raw:.3} the replay's (measured ×{:.3}…×{:.3})",
        RATIO_REACHED[0],
        RATIO_REACHED[1]
    );
    // levelled: the mean agrees (the response is linear in modulus and support); what is left
    // is how the two discretisations differ by region and depth
    assert!(
        (levelled - 1.0).abs() < 0.01,
        "levelled truth / replay ×{levelled:.4}"
    );
    // by region, the levelled truth still differs from the replay
    let sites = replay_model.sites().unwrap();
    let site = sites
        .iter()
        .find(|s| s.region == Region::Posterior)
        .unwrap();
    let n = site.normal;
    let path = protocol_path(
        site.point,
        n,
        STUDY_PRESS_DEPTHS[0],
        scene.probe.tip_radius,
        None,
        0.02,
    );
    let mean = |f: Vec<[f64; 3]>| f.iter().map(|&v| dot(v, n)).sum::<f64>() / f.len() as f64;
    let fr = mean(replay(&replay_model, &Variant::default(), &path).unwrap());
    let ft = mean(replay(&truth, &Variant::default(), &path).unwrap());
    eprintln!(
        "posterior, shallowest: levelled truth / replay ×{:.3}",
        ft / fr
    );
    assert!(
        (ft / fr - 1.0).abs() > 0.02,
        "the levelled truth is the replay at the posterior site (×{:.3})",
        ft / fr
    );
}

/// The cases of the same-mesh check below, chosen before it was run: no effect, each effect
/// but `mesh` alone, and three pairs.
const SAME_MESH_CASES: [&str; 12] = [
    "none",
    "modulus",
    "friction",
    "support",
    "hardening",
    "sensor",
    "tilt",
    "viscoelastic",
    "device",
    "modulus+sensor",
    "hardening+friction",
    "support+device",
];

/// What the diagnosis reaches on them (README, "A second constitutive law beside it"): 12 of
/// 12 with the material nuisance; 10 of 12 without it (modulus+sensor read
/// `hardening+sensor`, hardening+friction `friction`) and 5 of 12 without the contact nuisance
/// too (the no-effect case read as `support`).
const SAME_MESH_CORRECT_REACHED: usize = 12;

/// The hidden cases' independent code meshed the specimen as coarsely as the replay (its
/// no-effect force was within 10% of the replay's) and contacted it its own way. Here the
/// truth is the replay's own mesh with a penalty layer of 4 µm/N (250 N/mm) under the probe
/// where the replay's contact is hard, each case with its drawn ±15% stiffness offset and
/// effect, two probings per region (seeds 100…111); the default diagnosis.
#[test]
fn selftest_on_another_contact_formulation() {
    let start = std::time::Instant::now();
    let mut right = 0;
    let mut none_verdict = String::new();
    // (case, fitted μ, true μ) wherever friction is injected and the verdict is right
    let mut mu: Vec<(String, f64, f64)> = Vec::new();
    for (i, case) in SAME_MESH_CASES.iter().enumerate() {
        // `none` is read as no effect
        let effects: Vec<&str> = case.split('+').collect();
        let mut spec = RealitySpec::from_effects(&effects, 100 + i as u64).unwrap();
        spec.probings_per_region = 2;
        let root =
            std::env::temp_dir().join(format!("arthrosim_same_mesh_{}_{i}", std::process::id()));
        write_experiment_with_contact_layer(
            &spec,
            4e-6,
            &root.join("exp"),
            &root.join("truth.json"),
        )
        .unwrap();
        let r = gap_diagnosis::diagnose_dir(&root.join("exp"), &gap_diagnosis::Options::default())
            .unwrap();
        let _ = std::fs::remove_dir_all(&root);
        let label = spec.label();
        let ok = r.verdict.effect == label;
        right += usize::from(ok);
        if label == "none" {
            none_verdict.clone_from(&r.verdict.effect);
        }
        let injected_mu = spec
            .injected
            .iter()
            .find_map(|i| i.params.get("mu").copied());
        let fitted_mu = r
            .verdict
            .params
            .iter()
            .find_map(|p| (p.name == "mu").then_some(p.value));
        // the measure: a scale on a right verdict (a missed hardening beside friction
        // is carried by μ)
        if let (Some(t), Some(f), true) = (injected_mu, fitted_mu, ok) {
            mu.push((label.clone(), f, t));
        }
        eprintln!(
            "{label:22} offset ×{:.3}  found {:22} {}  shrink {:5.1}%  contact nuisance {}",
            spec.stiffness_scale,
            r.verdict.effect,
            if ok { "ok  " } else { "MISS" },
            100.0 * r.verdict.heldout_shrink,
            r.heldout
                .contact_compliance
                .map_or("–".into(), |c| format!("{:.2} µm/N", 1e6 * c))
        );
    }
    eprintln!(
        "{right}/{} right ({:.0} s)",
        SAME_MESH_CASES.len(),
        start.elapsed().as_secs_f64()
    );
    assert_eq!(none_verdict, "none", "the no-effect case");
    // Regression: the knots are replayed without the contact layer, so a friction delta μ·N of
    // the hard contact added to the layer's lower N read μ 15–25% low (0.31 for 0.41 beside a
    // fitted 8.3 µm/N); the layer now scales the deltas it carries (effects::layer_change).
    // The issue asks a scale within 15% of the truth.
    assert!(!mu.is_empty(), "no friction case was diagnosed right");
    for (case, f, t) in &mu {
        eprintln!("{case}: μ {f:.3} for {t:.3}");
        assert!(
            (f / t - 1.0).abs() <= 0.15,
            "{case}: μ {f:.3} for a true {t:.3}, more than 15% off"
        );
    }
    assert!(
        right >= SAME_MESH_CORRECT_REACHED,
        "{right} of {} right (reached {SAME_MESH_CORRECT_REACHED})",
        SAME_MESH_CASES.len()
    );
}

/// Regression: the tilt's centre was placed at the tilt fitted alone. A relaxing hold lowers
/// the force a tilt's earlier touch adds, so the tilt alone took the relaxation as less tilt:
/// the refined full cycle's viscoelastic+tilt case (`gap selftest --cases 14 --seed 1`, case
/// 12: g1 0.47, τ 1.28 s, tilt (4.94°, −3.12°)) had its centre at (2.08°, −1.66°), 3.2° off,
/// and read `tilt` with the tilt 59% short. The centre is now placed by the tilt fitted with a
/// relaxation beside it where that relaxes over the hold (`gap_diagnosis::centres`). This is
/// that case, made the way the self-test makes it. With the knots at ±6° the centre stood
/// within 20%; with them at ±3° (where a 2° tilt is fitted at all, `a_two_degree_tilt_…`) it
/// stands at (3.02°, −2.38°), 2.05° off (35%), as the 5.8° lies beyond the knots: the bound has
/// been 40% since, against the 55% (3.2°) of what broke.
#[test]
fn a_tilt_beside_a_relaxation_is_centred_near_its_tilt() {
    use gap_diagnosis::effects::Effect;
    use gap_diagnosis::reality::{stiffness_offset, write_experiment, STIFFNESS_OFFSET};
    let case_seed = 1u64.wrapping_mul(1_000_003).wrapping_add(12);
    let mut spec = RealitySpec::from_effects(&["viscoelastic", "tilt"], case_seed).unwrap();
    let defaults = SelftestOptions::default();
    spec.stiffness_scale = stiffness_offset(case_seed, STIFFNESS_OFFSET);
    spec.truth_mesh = defaults.truth_mesh;
    spec.probings_per_region = defaults.probings_per_region;
    spec.noise_sigma = defaults.noise_sigma;
    let dir = std::env::temp_dir().join(format!("gap_truth_relaxing_tilt_{}", std::process::id()));
    let truth = write_experiment(&spec, &dir.join("exp"), &dir.join("truth.json")).unwrap();
    let data_dir = gap_diagnosis::data_dir();
    let exp = gap_diagnosis::load_experiment(&dir.join("exp"), &data_dir).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let model = SimForceModel::for_experiment(&exp, &data_dir).unwrap();
    let effects = [Effect::Viscoelastic, Effect::Tilt];
    let data = gap_diagnosis::prepare_dataset(&exp, &model, &effects, &defaults.diagnose).unwrap();
    let (off, size) = tilt_centre_miss(&data[0], &truth);
    assert!(off < 0.4 * size, "centre {off:.3}° off a {size:.3}° tilt");
}

/// How far the single tilt's centre on `trial` stands from `truth`'s tilt, and that tilt's
/// size (degrees); a trial without the centre panics with the true tilt.
fn tilt_centre_miss(
    trial: &gap_diagnosis::dataset::TrialData,
    truth: &gap_diagnosis::reality::Truth,
) -> (f64, f64) {
    use gap_diagnosis::effects::Effect;
    let true_angles = injected_tilt(truth);
    let centre = trial
        .centres
        .iter()
        .find(|k| k.effects == [Effect::Tilt])
        .unwrap_or_else(|| panic!("no tilt centre for a true tilt of {true_angles:?}°"));
    let off = (centre.theta[0] - true_angles[0]).hypot(centre.theta[1] - true_angles[1]);
    let size = true_angles[0].hypot(true_angles[1]);
    eprintln!(
        "true tilt {true_angles:?}, centre {:?}: {off:.3}° off a {size:.3}° tilt",
        centre.theta
    );
    (off, size)
}

/// Regression: a tilt of 2–2.5° read `none` on every truth, the project's own too. The
/// quadratic through the knots, then at ±6°, where a press 18 mm from the origin moves 1.9 mm
/// and misses the tissue or presses it several times as deep, fitted such a tilt at 0.3°: under
/// `MIN_CENTRE_DEG`, so no replay came near it. This is the study-mesh proxy case that showed
/// it (`GAP_DEV_CASE_LIST=tilt=2 gap_dev DIR contact-layer-cases 4300 study:lateral`: tilt
/// (−2.0°, −1.25°), ×0.94, which fitted (−0.35°, −0.03°)). With the knots at ±3° the tilt
/// alone is fitted near it and its centre is made there, 0.15° off; the case reads `tilt`.
#[test]
fn a_two_degree_tilt_is_fitted_and_centred_near_it() {
    use gap_diagnosis::effects::Effect;
    let (truth, exp, model) = proxy("study:lateral", &["tilt=2"], 4300, "two_degree_tilt");
    let data = gap_diagnosis::prepare_dataset(
        &exp,
        &model,
        &[Effect::Tilt],
        &gap_diagnosis::Options::default(),
    )
    .unwrap();
    let (off, size) = tilt_centre_miss(&data[0], &truth);
    assert!(off < 0.25 * size, "centre {off:.3}° off a {size:.3}° tilt");
}

/// The coarse built-in mesh the coarse proxy sets use.
const COARSE: &str = "default:lateral:coarse";

/// A proxy case on `mesh` as `gap_dev DIR contact-layer-cases SEED MESH` writes it (the
/// same-mesh penalty truth, 4 µm/N), loaded as an experiment with its replay model; the folder
/// `label` is removed once loaded.
fn proxy(
    mesh: &str,
    effects: &[&str],
    seed: u64,
    label: &str,
) -> (
    gap_diagnosis::reality::Truth,
    gap_diagnosis::Experiment,
    SimForceModel,
) {
    let mut spec = RealitySpec::from_effects(effects, seed).unwrap();
    spec.mesh = mesh.into();
    let dir = std::env::temp_dir().join(format!("gap_truth_{label}_{}", std::process::id()));
    let truth =
        write_experiment_with_contact_layer(&spec, 4e-6, &dir.join("exp"), &dir.join("truth.json"))
            .unwrap();
    let data_dir = gap_diagnosis::data_dir();
    let exp = gap_diagnosis::load_experiment(&dir.join("exp"), &data_dir).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let model = SimForceModel::for_experiment(&exp, &data_dir).unwrap();
    (truth, exp, model)
}

/// The tilt `truth` injected, degrees (x, y).
fn injected_tilt(truth: &gap_diagnosis::reality::Truth) -> [f64; 2] {
    let tilt = truth
        .spec
        .injected
        .iter()
        .find(|i| i.effect == "tilt")
        .expect("a tilted truth");
    [tilt.params["tilt_x"], tilt.params["tilt_y"]]
}

/// Regression: a tilt on a soft support that the tilt alone did not fit to significance got
/// no centre, and neither did the pair, whose rounds started only from the single tilt's
/// centre. The tilt's knots stand on the fixed base, so their force overstates the tilt's
/// where the base gives, and the tilt alone took less tilt for it. This is the coarse-mesh
/// proxy case that showed it (`gap_dev DIR contact-layer-cases 800 default:lateral:coarse`,
/// case 17, seed 817: tilt (7.17°, 3.11°) on 947 N/m per node, the same-mesh penalty truth):
/// the tilt alone fitted under 1°, the pair's own fit over the support's centre 1.1°, and the
/// case read `mesh`. Now the pair's centre is searched from its own fit (`centres`); the case
/// reads `tilt+support`, tilt 1.8% and support 1.2% off. Since the tilt's knots stand at ±3°
/// the tilt alone fits this case 1.2° and gets a centre, so the pair's rounds start from it,
/// and this test no longer goes through the path where the tilt alone stays under 1°; it still
/// asks that the pair's centre reach the tilt: within 25%, where it is 19% short with the ±3°
/// knots and 20.3% short (6.23° for 7.82°) since the nuisances' level has a band of its own
/// (README, "A level band for the nuisances"); the failure it guards left no centre at all.
#[test]
fn a_tilt_on_a_soft_support_gets_the_pair_s_centre_near_its_tilt() {
    use gap_diagnosis::effects::Effect;
    let (truth, exp, model) = proxy(COARSE, &["support", "tilt"], 817, "soft_pair");
    let opts = gap_diagnosis::Options::default();
    let data = gap_diagnosis::prepare_dataset(&exp, &model, &Effect::ALL, &opts).unwrap();
    let centres: Vec<String> = data[0]
        .centres
        .iter()
        .map(|k| format!("{:?} at {:.4?}", k.effects, k.theta))
        .collect();
    eprintln!("centres: {centres:?}");
    let [tilt_x, tilt_y] = injected_tilt(&truth);
    let size = tilt_x.hypot(tilt_y);
    for d in &data {
        let pair = d
            .centres
            .iter()
            .find(|k| k.effects == [Effect::Tilt, Effect::Support])
            .unwrap_or_else(|| panic!("{}: no pair centre ({centres:?})", d.name));
        let fitted = pair.theta[0].hypot(pair.theta[1]);
        assert!(
            (fitted - size).abs() < 0.25 * size,
            "{}: the pair's centre tilts {fitted:.2}° for {size:.2}°",
            d.name
        );
    }
}

/// Regression: friction's knots are replayed on the fixed base, and its delta was added to a
/// soft support's force as if the support left the normal force, and with it the friction
/// force, as it was. A coarse-mesh proxy outside the hidden sets' case list (`gap_dev DIR
/// contact-layer-cases 1100 default:lateral:coarse` with `GAP_DEV_CASE_LIST` of other pairs,
/// case 7, seed 1107: μ 0.48 on 1,316 N/m per node, the same-mesh penalty truth) was 5.7 N RMS
/// off at the true parameters, and read `modulus+friction` with a modulus ×0.21. Friction's
/// delta now goes through the support's relative change of the normal force, as it goes
/// through the contact layer's (`effects::predict`): 0.8 N RMS there, and the case reads
/// `friction+support`.
#[test]
fn friction_on_a_soft_support_goes_through_the_support_s_normal_force() {
    use gap_diagnosis::effects::{Candidate, Effect};
    use gap_diagnosis::fit::{phase_sse, NuisanceFit};
    let (truth, exp, model) = proxy(COARSE, &["support", "friction"], 1107, "friction_support");
    let opts = gap_diagnosis::Options {
        centres: false,
        ..Default::default()
    };
    let data = gap_diagnosis::prepare_dataset(&exp, &model, &Effect::ALL, &opts).unwrap();
    let injected = |effect: &str, name: &str| {
        truth
            .spec
            .injected
            .iter()
            .find(|i| i.effect == effect)
            .map(|i| i.params[name])
            .unwrap()
    };
    let (mu, stiffness) = (
        injected("friction", "mu"),
        injected("support", "support_stiffness"),
    );
    // the truth's stiffness offset scales its modulus and its support alike: the replay at
    // the drawn support, scaled as a whole
    let nuisance = NuisanceFit {
        stiffness: truth.spec.stiffness_scale,
        ..NuisanceFit::NEUTRAL
    };
    let pair = Candidate::pair(Effect::Friction, Effect::Support);
    let every: Vec<Vec<bool>> = data.iter().map(|d| vec![true; d.t.len()]).collect();
    let rmse = phase_sse(&pair, &[mu, 1.0 / stiffness], nuisance, &data, &every).rmse();
    let floor = phase_sse(&pair, &[0.0, 0.0], nuisance, &data, &every).rmse();
    eprintln!(
        "μ {mu:.3} on {stiffness:.0} N/m per node: {rmse:.3} N RMS at the truth, \
         {floor:.3} N at none"
    );
    assert!(
        rmse < 1.5,
        "friction+support at its true parameters is {rmse:.3} N RMS off the measurement"
    );
}

/// Regression: a tilt beside an effect that is not re-simulated reads as the tilt alone. The
/// pair uses the single tilt's centre, which stands where the tilt fits alone, and the
/// tilt alone takes part of the other effect as tilt; the pair's fit then leaves the centre
/// along the interpolation's slopes, which the knots at ±6° set wrongly, and it stayed
/// there. This is the coarse-mesh proxy outside the hidden sets' case list that showed it
/// (`gap_dev DIR contact-layer-cases 1100 default:lateral:coarse` with `GAP_DEV_CASE_LIST` of
/// other pairs, case 0, seed 1100: modulus ×1.58 on an offset of ×1.11, tilt (−5.61°,
/// −3.80°), the same-mesh penalty truth). It read `tilt`, the tilt 13.7% off; with the
/// replay's slopes at the tilt's centre (`centres`) it reads `modulus+tilt`, the tilt 2.3%
/// and the modulus 6.6% off.
#[test]
fn a_tilt_beside_a_modulus_leaves_the_tilt_s_centre_along_the_replay_s_slopes() {
    use gap_diagnosis::effects::Effect;
    let (truth, exp, model) = proxy(COARSE, &["modulus", "tilt"], 1100, "modulus_tilt");
    let opts = gap_diagnosis::Options::default();
    // as `diagnose` runs it, with the prepared trials in hand
    let effects = gap_diagnosis::candidate_effects(&exp, &model, &opts);
    let data = gap_diagnosis::prepare_dataset(&exp, &model, &effects, &opts).unwrap();
    for d in &data {
        let k = d.centres.iter().find(|k| k.effects == [Effect::Tilt]);
        assert!(
            k.is_some_and(|k| k.slopes.len() == 2),
            "{}: the tilt's centre without its two slopes",
            d.name
        );
    }
    let start = std::time::Instant::now();
    let report = gap_diagnosis::diagnose_data(
        exp.dir.display().to_string(),
        model.describe(),
        &data,
        &effects,
        &opts,
        start,
    )
    .unwrap();
    let v = &report.verdict;
    eprintln!(
        "{} ({:.1}% held-out): {}",
        v.effect,
        100.0 * v.heldout_shrink,
        v.reason
    );
    assert_eq!(v.effect, "modulus+tilt");
    let fitted = |name: &str| v.params.iter().find(|p| p.name == name).unwrap().value;
    let [tilt_x, tilt_y] = injected_tilt(&truth);
    let size = tilt_x.hypot(tilt_y);
    let tilt = fitted("tilt_x").hypot(fitted("tilt_y"));
    assert!(
        (tilt - size).abs() < 0.15 * size,
        "tilt {tilt:.2}° for {size:.2}°"
    );
}
