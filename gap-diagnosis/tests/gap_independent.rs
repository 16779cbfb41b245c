//! The gap diagnosis on truths from another code (issue 15, points 1 and 4).
//!
//! `tools/independent_fe/independent_fe.py` models the study's lateral mesh with scikit-fem:
//! quadratic tets, small-strain elasticity, a frictionless ball held against the surface by a
//! penalty integrated over it, a direct solve. It shares nothing with the replay but the mesh
//! it is handed, and writes experiment folders as a lab would (the specimen as a `.msh` path,
//! the probe a `sphere`), which `diagnose_dir` reads as it reads theirs.
//!
//! Needs the study data and python3 with the tool's requirements (`.ci/run` installs
//! `tools/independent_fe/requirements.txt`); outside CI it skips without them. About four
//! minutes on 2 cores.
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

/// The independent code's experiment from `source`'s poses, with `effects` and the modulus
/// scaled by `level` (not an effect); then its diagnosis.
fn independent_case(
    root: &Path,
    source: &Path,
    specimen: &gap::reality::SpecimenFiles,
    name: &str,
    level: f64,
    effects: &[&str],
) -> Report {
    let out = root.join(name);
    let mut cmd = Command::new("python3");
    cmd.arg(tool())
        .arg("generate")
        .arg(source)
        .arg(&out)
        .arg("--mesh")
        .arg(&specimen.msh)
        .arg("--fixed")
        .arg(&specimen.fixed)
        .arg("--truth")
        .arg(root.join(format!("{name}_truth.json")))
        .arg("--level")
        .arg(level.to_string());
    for e in effects {
        cmd.arg("--effect").arg(e);
    }
    let run = cmd.output().expect("python3 runs");
    assert!(
        run.status.success(),
        "independent_fe {name}: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report = gap::diagnose_dir(&out, &gap::Options::default()).expect("diagnosed");
    eprintln!(
        "{name} (level {level:.3}, {effects:?}): {} — {}; measured {:.2} N, replayed {:.2} N",
        report.verdict.effect,
        report.verdict.reason,
        report.localisation.mean_normal_force_measured,
        report.localisation.mean_normal_force_simulated
    );
    report
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
/// and on it a no-effect case reads `none`, a device bias is recovered to a few millinewtons
/// and a support is named, as on the fifteen-probing cases measured for the README (there 5 of
/// 10 right: a modulus change, up or down, and a tilt whose path misses a region are not).
#[test]
fn another_code_s_truth_levelled_reads_none_a_device_and_a_support() {
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

    let raw = independent_case(&root, &source, &specimen, "raw", 1.0, &[]);
    let ratio =
        raw.localisation.mean_normal_force_simulated / raw.localisation.mean_normal_force_measured;
    eprintln!("the replay presses ×{ratio:.3} the independent code's mean normal force");
    // measured 2.88 (+188%); the project's own refined meshes put it at ×3.0-4.4
    assert!(
        (2.4..=3.4).contains(&ratio),
        "replay ×{ratio} the independent code's force"
    );

    let none = independent_case(&root, &source, &specimen, "none", ratio * 0.95, &[]);
    assert_eq!(none.verdict.effect, "none", "{}", none.verdict.reason);

    let bias = [0.25, -0.15, 0.30];
    let device = independent_case(
        &root,
        &source,
        &specimen,
        "device",
        ratio * 1.05,
        &["device=0.25,-0.15,0.3"],
    );
    assert_eq!(device.verdict.effect, "device", "{}", device.verdict.reason);
    for (axis, truth) in ["bias_x", "bias_y", "bias_z"].iter().zip(bias) {
        let fitted = param(&device, axis);
        assert!(
            (fitted - truth).abs() < 0.02,
            "{axis} {fitted} N for {truth} N"
        );
    }

    let support = independent_case(
        &root,
        &source,
        &specimen,
        "support",
        ratio,
        &["support=3e8"],
    );
    assert_eq!(
        support.verdict.effect, "support",
        "{}",
        support.verdict.reason
    );
    let _ = std::fs::remove_dir_all(&root);
}
