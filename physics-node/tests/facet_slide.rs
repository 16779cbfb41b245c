//! A frictionless ball slid at constant depth along the study's lateral meniscus, across its
//! facets: how much the normal force varies from facet to facet (issue 15, point 1: "≤ 5%, as
//! a converged reference does").
//!
//! The reference surface is not the mesh's own facets but the smooth one through its vertices
//! (`physics_node::mesh::smooth::SmoothSurface`: Phong tessellation over angle-weighted
//! vertex normals, sharp at the rims; the surface an independent FE with a smooth surface
//! contact sees; the study mesh is too coarse for a local fit, 3–4 superior vertices within
//! 5 mm of the site). The ball's centre follows it at `R − depth` along its normal from the
//! mid-body probing site, along the body and across it, quasi-statically (direct FEM solve,
//! converged LCP; holding each position 8 steps instead of 3 changes no number by more than
//! 0.1%). A contact that is smooth across facets then gives a force that changes only slowly
//! along the path, with the surface's curvature and the body's thickness; what the facets add
//! shows as the residual about a quadratic trend over the 6 mm path. The same paths are run on
//! the study mesh and on it refined once and twice, with the new boundary nodes on the facets
//! (the study's facets kept, four or sixteen triangles each) or on the smooth surface
//! (`Midpoints::Smooth`).
//!
//! Run with `--nocapture` to see the numbers; the README quotes them.

use nalgebra::{DMatrix, DVector, Point3, UnitQuaternion, Vector3};
use parry3d_f64::math::Vector as GVec;
use parry3d_f64::query::{PointQuery, PointQueryWithLocation};
use parry3d_f64::shape::TriMesh;
use physics_node::fem::test_meshes::write_refined_once;
use physics_node::mesh::smooth::SmoothSurface;
use physics_node::mesh::{Midpoints, TetMesh};
use physics_node::sim::Simulation;
use std::path::Path;

const RADIUS_M: f64 = 1.5e-3; // the built-in ball tip
const DEPTH_M: f64 = 0.4e-3;
/// Half length of the path, m: 6 mm across the 2.2 mm facets.
const HALF_PATH_M: f64 = 3.0e-3;
const STEP_M: f64 = 0.05e-3;
/// Steps each position is held before its force is read (quasi-static: 8 give the same
/// numbers to 0.1%).
const HOLD_STEPS: usize = 3;

/// The reference surface: the smooth surface through a mesh's boundary vertices
/// ([`physics_node::mesh::smooth::SmoothSurface`], Phong tessellation over angle-weighted vertex
/// normals; the geometry crate's, apart from the contact code it measures), with its facets in
/// a parry TriMesh to walk on.
struct ReferenceSurface {
    facets: TriMesh,
    smooth: SmoothSurface,
    nodes: Vec<Point3<f64>>,
}

impl ReferenceSurface {
    fn new(mesh: &TetMesh) -> ReferenceSurface {
        let smooth = SmoothSurface::new(mesh);
        let verts: Vec<_> = mesh
            .nodes
            .iter()
            .map(|p| GVec::new(p.x, p.y, p.z))
            .collect();
        let idx: Vec<[u32; 3]> = smooth.faces.iter().map(|t| t.map(|i| i as u32)).collect();
        ReferenceSurface {
            facets: TriMesh::new(verts, idx).unwrap(),
            smooth,
            nodes: mesh.nodes.clone(),
        }
    }

    /// Distance from `x` to the mesh's own facets at rest.
    fn facet_distance(&self, x: &Vector3<f64>) -> f64 {
        let p = self
            .facets
            .project_local_point(GVec::new(x.x, x.y, x.z), false)
            .point;
        (Vector3::new(p.x, p.y, p.z) - x).norm()
    }

