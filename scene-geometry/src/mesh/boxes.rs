//! Structured tet meshes of boxes, for tests, benchmarks and examples (not anatomy).

use nalgebra::Point3;

use super::TetMesh;

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
