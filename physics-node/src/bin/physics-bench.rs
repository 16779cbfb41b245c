//! Physics step benchmark: the probe indents a probing site and slides around it on the
//! surface with contact active the whole time; prints ONE JSON line.
//!
//! `cargo run --release -p physics-node --bin physics-bench -- [--launch FILE] [--mesh SPEC] --seconds 5`
//!
//! The scene is the default session's (`launch-config/launch/default.toml`, the calibrated
//! tissue), or the `[scene]` of `--launch FILE`; every option given overrides its key.
//! SPEC: default:coarse | default:fine | default:finest | study:lateral | study:medial | FILE.msh
use anyhow::{bail, Context};
use clap::Parser;
use nalgebra::{Point3, UnitQuaternion, Vector3};
use physics_node::sim::Simulation;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(name = "physics-bench")]
struct Args {
    /// Launch file whose `[scene]` is stepped (default: the embedded default session's).
    #[arg(long)]
    launch: Option<PathBuf>,
    /// Mesh spec (see module docs; default: the scene's).
    #[arg(long)]
    mesh: Option<String>,
    /// Wall-clock seconds of timed stepping.
    #[arg(long, default_value_t = 5.0)]
    seconds: f64,
    /// Coulomb friction of the contact (default: the scene's).
    #[arg(long)]
    friction: Option<f64>,
    /// FEM linear solver (`cg`, `cg-jacobi`, `cg-cholesky`, `cg-warped-cholesky`, `direct`;
    /// default: the scene's).
    #[arg(long)]
    solver: Option<launch_config::scene::SolverKind>,
    /// CG iteration cap (default: the scene's, SOFA's 25).
    #[arg(long)]
    cg_iterations: Option<u32>,
    /// CG relative residual tolerance (default: the scene's, SOFA's 1e-9).
    #[arg(long)]
    cg_tolerance: Option<f64>,
    /// Precision of the CG matrix (`f32` or `f64`; default: the scene's).
    #[arg(long)]
    cg_matrix: Option<launch_config::scene::CgMatrix>,
    /// Re-rotate an element's stiffness blocks only after its rotation moved by more than
    /// this, rad (default: the scene's; 0 = every step, as SOFA).
    #[arg(long)]
    stiffness_tolerance: Option<f64>,
    /// Stop after this many timed steps instead of after --seconds (same trajectory for A/B
    /// comparisons of the force).
    #[arg(long)]
    steps: Option<usize>,
    /// Element rotation (`qr` = SOFA's "large", or `polar`; default: the scene's).
    #[arg(long)]
    rotation: Option<launch_config::scene::RotationMethod>,
    /// Study data folder (default: $ARTHROSIM_DATA, else ../shared/data).
    #[arg(long)]
    data: Option<PathBuf>,
    /// How a partial compliance cache is filled: `prefetch` (worker thread, as the physics
    /// node) or `inline` (a miss is solved inside the step).
    #[arg(long, default_value = "prefetch")]
    compliance: String,
    /// Indentation of the proxy below the surface, m.
    #[arg(long, default_value_t = 1.5e-3)]
    depth: f64,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        bail!("--seconds must be > 0");
    }
    let data_dir = args.data.clone().unwrap_or_else(launch_config::data_dir);
    let launch = match &args.launch {
        Some(path) => {
            launch_config::load(path).with_context(|| format!("loading {}", path.display()))?
        }
        None => launch_config::load_str(
            launch_config::DEFAULT_LAUNCH,
            launch_config::DEFAULT_LAUNCH_ORIGIN,
        )
        .context("the embedded default launch file")?,
    };
    let mut scene = launch.scene;
    if let Some(mesh) = &args.mesh {
        scene.meniscus.mesh = mesh.clone();
        if mesh.starts_with("study:") {
            // The study's mesh carries its own fixed set (lateral) — the loader decides.
            scene.meniscus.fixed = "inferior".into();
        }
    }
    if let Some(f) = args.friction {
        scene.contact.friction = f;
    }
    if let Some(k) = args.solver {
        scene.solver.kind = k;
    }
    if let Some(r) = args.rotation {
        scene.solver.rotation = r;
    }
    if let Some(n) = args.cg_iterations {
        scene.solver.cg_iterations = n;
    }
    if let Some(t) = args.cg_tolerance {
        scene.solver.cg_tolerance = t;
    }
    if let Some(m) = args.cg_matrix {
        scene.solver.cg_matrix = m;
    }
    if let Some(t) = args.stiffness_tolerance {
        scene.solver.stiffness_rotation_tolerance = t;
    }
    let t_build = Instant::now();
    let filling = match args.compliance.as_str() {
        "prefetch" => physics_node::compliance::Filling::Prefetch,
        "inline" => physics_node::compliance::Filling::Inline,
        other => bail!("--compliance {other}: expected prefetch or inline"),
    };
    let mut sim = Simulation::with_filling(&scene, &data_dir, filling)
        .with_context(|| format!("building scene for {}", scene.meniscus.mesh))?;
    let build_s = t_build.elapsed().as_secs_f64();

    let (site, normal) = probing_site(&sim);
    let r = scene.probe.tip_radius;
    let q = UnitQuaternion::rotation_between(&Vector3::z(), &normal)
        .unwrap_or_else(UnitQuaternion::identity);
    let (t1, t2) = physics_node::contact::tangents(&normal);
    let start = site + normal * (r + 0.2e-3);
    sim.teleport_probe(&physics_node::probe::pose(start, q));

    // Indent, then circle: radius 2.5 mm at 0.5 Hz, depth oscillating ±0.5 mm at 0.7 Hz.
    let path = |t: f64| -> Point3<f64> {
        let ramp = (t / 0.3).min(1.0);
        let depth = ramp * (args.depth + 0.5e-3 * (2.0 * std::f64::consts::PI * 0.7 * t).sin());
        let a = 2.5e-3 * ramp;
        let w = 2.0 * std::f64::consts::PI * 0.5 * t;
        site + normal * (r - depth) + t1 * (a * w.cos()) + t2 * (a * w.sin())
    };
    // Warm-up: get into contact (not timed).
    for _ in 0..40 {
        sim.set_proxy_pose(&physics_node::probe::pose(path(sim.time()), q));
        sim.step()?;
    }
    // Step durations up to 10 s (longer ones count as 10 s; the maximum stays exact).
    let mut durations = msgs::timing::LatencyHistogram::new(10_000_000_000);
    let mut contacts_sum = 0u64;
    let mut in_contact = 0u64;
    let mut force_sum = 0.0;
    let mut stiffness_updates = 0u64;
    let misses_before = sim.compliance_misses();
    let approximations_before = sim.compliance_approximations();
    let times_before = sim.phase_times();
    let host = msgs::host_load::HostLoad::start();
    let t0 = Instant::now();
    let more = |done: u64| match args.steps {
        Some(n) => done < n as u64,
        None => t0.elapsed().as_secs_f64() < args.seconds,
    };
    while more(durations.count()) {
        sim.set_proxy_pose(&physics_node::probe::pose(path(sim.time()), q));
        let s = Instant::now();
        sim.step()?;
        durations.record(s.elapsed().as_nanos() as u64);
        stiffness_updates += sim.fem().stiffness_updates() as u64;
        let c = sim.contact_count() as u64;
        contacts_sum += c;
        in_contact += (c > 0) as u64;
        let f = sim.contact_force();
        force_sum += (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
    }
    let wall = t0.elapsed().as_secs_f64();
    let host = host.finish();
    let steps = durations.count().max(1);
    let total_step_s = durations.mean_ns() * durations.count() as f64 * 1e-9;
    let (slots, complete) = sim.compliance_cache_info();
    let t1 = sim.phase_times();
    let per_step = |a: u64, b: u64| (a - b) as f64 / 1e3 / steps as f64;
    let phases = serde_json::json!({
        "prepare": per_step(t1.prepare_ns, times_before.prepare_ns),
        "free_motion": per_step(t1.free_motion_ns, times_before.free_motion_ns),
        "detection": per_step(t1.detection_ns, times_before.detection_ns),
        "compliance": per_step(t1.compliance_ns, times_before.compliance_ns),
        "lcp": per_step(t1.lcp_ns, times_before.lcp_ns),
        "correction": per_step(t1.correction_ns, times_before.correction_ns),
    });
    let json = serde_json::json!({
        "mesh": scene.meniscus.mesh,
        "support_stiffness": scene.meniscus.support_stiffness,
        "strain_stiffening": scene.material.strain_stiffening,
        "support_length_m": sim.fem().support_length(),
        "nodes": sim.node_count(),
        "tets": sim.tet_count(),
        "steps": steps,
        "steps_per_s": steps as f64 / total_step_s,
        "wall_steps_per_s": steps as f64 / wall,
        "step_p50_us": durations.quantile_us(0.5),
        "step_p99_us": durations.quantile_us(0.99),
        "step_p99_over_p50": durations.quantile_us(0.99) / durations.quantile_us(0.5),
        "step_max_us": durations.max_ns() as f64 / 1e3,
        "contacts_mean": contacts_sum as f64 / steps as f64,
        "contact_fraction": in_contact as f64 / steps as f64,
        "force_mean_n": force_sum / steps as f64,
        "solver": scene.solver.kind,
        "rotation": scene.solver.rotation,
        "cg_iterations": scene.solver.cg_iterations,
        "cg_tolerance": scene.solver.cg_tolerance,
        "cg_matrix": scene.solver.cg_matrix,
        "stiffness_rotation_tolerance": scene.solver.stiffness_rotation_tolerance,
        "stiffness_updates_mean": stiffness_updates as f64 / steps as f64,
        "friction": scene.contact.friction,
        "compliance_slots": slots,
        "compliance_complete": complete,
        "compliance_misses": sim.compliance_misses() - misses_before,
        "compliance_filling": args.compliance,
        "compliance_approximated_contacts": sim.compliance_approximations() - approximations_before,
        "compliance_cached_nodes": sim.compliance_cached_nodes(),
        "build_s": build_s,
        "phase_mean_us": phases,
        "loadavg_1m_before": host.loadavg_1m_before,
        "loadavg_1m_after": host.loadavg_1m_after,
        "host_steal_fraction": host.host_steal_fraction,
    });
    println!("{json}");
    Ok(())
}

/// The mid-body probing site (region 2) if the mesh has sites, else the highest surface vertex
/// with an upward normal.
fn probing_site(sim: &Simulation) -> (Point3<f64>, Vector3<f64>) {
    let sites = sim.probing_sites();
    if let Some(s) = sites
        .iter()
        .find(|s| s.region == 2)
        .or_else(|| sites.first())
    {
        return (s.point, s.normal.normalize());
    }
    let top = sim
        .surface_positions()
        .iter()
        .copied()
        .max_by(|a, b| a.z.total_cmp(&b.z))
        .unwrap_or_else(Point3::origin);
    (top, Vector3::z())
}
