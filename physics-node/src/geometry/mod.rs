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

pub use frame::{canonical_frame, opening_angle, CanonicalFrame};
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
pub fn superior_point(surface: &SurfaceMesh, xy: Point2<f64>) -> Option<(Point3<f64>, Vector3<f64>)> {
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
                sites.push(ProbingSite { region, point, normal });
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
            if let Some((point, normal)) = superior_point(surface, centre + dir * ((r_in + r_out) / 2.0)) {
                sites.push(ProbingSite { region, point, normal });
            }
        }
    }
    sites
}
