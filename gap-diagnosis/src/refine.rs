//! Uniform refinement of a tetrahedral specimen mesh (every tet split into eight at its edge
//! midpoints), written as a Gmsh 2.2 file with its fixed-node list, so a scene can load the
//! refined specimen like any other `.msh` path. Used to build an independent, finer
//! discretisation of the study mesh as a convergence reference for the replay model.
use super::GapError;
use nalgebra::Point3;
use physics_node::mesh::TetMesh;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

/// A mesh refined once and its held nodes.
#[derive(Debug, Clone)]
pub struct Refined {
    /// The coarse nodes first (same indices), then one node per coarse edge.
    pub mesh: TetMesh,
    /// The coarse held nodes and the midpoint of every edge between two held nodes: on a
    /// linear tet mesh such an edge does not move, so the refined mesh is held exactly as the
    /// coarse one.
    pub fixed: Vec<usize>,
}

fn signed_volume6(p: &[Point3<f64>], t: [usize; 4]) -> f64 {
    let (a, b, c, d) = (p[t[0]], p[t[1]], p[t[2]], p[t[3]]);
    (b - a).cross(&(c - a)).dot(&(d - a))
}

/// Splits every tet into eight: four corner tets and the inner octahedron cut along its
/// shortest diagonal (the best-shaped of the three choices). Children keep the parent's
/// orientation.
pub fn refine_once(mesh: &TetMesh, fixed: &[usize]) -> Refined {
    let mut nodes = mesh.nodes.clone();
    let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
    let mut midpoint = |a: usize, b: usize, nodes: &mut Vec<Point3<f64>>| -> usize {
        let key = (a.min(b), a.max(b));
        *mid.entry(key).or_insert_with(|| {
            nodes.push(nalgebra::center(&nodes[a], &nodes[b]));
            nodes.len() - 1
        })
    };
    let mut tets = Vec::with_capacity(8 * mesh.tets.len());
    for &[v0, v1, v2, v3] in &mesh.tets {
        let parent = signed_volume6(&nodes, [v0, v1, v2, v3]).signum();
        let m01 = midpoint(v0, v1, &mut nodes);
        let m02 = midpoint(v0, v2, &mut nodes);
        let m03 = midpoint(v0, v3, &mut nodes);
        let m12 = midpoint(v1, v2, &mut nodes);
        let m13 = midpoint(v1, v3, &mut nodes);
        let m23 = midpoint(v2, v3, &mut nodes);
        // corners: scaled copies of the parent, same orientation
        tets.push([v0, m01, m02, m03]);
        tets.push([m01, v1, m12, m13]);
        tets.push([m02, m12, v2, m23]);
        tets.push([m03, m13, m23, v3]);
        // the octahedron around one diagonal, its other four midpoints as a cycle
        let d = |a: usize, b: usize| (nodes[a] - nodes[b]).norm_squared();
        let options = [
            ((m01, m23), [m02, m03, m13, m12]),
            ((m02, m13), [m01, m03, m23, m12]),
            ((m03, m12), [m01, m02, m23, m13]),
        ];
        let ((a, b), ring) = options
            .into_iter()
            .min_by(|x, y| d(x.0 .0, x.0 .1).total_cmp(&d(y.0 .0, y.0 .1)))
            .expect("three diagonals");
        for i in 0..4 {
            let mut t = [a, b, ring[i], ring[(i + 1) % 4]];
            if signed_volume6(&nodes, t) * parent < 0.0 {
                t.swap(2, 3);
            }
            tets.push(t);
        }
    }
    let held: Vec<bool> = {
        let mut h = vec![false; mesh.nodes.len()];
        for &f in fixed {
            h[f] = true;
        }
        h
    };
    let mut fixed_out: Vec<usize> = fixed.to_vec();
    fixed_out.extend(
        mid.iter()
            .filter(|((a, b), _)| held[*a] && held[*b])
            .map(|(_, &m)| m),
    );
    fixed_out.sort_unstable();
    fixed_out.dedup();
    Refined {
        mesh: TetMesh { nodes, tets },
        fixed: fixed_out,
    }
}

/// Writes `mesh` as Gmsh 2.2 ASCII (positions as they are, m) and `fixed` as a node list
/// (0-based, file order = mesh order), for `[scene.meniscus] mesh` and `fixed`.
pub fn write_msh(mesh: &TetMesh, fixed: &[usize], msh: &Path, list: &Path) -> Result<(), GapError> {
    let mut s = String::with_capacity(64 * (mesh.nodes.len() + mesh.tets.len()));
    s.push_str("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n");
    let _ = writeln!(s, "{}", mesh.nodes.len());
    for (i, p) in mesh.nodes.iter().enumerate() {
        // {:e} prints the shortest representation that reads back to the same f64
        let _ = writeln!(s, "{} {:e} {:e} {:e}", i + 1, p.x, p.y, p.z);
    }
    s.push_str("$EndNodes\n$Elements\n");
    let _ = writeln!(s, "{}", mesh.tets.len());
    for (i, t) in mesh.tets.iter().enumerate() {
        let _ = writeln!(
            s,
            "{} 4 2 0 0 {} {} {} {}",
            i + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        );
    }
    s.push_str("$EndElements\n");
    std::fs::write(msh, s).map_err(|e| GapError::Io(msh.to_path_buf(), e))?;
    let mut l = String::from("# 0-based held nodes of the refined mesh\n");
    for f in fixed {
        let _ = writeln!(l, "{f}");
    }
    std::fs::write(list, l).map_err(|e| GapError::Io(list.to_path_buf(), e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(m: &TetMesh) -> f64 {
        m.tets.iter().map(|t| signed_volume6(&m.nodes, *t) / 6.0).sum()
    }

    /// Two tets sharing a face: eight children each, every child positive, the volume kept,
    /// shared edges split once, and only edges between held nodes held.
    #[test]
    fn refinement_splits_into_eight_positive_children() {
        let p = |x, y, z| Point3::new(x, y, z);
        let mesh = TetMesh {
            nodes: vec![
                p(0.0, 0.0, 0.0),
                p(1.0, 0.0, 0.0),
                p(0.0, 1.0, 0.0),
                p(0.0, 0.0, 1.0),
                p(1.0, 1.0, 1.0),
            ],
            tets: vec![[0, 1, 2, 3], [1, 2, 3, 4]],
        };
        for t in &mesh.tets {
            assert!(signed_volume6(&mesh.nodes, *t) != 0.0);
        }
        let r = refine_once(&mesh, &[0, 1, 2]);
        assert_eq!(r.mesh.tets.len(), 16);
        // 9 distinct edges: 6 + 6 − 3 shared
        assert_eq!(r.mesh.nodes.len(), 5 + 9);
        for (c, t) in r.mesh.tets.iter().enumerate() {
            let parent = c / 8;
            let sp = signed_volume6(&mesh.nodes, mesh.tets[parent]).signum();
            assert_eq!(
                signed_volume6(&r.mesh.nodes, *t).signum(),
                sp,
                "child {c} flipped"
            );
        }
        assert!((volume(&r.mesh) - volume(&mesh)).abs() < 1e-12);
        // held: 0, 1, 2 and the midpoints of 01, 02, 12
        assert_eq!(r.fixed.len(), 6);
        for &f in &r.fixed[3..] {
            assert_eq!(r.mesh.nodes[f].z, 0.0, "a held midpoint off the held face");
        }
    }
}
