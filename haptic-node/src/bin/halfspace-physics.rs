//! A stand-in physics process for end-to-end tests of the haptic node: a flat elastic
//! half-space z < height of stiffness k, stepped at a fixed rate with absolute deadlines. It
//! reads the newest device state, and publishes the exact contact frame a physics node would
//! for a point probe at the proxy: one contact (normal +z, tangents x, y), δ_free = z − height,
//! W = 1/(k·dt) on each row (so the force is k·depth), λ and the contact force solved here.
use anyhow::Context;
use clap::Parser;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::{Pose, MAX_ROWS};
use std::sync::atomic::Ordering;

#[derive(Parser)]
#[command(name = "halfspace-physics")]
struct Cli {
    #[arg(long)]
    session: Option<String>,
    /// Half-space stiffness, N/m.
    #[arg(long, default_value_t = 500.0)]
    stiffness: f64,
    /// Surface height, m.
    #[arg(long, default_value_t = 0.0)]
    height: f64,
    /// Step (and publish) period, s.
    #[arg(long, default_value_t = 0.01)]
    dt: f64,
    /// Contact is reported when the proxy is closer than this to the surface, m.
    #[arg(long, default_value_t = 0.003)]
    alarm: f64,
    /// Stop after this many seconds (default: until SIGTERM).
    #[arg(long)]
    seconds: Option<f64>,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    anyhow::ensure!(
        cli.stiffness > 0.0 && cli.dt > 0.0,
        "stiffness and dt must be > 0"
    );
    let session = ipc::session_name(cli.session.as_deref())?;
    let stop = msgs::lifecycle::install_stop_flag();
    let node = ipc::create_node("halfspace-physics")?;
    let frames = ipc::publisher::<ContactFrame>(&node, &session)?;
    let devices = ipc::subscriber::<DeviceState>(&node, &session, Queue::Newest)?;
    let mut device: Box<DeviceState> = {
        use msgs::Topic;
        let mut slot = Box::new(core::mem::MaybeUninit::<DeviceState>::uninit());
        DeviceState::zeroed_in(&mut slot);
        // SAFETY: zeroed_in initialised it.
        unsafe { Box::from_raw(Box::into_raw(slot) as *mut DeviceState) }
    };
    let instance = msgs::clock::new_instance_id();
    let period = (cli.dt * 1e9) as u64;
    let w = 1.0 / (cli.stiffness * cli.dt);
    let start = msgs::clock::monotonic_ns();
    let end = cli.seconds.map(|s| start + (s * 1e9) as u64);
    let mut proxy = Pose {
        position: [0.0, 0.0, cli.height + 0.05],
        ..Pose::IDENTITY
    };
    let (mut used, mut used_instance) = (0u64, 0u64);
    // Below the haptic loop's priority, above everything else (tests run while others build).
    haptic_node::init_tracing();
    haptic_node::servo::request_realtime(70);
    msgs::lifecycle::announce_ready("physics");
    let mut next = start + period;
    let mut sequence = 0u64;
    while !stop.load(Ordering::SeqCst) && end.is_none_or(|e| msgs::clock::monotonic_ns() < e) {
        haptic_node::servo::sleep_until(next);
        next += period;
        if ipc::take_newest(&devices, &mut device).context("reading device state")? > 0
            && device.proxy_pose.is_finite()
        {
            proxy = device.proxy_pose;
            used = device.sequence;
            used_instance = device.instance_id;
        }
        sequence += 1;
        let gap = proxy.position[2] - cli.height;
        let contact = gap < cli.alarm;
        ipc::send_with(&frames, |f| {
            f.instance_id = instance;
            f.sequence = sequence;
            f.sim_time_s = sequence as f64 * cli.dt;
            f.dt_s = cli.dt;
            f.friction_mu = 0.0;
            f.device_sequence_used = used;
            f.device_instance_used = used_instance;
            f.proxy_pose = proxy;
            f.probe_free_pose = proxy;
            f.probe_pose = proxy;
            if contact {
                f.contact_count = 1;
                f.row_count = 3;
                f.contact_points[0] = [proxy.position[0], proxy.position[1], cli.height];
                f.constraint_directions[0] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
                f.constraint_directions[1] = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
                f.constraint_directions[2] = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
                f.free_violation[0] = gap;
                for r in 0..3 {
                    f.compliance[r * MAX_ROWS + r] = w;
                }
                let lambda = (-gap / w).max(0.0);
                f.lambda[0] = lambda;
                f.contact_force = [0.0, 0.0, lambda / cli.dt];
                f.probe_pose.position[2] = proxy.position[2].max(cli.height);
                f.lcp_iterations = 1;
            }
            // Stamped last, right before the send.
            f.publish_ns = msgs::clock::monotonic_ns();
            f.next_step_ns = next.max(f.publish_ns);
            f.publisher_cpu_plus_one = msgs::clock::current_cpu_plus_one();
        })?;
    }
    Ok(())
}
