//! The replay model's error floor against an independent discretisation (issue 15, point 1):
//! a no-effect probing of the study's lateral mesh replayed by the gap diagnosis' model
//! (study mesh, ball tip, the default offline solve: CG to 1e-6) against a direct solve on the same
//! specimen refined once (every tet split into eight; eight times the elements, a contact
//! surface with four times the facets).
//!
//! Reads the study data (`ARTHROSIM_DATA`); required under `CI=true`, skipped with a note
//! otherwise.
use gap_diagnosis::model::{replay, Variant};
use gap_diagnosis::{reality::protocol_path, Region, SimForceModel};
use launch_config::scene::OfflineSolver;
use launch_config::SceneConfig;
use physics_node::mesh::{write_refined_once, Midpoints};

use gap_diagnosis::signal::dot;

/// The study's lateral mesh probed with the ball tip, as the floor tests replay it.
fn study_ball_scene() -> SceneConfig {
    let mut scene = SceneConfig::default();
    scene.meniscus.mesh = "study:lateral".into();
    scene.probe.model = "sphere".into();
    scene
}

/// Agreement of one trial: mean normal force of each, and the RMSE of the force vector over
/// the whole trial and over its sliding phase.
struct Agreement {
    mean_model: f64,
    mean_reference: f64,
    rmse: f64,
    rmse_slide: f64,
}

