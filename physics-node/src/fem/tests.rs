//! Closed-form and consistency tests of the FEM model.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};

use super::test_meshes::{box_mesh, nodes_where};
use super::*;
use crate::mesh::TetMesh;

fn settings(solver: LinearSolver) -> FemSettings {
    FemSettings {
        solver,
        cg_matrix: cg_matrix_for(&solver),
        ..FemSettings::default()
    }
}

/// The tight CG of these tests ([`tight_cg`], 1e-13) compares against the direct solver to
/// ~1e-6 and needs the f64 matrix; SOFA's truncated CG (1e-9, 25 iterations) keeps f32.
fn cg_matrix_for(solver: &LinearSolver) -> CgMatrix {
    match solver {
        LinearSolver::Cg { tolerance, .. } if *tolerance < 1e-10 => CgMatrix::F64,
        _ => CgMatrix::F32,
    }
}

fn tight_cg(pc: Preconditioner) -> LinearSolver {
    LinearSolver::Cg {
        max_iterations: 2000,
        tolerance: 1e-13,
        preconditioner: pc,
    }
}

fn cube_model(solver: LinearSolver) -> FemModel {
    let mesh = box_mesh(0.01, 0.01, 0.01, 3, 3, 3);
    let fixed = nodes_where(&mesh, |p| p.z < 1e-9);
    FemModel::new(&mesh, Material::lateral(), &fixed, settings(solver)).unwrap()
}

fn zero_forces(m: &FemModel) -> Vec<Vector3<f64>> {
    vec![Vector3::zeros(); m.node_count()]
}

