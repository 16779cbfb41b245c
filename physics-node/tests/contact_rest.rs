//! A probe resting on the tissue under gravity: the contact force balances its weight;
//! with friction the tangential force never exceeds μ times the normal force, and the probe
//! sticks when the slope is below the friction angle and slides above it.

use nalgebra::{Point3, UnitQuaternion, Vector3};
use physics_node::fem::test_meshes::{box_mesh, write_msh22};
use physics_node::sim::Simulation;
use std::path::PathBuf;

/// A 30 × 30 × 6 mm tissue block centred on the origin, top at z = 6 mm, bottom held.
fn block_scene(
    name: &str,
    friction: f64,
    gravity: Vector3<f64>,
) -> (launch_config::SceneConfig, PathBuf) {
    let mut mesh = box_mesh(0.03, 0.03, 0.006, 8, 8, 3);
    for p in &mut mesh.nodes {
        p.x -= 0.015;
        p.y -= 0.015;
    }
    let dir = std::env::temp_dir().join(format!("physics-node-{}-{}", name, std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("block.msh");
    write_msh22(&mesh, &path).unwrap();
    let mut scene = launch_config::SceneConfig::default();
    scene.meniscus.mesh = path.display().to_string();
    scene.gravity = [gravity.x, gravity.y, gravity.z];
    scene.contact.friction = friction;
    scene.probe.model = "sphere".into();
    // Free rigid sphere: no linear coupling; the angular coupling only keeps it upright.
    scene.probe.coupling_stiffness = 0.0;
    scene.probe.coupling_damping = 0.0;
    (scene, dir)
}

const TOP: f64 = 0.006;

#[test]
fn probe_resting_under_gravity_carries_its_weight() {
    let g = Vector3::new(0.0, 0.0, -9.81);
    let (scene, dir) = block_scene("rest", 0.0, g);
    let mut sim = Simulation::new(&scene, &dir).unwrap();
    // The mesh is read; the scratch folder can go.
    let _ = std::fs::remove_dir_all(&dir);
    let r = scene.probe.tip_radius;
    let q = UnitQuaternion::identity();
    sim.teleport_probe(&physics_node::probe::pose(
        Point3::new(0.0, 0.0, TOP + r + 0.5e-3),
        q,
    ));
    let weight = scene.probe.mass * 9.81;
    let mut touched = false;
    for step in 0..400 {
        sim.step().unwrap();
        touched |= sim.contact_count() > 0;
        let f = sim.contact_force();
        // Contact only pushes (never pulls) and, frictionless on a flat top, only along z.
        assert!(f[2] >= -1e-12, "step {step}: pulling contact force {f:?}");
    }
    assert!(touched);
    // Averaged over the last 100 steps (the tissue still rings a little).
    let mut fz = 0.0;
    let mut fxy: f64 = 0.0;
    for _ in 0..100 {
        sim.step().unwrap();
        let f = sim.contact_force();
        fz += f[2] / 100.0;
        fxy = fxy.max(f[0].hypot(f[1]));
    }
    println!("weight {weight:.6} N, mean normal force {fz:.6} N, max tangential {fxy:.3e} N");
    assert!(
        (fz - weight).abs() < 0.01 * weight,
        "normal force {fz} vs m·g {weight}"
    );
    // The dent under the sphere tilts the contact normal slightly.
    assert!(
        fxy < 0.02 * weight,
        "tangential force {fxy} on a frictionless flat top"
    );
    let p = sim.probe_pose().position;
    assert!(
        p[2] > TOP + r - 0.5e-3 && p[2] < TOP + r + 0.1e-3,
        "probe height {}",
        p[2]
    );
}

/// Runs a sphere resting on the block under gravity tilted by `deg` about y, with friction
/// μ; checks the cone of every contact every step and returns (mean Σ|f_t|, mean Σ f_n,
/// sliding distance), sums over contacts in each contact's own frame (the dent under the
/// sphere tilts the contact normals away from the block's z).
fn tilted(deg: f64, mu: f64, settle: usize, steps: usize, x_start: f64) -> (f64, f64, f64) {
    let th = deg.to_radians();
    let g = Vector3::new(9.81 * th.sin(), 0.0, -9.81 * th.cos());
    let (scene, dir) = block_scene(&format!("tilt{deg}"), mu, g);
    let mut sim = Simulation::new(&scene, &dir).unwrap();
    // The mesh is read; the scratch folder can go.
    let _ = std::fs::remove_dir_all(&dir);
    let r = scene.probe.tip_radius;
    let q = UnitQuaternion::identity();
    sim.teleport_probe(&physics_node::probe::pose(
        Point3::new(x_start, 0.0, TOP + r + 0.2e-3),
        q,
    ));
    for _ in 0..settle {
        sim.step().unwrap();
    }
    let x0 = sim.probe_pose().position[0];
    let (mut ft_sum, mut fn_sum) = (0.0, 0.0);
    for step in 0..steps {
        sim.step().unwrap();
        let frame = sim.contact_frame();
        for k in 0..frame.contact_count as usize {
            let ln = frame.lambda[3 * k];
            let lt = frame.lambda[3 * k + 1].hypot(frame.lambda[3 * k + 2]);
            assert!(ln >= 0.0, "step {step}: negative normal impulse {ln}");
            assert!(
                lt <= mu * ln * (1.0 + 1e-9) + 1e-15,
                "step {step}: |λt| {lt} > μ λn {}",
                mu * ln
            );
            ft_sum += lt / frame.dt_s;
            fn_sum += ln / frame.dt_s;
        }
    }
    let slide = sim.probe_pose().position[0] - x0;
    (ft_sum / steps as f64, fn_sum / steps as f64, slide)
}

#[test]
fn friction_sticks_below_the_friction_angle() {
    let mu = 0.5;
    let deg: f64 = 15.0; // tan 15° = 0.27 < μ
    let (ft, fnn, slide) = tilted(deg, mu, 150, 150, 0.0);
    println!("stick: Σ f_t {ft:.5} N, Σ f_n {fnn:.5} N, slide {slide:.3e} m");
    assert!(
        ft > 0.5 * fnn * deg.to_radians().tan(),
        "friction must carry the slope"
    );
    assert!(ft <= mu * fnn * (1.0 + 1e-6));
    assert!(
        slide.abs() < 1e-4,
        "a sticking probe must not slide ({slide} m in 1.5 s)"
    );
}

#[test]
fn friction_slides_above_the_friction_angle_at_mu_times_normal() {
    let mu = 0.3;
    // tan 17.5° = 0.315 > μ: slow slide (0.14 m/s²) so the sphere stays on the block.
    let deg: f64 = 17.5;
    let (ft, fnn, slide) = tilted(deg, mu, 20, 30, -0.010);
    println!(
        "slide: f_t {ft:.5} N, μ f_n {:.5} N, slide {slide:.4} m",
        mu * fnn
    );
    assert!(
        ft <= mu * fnn * (1.0 + 1e-6),
        "Coulomb cone violated: {ft} > {}",
        mu * fnn
    );
    assert!(
        ft > 0.9 * mu * fnn,
        "sliding friction should sit on the cone: {ft} vs {}",
        mu * fnn
    );
    assert!(
        slide > 1e-3,
        "the probe must slide downhill (+x), moved {slide} m"
    );
}
