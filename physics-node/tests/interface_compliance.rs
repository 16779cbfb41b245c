//! `[scene.contact] interface_compliance`: a penalty interface in series with the tissue (the
//! gap self-test's truth uses one, so that its contact formulation differs from the replay's
//! hard contact). Two springs in series: a ball pressed to a depth d against a tissue that
//! carries F_hard there with a hard contact must carry d / (d / F_hard + c) through an
//! interface of compliance c, and the probe must sit c·F deeper than the hard contact lets it.

use nalgebra::UnitQuaternion;
use physics_node::sim::Simulation;

/// Normal force after pressing the ball `depth` into the mid site and holding it there.
fn press(interface_compliance: f64, depth: f64) -> f64 {
    let mut scene = launch_config::SceneConfig::default();
    scene.solver = scene.solver.offline().unwrap();
    scene.probe.model = "sphere".into();
    scene.contact.interface_compliance = interface_compliance;
    let data = launch_config::data_dir();
    let mut sim = Simulation::offline(&scene, &data).unwrap();
    let site = *sim.probing_sites().iter().find(|s| s.region == 2).unwrap();
    let n = site.normal.normalize();
    let q = UnitQuaternion::identity();
    let r = scene.probe.tip_radius;
    let at = |h: f64| physics_node::probe::pose(site.point + n * (r + h), q);
    sim.teleport_probe(&at(0.5e-3));
    let dt = sim.dt();
    let press_steps = (0.5 / dt).round() as usize;
    for k in 1..=press_steps {
        let w = k as f64 / press_steps as f64;
        sim.set_probe_kinematic(&at(0.5e-3 - w * (0.5e-3 + depth)));
        sim.step().unwrap();
    }
    for _ in 0..(0.5 / dt).round() as usize {
        sim.set_probe_kinematic(&at(-depth));
        sim.step().unwrap();
    }
    assert_eq!(sim.physics_faults(), 0);
    let f = sim.contact_force();
    f[0] * n.x + f[1] * n.y + f[2] * n.z
}

#[test]
fn a_penalty_interface_is_a_spring_in_series_with_the_tissue() {
    let depth = 0.6e-3;
    let hard = press(0.0, depth);
    assert!(hard > 0.2, "the hard press must carry a force ({hard} N)");
    // the tissue's secant stiffness at this depth, and an interface as stiff as it
    let c = depth / hard;
    let soft = press(c, depth);
    let series = depth / (depth / hard + c);
    eprintln!("hard {hard:.4} N, interface {c:.3e} m/N: {soft:.4} N (two springs in series: {series:.4} N)");
    // the tissue is not a linear spring (its secant stiffness at the shallower depth the
    // soft press reaches differs), so within 15%
    assert!(
        (soft / series - 1.0).abs() < 0.15,
        "{soft:.4} N through the interface, {series:.4} N for two springs in series"
    );
    // and none: the hard contact exactly
    assert_eq!(press(0.0, depth), hard);
}

#[test]
fn a_negative_interface_compliance_is_refused() {
    let mut scene = launch_config::SceneConfig::default();
    scene.contact.interface_compliance = -1e-5;
    let err = Simulation::offline(&scene, &launch_config::data_dir())
        .err()
        .expect("a negative interface compliance must be refused");
    assert!(err.to_string().contains("interface_compliance"), "{err}");
    let file = launch_config::LaunchFile {
        scene,
        ..Default::default()
    };
    let problems = launch_config::validate::validate(&file);
    assert!(
        format!("{problems:?}").contains("scene.contact.interface_compliance"),
        "{problems:?}"
    );
}