/// Deterministic pseudo-random numbers in [-1, 1] (no rand dependency).
fn lcg(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    ((*seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

fn signed_volume(p: &[Point3<f64>], t: &[usize; 4]) -> f64 {
    (p[t[1]] - p[t[0]])
        .cross(&(p[t[2]] - p[t[0]]))
        .dot(&(p[t[3]] - p[t[0]]))
        / 6.0
}

#[test]
fn rejects_bad_meshes_and_inputs() {
    let mut mesh = box_mesh(1.0, 1.0, 1.0, 1, 1, 1);
    let m = Material::lateral();
    let s = FemSettings::default();
    let mut bad = mesh.clone();
    bad.tets[2].swap(0, 1);
    let e = FemModel::new(&bad, m, &[], s).unwrap_err().to_string();
    assert!(e.contains("tet 2"), "{e}");
    let mut bad = mesh.clone();
    bad.tets[0][3] = 99;
    let e = FemModel::new(&bad, m, &[], s).unwrap_err().to_string();
    assert!(e.contains("node 99"), "{e}");
    mesh.nodes[0].x = f64::NAN;
    assert!(FemModel::new(&mesh, m, &[], s).is_err());
    let mesh = box_mesh(1.0, 1.0, 1.0, 1, 1, 1);
    assert!(FemModel::new(&mesh, m, &[100], s).is_err());
    let mut model = FemModel::new(&mesh, m, &[], s).unwrap();
    assert!(model.free_motion(0.01, &[Vector3::zeros(); 3]).is_err());
    assert!(model.free_motion(0.0, &zero_forces(&model)).is_err());
}

#[test]
fn settles_under_gravity_with_every_solver() {
    let mut tops = Vec::new();
    for solver in [
        LinearSolver::sofa_cg(),
        tight_cg(Preconditioner::BlockJacobi),
        tight_cg(Preconditioner::RestCholesky),
        tight_cg(Preconditioner::WarpedRestCholesky),
        tight_cg(Preconditioner::LaggedFactor),
        LinearSolver::Direct,
    ] {
        let mut m = cube_model(solver);
        let f = zero_forces(&m);
        for _ in 0..50 {
            m.step(0.01, &f).unwrap();
        }
        let top = m.positions().iter().map(|p| p.z).fold(f64::MIN, f64::max);
        assert!(top < 0.01 && top > 0.0099, "top {top}");
        tops.push(top);
    }
    // Static sag of a 1 cm cube of E = 3.5 MPa under its own weight: ρ g L² / (2E) ≈ 1.5e-7 m.
    let sag = 0.01 - tops[4];
    assert!(sag > 0.5e-7 && sag < 5e-7, "sag {sag}");
}

#[test]
fn cg_and_direct_agree() {
    let mut cg = cube_model(tight_cg(Preconditioner::None));
    let mut pcg = cube_model(tight_cg(Preconditioner::RestCholesky));
    // the offline solver: its factor is f32 (it only preconditions), the CG runs in f64
    let mut lagged = cube_model(tight_cg(Preconditioner::LaggedFactor));
    let mut direct = cube_model(LinearSolver::Direct);
    let mut f = zero_forces(&direct);
    // A sideways pull on a top corner: large enough to rotate elements.
    let corner = direct
        .positions()
        .iter()
        .position(|p| (p - Point3::new(0.01, 0.01, 0.01)).norm() < 1e-9)
        .unwrap();
    f[corner] = Vector3::new(2.0, -1.0, 0.5);
    for _ in 0..20 {
        cg.step(0.01, &f).unwrap();
        pcg.step(0.01, &f).unwrap();
        lagged.step(0.01, &f).unwrap();
        direct.step(0.01, &f).unwrap();
    }
    let disp = (direct.positions()[corner] - direct.rest_positions()[corner]).norm();
    assert!(disp > 1e-4, "corner moved {disp}");
    for i in 0..direct.node_count() {
        assert!((cg.positions()[i] - direct.positions()[i]).norm() < 1e-9 * 1e3 * disp);
        assert!((pcg.positions()[i] - direct.positions()[i]).norm() < 1e-9 * 1e3 * disp);
        assert!((lagged.positions()[i] - direct.positions()[i]).norm() < 1e-9 * 1e3 * disp);
    }
    // An f32 factor of a system that changed little still converges in a few iterations.
    assert!(
        lagged.last_solve().iterations <= 4,
        "{:?}",
        lagged.last_solve()
    );
    // The rest-Cholesky preconditioner needs few iterations.
    assert!(pcg.last_solve().iterations <= 15, "{:?}", pcg.last_solve());
}

#[test]
fn rigid_rotation_produces_no_elastic_force() {
    let mesh = box_mesh(0.02, 0.01, 0.005, 4, 2, 2);
    for (model_kind, rotation) in [
        (MaterialModel::Corotational, RotationMethod::Qr),
        (MaterialModel::Corotational, RotationMethod::Polar),
        (MaterialModel::StableNeoHookean, RotationMethod::Qr),
    ] {
        let s = FemSettings {
            gravity: Vector3::zeros(),
            rotation,
            ..settings(LinearSolver::Direct)
        };
        let mut m =
            FemModel::new(&mesh, Material::lateral().with_model(model_kind), &[], s).unwrap();
        let rot = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(1.0, 2.0, -0.5)),
            2.3,
        );
        let shift = Vector3::new(0.3, -0.1, 0.05);
        let rotated: Vec<Point3<f64>> = mesh.nodes.iter().map(|p| rot * p + shift).collect();
        for (i, p) in rotated.iter().enumerate() {
            m.set_position(i, *p).unwrap();
        }
        let mut f = zero_forces(&m);
        m.elastic_forces(&mut f).unwrap();
        let fmax = f.iter().map(|v| v.norm()).fold(0.0, f64::max);
        // Reference: the force scale of a 1% strain on this mesh, E·A·ε/n ≈ 3.5e6·5e-5·0.01.
        assert!(
            fmax < 1e-9,
            "{model_kind:?}/{rotation:?}: elastic force {fmax} N after a rigid rotation"
        );
        assert!(m.elastic_energy() < 1e-15);
        // Stepping keeps it still.
        for _ in 0..5 {
            m.step(0.01, &zero_forces(&m)).unwrap();
        }
        for (p, q) in m.positions().iter().zip(&rotated) {
            assert!((p - q).norm() < 1e-12);
        }
        // A linear (non-corotated) element would not: check the test can fail by comparing
        // to the small-strain energy of the same displacement field.
        let lin_strain: f64 = {
            let g = rot.matrix() - Matrix3::identity();
            let eps = (g + g.transpose()) * 0.5;
            eps.norm()
        };
        assert!(lin_strain > 0.5);
    }
}

/// Builds an irregular patch: a 3×3×3 box with interior nodes moved randomly.
fn irregular_patch() -> (TetMesh, Vec<usize>) {
    let mut mesh = box_mesh(1.0, 1.0, 1.0, 3, 3, 3);
    let boundary = nodes_where(&mesh, |p| {
        p.iter().any(|c| c.abs() < 1e-9 || (c - 1.0).abs() < 1e-9)
    });
    let mut seed = 7;
    for i in 0..mesh.nodes.len() {
        if !boundary.contains(&i) {
            for c in 0..3 {
                mesh.nodes[i][c] += 0.08 * lcg(&mut seed);
            }
        }
    }
    for t in &mesh.tets {
        assert!(signed_volume(&mesh.nodes, t) > 0.0);
    }
    (mesh, boundary)
}

#[test]
fn patch_test_reproduces_linear_field() {
    let (mesh, boundary) = irregular_patch();
    let interior = mesh.nodes.len() - boundary.len();
    assert!(interior == 8);
    let g = Matrix3::new(
        0.010, 0.004, -0.002, 0.001, -0.006, 0.003, 0.002, 0.005, 0.008,
    );
    let c = Vector3::new(0.1, -0.2, 0.3);
    let field = |p: &Point3<f64>| p + g * p.coords + c;
    for model_kind in [MaterialModel::Corotational, MaterialModel::StableNeoHookean] {
        let s = FemSettings {
            gravity: Vector3::zeros(),
            ..settings(LinearSolver::Direct)
        };
        let mut m = FemModel::new(
            &mesh,
            Material::lateral().with_model(model_kind),
            &boundary,
            s,
        )
        .unwrap();
        for &b in &boundary {
            m.set_position(b, field(&mesh.nodes[b])).unwrap();
        }
        let it = m.solve_static(&zero_forces(&m), false, 30, 1e-12).unwrap();
        assert!(it >= 1);
        for i in 0..mesh.nodes.len() {
            let err = (m.positions()[i] - field(&mesh.nodes[i])).norm();
            assert!(
                err < 1e-10,
                "{model_kind:?}: node {i} off the linear field by {err}"
            );
        }
        // Constant stress: every element has the same deformation gradient I + G.
        let mut f = zero_forces(&m);
        m.elastic_forces(&mut f).unwrap();
        for (i, fi) in f.iter().enumerate() {
            if !boundary.contains(&i) {
                assert!(
                    fi.norm() < 1e-6,
                    "interior node {i} unbalanced by {}",
                    fi.norm()
                );
            }
        }
    }
}

/// Cantilever of [`super::test_meshes::cantilever_deflection`] with this file's solver
/// settings (the ν = 0.3 mesh-convergence table is `examples/cantilever_table.rs`).
fn cantilever_deflection_nu(nx: usize, nyz: usize, solver: LinearSolver, nu: f64) -> (f64, f64) {
    super::test_meshes::cantilever_deflection(nx, nyz, settings(solver), nu).unwrap()
}

#[test]
fn cantilever_matches_euler_bernoulli() {
    // ν = 0: Euler–Bernoulli has no Poisson term; shear adds ~0.6% at L/h = 10.
    // Convergence (δ/δ_EB): 40×4×4 0.829, 80×8×8 0.954, 100×10×10 0.972.
    let (coarse, eb) = cantilever_deflection_nu(20, 2, LinearSolver::Direct, 0.0);
    let (fine, _) = cantilever_deflection_nu(100, 10, LinearSolver::Direct, 0.0);
    let err = (fine - eb).abs() / eb;
    assert!(
        err < 0.05,
        "fine mesh δ = {fine:.6e} m vs Euler–Bernoulli {eb:.6e} m ({:.1}%)",
        err * 100.0
    );
    // Linear tets are too stiff on coarse meshes and converge from below.
    assert!(coarse < fine, "coarse {coarse} fine {fine}");
}

#[test]
fn energy_does_not_grow_in_free_vibration() {
    let mesh = box_mesh(0.04, 0.01, 0.01, 8, 2, 2);
    let fixed = nodes_where(&mesh, |p| p.x < 1e-9);
    let s = FemSettings {
        gravity: Vector3::zeros(),
        ..settings(LinearSolver::Direct)
    };
    for model_kind in [MaterialModel::Corotational, MaterialModel::StableNeoHookean] {
        let mut m =
            FemModel::new(&mesh, Material::lateral().with_model(model_kind), &fixed, s).unwrap();
        // Pre-bend with a tip load, then release.
        let mut f = zero_forces(&m);
        for i in nodes_where(&mesh, |p| (p.x - 0.04).abs() < 1e-9) {
            f[i] = Vector3::new(0.0, 0.01, -0.05);
        }
        m.solve_static(&f, false, 30, 1e-10).unwrap();
        let e0 = m.elastic_energy() + m.kinetic_energy();
        assert!(e0 > 1e-5, "pre-bend energy {e0}");
        let zero = zero_forces(&m);
        let mut prev = e0;
        let mut moved = false;
        for step in 0..200 {
            m.step(0.001, &zero).unwrap();
            let e = m.elastic_energy() + m.kinetic_energy();
            assert!(
                e <= prev * (1.0 + 1e-6) + 1e-15,
                "{model_kind:?} step {step}: energy grew {prev} → {e}"
            );
            moved |= m.kinetic_energy() > 0.1 * e0;
            prev = e;
        }
        assert!(moved, "the beam never vibrated");
        assert!(prev < e0);
    }
}

#[test]
fn inverted_element_recovers() {
    for (model_kind, rotation) in [
        (MaterialModel::Corotational, RotationMethod::Qr),
        (MaterialModel::Corotational, RotationMethod::Polar),
        (MaterialModel::StableNeoHookean, RotationMethod::Qr),
    ] {
        let mesh = box_mesh(0.01, 0.01, 0.01, 2, 2, 2);
        let fixed = nodes_where(&mesh, |p| p.z < 1e-9);
        let s = FemSettings {
            gravity: Vector3::zeros(),
            rayleigh_mass: 5.0,
            rotation,
            ..settings(LinearSolver::Direct)
        };
        let mut m =
            FemModel::new(&mesh, Material::lateral().with_model(model_kind), &fixed, s).unwrap();
        // Push the centre node down through the bottom layer: its lower tets invert.
        let centre = nodes_where(&mesh, |p| {
            (p - Point3::new(0.005, 0.005, 0.005)).norm() < 1e-9
        })[0];
        m.set_position(centre, Point3::new(0.005, 0.005, -0.002))
            .unwrap();
        let inverted = mesh
            .tets
            .iter()
            .filter(|t| signed_volume(m.positions(), t) < 0.0)
            .count();
        assert!(inverted > 0);
        let zero = zero_forces(&m);
        for _ in 0..300 {
            m.step(0.01, &zero).unwrap();
        }
        let inverted = mesh
            .tets
            .iter()
            .filter(|t| signed_volume(m.positions(), t) <= 0.0)
            .count();
        assert_eq!(inverted, 0, "{model_kind:?}/{rotation:?}");
        let err = (m.positions()[centre] - mesh.nodes[centre]).norm();
        assert!(
            err < 1e-4,
            "{model_kind:?}/{rotation:?}: centre node {err} m from rest"
        );
    }
}

#[test]
fn neo_hookean_matches_linear_at_small_strain_and_stiffens_in_compression() {
    let mesh = box_mesh(0.01, 0.01, 0.01, 2, 2, 2);
    let s = FemSettings {
        gravity: Vector3::zeros(),
        ..settings(LinearSolver::Direct)
    };
    let corot = Material::lateral();
    let nh = corot.with_model(MaterialModel::StableNeoHookean);
    let mut a = FemModel::new(&mesh, corot, &[], s).unwrap();
    let mut b = FemModel::new(&mesh, nh, &[], s).unwrap();
    let mut seed = 3;
    for i in 0..mesh.nodes.len() {
        let d = Vector3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)) * 1e-7;
        a.set_position(i, mesh.nodes[i] + d).unwrap();
        b.set_position(i, mesh.nodes[i] + d).unwrap();
    }
    let (mut fa, mut fb) = (zero_forces(&a), zero_forces(&b));
    a.elastic_forces(&mut fa).unwrap();
    b.elastic_forces(&mut fb).unwrap();
    let scale = fa.iter().map(|v| v.norm()).fold(0.0, f64::max);
    let diff = fa
        .iter()
        .zip(&fb)
        .map(|(x, y)| (x - y).norm())
        .fold(0.0, f64::max);
    assert!(
        scale > 0.0 && diff < 1e-3 * scale,
        "diff {diff} scale {scale}"
    );

    // Uniaxial stress (laterally free), homogeneous F = diag(a, a, 1 − strain) with a chosen
    // so that the lateral faces carry no load; compare the axial reaction on the top face.
    let axial_force = |m: &mut FemModel, strain: f64| {
        let set = |m: &mut FemModel, a: f64| {
            for i in 0..mesh.nodes.len() {
                let p = mesh.nodes[i];
                m.set_position(i, Point3::new(p.x * a, p.y * a, p.z * (1.0 - strain)))
                    .unwrap();
            }
            let mut f = zero_forces(m);
            m.elastic_forces(&mut f).unwrap();
            let lateral: f64 = nodes_where(&mesh, |p| (p.x - 0.01).abs() < 1e-9)
                .iter()
                .map(|&i| f[i].x)
                .sum();
            let axial: f64 = nodes_where(&mesh, |p| (p.z - 0.01).abs() < 1e-9)
                .iter()
                .map(|&i| f[i].z)
                .sum();
            (lateral, axial)
        };
        // Lateral face force: positive (pulls in) when a is too large.
        let (mut lo, mut hi) = (1.0, 2.0);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if set(m, mid).0 < 0.0 {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        set(m, 0.5 * (lo + hi)).1
    };
    let area = 1e-4;
    let e = corot.youngs_modulus;
    let small_a = axial_force(&mut a, 0.001);
    let small_b = axial_force(&mut b, 0.001);
    // Linear: σ = E ε.
    assert!(
        (small_a - e * 0.001 * area).abs() < 1e-6 * small_a,
        "{small_a}"
    );
    assert!(
        (small_a - small_b).abs() < 0.01 * small_a,
        "{small_a} {small_b}"
    );
    let big_a = axial_force(&mut a, 0.4);
    let big_b = axial_force(&mut b, 0.4);
    assert!((big_a - e * 0.4 * area).abs() < 1e-6 * big_a, "{big_a}");
    // Neo-Hookean: 1.36× the linear nominal stress at 40% (closed form of this energy).
    assert!(
        big_b > 1.3 * big_a && big_b < 1.42 * big_a,
        "corotational {big_a} N, neo-Hookean {big_b} N"
    );
}

