//! Small structured tet meshes for tests, benchmarks and examples (not anatomy).

use nalgebra::Point3;

// The structured boxes and the mesh writers live with the meshes (the geometry crate's tests
// use the boxes too, and the gap diagnosis writes its refined truth's mesh).
pub use crate::mesh::boxes::{box_mesh, graded_box_mesh};
use crate::mesh::TetMesh;
pub use crate::mesh::{write_msh22, write_refined_once};

/// Indices of the nodes whose position satisfies `pred`.
pub fn nodes_where(mesh: &TetMesh, pred: impl Fn(&Point3<f64>) -> bool) -> Vec<usize> {
    (0..mesh.nodes.len())
        .filter(|&i| pred(&mesh.nodes[i]))
        .collect()
}

/// A 1 m × 0.1 m × 0.1 m cantilever of `nx` × `nyz` × `nyz` hexes (E = 1 MPa, Poisson ratio
/// `nu`, corotational), clamped at x = 0, under a 0.1 N tip load in −z (δ ≈ 4 mm ≪ L, the
/// linear regime), solved statically with `settings` (gravity off). Returns the mean tip
/// deflection and the Euler–Bernoulli deflection δ = PL³/(3EI), both in m.
pub fn cantilever_deflection(
    nx: usize,
    nyz: usize,
    settings: super::FemSettings,
    nu: f64,
) -> Result<(f64, f64), super::FemError> {
    use super::{FemModel, FemSettings, Material, MaterialModel};
    use nalgebra::Vector3;
    let (l, h) = (1.0, 0.1);
    let mesh = box_mesh(l, h, h, nx, nyz, nyz);
    let fixed = nodes_where(&mesh, |p| p.x < 1e-9);
    let tip = nodes_where(&mesh, |p| (p.x - l).abs() < 1e-9);
    let mat = Material {
        youngs_modulus: 1.0e6,
        poisson_ratio: nu,
        density: 1000.0,
        model: MaterialModel::Corotational,
    };
    let s = FemSettings {
        gravity: Vector3::zeros(),
        ..settings
    };
    let mut m = FemModel::new(&mesh, mat, &fixed, s)?;
    let p_total = 0.1; // N
    let mut f = vec![Vector3::zeros(); m.node_count()];
    // Equal shares over the tip face (the resultant is what counts).
    for &i in &tip {
        f[i] = Vector3::new(0.0, 0.0, -p_total / tip.len() as f64);
    }
    m.solve_static(&f, false, 20, 1e-7)?;
    let deflection = -tip
        .iter()
        .map(|&i| m.positions()[i].z - mesh.nodes[i].z)
        .sum::<f64>()
        / tip.len() as f64;
    let inertia = h * h * h * h / 12.0;
    let eb = p_total * l * l * l / (3.0 * mat.youngs_modulus * inertia);
    Ok((deflection, eb))
}

/// The data folder when the study's lateral mesh is there (`ARTHROSIM_DATA`, see
/// [`launch_config::data_dir`]); `None`, with a note naming `test`, when it is not. Under
/// `CI=true` the study data is required, so a missing mesh fails the test instead.
pub fn study_data(test: &str) -> Option<std::path::PathBuf> {
    let d = launch_config::data_dir();
    if d.join("meniscus/lateral_meniscus_computation.msh")
        .is_file()
    {
        return Some(d);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "{test}: CI=true but the study data is missing at {}",
        d.display()
    );
    eprintln!(
        "{test} skipped: no study mesh under {} (set ARTHROSIM_DATA)",
        d.display()
    );
    None
}
