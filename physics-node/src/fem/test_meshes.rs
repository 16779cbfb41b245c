//! Small structured tet meshes for tests, benchmarks and examples (not anatomy).

use nalgebra::Point3;

// The structured boxes live with the meshes (the geometry crate's tests use them too).
pub use crate::mesh::boxes::{box_mesh, graded_box_mesh};
use crate::mesh::{refine_once, Midpoints, TetMesh};

/// Writes a tet mesh as Gmsh 2.2 ASCII (scenes read their meshes from files).
pub fn write_msh22(mesh: &TetMesh, path: &std::path::Path) -> std::io::Result<()> {
    use std::fmt::Write as _;
    let mut s = String::from("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n");
    let _ = writeln!(s, "{}", mesh.nodes.len());
    for (i, p) in mesh.nodes.iter().enumerate() {
        let _ = writeln!(s, "{} {:.17e} {:.17e} {:.17e}", i + 1, p.x, p.y, p.z);
    }
    let _ = writeln!(s, "$EndNodes\n$Elements\n{}", mesh.tets.len());
    for (i, t) in mesh.tets.iter().enumerate() {
        let _ = writeln!(
            s,
            "{} 4 2 0 1 {} {} {} {}",
            i + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        );
    }
    s += "$EndElements\n";
    std::fs::write(path, s)
}

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

/// A scene's mesh refined once ([`refine_once`], its boundary midpoints as `midpoints` says)
/// and written into `dir` as Gmsh 2.2 with its fixed-node list, so a scene can name it
/// (`[scene.meniscus] mesh`, `fixed`). Returns the refined mesh, the `.msh` path and the
/// fixed-node list path.
pub fn write_refined_once(
    mesh: &TetMesh,
    fixed: &[usize],
    midpoints: Midpoints,
    dir: &std::path::Path,
) -> std::io::Result<(TetMesh, std::path::PathBuf, std::path::PathBuf)> {
    let (fine, fine_fixed) = refine_once(mesh, fixed, midpoints);
    std::fs::create_dir_all(dir)?;
    let msh = dir.join("refined_once.msh");
    write_msh22(&fine, &msh)?;
    let list = dir.join("refined_once_fixed.txt");
    let held: Vec<String> = fine_fixed.iter().map(|i| i.to_string()).collect();
    std::fs::write(&list, held.join(" "))?;
    Ok((fine, msh, list))
}
