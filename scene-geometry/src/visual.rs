//! The visual model: a high-resolution surface carried by the tet mesh through barycentric
//! coordinates (SOFA's BarycentricMapping), so viewers see a smooth deforming meniscus while
//! the physics runs on the coarse mesh.

use nalgebra::{Matrix3, Point3, Vector3};

use crate::mesh::{MeshError, SurfaceMesh, TetMesh};

/// Each visual vertex as an affine combination of the four nodes of one tet: the tet that
/// contains it or, for vertices outside the mesh, the nearest tet (coordinates then
/// extrapolate, some negative, which still reproduces the rest position exactly and follows
/// any affine motion of that tet).
#[derive(Debug, Clone)]
pub struct BarycentricMap {
    nodes: Vec<[usize; 4]>,
    weights: Vec<[f64; 4]>,
    node_count: usize,
    /// Distance of each mapped point from its tet at rest (0 inside), m.
    outside: Vec<f64>,
}

impl BarycentricMap {
    /// Maps `points` (rest positions, same frame as `mesh`) onto `mesh`.
    pub fn new(mesh: &TetMesh, points: &[Point3<f64>]) -> Result<Self, MeshError> {
        if mesh.tets.is_empty() {
            return Err(MeshError::invalid(
                "<visual map>",
                "the tet mesh has no tetrahedra",
            ));
        }
        let grid = TetGrid::new(mesh);
        let mut stamp = vec![u32::MAX; mesh.tets.len()];
        let mut nodes = Vec::with_capacity(points.len());
        let mut weights = Vec::with_capacity(points.len());
        let mut outside = Vec::with_capacity(points.len());
        for (i, p) in points.iter().enumerate() {
            let (tet, dist) = grid.locate(mesh, p, &mut stamp, i as u32);
            nodes.push(mesh.tets[tet]);
            weights.push(barycentric(mesh, tet, p));
            outside.push(dist);
        }
        Ok(BarycentricMap {
            nodes,
            weights,
            node_count: mesh.nodes.len(),
            outside,
        })
    }

    /// Number of mapped points.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Rest distance of each mapped point outside its tet, m (0 for contained points).
    pub fn outside_distances(&self) -> &[f64] {
        &self.outside
    }

    /// Positions of the mapped points for the current tet-node positions. No allocation.
    ///
    /// Panics if `tet_positions` is not the mapped mesh's node count or `out` is not
    /// [`len`](Self::len) long (a wiring error, not an input error).
    pub fn update(&self, tet_positions: &[Point3<f64>], out: &mut [Point3<f64>]) {
        assert_eq!(
            tet_positions.len(),
            self.node_count,
            "tet positions of another mesh"
        );
        assert_eq!(
            out.len(),
            self.nodes.len(),
            "output buffer of another length"
        );
        for ((o, n), w) in out.iter_mut().zip(&self.nodes).zip(&self.weights) {
            let mut v = Vector3::zeros();
            for k in 0..4 {
                v += tet_positions[n[k]].coords * w[k];
            }
            *o = Point3::from(v);
        }
    }
}

/// A surface carried by the tets: rest surface, its map and the current positions.
#[derive(Debug, Clone)]
pub struct VisualModel {
    pub surface: SurfaceMesh,
    pub map: BarycentricMap,
    /// Current vertex positions (world m), updated by [`VisualModel::update`].
    pub positions: Vec<Point3<f64>>,
}

impl VisualModel {
    pub fn new(mesh: &TetMesh, surface: SurfaceMesh) -> Result<Self, MeshError> {
        let map = BarycentricMap::new(mesh, &surface.vertices)?;
        let positions = surface.vertices.clone();
        Ok(VisualModel {
            surface,
            map,
            positions,
        })
    }

    /// Follows the tets. No allocation.
    pub fn update(&mut self, tet_positions: &[Point3<f64>]) {
        self.map.update(tet_positions, &mut self.positions);
    }
}

/// Barycentric coordinates of `p` in tet `t` (sum 1; all ≥ 0 inside).
fn barycentric(mesh: &TetMesh, t: usize, p: &Point3<f64>) -> [f64; 4] {
    let [a, b, c, d] = mesh.tet_points(t);
    let m = Matrix3::from_columns(&[b - a, c - a, d - a]);
    // Tets are validated non-degenerate at load; fall back to the centroid if not.
    match m.try_inverse() {
        Some(inv) => {
            let l = inv * (p - a);
            [1.0 - l.x - l.y - l.z, l.x, l.y, l.z]
        }
        None => [0.25; 4],
    }
}

