//! The project's own parametric meniscus: a C-shaped wedge swept along an elliptical arc,
//! meshed as a structured (arc × radial × vertical) hexahedral sweep, each hex split into six
//! tetrahedra along its main diagonal (Kuhn/Freudenthal split: the same split in every hex,
//! so neighbouring hexes share face diagonals and the mesh is conforming).
//!
//! Frame (the world frame of the simulation): z up (superior), the inferior surface is the
//! plane z = 0, x–y footprint centred at the origin. The C opens toward +y (the
//! intercondylar side); the arc parameter s runs counter-clockwise seen from above, from the
//! posterior horn tip (s = 0, on the −x side) through the mid body (s = 0.5, at −y) to the
//! anterior horn tip (s = 1, on the +x side).
//!
//! Cross-section at arc parameter s, radial coordinate u ∈ [0, 1] (0 = thin inner free edge,
//! 1 = peripheral rim) and vertical v ∈ [0, 1]: the inferior face is flat (it rests on the
//! tibial plateau), the peripheral wall is vertical with the rim thickness H(s), and the
//! superior (femoral) face falls concavely from the rim to the inner edge,
//! z_top = h_in + (H − h_in) · u^1.2 (close to the triangular wedge of anatomy texts).
//!
//! Sizes (document of choice):
//! - Lateral: outer periphery an ellipse of semi-axes 23.0 mm (x) × 23.7 mm (y), arc from
//!   110° to 430° (a 40° opening between the horns, which in the lateral meniscus insert
//!   close together), giving a ≈ 46 × 46 mm footprint. Thickness at the rim posterior horn /
//!   body / anterior horn 7.0 / 6.4 / 4.8 mm and width 12.0 / 8.6 / 11.8 mm (the values of the
//!   issue, posterior horn the thicker one), interpolated quadratically along s.
//! - Medial: a more open C, ellipse 22.5 mm (x) × 20.0 mm (y), arc from 160° to 380° (a 140°
//!   opening), ≈ 45 × 27 mm footprint; thickness 7.0 / 6.0 / 5.0 mm and width
//!   14.0 / 9.5 / 8.0 mm (the medial posterior horn is the widest part, the anterior horn the
//!   narrowest).
//! - Both: the inner free edge is truncated at h_in = 1.5 mm (a knife edge would make flat
//!   tets at coarse resolution). The rim is 4.8–7.0 mm tall; the 13 mm height of the MRI
//!   surface's bounding box comes from the plateau's tilt and curvature in scanner
//!   coordinates, which this flat-based model leaves out.
//!
//! Resolutions (arc × radial × vertical divisions → nodes):
//! coarse 22 × 3 × 2 → 276 nodes, 792 tets (comparable to the study's 258-node mesh);
//! fine 63 × 7 × 4 → 2,560 nodes; finest 100 × 12 × 7 → 10,504 nodes.

use nalgebra::{Point2, Point3, Vector2};

use crate::mesh::TetMesh;

/// Which meniscus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Side {
    Lateral,
    Medial,
}

/// Mesh resolution of the parametric meniscus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Resolution {
    Coarse,
    Fine,
    Finest,
    /// Chosen (arc, radial, vertical) divisions, e.g. for a mesh convergence study.
    Divisions([usize; 3]),
}

impl Resolution {
    /// (arc, radial, vertical) divisions.
    pub fn divisions(self) -> [usize; 3] {
        match self {
            Resolution::Coarse => [22, 3, 2],
            Resolution::Fine => [63, 7, 4],
            Resolution::Finest => [100, 12, 7],
            Resolution::Divisions(d) => d,
        }
    }
}

