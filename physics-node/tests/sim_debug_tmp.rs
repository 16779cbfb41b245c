use nalgebra::{UnitQuaternion, Vector3};
#[allow(unused_imports)]
use nalgebra::Point3;
use physics_node::sim::Simulation;

#[test]
fn debug_press() {
    let data = launch_config::data_dir();
    let mut scene = launch_config::SceneConfig::default();
    scene.probe.model = "sphere".into();
    let mut sim = Simulation::new(&scene, &data).unwrap();
    let site = sim.probing_sites().iter().find(|s| s.region == 2).unwrap().clone();
    println!("site {:?} n {:?}", site.point, site.normal);
    let n = site.normal;
    let r = scene.probe.tip_radius;
    let q = UnitQuaternion::identity();
    sim.teleport_probe(&physics_node::probe::pose(site.point + n * (r + 0.1e-3), q));
    for depth_mm in [0.0, 0.5, 1.0, 1.5, 2.0, 3.0] {
        let target = site.point + n * (r - depth_mm * 1e-3);
        for _ in 0..100 {
            sim.set_probe_kinematic(&physics_node::probe::pose(target, q));
            sim.step().unwrap();
        }
        let f = sim.contact_force();
        let fr = sim.contact_frame();
        println!("depth {depth_mm} mm: force {:?} contacts {} lcp it {} res {:e} gap0 {:e} lam {:e} W00 {:e}", f, sim.contact_count(), fr.lcp_iterations, fr.lcp_residual, fr.free_violation[0], fr.lambda[0], fr.w(0,0));
    }
    let _ = Vector3::<f64>::zeros();
}

#[test]
fn debug_static_stiffness() {
    use physics_node::fem::*;
    let data = launch_config::data_dir();
    let scene = launch_config::SceneConfig::default();
    let loaded = physics_node::mesh::load_scene_mesh(&scene.meniscus, &data).unwrap();
    let site = loaded.probing_sites.iter().find(|s| s.region == 2).unwrap().clone();
    let (node, _) = loaded.mesh.nodes.iter().enumerate().map(|(i,p)| (i, (p - site.point).norm())).min_by(|a,b| a.1.total_cmp(&b.1)).unwrap();
    let mat = Material::from_config(&scene.material).unwrap();
    println!("material {:?} nodes {} fixed {}", mat, loaded.mesh.nodes.len(), loaded.fixed_nodes.len());
    let settings = FemSettings::from_scene(&scene).unwrap();
    let mut fem = FemModel::new(&loaded.mesh, mat, &loaded.fixed_nodes, settings).unwrap();
    let mut f = vec![Vector3::zeros(); loaded.mesh.nodes.len()];
    f[node] = -site.normal * 1.0;
    fem.solve_static(&f, false, 20, 1e-10).unwrap();
    let u = fem.positions()[node] - loaded.mesh.nodes[node];
    println!("node {node} at {:?}: 1 N → u = {:?} mm (k = {} N/mm)", loaded.mesh.nodes[node], u * 1e3, 1.0 / (u.norm() * 1e3));
    let mut lo = nalgebra::Vector3::repeat(1.0); let mut hi = -lo;
    for p in &loaded.mesh.nodes { lo = lo.inf(&p.coords); hi = hi.sup(&p.coords); }
    println!("bbox {:?} {:?}", lo*1e3, hi*1e3);
}