/// Distance from `p` to tet `t` (0 inside).
fn tet_distance(mesh: &TetMesh, t: usize, p: &Point3<f64>) -> f64 {
    let l = barycentric(mesh, t, p);
    if l.iter().all(|&v| v >= -1e-12) {
        return 0.0;
    }
    let q = mesh.tet_points(t);
    let mut best = f64::INFINITY;
    for f in crate::mesh::topology::TET_FACES {
        let c = closest_on_triangle(p, q[f[0]], q[f[1]], q[f[2]]);
        best = best.min((p - c).norm());
    }
    best
}

/// Closest point to `p` on triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
pub fn closest_on_triangle(
    p: &Point3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Point3<f64> {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Uniform grid of tet bounding boxes for point location.
struct TetGrid {
    lo: Point3<f64>,
    h: f64,
    dims: [usize; 3],
    /// CSR: tets overlapping cell c are `items[start[c]..start[c + 1]]`.
    start: Vec<usize>,
    items: Vec<usize>,
}

impl TetGrid {
    fn new(mesh: &TetMesh) -> Self {
        let (lo, hi) = mesh.bounding_box();
        let ext = hi - lo;
        let vol = ext.x.max(1e-12) * ext.y.max(1e-12) * ext.z.max(1e-12);
        // About one tet per cell.
        let mut h = (vol / mesh.tets.len() as f64).cbrt();
        let max_extent = ext.max();
        if !(h > 0.0) {
            h = max_extent.max(1e-9);
        }
        h = h.max(max_extent / 256.0);
        let dims = [ext.x, ext.y, ext.z].map(|e| ((e / h).floor() as usize + 1).max(1));
        let cell_of = |v: f64, axis: usize| {
            (((v - lo[axis]) / h).floor().max(0.0) as usize).min(dims[axis] - 1)
        };
        let ncell = dims[0] * dims[1] * dims[2];
        let mut ranges = Vec::with_capacity(mesh.tets.len());
        let mut count = vec![0usize; ncell + 1];
        for t in 0..mesh.tets.len() {
            let p = mesh.tet_points(t);
            let mut a = [usize::MAX; 3];
            let mut b = [0usize; 3];
            for q in p {
                for k in 0..3 {
                    let c = cell_of(q[k], k);
                    a[k] = a[k].min(c);
                    b[k] = b[k].max(c);
                }
            }
            for i in a[0]..=b[0] {
                for j in a[1]..=b[1] {
                    for k in a[2]..=b[2] {
                        count[(i * dims[1] + j) * dims[2] + k] += 1;
                    }
                }
            }
            ranges.push((a, b));
        }
        let mut start = vec![0usize; ncell + 1];
        for c in 0..ncell {
            start[c + 1] = start[c] + count[c];
        }
        let mut fill = start.clone();
        let mut items = vec![0usize; start[ncell]];
        for (t, (a, b)) in ranges.into_iter().enumerate() {
            for i in a[0]..=b[0] {
                for j in a[1]..=b[1] {
                    for k in a[2]..=b[2] {
                        let c = (i * dims[1] + j) * dims[2] + k;
                        items[fill[c]] = t;
                        fill[c] += 1;
                    }
                }
            }
        }
        TetGrid {
            lo,
            h,
            dims,
            start,
            items,
        }
    }

    /// The tet containing `p`, else the nearest one, with the distance.
    fn locate(
        &self,
        mesh: &TetMesh,
        p: &Point3<f64>,
        stamp: &mut [u32],
        query: u32,
    ) -> (usize, f64) {
        let cell: [usize; 3] = std::array::from_fn(|k| {
            (((p[k] - self.lo[k]) / self.h).floor().max(0.0) as usize).min(self.dims[k] - 1)
        });
        let mut best = (0usize, f64::INFINITY);
        let max_ring = *self.dims.iter().max().unwrap_or(&1);
        for ring in 0..=max_ring {
            let lo: [isize; 3] = std::array::from_fn(|k| cell[k] as isize - ring as isize);
            let hi: [isize; 3] = std::array::from_fn(|k| cell[k] as isize + ring as isize);
            for i in lo[0].max(0)..=hi[0].min(self.dims[0] as isize - 1) {
                for j in lo[1].max(0)..=hi[1].min(self.dims[1] as isize - 1) {
                    for k in lo[2].max(0)..=hi[2].min(self.dims[2] as isize - 1) {
                        // Only the shell of this ring: inner cells were done before.
                        let on_shell = i == lo[0]
                            || i == hi[0]
                            || j == lo[1]
                            || j == hi[1]
                            || k == lo[2]
                            || k == hi[2];
                        if !on_shell {
                            continue;
                        }
                        let c =
                            (i as usize * self.dims[1] + j as usize) * self.dims[2] + k as usize;
                        for &t in &self.items[self.start[c]..self.start[c + 1]] {
                            if stamp[t] == query {
                                continue;
                            }
                            stamp[t] = query;
                            let d = tet_distance(mesh, t, p);
                            // Ties (shared faces, edges): keep the lowest tet index so the
                            // map is deterministic.
                            if d < best.1 || (d == best.1 && t < best.0) {
                                best = (t, d);
                            }
                        }
                    }
                }
            }
            if best.1 == 0.0 {
                return best;
            }
            // Every tet within distance (ring − 1)·h of p overlaps a cell already visited
            // (clamping p into the grid box does not increase distances to points inside it).
            if ring >= 1 && best.1 <= (ring - 1) as f64 * self.h {
                return best;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{ParametricMeniscus, Resolution, Side};
    use nalgebra::{Rotation3, Vector3};

    fn brute_force_nearest(mesh: &TetMesh, p: &Point3<f64>) -> f64 {
        (0..mesh.tets.len())
            .map(|t| tet_distance(mesh, t, p))
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn rest_surface_is_reproduced_and_rigid_motion_followed() {
        let m = ParametricMeniscus::new(Side::Lateral, Resolution::Coarse);
        // A "visual" surface: the fine mesh's boundary, scaled slightly about the centroid
        // so some vertices fall outside the coarse mesh and some inside.
        let fine = ParametricMeniscus::new(Side::Lateral, Resolution::Fine);
        let (mut surface, _) = fine.mesh.boundary_surface();
        for v in &mut surface.vertices {
            v.x *= 1.01;
            v.z = v.z * 1.02 - 1e-4;
        }
        let mut visual = VisualModel::new(&m.mesh, surface.clone()).unwrap();
        let inside = visual
            .map
            .outside_distances()
            .iter()
            .filter(|&&d| d == 0.0)
            .count();
        let outside = visual.map.len() - inside;
        assert!(
            inside > 100 && outside > 100,
            "inside {inside}, outside {outside}"
        );
        // Nearest tets are truly the nearest (against brute force) for a sample.
        for (i, v) in surface.vertices.iter().enumerate().step_by(37) {
            let d = visual.map.outside_distances()[i];
            assert!(
                (d - brute_force_nearest(&m.mesh, v)).abs() < 1e-12,
                "vertex {i}"
            );
        }
        // Rest: exact reproduction.
        visual.update(&m.mesh.nodes);
        for (p, q) in visual.positions.iter().zip(&surface.vertices) {
            assert!((p - q).norm() < 1e-15, "{p} vs {q}");
        }
        // Rigid motion: rotate 40° about an oblique axis and translate.
        let r = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, 3.0)),
            0.7,
        );
        let t = Vector3::new(0.01, -0.02, 0.03);
        let moved: Vec<Point3<f64>> = m.mesh.nodes.iter().map(|p| r * p + t).collect();
        visual.update(&moved);
        for (p, q) in visual.positions.iter().zip(&surface.vertices) {
            assert!((p - (r * q + t)).norm() < 1e-14, "{p} vs {}", r * q + t);
        }
    }

    #[test]
    fn far_points_map_to_the_nearest_tet() {
        let m = ParametricMeniscus::new(Side::Medial, Resolution::Coarse);
        let pts = [
            Point3::new(0.1, 0.05, -0.2),
            Point3::new(0.0, 0.0, 0.004),
            Point3::new(-0.03, 0.0, 0.002),
        ];
        let map = BarycentricMap::new(&m.mesh, &pts).unwrap();
        for (i, p) in pts.iter().enumerate() {
            assert!((map.outside_distances()[i] - brute_force_nearest(&m.mesh, p)).abs() < 1e-12);
        }
        let mut out = vec![Point3::origin(); 3];
        map.update(&m.mesh.nodes, &mut out);
        for (p, q) in out.iter().zip(&pts) {
            assert!((p - q).norm() < 1e-12);
        }
    }

    #[test]
    fn study_mri_surface_maps_onto_the_study_mesh() {
        let Some(data) = crate::mesh::tests::study_data() else {
            return;
        };
        let cfg = launch_config::scene::MeniscusConfig {
            mesh: "study:lateral".into(),
            ..Default::default()
        };
        let m = crate::mesh::load_scene_mesh(&cfg, &data).unwrap();
        let mut stl =
            crate::mesh::read_stl(&data.join("meniscus/lateral_meniscus_visual.stl")).unwrap();
        // Scanner mm → m, then the same canonical frame as the study mesh.
        crate::mesh::Transform {
            scale: 1e-3,
            ..crate::mesh::Transform::identity()
        }
        .apply_surface(&mut stl);
        let frame = crate::geometry::canonical_surface_frame(&stl);
        for v in &mut stl.vertices {
            *v = frame.isometry * *v;
        }
        // The same placement as a launch-file `visual_transform` on the raw file.
        let placement = crate::mesh::Transform {
            scale: 1e-3,
            ..crate::mesh::Transform::identity()
        }
        .then(&crate::mesh::Transform::from_isometry(&frame.isometry))
        .to_config();
        eprintln!("visual_transform for the MRI surface: {placement:?}");
        let via_config = launch_config::scene::MeniscusConfig {
            mesh: "study:lateral".into(),
            visual: Some(
                data.join("meniscus/lateral_meniscus_visual.stl")
                    .display()
                    .to_string(),
            ),
            visual_transform: placement,
            ..Default::default()
        };
        let loaded = crate::mesh::load_scene_mesh(&via_config, &data)
            .unwrap()
            .visual
            .unwrap();
        for (a, b) in loaded.vertices.iter().zip(&stl.vertices) {
            assert!((a - b).norm() < 1e-9);
        }
        let (lo, hi) = stl.bounding_box();
        let size = (hi - lo) * 1e3;
        assert!(
            size.x > 40.0 && size.x < 52.0 && size.y > 40.0 && size.y < 52.0,
            "MRI surface {size:?} mm"
        );
        let started = std::time::Instant::now();
        let mut visual = VisualModel::new(&m.mesh, stl.clone()).unwrap();
        let d = visual.map.outside_distances();
        let mut sorted = d.to_vec();
        sorted.sort_by(f64::total_cmp);
        eprintln!(
            "MRI surface: {} vertices, {} triangles, size {:.1?} mm; map built in {:?}; outside the tets: {} vertices, median {:.2} mm, max {:.2} mm",
            stl.vertices.len(),
            stl.triangles.len(),
            size,
            started.elapsed(),
            d.iter().filter(|&&x| x > 0.0).count(),
            sorted[sorted.len() / 2] * 1e3,
            sorted[sorted.len() - 1] * 1e3
        );
        visual.update(&m.mesh.nodes);
        for (p, q) in visual.positions.iter().zip(&stl.vertices) {
            assert!((p - q).norm() < 1e-12);
        }
        // Per-step cost of following the tets (printed, not asserted).
        let started = std::time::Instant::now();
        for _ in 0..200 {
            visual.update(&m.mesh.nodes);
        }
        eprintln!(
            "visual update: {:.1} µs per step",
            started.elapsed().as_secs_f64() / 200.0 * 1e6
        );
        let r = Rotation3::from_axis_angle(&Vector3::y_axis(), 0.3);
        let t = Vector3::new(0.0, 0.01, 0.0);
        let moved: Vec<Point3<f64>> = m.mesh.nodes.iter().map(|p| r * p + t).collect();
        visual.update(&moved);
        for (p, q) in visual.positions.iter().zip(&stl.vertices) {
            assert!((p - (r * q + t)).norm() < 1e-10);
        }
    }
}
