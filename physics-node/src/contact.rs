//! Proximity queries between the probe's collision spheres and the deforming boundary surface
//! of the tet mesh, with the side of the surface tracked so that a probe pressed deep into
//! the tissue keeps an outward normal (parry's point projection on a TriMesh treats the mesh
//! as a shell; see `shared/notes/crates.md`).
//!
//! Detection runs on the start-of-step (already corrected, hence non-penetrating) positions,
//! the way a god-object sits on the surface: the closest feature of the last valid probe
//! position gives the contact point (barycentric on a triangle) and the outward normal; the
//! violation is then evaluated at the free-motion positions along that normal. A probe point
//! that is found inside the closed surface (angle-weighted pseudo-normal test, Bærentzen &
//! Aanæs 2005) keeps the close features that face the side it was tracked on, and the tracked
//! triangle (or a neighbour of it) when it went through it, instead of jumping to the nearest
//! — possibly opposite — side of a thin or crushed meniscus.

use crate::probe::Probe;
use nalgebra::{Point3, Vector3};
use parry3d_f64::bounding_volume::Aabb;
use parry3d_f64::math::Vector as GVec;
use parry3d_f64::query::PointQueryWithLocation;
use parry3d_f64::shape::{TriMesh, TriMeshFlags, Triangle, TrianglePointLocation};

const NO_TRIANGLE: u32 = u32::MAX;
/// Contacts kept per probe sphere (the most violated), as many as a frame carries
/// (`msgs::MAX_CONTACTS`): a ball whose contact patch spans many small faces must be held by
/// all of them, or the surface between the held points sinks into it. With 8, a 3 mm ball on
/// a block of 0.15 mm cells was 22–42% softer than Hertz; with 32 it is within +6…+19%
/// (`tests/hertz_block.rs`). The step's overall cap (`max_contacts`, most violated first)
/// still bounds the LCP.
pub const FEATURES_PER_SPHERE: usize = msgs::MAX_CONTACTS;

/// Tissue nodes a ball's Hertz patch can spread its force over ([`ContactParams::
/// hertz_patch`]). A patch of radius 0.77 mm on the study mesh refined twice (0.55 mm facets)
/// covers 7–10. Beyond this the weakest are dropped and the rest renormalised, a load more
/// central than Hertz's: a 3 mm ball 0.1–0.3 mm into a block of 0.15 mm cells covers 42–125
/// (`tests/hertz_block.rs`).
pub const PATCH_NODES: usize = 32;

/// [`Contact::patch`] of a contact held at one closest point.
pub const NO_PATCH: u32 = u32::MAX;

/// The nodes a contact spread over its Hertz patch acts on, with their weights (summing to 1):
/// the first `len`. Kept beside the contacts ([`ContactDetector::patches`]) so that a contact
/// stays the small value the default, closest-point path copies and sorts: with the patch's
/// arrays in every contact the physics bench's step took 12% longer, the free motion's share
/// most of it.
#[derive(Debug, Clone, Copy)]
pub struct Patch {
    pub nodes: [usize; PATCH_NODES],
    pub weights: [f64; PATCH_NODES],
    pub len: usize,
}

/// Rings of the patch quadrature (centre outwards), with 6j + 3 points on ring j so that
/// every point stands for the same area of the disc.
const PATCH_RINGS: usize = 4;
const PATCH_POINTS: usize = 3 + 9 + 15 + 21;

#[inline]
fn to_g(v: &Vector3<f64>) -> GVec {
    GVec::new(v.x, v.y, v.z)
}

#[inline]
fn from_g(v: GVec) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

/// The deforming boundary surface used for collision: a deformable parry TriMesh refitted each
/// step, plus face normals and adjacency for pseudo-normals.
pub struct TissueSurface {
    /// Triangles in mesh node indices, outward.
    pub triangles: Vec<[usize; 3]>,
    /// Surface vertex → mesh node.
    pub nodes: Vec<usize>,
    trimesh: TriMesh,
    /// Unit face normals at the current refit.
    face_normals: Vec<Vector3<f64>>,
    /// Unit face normals at the refit before ([`Self::contact_normal`]).
    previous_normals: Vec<Vector3<f64>>,
    /// Triangle across local edge k (parry's order: 0 = AB, 1 = BC, 2 = AC).
    neighbors: Vec<[u32; 3]>,
    /// Incident triangles per surface vertex (CSR).
    vertex_tri_start: Vec<u32>,
    vertex_tris: Vec<u32>,
    /// Triangles whose nodes are all held (the inferior surface on the bone): the rigid
    /// support sheet stands in for them, so tissue contacts skip them.
    pub rigid: Vec<bool>,
    /// Bounding box of the refitted surface.
    pub lo: Vector3<f64>,
    pub hi: Vector3<f64>,
}

