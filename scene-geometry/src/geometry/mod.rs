//! Meniscus geometry: the project's parametric meniscus, the canonical world frame of a
//! loaded mesh, and the probing sites of the examination protocol.
//!
//! Conventions (world frame): z up (superior), inferior plane at z ≈ 0, footprint centred at
//! the origin, the C opening toward +y (intercondylar side). Going counter-clockwise seen from
//! above, the meniscus runs from the posterior horn (−x side) through the mid body (−y) to the
//! anterior horn (+x side). For the study's meshes, which are rotated (not mirrored) into this
//! frame, "posterior" is simply the horn that ends up on −x.

pub mod frame;
pub mod meniscus;

pub use frame::{canonical_frame, canonical_surface_frame, opening_angle, CanonicalFrame};
pub use meniscus::{MeniscusShape, ParametricMeniscus, Resolution, Side};

use nalgebra::{Point2, Point3, Vector3};

use crate::mesh::SurfaceMesh;

/// Region codes as in `msgs::haptic_to_physics::DeviceState.region`.
pub const REGION_POSTERIOR: u32 = 1;
pub const REGION_MID: u32 = 2;
pub const REGION_ANTERIOR: u32 = 3;

/// Arc parameter of each region's centre (posterior horn, mid body, anterior horn).
pub const REGION_CENTRES: [(u32, f64); 3] = [
    (REGION_POSTERIOR, 0.2),
    (REGION_MID, 0.5),
    (REGION_ANTERIOR, 0.8),
];
/// The five probings of a region, spread along the arc around its centre.
pub const PROBING_OFFSETS: [f64; 5] = [-0.04, -0.02, 0.0, 0.02, 0.04];

/// A place on the superior (femoral) surface where the protocol probes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbingSite {
    /// 1 posterior, 2 mid, 3 anterior.
    pub region: u32,
    /// On the surface, world m.
    pub point: Point3<f64>,
    /// Outward unit normal of the surface there.
    pub normal: Vector3<f64>,
}

/// Highest upward-facing surface point above `xy` (vertical ray from above), with the
/// triangle's outward normal.
pub fn superior_point(
    surface: &SurfaceMesh,
    xy: Point2<f64>,
) -> Option<(Point3<f64>, Vector3<f64>)> {
    let mut best: Option<(Point3<f64>, Vector3<f64>)> = None;
    for t in 0..surface.triangles.len() {
        let n = surface.triangle_normal(t);
        if n.z <= 0.05 {
            continue;
        }
        let [a, b, c] = surface.triangles[t].map(|i| surface.vertices[i]);
        // 2-D barycentric coordinates of xy in the projected triangle.
        let det = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if det.abs() < 1e-300 {
            continue;
        }
        let l1 = ((xy.x - a.x) * (c.y - a.y) - (c.x - a.x) * (xy.y - a.y)) / det;
        let l2 = ((b.x - a.x) * (xy.y - a.y) - (xy.x - a.x) * (b.y - a.y)) / det;
        let l0 = 1.0 - l1 - l2;
        let eps = -1e-12;
        if l0 < eps || l1 < eps || l2 < eps {
            continue;
        }
        let z = l0 * a.z + l1 * b.z + l2 * c.z;
        if best.is_none_or(|(p, _)| z > p.z) {
            best = Some((Point3::new(xy.x, xy.y, z), n));
        }
    }
    best
}

/// Probing sites of the parametric meniscus: for each region, five arc parameters around the
/// region centre, halfway across the superior surface (u = 0.5), projected onto the mesh's
/// faceted surface.
pub fn parametric_probing_sites(m: &ParametricMeniscus, surface: &SurfaceMesh) -> Vec<ProbingSite> {
    let mut sites = Vec::with_capacity(15);
    for (region, centre) in REGION_CENTRES {
        for off in PROBING_OFFSETS {
            let xy = m.footprint(centre + off, 0.5);
            if let Some((point, normal)) = superior_point(surface, xy) {
                sites.push(ProbingSite {
                    region,
                    point,
                    normal,
                });
            }
        }
    }
    sites
}

