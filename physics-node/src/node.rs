//! The physics node process: steps the [`Simulation`] in real time (one step per dt of wall
//! time, absolute deadlines), driven by the newest device state (or, only with
//! `[bridge] accept_target_pose`, an external probe target, which overrides the device while
//! it keeps arriving; its frames name no device sample, so no haptic node renders them),
//! publishes the contact frame every step and the deformed surface at ~30 Hz.
//!
//! A material (degeneration grade) change is prepared on a worker thread and swapped in at a
//! step boundary; at most one starts per `[scene] material_change_interval_s`, and commands
//! in between are coalesced (the newest wins), so a flood of them cannot stall the loop.
//!
//! Lifecycle: new (load scene, build simulation) → start (open ports, READY) → step loop →
//! stop (on the stop flag or the optional time bound; the CSV is flushed).

use crate::sim::{ContactForceCsv, MaterialParts, Simulation};
use anyhow::Context;
use msgs::bridge_to_physics::{MaterialCommand, ProbeTarget};
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::{MAX_SURFACE_TRIANGLES, MAX_SURFACE_VERTICES};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// Surface publication period, s (~30 Hz).
const SURFACE_PERIOD_S: f64 = 1.0 / 30.0;
/// An external probe target overrides the device until none arrived for this long, s.
const TARGET_HOLD_S: f64 = 0.5;
/// When the loop falls this many steps behind, it re-anchors its schedule instead of
/// bursting to catch up (a burst would jump the tissue ahead of the device).
const MAX_LAG_STEPS: u32 = 5;

#[derive(clap::Args, Debug, Clone, Default)]
pub struct NodeArgs {
    /// `--launch` (its `[scene]` section), `--session`, `--out` (`contact_force.csv`).
    #[command(flatten)]
    pub common: launch_config::node::CommonArgs,
    /// Study data folder (default: $ARTHROSIM_DATA, else ../shared/data).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Stop after this many seconds of simulated time (0: run until stopped).
    #[arg(long, default_value_t = 0.0)]
    pub seconds: f64,
}

