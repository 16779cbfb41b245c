//! Calibration closes the loop (issue 13, point 2): a generated experiment with one tissue
//! effect injected is diagnosed with calibration, and the experiment re-simulated in the
//! calibrated launch file's scene (the replay model built from that file, no effect applied
//! on top) reproduces the held-out error the report promised.
use recordings::gap::calibrate::{self, Input, SceneChange};
use recordings::gap::dataset::{self, BuildOptions};
use recordings::gap::reality::RealitySpec;
use recordings::gap::{self, fit, Effect, Options, SimForceModel};
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
        },
    )
    .unwrap();
    fit::Baseline::of(&trials).rmse
}

fn close_the_loop(effect: &str, key: &str) {
    let dir = scratch(effect.split('=').next().unwrap());
    let exp_dir = dir.join("experiment");
    let mut spec = RealitySpec::from_effects(&[effect], 3).unwrap();
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
    eprintln!(
        "{effect}: baseline {baseline:.4} N, promised held-out {promised:.4} N, \
         re-simulated in the calibrated scene {resim:.4} N; {:?}",
        cal.changes
    );
    assert!(
        promised < 0.5 * baseline,
        "the fit should remove most of the injected effect: {promised} vs {baseline}"
    );
    assert!(
        (resim - promised).abs() <= 0.05 * promised,
        "re-simulated {resim:.4} N vs promised {promised:.4} N (> 5% apart)"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn calibrated_modulus_reproduces_the_promised_heldout_error() {
    close_the_loop("modulus=0.6", "scene.material.modulus_scale");
}

#[test]
fn calibrated_support_reproduces_the_promised_heldout_error() {
    close_the_loop("support=1500", "scene.meniscus.support_stiffness");
}