/// One no-effect probing per region at the study's press depths (the middle one sliding
/// 3 mm), replayed by `model` and by `reference`; their agreement per probing, printed.
fn compare_over_protocol(
    model: &SimForceModel,
    reference: &SimForceModel,
    scene: &SceneConfig,
    labels: (&str, &str),
) -> Vec<Agreement> {
    let sites = model.sites().unwrap();
    let standoff = scene.probe.tip_radius;
    let mut results = Vec::new();
    for (region, depth, slide) in [
        (Region::Posterior, 0.8e-3, false),
        (Region::Mid, 1.0e-3, true),
        (Region::Anterior, 1.2e-3, false),
    ] {
        let site = sites
            .iter()
            .filter(|s| s.region == region)
            .nth(2)
            .copied()
            .unwrap();
        let n = site.normal;
        let slide_dir = slide.then(|| {
            let a = if n[2].abs() < 0.9 {
                [0.0, 0.0, 1.0]
            } else {
                [1.0, 0.0, 0.0]
            };
            let k = dot(a, n);
            let t = [a[0] - k * n[0], a[1] - k * n[1], a[2] - k * n[2]];
            let l = dot(t, t).sqrt();
            [t[0] / l, t[1] / l, t[2] / l]
        });
        let path = protocol_path(site.point, n, depth, standoff, slide_dir, 0.02);
        let fm = replay(model, &Variant::default(), &path).unwrap();
        let fr = replay(reference, &Variant::default(), &path).unwrap();
        // the slide: the steps whose tangential offset is changing or held at its end
        let tangential: Vec<f64> = path
            .poses
            .iter()
            .map(|p| {
                let d = [
                    p.position[0] - path.poses[0].position[0],
                    p.position[1] - path.poses[0].position[1],
                    p.position[2] - path.poses[0].position[2],
                ];
                let k = dot(d, n);
                let t = [d[0] - k * n[0], d[1] - k * n[1], d[2] - k * n[2]];
                dot(t, t).sqrt()
            })
            .collect();
        let err2 = |a: [f64; 3], b: [f64; 3]| {
            (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
        };
        let len = fm.len() as f64;
        let sliding: Vec<usize> = (0..fm.len()).filter(|&k| tangential[k] > 1e-5).collect();
        let a = Agreement {
            mean_model: fm.iter().map(|f| dot(*f, n)).sum::<f64>() / len,
            mean_reference: fr.iter().map(|f| dot(*f, n)).sum::<f64>() / len,
            rmse: (fm.iter().zip(&fr).map(|(a, b)| err2(*a, *b)).sum::<f64>() / len).sqrt(),
            rmse_slide: if sliding.is_empty() {
                0.0
            } else {
                (sliding.iter().map(|&k| err2(fm[k], fr[k])).sum::<f64>() / sliding.len() as f64)
                    .sqrt()
            },
        };
        let peak = fr.iter().map(|f| dot(*f, n)).fold(0.0, f64::max);
        eprintln!(
            "{:9} depth {:.1} mm{}: mean normal force {:.3} N ({}) vs {:.3} N ({}), {:+.1}%; \
             RMSE {:.3} N (slide {:.3} N); reference peak {:.2} N",
            region.name(),
            depth * 1e3,
            if slide { " + 3 mm slide" } else { "" },
            a.mean_model,
            labels.0,
            a.mean_reference,
            labels.1,
            100.0 * (a.mean_model / a.mean_reference - 1.0),
            a.rmse,
            a.rmse_slide,
            peak
        );
        assert!(
            peak > 0.5,
            "{}: no contact in the reference ({peak} N)",
            region.name()
        );
        results.push(a);
    }
    results
}

/// Mean normal force difference (%, over all probings) and force RMSE (N) of the agreements.
fn summary(results: &[Agreement]) -> (f64, f64) {
    let mean_m: f64 = results.iter().map(|a| a.mean_model).sum();
    let mean_r: f64 = results.iter().map(|a| a.mean_reference).sum();
    let rmse = (results.iter().map(|a| a.rmse * a.rmse).sum::<f64>() / results.len() as f64).sqrt();
    (100.0 * (mean_m / mean_r - 1.0), rmse)
}

#[test]
fn replay_model_against_the_refined_study_mesh() {
    let Some(data) = physics_node::fem::test_meshes::study_data("gap_floor") else {
        return;
    };
    let scene = study_ball_scene();
    // the replay model as the diagnosis runs it (default offline solve)
    assert_eq!(scene.solver.offline, OfflineSolver::Cg);
    let model = SimForceModel::from_scene(scene.clone(), &data);

    let loaded = physics_node::mesh::load_scene_mesh(&scene.meniscus, &data).unwrap();
    let dir = std::env::temp_dir().join(format!("gap_floor_{}", std::process::id()));
    let files =
        write_refined_once(&loaded.mesh, &loaded.fixed_nodes, Midpoints::Flat, &dir).unwrap();
    let mut fine = scene.clone();
    fine.meniscus.mesh = files.msh.display().to_string();
    fine.meniscus.fixed = files.fixed_list.display().to_string();
    fine.solver.offline = OfflineSolver::Direct;
    let reference = SimForceModel::from_scene(fine, &data);
    let (n_coarse, n_fine) = (
        model
            .simulation(&Variant::default(), 0.02)
            .unwrap()
            .node_count(),
        reference
            .simulation(&Variant::default(), 0.02)
            .unwrap()
            .node_count(),
    );

    let results = compare_over_protocol(&model, &reference, &scene, ("replay", "refined"));
    let _ = std::fs::remove_dir_all(&dir);
    let (diff, rmse) = summary(&results);
    // What this measures (README, "The replay model against a refined study mesh"): the
    // study mesh (258 nodes, 2.2 mm facets) is far stiffer under a ball than the same
    // specimen refined once — the floor is the discretisation, not the solve. The bounds are
    // what the model reaches now, with a margin, so a change that widens the floor fails
    // here; the target (3%, 0.4 N) is not met.
    assert!(
        diff.abs() < 160.0,
        "mean normal force {diff:+.1}% from the refined reference (measured +112%)"
    );
    assert!(
        rmse < 18.0,
        "RMSE {rmse:.3} N against the refined reference (measured 13.4 N)"
    );
    eprintln!(
        "floor: study:lateral ({n_coarse} nodes) vs refined once ({n_fine} nodes), ball tip, \
         direct solve: mean normal force {diff:+.1}%, RMSE {rmse:.3} N over the three trials"
    );
}

/// Is the refined-once reference converged? The same probings on the study mesh refined once
/// and refined twice (every tet split into eight, twice: ~10,000 nodes), both with a direct
/// solve, and the diagnosis' replay against the twice-refined one, with the new boundary nodes
/// on the facets or on the smooth surface (`Midpoints`). A measurement for the README (issue
/// 15, point 1: "a converged refined FE"), too slow for the suite in the dev profile:
/// `cargo test --release --test gap_floor -- --ignored`.
/// `hertz_patch`: every model's ball spread over its Hertz patch (`[scene.contact]
/// hertz_patch`), the replay's and the references' alike.
fn refined_once_against_refined_twice(midpoints: Midpoints, hertz_patch: bool) {
    let Some(data) = physics_node::fem::test_meshes::study_data("gap_floor") else {
        return;
    };
    let mut scene = study_ball_scene();
    scene.contact.hertz_patch = hertz_patch;
    let loaded = physics_node::mesh::load_scene_mesh(&scene.meniscus, &data).unwrap();
    let dir = std::env::temp_dir().join(format!(
        "gap_floor_twice_{midpoints:?}_{hertz_patch}_{}",
        std::process::id()
    ));
    let on = |files: &physics_node::mesh::RefinedFiles| {
        let mut s = scene.clone();
        s.meniscus.mesh = files.msh.display().to_string();
        s.meniscus.fixed = files.fixed_list.display().to_string();
        s.solver.offline = OfflineSolver::Direct;
        SimForceModel::from_scene(s, &data)
    };
    let once = write_refined_once(
        &loaded.mesh,
        &loaded.fixed_nodes,
        midpoints,
        &dir.join("once"),
    )
    .unwrap();
    let twice = write_refined_once(&once.mesh, &once.fixed, midpoints, &dir.join("twice")).unwrap();
    let (m1, m2) = (on(&once), on(&twice));
    let replay_model = SimForceModel::from_scene(scene.clone(), &data);
    let started = std::time::Instant::now();
    let once_twice = compare_over_protocol(&m1, &m2, &scene, ("refined once", "refined twice"));
    let replay_twice =
        compare_over_protocol(&replay_model, &m2, &scene, ("replay", "refined twice"));
    let (d12, r12) = summary(&once_twice);
    let (d02, r02) = summary(&replay_twice);
    println!(
        "{{\"midpoints\":\"{midpoints:?}\",\"hertz_patch\":{hertz_patch},\"refined_once_vs_twice_mean_normal_pct\":{d12:.2},\"refined_once_vs_twice_rmse_n\":{r12:.4},\
         \"replay_vs_twice_mean_normal_pct\":{d02:.2},\"replay_vs_twice_rmse_n\":{r02:.4},\
         \"twice_nodes\":{},\"seconds\":{:.1}}}",
        m2.simulation(&Variant::default(), 0.02).unwrap().node_count(),
        started.elapsed().as_secs_f64()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
#[ignore = "minutes: ~10,000-node direct solves (run with --release -- --ignored)"]
fn refined_once_against_refined_twice_on_the_facets() {
    refined_once_against_refined_twice(Midpoints::Flat, false);
}

#[test]
#[ignore = "minutes: ~10,000-node direct solves (run with --release -- --ignored)"]
fn refined_once_against_refined_twice_on_the_smooth_surface() {
    refined_once_against_refined_twice(Midpoints::Smooth, false);
}

/// The same with every ball spread over its Hertz patch (README, "A contact spread over the
/// Hertz patch"): +50% refined once against twice, +201% and +225% the replay against twice,
/// where the closest points give +90–94% and +311–344%.
#[test]
#[ignore = "minutes: ~10,000-node direct solves (run with --release -- --ignored)"]
fn refined_once_against_refined_twice_on_the_facets_with_the_hertz_patch() {
    refined_once_against_refined_twice(Midpoints::Flat, true);
}

#[test]
#[ignore = "minutes: ~10,000-node direct solves (run with --release -- --ignored)"]
fn refined_once_against_refined_twice_on_the_smooth_surface_with_the_hertz_patch() {
    refined_once_against_refined_twice(Midpoints::Smooth, true);
}
