//! Exploration runs (ignored): `cargo test -p recordings --test gap_dev -- --ignored --nocapture`.
use recordings::gap::{self, reality::RealitySpec};
use std::time::Instant;

#[test]
#[ignore]
fn explore_case() {
    let eff = std::env::var("GAP_EFFECT").unwrap_or_else(|_| "modulus=0.6".into());
    let effs: Vec<&str> = eff.split(';').collect();
    let mut spec = RealitySpec::from_effects(&effs, 7).unwrap();
    if let Ok(n) = std::env::var("GAP_PROBINGS") {
        spec.probings_per_region = n.parse().unwrap();
    }
    let tmp = std::env::temp_dir().join(format!("gap_dev_{}", std::process::id()));
    let t = Instant::now();
    let truth = gap::reality::write_experiment(&spec, &tmp.join("exp"), &tmp.join("truth.json")).unwrap();
    eprintln!("truth {} generated in {:.1}s", truth.label, t.elapsed().as_secs_f64());
    let t = Instant::now();
    let r = gap::diagnose_dir(&tmp.join("exp"), &gap::Options { progress: true, ..Default::default() }).unwrap();
    eprintln!("diagnosed in {:.1}s", t.elapsed().as_secs_f64());
    eprintln!("noise {:.4} lag {:?} base rmse {:.4}", r.noise_sigma, r.lag_median_s, r.heldout.baseline_rmse);
    eprintln!("{}", r.localisation.summary);
    for c in &r.ranking {
        eprintln!(
            "{:24} k={} held {:.4} shrink {:5.1}% dBIC {:9.1} score {:9.1} params {:?}",
            c.effect,
            c.n_params,
            c.heldout_rmse,
            100.0 * c.heldout_shrink,
            c.delta_bic,
            c.score,
            c.params.iter().map(|p| format!("{}={:.4}±{:.4}", p.name, p.value, p.std)).collect::<Vec<_>>()
        );
    }
    eprintln!("verdict {} ({:.1}%): {}", r.verdict.effect, 100.0 * r.verdict.heldout_shrink, r.verdict.reason);
    gap::write_report(&r, &tmp.join("report")).unwrap();
    eprintln!("report in {}", tmp.join("report").display());
}

#[test]
#[ignore]
fn explore_paths() {
    use gap::model::{ForceModel, Variant};
    let model = gap::SimForceModel::from_scene(launch_config::SceneConfig::default(), &gap::data_dir());
    let sim = model.simulation(&Variant::default(), 0.01).unwrap();
    let sites: Vec<_> = sim.probing_sites().iter().step_by(2).cloned().collect();
    for s in &sites {
        for (depth, slide) in [(1.6e-3, false), (2.8e-3, false), (2.2e-3, true)] {
            let n = [s.normal.x, s.normal.y, s.normal.z];
            let sl = slide.then_some([n[2], 0.0, -n[0]]);
            let mut path = gap::reality::protocol_path([s.point.x, s.point.y, s.point.z], n, depth, sl, 0.01);
            if let Ok(q) = std::env::var("GAP_Q") {
                let q: Vec<f64> = q.split(',').map(|v| v.parse().unwrap()).collect();
                path.poses.iter_mut().for_each(|p| p.orientation = [q[0], q[1], q[2], q[3]]);
            }
            let t = Instant::now();
            let r = model.replay_untilted(&Variant::default(), &path);
            match r {
                Ok(f) => {
                    let peak = f.iter().map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()).fold(0.0, f64::max);
                    eprintln!("region {} depth {:.1} slide {} steps {} peak {:.3} N in {:.2}s", s.region, depth * 1e3, slide, f.len(), peak, t.elapsed().as_secs_f64());
                }
                Err(e) => eprintln!("region {} depth {:.1} slide {}: {e}", s.region, depth * 1e3, slide),
            }
        }
    }
}
