//! Release-mode timing of the FEM free motion (no contact): one JSON line per mesh and
//! solver. `cargo run --release -p physics-node --example fem_timing [-- SPEC...]`
//! SPEC: a scene mesh spec (`study:lateral`, `default:lateral:fine`, …) or `box:NX:NY:NZ`.
//! Prints numbers; asserts nothing.

use std::time::Instant;

use launch_config::scene::MeniscusConfig;
use nalgebra::Vector3;
use physics_node::fem::test_meshes::{box_mesh, nodes_where};
use physics_node::fem::{FemModel, FemSettings, LinearSolver, Material, Preconditioner};
use physics_node::mesh::{load_scene_mesh, resolve_data_dir, TetMesh};

fn load(spec: &str) -> Option<(TetMesh, Vec<usize>)> {
    if let Some(rest) = spec.strip_prefix("box:") {
        let d: Vec<usize> = rest.split(':').filter_map(|s| s.parse().ok()).collect();
        if d.len() != 3 {
            return None;
        }
        let mesh = box_mesh(0.04, 0.02, 0.008, d[0], d[1], d[2]);
        let fixed = nodes_where(&mesh, |p| p.z < 1e-9);
        return Some((mesh, fixed));
    }
    let cfg = MeniscusConfig {
        mesh: spec.to_string(),
        ..MeniscusConfig::default()
    };
    match load_scene_mesh(&cfg, &resolve_data_dir()) {
        Ok(l) => Some((l.mesh, l.fixed_nodes)),
        Err(e) => {
            eprintln!("skipping {spec}: {e}");
            None
        }
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let specs: Vec<String> = if args.is_empty() {
        [
            "study:lateral",
            "default:lateral:coarse",
            "default:lateral:fine",
            "box:7:5:3",
            "box:24:12:7",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    } else {
        args
    };
    let cg = |pc| LinearSolver::Cg {
        max_iterations: 25,
        tolerance: 1e-9,
        preconditioner: pc,
    };
    let solvers = [
        ("cg", cg(Preconditioner::None)),
        ("cg-jacobi", cg(Preconditioner::BlockJacobi)),
        ("cg-cholesky", cg(Preconditioner::RestCholesky)),
        ("cg-warped-cholesky", cg(Preconditioner::WarpedRestCholesky)),
        ("direct", LinearSolver::Direct),
    ];
    for spec in &specs {
        let Some((mesh, fixed)) = load(spec) else {
            continue;
        };
        let (lo, hi) = mesh.nodes.iter().fold(
            (Vector3::repeat(f64::MAX), Vector3::repeat(f64::MIN)),
            |(lo, hi), p| (lo.inf(&p.coords), hi.sup(&p.coords)),
        );
        // Load: a point force on the top node nearest the centre, sweeping sideways.
        let centre = (lo + hi) * 0.5;
        let loaded = (0..mesh.nodes.len())
            .min_by(|&a, &b| {
                let da = (mesh.nodes[a].coords - Vector3::new(centre.x, centre.y, hi.z)).norm();
                let db = (mesh.nodes[b].coords - Vector3::new(centre.x, centre.y, hi.z)).norm();
                da.total_cmp(&db)
            })
            .unwrap();
        let only = std::env::var("FEM_TIMING_SOLVER").ok();
        for (name, solver) in solvers {
            if only.as_deref().is_some_and(|o| o != name) {
                continue;
            }
            let settings = FemSettings {
                solver,
                ..FemSettings::default()
            };
            let t_build = Instant::now();
            let mut fem = match FemModel::new(&mesh, Material::lateral(), &fixed, settings) {
                Ok(f) => f,
                Err(e) => {
                    eprintln!("{spec}/{name}: {e}");
                    continue;
                }
            };
            let build_ms = t_build.elapsed().as_secs_f64() * 1e3;
            let t_rc = Instant::now();
            let mut rc = fem.rest_compliance(0.01, 32).expect("rest compliance");
            let rest_factor_ms = t_rc.elapsed().as_secs_f64() * 1e3;
            let n = fem.node_count();
            let mut block = vec![0.0; 3 * n * 24];
            for c in 0..24 {
                block[c * 3 * n + (3 * loaded + c % 3)] = 1.0;
            }
            let t_bs = Instant::now();
            rc.solve_block_in_place(&mut block, 24);
            let block24_us = t_bs.elapsed().as_secs_f64() * 1e6;
            let mut forces = vec![Vector3::zeros(); n];
            let steps = 2000;
            let mut times = msgs::timing::LatencyHistogram::new(10_000_000_000);
            let mut iters = 0usize;
            let t_all = Instant::now();
            for s in 0..steps {
                let ph = s as f64 * 0.01;
                forces[loaded] = Vector3::new(
                    0.5 * ph.sin(),
                    0.3 * (0.7 * ph).cos(),
                    -1.0 - 0.5 * (1.3 * ph).sin(),
                );
                let t = Instant::now();
                fem.update_node_rotations();
                let st = fem.free_motion(0.01, &forces).expect("free motion");
                fem.commit();
                times.record(t.elapsed().as_nanos() as u64);
                iters += st.iterations;
                if t_all.elapsed().as_secs_f64() > 10.0 {
                    break;
                }
            }
            let done = times.count();
            let pct = |p: f64| times.quantile_us(p);
            println!(
                "{{\"mesh\":\"{spec}\",\"solver\":\"{name}\",\"nodes\":{n},\"tets\":{},\"free_nodes\":{},\"steps\":{done},\"free_motion_p50_us\":{:.1},\"free_motion_p99_us\":{:.1},\"cg_iterations_mean\":{:.2},\"build_ms\":{build_ms:.1},\"rest_factor_ms\":{rest_factor_ms:.1},\"block24_solve_us\":{block24_us:.0},\"rest_factor_nnz\":{}}}",
                fem.tet_count(),
                fem.free_nodes().len(),
                pct(0.5),
                pct(0.99),
                iters as f64 / done as f64,
                rc.cholesky_mut().factor_nnz(),
            );
        }
    }
}