#[test]
fn an_f32_factor_solves_to_single_precision_and_a_f64_one_to_double() {
    let mut m = cube_model(LinearSolver::sofa_cg());
    m.assemble_rest_system(0.01);
    let mut seed = 5;
    let nf = m.free_nodes().len();
    let b: Vec<f64> = (0..3 * nf).map(|_| lcg(&mut seed)).collect();
    let residual = |precision| {
        let mut chol = SparseCholesky::with_precision(&m.pattern, &m.a, 1, precision).unwrap();
        assert_eq!(chol.precision(), precision);
        let mut x = b.clone();
        chol.solve_in_place(&mut x);
        let mut ax = vec![0.0; 3 * nf];
        m.pattern().mul(&m.a, &x, &mut ax);
        let r: f64 = ax.iter().zip(&b).map(|(y, b)| (y - b).powi(2)).sum();
        let b2: f64 = b.iter().map(|b| b * b).sum();
        (r / b2).sqrt()
    };
    let (single, double) = (
        residual(FactorPrecision::F32),
        residual(FactorPrecision::F64),
    );
    assert!(double < 1e-12, "f64 factor: relative residual {double:e}");
    // f32 rounding, not a wrong factor: well under 1, well above f64's
    assert!(
        single > 1e-9 && single < 1e-3,
        "f32 factor: relative residual {single:e}"
    );
}

