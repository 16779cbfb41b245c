//! The haptic node process: ports, device, the 1 kHz loop, statistics, clean stop.

use crate::config::{load_device_config, Limits};
use crate::device::{self, operator, DeviceSample};
use crate::render::{boxed_frame, norm, Renderer, TickOutput};
use crate::servo;
use crate::stats::{LatencyHistogram, LoopStats, TRANSPORT_MAX_NS};
use crate::transport;
use crate::NodeArgs;
use anyhow::Context;
use launch_config::device::{DeviceBackend, SiteSource};
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::{fault, DeviceState};
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// Probing sites for the emulator's operator model, as the `[device.emulated] sites` setting
/// asks: the scene geometry's sites on the `[scene]` meniscus, or a plane.
pub fn resolve_sites(
    config: &launch_config::DeviceConfig,
    launch: Option<&Path>,
) -> anyhow::Result<Vec<operator::Site>> {
    let e = &config.emulated;
    match e.sites {
        SiteSource::Plane => Ok(operator::plane_sites(
            e.plane_height_m,
            e.probings_per_region,
        )),
        SiteSource::Scene => {
            let scene = match launch {
                Some(p) => {
                    launch_config::load(p)
                        .with_context(|| format!("loading launch file {}", p.display()))?
                        .scene
                }
                None => launch_config::SceneConfig::default(),
            };
            let data = launch_config::data_dir();
            let m = scene_geometry::mesh::load_scene_mesh(&scene.meniscus, &data).with_context(
                || {
                    format!(
                        "loading the scene meniscus {:?} for the probing sites",
                        scene.meniscus.mesh
                    )
                },
            )?;
            Ok(m.probing_sites
                .iter()
                .map(|s| operator::Site {
                    point: [s.point.x, s.point.y, s.point.z],
                    normal: [s.normal.x, s.normal.y, s.normal.z],
                    region: s.region,
                })
                .collect())
        }
    }
}

/// SCHED_FIFO priority of the transport probe relative to the servo thread's.
const PROBE_PRIORITY_BELOW_SERVO: i32 = 10;

/// Summary written to `--out DIR/haptic-stats.json` and used by the bench.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Summary {
    pub ticks: u64,
    pub tick_hz: f64,
    pub period_err_p50_us: f64,
    pub period_err_p99_us: f64,
    pub period_err_max_us: f64,
    pub lcp_p50_us: f64,
    pub lcp_p99_us: f64,
    pub lcp_iterations_mean: f64,
    pub frame_age_p50_us: f64,
    pub frame_age_p99_us: f64,
    pub transport_p50_us: f64,
    pub transport_p99_us: f64,
    /// Frames the transport probe recorded (0: no probe).
    pub transport_frames: u64,
    /// Of those, frames already there when the probe's window opened (latency an upper bound).
    pub transport_unwatched: u64,
    /// Whether the probe ran at SCHED_FIFO.
    pub transport_probe_fifo: bool,
    pub overruns: u64,
    pub contact_ticks: u64,
    pub max_rendered_n: f64,
    /// Ticks with a fault other than the clamp or the rate limit.
    pub fault_ticks: u64,
    /// Every fault bit seen (`msgs::fault`), so a count says which faults it holds.
    pub faults_seen: u32,
    pub restarts: u64,
    pub invalid_frames: u64,
    pub realtime: bool,
}

fn fill_stats(
    s: &mut HapticStats,
    st: &LoopStats,
    transport: &LatencyHistogram,
    elapsed_s: f64,
    last_force: [f64; 3],
) {
    s.ticks = st.ticks;
    s.tick_hz = if elapsed_s > 0.0 {
        st.ticks as f64 / elapsed_s
    } else {
        0.0
    };
    s.period_err_p50_us = st.period_error.quantile_us(0.5);
    s.period_err_p99_us = st.period_error.quantile_us(0.99);
    s.period_err_max_us = st.period_error.max_ns() as f64 / 1e3;
    s.lcp_p50_us = st.lcp.quantile_us(0.5);
    s.lcp_p99_us = st.lcp.quantile_us(0.99);
    s.lcp_iterations_mean = if st.lcp_solves > 0 {
        st.lcp_iterations_sum as f64 / st.lcp_solves as f64
    } else {
        0.0
    };
    s.frame_age_p50_us = st.frame_age.quantile_us(0.5);
    s.frame_age_p99_us = st.frame_age.quantile_us(0.99);
    // Not measured (no transport probe): −1.
    let measured = transport.count() > 0;
    s.transport_p50_us = if measured {
        transport.quantile_us(0.5)
    } else {
        -1.0
    };
    s.transport_p99_us = if measured {
        transport.quantile_us(0.99)
    } else {
        -1.0
    };
    s.rendered_force_norm_n = norm(last_force);
    s.fault_count = st.fault_ticks;
    s.faults = st.faults_seen;
}

