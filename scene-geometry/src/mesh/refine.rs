//! Uniform refinement of a tet mesh: every tet split into eight at its edge midpoints (the
//! inner octahedron cut along one diagonal), with the new boundary nodes on the facets or on
//! the smooth surface through the boundary vertices ([`SmoothSurface`]).
//!
//! Refining a mesh whose midpoints stay on its facets keeps its facets: the refined surface is
//! still the coarse chord polygon. With [`Midpoints::Smooth`] the boundary midpoints go onto
//! the smooth surface, so each refinement halves the facets and quarters their distance from a
//! smooth tissue: the self-test's refined truth is such a tissue (`gap_diagnosis`'s
//! `RefinedTruth`). A ball slid along the refined study mesh varies as much either way (README,
//! "Facet to facet"): that variation is the contact's and the elements' discretisation.

use std::collections::BTreeMap;

use nalgebra::Point3;

use super::smooth::SmoothSurface;
use super::topology::tet_det;
use super::TetMesh;

/// Where the midpoint of a boundary edge goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Midpoints {
    /// On the edge (the refined surface is the coarse one).
    Flat,
    /// On the smooth surface through the boundary vertices ([`SmoothSurface`]: rounded between
    /// faces that bend by less than [`CREASE_ANGLE_DEG`](super::smooth::CREASE_ANGLE_DEG),
    /// sharp at the rims), except on edges whose two ends are
    /// both held (the inferior surface on the bone stays in its plane). A midpoint whose lift
    /// would flatten or invert one of its new tets is lifted less (halved until every new tet
    /// keeps at least a quarter of the volume it has with the flat midpoint).
    Smooth,
}

/// The mesh refined once and its held nodes: a midpoint is held when both ends of its edge
/// are. The first `mesh.nodes.len()` nodes are the old ones, in their order.
pub fn refine_once(mesh: &TetMesh, fixed: &[usize], midpoints: Midpoints) -> (TetMesh, Vec<usize>) {
    let mut nodes = mesh.nodes.clone();
    let mut is_fixed = vec![false; mesh.nodes.len()];
    for &f in fixed {
        is_fixed[f] = true;
    }
    // edge (low, high) → its midpoint node
    let mut mid: BTreeMap<(usize, usize), usize> = BTreeMap::new();
    let mut midpoint = |a: usize, b: usize, nodes: &mut Vec<Point3<f64>>| {
        *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
            nodes.push(Point3::from((nodes[a].coords + nodes[b].coords) * 0.5));
            is_fixed.push(is_fixed[a] && is_fixed[b]);
            nodes.len() - 1
        })
    };
    let mut tets = Vec::with_capacity(mesh.tets.len() * 8);
    for t in &mesh.tets {
        let [a, b, c, d] = *t;
        let ab = midpoint(a, b, &mut nodes);
        let ac = midpoint(a, c, &mut nodes);
        let ad = midpoint(a, d, &mut nodes);
        let bc = midpoint(b, c, &mut nodes);
        let bd = midpoint(b, d, &mut nodes);
        let cd = midpoint(c, d, &mut nodes);
        for mut child in [
            [a, ab, ac, ad],
            [ab, b, bc, bd],
            [ac, bc, c, cd],
            [ad, bd, cd, d],
            [ac, bd, ab, bc],
            [ac, bd, bc, cd],
            [ac, bd, cd, ad],
            [ac, bd, ad, ab],
        ] {
            if det(&nodes, &child) < 0.0 {
                child.swap(2, 3);
            }
            tets.push(child);
        }
    }
    if midpoints == Midpoints::Smooth {
        lift_boundary_midpoints(mesh, &mid, &is_fixed, &mut nodes, &tets);
    }
    let fixed = (0..nodes.len()).filter(|&i| is_fixed[i]).collect();
    (TetMesh { nodes, tets }, fixed)
}

fn det(nodes: &[Point3<f64>], t: &[usize; 4]) -> f64 {
    tet_det([&nodes[t[0]], &nodes[t[1]], &nodes[t[2]], &nodes[t[3]]])
}

