//! Energy does not grow without input: a free probe (no coupling) dropped on the meniscus
//! under gravity; tissue, probe and contact only exchange and dissipate energy
//! (backward Euler and inelastic contact), so the total never exceeds its initial value.

use nalgebra::{UnitQuaternion, Vector3};
use physics_node::sim::Simulation;

#[test]
fn energy_does_not_grow_without_input() {
    let mut scene = launch_config::SceneConfig::default();
    scene.probe.model = "sphere".into();
    scene.probe.coupling_stiffness = 0.0;
    scene.probe.coupling_damping = 0.0;
    scene.contact.friction = 0.2;
    let mut sim = Simulation::new(&scene, &launch_config::data_dir()).unwrap();
    let site = *sim.probing_sites().iter().find(|s| s.region == 2).unwrap();
    let drop = 3e-3;
    let start = site.point + site.normal.normalize() * (scene.probe.tip_radius + drop);
    sim.teleport_probe(&physics_node::probe::pose(
        start,
        UnitQuaternion::identity(),
    ));
    let e0 = sim.energy();
    let scale = scene.probe.mass * 9.81 * drop;
    let mut worst: f64 = f64::NEG_INFINITY;
    let mut touched = false;
    for k in 0..300 {
        sim.step().unwrap();
        touched |= sim.contact_count() > 0;
        let e = sim.energy();
        worst = worst.max(e - e0);
        assert!(
            e <= e0 + 1e-3 * scale,
            "step {k}: energy grew by {:.3e} J (scale {scale:.3e} J)",
            e - e0
        );
    }
    let v = Vector3::from(sim.probe_pose().position) - start.coords;
    println!(
        "max energy increase {worst:.3e} J (drop energy {scale:.3e} J), probe moved {:.2} mm",
        v.norm() * 1e3
    );
    assert!(touched, "the probe must have landed");
}
