//! Calibration closes the loop (issue 13, point 2): a generated experiment with one tissue
//! effect injected is diagnosed with calibration, and the experiment re-simulated in the
//! calibrated launch file's scene (the replay model built from that file, no effect applied
//! on top) reproduces the held-out error the report promised.
use gap_diagnosis::calibrate::{self, Input, SceneChange};
use gap_diagnosis::dataset::{self, BuildOptions};
use gap_diagnosis::reality::{RealitySpec, TruthMesh};
use gap_diagnosis::{self as gap, fit, Effect, Options, SimForceModel};
use std::path::{Path, PathBuf};

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("arthrosim-calibrate-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Two probings per region (six trials, leave-one-region-out) and the tissue candidates
/// only: the loop is the point here, not the ranking among all nine effects.
fn options() -> Options {
    Options {
        effects: vec![Effect::Modulus, Effect::Hardening, Effect::Support],
        pairs: false,
        ..Options::default()
    }
}

/// RMSE of the experiment replayed in the scene of `launch` (a launch file on disk), N.
fn resimulated_rmse(exp_dir: &Path, launch: &Path, dt: f64) -> f64 {
    let data = gap::data_dir();
    let exp = gap::load_experiment(exp_dir, &data).unwrap();
    let file = launch_config::load(launch).expect("the calibrated launch file validates");
    let model = SimForceModel::from_scene(file.scene, &data);
    let trials = dataset::build(
        &exp,
        &model,
        &[],
        &BuildOptions {
            dt,
            progress: false,
            contact_knot: false,
            material_knot: false,
        },
    )
    .unwrap();
    fit::Baseline::of(&trials).rmse
}

/// `within_below`: how far below the promised held-out error the calibrated scene's own error
/// may be (1 − 5% where the folds' fits agree with the overall one).
fn close_the_loop(effect: &str, key: &str, within_below: f64) {
    let dir = scratch(effect.split('=').next().unwrap());
    let exp_dir = dir.join("experiment");
    let mut spec = RealitySpec::from_effects(&[effect], 3).unwrap();
    // the truth on the replay's own mesh (with its stiffness offset): a calibrated scene can
    // reproduce it, which is what this loop checks; a refined truth's floor is the
    // self-test's matter
    spec.truth_mesh = TruthMesh::Replay;
    spec.probings_per_region = 2;
    gap::reality::write_experiment(&spec, &exp_dir, &dir.join("truth.json")).unwrap();

    let opts = options();
    let (report, cal) =
        calibrate::calibrate_input(&Input::Path(exp_dir.clone()), None, &opts).expect("diagnosis");
    let injected = effect.split('=').next().unwrap();
    assert_eq!(report.verdict.effect, injected, "{}", report.verdict.reason);
    assert!(
        cal.changes
            .iter()
            .any(|c| matches!(c, SceneChange::Set { key: k, .. } if k == key)),
        "{:?}",
        cal.changes
    );
    let out = dir.join("calibrated.toml");
    calibrate::write_launch(&cal, &out).unwrap();

    let resim = resimulated_rmse(&exp_dir, &out, opts.dt);
    let promised = report.heldout.winner_rmse;
    let baseline = report.heldout.baseline_rmse;
    let fitted = report
        .ranking
        .iter()
        .find(|c| c.effect == report.verdict.effect)
        .unwrap()
        .fit_rmse;
    eprintln!(
        "{effect}: baseline {baseline:.4} N, promised held-out {promised:.4} N, fit on all \
         trials {fitted:.4} N, re-simulated in the calibrated scene {resim:.4} N; {:?}; {:?}",
        cal.changes, cal.refined
    );
    assert!(
        promised < 0.5 * baseline,
        "the fit should remove most of the injected effect: {promised} vs {baseline}"
    );
    // the written scene renders the fitted model: its physics gives the error of the fit
    // (an interpolated re-simulated effect: up to the physics' own step-to-step roughness,
    // a few hundredths of a newton here, between a re-simulation and its neighbours)
    let tol = if within_below >= 0.95 { 0.05 } else { 0.10 };
    assert!(
        (resim - fitted).abs() <= tol * fitted,
        "re-simulated {resim:.4} N vs fitted {fitted:.4} N (> {tol} apart)"
    );
    // and what the report promised on held-out trials, within 5%, or better: a held-out
    // error carries each fold's own fit, the written scene the fit on every trial
    assert!(
        resim <= 1.05 * promised,
        "re-simulated {resim:.4} N, promised {promised:.4} N"
    );
    assert!(
        resim >= within_below * promised,
        "re-simulated {resim:.4} N is far below the promised {promised:.4} N: the promise \
         was not about this scene"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn calibrated_modulus_reproduces_the_promised_heldout_error() {
    // a post-processing effect: every fold fits the same scale, held-out = in-sample
    close_the_loop("modulus=0.6", "scene.material.modulus_scale", 0.95);
}

#[test]
fn calibrated_support_reproduces_the_promised_heldout_error() {
    // a re-simulated effect: the folds' fits spread around the overall one (six trials; the
    // replayed path is reconstructed from ~38 Hz samples), and each fold fits two parameters
    // that trade against each other (the compliance and the stiffness nuisance, on two
    // regions), so the scene written from the fit on every trial may do up to 35% better than
    // the held-out promise (reached with presses of 1.0–1.8 mm: 0.0352 N against 0.0498 N,
    // 29% better, truth offset ×0.930: written 1372 N/m and modulus ×0.952 for a truth of
    // 1395 N/m and ×0.930; at the study's 0.5–1.2 mm: 0.0213 N against 0.0212 N, written
    // 1397 N/m and ×0.927)
    close_the_loop("support=1500", "scene.meniscus.support_stiffness", 0.65);
}

/// No effect injected: the verdict is `none` and the written launch file's scene is the
/// input scene, unchanged (and says so).
#[test]
fn verdict_none_writes_the_input_scene_unchanged() {
    let dir = scratch("none");
    let exp_dir = dir.join("experiment");
    let mut spec = RealitySpec::from_effects(&["none"], 5).unwrap();
    spec.truth_mesh = TruthMesh::Replay;
    spec.probings_per_region = 2;
    gap::reality::write_experiment(&spec, &exp_dir, &dir.join("truth.json")).unwrap();
    let (report, cal) =
        calibrate::calibrate_input(&Input::Path(exp_dir.clone()), None, &options()).unwrap();
    assert_eq!(report.verdict.effect, "none", "{}", report.verdict.reason);
    assert!(cal.unchanged() && cal.changes.is_empty());
    let out = dir.join("calibrated.toml");
    let written = calibrate::write_launch(&cal, &out).unwrap();
    let data = gap::data_dir();
    let exp = gap::load_experiment(&exp_dir, &data).unwrap();
    let input = SimForceModel::for_experiment(&exp, &data).unwrap().scene;
    assert_eq!(written.scene, input);
    let text = std::fs::read_to_string(&out).unwrap();
    assert!(
        text.contains("Verdict none") && text.contains("unchanged"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