#[test]
fn rest_compliance_solves_rest_system() {
    let mut m = cube_model(LinearSolver::sofa_cg());
    let dt = 0.01;
    let mut comp = m.rest_compliance(dt, 4).unwrap();
    let n = m.node_count();
    let mut seed = 11;
    let ncols = 6;
    let b: Vec<f64> = (0..3 * n * ncols).map(|_| lcg(&mut seed)).collect();
    let mut x = b.clone();
    comp.solve_block_in_place(&mut x, ncols);
    // Check A0 x = b on free dofs with the model's own rest system.
    let a0 = {
        let mut m2 = cube_model(LinearSolver::sofa_cg());
        m2.assemble_rest_system(dt);
        m2.a.clone()
    };
    let nf = m.free_nodes().len();
    for c in 0..ncols {
        let mut xr = vec![0.0; 3 * nf];
        let mut yr = vec![0.0; 3 * nf];
        for (row, &node) in m.free_nodes().iter().enumerate() {
            for k in 0..3 {
                xr[3 * row + k] = x[c * 3 * n + 3 * node + k];
            }
        }
        m.pattern().mul(&a0, &xr, &mut yr);
        for (row, &node) in m.free_nodes().iter().enumerate() {
            for k in 0..3 {
                let want = b[c * 3 * n + 3 * node + k];
                assert!((yr[3 * row + k] - want).abs() < 1e-8 * (1.0 + want.abs()));
            }
        }
        for node in 0..n {
            if m.is_held(node) {
                for k in 0..3 {
                    assert_eq!(x[c * 3 * n + 3 * node + k], 0.0);
                }
            }
        }
    }
    // Single-column solve equals the block solve.
    let mut single = b[..3 * n].to_vec();
    comp.solve_in_place(&mut single);
    for (s, x) in single.iter().zip(&x[..3 * n]) {
        assert!((s - x).abs() < 1e-12 * (1.0 + x.abs()));
    }
}

