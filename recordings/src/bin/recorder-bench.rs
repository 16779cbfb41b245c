//! Recorder benchmark: starts the real `recorder` process (the sibling binary), feeds it a
//! full-rate session over iceoryx2 from this process (device ticks at `--tick-hz`, physics
//! steps at a tenth of that with `--contacts` contacts, 10 Hz haptic stats, 20 Hz surface
//! frames of a meniscus-sized mesh), stops it and prints one JSON line: messages/s
//! sustained, bytes per minute of session, recorder CPU share (of one core), dropped samples.
//!
//! `cargo build --release -p recordings && target/release/recorder-bench --seconds 20`

use anyhow::{bail, Context};
use clap::Parser;
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc;
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[derive(Parser)]
struct Args {
    /// Session length, s.
    #[arg(long, default_value_t = 20.0)]
    seconds: f64,
    /// Device tick rate, Hz (physics steps at a tenth).
    #[arg(long, default_value_t = 1000.0)]
    tick_hz: f64,
    /// Active contacts per physics step (rows = 3 × contacts; W is rows²).
    #[arg(long, default_value_t = 4)]
    contacts: u32,
    /// Record each step's contact problem too (`[recording] contact_problem = true`).
    #[arg(long)]
    contact_problem: bool,
    /// Output folder (default: a fresh temporary folder).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// utime + stime of a process, s.
fn cpu_seconds(pid: u32) -> anyhow::Result<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat
        .rsplit_once(')')
        .map(|(_, r)| r)
        .context("malformed /proc stat")?;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = fields[11].parse::<f64>()? + fields[12].parse::<f64>()?;
    // SAFETY: sysconf has no preconditions.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    Ok(ticks / hz)
}

