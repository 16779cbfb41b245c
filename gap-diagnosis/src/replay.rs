//! Replay: re-drive the physics from a recording. The physics library
//! (`physics_node::sim::Simulation`) is stepped offline in lockstep with the recorded
//! physics steps: before step k the proxy is set to the pose step k was driven toward
//! (`ContactStep.proxy_pose`), so with the same build and scene the replayed contact forces
//! are bit-identical to the recorded ones. Runs as fast as possible or paced at real time,
//! writes a new recording, and can publish over iceoryx2 so a bridge re-publishes to ROS 2.
//!
//! Limits: the scene comes from the recording's `scene.toml` attachment (or an override);
//! material changes sent during the live session (MaterialCommand) are not in the
//! recording, and a recording that starts after physics step 1 cannot be reproduced
//! exactly (both are reported, not hidden).

use launch_config::{RecordingConfig, SceneConfig};
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc;
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::Topic;
use physics_node::sim::Simulation;
use recordings::channels::*;
use recordings::export::read_lossless;
use recordings::read::{scan, Event};
use recordings::writer::{SessionInfo, SessionWriter, WriteSummary};
use recordings::RecordingError;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How to replay.
#[derive(Debug, Clone, Default)]
pub struct ReplayOptions {
    /// New recording of the replayed session (None: no file).
    pub out: Option<PathBuf>,
    /// Pace steps at the recorded simulation time (false: as fast as possible).
    pub realtime: bool,
    /// Where `study:` meshes are read from (None: `launch_config::data_dir()`).
    pub data_dir: Option<PathBuf>,
    /// Scene override (None: the recording's `scene.toml` attachment).
    pub scene: Option<SceneConfig>,
    /// Publish contact frames, surface frames and the recorded device states on this
    /// iceoryx2 session, so a running viz-bridge re-publishes the replay to ROS 2.
    pub publish_session: Option<String>,
    /// Stop after this many steps.
    pub max_steps: Option<u64>,
    /// Recording settings of the new file (mesh rate, compression, flush interval).
    pub recording: RecordingConfig,
}

/// First step whose replayed force differs from the recorded one.
#[derive(Debug, Clone, Serialize)]
pub struct ForceMismatch {
    pub sequence: u64,
    pub recorded: [f64; 3],
    pub replayed: [f64; 3],
}

#[derive(Debug, Clone, Serialize)]
pub struct ReplayReport {
    pub input: PathBuf,
    pub steps: u64,
    pub recorded_steps: u64,
    /// Steps whose contact force matched bit for bit.
    pub identical_steps: u64,
    pub first_mismatch: Option<ForceMismatch>,
    pub max_force_difference_n: f64,
    /// The recording's first physics step was not step 1 (exact replay impossible).
    pub starts_mid_session: bool,
    /// Steps of other physics instances in the recording (not replayed).
    pub other_instance_steps: u64,
    /// `recording` (scene.toml attachment) or `override`.
    pub scene_source: String,
    pub wall_s: f64,
    pub steps_per_s: f64,
    pub output: Option<WriteSummary>,
}

impl ReplayReport {
    /// Every replayed step reproduced the recorded contact force bit for bit.
    pub fn bit_identical(&self) -> bool {
        self.steps > 0 && self.identical_steps == self.steps && !self.starts_mid_session
    }
}

