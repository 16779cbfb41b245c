//! Small structured tet meshes for tests, benchmarks and examples (not anatomy).

use nalgebra::Point3;

use crate::mesh::TetMesh;

/// A box [0, lx] × [0, ly] × [0, lz] of nx × ny × nz hexahedra, each split into 6 tets along
/// its main diagonal (Kuhn split: conforming across hexes). All tets positively oriented.
pub fn box_mesh(lx: f64, ly: f64, lz: f64, nx: usize, ny: usize, nz: usize) -> TetMesh {
    let ticks = |l: f64, n: usize| -> Vec<f64> {
        let n = n.max(1);
        (0..=n).map(|i| l * i as f64 / n as f64).collect()
    };
    graded_box_mesh(&ticks(lx, nx), &ticks(ly, ny), &ticks(lz, nz))
}

/// A structured box whose hexahedra lie between the given increasing grid coordinates on each
/// axis (graded meshes: fine where a test presses, coarse far away), split as [`box_mesh`].
pub fn graded_box_mesh(xs: &[f64], ys: &[f64], zs: &[f64]) -> TetMesh {
    let (nx, ny, nz) = (xs.len() - 1, ys.len() - 1, zs.len() - 1);
    let id = |i: usize, j: usize, k: usize| (k * (ny + 1) + j) * (nx + 1) + i;
    let mut nodes = Vec::with_capacity(xs.len() * ys.len() * zs.len());
    for &z in zs {
        for &y in ys {
            for &x in xs {
                nodes.push(Point3::new(x, y, z));
            }
        }
    }
    let perms = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for p in perms {
                    let mut c = [i, j, k];
                    let mut t = [id(c[0], c[1], c[2]), 0, 0, 0];
                    for (s, axis) in p.iter().enumerate() {
                        c[*axis] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    let (a, b, cc, d) = (nodes[t[0]], nodes[t[1]], nodes[t[2]], nodes[t[3]]);
                    if (b - a).cross(&(cc - a)).dot(&(d - a)) < 0.0 {
                        t.swap(2, 3);
                    }
                    tets.push(t);
                }
            }
        }
    }
    TetMesh { nodes, tets }
}

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

fn tet_volume(m: &TetMesh, t: &[usize; 4]) -> f64 {
    let x = |i: usize| m.nodes[t[i]];
    nalgebra::Matrix3::from_columns(&[x(1) - x(0), x(2) - x(0), x(3) - x(0)]).determinant() / 6.0
}

/// The mesh refined once: every tet split into 8 (edge midpoints; inner octahedron cut along one diagonal); a
/// midpoint is fixed when both ends of its edge are.
pub fn refine_once(mesh: &TetMesh, fixed: &[usize]) -> (TetMesh, Vec<usize>) {
    let mut out = TetMesh {
        nodes: mesh.nodes.clone(),
        tets: Vec::new(),
    };
    let mut is_fixed = vec![false; mesh.nodes.len()];
    for &f in fixed {
        is_fixed[f] = true;
    }
    let mut mid: std::collections::BTreeMap<(usize, usize), usize> =
        std::collections::BTreeMap::new();
    let mut midpoint = |a: usize, b: usize, out: &mut TetMesh, is_fixed: &mut Vec<bool>| {
        let key = (a.min(b), a.max(b));
        *mid.entry(key).or_insert_with(|| {
            out.nodes.push(nalgebra::Point3::from(
                (out.nodes[a].coords + out.nodes[b].coords) * 0.5,
            ));
            is_fixed.push(is_fixed[a] && is_fixed[b]);
            out.nodes.len() - 1
        })
    };
    for t in &mesh.tets {
        let [a, b, c, d] = *t;
        let ab = midpoint(a, b, &mut out, &mut is_fixed);
        let ac = midpoint(a, c, &mut out, &mut is_fixed);
        let ad = midpoint(a, d, &mut out, &mut is_fixed);
        let bc = midpoint(b, c, &mut out, &mut is_fixed);
        let bd = midpoint(b, d, &mut out, &mut is_fixed);
        let cd = midpoint(c, d, &mut out, &mut is_fixed);
        let children = [
            [a, ab, ac, ad],
            [ab, b, bc, bd],
            [ac, bc, c, cd],
            [ad, bd, cd, d],
            [ac, bd, ab, bc],
            [ac, bd, bc, cd],
            [ac, bd, cd, ad],
            [ac, bd, ad, ab],
        ];
        let v0 = tet_volume(mesh, t);
        let mut sum = 0.0;
        for mut ch in children {
            if tet_volume(&out, &ch) < 0.0 {
                ch.swap(2, 3);
            }
            sum += tet_volume(&out, &ch);
            out.tets.push(ch);
        }
        assert!(
            (sum - v0).abs() <= 1e-9 * v0.abs(),
            "refinement must preserve volume"
        );
    }
    let fixed = (0..out.nodes.len()).filter(|&i| is_fixed[i]).collect();
    (out, fixed)
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

/// A scene's mesh refined once ([`refine_once`]) and written into `dir` as Gmsh 2.2 with its
/// fixed-node list, so a scene can name it (`[scene.meniscus] mesh`, `fixed`). Returns the
/// refined mesh, the `.msh` path and the fixed-node list path.
pub fn write_refined_once(
    mesh: &TetMesh,
    fixed: &[usize],
    dir: &std::path::Path,
) -> std::io::Result<(TetMesh, std::path::PathBuf, std::path::PathBuf)> {
    let (fine, fine_fixed) = refine_once(mesh, fixed);
    std::fs::create_dir_all(dir)?;
    let msh = dir.join("refined_once.msh");
    write_msh22(&fine, &msh)?;
    let list = dir.join("refined_once_fixed.txt");
    let held: Vec<String> = fine_fixed.iter().map(|i| i.to_string()).collect();
    std::fs::write(&list, held.join(" "))?;
    Ok((fine, msh, list))
}