/// Runs the physics node until the stop flag is raised (SIGINT/SIGTERM) or `--seconds` pass.
pub fn run_node(args: NodeArgs) -> anyhow::Result<()> {
    launch_config::node::init_tracing("info");
    let stop = msgs::lifecycle::install_stop_flag();
    let session = ipc::session_name(args.common.session.as_deref())?;
    let (scene, accept_target_pose) = match &args.common.launch {
        Some(path) => {
            let file = launch_config::load(path)
                .with_context(|| format!("loading launch file {}", path.display()))?;
            (file.scene, file.bridge.accept_target_pose)
        }
        None => (launch_config::SceneConfig::default(), false),
    };
    let data_dir = args.data.clone().unwrap_or_else(launch_config::data_dir);
    // Real time: a partial compliance cache is filled ahead of the probe on a worker thread,
    // never solved inside a step.
    let mut sim = Simulation::with_filling(&scene, &data_dir, crate::compliance::Filling::Prefetch)
        .context("building the physics scene")?;
    let mut csv = match &args.common.out {
        Some(dir) => {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
            let path = dir.join("contact_force.csv");
            Some(
                ContactForceCsv::create(&path)
                    .with_context(|| format!("creating {}", path.display()))?,
            )
        }
        None => None,
    };

    // Ports live on this thread (iceoryx2 ports are not Send).
    let node = ipc::create_node("physics")?;
    let frame_pub = ipc::publisher::<ContactFrame>(&node, &session)?;
    let surface_pub = ipc::publisher::<SurfaceFrame>(&node, &session)?;
    let device_sub = ipc::subscriber::<DeviceState>(&node, &session, Queue::Newest)?;
    // External targets are opt-in: without `[bridge] accept_target_pose` nothing listens.
    let target_sub = if accept_target_pose {
        Some(ipc::subscriber::<ProbeTarget>(
            &node,
            &session,
            Queue::Newest,
        )?)
    } else {
        None
    };
    let material_sub = ipc::subscriber::<MaterialCommand>(&node, &session, Queue::Newest)?;

    let instance_id = msgs::clock::new_instance_id();
    sim.set_instance_id(instance_id);
    // Received samples land in boxed slots (the frames are large; no stack copies).
    let mut device = boxed_zeroed::<DeviceState>();
    let mut target = boxed_zeroed::<ProbeTarget>();
    let mut material = boxed_zeroed::<MaterialCommand>();
    let mut last_target_time: Option<f64> = None;
    let mut materials = MaterialWorker::spawn(scene.clone(), data_dir.clone())?;
    let change_interval = Duration::from_secs_f64(scene.material_change_interval_s.max(0.0));

    let mut surface_seq = 0u64;
    let mut next_surface_time = 0.0;

    msgs::lifecycle::announce_ready("physics");
    tracing::info!(session, nodes = sim.node_count(), "physics node running");

    let dt = sim.dt();
    let start = Instant::now();
    let mut anchor = start;
    let mut steps_since_anchor: u32 = 0;
    while !stop.load(Ordering::SeqCst) {
        if args.seconds > 0.0 && sim.time() >= args.seconds - 0.5 * dt {
            break;
        }
        if ipc::take_newest(&material_sub, &mut material)? > 0 {
            materials.request(material.degeneration_grade, sim.degeneration_grade());
        }
        materials.poll(&mut sim, change_interval);
        if let Some(target_sub) = &target_sub {
            if ipc::take_newest(target_sub, &mut target)? > 0 && target.pose.is_finite() {
                sim.set_proxy_pose(&target.pose);
                sim.set_external_drive();
                last_target_time = Some(sim.time());
            }
        }
        let target_active = last_target_time.is_some_and(|t| sim.time() - t < TARGET_HOLD_S);
        if ipc::take_newest(&device_sub, &mut device)? > 0
            && !target_active
            && device.proxy_pose.is_finite()
        {
            sim.set_proxy_pose(&device.proxy_pose);
            sim.set_device_sample(device.instance_id, device.sequence);
        }

        let t0 = Instant::now();
        sim.step().context("physics step")?;
        let step_ns = t0.elapsed().as_nanos() as u64;

        // Absolute deadlines: step k ends at anchor + k·dt.
        let deadline = anchor + Duration::from_secs_f64(dt * (steps_since_anchor + 1) as f64);
        ipc::send_with(&frame_pub, |f| {
            *f = *sim.contact_frame();
            f.step_duration_ns = step_ns;
            let (now, now_ns) = (Instant::now(), msgs::clock::monotonic_ns());
            f.publish_ns = now_ns;
            f.next_step_ns = now_ns + deadline.saturating_duration_since(now).as_nanos() as u64;
            f.publisher_cpu_plus_one = msgs::clock::current_cpu_plus_one();
        })?;
        if sim.time() + 1e-9 >= next_surface_time {
            next_surface_time = sim.time() + SURFACE_PERIOD_S;
            surface_seq += 1;
            ipc::send_with(&surface_pub, |s| {
                fill_surface(&sim, s, instance_id, surface_seq)
            })?;
        }
        if let Some(csv) = csv.as_mut() {
            csv.write(&sim)?;
        }

        steps_since_anchor += 1;
        let now = Instant::now();
        if deadline > now {
            std::thread::sleep(deadline - now);
        } else if now - deadline > Duration::from_secs_f64(dt * MAX_LAG_STEPS as f64) {
            tracing::warn!(
                lag_ms = (now - deadline).as_secs_f64() * 1e3,
                "physics behind real time; re-anchoring"
            );
            anchor = now;
            steps_since_anchor = 0;
        }
    }
    if let Some(csv) = csv.as_mut() {
        csv.flush()?;
    }
    tracing::info!(
        steps = (sim.time() / dt).round(),
        physics_faults = sim.physics_faults(),
        "physics node stopped"
    );
    Ok(())
}

fn boxed_zeroed<T: msgs::Topic>() -> Box<T> {
    let mut slot = Box::new(core::mem::MaybeUninit::<T>::uninit());
    T::zeroed_in(&mut slot);
    // SAFETY: zeroed_in initialised the value (all payloads are plain old data).
    unsafe { Box::from_raw(Box::into_raw(slot) as *mut T) }
}

/// Copies the visual surface into a surface frame (truncated to the frame's capacity).
pub fn fill_surface(sim: &Simulation, s: &mut SurfaceFrame, instance_id: u64, sequence: u64) {
    let pos = sim.surface_positions();
    let tris = sim.surface_triangles();
    let nv = pos.len().min(MAX_SURFACE_VERTICES);
    let mut nt = 0;
    for tri in tris.iter() {
        if nt == MAX_SURFACE_TRIANGLES {
            break;
        }
        if tri.iter().all(|&v| v < nv) {
            s.triangles[nt] = [tri[0] as u32, tri[1] as u32, tri[2] as u32];
            nt += 1;
        }
    }
    for (dst, p) in s.positions.iter_mut().zip(pos.iter().take(nv)) {
        *dst = [p.x as f32, p.y as f32, p.z as f32];
    }
    s.instance_id = instance_id;
    s.sequence = sequence;
    s.publish_ns = msgs::clock::monotonic_ns();
    s.sim_time_s = sim.time();
    s.vertex_count = nv as u32;
    s.triangle_count = nt as u32;
}