impl TissueSurface {
    /// Builds the collision surface from the mesh's boundary triangles and rest positions.
    pub fn new(triangles: Vec<[usize; 3]>, positions: &[Point3<f64>]) -> Option<TissueSurface> {
        if triangles.is_empty() {
            return None;
        }
        let mut node_to_vertex = vec![u32::MAX; positions.len()];
        let mut nodes = Vec::new();
        let mut local = Vec::with_capacity(triangles.len());
        for tri in &triangles {
            let mut l = [0u32; 3];
            for k in 0..3 {
                let n = tri[k];
                if node_to_vertex[n] == u32::MAX {
                    node_to_vertex[n] = nodes.len() as u32;
                    nodes.push(n);
                }
                l[k] = node_to_vertex[n];
            }
            local.push(l);
        }
        let verts: Vec<GVec> = nodes.iter().map(|&n| to_g(&positions[n].coords)).collect();

        // Edge adjacency through a sorted edge list (deterministic, no hashing).
        let mut edges: Vec<((u32, u32), u32, u8)> = Vec::with_capacity(local.len() * 3);
        for (t, l) in local.iter().enumerate() {
            for (k, (a, b)) in [(l[0], l[1]), (l[1], l[2]), (l[0], l[2])]
                .into_iter()
                .enumerate()
            {
                edges.push(((a.min(b), a.max(b)), t as u32, k as u8));
            }
        }
        edges.sort_unstable();
        let mut neighbors = vec![[NO_TRIANGLE; 3]; local.len()];
        // A manifold edge is shared by exactly two triangles; open and non-manifold edges
        // get no neighbour.
        for run in edges.chunk_by(|a, b| a.0 == b.0) {
            if let [(_, ta, ka), (_, tb, kb)] = *run {
                neighbors[ta as usize][ka as usize] = tb;
                neighbors[tb as usize][kb as usize] = ta;
            }
        }
        let mut counts = vec![0u32; nodes.len() + 1];
        for l in &local {
            for &v in l {
                counts[v as usize + 1] += 1;
            }
        }
        for k in 0..nodes.len() {
            counts[k + 1] += counts[k];
        }
        let mut fill = counts.clone();
        let mut vertex_tris = vec![0u32; local.len() * 3];
        for (t, l) in local.iter().enumerate() {
            for &v in l {
                vertex_tris[fill[v as usize] as usize] = t as u32;
                fill[v as usize] += 1;
            }
        }
        let trimesh = TriMesh::with_flags(verts, local, TriMeshFlags::DEFORMABLE).ok()?;
        let mut s = TissueSurface {
            face_normals: vec![Vector3::zeros(); triangles.len()],
            previous_normals: vec![Vector3::zeros(); triangles.len()],
            rigid: vec![false; triangles.len()],
            triangles,
            nodes,
            trimesh,
            neighbors,
            vertex_tri_start: counts,
            vertex_tris,
            lo: Vector3::zeros(),
            hi: Vector3::zeros(),
        };
        s.refit(positions);
        // no refit before the first: both normals are the rest shape's
        s.refit(positions);
        Some(s)
    }

    /// Moves the surface to `positions` (mesh nodes): BVH refit, face normals, bounding box.
    pub fn refit(&mut self, positions: &[Point3<f64>]) {
        let nodes = &self.nodes;
        self.trimesh.update_vertices(|v| {
            for (dst, &n) in v.iter_mut().zip(nodes.iter()) {
                *dst = to_g(&positions[n].coords);
            }
        });
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        for &n in &self.nodes {
            lo = lo.inf(&positions[n].coords);
            hi = hi.sup(&positions[n].coords);
        }
        self.lo = lo;
        self.hi = hi;
        // the normals of the refit before, for the contact direction; the loop below
        // overwrites every face's current one
        std::mem::swap(&mut self.previous_normals, &mut self.face_normals);
        for (t, tri) in self.triangles.iter().enumerate() {
            let a = positions[tri[0]].coords;
            let n = (positions[tri[1]].coords - a).cross(&(positions[tri[2]].coords - a));
            let len = n.norm();
            self.face_normals[t] = if len > 0.0 { n / len } else { Vector3::zeros() };
        }
    }

    /// The direction a contact on face `t` pushes along: the bisector of the face's unit
    /// normals at the last two refits (start-of-step shapes).
    ///
    /// The face normal of the start-of-step shape alone closed a loop through the step: the
    /// contact force along it twists the loaded faces, and the next step pushes along the
    /// twisted normal. Under a deep press that loop's gain passed −1 and the fixed point
    /// became a two-step cycle: a ball held still in a dent of the study mesh (67 N, two
    /// faces meeting at a concave edge) settled into forces alternating (−12.1, 8.5, 55.4) ↔
    /// (−6.8, −4.6, 62.5) N every step, its faces' normals swinging by 15°
    /// (`tests/held_ball_normal_cycle.rs`). With the bisector the loop's gain is halved and
    /// its two-step mode averages out: a fixed point keeps its own normal exactly, and a
    /// probe moving quasi-statically sees the normal half a step late.
    pub fn contact_normal(&self, t: u32) -> Vector3<f64> {
        let now = self.face_normals[t as usize];
        (now + self.previous_normals[t as usize])
            .try_normalize(1e-12)
            .unwrap_or(now)
    }

    pub fn face_normal(&self, t: u32) -> Vector3<f64> {
        self.face_normals[t as usize]
    }

    /// Angle-weighted pseudo-normal of the feature a projection landed on (unnormalised).
    fn pseudo_normal(&self, t: u32, location: &TrianglePointLocation) -> Vector3<f64> {
        match *location {
            TrianglePointLocation::OnFace(..) | TrianglePointLocation::OnSolid => {
                self.face_normals[t as usize]
            }
            TrianglePointLocation::OnEdge(k, _) => {
                let other = self.neighbors[t as usize][k as usize];
                let mut n = self.face_normals[t as usize];
                if other != NO_TRIANGLE {
                    n += self.face_normals[other as usize];
                }
                n
            }
            TrianglePointLocation::OnVertex(k) => {
                let v = self.trimesh.indices()[t as usize][k as usize] as usize;
                let verts = self.trimesh.vertices();
                let mut n = Vector3::zeros();
                for &tt in &self.vertex_tris
                    [self.vertex_tri_start[v] as usize..self.vertex_tri_start[v + 1] as usize]
                {
                    let l = self.trimesh.indices()[tt as usize];
                    let j = (0..3).find(|&j| l[j] as usize == v).unwrap_or(0);
                    let p = from_g(verts[l[j] as usize]);
                    let e1 = (from_g(verts[l[(j + 1) % 3] as usize]) - p).normalize();
                    let e2 = (from_g(verts[l[(j + 2) % 3] as usize]) - p).normalize();
                    let angle = e1.dot(&e2).clamp(-1.0, 1.0).acos();
                    if angle.is_finite() {
                        n += self.face_normals[tt as usize] * angle;
                    }
                }
                n
            }
        }
    }

    /// `p` lies behind triangle `t`'s plane at its closest point: a probe tracked on `t` went
    /// through it.
    fn behind(&self, t: u32, p: &Vector3<f64>) -> bool {
        let (c, _) = self.project_on_triangle(t, p);
        self.face_normal(t).dot(&(p - c)) < 0.0
    }

