//! Tet-mesh geometry and topology: orientation, quality, volume, bounding box, boundary
//! surface, inferior nodes.

use std::path::Path;

use nalgebra::{Point3, Vector3};

use super::{MeshError, SurfaceMesh, TetMesh};

/// Below this normalised quality (1 = regular tet) a valid tet is reported as a sliver.
/// In the study's lateral mesh two tets fall below it, 583 and 584 (q ≈ 0.017, sharing a
/// 0.10 mm edge, 0.008 mm³ against a median of 8 mm³: the one thin spot of that mesh); the
/// next worst is 0.034.
pub const SLIVER_QUALITY: f64 = 0.02;

/// |6V| ≤ this × (longest edge)³ counts as zero volume (rounding noise of a flat tet).
pub const ZERO_VOLUME_RELATIVE: f64 = 1e-10;

/// A thin but valid tetrahedron.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sliver {
    pub tet: usize,
    /// 6√2·V / l_rms³ (1 for a regular tet, → 0 for a flat one).
    pub quality: f64,
}

/// Outward, counter-clockwise faces of a positively oriented tet [a, b, c, d], each listed
/// opposite the vertex of the same index.
pub const TET_FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]];

/// det[x1−x0, x2−x0, x3−x0] = 6 × signed volume.
pub fn tet_det(p: [&Point3<f64>; 4]) -> f64 {
    let a = p[1] - p[0];
    let b = p[2] - p[0];
    let c = p[3] - p[0];
    a.dot(&b.cross(&c))
}

fn edges(p: [&Point3<f64>; 4]) -> [f64; 6] {
    [
        (p[1] - p[0]).norm_squared(),
        (p[2] - p[0]).norm_squared(),
        (p[3] - p[0]).norm_squared(),
        (p[2] - p[1]).norm_squared(),
        (p[3] - p[1]).norm_squared(),
        (p[3] - p[2]).norm_squared(),
    ]
}

/// Normalised volume quality 6√2·|V| / l_rms³: 1 for a regular tet, 0 for a flat one.
pub fn tet_quality(p: [&Point3<f64>; 4]) -> f64 {
    let e = edges(p);
    let l_rms = (e.iter().sum::<f64>() / 6.0).sqrt();
    if l_rms == 0.0 {
        return 0.0;
    }
    let vol = tet_det(p).abs() / 6.0;
    6.0 * std::f64::consts::SQRT_2 * vol / (l_rms * l_rms * l_rms)
}

impl TetMesh {
    pub fn tet_points(&self, t: usize) -> [&Point3<f64>; 4] {
        let [a, b, c, d] = self.tets[t];
        [
            &self.nodes[a],
            &self.nodes[b],
            &self.nodes[c],
            &self.nodes[d],
        ]
    }

    /// Signed volume of tet `t`, m³.
    pub fn tet_volume(&self, t: usize) -> f64 {
        tet_det(self.tet_points(t)) / 6.0
    }

    /// Total volume, m³.
    pub fn volume(&self) -> f64 {
        (0..self.tets.len()).map(|t| self.tet_volume(t)).sum()
    }

    /// Axis-aligned bounding box (min, max) of the nodes.
    pub fn bounding_box(&self) -> (Point3<f64>, Point3<f64>) {
        bounding_box(&self.nodes)
    }

    /// Reorders negatively oriented tets (swaps their nodes 1 and 2) so all have
    /// det > 0. Returns how many were reordered.
    pub fn orient_positive(&mut self) -> usize {
        let mut flipped = 0;
        for t in 0..self.tets.len() {
            if tet_det(self.tet_points(t)) < 0.0 {
                self.tets[t].swap(1, 2);
                flipped += 1;
            }
        }
        flipped
    }

    /// Rejects flat tets and reorders negative ones; returns the slivers (thin but valid)
    /// after warning about each, and how many tets were reordered. `path` names the source in messages; `lines[t]` (if given)
    /// is the file line of tet `t` and `tags[t]` its element number in the file.
    pub(crate) fn validate(
        &mut self,
        path: &Path,
        lines: Option<&[usize]>,
        tags: Option<&[usize]>,
    ) -> Result<(Vec<Sliver>, usize), MeshError> {
        let mut slivers = Vec::new();
        for t in 0..self.tets.len() {
            let p = self.tet_points(t);
            let det = tet_det(p);
            let lmax = edges(p).iter().cloned().fold(0.0, f64::max).sqrt();
            if !(det.abs() > ZERO_VOLUME_RELATIVE * lmax * lmax * lmax) {
                return Err(MeshError::ZeroVolume {
                    path: path.to_path_buf(),
                    line: lines.map_or(0, |l| l[t]),
                    element: tags.map_or(t, |g| g[t]),
                    volume: det / 6.0,
                    edge: lmax,
                });
            }
            let q = tet_quality(p);
            if q < SLIVER_QUALITY {
                tracing::warn!(
                    file = %path.display(),
                    element = tags.map_or(t, |g| g[t]),
                    quality = q,
                    "thin (sliver) tetrahedron kept; quality 6√2·V/l_rms³ = {q:.4} < {SLIVER_QUALITY}"
                );
                slivers.push(Sliver { tet: t, quality: q });
            }
        }
        let flipped = self.orient_positive();
        Ok((slivers, flipped))
    }