fn same_bits(a: [f64; 3], b: [f64; 3]) -> bool {
    a.iter()
        .zip(b.iter())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

fn boxed_zeroed<T: Topic>() -> Box<T> {
    let mut slot = Box::new(core::mem::MaybeUninit::<T>::uninit());
    T::zeroed_in(&mut slot);
    // SAFETY: zeroed_in initialised the value (every payload is plain old data).
    unsafe { Box::from_raw(Box::into_raw(slot) as *mut T) }
}

/// The recording's scene attachment, parsed.
pub fn recorded_scene(path: &Path) -> Result<Option<SceneConfig>, RecordingError> {
    let mut text: Option<String> = None;
    scan(path, &mut |event| {
        if let Event::Attachment { name, data, .. } = event {
            if name == ATTACHMENT_SCENE {
                text = Some(String::from_utf8_lossy(data).into_owned());
            }
        }
        Ok(())
    })?;
    match text {
        None => Ok(None),
        Some(t) => {
            toml::from_str::<SceneConfig>(&t)
                .map(Some)
                .map_err(|e| RecordingError::Launch {
                    path: path.to_path_buf(),
                    detail: format!("attachment {ATTACHMENT_SCENE}: {e}"),
                })
        }
    }
}

/// A DeviceState rebuilt from its lossless record (for re-publishing and re-recording).
pub fn device_state_of(t: &DeviceTick, out: &mut DeviceState) {
    out.instance_id = t.instance_id;
    out.sequence = t.sequence;
    out.publish_ns = t.publish_ns;
    out.device_kind = msgs::haptic_to_physics::DeviceKind::Replay as u32;
    out.buttons = t.buttons;
    out.proxy_pose = (&t.proxy_pose).into();
    out.proxy_velocity = t.proxy_velocity;
    out.joint_angles = t.joint_angles;
    out.commanded_force = [
        t.commanded_force.x,
        t.commanded_force.y,
        t.commanded_force.z,
    ];
    out.rendered_force = [t.rendered_force.x, t.rendered_force.y, t.rendered_force.z];
    out.frame_sequence_used = t.frame_sequence_used;
    out.frame_instance_used = t.frame_instance_used;
    out.frame_age_ns = t.frame_age_ns;
    out.contact_count = t.contact_count;
    out.faults = t.faults;
    out.lcp_iterations = t.lcp_iterations;
    out.probing_index = t.probing_index;
    out.region = t.region;
    out.phase = t.phase;
}

/// Replays `path` (see module docs).
pub fn replay(path: &Path, options: &ReplayOptions) -> Result<ReplayReport, RecordingError> {
    let (mut steps, mut ticks) = read_lossless(path)?;
    if steps.is_empty() {
        return Err(RecordingError::MissingTopic {
            path: path.to_path_buf(),
            topic: TOPIC_CONTACT_STEP.into(),
            why: "replay follows the recorded physics steps".into(),
        });
    }
    let (scene, scene_source) = match &options.scene {
        Some(s) => (s.clone(), "override".to_string()),
        None => match recorded_scene(path)? {
            Some(s) => (s, "recording".to_string()),
            None => {
                return Err(RecordingError::MissingTopic {
                    path: path.to_path_buf(),
                    topic: format!("attachment {ATTACHMENT_SCENE}"),
                    why: "replay needs the session's scene (or pass one)".into(),
                })
            }
        },
    };
    // Replay the first physics instance; later instances (a restarted physics node) are
    // counted, not replayed.
    let instance = steps[0].instance_id;
    let total = steps.len() as u64;
    steps.retain(|s| s.instance_id == instance);
    steps.sort_by_key(|s| s.sequence);
    steps.dedup_by_key(|s| s.sequence);
    let other_instance_steps = total - steps.len() as u64;
    let starts_mid_session = steps[0].sequence != 1;
    ticks.sort_by_key(|t| t.sequence);

    let data_dir = options
        .data_dir
        .clone()
        .unwrap_or_else(launch_config::data_dir);
    let physics = |e: physics_node::error::PhysicsError| RecordingError::Physics {
        path: path.to_path_buf(),
        detail: e.to_string(),
    };
    let mut sim = Simulation::new(&scene, &data_dir).map_err(physics)?;
    sim.set_instance_id(instance);

    let mut writer = match &options.out {
        Some(out) => {
            let info = SessionInfo {
                session: options
                    .publish_session
                    .clone()
                    .unwrap_or_else(|| "replay".into()),
                launch_path: None,
                launch_text: String::new(),
                scene_toml: toml::to_string(&scene).unwrap_or_default(),
                source: format!("replay of {}", path.display()),
            };
            Some(SessionWriter::create(out, &options.recording, &info)?)
        }
        None => None,
    };

    // Optional live re-publication (ports on this thread).
    let link = |e: ipc::LinkError| RecordingError::Link {
        path: path.to_path_buf(),
        detail: e.to_string(),
    };
    let ports = match &options.publish_session {
        Some(session) => {
            let node = ipc::create_node(&format!("replay-{}", std::process::id())).map_err(link)?;
            let frames = ipc::publisher::<ContactFrame>(&node, session).map_err(link)?;
            let surfaces = ipc::publisher::<SurfaceFrame>(&node, session).map_err(link)?;
            let devices = ipc::publisher::<DeviceState>(&node, session).map_err(link)?;
            Some((node, frames, surfaces, devices))
        }
        None => None,
    };

    let mut frame = boxed_zeroed::<ContactFrame>();
    let mut surface = boxed_zeroed::<SurfaceFrame>();
    let mut device = boxed_zeroed::<DeviceState>();
    let base_ns = msgs::clock::realtime_ns();
    let started = Instant::now();
    let mut next_tick = 0usize;
    let mut surface_seq = 0u64;
    let mut next_surface_time = 0.0;
    let surface_period_s = if options.recording.mesh_rate_hz > 0.0 {
        1.0 / options.recording.mesh_rate_hz
    } else {
        f64::INFINITY
    };
    let (mut identical, mut replayed) = (0u64, 0u64);
    let mut first_mismatch = None;
    let mut max_diff = 0.0f64;

    for recorded in &steps {
        if options.max_steps.is_some_and(|m| replayed >= m) {
            break;
        }
        // Device ticks up to the one this step consumed, in order.
        while next_tick < ticks.len() && ticks[next_tick].sequence <= recorded.device_sequence_used
        {
            let t = &ticks[next_tick];
            device_state_of(t, &mut device);
            let log_ns = base_ns + (t.publish_ns.saturating_sub(ticks[0].publish_ns));
            if let Some(w) = writer.as_mut() {
                w.write_device_state(&device, log_ns)?;
            }
            if let Some((_, _, _, devices)) = &ports {
                device.publish_ns = msgs::clock::monotonic_ns();
                ipc::send_copy(devices, &*device).map_err(link)?;
            }
            next_tick += 1;
        }

        sim.set_device_sequence(recorded.device_sequence_used);
        sim.set_proxy_pose(&(&recorded.proxy_pose).into());
        let t0 = Instant::now();
        sim.step().map_err(physics)?;
        let step_ns = t0.elapsed().as_nanos() as u64;
        replayed += 1;

        let force = sim.contact_force();
        let recorded_force = [
            recorded.contact_force.x,
            recorded.contact_force.y,
            recorded.contact_force.z,
        ];
        if same_bits(force, recorded_force) && sim.contact_frame().sequence == recorded.sequence {
            identical += 1;
        } else if first_mismatch.is_none() {
            first_mismatch = Some(ForceMismatch {
                sequence: recorded.sequence,
                recorded: recorded_force,
                replayed: force,
            });
        }
        for k in 0..3 {
            let d = (force[k] - recorded_force[k]).abs();
            if d.is_finite() {
                max_diff = max_diff.max(d);
            }
        }

        if options.realtime {
            let due = started + Duration::from_secs_f64(sim.time());
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }

        let log_ns = base_ns + (sim.time() * 1e9) as u64;
        if writer.is_some() || ports.is_some() {
            *frame = *sim.contact_frame();
            frame.step_duration_ns = step_ns;
            frame.publish_ns = msgs::clock::monotonic_ns();
        }
        if let Some(w) = writer.as_mut() {
            w.write_contact_frame(&frame, log_ns)?;
        }
        // The surface at the viewer rate, by simulation time.
        let surface_due =
            (writer.is_some() || ports.is_some()) && sim.time() + 1e-9 >= next_surface_time;
        if surface_due {
            next_surface_time = sim.time() + surface_period_s;
            surface_seq += 1;
            physics_node::node::fill_surface(&sim, &mut surface, instance, surface_seq);
            if let Some(w) = writer.as_mut() {
                w.write_surface(&surface, log_ns)?;
            }
        }
        if let Some((_, frames, surfaces, _)) = &ports {
            ipc::send_copy(frames, &*frame).map_err(link)?;
            if surface_due {
                ipc::send_copy(surfaces, &*surface).map_err(link)?;
            }
        }
        if let Some(w) = writer.as_mut() {
            w.maybe_flush(msgs::clock::monotonic_ns())?;
        }
    }

    let output = match writer {
        Some(w) => {
            let mut extra = std::collections::BTreeMap::new();
            extra.insert("replayed_steps".into(), replayed.to_string());
            extra.insert("identical_steps".into(), identical.to_string());
            Some(w.finish(extra)?)
        }
        None => None,
    };
    let wall_s = started.elapsed().as_secs_f64();
    Ok(ReplayReport {
        input: path.to_path_buf(),
        steps: replayed,
        recorded_steps: total,
        identical_steps: identical,
        first_mismatch,
        max_force_difference_n: max_diff,
        starts_mid_session,
        other_instance_steps,
        scene_source,
        wall_s,
        steps_per_s: if wall_s > 0.0 {
            replayed as f64 / wall_s
        } else {
            0.0
        },
        output,
    })
}
