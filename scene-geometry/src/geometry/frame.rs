//! The canonical world frame of a loaded meniscus mesh: z up (superior), inferior plane at
//! z ≈ 0, footprint centred at the origin, the C opening toward +y.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::mesh::topology::face_normal;
use crate::mesh::{SurfaceMesh, TetMesh};

/// Result of [`canonical_frame`].
#[derive(Debug, Clone)]
pub struct CanonicalFrame {
    /// World-from-mesh rigid motion.
    pub isometry: Isometry3<f64>,
    /// The nodes that defined the inferior plane.
    pub inferior_nodes: Vec<usize>,
    /// Outward normal of the inferior plane in mesh coordinates (mapped to −z).
    pub inferior_normal: Vector3<f64>,
}

/// Finds the rigid motion that puts `mesh` in the canonical frame.
///
/// The inferior plane is a least-squares plane through `inferior_hint` (e.g. the study's
/// fixed nodes) if given; otherwise the largest flat patch of the boundary (boundary faces
/// whose normals lie within 15° of each other, by area), which for a meniscus is its flat
/// tibial face. Its outward normal (away from the body) is rotated to −z and its mean height
/// to z = 0. The C's opening is found as the widest angular gap of the nodes around the
/// footprint centre and turned to +y; finally the footprint's bounding box is centred.
pub fn canonical_frame(mesh: &TetMesh, inferior_hint: Option<&[usize]>) -> CanonicalFrame {
    canonical_frame_of(&mesh.nodes, &mesh.boundary_faces(), inferior_hint)
}

/// [`canonical_frame`] of a closed triangle surface (e.g. a visual model), its vertices
/// standing in for the nodes.
pub fn canonical_surface_frame(surface: &SurfaceMesh) -> CanonicalFrame {
    canonical_frame_of(&surface.vertices, &surface.triangles, None)
}

fn canonical_frame_of(
    points: &[Point3<f64>],
    faces: &[[usize; 3]],
    inferior_hint: Option<&[usize]>,
) -> CanonicalFrame {
    let body = centroid(points.iter());
    let (normal, inferior_nodes) = match inferior_hint {
        Some(hint) if hint.len() >= 3 => {
            let c = centroid(hint.iter().map(|&i| &points[i]));
            let mut cov = Matrix3::zeros();
            for &i in hint {
                let d = points[i] - c;
                cov += d * d.transpose();
            }
            let eig = cov.symmetric_eigen();
            let k = eig.eigenvalues.imin();
            let mut n: Vector3<f64> = eig.eigenvectors.column(k).into_owned();
            if n.dot(&(body - c)) > 0.0 {
                n = -n;
            }
            (n.normalize(), hint.to_vec())
        }
        _ => flat_patch(points, faces),
    };
    let down = -Vector3::z();
    let r1 = Rotation3::rotation_between(&normal, &down)
        .unwrap_or_else(|| Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
    let rotated: Vec<Point3<f64>> = points.iter().map(|p| r1 * p).collect();
    let gap = opening_angle(&rotated);
    let r2 = Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2 - gap);
    let r = r2 * r1;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        let q = r * p;
        for d in 0..2 {
            lo[d] = lo[d].min(q[d]);
            hi[d] = hi[d].max(q[d]);
        }
    }
    let z0 = inferior_nodes
        .iter()
        .map(|&i| (r * points[i]).z)
        .sum::<f64>()
        / inferior_nodes.len().max(1) as f64;
    let t = Vector3::new(-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -z0);
    CanonicalFrame {
        isometry: Isometry3::from_parts(
            Translation3::from(t),
            UnitQuaternion::from_rotation_matrix(&r),
        ),
        inferior_nodes,
        inferior_normal: normal,
    }
}

/// Polar angle (from +x, counter-clockwise) of the middle of the widest angular gap of the
/// points around their footprint bounding-box centre: the direction in which the C opens.
pub fn opening_angle(points: &[Point3<f64>]) -> f64 {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in points {
        for d in 0..2 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let mut angles: Vec<f64> = points
        .iter()
        .map(|p| (p.y - c[1]).atan2(p.x - c[0]))
        .collect();
    angles.sort_by(f64::total_cmp);
    if angles.len() < 2 {
        return std::f64::consts::FRAC_PI_2;
    }
    // Wrap-around gap first.
    let mut best = (
        angles[0] + std::f64::consts::TAU - angles[angles.len() - 1],
        angles[angles.len() - 1],
    );
    for w in angles.windows(2) {
        if w[1] - w[0] > best.0 {
            best = (w[1] - w[0], w[0]);
        }
    }
    best.1 + best.0 / 2.0
}

fn centroid<'a>(points: impl Iterator<Item = &'a Point3<f64>>) -> Point3<f64> {
    let mut s = Vector3::zeros();
    let mut n = 0.0f64;
    for p in points {
        s += p.coords;
        n += 1.0;
    }
    Point3::from(s / n.max(1.0))
}

/// Outward normal and nodes of the largest flat patch of the boundary.
fn flat_patch(nodes: &[Point3<f64>], faces: &[[usize; 3]]) -> (Vector3<f64>, Vec<usize>) {
    let weighted: Vec<(Vector3<f64>, f64)> = faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| nodes[i]);
            let w = (b - a).cross(&(c - a));
            (face_normal(&a, &b, &c), w.norm() / 2.0)
        })
        .collect();
    let cos_tol = 15f64.to_radians().cos();
    // Candidate directions: every face normal (strided on big meshes to bound the cost).
    let stride = (faces.len() / 2000).max(1);
    let mut best = (Vector3::z(), -1.0);
    for (n, _) in weighted.iter().step_by(stride) {
        let area: f64 = weighted
            .iter()
            .filter(|(m, _)| m.dot(n) > cos_tol)
            .map(|(_, a)| a)
            .sum();
        if area > best.1 {
            best = (*n, area);
        }
    }
    let mut mean = Vector3::zeros();
    let mut on = vec![false; nodes.len()];
    for (f, (m, a)) in faces.iter().zip(&weighted) {
        if m.dot(&best.0) > cos_tol {
            mean += m * *a;
            for &v in f {
                on[v] = true;
            }
        }
    }
    let patch = (0..nodes.len()).filter(|&i| on[i]).collect();
    (mean.normalize(), patch)
}