#[test]
fn node_rotations_follow_a_rigid_rotation_and_correction_moves_nodes() {
    let mesh = box_mesh(0.02, 0.01, 0.01, 2, 1, 1);
    let s = FemSettings {
        gravity: Vector3::zeros(),
        ..settings(LinearSolver::Direct)
    };
    let mut m = FemModel::new(&mesh, Material::lateral(), &[], s).unwrap();
    let rot = Rotation3::from_axis_angle(&Vector3::z_axis(), 1.0);
    for (i, p) in mesh.nodes.iter().enumerate() {
        m.set_position(i, rot * p).unwrap();
    }
    // The step's rotation extraction is warm-started with a few iterations per call, so a
    // sudden 1 rad turn takes a few steps to be tracked exactly.
    for _ in 0..10 {
        m.free_motion(0.01, &zero_forces(&m)).unwrap();
        m.update_node_rotations();
    }
    // Step tolerance of the extraction is 1e-7 rad.
    for r in m.node_rotations() {
        let err = (r - rot.matrix()).norm();
        assert!(err < 1e-6, "node rotation off by {err}");
    }
    let before = m.free_positions()[3];
    m.apply_correction(&[(3, Vector3::new(0.0, 0.0, 1e-3))])
        .unwrap();
    assert!((m.free_positions()[3] - before - Vector3::new(0.0, 0.0, 1e-3)).norm() < 1e-15);
    assert!((m.free_velocities()[3].z - 0.1).abs() < 1e-12);
    m.commit();
    assert!((m.positions()[3] - before).z > 0.0);
}