fn boxed_zeroed<T: msgs::Topic>() -> Box<T> {
    let mut slot = Box::new(core::mem::MaybeUninit::<T>::uninit());
    T::zeroed_in(&mut slot);
    // SAFETY: zeroed_in initialised the value (plain old data).
    unsafe { Box::from_raw(Box::into_raw(slot) as *mut T) }
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let exe = std::env::current_exe()?;
    let recorder = exe.with_file_name("recorder");
    if !recorder.exists() {
        bail!(
            "{} not found: build it with `cargo build --release -p recordings`",
            recorder.display()
        );
    }
    let out = args.out.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("recorder-bench-{}", std::process::id()))
    });
    std::fs::create_dir_all(&out)?;
    let session = format!("recorder-bench-{}", std::process::id());

    let mut command = Command::new(&recorder);
    command.args(["--session", &session, "--out"]).arg(&out);
    if args.contact_problem {
        let launch = out.join("bench-launch.toml");
        std::fs::write(&launch, "[recording]\ncontact_problem = true\n")?;
        command.arg("--launch").arg(&launch);
    }
    let mut child = command
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .with_context(|| format!("starting {}", recorder.display()))?;
    let mut stdout = BufReader::new(child.stdout.take().context("recorder stdout")?);
    let mut line = String::new();
    loop {
        line.clear();
        if stdout.read_line(&mut line)? == 0 {
            bail!("recorder exited before READY");
        }
        if line.trim() == "READY recorder" {
            break;
        }
    }

    let node = ipc::create_node("recorder-bench")?;
    let device_pub = ipc::publisher::<DeviceState>(&node, &session)?;
    let frame_pub = ipc::publisher::<ContactFrame>(&node, &session)?;
    let stats_pub = ipc::publisher::<HapticStats>(&node, &session)?;
    let surface_pub = ipc::publisher::<SurfaceFrame>(&node, &session)?;
    // A meniscus-sized visual surface: 258 vertices, 512 triangles.
    let mut surface = boxed_zeroed::<SurfaceFrame>();
    surface.vertex_count = 258;
    surface.triangle_count = 512;
    for (i, p) in surface.positions.iter_mut().take(258).enumerate() {
        let a = i as f32 * 0.1;
        *p = [0.02 * a.cos(), 0.02 * a.sin(), 0.001 * (i % 7) as f32];
    }
    for (i, t) in surface.triangles.iter_mut().take(512).enumerate() {
        let i = i as u32;
        *t = [i % 258, (i + 1) % 258, (i + 2) % 258];
    }
    let rows = (args.contacts.min(msgs::MAX_CONTACTS as u32) * 3) as usize;
    let tick_period = 1.0 / args.tick_hz;

    let cpu0 = cpu_seconds(child.id())?;
    let start = Instant::now();
    let (mut ticks, mut steps, mut stats, mut surfaces) = (0u64, 0u64, 0u64, 0u64);
    while start.elapsed().as_secs_f64() < args.seconds {
        let due = (start.elapsed().as_secs_f64() / tick_period) as u64;
        while ticks < due {
            ticks += 1;
            let t = ticks as f64 * tick_period;
            ipc::send_with(&device_pub, |d| {
                d.instance_id = 1;
                d.sequence = ticks;
                d.publish_ns = msgs::clock::monotonic_ns();
                d.proxy_pose.position = [0.01 * t.sin(), 0.0, 0.02 - 0.001 * t];
                d.proxy_pose.orientation = [0.0, 0.0, 0.0, 1.0];
                d.joint_angles = [t, -t, 0.5 * t, 0.1, 0.2, 0.3];
                d.rendered_force = [0.0, 0.0, (0.3 * t).sin().abs()];
                d.region = 1 + ((ticks / 10_000) % 3) as u32;
                d.probing_index = (ticks / 10_000) as u32 + 1;
            })?;
            if ticks % 10 == 0 {
                steps += 1;
                ipc::send_with(&frame_pub, |f| {
                    f.instance_id = 2;
                    f.sequence = steps;
                    f.publish_ns = msgs::clock::monotonic_ns();
                    f.sim_time_s = steps as f64 * 0.01;
                    f.dt_s = 0.01;
                    f.contact_count = (rows / 3) as u32;
                    f.row_count = rows as u32;
                    f.device_sequence_used = ticks;
                    f.probe_pose.orientation = [0.0, 0.0, 0.0, 1.0];
                    f.contact_force = [0.01, -0.02, 0.5 + 0.1 * t.sin()];
                    for r in 0..rows {
                        f.free_violation[r] = -1e-4 * (r as f64 + t);
                        f.lambda[r] = 1e-3 * t / (r + 1) as f64;
                        f.constraint_directions[r] = [0.0, 0.0, 1.0, 0.0, t, 0.0];
                        for c in 0..rows {
                            f.compliance[r * msgs::MAX_ROWS + c] =
                                1e-4 / (1 + r + c) as f64 + 1e-9 * t;
                        }
                    }
                })?;
            }
            if ticks % 100 == 0 {
                stats += 1;
                ipc::send_with(&stats_pub, |h| {
                    h.sequence = stats;
                    h.ticks = ticks;
                    h.publish_ns = msgs::clock::monotonic_ns();
                    h.tick_hz = args.tick_hz;
                })?;
            }
            if ticks % 50 == 0 {
                surfaces += 1;
                surface.sequence = surfaces;
                surface.publish_ns = msgs::clock::monotonic_ns();
                ipc::send_copy(&surface_pub, &*surface)?;
            }
        }
        std::thread::sleep(Duration::from_micros(300));
    }
    // Give the recorder one drain period and a flush before stopping it.
    std::thread::sleep(Duration::from_millis(100));
    let wall = start.elapsed().as_secs_f64();
    let cpu = cpu_seconds(child.id())? - cpu0;

    // SAFETY: SIGTERM to our own child.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    let mut recorded: Option<serde_json::Value> = None;
    loop {
        line.clear();
        if stdout.read_line(&mut line)? == 0 {
            break;
        }
        if let Some(json) = line.trim().strip_prefix("RECORDED ") {
            recorded = Some(serde_json::from_str(json)?);
        }
    }
    let status = child.wait()?;
    if !status.success() {
        bail!("recorder exited with {status}");
    }
    let recorded = recorded.context("no RECORDED line")?;
    let file = out.join("session.mcap");
    let bytes = std::fs::metadata(&file)?.len();
    let get = |k: &str| recorded[k].as_u64().unwrap_or(0);
    let samples_published = ticks + steps + stats + surfaces;
    let samples_received =
        get("device_states") + get("contact_frames") + get("haptic_stats") + get("surface_frames");
    let dropped = get("device_states_dropped")
        + get("contact_frames_dropped")
        + (ticks - get("device_states").min(ticks))
        + (steps - get("contact_frames").min(steps));
    let json = serde_json::json!({
        "bench": "recorder",
        "seconds": wall,
        "tick_hz": args.tick_hz,
        "contacts": rows / 3,
        "contact_problem": args.contact_problem,
        "samples_published": samples_published,
        "samples_received": samples_received,
        "mcap_messages": get("messages_written"),
        "messages_per_s": get("messages_written") as f64 / wall,
        "samples_per_s": samples_received as f64 / wall,
        "bytes": bytes,
        "bytes_per_minute": bytes as f64 / (wall / 60.0),
        "recorder_cpu_share": cpu / wall,
        "dropped": dropped,
        "max_device_backlog": get("max_device_backlog"),
        "flushes": get("flushes"),
        "file": file,
    });
    println!("{json}");
    if args.out.is_none() {
        let _ = std::fs::remove_dir_all(&out);
    }
    Ok(())
}