    /// The facets' closest point to `x`, the smooth surface's point over it and its normal.
    fn project(&self, x: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
        let (proj, (t, loc)) = self
            .facets
            .project_local_point_and_get_location(GVec::new(x.x, x.y, x.z), false);
        let w = loc.barycentric_coordinates().unwrap_or([1.0 / 3.0; 3]);
        (
            Vector3::new(proj.point.x, proj.point.y, proj.point.z),
            self.smooth.point(&self.nodes, t as usize, w),
            self.smooth.normal(&self.nodes, t as usize, w),
        )
    }
}

/// A quantity along the path: (s m, value).
type Curve = Vec<(f64, f64)>;

/// Normal force along the path (s, force N), and the ball's geometric indentation into the
/// mesh's own facets at rest along it, raised to the 3/2 of a Hertz contact (s, m^1.5): how
/// much of the force's variation the faceted geometry alone would explain. The path walks the
/// smooth surface through the mesh's vertices from the site in small steps along `dir`
/// projected onto the local tangent plane, each step carried back onto the surface; the ball's
/// centre is `R − depth` out along the surface's normal.
fn slide(
    scene: &launch_config::SceneConfig,
    data: &Path,
    mesh: &TetMesh,
    site: (Vector3<f64>, Vector3<f64>),
    depth_m: f64,
) -> (Curve, Curve) {
    let radius = scene.probe.tip_radius;
    let surface = ReferenceSurface::new(mesh);
    let mut sim = Simulation::new(scene, data).unwrap();
    let rot = UnitQuaternion::identity();
    let (origin, dir) = site;
    // Surface points (point, normal) every STEP_M / 10 from −(HALF_PATH_M + 0.5 mm) to
    // +HALF_PATH_M, walked both ways from the site.
    let fine = STEP_M / 10.0;
    let walk = |sign: f64, length: f64| {
        let mut at = surface.project(&origin);
        let mut out = vec![at];
        for _ in 0..(length / fine).round() as usize {
            // Walk on the facets (their closest point moves continuously along them), read
            // the smooth surface over each step.
            let step = dir * sign - at.2 * at.2.dot(&(dir * sign));
            at = surface.project(&(at.0 + step.normalize() * fine));
            out.push(at);
        }
        out
    };
    let back = walk(-1.0, HALF_PATH_M + 0.5e-3);
    let ahead = walk(1.0, HALF_PATH_M);
    let surface_at = |s: f64| {
        let k = (s.abs() / fine).round() as usize;
        if s < 0.0 {
            back[k]
        } else {
            ahead[k]
        }
    };
    let centre = |s: f64, depth: f64| {
        let (_, p, n) = surface_at(s);
        (Point3::from(p + n * (radius - depth)), n)
    };
    let s0 = -HALF_PATH_M - 0.5e-3;
    sim.teleport_probe(&physics_node::probe::pose(centre(s0, -0.05e-3).0, rot));
    // Press to depth before the path starts, then settle.
    for k in 0..30 {
        let d = -0.05e-3 + (depth_m + 0.05e-3) * ((k + 1) as f64 / 10.0).min(1.0);
        sim.set_probe_kinematic(&physics_node::probe::pose(centre(s0, d).0, rot));
        sim.step().unwrap();
    }
    let n_steps = ((2.0 * HALF_PATH_M + 0.5e-3) / STEP_M).round() as usize;
    let mut out = Vec::new();
    let mut indentation = Vec::new();
    for k in 1..=n_steps {
        let s = s0 + k as f64 * STEP_M;
        let (c, n) = centre(s, depth_m);
        for _ in 0..HOLD_STEPS {
            sim.set_probe_kinematic(&physics_node::probe::pose(c, rot));
            sim.step().unwrap();
            assert_eq!(
                sim.contact_frame().physics_faults,
                0,
                "faulty step at s = {s}"
            );
        }
        if s >= -HALF_PATH_M - 1e-12 {
            out.push((s, Vector3::from(sim.contact_force()).dot(&n)));
            let into_facets = (radius - surface.facet_distance(&c.coords)).max(0.0);
            indentation.push((s, into_facets.powf(1.5)));
        }
    }
    (out, indentation)
}