/// Shape parameters, metres and degrees.
#[derive(Debug, Clone, PartialEq)]
pub struct MeniscusShape {
    /// Semi-axes (x, y) of the outer periphery ellipse.
    pub semi_axes: [f64; 2],
    /// Polar angle of the posterior horn tip and of the anterior horn tip (counter-clockwise
    /// from +x; end > start).
    pub arc_deg: [f64; 2],
    /// Rim thickness at posterior horn, body, anterior horn.
    pub thickness: [f64; 3],
    /// Radial width at posterior horn, body, anterior horn.
    pub width: [f64; 3],
    /// Thickness of the inner free edge.
    pub inner_edge: f64,
    /// Exponent of the concave superior face (1 = straight ramp).
    pub concavity: f64,
}

impl MeniscusShape {
    pub fn anatomical(side: Side) -> Self {
        match side {
            Side::Lateral => MeniscusShape {
                semi_axes: [23.0e-3, 23.7e-3],
                arc_deg: [110.0, 430.0],
                thickness: [7.0e-3, 6.4e-3, 4.8e-3],
                width: [12.0e-3, 8.6e-3, 11.8e-3],
                inner_edge: 1.5e-3,
                concavity: 1.2,
            },
            Side::Medial => MeniscusShape {
                semi_axes: [22.5e-3, 20.0e-3],
                arc_deg: [160.0, 380.0],
                thickness: [7.0e-3, 6.0e-3, 5.0e-3],
                width: [14.0e-3, 9.5e-3, 8.0e-3],
                inner_edge: 1.5e-3,
                concavity: 1.2,
            },
        }
    }

    /// Quadratic interpolation through (0, v0), (0.5, v1), (1, v2).
    fn along(v: [f64; 3], s: f64) -> f64 {
        let l0 = 2.0 * (s - 0.5) * (s - 1.0);
        let l1 = -4.0 * s * (s - 1.0);
        let l2 = 2.0 * s * (s - 0.5);
        v[0] * l0 + v[1] * l1 + v[2] * l2
    }

    pub fn thickness_at(&self, s: f64) -> f64 {
        Self::along(self.thickness, s)
    }

    pub fn width_at(&self, s: f64) -> f64 {
        Self::along(self.width, s)
    }

    fn angle(&self, s: f64) -> f64 {
        (self.arc_deg[0] + s * (self.arc_deg[1] - self.arc_deg[0])).to_radians()
    }

    /// Outer periphery point and its outward unit normal (in the footprint plane).
    fn periphery(&self, s: f64) -> (Point2<f64>, Vector2<f64>) {
        let [a, b] = self.semi_axes;
        let phi = self.angle(s);
        let p = Point2::new(a * phi.cos(), b * phi.sin());
        let n = Vector2::new(phi.cos() / a, phi.sin() / b).normalize();
        (p, n)
    }

    /// Footprint point at arc parameter s and radial coordinate u (0 inner edge, 1 rim).
    pub fn footprint(&self, s: f64, u: f64) -> Point2<f64> {
        let (p, n) = self.periphery(s);
        p - n * ((1.0 - u) * self.width_at(s))
    }

    /// Height of the superior surface at (s, u).
    pub fn top(&self, s: f64, u: f64) -> f64 {
        let h = self.thickness_at(s);
        self.inner_edge + (h - self.inner_edge) * u.powf(self.concavity)
    }

    /// Point at (s, u, v), v ∈ [0, 1] from the inferior plane to the superior surface.
    pub fn point(&self, s: f64, u: f64, v: f64) -> Point3<f64> {
        let f = self.footprint(s, u);
        Point3::new(f.x, f.y, v * self.top(s, u))
    }
}

/// A generated meniscus mesh.
#[derive(Debug, Clone)]
pub struct ParametricMeniscus {
    pub side: Side,
    pub shape: MeniscusShape,
    pub divisions: [usize; 3],
    /// Positively oriented tets; the footprint is centred at the origin.
    pub mesh: TetMesh,
    /// Nodes of the inferior surface (v = 0): the fixed set.
    pub inferior: Vec<usize>,
    /// Shift applied to centre the footprint (added to `shape.point`).
    pub offset: [f64; 2],
}

impl ParametricMeniscus {
    pub fn new(side: Side, resolution: Resolution) -> Self {
        Self::with_shape(
            side,
            MeniscusShape::anatomical(side),
            resolution.divisions(),
        )
    }