/// Moves the midpoints of the coarse mesh's boundary edges onto its smooth surface, as far as
/// the new tets around each allow.
fn lift_boundary_midpoints(
    coarse: &TetMesh,
    mid: &BTreeMap<(usize, usize), usize>,
    is_fixed: &[bool],
    nodes: &mut [Point3<f64>],
    tets: &[[usize; 4]],
) {
    let surface = SmoothSurface::new(coarse);
    // the lift of each boundary midpoint, from the flat position
    let mut lift: BTreeMap<usize, nalgebra::Vector3<f64>> = BTreeMap::new();
    for f in &surface.faces {
        for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            let m = mid[&(a.min(b), a.max(b))];
            if is_fixed[m] || lift.contains_key(&m) {
                continue;
            }
            let flat = nodes[m].coords;
            if let Some(smooth) = surface.edge_midpoint(&coarse.nodes, a, b) {
                lift.insert(m, smooth - flat);
            }
        }
    }
    // new tets around each lifted midpoint, and each tet's volume with flat midpoints
    let mut around: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for (k, t) in tets.iter().enumerate() {
        for n in t {
            if lift.contains_key(n) {
                around.entry(*n).or_default().push(k);
            }
        }
    }
    let flat_det: Vec<f64> = tets.iter().map(|t| det(nodes, t)).collect();
    for (&m, &l) in &lift {
        nodes[m] += l;
    }
    // Lifts are halved where a new tet lost more than three quarters of its volume; a handful
    // of rounds settles it (one on the built-in coarse mesh, 76 midpoints halved; one on the
    // study mesh, 4), and the last falls back to flat.
    const ROUNDS: usize = 8;
    for round in 0..=ROUNDS {
        let mut shrink = Vec::new();
        for (&m, ks) in &around {
            if ks
                .iter()
                .any(|&k| det(nodes, &tets[k]) < 0.25 * flat_det[k])
            {
                shrink.push(m);
            }
        }
        if shrink.is_empty() {
            break;
        }
        for m in shrink {
            let l = lift[&m];
            let now = if round == ROUNDS { -l } else { -l * 0.5 };
            nodes[m] += now;
            lift.insert(m, l + now);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::smooth::tests::{roof, slab};

    #[test]
    fn flat_refinement_keeps_the_volume_and_holds_midpoints_of_held_edges() {
        let mesh = slab(3);
        let held: Vec<usize> = (0..16).collect(); // the bottom layer
        let (fine, fine_held) = refine_once(&mesh, &held, Midpoints::Flat);
        assert_eq!(fine.tets.len(), mesh.tets.len() * 8);
        assert!((fine.volume() - mesh.volume()).abs() < 1e-12 * mesh.volume());
        assert!(fine.tets.iter().all(|t| det(&fine.nodes, t) > 0.0));
        // the bottom of a 3 × 3 slab refined: 7 × 7 nodes, all at z = 0
        assert_eq!(fine_held.len(), 49);
        assert!(fine_held.iter().all(|&i| fine.nodes[i].z == 0.0));
    }

    #[test]
    fn smooth_refinement_rounds_a_bend_and_keeps_walls_rims_and_held_nodes() {
        let mesh = roof();
        let held: Vec<usize> = (0..25).collect(); // the bottom layer
        let (flat, _) = refine_once(&mesh, &held, Midpoints::Flat);
        let (smooth, smooth_held) = refine_once(&mesh, &held, Midpoints::Smooth);
        assert_eq!(flat.nodes.len(), smooth.nodes.len());
        assert!(smooth.tets.iter().all(|t| det(&smooth.nodes, t) > 0.0));
        let (mut raised, mut on_walls) = (0, 0);
        for i in 0..flat.nodes.len() {
            let (f, s) = (flat.nodes[i], smooth.nodes[i]);
            if i < mesh.nodes.len() || smooth_held.contains(&i) {
                assert_eq!(f, s, "node {i}: old and held nodes stay");
                continue;
            }
            // the flat walls stay in their planes, rims included
            for (axis, wall) in [(0, 0.0), (0, 4.0), (1, 0.0), (1, 4.0)] {
                if f[axis] == wall {
                    on_walls += 1;
                    assert!(
                        (s[axis] - wall).abs() < 1e-12,
                        "node {i} left its wall: {s:?}"
                    );
                }
            }
            // the roof's midpoints rise towards the bend, never sink
            if f.z > 0.5 {
                assert!(s.z >= f.z - 1e-12, "node {i} sank: {f:?} → {s:?}");
                if s.z > f.z + 1e-3 {
                    raised += 1;
                }
            }
        }
        assert!(raised > 0, "the bend must be rounded");
        assert!(on_walls > 0, "no midpoint on a wall was checked");
    }

    /// The largest lift off the facets, m, and the smallest new tet's volume over its volume
    /// with flat midpoints.
    fn lifts(mesh: &TetMesh, fixed: &[usize]) -> (f64, f64) {
        let (flat, _) = refine_once(mesh, fixed, Midpoints::Flat);
        let (smooth, _) = refine_once(mesh, fixed, Midpoints::Smooth);
        let lift = (0..flat.nodes.len())
            .map(|i| (smooth.nodes[i] - flat.nodes[i]).norm())
            .fold(0.0, f64::max);
        let kept = (0..flat.tets.len())
            .map(|k| det(&smooth.nodes, &smooth.tets[k]) / det(&flat.nodes, &flat.tets[k]))
            .fold(f64::INFINITY, f64::min);
        (lift, kept)
    }

    #[test]
    fn the_study_and_default_meshes_refine_onto_their_smooth_surfaces() {
        let mut specs = vec!["default:lateral:coarse"];
        let data = crate::mesh::tests::study_data();
        if data.is_some() {
            specs.push("study:lateral");
        }
        let dir = data.unwrap_or_default();
        for spec in specs {
            let cfg = launch_config::scene::MeniscusConfig {
                mesh: spec.into(),
                ..Default::default()
            };
            let m = crate::mesh::load_scene_mesh(&cfg, &dir).unwrap();
            let (lift, kept) = lifts(&m.mesh, &m.fixed_nodes);
            eprintln!(
                "{spec}: {} nodes, largest lift {:.3} mm, smallest new tet ×{kept:.2} of its flat volume",
                m.mesh.nodes.len(),
                lift * 1e3
            );
            // every new tet keeps at least the quarter the guard allows, and the lifts are a
            // fraction of the facets (the study's are 2–4 mm)
            assert!(kept >= 0.25, "{spec}: a new tet kept ×{kept}");
            assert!(
                lift > 1e-6 && lift < 0.8e-3,
                "{spec}: largest lift {lift} m"
            );
        }
    }
}