/// A 10 × 10 × 5 mm block whose bottom nodes hang on springs of `stiffness` N/m each.
fn supported_block(stiffness: f64) -> (TetMesh, Vec<usize>, FemModel) {
    let mesh = box_mesh(0.01, 0.01, 0.005, 2, 2, 1);
    let support = nodes_where(&mesh, |p| p.z < 1e-9);
    let s = FemSettings {
        support_stiffness: stiffness,
        ..settings(LinearSolver::Direct)
    };
    let m = FemModel::new(&mesh, Material::lateral(), &support, s).unwrap();
    (mesh, support, m)
}

#[test]
fn support_springs_carry_the_weight() {
    let (mesh, support, mut m) = supported_block(500.0);
    assert!(m.free_nodes().len() == mesh.nodes.len());
    m.solve_static(&zero_forces(&m), true, 30, 1e-10).unwrap();
    let weight: f64 = m.masses().iter().sum::<f64>() * 9.81;
    let spring: f64 = support
        .iter()
        .map(|&i| -500.0 * (m.positions()[i].z - mesh.nodes[i].z))
        .sum();
    assert!(
        (spring - weight).abs() < 1e-6 * weight,
        "springs {spring} N, weight {weight} N"
    );
}

/// The support stiffens by the tissue's law, its displacement over the body's thickness
/// read as a strain (the calibrated default tissue rests on it).
#[test]
fn stiffening_support_follows_the_law_of_its_displacement() {
    let (mesh, support, mut m) = supported_block(500.0);
    m.set_support_length(0.005);
    m.set_stiffening(StrainStiffening::new(2.0).unwrap());
    let i = support[0];
    m.set_position(i, mesh.nodes[i] + Vector3::new(0.0, 0.0, -1e-3))
        .unwrap();
    m.free_motion(0.01, &zero_forces(&m)).unwrap();
    let (u, f) = m.support_hardening();
    assert!((u - 1e-3).abs() < 1e-12, "largest support displacement {u}");
    assert!(
        (f - (2.0f64 * 1e-3 / 0.005).exp()).abs() < 1e-12,
        "factor {f}"
    );
    // The linear law leaves the support at its rest stiffness.
    m.set_stiffening(StrainStiffening::NONE);
    m.free_motion(0.01, &zero_forces(&m)).unwrap();
    assert_eq!(m.support_hardening().1, 1.0);
    // A softer support (a degeneration grade) is a new rest stiffness.
    m.set_support_stiffness(500.0 * 0.59).unwrap();
    assert!(m.set_support_stiffness(f64::NAN).is_err());
}

#[test]
fn material_change_rescales_response() {
    let mut m = cube_model(LinearSolver::Direct);
    let f = zero_forces(&m);
    m.solve_static(&f, true, 20, 1e-10).unwrap();
    let sag0 = 0.01 - m.positions().iter().map(|p| p.z).fold(f64::MIN, f64::max);
    m.reset();
    m.set_material(Material::lateral().degenerated(2.0).unwrap())
        .unwrap();
    m.solve_static(&f, true, 20, 1e-10).unwrap();
    let sag2 = 0.01 - m.positions().iter().map(|p| p.z).fold(f64::MIN, f64::max);
    assert!((sag2 / sag0 - 1.0 / 0.59).abs() < 1e-3, "{sag0} {sag2}");
}