    pub fn with_shape(side: Side, shape: MeniscusShape, divisions: [usize; 3]) -> Self {
        let [na, nr, nz] = divisions.map(|d| d.max(1));
        let index = |i: usize, j: usize, k: usize| (i * (nr + 1) + j) * (nz + 1) + k;
        let mut nodes = Vec::with_capacity((na + 1) * (nr + 1) * (nz + 1));
        for i in 0..=na {
            for j in 0..=nr {
                for k in 0..=nz {
                    nodes.push(shape.point(
                        i as f64 / na as f64,
                        j as f64 / nr as f64,
                        k as f64 / nz as f64,
                    ));
                }
            }
        }
        // Centre the footprint's bounding box at the origin.
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for p in &nodes {
            for d in 0..2 {
                lo[d] = lo[d].min(p[d]);
                hi[d] = hi[d].max(p[d]);
            }
        }
        let offset = [-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0];
        for p in &mut nodes {
            p.x += offset[0];
            p.y += offset[1];
        }

        // Kuhn split: one tet per permutation of the axes, walking from corner 000 to 111.
        // (arc, radial-outward, up) is a left-handed triple (the arc runs counter-clockwise,
        // radial points out), so even permutations come out negative and get nodes 1 and 2
        // swapped; odd ones are positive as they are.
        const PERMS: [([usize; 3], bool); 6] = [
            ([0, 1, 2], true),
            ([1, 2, 0], true),
            ([2, 0, 1], true),
            ([0, 2, 1], false),
            ([2, 1, 0], false),
            ([1, 0, 2], false),
        ];
        let mut tets = Vec::with_capacity(na * nr * nz * 6);
        for i in 0..na {
            for j in 0..nr {
                for k in 0..nz {
                    for (perm, even) in PERMS {
                        let mut c = [i, j, k];
                        let mut t = [index(c[0], c[1], c[2]); 4];
                        for (step, &axis) in perm.iter().enumerate() {
                            c[axis] += 1;
                            t[step + 1] = index(c[0], c[1], c[2]);
                        }
                        if even {
                            t.swap(1, 2);
                        }
                        tets.push(t);
                    }
                }
            }
        }
        let mut inferior = Vec::with_capacity((na + 1) * (nr + 1));
        for i in 0..=na {
            for j in 0..=nr {
                inferior.push(index(i, j, 0));
            }
        }
        ParametricMeniscus {
            side,
            shape,
            divisions: [na, nr, nz],
            mesh: TetMesh { nodes, tets },
            inferior,
            offset,
        }
    }

