//! The replay model against a reference it was not built with: a rigid ball pressed
//! quasi-statically into a thick elastic block, against Hertz's closed form
//! F = 4/3 · E* · √R · d^{3/2}, E* = E / (1 − ν²) (issue 15, point 1).
//!
//! The block is the project's FE and contact model as the gap diagnosis replays it
//! (corotational tets, the probe's collision sphere against the boundary triangles, the
//! contact LCP), on a graded structured mesh: 0.15 mm hexes under the ball growing by 1.4× per
//! cell towards the block's sides, 18 mm wide and 9 mm deep with its base fixed, so the
//! contact radius (a = √(R·d) ≤ 0.95 mm) spans several elements and the block is ≥ 9
//! contact radii across — a half-space to within a few percent. What differs from Hertz is
//! then the model itself: linear tets under a curved load, and a contact that holds the ball
//! at up to `FEATURES_PER_SPHERE` surface features.
//!
//! Run with `--nocapture` to see the table; the README quotes it.

use nalgebra::{Point3, UnitQuaternion};
use physics_node::fem::test_meshes::{graded_box_mesh, write_msh22};
use physics_node::sim::Simulation;

const RADIUS_M: f64 = 3.0e-3;
const DEPTHS_MM: [f64; 3] = [0.1, 0.2, 0.3];
const HALF_WIDTH_M: f64 = 9.0e-3;
const FINE_CELL_M: f64 = 0.15e-3;
const GRADING: f64 = 1.4;

/// Grid coordinates from 0 outwards: cells of `h0` growing by `g` until `extent` is covered
/// (the last cell clipped to it).
fn graded(h0: f64, g: f64, extent: f64) -> Vec<f64> {
    let mut out = vec![0.0];
    let mut h = h0;
    while *out.last().unwrap() < extent - 1e-12 {
        let next = (out.last().unwrap() + h).min(extent);
        // A sliver last cell would spoil the mesh: merge it into the previous one.
        if extent - next < 0.3 * h && next < extent {
            out.push(extent);
            break;
        }
        out.push(next);
        h *= g;
    }
    out
}

/// Hertz: rigid sphere on an elastic half-space.
fn hertz(e: f64, nu: f64, radius: f64, depth: f64) -> f64 {
    4.0 / 3.0 * e / (1.0 - nu * nu) * radius.sqrt() * depth.powf(1.5)
}