/// The packed f32 system (written by the fused corotational pass) and its SIMD and portable
/// products against the f64 assembly and product: same matrix to f32 precision.
#[test]
fn packed_f32_system_matches_f64_assembly_and_product() {
    let mesh = box_mesh(0.01, 0.006, 0.004, 5, 3, 2);
    let fixed = nodes_where(&mesh, |p| p.x < 1e-9);
    let mut models: Vec<FemModel> = [CgMatrix::F32, CgMatrix::F64]
        .into_iter()
        .map(|cg_matrix| {
            let s = FemSettings {
                cg_matrix,
                ..FemSettings::default()
            };
            FemModel::new(&mesh, Material::lateral(), &fixed, s).unwrap()
        })
        .collect();
    // A rotated and stretched state, so element rotations are far from identity.
    let rot = Rotation3::from_euler_angles(0.4, -0.3, 0.7);
    let mut seed = 7u64;
    let deformed: Vec<Point3<f64>> = mesh
        .nodes
        .iter()
        .map(|p| {
            let jitter = Vector3::new(lcg(&mut seed), lcg(&mut seed), lcg(&mut seed)) * 2e-4;
            Point3::from(rot * (p.coords * 1.05) + jitter)
        })
        .collect();
    for m in models.iter_mut() {
        for (i, p) in deformed.iter().enumerate() {
            if !m.is_held(i) {
                m.set_position(i, *p).unwrap();
            }
        }
        m.assemble(false, 1e-4, true, false);
    }
    let (f32_model, f64_model) = (&models[0], &models[1]);
    // The fused pass computes rotations and forces four elements at a time: the same
    // forces as the element-by-element assembly.
    assert!(f32_model.tet_count() >= 8);
    let f_scale = f64_model.force.iter().map(|f| f.norm()).fold(0.0, f64::max);
    assert!(f_scale > 0.0);
    for (a, b) in f32_model.force.iter().zip(&f64_model.force) {
        assert!((a - b).norm() <= 1e-12 * f_scale, "force {a} vs {b}");
    }
    for (a, b) in f32_model.elem_rot_m.iter().zip(&f64_model.elem_rot_m) {
        assert!((a - b).amax() <= 1e-12, "rotation {a} vs {b}");
    }
    let mut reference = f64_model.upper32.clone();
    reference.pack(&f64_model.pattern, &f64_model.a);
    let scale = f64_model.a.iter().map(|b| b.amax()).fold(0.0, f64::max);
    for row in 0..f64_model.free_nodes.len() {
        let d = (f32_model.upper32.diagonal_block(row, false)
            - reference.diagonal_block(row, false))
        .amax();
        assert!(
            d <= 1e-6 * scale,
            "diagonal block {row} differs by {d} (scale {scale})"
        );
    }
    let n = 3 * f64_model.free_nodes.len();
    let x: Vec<f64> = (0..n).map(|_| lcg(&mut seed)).collect();
    let mut y_ref = vec![0.0; n];
    let dot_ref = f64_model
        .pattern
        .mul_dot_upper(&f64_model.a, &x, &mut y_ref);
    let y_norm = y_ref.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut packed = f32_model.upper32.clone();
    let mut y_simd = vec![0.0; n];
    let dot_simd = packed.mul_dot(&x, &mut y_simd, false);
    let mut y_portable = vec![0.0; n];
    let dot_portable = packed.mul_dot_portable(&x, &mut y_portable, false);
    // The diagonal shift (mass and support of a step) adds d_i x_i.
    let shift = |row: usize| 0.3 * scale * (1 + row % 3) as f64;
    for row in 0..n / 3 {
        packed.set_shift(row, shift(row));
    }
    let mut y_shifted = vec![0.0; n];
    let dot_shifted = packed.mul_dot(&x, &mut y_shifted, true);
    let mut y_shifted_portable = vec![0.0; n];
    let dot_shifted_portable = packed.mul_dot_portable(&x, &mut y_shifted_portable, true);
    for (i, (ys, ysp)) in y_shifted
        .iter_mut()
        .zip(&mut y_shifted_portable)
        .enumerate()
    {
        *ys -= shift(i / 3) * x[i];
        *ysp -= shift(i / 3) * x[i];
    }
    let x_shift_x: f64 = (0..n).map(|i| shift(i / 3) * x[i] * x[i]).sum();
    for (y, dot, path) in [
        (&y_simd, dot_simd, "simd"),
        (&y_portable, dot_portable, "portable"),
        (&y_shifted, dot_shifted - x_shift_x, "simd shifted"),
        (
            &y_shifted_portable,
            dot_shifted_portable - x_shift_x,
            "portable shifted",
        ),
    ] {
        let err = y
            .iter()
            .zip(&y_ref)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
        assert!(
            err <= 1e-6 * y_norm,
            "{path}: |y - y_ref| = {err}, |y_ref| = {y_norm}"
        );
        assert!(
            (dot - dot_ref).abs() <= 1e-6 * dot_ref.abs(),
            "{path}: x·y {dot} vs {dot_ref}"
        );
    }
}