    /// Footprint point (world, centred) of the superior surface at (s, u).
    pub fn footprint(&self, s: f64, u: f64) -> Point2<f64> {
        let f = self.shape.footprint(s, u);
        Point2::new(f.x + self.offset[0], f.y + self.offset[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::topology::tet_det;
    use std::collections::HashSet;

    fn check(
        side: Side,
        res: Resolution,
        min_nodes: usize,
        max_nodes: usize,
    ) -> ParametricMeniscus {
        let m = ParametricMeniscus::new(side, res);
        let n = m.mesh.nodes.len();
        assert!(
            n >= min_nodes && n <= max_nodes,
            "{side:?} {res:?}: {n} nodes"
        );
        // Every tet positive as generated (no reordering needed) and not thin.
        for t in 0..m.mesh.tets.len() {
            let d = tet_det(m.mesh.tet_points(t));
            assert!(d > 0.0, "tet {t} det {d}");
            let q = crate::mesh::topology::tet_quality(m.mesh.tet_points(t));
            assert!(q > crate::mesh::SLIVER_QUALITY, "tet {t} quality {q}");
        }
        // No duplicate nodes.
        let keys: HashSet<[i64; 3]> = m
            .mesh
            .nodes
            .iter()
            .map(|p| {
                [
                    (p.x * 1e7).round() as i64,
                    (p.y * 1e7).round() as i64,
                    (p.z * 1e7).round() as i64,
                ]
            })
            .collect();
        assert_eq!(keys.len(), n, "duplicate nodes");
        // Conforming: every interior face shared by exactly two tets, the boundary closed
        // (each boundary edge shared by two boundary faces).
        let faces = m.mesh.boundary_faces();
        let mut edges = std::collections::HashMap::new();
        for f in &faces {
            for e in 0..3 {
                let (a, b) = (f[e], f[(e + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&c| c == 2), "boundary not closed");
        // Volume equals the sum of positive tets, and Euler characteristic of a closed
        // genus-0 surface: V − E + F = 2.
        let (surface, _) = m.mesh.boundary_surface();
        let chi = surface.vertices.len() as i64 - edges.len() as i64 + faces.len() as i64;
        assert_eq!(chi, 2);
        // Inferior set: exactly the z = 0 nodes.
        let zero: Vec<usize> = (0..n)
            .filter(|&i| m.mesh.nodes[i].z.abs() < 1e-12)
            .collect();
        assert_eq!(m.inferior, zero);
        m
    }

    #[test]
    fn lateral_resolutions_have_claimed_node_counts_and_positive_tets() {
        let c = check(Side::Lateral, Resolution::Coarse, 250, 300);
        assert_eq!(c.mesh.nodes.len(), 276);
        assert_eq!(c.mesh.tets.len(), 792);
        check(Side::Lateral, Resolution::Fine, 2500, 3000);
        check(Side::Lateral, Resolution::Finest, 10_000, 11_000);
    }

    #[test]
    fn medial_resolutions_have_claimed_node_counts_and_positive_tets() {
        check(Side::Medial, Resolution::Coarse, 250, 300);
        check(Side::Medial, Resolution::Fine, 2500, 3000);
    }

    #[test]
    fn dimensions_match_the_documented_anatomy() {
        let l = ParametricMeniscus::new(Side::Lateral, Resolution::Fine);
        let (lo, hi) = l.mesh.bounding_box();
        let size = (hi - lo) * 1e3;
        assert!(
            (size.x - 46.0).abs() < 1.5 && (size.y - 46.0).abs() < 1.5,
            "lateral footprint {size:?}"
        );
        assert!(
            lo.z.abs() < 1e-12 && (hi.z * 1e3 - 7.0).abs() < 0.05,
            "lateral height {size:?}"
        );
        assert!(
            (lo.x + hi.x).abs() < 1e-9 && (lo.y + hi.y).abs() < 1e-9,
            "footprint centred"
        );
        let s = &l.shape;
        for (sv, th, w) in [(0.0, 7.0, 12.0), (0.5, 6.4, 8.6), (1.0, 4.8, 11.8)] {
            assert!((s.thickness_at(sv) * 1e3 - th).abs() < 1e-9);
            assert!((s.width_at(sv) * 1e3 - w).abs() < 1e-9);
        }
        // The C opens toward +y: the mid body lies at −y, the horns at −x (posterior)
        // and +x (anterior).
        let body = l.footprint(0.5, 1.0);
        assert!(body.y < -0.02 && body.x.abs() < 1e-3);
        assert!(l.footprint(0.0, 0.5).x < 0.0 && l.footprint(1.0, 0.5).x > 0.0);

        let m = ParametricMeniscus::new(Side::Medial, Resolution::Fine);
        let (lo, hi) = m.mesh.bounding_box();
        let size = (hi - lo) * 1e3;
        assert!(
            (size.x - 45.0).abs() < 1.5 && (size.y - 27.0).abs() < 1.5,
            "medial footprint {size:?}"
        );
        // Volume: a few cm³, as a meniscus.
        let v = m.mesh.volume() * 1e6;
        assert!(v > 2.0 && v < 8.0, "medial volume {v} cm³");
        let v = l.mesh.volume() * 1e6;
        assert!(v > 2.0 && v < 8.0, "lateral volume {v} cm³");
    }
}
