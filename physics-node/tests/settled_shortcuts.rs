//! Offline replays skip the work of a settled tissue (`Simulation::offline`): a step under a
//! probe held at its last target repeats the last one, and a tissue that no contact force
//! acts on is not assembled or solved. A diagnosis spends 40–60% of its steps there. The
//! forces must stay those of the full step, touches must still be felt when the probe moves
//! on, and the live node (`Simulation::new`) must never take a shortcut.

use nalgebra::UnitQuaternion;
use physics_node::sim::Simulation;

/// Contact force of every step of a probing at the mid site: approach from 2 mm above,
/// press 0.8 mm, hold 1 s, lift back to 2 mm above, hold 0.5 s, press again 0.5 mm.
fn probing(sim: &mut Simulation, scene: &launch_config::SceneConfig) -> Vec<[f64; 3]> {
    let site = *sim.probing_sites().iter().find(|s| s.region == 2).unwrap();
    let n = site.normal.normalize();
    // the probe upright, as the diagnosis's protocol holds it
    let q = UnitQuaternion::identity();
    let r = scene.probe.tip_radius;
    // (time s, height above the surface m)
    let waypoints = [
        (0.0, 2.0e-3),
        (0.6, 0.0),
        (1.0, -0.8e-3),
        (2.0, -0.8e-3),
        (3.0, 2.0e-3),
        (3.5, 2.0e-3),
        (4.2, -0.5e-3),
    ];
    let height = |t: f64| {
        let k = waypoints
            .windows(2)
            .position(|w| t <= w[1].0)
            .unwrap_or(waypoints.len() - 2);
        let (a, b) = (waypoints[k], waypoints[k + 1]);
        let w = ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0);
        a.1 + w * (b.1 - a.1)
    };
    sim.teleport_probe(&physics_node::probe::pose(
        site.point + n * (r + height(0.0)),
        q,
    ));
    let dt = sim.dt();
    let steps = (4.2 / dt).round() as usize;
    let mut out = Vec::with_capacity(steps);
    for k in 1..=steps {
        let target = site.point + n * (r + height(k as f64 * dt));
        sim.set_probe_kinematic(&physics_node::probe::pose(target, q));
        sim.step().unwrap();
        out.push(sim.contact_force());
    }
    assert_eq!(sim.physics_faults(), 0);
    out
}

/// The default scene as the diagnosis replays it: its converged offline solver.
fn offline_scene() -> launch_config::SceneConfig {
    let mut scene = launch_config::SceneConfig::default();
    scene.solver = scene.solver.offline().unwrap();
    scene
}

fn norm(f: [f64; 3]) -> f64 {
    (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt()
}

#[test]
fn settled_shortcuts_keep_the_full_steps_forces_within_a_millinewton() {
    let scene = offline_scene();
    let data = launch_config::data_dir();
    let mut fast = Simulation::offline(&scene, &data).unwrap();
    let mut full = Simulation::offline(&scene, &data).unwrap();
    full.set_settled_shortcuts(false);
    let a = probing(&mut fast, &scene);
    let b = probing(&mut full, &scene);
    assert_eq!(full.settled_steps(), (0, 0));

    let (repeated, at_rest) = fast.settled_steps();
    let steps = a.len() as u64;
    // the 1 s and 0.5 s holds, less the steps the tissue needs to settle; the approach and
    // the lifted phase, less the recovery after release
    assert!(
        repeated > steps / 8,
        "{repeated} of {steps} steps repeated: the holds were not recognised"
    );
    assert!(
        at_rest > steps / 8,
        "{at_rest} of {steps} steps without free motion: the untouched tissue was not"
    );

    let peak = b.iter().map(|f| norm(*f)).fold(0.0, f64::max);
    assert!(peak > 0.5, "the probing must press (peak {peak} N)");
    let mut worst = 0.0f64;
    for (k, (fa, fb)) in a.iter().zip(&b).enumerate() {
        let d = norm([fa[0] - fb[0], fa[1] - fb[1], fa[2] - fb[2]]);
        worst = worst.max(d);
        // a touch is felt at the same step, a release lets go at the same step
        assert_eq!(
            norm(*fa) > 1e-6,
            norm(*fb) > 1e-6,
            "step {k}: in contact with the shortcuts {fa:?}, without {fb:?}"
        );
    }
    eprintln!("repeated {repeated} at rest {at_rest} of {steps}; worst {worst:e} N, peak {peak} N");
    assert!(
        worst < 1e-3,
        "largest force difference {worst:e} N (peak {peak:.2} N)"
    );
}

#[test]
fn the_live_simulation_takes_every_step() {
    let scene = offline_scene();
    let data = launch_config::data_dir();
    let mut live = Simulation::new(&scene, &data).unwrap();
    probing(&mut live, &scene);
    assert_eq!(live.settled_steps(), (0, 0));
}