    /// Closest point of `p` on triangle `t`: (point, barycentric weights).
    fn project_on_triangle(&self, t: u32, p: &Vector3<f64>) -> (Vector3<f64>, [f64; 3]) {
        let tri = self.trimesh.triangle(t);
        let (proj, loc) = tri.project_local_point_and_get_location(to_g(p), false);
        let w = loc.barycentric_coordinates().unwrap_or([1.0 / 3.0; 3]);
        (from_g(proj.point), w)
    }

    fn triangle_nodes(&self, t: u32) -> [usize; 3] {
        self.triangles[t as usize]
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.triangles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    #[allow(dead_code)]
    fn triangle_shape(&self, t: u32) -> Triangle {
        self.trimesh.triangle(t)
    }
}

/// Distances of the contact model, m.
#[derive(Debug, Clone, Copy)]
pub struct ContactParams {
    pub alarm_distance: f64,
    pub contact_distance: f64,
    pub max_contacts: usize,
    /// Spread each probe ball's force over its contact patch instead of holding the closest
    /// point of every close triangle: one contact per ball, acting on the tissue nodes under
    /// a disc of the Hertz radius a = √(R δ) (δ the indentation of the surface under the ball
    /// from its rest shape), each node weighted by the Hertz pressure √(1 − r²/a²) integrated
    /// against its shape functions, along the pressure-weighted mean normal of the rest shape
    /// under the patch; its gap is the pressure-weighted mean distance from the ball to the
    /// surface there.
    ///
    /// Why: the closest points put a ball's force on the few nodes of one or two facets, and
    /// it jumps between nodes, edges and faces as the ball slides: slid at constant depth along
    /// the study mesh refined once it varies by 10.5% RMS from facet to facet
    /// (`tests/facet_slide.rs`). The patch's weights are continuous in the ball's position, as
    /// a surface-integrated contact's are.
    pub hertz_patch: bool,
}

/// One probe point – tissue triangle contact, linearised at the start-of-step geometry.
#[derive(Debug, Clone, Copy)]
pub struct Contact {
    /// Probe collision sphere.
    pub sphere: usize,
    /// Tissue triangle (collision surface index) of the contact point.
    pub triangle: u32,
    /// The triangle's mesh nodes with the contact point's barycentric weights.
    pub nodes: [usize; 3],
    pub weights: [f64; 3],
    /// Index of the Hertz patch the force is spread over instead ([`ContactDetector::
    /// patches`]; [`NO_PATCH`]: held at the contact point).
    pub patch: u32,
    /// Outward normal (out of the tissue, onto the probe) and two tangents.
    pub normal: Vector3<f64>,
    pub t1: Vector3<f64>,
    pub t2: Vector3<f64>,
    /// Sphere radius used for the gap (radius, or the contact distance for points).
    pub radius: f64,
    /// Contact point on the tissue at the start of the step, world m.
    pub point: Vector3<f64>,
    /// Probe sphere centre at the start of the step.
    pub probe_point: Vector3<f64>,
    /// Gap at the start of the step (≥ 0 separated).
    pub gap_start: f64,
    /// Free-motion violation per row: normal gap, tangential free slip.
    pub free_violation: [f64; 3],
}

impl Default for Contact {
    fn default() -> Contact {
        Contact {
            sphere: 0,
            triangle: 0,
            nodes: [0; 3],
            weights: [0.0; 3],
            patch: NO_PATCH,
            normal: Vector3::zeros(),
            t1: Vector3::zeros(),
            t2: Vector3::zeros(),
            radius: 0.0,
            point: Vector3::zeros(),
            probe_point: Vector3::zeros(),
            gap_start: 0.0,
            free_violation: [0.0; 3],
        }
    }
}

impl Contact {
    /// The nodes the contact acts on, with their weights: its patch's (from `patches`, the
    /// detector's) or its triangle's.
    pub fn spread<'a>(&'a self, patches: &'a [Patch]) -> impl Iterator<Item = (usize, f64)> + 'a {
        let (nodes, weights): (&[usize], &[f64]) = match patches.get(self.patch as usize) {
            Some(p) => (&p.nodes[..p.len], &p.weights[..p.len]),
            None => (&self.nodes, &self.weights),
        };
        nodes.iter().copied().zip(weights.iter().copied())
    }
}

/// Two unit tangents orthogonal to `n`, chosen deterministically from the smallest axis of n.
pub fn tangents(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let a = if n.x.abs() <= n.y.abs() && n.x.abs() <= n.z.abs() {
        Vector3::x()
    } else if n.y.abs() <= n.z.abs() {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let t1 = n.cross(&a).normalize();
    let t2 = n.cross(&t1);
    (t1, t2)
}

/// The proximity query stage with the per-sphere side tracking.
pub struct ContactDetector {
    pub params: ContactParams,
    /// Triangle each sphere was last in contact with (NO_TRIANGLE: none).
    tracked: Vec<u32>,
    /// Candidates of this step (capacity: one per sphere, reserved once).
    candidates: Vec<Contact>,
    /// Selected contacts, at most max_contacts, ordered by free gap then sphere index.
    pub contacts: Vec<Contact>,
    /// The patch's nodes and weights while it is integrated (reserved once).
    patch: Vec<(usize, f64)>,
    /// This step's Hertz patches, one per ball in contact ([`Contact::patch`]; reserved
    /// once).
    pub patches: Vec<Patch>,
}

impl ContactDetector {
    pub fn new(params: ContactParams, spheres: usize) -> ContactDetector {
        // scratch of the Hertz patches, reserved once (none without them)
        let (points, balls) = if params.hertz_patch {
            (3 * PATCH_POINTS, spheres)
        } else {
            (0, 0)
        };
        ContactDetector {
            params,
            tracked: vec![NO_TRIANGLE; spheres],
            // Several features per sphere (a sphere in a dent touches a few triangles); a
            // full list keeps the most violated (see `push`).
            candidates: Vec::with_capacity(spheres * 2 * FEATURES_PER_SPHERE),
            contacts: Vec::with_capacity(params.max_contacts.max(1)),
            patch: Vec::with_capacity(points),
            patches: Vec::with_capacity(balls),
        }
    }

    /// Forget the side history (after a teleport of the probe).
    pub fn reset_tracking(&mut self) {
        self.tracked.iter_mut().for_each(|t| *t = NO_TRIANGLE);
    }

    /// Finds the contacts of this step. `surface` must be refitted to `positions` (start of
    /// step); `free_positions` are the tissue nodes after free motion, `rest` at rest (what a
    /// Hertz patch's indentation and normal are measured from); `tissue_motion` bounds how far
    /// any surface node moved in the free motion.
    #[allow(clippy::too_many_arguments)]
    pub fn detect(
        &mut self,
        probe: &Probe,
        surface: &TissueSurface,
        support: Option<&TissueSurface>,
        positions: &[Point3<f64>],
        free_positions: &[Point3<f64>],
        rest: &[Point3<f64>],
        tissue_motion: f64,
    ) {
        self.candidates.clear();
        self.contacts.clear();
        self.patches.clear();
        let margin = (self.params.alarm_distance - self.params.contact_distance).max(0.0);
        let nodes = (positions, free_positions);
        for i in 0..probe.spheres.len() {
            let radius = if probe.spheres[i].radius > 0.0 {
                probe.spheres[i].radius
            } else {
                self.params.contact_distance
            };
            let p0 = probe.sphere_world(i);
            let pf = probe.sphere_world_free(i);
            let reach = radius + margin + (pf - p0).norm() + tissue_motion;
            // Cheap box rejection before the BVH query.
            let outside_box =
                (0..3).any(|k| p0[k] < surface.lo[k] - reach || p0[k] > surface.hi[k] + reach);
            if outside_box {
                self.tracked[i] = NO_TRIANGLE;
                continue;
            }
            let Some((proj, (tri, location))) = surface
                .trimesh
                .project_local_point_and_get_location_with_max_dist(to_g(&p0), false, reach)
            else {
                if self.tracked[i] == NO_TRIANGLE {
                    continue;
                }
                // Nothing within reach of a point that was tracked: it is far outside
                // (lifted off), unless it went through; the tracked side decides.
                let t = self.tracked[i];
                if !surface.behind(t, &p0) {
                    self.tracked[i] = NO_TRIANGLE;
                    continue;
                }
                let first = self.candidates.len();
                self.push_tracked(i, first, t, radius, (&p0, &pf), surface, nodes);
                continue;
            };
            let c = from_g(proj.point);
            let to_point = p0 - c;
            let pseudo = surface.pseudo_normal(tri, &location);
            let inside = pseudo.dot(&to_point) < 0.0;
            if inside && self.tracked[i] != NO_TRIANGLE {
                // The nearest feature says inside. Either the point went through the tracked
                // side, or the tissue under a deep press is crushed so thin that the far side
                // (the held inferior face) is nearer than the dent the probe sits in. Keeping
                // only the tracked triangle in the second case made the contact count
                // alternate 1 ↔ 13 step to step and the force 48 ↔ 108 N
                // (`tests/deep_press_chatter.rs`): keep every close feature on the probe's
                // side, and the tracked triangle as well when the point is behind it.
                let t = self.tracked[i];
                let side = surface.face_normal(t);
                let first = self.candidates.len();
                let probe = (&p0, &pf);
                self.push_close_features(
                    i,
                    first,
                    radius,
                    reach,
                    probe,
                    Some(&side),
                    surface,
                    nodes,
                );
                self.keep_closest(first);
                if self.candidates.len() == first || surface.behind(t, &p0) {
                    self.push_tracked(i, first, t, radius, probe, surface, nodes);
                } else {
                    self.track_most_violated(i, first);
                }
                continue;
            }
            // Outside: one contact per close surface feature (a sphere in a dent touches
            // several triangles; only the nearest would make it rock between them).
            let first = self.candidates.len();
            self.push_close_features(i, first, radius, reach, (&p0, &pf), None, surface, nodes);
            self.keep_closest(first);
            if self.candidates.len() == first && !surface.rigid[tri as usize] {
                // Nothing but the nearest feature (numerically on an edge of a far side):
                // fall back to it with its pseudo-normal.
                let dist = to_point.norm();
                let normal = match location {
                    TrianglePointLocation::OnFace(..) | TrianglePointLocation::OnSolid => {
                        surface.contact_normal(tri)
                    }
                    _ if dist > 1e-9 => to_point / dist,
                    _ => pseudo
                        .try_normalize(0.0)
                        .unwrap_or_else(|| surface.face_normal(tri)),
                };
                self.push_feature(
                    i,
                    first,
                    tri,
                    &location,
                    normal,
                    radius,
                    &c,
                    (&p0, &pf),
                    surface,
                    nodes,
                    false,
                );
            } else if self.candidates[first..].iter().any(|k| k.triangle == tri) {
                // Track the nearest triangle for the inside case.
                self.tracked[i] = tri;
            }
        }
        if self.params.hertz_patch {
            for i in 0..probe.spheres.len() {
                self.collapse_to_patch(i, probe, surface, nodes, rest);
            }
        }
        if let Some(support) = support {
            self.detect_support(probe, support, positions, free_positions);
        }
        // Keep the most violated ones (deterministic: gap, then sphere index).
        self.candidates.sort_unstable_by(|a, b| {
            a.free_violation[0]
                .total_cmp(&b.free_violation[0])
                .then(a.sphere.cmp(&b.sphere))
                .then(a.triangle.cmp(&b.triangle))
        });
        let n = self.candidates.len().min(self.params.max_contacts);
        self.contacts.extend_from_slice(&self.candidates[..n]);
    }

    /// Contacts with the rigid support (the bone under the held inferior surface): a one-sided
    /// sheet whose normals point into the tissue. A probe crushing the tissue stops on it
    /// instead of passing the inferior plane; below the sheet it is pushed back up.
    fn detect_support(
        &mut self,
        probe: &Probe,
        support: &TissueSurface,
        positions: &[Point3<f64>],
        free_positions: &[Point3<f64>],
    ) {
        let margin = (self.params.alarm_distance - self.params.contact_distance).max(0.0);
        for i in 0..probe.spheres.len() {
            let radius = if probe.spheres[i].radius > 0.0 {
                probe.spheres[i].radius
            } else {
                self.params.contact_distance
            };
            let p0 = probe.sphere_world(i);
            let pf = probe.sphere_world_free(i);
            let reach = radius + margin + (pf - p0).norm();
            if (0..3).any(|k| p0[k] < support.lo[k] - reach || p0[k] > support.hi[k] + reach) {
                continue;
            }
            let first = self.candidates.len();
            let aabb = Aabb::new(
                to_g(&(p0 - Vector3::repeat(reach))),
                to_g(&(p0 + Vector3::repeat(reach))),
            );
            for t in support.trimesh.bvh().intersect_aabb(&aabb) {
                let (proj, loc) = support
                    .trimesh
                    .triangle(t)
                    .project_local_point_and_get_location(to_g(&p0), false);
                let c = from_g(proj.point);
                if (p0 - c).norm() > reach {
                    continue;
                }
                // One-sided: always the (pseudo-)normal of the sheet, whichever side.
                let normal = support
                    .pseudo_normal(t, &loc)
                    .try_normalize(0.0)
                    .unwrap_or_else(|| support.face_normal(t));
                self.push_feature(
                    i,
                    first,
                    t,
                    &loc,
                    normal,
                    radius,
                    &c,
                    (&p0, &pf),
                    support,
                    (positions, free_positions),
                    true,
                );
            }
            self.keep_closest(first);
        }
    }

    /// Pushes one contact per surface feature within `reach` of sphere `i` whose outward
    /// normal faces the sphere's centre (candidates of this sphere start at `first`). With
    /// `side`, features facing away from it are left out.
    #[allow(clippy::too_many_arguments)]
    fn push_close_features(
        &mut self,
        i: usize,
        first: usize,
        radius: f64,
        reach: f64,
        probe: (&Vector3<f64>, &Vector3<f64>),
        side: Option<&Vector3<f64>>,
        surface: &TissueSurface,
        nodes: (&[Point3<f64>], &[Point3<f64>]),
    ) {
        let p0 = probe.0;
        let lo = p0 - Vector3::repeat(reach);
        let hi = p0 + Vector3::repeat(reach);
        let aabb = Aabb::new(to_g(&lo), to_g(&hi));
        for t in surface.trimesh.bvh().intersect_aabb(&aabb) {
            if surface.rigid[t as usize] {
                continue;
            }
            let tri_shape = surface.trimesh.triangle(t);
            let (proj, loc) = tri_shape.project_local_point_and_get_location(to_g(p0), false);
            let c = from_g(proj.point);
            let d = p0 - c;
            let dist = d.norm();
            if dist > reach {
                continue;
            }
            let normal = match loc {
                TrianglePointLocation::OnFace(..) | TrianglePointLocation::OnSolid => {
                    // Behind this face's plane while outside the solid: a far side.
                    if surface.face_normal(t).dot(&d) < 0.0 {
                        continue;
                    }
                    surface.contact_normal(t)
                }
                _ => {
                    let pseudo = surface.pseudo_normal(t, &loc);
                    if pseudo.dot(&d) < 0.0 {
                        continue;
                    }
                    if dist > 1e-9 {
                        d / dist
                    } else {
                        pseudo
                            .try_normalize(0.0)
                            .unwrap_or_else(|| surface.face_normal(t))
                    }
                }
            };
            // Facing away from the side the probe is tracked on: the far side of a
            // thin, crushed part of the tissue.
            if side.is_some_and(|s| normal.dot(s) <= 0.0) {
                continue;
            }
            self.push_feature(
                i, first, t, &loc, normal, radius, &c, probe, surface, nodes, false,
            );
        }
    }

    /// Pushes the contact at the feature a projection landed on (point `c`, location `loc` on
    /// triangle `t`) unless this sphere already has it: edges and vertices are reported by
    /// every triangle sharing them. `probe` is the sphere's centre at the start of the step and
    /// after free motion, `nodes` the tissue positions at the same two instants.
    #[allow(clippy::too_many_arguments)]
    fn push_feature(
        &mut self,
        i: usize,
        first: usize,
        t: u32,
        loc: &TrianglePointLocation,
        normal: Vector3<f64>,
        radius: f64,
        c: &Vector3<f64>,
        probe: (&Vector3<f64>, &Vector3<f64>),
        surface: &TissueSurface,
        nodes: (&[Point3<f64>], &[Point3<f64>]),
        support: bool,
    ) {
        if self.already_found(first, c, &normal) {
            return;
        }
        let weights = loc.barycentric_coordinates().unwrap_or([1.0 / 3.0; 3]);
        self.push(
            i, first, t, weights, normal, radius, c, probe.0, probe.1, surface, nodes.0, nodes.1,
            support,
        );
    }

    /// Tracks sphere `i` on its most violated candidate (those from `first` on).
    fn track_most_violated(&mut self, i: usize, first: usize) {
        if let Some(k) = self.candidates[first..].iter().min_by(|a, b| {
            a.gap_start
                .total_cmp(&b.gap_start)
                .then(a.triangle.cmp(&b.triangle))
        }) {
            self.tracked[i] = k.triangle;
        }
    }

    /// Keeps the [`FEATURES_PER_SPHERE`] most violated candidates of one sphere (those from
    /// `first` on): more add rows to W, not support.
    fn keep_closest(&mut self, first: usize) {
        let mine = &mut self.candidates[first..];
        if mine.len() > FEATURES_PER_SPHERE {
            mine.sort_unstable_by(|a, b| {
                a.free_violation[0]
                    .total_cmp(&b.free_violation[0])
                    .then(a.triangle.cmp(&b.triangle))
            });
            self.candidates.truncate(first + FEATURES_PER_SPHERE);
        }
    }

    /// Sphere `i` is inside the surface at the start of the step: keep it on its tracked
    /// triangle or the neighbour across the edge it slid over, unless that one is among the
    /// sphere's candidates already (those from `first` on).
    #[allow(clippy::too_many_arguments)]
    fn push_tracked(
        &mut self,
        i: usize,
        first: usize,
        t: u32,
        radius: f64,
        probe: (&Vector3<f64>, &Vector3<f64>),
        surface: &TissueSurface,
        nodes: (&[Point3<f64>], &[Point3<f64>]),
    ) {
        let (p0, pf) = probe;
        let (positions, free_positions) = nodes;
        // Best of the triangle and its edge neighbours: smallest in-plane clamp distance.
        let mut best = (t, f64::INFINITY);
        for cand in core::iter::once(t).chain(surface.neighbors[t as usize].iter().copied()) {
            if cand == NO_TRIANGLE || surface.rigid[cand as usize] {
                continue;
            }
            let n = surface.face_normal(cand);
            let (c, _) = surface.project_on_triangle(cand, p0);
            let d = p0 - c;
            let in_plane = (d - n * n.dot(&d)).norm();
            if in_plane < best.1 {
                best = (cand, in_plane);
            }
        }
        let t = best.0;
        // Found already among this sphere's close features: one row per feature.
        if self.candidates[first..].iter().any(|k| k.triangle == t) {
            self.tracked[i] = t;
            return;
        }
        let (c, w) = surface.project_on_triangle(t, p0);
        let n = surface.contact_normal(t);
        self.push(
            i,
            first,
            t,
            w,
            n,
            radius,
            &c,
            p0,
            pf,
            surface,
            positions,
            free_positions,
            false,
        );
    }

    /// Replaces sphere `i`'s candidates by one contact spread over its Hertz patch
    /// ([`ContactParams::hertz_patch`]), started at the closest of them.
    fn collapse_to_patch(
        &mut self,
        i: usize,
        probe: &Probe,
        surface: &TissueSurface,
        nodes: (&[Point3<f64>], &[Point3<f64>]),
        rest: &[Point3<f64>],
    ) {
        let (positions, free_positions) = nodes;
        let Some(anchor) = self
            .candidates
            .iter()
            .filter(|k| k.sphere == i)
            .min_by(|a, b| {
                a.gap_start
                    .total_cmp(&b.gap_start)
                    .then(a.triangle.cmp(&b.triangle))
            })
            .copied()
        else {
            return;
        };
        self.candidates.retain(|k| k.sphere != i);
        let (p0, pf) = (anchor.probe_point, probe.sphere_world_free(i));
        let radius = anchor.radius;
        // the first radius from the surface's indentation at the closest point (from its rest
        // shape) and the ball's penetration where it has not been resolved
        let mut delta = (-anchor.gap_start).max(0.0);
        for (n, w) in anchor.spread(&[]) {
            delta += w * anchor.normal.dot(&(rest[n] - positions[n]));
        }
        let mut axis = anchor.normal;
        let mut contact = anchor;
        let mut a = (radius * delta.max(0.0)).sqrt().min(0.9 * radius);
        if a > 1e-3 * radius {
            // Three passes, each about the last one's mean direction and at the radius of its
            // mean indentation: both are continuous in the ball's position where the closest
            // feature, which starts it, jumps.
            let mut gap = anchor.gap_start;
            for _ in 0..3 {
                let Some((direction, mean_gap)) =
                    self.integrate_patch(&p0, &axis, a, radius, surface, rest)
                else {
                    break;
                };
                axis = direction;
                gap = mean_gap;
                // a Hertz dent is parabolic: its pressure-weighted mean depth is 4/5 of the
                // depth under the centre, as is a ball's mean penetration of a flat face
                let mut mean_depth = 0.0;
                for &(n, w) in &self.patch {
                    mean_depth += w * axis.dot(&(rest[n] - positions[n]));
                }
                let depth = (mean_depth.max(0.0) + (-mean_gap).max(0.0)) / 0.8;
                a = (radius * depth).sqrt().min(0.9 * radius);
                if a <= 1e-3 * radius {
                    break;
                }
            }
            if !self.patch.is_empty() {
                self.patch
                    .sort_unstable_by(|x, y| y.1.total_cmp(&x.1).then(x.0.cmp(&y.0)));
                self.patch.truncate(PATCH_NODES);
                let total: f64 = self.patch.iter().map(|e| e.1).sum();
                let mut spread = Patch {
                    nodes: [0; PATCH_NODES],
                    weights: [0.0; PATCH_NODES],
                    len: self.patch.len(),
                };
                for (k, &(n, w)) in self.patch.iter().enumerate() {
                    spread.nodes[k] = n;
                    spread.weights[k] = w / total;
                }
                contact.patch = self.patches.len() as u32;
                self.patches.push(spread);
                contact.normal = axis;
                // the gap the row's weights measure: the pressure-weighted mean distance from
                // the ball to the surface over the patch
                contact.gap_start = gap;
            }
        }
        let (t1, t2) = tangents(&contact.normal);
        let mut moved = Vector3::zeros();
        for (n, w) in contact.spread(&self.patches) {
            moved += w * (free_positions[n].coords - positions[n].coords);
        }
        let slip = (pf - p0) - moved;
        contact.t1 = t1;
        contact.t2 = t2;
        contact.free_violation = [
            contact.gap_start + contact.normal.dot(&slip),
            t1.dot(&slip),
            t2.dot(&slip),
        ];
        self.candidates.push(contact);
    }

    /// Integrates the Hertz pressure over a disc of radius `a` on the ball (centre `p0`,
    /// `radius`) about `axis` (out of the tissue), each quadrature point projected onto the
    /// surface: fills [`Self::patch`] with each node's weight (the pressure times its shape
    /// function there, normalised to sum to 1) and returns the pressure-weighted mean
    /// normal of the rest shape there and mean distance from the ball's surface to the
    /// tissue's (negative: penetrating). `None` when every point lands on a
    /// held triangle.
    fn integrate_patch(
        &mut self,
        p0: &Vector3<f64>,
        axis: &Vector3<f64>,
        a: f64,
        radius: f64,
        surface: &TissueSurface,
        rest: &[Point3<f64>],
    ) -> Option<(Vector3<f64>, f64)> {
        let (t1, t2) = tangents(axis);
        self.patch.clear();
        let (mut direction, mut gap, mut total) = (Vector3::zeros(), 0.0, 0.0);
        for ring in 0..PATCH_RINGS {
            let rho = a * (ring as f64 + 0.5) / PATCH_RINGS as f64;
            let pressure = (1.0 - (rho / a).powi(2)).sqrt();
            let count = 6 * ring + 3;
            let sin = rho / radius;
            let cos = (1.0 - sin * sin).sqrt();
            for m in 0..count {
                let phi =
                    std::f64::consts::TAU * (m as f64 + 0.5 * (ring % 2) as f64) / count as f64;
                let d = -axis * cos + (t1 * phi.cos() + t2 * phi.sin()) * sin;
                let sample = p0 + d * radius;
                let (proj, (tri, loc)) = surface
                    .trimesh
                    .project_local_point_and_get_location(to_g(&sample), false);
                if surface.rigid[tri as usize] {
                    continue;
                }
                let q = from_g(proj.point);
                let dist = (p0 - q).norm();
                // The direction is the rest shape's normal under the patch: on a dent that
                // has taken the ball's shape every direction from the surface to the centre
                // is the ball's own radius, so their mean is whatever axis the patch was
                // sampled about, and it kept the closest feature's normal, jumping by 11°
                // when that feature changed.
                let nodes = surface.triangle_nodes(tri);
                let [r0, r1, r2] = nodes.map(|n| rest[n]);
                if let Some(rest_normal) = (r1 - r0).cross(&(r2 - r0)).try_normalize(1e-30) {
                    direction += rest_normal * pressure;
                }
                gap += pressure * (dist - radius);
                total += pressure;
                let bary = loc.barycentric_coordinates().unwrap_or([1.0 / 3.0; 3]);
                for (&n, b) in nodes.iter().zip(bary) {
                    let w = pressure * b;
                    if w <= 0.0 {
                        continue;
                    }
                    match self.patch.iter_mut().find(|(m, _)| *m == n) {
                        Some(e) => e.1 += w,
                        None => self.patch.push((n, w)),
                    }
                }
            }
        }
        if total <= 0.0 {
            self.patch.clear();
            return None;
        }
        self.patch.iter_mut().for_each(|e| e.1 /= total);
        Some((direction.try_normalize(1e-12).unwrap_or(*axis), gap / total))
    }

    /// True when a candidate found since index `first` (this probe sphere) already has this
    /// point and normal: edges and vertices are reported by every triangle sharing them.
    fn already_found(&self, first: usize, point: &Vector3<f64>, normal: &Vector3<f64>) -> bool {
        self.candidates[first..].iter().any(|k| {
            (k.point - point).norm_squared() < 1e-18 && (k.normal - normal).norm_squared() < 1e-12
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn push(
        &mut self,
        i: usize,
        first: usize,
        tri: u32,
        weights: [f64; 3],
        normal: Vector3<f64>,
        radius: f64,
        c: &Vector3<f64>,
        p0: &Vector3<f64>,
        pf: &Vector3<f64>,
        surface: &TissueSurface,
        positions: &[Point3<f64>],
        free_positions: &[Point3<f64>],
        support: bool,
    ) {
        let nodes = surface.triangle_nodes(tri);
        let gap_start = normal.dot(&(p0 - c)) - radius;
        // Contact point moved with the free motion of the tissue.
        let mut c_free = *c;
        for k in 0..3 {
            c_free += weights[k] * (free_positions[nodes[k]].coords - positions[nodes[k]].coords);
        }
        let gap_free = normal.dot(&(pf - c_free)) - radius;
        let alarm = (self.params.alarm_distance - self.params.contact_distance).max(0.0);
        if gap_start.min(gap_free) > alarm {
            if gap_start > 0.0 && !support {
                self.tracked[i] = NO_TRIANGLE;
            }
            return;
        }
        if !support {
            self.tracked[i] = tri;
        }
        let (t1, t2) = tangents(&normal);
        let slip = (pf - p0) - (c_free - c);
        let contact = Contact {
            sphere: i,
            triangle: tri,
            nodes,
            weights,
            patch: NO_PATCH,
            normal,
            t1,
            t2,
            radius,
            point: *c,
            probe_point: *p0,
            gap_start,
            free_violation: [gap_free, t1.dot(&slip), t2.dot(&slip)],
        };
        if self.candidates.len() < self.candidates.capacity() {
            self.candidates.push(contact);
            return;
        }
        // Fixed capacity (no allocation in the step). A full list must not drop the features
        // that matter: the bounding-volume query returns them in no particular order, and a
        // sphere on a fine surface has more features within reach than slots, so the ones
        // under it could be the ones left out (a ball pressed into a finely meshed block
        // found no contact at all). The new feature replaces the least violated of this
        // sphere's own (or, when it has none yet, of all) if it is more violated.
        let from = if first < self.candidates.len() {
            first
        } else {
            0
        };
        let weakest = (from..self.candidates.len()).max_by(|&a, &b| {
            self.candidates[a].free_violation[0].total_cmp(&self.candidates[b].free_violation[0])
        });
        if let Some(w) = weakest {
            if gap_free < self.candidates[w].free_violation[0] {
                self.candidates[w] = contact;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fem::test_meshes::box_mesh;

    #[test]
    fn boundary_of_a_box_is_closed_and_outward() {
        let mesh = box_mesh(0.02, 0.01, 0.005, 4, 3, 2);
        let tris = mesh.boundary_faces();
        // 2 triangles per boundary quad.
        assert_eq!(tris.len(), 2 * 2 * (4 * 3 + 4 * 2 + 3 * 2));
        let centre = Vector3::new(0.01, 0.005, 0.0025);
        let mut edges: Vec<(usize, usize)> = Vec::new();
        for t in &tris {
            let [a, b, c] = t.map(|i| mesh.nodes[i].coords);
            let n = (b - a).cross(&(c - a));
            assert!(
                n.dot(&((a + b + c) / 3.0 - centre)) > 0.0,
                "inward triangle {t:?}"
            );
            for (u, v) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                edges.push((u.min(v), u.max(v)));
            }
        }
        edges.sort_unstable();
        for e in edges.chunks(2) {
            assert_eq!(e[0], e[1], "open edge");
        }
    }

    /// The Hertz patch's contact is one per ball, its weights sum to 1 and, as the ball slides
    /// across the mesh's nodes and edges, its gap and weights change in proportion to the
    /// step: the closest points jump from node to edge to face.
    #[test]
    fn a_patch_contact_is_continuous_as_the_ball_slides() {
        // 0.5 mm quads, the ball 0.1 mm into the face at rest: a = √(3 mm · 0.1 mm) = 0.55 mm.
        let mesh = box_mesh(0.024, 0.024, 0.005, 48, 48, 1);
        let surface = TissueSurface::new(mesh.boundary_faces(), &mesh.nodes).unwrap();
        let params = ContactParams {
            alarm_distance: 3.408e-3,
            contact_distance: 1.136e-3,
            max_contacts: 32,
            hertz_patch: true,
        };
        let mut detector = ContactDetector::new(params, 1);
        let mut last: Option<(f64, Vec<(usize, f64)>)> = None;
        let step = 0.01e-3;
        for k in 0..60 {
            let probe = ball_at([0.012 + k as f64 * step, 0.0121, 0.005 + 3.0e-3 - 0.1e-3]);
            detector.reset_tracking();
            detector.detect(
                &probe,
                &surface,
                None,
                &mesh.nodes,
                &mesh.nodes,
                &mesh.nodes,
                0.0,
            );
            assert_eq!(detector.contacts.len(), 1, "one contact per ball");
            let c = detector.contacts[0];
            let spread = &detector.patches;
            assert!(
                spread.get(c.patch as usize).is_some_and(|p| p.len > 3),
                "spread over its patch"
            );
            let total: f64 = c.spread(spread).map(|(_, w)| w).sum();
            assert!((total - 1.0).abs() < 1e-12, "weights sum to {total}");
            assert!((c.normal - Vector3::z()).norm() < 1e-9, "{:?}", c.normal);
            // the pressure-weighted mean gap of a sphere δ into a flat face over a = √(R δ):
            // −δ + ⟨r²⟩/(2R) with ⟨r²⟩ = 2a²/5, so −0.8 δ
            assert!(
                (c.gap_start + 0.08e-3).abs() < 2e-6,
                "mean gap {} m",
                c.gap_start
            );
            let weights: Vec<(usize, f64)> = c.spread(spread).collect();
            if let Some((gap, before)) = &last {
                assert!((c.gap_start - gap).abs() < 1e-7, "gap jumps at step {k}");
                // weight moved between nodes: bounded by the step over the patch's size
                let mut moved = 0.0;
                for &(n, w) in &weights {
                    let was = before.iter().find(|e| e.0 == n).map_or(0.0, |e| e.1);
                    moved += (w - was).abs();
                }
                for &(n, w) in before {
                    if !weights.iter().any(|e| e.0 == n) {
                        moved += w;
                    }
                }
                assert!(moved < 0.1, "{moved} of the weight moved at step {k}");
            }
            last = Some((c.gap_start, weights));
        }
    }

    /// A ball-tipped probe of radius 3 mm with its centre at `centre`.
    fn ball_at(centre: [f64; 3]) -> Probe {
        let cfg = launch_config::scene::ProbeConfig {
            model: "sphere".into(),
            tip_radius: 3.0e-3,
            initial_position: centre,
            ..Default::default()
        };
        Probe::new(&cfg, 1.136e-3, std::path::Path::new(".")).unwrap()
    }

    /// Regression: the candidate list has a fixed capacity (16 per sphere) and used to drop
    /// every feature found after it was full. A ball on a finely meshed block has hundreds
    /// of features within reach, returned by the bounding-volume query in no useful order,
    /// so the triangles under the ball were dropped and a ball pressed into the block felt
    /// no contact at all.
    #[test]
    fn a_full_candidate_list_keeps_the_features_under_the_sphere() {
        // 24 mm × 24 mm top face of 0.5 mm quads, at z = 5 mm.
        let mesh = box_mesh(0.024, 0.024, 0.005, 48, 48, 1);
        let surface = TissueSurface::new(mesh.boundary_faces(), &mesh.nodes).unwrap();
        // The ball's centre above the middle of the face, the ball 0.1 mm into the tissue.
        let probe = ball_at([0.012, 0.012, 0.005 + 3.0e-3 - 0.1e-3]);
        let params = ContactParams {
            alarm_distance: 3.408e-3,
            contact_distance: 1.136e-3,
            max_contacts: 32,
            hertz_patch: false,
        };
        let mut detector = ContactDetector::new(params, probe.spheres.len());
        detector.detect(
            &probe,
            &surface,
            None,
            &mesh.nodes,
            &mesh.nodes,
            &mesh.nodes,
            0.0,
        );
        let deepest = detector
            .contacts
            .iter()
            .map(|c| c.free_violation[0])
            .fold(f64::INFINITY, f64::min);
        assert!(
            (deepest + 0.1e-3).abs() < 1e-6,
            "the ball is 0.1 mm in, the deepest contact found: {deepest} m"
        );
        // The kept ones are the features under and around the ball (all within half a
        // millimetre of touching), not far ones at the rim of reach (the list that dropped
        // new features kept ones 1.4–2.2 mm away).
        assert!(
            detector
                .contacts
                .iter()
                .all(|c| c.free_violation[0] < 0.5e-3),
            "{:?}",
            detector
                .contacts
                .iter()
                .map(|c| c.free_violation[0])
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn tangents_are_orthonormal() {
        for n in [
            Vector3::z(),
            Vector3::new(0.3, -0.4, 0.866).normalize(),
            -Vector3::x(),
        ] {
            let (t1, t2) = tangents(&n);
            assert!(
                t1.dot(&n).abs() < 1e-12 && t2.dot(&n).abs() < 1e-12 && t1.dot(&t2).abs() < 1e-12
            );
            assert!((t1.norm() - 1.0).abs() < 1e-12 && (t2.norm() - 1.0).abs() < 1e-12);
            assert!(
                (t1.cross(&t2) - n).norm() < 1e-12,
                "right-handed (n, t1, t2)"
            );
        }
    }
}
