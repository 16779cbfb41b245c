//! Benchmark of the haptic loop against a real physics process. Prints one JSON line.
//!
//! `cargo run --release -p haptic-node --bin haptic-bench -- --seconds 10`
//!
//! Starts the physics-node binary (built first with `cargo build --release -p physics-node
//! -p haptic-node --bins`, found next to this executable) and the haptic-node binary (emulated Touch driven
//! by the operator protocol on the default scene, transport probe on), each as its own
//! process on a fresh session, and reads the haptic node's run summary. The LCP is also
//! timed in-process on synthetic frames of 8 and 32 contacts through the same renderer the
//! loop uses.
use anyhow::{bail, Context};
use clap::Parser;
use haptic_node::config::Limits;
use haptic_node::render::{boxed_frame, Renderer};
use haptic_node::stats::LatencyHistogram;
use msgs::Pose;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(name = "haptic-bench")]
struct Cli {
    /// Length of the run with the real physics process, s.
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Physics binary to use (default: physics-node next to this executable, built first).
    #[arg(long)]
    physics: Option<PathBuf>,
    /// Do not run `cargo build` for the physics binary.
    #[arg(long)]
    no_build: bool,
    /// LCP re-solves per synthetic size.
    #[arg(long, default_value_t = 20_000)]
    lcp_solves: u32,
}

struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start(exe: &Path, args: &[&str]) -> anyhow::Result<Killed> {
    let mut child = Command::new(exe)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .with_context(|| format!("starting {}", exe.display()))?;
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if line.starts_with("READY") {
                let _ = tx.send(());
            }
        }
    });
    let child = Killed(child);
    rx.recv_timeout(Duration::from_secs(60))
        .with_context(|| format!("{} did not become ready within 60 s", exe.display()))?;
    Ok(child)
}

/// A frame holding the synthetic patch of `n` contacts (`contact_lcp::synthetic`, the
/// problem the `patch-timing` example times too).
fn synthetic_frame(n: usize, frame: &mut msgs::physics_to_haptic::ContactFrame) {
    let dt = 0.01;
    frame.instance_id = 1;
    frame.sequence = 1;
    frame.dt_s = dt;
    frame.contact_count = n as u32;
    frame.row_count = (3 * n) as u32;
    frame.friction_mu = 0.2;
    frame.proxy_pose = Pose::IDENTITY;
    frame.probe_free_pose = Pose::IDENTITY;
    let patch = contact_lcp::synthetic::synthetic_patch(n, dt);
    frame.contact_points[..n].copy_from_slice(&patch.points);
    frame.constraint_directions[..3 * n].copy_from_slice(&patch.directions);
    frame.free_violation[..3 * n].copy_from_slice(&patch.free_violation);
    frame.compliance.copy_from_slice(&patch.compliance);
}