    /// Faces used by exactly one tet, outward and counter-clockwise (for positive tets),
    /// as node-index triples, sorted. The one definition of the boundary: the collision
    /// surface, the smooth surface, the canonical frame and the visual surface all start here.
    pub fn boundary_faces(&self) -> Vec<[usize; 3]> {
        // Sorted keys rather than a hash map: deterministic, and no hashing of 4·tets faces.
        let mut keyed: Vec<([usize; 3], [usize; 3])> = Vec::with_capacity(self.tets.len() * 4);
        for tet in &self.tets {
            for f in TET_FACES {
                let face = [tet[f[0]], tet[f[1]], tet[f[2]]];
                let mut key = face;
                key.sort_unstable();
                keyed.push((key, face));
            }
        }
        keyed.sort_unstable();
        // A face is on the boundary when no other tet shares its key.
        let mut faces: Vec<[usize; 3]> = keyed
            .chunk_by(|a, b| a.0 == b.0)
            .filter(|run| run.len() == 1)
            .map(|run| run[0].1)
            .collect();
        faces.sort_unstable();
        faces
    }

    /// The boundary as a compact surface and, for each surface vertex, its mesh node.
    pub fn boundary_surface(&self) -> (SurfaceMesh, Vec<usize>) {
        let faces = self.boundary_faces();
        let mut node_to_vertex = vec![usize::MAX; self.nodes.len()];
        let mut surface_to_node = Vec::new();
        let mut triangles = Vec::with_capacity(faces.len());
        for f in faces {
            let mut tri = [0; 3];
            for (k, &n) in f.iter().enumerate() {
                if node_to_vertex[n] == usize::MAX {
                    node_to_vertex[n] = surface_to_node.len();
                    surface_to_node.push(n);
                }
                tri[k] = node_to_vertex[n];
            }
            triangles.push(tri);
        }
        let vertices = surface_to_node.iter().map(|&n| self.nodes[n]).collect();
        (
            SurfaceMesh {
                vertices,
                triangles,
            },
            surface_to_node,
        )
    }

    /// Nodes of the inferior surface: on boundary faces whose outward normal points down
    /// (n_z ≤ −cos 45°) and that lie in the lowest `band` (fraction of the height) of the mesh.
    /// Sorted, unique.
    pub fn inferior_nodes(&self, band: f64) -> Vec<usize> {
        let (lo, hi) = self.bounding_box();
        let z_limit = lo.z + band * (hi.z - lo.z);
        let mut on = vec![false; self.nodes.len()];
        for f in self.boundary_faces() {
            let n = face_normal(&self.nodes[f[0]], &self.nodes[f[1]], &self.nodes[f[2]]);
            let zc = (self.nodes[f[0]].z + self.nodes[f[1]].z + self.nodes[f[2]].z) / 3.0;
            if n.z <= -std::f64::consts::FRAC_1_SQRT_2 && zc <= z_limit {
                for &v in &f {
                    on[v] = true;
                }
            }
        }
        (0..self.nodes.len()).filter(|&i| on[i]).collect()
    }

    /// Removes nodes used by no tet; returns for each kept node its old index.
    pub fn drop_unused_nodes(&mut self) -> Vec<usize> {
        let mut used = vec![false; self.nodes.len()];
        for t in &self.tets {
            for &n in t {
                used[n] = true;
            }
        }
        let mut new_index = vec![usize::MAX; self.nodes.len()];
        let mut old_index = Vec::new();
        for (i, &u) in used.iter().enumerate() {
            if u {
                new_index[i] = old_index.len();
                old_index.push(i);
            }
        }
        if old_index.len() != self.nodes.len() {
            self.nodes = old_index.iter().map(|&i| self.nodes[i]).collect();
            for t in &mut self.tets {
                for n in t.iter_mut() {
                    *n = new_index[*n];
                }
            }
        }
        old_index
    }
}

impl SurfaceMesh {
    /// Unit outward normal of triangle `t` (zero for a degenerate triangle).
    pub fn triangle_normal(&self, t: usize) -> Vector3<f64> {
        let [a, b, c] = self.triangles[t];
        face_normal(&self.vertices[a], &self.vertices[b], &self.vertices[c])
    }

    pub fn bounding_box(&self) -> (Point3<f64>, Point3<f64>) {
        bounding_box(&self.vertices)
    }
}

pub fn face_normal(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>) -> Vector3<f64> {
    let n = (b - a).cross(&(c - a));
    let len = n.norm();
    if len > 0.0 {
        n / len
    } else {
        n
    }
}

pub fn bounding_box(points: &[Point3<f64>]) -> (Point3<f64>, Point3<f64>) {
    let mut lo = Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
    let mut hi = Point3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (lo, hi)
}