/// The ball pressed into the block at [`DEPTHS_MM`]: the largest deviation from Hertz.
fn press_the_block(hertz_patch: bool) -> f64 {
    // The block, centred on x = y = 0, top face at z = 0 (the ball presses at the origin).
    let half = graded(FINE_CELL_M, GRADING, HALF_WIDTH_M);
    let mut xs: Vec<f64> = half.iter().rev().map(|x| -x).collect();
    xs.extend_from_slice(&half[1..]);
    let zs: Vec<f64> = graded(FINE_CELL_M, GRADING, HALF_WIDTH_M)
        .iter()
        .rev()
        .map(|z| -z)
        .collect();
    let mesh = graded_box_mesh(&xs, &xs, &zs);
    let bottom: Vec<String> = (0..mesh.nodes.len())
        .filter(|&i| mesh.nodes[i].z <= -HALF_WIDTH_M + 1e-12)
        .map(|i| i.to_string())
        .collect();

    // one directory per press: the two tests run side by side and each removes its own
    let dir = std::env::temp_dir().join(format!(
        "physics-node-hertz-{}-{}",
        std::process::id(),
        if hertz_patch { "patch" } else { "points" }
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let msh = dir.join("block.msh");
    write_msh22(&mesh, &msh).unwrap();
    let fixed = dir.join("fixed.txt");
    std::fs::write(&fixed, bottom.join(" ")).unwrap();

    let mut scene = launch_config::SceneConfig {
        gravity: [0.0; 3],
        ..Default::default()
    };
    scene.meniscus.mesh = msh.display().to_string();
    scene.meniscus.fixed = fixed.display().to_string();
    scene.meniscus.support_stiffness = 0.0;
    scene.material.strain_stiffening = 0.0;
    scene.contact.friction = 0.0; // Hertz is frictionless
    scene.contact.lcp_max_iterations = 3000;
    scene.probe.model = "sphere".into();
    scene.probe.tip_radius = RADIUS_M;
    scene.solver.kind = launch_config::scene::SolverKind::CgWarpedCholesky;
    scene.solver.cg_iterations = 200;
    scene.contact.hertz_patch = hertz_patch;
    let (e, nu) = (3.5e6, 0.29); // the default preset "lateral"
    let mut sim = Simulation::new(&scene, &dir).unwrap();

    // The ball's centre above the origin, `depth` into the block.
    let pose = |depth: f64| {
        physics_node::probe::pose(
            Point3::new(0.0, 0.0, RADIUS_M - depth),
            UnitQuaternion::identity(),
        )
    };
    sim.teleport_probe(&pose(-0.05e-3));
    println!(
        "block {} nodes, {} tets; ball R {} mm, E {} MPa, ν {nu}",
        mesh.nodes.len(),
        mesh.tets.len(),
        RADIUS_M * 1e3,
        e * 1e-6
    );
    println!("depth_mm  F_model_N  F_hertz_N  error_%  active_contacts");
    let mut worst: f64 = 0.0;
    let mut depth_prev = -0.05e-3;
    for &d_mm in &DEPTHS_MM {
        let d = d_mm * 1e-3;
        // Ramp over 5 steps, hold 10, average the last 5 (quasi-static at 10 ms steps).
        let mut f_mean = 0.0;
        for k in 0..15 {
            let s = ((k + 1) as f64 / 5.0).min(1.0);
            sim.set_probe_kinematic(&pose(depth_prev + (d - depth_prev) * s));
            sim.step().unwrap();
            assert_eq!(
                sim.contact_frame().physics_faults,
                0,
                "faulty step at {d_mm} mm"
            );
            if k >= 10 {
                f_mean += sim.contact_force()[2] / 5.0;
            }
        }
        depth_prev = d;
        let frame = sim.contact_frame();
        let active = (0..sim.contacts().len())
            .filter(|&k| frame.lambda[3 * k] > 0.0)
            .count();
        let reference = hertz(e, nu, RADIUS_M, d);
        let error = (f_mean - reference) / reference;
        worst = worst.max(error.abs());
        println!(
            "{d_mm:8.2}  {f_mean:9.4}  {reference:9.4}  {:+7.1}  {active}",
            error * 100.0
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
    println!("largest deviation from Hertz: {:.1}%", worst * 100.0);
    worst
}

#[test]
fn ball_on_thick_block_follows_hertz() {
    let worst = press_the_block(false);
    // Reached (README): +19%, +11%, +6% at 0.1, 0.2, 0.3 mm — stiffer than Hertz where the
    // contact radius spans only ~4 cells, converging as it spans more. With eight features
    // per sphere the model was 22–42% softer (the surface between the held points sank into
    // the ball); with a full candidate list that dropped new features it found no contact at
    // all (0 N). The bound is what is reached, with margin.
    assert!(
        worst < 0.3,
        "ball on block deviates {:.0}% from Hertz",
        worst * 100.0
    );
}

/// The same press with the ball's force spread over its Hertz patch
/// (`[scene.contact] hertz_patch`): one contact whose weights are the Hertz pressure on the
/// nodes under the patch, its gap the pressure-weighted mean over the patch.
#[test]
fn ball_spread_over_its_hertz_patch_on_a_thick_block() {
    let worst = press_the_block(true);
    // Reached (README): +23%, +22%, +19% at 0.1, 0.2, 0.3 mm, the patch's 42–125 nodes cut
    // to the 32 a patch carries (`PATCH_NODES`; with 64, +26%, +26%, +25%). A load of
    // Hertz's shape on linear tets is stiffer than the continuum (the bulk floor of
    // `floor_patch_convergence`); the closest points above let the surface between them sink
    // into the ball, which offsets it. The bound is what is reached, with margin.
    assert!(
        worst < 0.3,
        "ball spread over its patch deviates {:.0}% from Hertz",
        worst * 100.0
    );
}