/// Probing sites of any meniscus surface already in the world frame, by angle around the
/// footprint centre: the C's angular extent (measured counter-clockwise from +y, the opening)
/// is taken as arc parameter 0 → 1; at each site's angle the superior surface is sampled
/// along the ray from the centre and the site is put halfway between its inner and outer
/// edge.
pub fn probing_sites(surface: &SurfaceMesh) -> Vec<ProbingSite> {
    let (lo, hi) = surface.bounding_box();
    let centre = Point2::new((lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0);
    // Angle from +y, counter-clockwise, in [0, 2π).
    let angle_from_opening = |p: &Point3<f64>| {
        let a = (p.y - centre.y).atan2(p.x - centre.x) - std::f64::consts::FRAC_PI_2;
        a.rem_euclid(std::f64::consts::TAU)
    };
    let (mut amin, mut amax) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in &surface.vertices {
        let a = angle_from_opening(p);
        amin = amin.min(a);
        amax = amax.max(a);
    }
    let reach = ((hi.x - lo.x).powi(2) + (hi.y - lo.y).powi(2)).sqrt();
    let samples = 240;
    let mut sites = Vec::with_capacity(15);
    for (region, c) in REGION_CENTRES {
        for off in PROBING_OFFSETS {
            let s = c + off;
            let a = amin + s * (amax - amin) + std::f64::consts::FRAC_PI_2;
            let dir = nalgebra::Vector2::new(a.cos(), a.sin());
            let (mut r_in, mut r_out) = (f64::INFINITY, f64::NEG_INFINITY);
            for k in 0..=samples {
                let r = reach * k as f64 / samples as f64;
                if superior_point(surface, centre + dir * r).is_some() {
                    r_in = r_in.min(r);
                    r_out = r_out.max(r);
                }
            }
            if r_in > r_out {
                continue;
            }
            if let Some((point, normal)) =
                superior_point(surface, centre + dir * ((r_in + r_out) / 2.0))
            {
                sites.push(ProbingSite {
                    region,
                    point,
                    normal,
                });
            }
        }
    }
    sites
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{load_scene_mesh, LoadedMeniscus};
    use launch_config::scene::MeniscusConfig;
    use std::path::Path;

    fn load(spec: &str) -> LoadedMeniscus {
        let cfg = MeniscusConfig {
            mesh: spec.into(),
            ..Default::default()
        };
        load_scene_mesh(&cfg, Path::new("/nonexistent")).unwrap()
    }

    /// Distance from `p` to the nearest surface triangle.
    fn surface_distance(s: &SurfaceMesh, p: &Point3<f64>) -> f64 {
        s.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| s.vertices[i]);
                (p - crate::visual::closest_on_triangle(p, &a, &b, &c)).norm()
            })
            .fold(f64::INFINITY, f64::min)
    }

    fn check_sites(m: &LoadedMeniscus) {
        let sites = &m.probing_sites;
        assert_eq!(sites.len(), 15, "{}", m.name);
        for (k, region) in [REGION_POSTERIOR, REGION_MID, REGION_ANTERIOR]
            .into_iter()
            .enumerate()
        {
            assert!(sites[5 * k..5 * k + 5].iter().all(|s| s.region == region));
        }
        for s in sites {
            assert!(
                surface_distance(&m.surface, &s.point) < 1e-12,
                "{s:?} off the surface"
            );
            assert!((s.normal.norm() - 1.0).abs() < 1e-12);
            assert!(
                s.normal.z > 0.5,
                "{}: normal {:?} not roughly +z",
                m.name,
                s.normal
            );
            // Superior: the site is the top of the mesh above its footprint point.
            assert!(s.point.z > 0.5e-3);
        }
        // Posterior horn on −x, mid body at −y, anterior horn on +x.
        let mean = |r: usize| {
            sites[5 * r..5 * r + 5]
                .iter()
                .fold(Vector3::zeros(), |a, s| a + s.point.coords)
                / 5.0
        };
        assert!(mean(0).x < -0.008, "{}: posterior {:?}", m.name, mean(0));
        assert!(
            mean(1).y < -0.005 && mean(1).y < mean(0).y && mean(1).y < mean(2).y,
            "{}: mid {:?}",
            m.name,
            mean(1)
        );
        assert!(mean(2).x > 0.008, "{}: anterior {:?}", m.name, mean(2));
        // Spread slightly along the arc: distinct, within a few mm of each other.
        for r in 0..3 {
            for i in 0..4 {
                let d = (sites[5 * r + i + 1].point - sites[5 * r + i].point).norm();
                assert!(d > 0.5e-3 && d < 5e-3, "{}: step {d}", m.name);
            }
        }
    }

    #[test]
    fn default_specs_load_with_inferior_fixed_set_and_probing_sites() {
        for (spec, nodes) in [
            ("default:lateral:coarse", 276),
            ("default:coarse", 276),
            ("default:medial:coarse", 276),
            ("default:lateral:fine", 2560),
            // Chosen divisions (a convergence study): 45 × 4 × 3 nodes.
            ("default:lateral:44x3x2", 540),
        ] {
            let m = load(spec);
            assert_eq!(m.mesh.nodes.len(), nodes, "{spec}");
            // The fixed set is the inferior face (z = 0), and all of it.
            assert!(m
                .fixed_nodes
                .iter()
                .all(|&i| m.mesh.nodes[i].z.abs() < 1e-12));
            let on_floor = m.mesh.nodes.iter().filter(|p| p.z.abs() < 1e-12).count();
            assert_eq!(m.fixed_nodes.len(), on_floor);
            // The generic inferior selection finds the same set.
            assert_eq!(m.mesh.inferior_nodes(0.35), m.fixed_nodes, "{spec}");
            // Surface ↔ node map, both ways.
            for (v, &n) in m.surface_to_node.iter().enumerate() {
                assert_eq!(m.surface.vertices[v], m.mesh.nodes[n]);
            }
            let back = m.node_to_surface();
            for (n, v) in back.iter().enumerate() {
                if let Some(v) = v {
                    assert_eq!(m.surface_to_node[*v], n);
                }
            }
            // Interior nodes exist from the fine level on (coarse has 2 layers through the
            // thickness and 3 across: every node is on the surface except the middle ones).
            assert!(back.iter().filter(|v| v.is_none()).count() < m.mesh.nodes.len() / 2);
            check_sites(&m);
        }
        let cfg = MeniscusConfig {
            mesh: "default:lateral:coarse".into(),
            fixed: "none".into(),
            ..Default::default()
        };
        assert!(load_scene_mesh(&cfg, Path::new("."))
            .unwrap()
            .fixed_nodes
            .is_empty());
    }

    #[test]
    fn generic_probing_sites_agree_with_the_parametric_ones() {
        // The angle-based sites of arbitrary meshes, run on the parametric mesh, land in the
        // same regions as the arc-parameter sites.
        let m = load("default:lateral:fine");
        let generic = probing_sites(&m.surface);
        assert_eq!(generic.len(), 15);
        for (g, p) in generic.iter().zip(&m.probing_sites) {
            assert_eq!(g.region, p.region);
            assert!((g.point - p.point).norm() < 8e-3, "{g:?} vs {p:?}");
        }
    }

    #[test]
    fn bad_specs_are_typed_errors() {
        for (spec, needle) in [
            ("default:lateral:huge", "unknown resolution `huge`"),
            ("default:lateral:44x0x2", "ARCxRADIALxVERTICAL"),
            ("default:left:coarse", "unknown meniscus `left`"),
            ("study:knee", "unknown meniscus `knee`"),
            ("default:a:b:c", "expected default:SIDE:RESOLUTION"),
            (
                "mesh.vtk",
                "not default:…, study:… or a path to a .msh file",
            ),
            ("/nonexistent/m.msh", "cannot read"),
        ] {
            let cfg = MeniscusConfig {
                mesh: spec.into(),
                ..Default::default()
            };
            let e = load_scene_mesh(&cfg, Path::new("/nonexistent"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(needle), "{spec}: {e}");
        }
        let cfg = MeniscusConfig {
            fixed: "/nonexistent/fixed.txt".into(),
            ..Default::default()
        };
        let e = load_scene_mesh(&cfg, Path::new("/nonexistent"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("fixed.txt") && e.contains("cannot read"), "{e}");
    }
}
