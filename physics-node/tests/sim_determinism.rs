//! Same scene, same inputs → bit-identical outputs (contact frames, forces, poses).

use nalgebra::{UnitQuaternion, Vector3};
use physics_node::sim::Simulation;

fn run() -> Vec<u64> {
    let mut scene = launch_config::SceneConfig::default();
    scene.contact.friction = 0.3;
    let mut sim = Simulation::new(&scene, &launch_config::data_dir()).unwrap();
    let site = *sim.probing_sites().iter().find(|s| s.region == 2).unwrap();
    let n = site.normal.normalize();
    let q = UnitQuaternion::rotation_between(&Vector3::z(), &n).unwrap();
    let (t1, t2) = physics_node::contact::tangents(&n);
    let r = scene.probe.tip_radius;
    sim.teleport_probe(&physics_node::probe::pose(site.point + n * (r + 0.3e-3), q));
    let mut out = Vec::new();
    for k in 0..250 {
        let t = k as f64 * 0.01;
        let target = site.point
            + n * (r - 1.5e-3 * (t / 0.5).min(1.0))
            + t1 * (2e-3 * (3.0 * t).sin())
            + t2 * (1e-3 * t);
        sim.set_proxy_pose(&physics_node::probe::pose(target, q));
        sim.step().unwrap();
        let f = sim.contact_frame();
        let rows = f.row_count as usize;
        out.push(f.contact_count as u64);
        out.extend(sim.contact_force().iter().map(|v| v.to_bits()));
        out.extend(
            f.probe_pose
                .position
                .iter()
                .chain(&f.probe_pose.orientation)
                .map(|v| v.to_bits()),
        );
        out.extend(f.lambda[..rows].iter().map(|v| v.to_bits()));
        out.extend(f.free_violation[..rows].iter().map(|v| v.to_bits()));
        for i in 0..rows {
            out.extend((0..rows).map(|j| f.w(i, j).to_bits()));
            out.extend(f.constraint_directions[i].iter().map(|v| v.to_bits()));
        }
        out.extend(
            sim.surface_positions()
                .iter()
                .flat_map(|p| p.iter().map(|v| v.to_bits()).collect::<Vec<_>>()),
        );
    }
    out
}

#[test]
fn two_runs_are_bit_identical() {
    let a = run();
    let b = run();
    assert!(a.len() > 1000);
    // The run must actually exercise contact.
    assert_eq!(a.len(), b.len());
    let first = a.iter().zip(&b).position(|(x, y)| x != y);
    assert!(first.is_none(), "runs diverge at output word {first:?}");
}