/// Variation of a quantity along the path: (mean, (max − min)/mean, RMS and largest |residual|
/// about a least-squares quadratic trend, both / mean).
fn variation(curve: &[(f64, f64)]) -> (f64, f64, f64, f64) {
    let n = curve.len();
    let mean = curve.iter().map(|c| c.1).sum::<f64>() / n as f64;
    let (lo, hi) = curve
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), c| {
            (l.min(c.1), h.max(c.1))
        });
    let a = DMatrix::from_fn(n, 3, |r, k| curve[r].0.powi(k as i32));
    let b = DVector::from_iterator(n, curve.iter().map(|c| c.1));
    let c = a.clone().svd(true, true).solve(&b, 1e-18).unwrap();
    let res = &a * &c - &b;
    let rms = (res.norm_squared() / n as f64).sqrt();
    (mean, (hi - lo) / mean, rms / mean, res.amax() / mean)
}

/// The middle mid-body probing site and the two path directions in its tangent plane: along
/// the body (the line of the mid-body sites), where the thickness changes slowly, and across.
fn mid_body_paths(
    loaded: &physics_node::mesh::LoadedMeniscus,
) -> (
    physics_node::geometry::ProbingSite,
    Vector3<f64>,
    Vector3<f64>,
) {
    let mid: Vec<_> = loaded
        .probing_sites
        .iter()
        .filter(|s| s.region == 2)
        .collect();
    let site = mid[mid.len() / 2];
    // Along the body (the line of the mid-body sites, in the middle site's tangent plane),
    // where the thickness changes slowly, and across it.
    let n = site.normal.normalize();
    let along = mid[mid.len() - 1].point - mid[0].point;
    let e1 = (along - n * n.dot(&along)).normalize();
    let e2 = n.cross(&e1);
    (*site, e1, e2)
}