/// Stiffness blocks re-rotated in place only past a tolerance: with a vanishing tolerance
/// the in-place updates reproduce the every-step assembly (to f32 round-off); with 1e-3 rad
/// only the elements that turned are updated and the motion stays close; a material change
/// rebuilds the blocks.
#[test]
fn lazy_stiffness_rotation_follows_every_step_assembly() {
    let mesh = box_mesh(0.02, 0.004, 0.004, 10, 2, 2);
    let fixed = nodes_where(&mesh, |p| p.x < 1e-9);
    let model = |tolerance: f64| {
        // A converged CG: SOFA's 25 iterations leave this beam's residual near 1, and
        // that truncation amplifies any perturbation (even f32 vs f64) to ~1e-2.
        let s = FemSettings {
            stiffness_rotation_tolerance: tolerance,
            rayleigh_mass: 30.0,
            solver: LinearSolver::Cg {
                max_iterations: 1000,
                tolerance: 1e-10,
                preconditioner: Preconditioner::None,
            },
            ..FemSettings::default()
        };
        FemModel::new(&mesh, Material::lateral(), &fixed, s).unwrap()
    };
    let (mut every, mut updated, mut lazy) = (model(0.0), model(1e-12), model(1e-3));
    let tip: Vec<usize> = nodes_where(&mesh, |p| p.x > 0.02 - 1e-9);
    let mut f = zero_forces(&every);
    let mut updates = Vec::new();
    // Largest position difference to the every-step assembly over the whole run.
    let (mut worst_updated, mut worst_lazy) = (0.0f64, 0.0f64);
    for step in 0..160 {
        // Bend the free end sideways (large rotations near the tip), hold, let it settle.
        let load = 0.05 * (step as f64 / 60.0).min(1.0);
        for &i in &tip {
            f[i] = Vector3::new(0.0, load, 0.3 * load);
        }
        every.step(0.01, &f).unwrap();
        updated.step(0.01, &f).unwrap();
        lazy.step(0.01, &f).unwrap();
        assert_eq!(every.stiffness_updates(), every.tet_count());
        updates.push(lazy.stiffness_updates());
        for (m, worst) in [(&updated, &mut worst_updated), (&lazy, &mut worst_lazy)] {
            for (a, b) in every.positions().iter().zip(m.positions()) {
                *worst = worst.max((a - b).norm());
            }
        }
    }
    let tets = lazy.tet_count();
    assert_eq!(updates[0], tets, "the first step builds every element");
    assert!(
        updates[1..].iter().any(|&u| u < tets / 2),
        "few elements turn by more than 1e-3 per step: {updates:?}"
    );
    assert!(
        updates[1..].iter().any(|&u| u > 0),
        "the bending beam re-rotates some"
    );
    let span = every
        .positions()
        .iter()
        .zip(every.rest_positions())
        .map(|(p, r)| (p - r).norm())
        .fold(0.0, f64::max);
    assert!(span > 1e-3, "the tip moved {span} m");
    // In-place updates of every element: the same matrix up to f32 round-off (2e-5 of the
    // motion when measured: the beam's conditioning amplifies 1e-7).
    assert!(
        worst_updated < 1e-4 * span,
        "{worst_updated} vs span {span}"
    );
    // The lagged Jacobian perturbs each implicit step by about the tolerance (2e-5 of the
    // motion when measured).
    assert!(worst_lazy < 1e-3 * span, "{worst_lazy} vs span {span}");
    // A new modulus must not keep the old blocks.
    lazy.set_material(Material::lateral().degenerated(2.0).unwrap())
        .unwrap();
    lazy.step(0.01, &f).unwrap();
    assert_eq!(lazy.stiffness_updates(), tets);
}
