//! The gap diagnosis on truths from another code (issue 15, points 1 and 4).
//!
//! `tools/independent_fe/independent_fe.py` models the study's lateral mesh with scikit-fem:
//! quadratic tets, small-strain elasticity, a frictionless ball held against the surface by a
//! penalty integrated over it, a direct solve. It shares nothing with the replay but the mesh
//! it is handed, and writes experiment folders as a lab would (the specimen as a `.msh` path,
//! the probe a `sphere`), which `diagnose_dir` reads as it reads theirs. Its friction (an
//! option the cases here do not use) is checked on a block by its `slide` command.
//!
//! Needs the study data and python3 with the tool's requirements (`.ci/run` installs
//! `tools/independent_fe/requirements.txt`); outside CI it skips without them. About
//! eleven minutes on 2 cores in the test profile (680 s on 2026-12-02, the machine otherwise
//! idle).
use gap_diagnosis::{self as gap, Report};
use std::path::{Path, PathBuf};
use std::process::Command;

fn in_ci() -> bool {
    std::env::var("CI").map(|v| v == "true").unwrap_or(false)
}

/// The study data and a python3 that imports scikit-fem; in CI both are required.
fn ready() -> bool {
    let data = gap::data_dir()
        .join("meniscus/lateral_meniscus_computation.msh")
        .is_file();
    let python = Command::new("python3")
        .args(["-c", "import skfem, scipy, numpy"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !(data && python) && in_ci() {
        panic!(
            "CI=true but the study data ({data}) or python3 with scikit-fem ({python}) is missing"
        );
    }
    data && python
}

fn tool() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tools/independent_fe/independent_fe.py")
}

/// One case of the independent code: what it is handed and, once spawned, its process.
struct Case {
    name: &'static str,
    level: f64,
    effects: &'static [&'static str],
    generator: std::process::Child,
}

/// Starts the independent code on `source`'s poses, with `effects` and the modulus scaled by
/// `level` (not an effect). The generator is single-threaded for most of a case, so the
/// levelled cases run side by side on CI's 2 cores (measured 38–150 s each, alone to three at
/// once).
fn spawn_case(
    root: &Path,
    source: &Path,
    specimen: &gap::reality::SpecimenFiles,
    name: &'static str,
    level: f64,
    effects: &'static [&'static str],
) -> Case {
    let mut cmd = Command::new("python3");
    cmd.arg(tool())
        .arg("generate")
        .arg(source)
        .arg(root.join(name))
        .arg("--mesh")
        .arg(&specimen.msh)
        .arg("--fixed")
        .arg(&specimen.fixed)
        .arg("--truth")
        .arg(root.join(format!("{name}_truth.json")))
        .arg("--level")
        .arg(level.to_string())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped());
    for e in effects {
        cmd.arg("--effect").arg(e);
    }
    Case {
        name,
        level,
        effects,
        generator: cmd.spawn().expect("python3 starts"),
    }
}

