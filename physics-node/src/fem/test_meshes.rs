//! Small structured tet meshes for tests, benchmarks and examples (not anatomy).

use nalgebra::Point3;

use crate::mesh::TetMesh;

/// A box [0, lx] × [0, ly] × [0, lz] of nx × ny × nz hexahedra, each split into 6 tets along
/// its main diagonal (Kuhn split: conforming across hexes). All tets positively oriented.
pub fn box_mesh(lx: f64, ly: f64, lz: f64, nx: usize, ny: usize, nz: usize) -> TetMesh {
    let (nx, ny, nz) = (nx.max(1), ny.max(1), nz.max(1));
    let id = |i: usize, j: usize, k: usize| (k * (ny + 1) + j) * (nx + 1) + i;
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push(Point3::new(
                    lx * i as f64 / nx as f64,
                    ly * j as f64 / ny as f64,
                    lz * k as f64 / nz as f64,
                ));
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

/// Indices of the nodes whose position satisfies `pred`.
pub fn nodes_where(mesh: &TetMesh, pred: impl Fn(&Point3<f64>) -> bool) -> Vec<usize> {
    (0..mesh.nodes.len())
        .filter(|&i| pred(&mesh.nodes[i]))
        .collect()
}