fn lcp_p99_us(contacts: usize, solves: u32) -> anyhow::Result<(f64, f64)> {
    let limits = Limits::from_config(&launch_config::DeviceConfig::default())?;
    let mut renderer = Renderer::new(limits);
    let mut frame = boxed_frame();
    synthetic_frame(contacts, &mut frame);
    let mut hist = LatencyHistogram::new(1_000_000);
    let mut iterations = 0u64;
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let t0 = msgs::clock::monotonic_ns();
    for i in 0..solves as u64 {
        if i % 10 == 0 {
            // A new physics frame every 10 ticks (100 Hz vs 1 kHz).
            let mut f = boxed_frame();
            *f = *frame;
            f.sequence = 1 + i / 10;
            f.publish_ns = t0 + i * 1_000_000;
            renderer.accept_frame(&mut f, t0 + i * 1_000_000);
        }
        // The hand trembles by up to ±50 µm around the frame's proxy.
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        let jitter = (seed % 1000) as f64 / 1000.0 - 0.5;
        let proxy = Pose {
            position: [jitter * 1e-4, -jitter * 5e-5, jitter * 1e-4],
            ..Pose::IDENTITY
        };
        let out = renderer.tick(t0 + i * 1_000_000 + 500_000, &proxy, true);
        if out.lcp_ns == 0 {
            bail!(
                "synthetic frame of {contacts} contacts was not solved (faults {:#x})",
                out.faults
            );
        }
        hist.record(out.lcp_ns);
        iterations += out.lcp_iterations as u64;
    }
    Ok((hist.quantile_us(0.99), iterations as f64 / solves as f64))
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    let here = std::env::current_exe()?.parent().unwrap().to_path_buf();
    let physics = match &cli.physics {
        Some(p) => p.clone(),
        None => {
            if !cli.no_build {
                let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
                let status =
                    Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
                        .current_dir(workspace)
                        .args([
                            "build",
                            "--release",
                            "-p",
                            "physics-node",
                            "-p",
                            "haptic-node",
                            "--bins",
                        ])
                        .stdout(Stdio::null())
                        .stderr(Stdio::inherit())
                        .status()
                        .context("running cargo build for physics-node")?;
                if !status.success() {
                    // The shared checkout may be mid-edit; an existing binary still measures.
                    eprintln!("warning: cargo build --release -p physics-node -p haptic-node --bins failed; using the existing binaries");
                }
            }
            here.join("physics-node")
        }
    };
    if !physics.exists() {
        bail!("physics binary {} not found (build it with cargo build --release -p physics-node --bins)", physics.display());
    }
    let haptic = here.join("haptic-node");
    if !haptic.exists() {
        bail!(
            "haptic-node binary {} not found next to the bench",
            haptic.display()
        );
    }

    // LCP on synthetic frames first, on a thread with the servo loop's scheduling
    // (SCHED_FIFO when granted), as the loop runs it.
    let solves = cli.lcp_solves;
    let (lcp8, it8, lcp32, it32) =
        std::thread::spawn(move || -> anyhow::Result<(f64, f64, f64, f64)> {
            haptic_node::servo::request_realtime(80);
            let (a, b) = lcp_p99_us(8, solves)?;
            let (c, d) = lcp_p99_us(32, solves)?;
            Ok((a, b, c, d))
        })
        .join()
        .map_err(|_| anyhow::anyhow!("LCP timing thread panicked"))??;

    let session = format!("bench-{}", std::process::id());
    let out = std::env::temp_dir().join(format!("haptic-bench-{}", std::process::id()));
    let host = msgs::host_load::HostLoad::start();
    let _physics = start(&physics, &["--session", &session])?;
    let seconds = cli.seconds.to_string();
    let mut haptic = start(
        &haptic,
        &[
            "--session",
            &session,
            "--seconds",
            &seconds,
            "--transport-probe",
            "--out",
            out.to_str().unwrap(),
        ],
    )?;
    let deadline = Instant::now() + Duration::from_secs_f64(cli.seconds + 30.0);
    loop {
        if let Some(status) = haptic.0.try_wait()? {
            if !status.success() {
                bail!("haptic-node exited with {status}");
            }
            break;
        }
        if Instant::now() > deadline {
            bail!("haptic-node did not finish within {} s", cli.seconds + 30.0);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let host = host.finish();
    let summary_path = out.join("haptic-stats.json");
    let text = std::fs::read_to_string(&summary_path)
        .with_context(|| format!("reading {}", summary_path.display()))?;
    let s: serde_json::Value = serde_json::from_str(&text)?;
    std::fs::remove_dir_all(&out).ok();
    let line = serde_json::json!({
        "seconds": cli.seconds,
        "tick_hz": s["tick_hz"],
        "period_err_p50_us": s["period_err_p50_us"],
        "period_err_p99_us": s["period_err_p99_us"],
        "period_err_max_us": s["period_err_max_us"],
        "lcp_p99_us_8": lcp8,
        "lcp_p99_us_32": lcp32,
        "lcp_iterations_mean_8": it8,
        "lcp_iterations_mean_32": it32,
        "lcp_p99_us_run": s["lcp_p99_us"],
        "transport_p50_us": s["transport_p50_us"],
        "transport_p99_us": s["transport_p99_us"],
        "transport_frames": s["transport_frames"],
        "transport_unwatched": s["transport_unwatched"],
        "transport_probe_fifo": s["transport_probe_fifo"],
        "frame_age_p50_us": s["frame_age_p50_us"],
        "frame_age_p99_us": s["frame_age_p99_us"],
        "overruns": s["overruns"],
        "contact_ticks": s["contact_ticks"],
        "max_rendered_n": s["max_rendered_n"],
        "fault_ticks": s["fault_ticks"],
        "faults_seen": s["faults_seen"],
        "realtime": s["realtime"],
        "loadavg_1m_before": host.loadavg_1m_before,
        "loadavg_1m_after": host.loadavg_1m_after,
        "host_steal_fraction": host.host_steal_fraction,
        "cpus": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(0),
    });
    println!("{line}");
    Ok(())
}