#[test]
fn ball_slid_across_facets_at_constant_depth() {
    let Some(data) = physics_node::fem::test_meshes::study_data("facet_slide") else {
        return;
    };
    let mut scene = launch_config::SceneConfig {
        gravity: [0.0; 3],
        ..Default::default()
    };
    scene.meniscus.mesh = "study:lateral".into();
    scene.meniscus.support_stiffness = 0.0;
    scene.material.strain_stiffening = 0.0;
    scene.contact.friction = 0.0;
    scene.contact.lcp_max_iterations = 3000;
    scene.probe.model = "sphere".into();
    scene.probe.tip_radius = RADIUS_M;
    scene.solver.kind = launch_config::scene::SolverKind::Direct;
    let loaded = physics_node::mesh::load_scene_mesh(&scene.meniscus, &data).unwrap();
    let (site, e1, e2) = mid_body_paths(&loaded);

    let dir = std::env::temp_dir().join(format!("physics-node-facet-slide-{}", std::process::id()));
    // The study mesh refined once and twice, with its new boundary nodes on the facets (the
    // same facets, four triangles each, then sixteen) or on the smooth surface
    // (`Midpoints::Smooth`).
    let refined = |mesh: &TetMesh, fixed: &[usize], midpoints, name: &str| {
        let files = write_refined_once(mesh, fixed, midpoints, &dir.join(name)).unwrap();
        let mut sc = scene.clone();
        sc.meniscus.mesh = files.msh.display().to_string();
        sc.meniscus.fixed = files.fixed_list.display().to_string();
        (files.mesh, files.fixed, sc)
    };
    let (mesh, fixed) = (&loaded.mesh, &loaded.fixed_nodes);
    let (flat_once, flat_once_fixed, flat_once_scene) = refined(mesh, fixed, Midpoints::Flat, "f1");
    let (smooth_once, smooth_once_fixed, smooth_once_scene) =
        refined(mesh, fixed, Midpoints::Smooth, "s1");
    let (flat_twice, _, flat_twice_scene) =
        refined(&flat_once, &flat_once_fixed, Midpoints::Flat, "f2");
    let (smooth_twice, _, smooth_twice_scene) =
        refined(&smooth_once, &smooth_once_fixed, Midpoints::Smooth, "s2");
    println!(
        "study mesh {} nodes / {} tets, refined once {} nodes / {} tets, twice {} nodes; ball R {} mm, {} mm deep",
        loaded.mesh.nodes.len(),
        loaded.mesh.tets.len(),
        flat_once.nodes.len(),
        flat_once.tets.len(),
        flat_twice.nodes.len(),
        RADIUS_M * 1e3,
        DEPTH_M * 1e3
    );
    // The same scenes with each ball's force spread over its Hertz patch
    // (`[scene.contact] hertz_patch`).
    let patch = |sc: &launch_config::SceneConfig| {
        let mut sc = sc.clone();
        sc.contact.hertz_patch = true;
        sc
    };
    let (study_patch, flat_once_patch, smooth_once_patch, flat_twice_patch, smooth_twice_patch) = (
        patch(&scene),
        patch(&flat_once_scene),
        patch(&smooth_once_scene),
        patch(&flat_twice_scene),
        patch(&smooth_twice_scene),
    );
    // (name, mesh, scene, slid across the body too: the twice-refined meshes take ~30 s a path)
    let meshes = [
        ("study", &loaded.mesh, &scene, true),
        ("refined once, flat", &flat_once, &flat_once_scene, true),
        (
            "refined once, smooth",
            &smooth_once,
            &smooth_once_scene,
            true,
        ),
        ("refined twice, flat", &flat_twice, &flat_twice_scene, false),
        (
            "refined twice, smooth",
            &smooth_twice,
            &smooth_twice_scene,
            false,
        ),
        ("study, patch", &loaded.mesh, &study_patch, false),
        (
            "refined once, flat, patch",
            &flat_once,
            &flat_once_patch,
            false,
        ),
        (
            "refined once, smooth, patch",
            &smooth_once,
            &smooth_once_patch,
            false,
        ),
        (
            "refined twice, flat, patch",
            &flat_twice,
            &flat_twice_patch,
            false,
        ),
        (
            "refined twice, smooth, patch",
            &smooth_twice,
            &smooth_twice_patch,
            false,
        ),
    ];

    // (path, mesh) → detrended RMS / mean.
    let mut along_body = Vec::new();
    for (label, e) in [("the body", e1), ("across", e2)] {
        for (name, mesh, sc, across) in meshes {
            if label == "across" && !across {
                continue;
            }
            let t = std::time::Instant::now();
            let (curve, indentation) = slide(sc, &data, mesh, (site.point.coords, e), DEPTH_M);
            let (mean, range, rms, largest) = variation(&curve);
            let (_, _, geometric_rms, geometric_largest) = variation(&indentation);
            println!(
                "{name:>22} along {label}: mean {mean:.3} N, (max − min)/mean {:.1}%, detrended RMS {:.1}%, largest {:.1}% ({} positions, {:.1} s); the facets' geometry alone (indentation^1.5): RMS {:.1}%, largest {:.1}%",
                range * 100.0,
                rms * 100.0,
                largest * 100.0,
                curve.len(),
                t.elapsed().as_secs_f64(),
                geometric_rms * 100.0,
                geometric_largest * 100.0
            );
            let line: Vec<String> = curve.iter().map(|c| format!("{:.3}", c.1)).collect();
            println!("  F: {}", line.join(" "));
            assert!(
                curve.iter().all(|c| c.1.is_finite()),
                "{name} along {label}"
            );
            // Across the body the path reaches the study mesh's rim, a crease the smooth
            // surface keeps (`CREASE_ANGLE_DEG`), where the ball's centre, carried along the
            // surface normal, jumps and the ball lifts off: reported, not held.
            let off = curve.iter().filter(|c| c.1 <= 0.0).count();
            if label == "the body" {
                assert_eq!(
                    off, 0,
                    "the ball must stay in contact on {name} along {label}"
                );
                along_body.push((name, rms));
            } else if off > 0 {
                println!("  {off} positions out of contact");
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
    // Reached (README), detrended RMS along the body: 6.6% on the study mesh; 10.5% and 10.8%
    // refined once with its midpoints on the facets and on the smooth surface; 5.7% and 5.6%
    // refined twice (largest residuals 18.8%, 22.0%, 22.0%, 13.6%, 11.2%). Across the body
    // the force follows the thickness (1.2 → 13 N over 6 mm), which a quadratic trend does not
    // remove, so only the path along the body is held to bounds: what is reached, with
    // margin, so that a rougher contact fails here. With the force spread over the Hertz
    // patch: 6.3% on the study mesh, 7.0% and 7.1% refined once, 2.8% and 2.6% refined twice
    // (largest 13.4%, 12.8%, 13.5%, 6.9%, 7.3%); refined twice, the issue's ≤ 5% is held.
    for (name, rms) in along_body {
        let bound = match name {
            "study" => 0.10,
            "refined once, flat" | "refined once, smooth" => 0.15,
            "study, patch" => 0.09,
            "refined once, flat, patch" | "refined once, smooth, patch" => 0.10,
            "refined twice, flat, patch" | "refined twice, smooth, patch" => 0.05,
            _ => 0.075,
        };
        assert!(
            rms < bound,
            "{name}: the force slid along the body varies {:.1}% RMS about its trend",
            rms * 100.0
        );
    }
}

/// The trainee's side of the same question: the built-in hook on the default session's scene
/// (the embedded `default.toml`: the calibrated tissue on `default:lateral:44x3x2`, its soft
/// support, stiffening and contact; no study data), its tip held 1.5 mm under the smooth
/// surface (a firm press on the calibrated tissue, ~0.36 N before the device's force scale)
/// and slid along the body and across it. What varies about the trend is what a hand sliding
/// at a steady depth would feel as bumps from the facets (README, "Facet to facet").
#[test]
fn the_default_hook_slid_across_facets() {
    const HOOK_DEPTH_M: f64 = 1.5e-3;
    let scene = launch_config::load_str(
        launch_config::DEFAULT_LAUNCH,
        launch_config::DEFAULT_LAUNCH_ORIGIN,
    )
    .unwrap()
    .scene;
    assert_eq!(scene.probe.model, "default", "the built-in hook");
    let data = launch_config::data_dir();
    let loaded = physics_node::mesh::load_scene_mesh(&scene.meniscus, &data).unwrap();
    let (site, e1, e2) = mid_body_paths(&loaded);
    // Reached (README): 0.8% RMS about the trend along the body (largest 2.0%), 4.4% across
    // it (largest 9.1%, where the path's slope turns): the calibrated tissue's soft support
    // takes most of the press, so the facets' local compliance barely shows. Held to what is
    // reached, with margin.
    for (label, e, bound) in [("the body", e1, 0.03), ("across", e2, 0.08)] {
        let (curve, _) = slide(
            &scene,
            &data,
            &loaded.mesh,
            (site.point.coords, e),
            HOOK_DEPTH_M,
        );
        let (mean, range, rms, largest) = variation(&curve);
        println!(
            "default hook ({}, {} nodes) along {label}: mean {mean:.3} N, (max − min)/mean {:.1}%, detrended RMS {:.1}%, largest {:.1}%",
            scene.meniscus.mesh,
            loaded.mesh.nodes.len(),
            range * 100.0,
            rms * 100.0,
            largest * 100.0
        );
        let line: Vec<String> = curve.iter().map(|c| format!("{:.3}", c.1)).collect();
        println!("  F: {}", line.join(" "));
        assert!(
            curve.iter().all(|c| c.1 > 0.0 && c.1.is_finite()),
            "the hook must stay in contact along {label}"
        );
        assert!(
            rms < bound,
            "the hook slid along {label} varies {:.1}% RMS about its trend",
            rms * 100.0
        );
    }
}
