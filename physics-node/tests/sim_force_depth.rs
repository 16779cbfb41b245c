//! Force–depth curve of a 1.5 mm sphere pressed along the surface normal into the body of the
//! study's lateral meniscus (E = 3.5 MPa, its fixed nodes), 0.25–3 mm, printed beside a Hertz
//! estimate, on the study mesh and on the same mesh refined once (every tet split in 8).
//! Asserts only sane behaviour: positive, monotonic force.
//!
//! Run with `cargo test -p physics-node --test sim_force_depth -- --nocapture` to see the table.

use nalgebra::{Point3, UnitQuaternion, Vector3};
use physics_node::fem::test_meshes::write_refined_once;
use physics_node::mesh::Midpoints;
use physics_node::sim::Simulation;
use std::path::Path;

const DEPTHS_MM: [f64; 9] = [0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0];

/// Presses the sphere kinematically at the mid-body site; returns (depth mm, normal force N).
fn curve(
    scene: &launch_config::SceneConfig,
    data: &Path,
    site: &(Point3<f64>, Vector3<f64>),
) -> Vec<(f64, f64)> {
    let mut sim = Simulation::new(scene, data).unwrap();
    let (p, n) = *site;
    let r = scene.probe.tip_radius;
    let q = UnitQuaternion::identity();
    sim.teleport_probe(&physics_node::probe::pose(p + n * (r + 0.05e-3), q));
    let mut out = Vec::new();
    let mut depth_prev = -0.05e-3;
    for &d_mm in &DEPTHS_MM {
        let d = d_mm * 1e-3;
        // Ramp over 10 steps, then hold 60 steps; average the last 10 (quasi-static).
        let mut f_mean = 0.0;
        for k in 0..70 {
            let s = ((k + 1) as f64 / 10.0).min(1.0);
            let depth = depth_prev + (d - depth_prev) * s;
            sim.set_probe_kinematic(&physics_node::probe::pose(p + n * (r - depth), q));
            sim.step().unwrap();
            if k >= 60 {
                f_mean += Vector3::from(sim.contact_force()).dot(&n) / 10.0;
            }
        }
        depth_prev = d;
        out.push((d_mm, f_mean));
    }
    out
}

#[test]
fn force_depth_curve_on_study_lateral_mesh_and_refined() {
    let Some(data) = physics_node::fem::test_meshes::study_data("sim_force_depth") else {
        return;
    };
    let mut scene = launch_config::SceneConfig::default();
    scene.meniscus.mesh = "study:lateral".into();
    scene.probe.model = "sphere".into();
    scene.probe.tip_radius = 1.5e-3;
    // Sparse direct FEM solve: SOFA's plain CG (25 iterations, no preconditioner) does not
    // converge on the refined mesh and the quasi-static press then diverges.
    scene.solver.kind = launch_config::scene::SolverKind::Direct;
    let loaded = physics_node::mesh::load_scene_mesh(&scene.meniscus, &data).unwrap();
    let site = loaded
        .probing_sites
        .iter()
        .find(|s| s.region == 2)
        .map(|s| (s.point, s.normal.normalize()))
        .expect("mid-body probing site");
    let coarse = curve(&scene, &data, &site);

    // Refined once, same geometry and support.
    let dir = std::env::temp_dir().join(format!("physics-node-refined-{}", std::process::id()));
    let files =
        write_refined_once(&loaded.mesh, &loaded.fixed_nodes, Midpoints::Flat, &dir).unwrap();
    let mut fine_scene = scene.clone();
    fine_scene.meniscus.mesh = files.msh.display().to_string();
    fine_scene.meniscus.fixed = files.fixed_list.display().to_string();
    let fine = curve(&fine_scene, &data, &site);
    let _ = std::fs::remove_dir_all(&dir);

    // Hertz: rigid sphere on an elastic half-space, F = 4/3 E* √R d^{3/2}.
    let (e, nu) = (3.5e6, 0.29);
    let e_star = e / (1.0 - nu * nu);
    let radius: f64 = 1.5e-3;
    println!(
        "study lateral mesh: {} nodes, refined: {} nodes / {} tets; site {:?} normal {:?}",
        loaded.mesh.nodes.len(),
        files.mesh.nodes.len(),
        files.mesh.tets.len(),
        site.0,
        site.1
    );
    println!("depth_mm  F_study_N  F_refined_N  F_hertz_N");
    for ((d, fc), (_, ff)) in coarse.iter().zip(&fine) {
        let hertz = 4.0 / 3.0 * e_star * radius.sqrt() * (d * 1e-3_f64).powf(1.5);
        println!("{d:8.2}  {fc:9.3}  {ff:11.3}  {hertz:9.3}");
    }
    for curve in [&coarse, &fine] {
        for w in curve.windows(2) {
            assert!(
                w[1].1 >= w[0].1 - 1e-6,
                "force must not drop with depth: {curve:?}"
            );
        }
        assert!(
            curve.iter().skip(1).all(|&(_, f)| f > 0.0),
            "pressing must push back: {curve:?}"
        );
        assert!(curve.iter().all(|&(_, f)| f.is_finite()));
    }
    // Refinement softens a point-like indentation (more surface dofs under the sphere).
    assert!(fine.last().unwrap().1 < coarse.last().unwrap().1 * 1.5);
}