fn publish_state(
    publisher: &ipc::IpcPublisher<DeviceState>,
    instance: u64,
    sequence: u64,
    now: u64,
    kind: u32,
    sample: &DeviceSample,
    out: &TickOutput,
) -> Result<(), msgs::ipc::LinkError> {
    ipc::send_with(publisher, |s| {
        s.instance_id = instance;
        s.sequence = sequence;
        s.publish_ns = now;
        s.device_kind = kind;
        s.buttons = sample.buttons;
        s.proxy_pose = sample.pose;
        s.proxy_velocity = sample.velocity;
        s.joint_angles = sample.joint_angles;
        s.commanded_force = out.commanded;
        s.rendered_force = out.rendered;
        s.frame_sequence_used = out.frame_sequence;
        s.frame_instance_used = out.frame_instance;
        s.frame_age_ns = out.frame_age_ns;
        s.contact_count = out.contact_count;
        s.faults = out.faults;
        s.lcp_iterations = out.lcp_iterations;
        s.probing_index = sample.probing_index;
        s.region = sample.region;
        s.phase = sample.phase;
    })
}

/// Runs the haptic node until SIGINT/SIGTERM, `--seconds`, or the device's end.
pub fn run(args: NodeArgs) -> anyhow::Result<()> {
    let session = ipc::session_name(args.common.session.as_deref())?;
    let mut config = load_device_config(args.common.launch.as_deref())?;
    if let Some(b) = args.device {
        config.backend = b;
    }
    if let Some(p) = &args.replay {
        config.backend = DeviceBackend::Replay;
        config.replay.path = p.display().to_string();
    }
    if args.no_realtime {
        config.realtime = false;
    }
    let limits = Limits::from_config(&config)?;
    let sites = if config.backend == DeviceBackend::Emulated {
        resolve_sites(&config, args.common.launch.as_deref())?
    } else {
        Vec::new()
    };
    let stop = msgs::lifecycle::install_stop_flag();

    let node = ipc::create_node("haptic")?;
    let frames = ipc::subscriber::<ContactFrame>(&node, &session, Queue::Newest)?;
    let states = ipc::publisher::<DeviceState>(&node, &session)?;
    let stats_pub = ipc::publisher::<HapticStats>(&node, &session)?;

    let start_ns = msgs::clock::monotonic_ns();
    let mut device = device::open(&config, &sites, start_ns)
        .with_context(|| format!("opening the {} device", config.backend))?;
    let kind = device.kind() as u32;
    let instance = msgs::clock::new_instance_id();

    let transport = Arc::new(Mutex::new(LatencyHistogram::new(TRANSPORT_MAX_NS)));
    let probe_counters = Arc::new(transport::ProbeCounters::default());
    let probe_stop = Arc::new(AtomicBool::new(false));
    // Below the servo thread, so the probe never delays a tick.
    let probe_priority = config
        .realtime
        .then_some((config.realtime_priority - PROBE_PRIORITY_BELOW_SERVO).max(1));
    let probe = args.transport_probe.then(|| {
        transport::spawn(
            session.clone(),
            probe_priority,
            probe_stop.clone(),
            transport.clone(),
            probe_counters.clone(),
        )
    });

    let realtime = if config.realtime {
        servo::request_realtime(config.realtime_priority)
    } else {
        tracing::info!("real-time scheduling not requested ([device] realtime = false)");
        servo::Realtime {
            fifo: false,
            locked: false,
        }
    };

    // Everything the loop touches is allocated here.
    let mut renderer = Renderer::new(limits.clone());
    renderer.set_device_instance(instance);
    let mut incoming = boxed_frame();
    let mut sample = DeviceSample::default();
    let mut stats = LoopStats::new();
    let mut transport_snapshot = LatencyHistogram::new(TRANSPORT_MAX_NS);
    let mut stats_msg: Box<HapticStats> = Box::new(HapticStats {
        instance_id: instance,
        sequence: 0,
        publish_ns: 0,
        ticks: 0,
        tick_hz: 0.0,
        period_err_p50_us: 0.0,
        period_err_p99_us: 0.0,
        period_err_max_us: 0.0,
        lcp_p50_us: 0.0,
        lcp_p99_us: 0.0,
        lcp_iterations_mean: 0.0,
        frame_age_p50_us: 0.0,
        frame_age_p99_us: 0.0,
        transport_p50_us: -1.0,
        transport_p99_us: -1.0,
        rendered_force_norm_n: 0.0,
        fault_count: 0,
        faults: 0,
        realtime: (realtime.fifo && realtime.locked) as u32,
    });
    let stats_period_ns = (1e9 / config.stats_rate_hz.max(0.1)) as u64;
    let end_ns = args.seconds.map(|s| start_ns + (s.max(0.0) * 1e9) as u64);
    let period = limits.period_ns;
    let mut logged_link = false;
    let mut logged_device = false;

    msgs::lifecycle::announce_ready("haptic");
    tracing::info!(session, backend = %config.backend, rate_hz = limits.rate_hz, "haptic node running");

    let loop_start = msgs::clock::monotonic_ns();
    let mut next = loop_start + period;
    let mut next_stats = loop_start + stats_period_ns;
    let mut sequence = 0u64;
    let spin_ns = (config.servo_spin_s * 1e9) as u64;
    // Rate over the loop's own ticks (not the shutdown ramp and thread joins after it).
    let mut last_tick_ns: u64;
    loop {
        servo::wait_until(next, spin_ns);
        let now = msgs::clock::monotonic_ns();
        last_tick_ns = now;
        if stop.load(Ordering::SeqCst) {
            break;
        }
        stats.period_error.record(now.saturating_sub(next));
        stats.ticks += 1;
        sequence += 1;

        let device_ok = match device.sample(now, &mut sample) {
            Ok(()) => true,
            Err(e) => {
                if !logged_device {
                    tracing::error!("device error (logged once): {e}");
                    logged_device = true;
                }
                false
            }
        };
        // Ticks up to sequence − 1 have been published: a frame can use no later sample.
        renderer.set_device_sequence(sequence - 1);
        match ipc::take_newest(&frames, &mut incoming) {
            Ok(0) => {}
            Ok(_) => renderer.accept_frame(&mut incoming, now),
            Err(e) => {
                if !logged_link {
                    tracing::warn!("contact frame link (logged once): {e}");
                    logged_link = true;
                }
            }
        }
        let velocity_ok = sample.velocity.iter().all(|v| v.is_finite());
        let mut out = if device_ok {
            renderer.tick(now, &sample.pose, velocity_ok)
        } else {
            // A failing device is treated like a non-finite one: no force.
            let mut o = renderer.tick(
                now,
                &msgs::Pose {
                    position: [f64::NAN; 3],
                    ..msgs::Pose::IDENTITY
                },
                false,
            );
            o.faults |= fault::DEVICE_ERROR;
            o
        };
        if device.command_force(now, out.rendered).is_err() {
            out.faults |= fault::DEVICE_ERROR;
            device.zero_force();
        }
        if let Err(e) = publish_state(&states, instance, sequence, now, kind, &sample, &out) {
            if !logged_link {
                tracing::warn!("device state link (logged once): {e}");
                logged_link = true;
            }
        }

        if out.lcp_ns > 0 {
            stats.lcp.record(out.lcp_ns);
            stats.lcp_iterations_sum += out.lcp_iterations as u64;
            stats.lcp_solves += 1;
        }
        if out.contact_count > 0 {
            stats.contact_ticks += 1;
        }
        stats.max_rendered_n = stats.max_rendered_n.max(norm(out.rendered));
        if renderer.has_frame() && out.faults & fault::STALE_FRAME == 0 {
            stats.frame_age.record(out.frame_age_ns);
        }
        if out.faults != 0 {
            stats.faults_seen |= out.faults;
            if out.faults & !(fault::FORCE_CLAMPED | fault::RATE_LIMITED) != 0 {
                stats.fault_ticks += 1;
            }
        }
        if now >= next_stats {
            next_stats += stats_period_ns;
            if probe.is_some() {
                if let Ok(h) = transport.try_lock() {
                    transport_snapshot.clear();
                    transport_snapshot.merge(&h);
                }
            }
            stats_msg.sequence += 1;
            stats_msg.publish_ns = now;
            fill_stats(
                &mut stats_msg,
                &stats,
                &transport_snapshot,
                (now - loop_start) as f64 * 1e-9,
                renderer.last_force(),
            );
            let _ = ipc::send_copy(&stats_pub, &*stats_msg);
        }

        next += period;
        if next <= now {
            // Overrun: skip the missed deadlines, keep the phase of the grid.
            let missed = (now - next) / period + 1;
            stats.overruns += missed;
            next += missed * period;
        }
        if end_ns.is_some_and(|e| now >= e) || device.finished() {
            break;
        }
    }

    // Clean stop: ramp the force to zero on the servo grid, then zero the device.
    let ramp_ticks = ((limits.stale_ramp_s * limits.rate_hz).ceil() as u64).max(1) + 1;
    for _ in 0..ramp_ticks {
        servo::sleep_until(next);
        let now = msgs::clock::monotonic_ns();
        let _ = device.sample(now, &mut sample);
        // The session is stopping, not the protocol's hold or press: the ramp's ticks say
        // Idle, so a reader of the recording does not take the fade-out for the hand's
        // (a hold's force then ramped 0.45 → 0 N in its last 10 ticks).
        sample.phase = msgs::protocol::Phase::Idle as u32;
        let f = renderer.shutdown_tick(now);
        let _ = device.command_force(now, f);
        sequence += 1;
        let out = TickOutput {
            rendered: f,
            ..TickOutput::default()
        };
        let _ = publish_state(&states, instance, sequence, now, kind, &sample, &out);
        next += period;
    }
    device.zero_force();
    drop(device);
    probe_stop.store(true, Ordering::SeqCst);
    if let Some(p) = probe {
        let _ = p.join();
    }
    let end = msgs::clock::monotonic_ns();
    let transport_final = transport
        .lock()
        .map(|h| h.clone())
        .unwrap_or_else(|_| LatencyHistogram::new(2));
    fill_stats(
        &mut stats_msg,
        &stats,
        &transport_final,
        (last_tick_ns - loop_start) as f64 * 1e-9,
        [0.0; 3],
    );
    stats_msg.sequence += 1;
    stats_msg.publish_ns = end;
    let _ = ipc::send_copy(&stats_pub, &*stats_msg);
    let summary = Summary {
        ticks: stats.ticks,
        tick_hz: stats_msg.tick_hz,
        period_err_p50_us: stats_msg.period_err_p50_us,
        period_err_p99_us: stats_msg.period_err_p99_us,
        period_err_max_us: stats_msg.period_err_max_us,
        lcp_p50_us: stats_msg.lcp_p50_us,
        lcp_p99_us: stats_msg.lcp_p99_us,
        lcp_iterations_mean: stats_msg.lcp_iterations_mean,
        frame_age_p50_us: stats_msg.frame_age_p50_us,
        frame_age_p99_us: stats_msg.frame_age_p99_us,
        transport_p50_us: stats_msg.transport_p50_us,
        transport_p99_us: stats_msg.transport_p99_us,
        transport_frames: probe_counters.frames.load(Ordering::Relaxed),
        transport_unwatched: probe_counters.unwatched.load(Ordering::Relaxed),
        transport_probe_fifo: probe_counters.fifo.load(Ordering::Relaxed),
        overruns: stats.overruns,
        contact_ticks: stats.contact_ticks,
        max_rendered_n: stats.max_rendered_n,
        fault_ticks: stats.fault_ticks,
        faults_seen: stats.faults_seen,
        restarts: renderer.restarts,
        invalid_frames: renderer.invalid_frames,
        realtime: realtime.fifo && realtime.locked,
    };
    tracing::info!(?summary, "haptic node stopped, force zero");
    if let Some(dir) = &args.common.out {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("creating output directory {}", dir.display()))?;
        let path = dir.join("haptic-stats.json");
        std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