/// Waits for `generator` (of case `name`) and checks it wrote its experiment.
fn wait_written(name: &str, generator: std::process::Child) {
    let run = generator.wait_with_output().expect("python3 runs");
    assert!(
        run.status.success(),
        "independent_fe {name}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
}

/// Waits for `case`'s generator, then diagnoses its experiment.
fn diagnose_case(root: &Path, case: Case) -> Report {
    let Case {
        name,
        level,
        effects,
        generator,
    } = case;
    wait_written(name, generator);
    let report = gap::diagnose_dir(&root.join(name), &gap::Options::default()).expect("diagnosed");
    eprintln!(
        "{name} (level {level:.3}, {effects:?}): {} — {}; measured {:.2} N, replayed {:.2} N",
        report.verdict.effect,
        report.verdict.reason,
        report.localisation.mean_normal_force_measured,
        report.localisation.mean_normal_force_simulated
    );
    report
}

/// The replay's mean normal force over the measured one on the experiment in `dir`, from its
/// baseline replays: what [`Report`]'s `localisation` gives, without the diagnosis' other
/// replays.
fn replay_over_measured(dir: &Path) -> f64 {
    let data = gap::data_dir();
    let exp = gap::load_experiment(dir, &data).expect("experiment loads");
    let model = gap::SimForceModel::for_experiment(&exp, &data).expect("replay model");
    let opts = gap::Options {
        nuisance: false,
        centres: false,
        ..gap::Options::default()
    };
    let trials = gap::prepare_dataset(&exp, &model, &[], &opts).expect("replayed");
    let at = gap::localise(&trials);
    eprintln!(
        "raw: measured {:.2} N, replayed {:.2} N",
        at.mean_normal_force_measured, at.mean_normal_force_simulated
    );
    at.mean_normal_force_simulated / at.mean_normal_force_measured
}

fn param(report: &Report, name: &str) -> f64 {
    report
        .verdict
        .params
        .iter()
        .find(|p| p.name == name)
        .unwrap_or_else(|| panic!("{name} in {:?}", report.verdict.params))
        .value
}

/// The replay against an outside code of the same specimen, and the verdicts on it.
///
/// Unlevelled, the P2 reference presses the study mesh's 15 probings with 11.1 N on average
/// where the replay presses 32.0 N (README, "The replay model against an independent code"):
/// the floor issue 15 asks to measure, from outside the project. Levelled by that ratio (as the
/// self-test's refined truth is levelled), what is left is the two codes' difference in shape,
/// and on it a no-effect case reads `none`, a device bias is recovered to a few millinewtons,
/// a support is named, and so are a relaxation (g1 and τ within 15%) and a sensor (its delay
/// and low-pass within 20% in sum), each applied by the other code to its own force history.
/// The README's tables ("The replay model against an independent code", "Signal effects on
/// the independent code") give what it misses on more cases.
#[test]
fn another_code_s_truth_levelled_reads_none_a_device_a_support_a_relaxation_and_a_sensor() {
    if !ready() {
        eprintln!("skipped: needs the study data and python3 with scikit-fem");
        return;
    }
    let root = std::env::temp_dir().join(format!("arthrosim_independent_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let specimen = gap::reality::export_specimen("study:lateral", &root.join("specimen"), false)
        .expect("specimen written");
    // the protocol's poses and sampling, from the project's generator (its forces are replaced)
    let mut spec = gap::reality::RealitySpec::from_effects(&[], 4000).unwrap();
    spec.mesh = "study:lateral".into();
    let source = root.join("source");
    gap::reality::write_experiment_with_contact_layer(
        &spec,
        4e-6,
        &source,
        &root.join("source_truth.json"),
    )
    .unwrap();

    // unlevelled: the baseline replays alone give the ratio (a diagnosis of it reads `modulus`,
    // README)
    let raw = spawn_case(&root, &source, &specimen, "raw", 1.0, &[]);
    wait_written(raw.name, raw.generator);
    let ratio = replay_over_measured(&root.join("raw"));
    eprintln!("the replay presses ×{ratio:.3} the independent code's mean normal force");
    // measured 2.88 (+188%); the project's own refined meshes put it at ×3.0-4.4
    assert!(
        (2.4..=3.4).contains(&ratio),
        "replay ×{ratio} the independent code's force"
    );

    // every levelled case's generator at once; each is diagnosed as it is needed
    let spawn = |name, level, effects| spawn_case(&root, &source, &specimen, name, level, effects);
    let cases = [
        spawn("none", ratio * 0.95, &[]),
        spawn("device", ratio * 1.05, &["device=0.25,-0.15,0.3"]),
        spawn("support", ratio, &["support=3e8"]),
        spawn("viscoelastic", ratio * 0.97, &["viscoelastic=0.35,0.8"]),
        spawn("sensor", ratio * 1.03, &["sensor=0.03,0.02"]),
    ];
    let [none, device, support, relaxing, sensed] = cases.map(|c| diagnose_case(&root, c));
    assert_eq!(none.verdict.effect, "none", "{}", none.verdict.reason);

    let bias = [0.25, -0.15, 0.30];
    assert_eq!(device.verdict.effect, "device", "{}", device.verdict.reason);
    for (axis, truth) in ["bias_x", "bias_y", "bias_z"].iter().zip(bias) {
        let fitted = param(&device, axis);
        assert!(
            (fitted - truth).abs() < 0.02,
            "{axis} {fitted} N for {truth} N"
        );
    }

    assert_eq!(
        support.verdict.effect, "support",
        "{}",
        support.verdict.reason
    );

    // a relaxation the other code applies to its own force history: g1 0.371, τ 0.843 s here
    // for 0.35, 0.8 s, and 0.369, 0.870 s on seed 4214's poses (README, "Signal effects on the
    // independent code")
    assert_eq!(
        relaxing.verdict.effect, "viscoelastic",
        "{}",
        relaxing.verdict.reason
    );
    for (name, truth) in [("prony_g1", 0.35), ("prony_tau1", 0.8)] {
        let fitted = param(&relaxing, name);
        eprintln!("viscoelastic: {name} {fitted:.4} for {truth}");
        assert!(
            (fitted / truth - 1.0).abs() < 0.15,
            "{name} {fitted} for {truth}"
        );
    }

    // a sensor's delay and low-pass: named, and the two together lag the force by their sum
    assert_eq!(sensed.verdict.effect, "sensor", "{}", sensed.verdict.reason);
    // measured 23.4 + 22.2 ms, each ± 12 ms: which of the two lags is set by the two codes'
    // difference at the onsets, not by the sensor (README), so only their sum is held
    let (delay, tau) = (param(&sensed, "delay"), param(&sensed, "lowpass_tau"));
    assert!(
        ((delay + tau) / 0.05 - 1.0).abs() < 0.2,
        "delay {delay} s + low-pass {tau} s for 0.05 s"
    );
    let _ = std::fs::remove_dir_all(&root);
}

/// The independent code's own friction, which its friction cases stand on (README, "Friction
/// on the independent code"): a ball pressed 0.2 mm into a block and slid 2 mm settles,
/// every sample slipping, at −Fx/Fz 0.255 for μ 0.3 (under μ: the pressure moves to the
/// trailing side) and at none without friction. On a coarse block (6 cells across, ~1 min).
#[test]
fn the_independent_code_s_friction_slides_under_its_coulomb_bound() {
    if !ready() {
        eprintln!("skipped: needs the study data and python3 with scikit-fem");
        return;
    }
    let sliding_ratio = |mu: f64| -> f64 {
        let out = Command::new("python3")
            .arg(tool())
            .args(["slide", "--cells", "6", "--mu", &mu.to_string()])
            .output()
            .expect("python3 runs");
        assert!(
            out.status.success(),
            "slide --mu {mu}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        // after the press (steps 0–10) and the slide's first 0.5 mm, where the traction builds
        let rows: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(|l| serde_json::from_str(l).expect("one JSON object a line"))
            .filter(|r: &serde_json::Value| r["step"].as_u64().unwrap() >= 21)
            .collect();
        assert!(
            rows.len() >= 20,
            "slide --mu {mu}: {} sliding steps",
            rows.len()
        );
        assert!(
            rows.iter().all(|r| r["unconverged"].as_u64() == Some(0)),
            "slide --mu {mu}: a contact solve did not converge"
        );
        rows.iter()
            .map(|r| r["ratio"].as_f64().unwrap())
            .sum::<f64>()
            / rows.len() as f64
    };
    let (with, without) = (sliding_ratio(0.3), sliding_ratio(0.0));
    eprintln!("-Fx/Fz sliding: {with:.3} with mu 0.3, {without:.3} without");
    assert!(without.abs() < 0.05, "frictionless: {without}");
    assert!((0.2..0.3).contains(&with), "mu 0.3: {with}");
}