/// Requests to the material worker.
enum MaterialJob {
    Prepare(f64),
    /// Old parts handed back after a swap: dropped here, not in the real-time loop.
    Retire(Box<MaterialParts>),
}

/// Prepares material changes on its own thread and hands them to the loop, rate-limited.
struct MaterialWorker {
    jobs: std::sync::mpsc::Sender<MaterialJob>,
    done: std::sync::mpsc::Receiver<Result<Box<MaterialParts>, String>>,
    /// A preparation is under way.
    busy: bool,
    /// Newest requested grade not yet started (coalesced).
    pending: Option<f64>,
    /// Grade the loop will have once what is under way is swapped in.
    target: Option<f64>,
    last_start: Option<Instant>,
    coalesced: u64,
}

impl MaterialWorker {
    fn spawn(
        scene: launch_config::SceneConfig,
        data_dir: PathBuf,
    ) -> anyhow::Result<MaterialWorker> {
        let (jobs, job_rx) = std::sync::mpsc::channel::<MaterialJob>();
        let (done_tx, done) = std::sync::mpsc::channel();
        std::thread::Builder::new()
            .name("physics-material".into())
            .spawn(move || {
                for job in job_rx {
                    match job {
                        MaterialJob::Prepare(grade) => {
                            let started = Instant::now();
                            let r = Simulation::prepare_material(&scene, &data_dir, grade)
                                .map(Box::new)
                                .map_err(|e| e.to_string());
                            tracing::info!(
                                grade,
                                seconds = started.elapsed().as_secs_f64(),
                                "material prepared off the step loop"
                            );
                            if done_tx.send(r).is_err() {
                                break;
                            }
                        }
                        MaterialJob::Retire(old) => drop(old),
                    }
                }
            })
            .context("starting the material worker thread")?;
        Ok(MaterialWorker {
            jobs,
            done,
            busy: false,
            pending: None,
            target: None,
            last_start: None,
            coalesced: 0,
        })
    }

    /// A grade command: checked, then queued (replacing any grade not yet started).
    fn request(&mut self, grade: f64, current: f64) {
        if !(grade.is_finite() && (0.0..=2.0).contains(&grade)) {
            tracing::warn!(
                "material command rejected: degeneration grade must be in 0..=2, got {grade}"
            );
            return;
        }
        let effective = self.target.unwrap_or(current);
        if self.pending.is_some() {
            self.coalesced += 1;
        }
        self.pending = (grade != effective).then_some(grade);
    }

    /// Swaps in a finished preparation and starts the pending one when the rate limit allows.
    /// Never blocks.
    fn poll(&mut self, sim: &mut Simulation, interval: Duration) {
        if self.busy {
            match self.done.try_recv() {
                Ok(Ok(parts)) => {
                    self.busy = false;
                    self.target = None;
                    let grade = parts.grade();
                    match sim.swap_material(*parts) {
                        Ok(old) => {
                            tracing::info!(
                                grade,
                                coalesced = self.coalesced,
                                "material swapped in"
                            );
                            let _ = self.jobs.send(MaterialJob::Retire(Box::new(old)));
                        }
                        Err(parts) => {
                            tracing::warn!(
                                grade,
                                "prepared material does not fit the scene; ignored"
                            );
                            let _ = self.jobs.send(MaterialJob::Retire(Box::new(parts)));
                        }
                    }
                }
                Ok(Err(e)) => {
                    self.busy = false;
                    self.target = None;
                    tracing::warn!("material command failed: {e}");
                }
                Err(_) => {}
            }
        }
        if self.busy {
            return;
        }
        let due = self.last_start.is_none_or(|t| t.elapsed() >= interval);
        if let (Some(grade), true) = (self.pending, due) {
            if self.jobs.send(MaterialJob::Prepare(grade)).is_ok() {
                self.pending = None;
                self.target = Some(grade);
                self.busy = true;
                self.last_start = Some(Instant::now());
            }
        }
    }
}
