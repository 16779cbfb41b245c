//! End to end: the `physics-node` binary announces READY, paces its steps in real time,
//! follows a device state published on shared memory into contact, publishes contact frames
//! and the surface, and stops cleanly (exit 0) on SIGTERM.

use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::Topic;
use nalgebra::{UnitQuaternion, Vector3};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn boxed<T: Topic>() -> Box<T> {
    let mut slot = Box::new(core::mem::MaybeUninit::<T>::uninit());
    T::zeroed_in(&mut slot);
    // SAFETY: zeroed_in initialised it (plain old data).
    unsafe { Box::from_raw(Box::into_raw(slot) as *mut T) }
}

#[test]
fn node_follows_device_into_contact_and_stops_on_sigterm() {
    let session = format!("physics-node-test-{}", std::process::id());
    // Where to press: the default scene's mid-body site.
    let scene = launch_config::SceneConfig::default();
    let sim = physics_node::sim::Simulation::new(&scene, &launch_config::data_dir()).unwrap();
    let site = *sim.probing_sites().iter().find(|s| s.region == 2).unwrap();
    drop(sim);
    let n = site.normal.normalize();
    let q = UnitQuaternion::rotation_between(&Vector3::z(), &n).unwrap();
    let out_dir = std::env::temp_dir().join(format!("{session}-out"));

    let mut child = Command::new(env!("CARGO_BIN_EXE_physics-node"))
        .args(["--session", &session, "--out"])
        .arg(&out_dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let ready = rx.recv_timeout(Duration::from_secs(60));
    if !matches!(&ready, Ok(l) if l == "READY physics") {
        let _ = child.kill();
        panic!("no READY line: {ready:?}");
    }

    let node = ipc::create_node("physics-node-test").unwrap();
    let device_pub = ipc::publisher::<DeviceState>(&node, &session).unwrap();
    let frame_sub = ipc::subscriber::<ContactFrame>(&node, &session, Queue::Newest).unwrap();
    let surface_sub = ipc::subscriber::<SurfaceFrame>(&node, &session, Queue::Newest).unwrap();
    let mut frame = boxed::<ContactFrame>();
    let mut surface = boxed::<SurfaceFrame>();
    let r = scene.probe.tip_radius;
    let target = site.point + n * (r - 1.0e-3);
    let start = Instant::now();
    let mut first: Option<(Instant, f64)> = None;
    let mut in_contact = None;
    let mut seq = 0u64;
    // Each frame names its next step start; no later frame may be published before it.
    let mut promised_next_step = 0u64;
    let mut schedule_broken = Vec::new();
    while start.elapsed() < Duration::from_secs(20) {
        seq += 1;
        ipc::send_with(&device_pub, |d| {
            d.sequence = seq;
            d.proxy_pose = physics_node::probe::pose(target, q);
        })
        .unwrap();
        if ipc::take_newest(&frame_sub, &mut frame).unwrap() > 0 {
            first.get_or_insert((Instant::now(), frame.sim_time_s));
            let period_ns = (frame.dt_s * 1e9) as u64;
            if frame.publish_ns < promised_next_step
                || frame.next_step_ns < frame.publish_ns
                || frame.next_step_ns > frame.publish_ns + period_ns
            {
                schedule_broken.push((
                    frame.sequence,
                    promised_next_step,
                    frame.publish_ns,
                    frame.next_step_ns,
                ));
            }
            promised_next_step = frame.next_step_ns;
            if frame.contact_count > 0 && frame.device_sequence_used > 0 && frame.is_valid() {
                in_contact = Some(frame.contact_force);
                if first.unwrap().0.elapsed() > Duration::from_secs(1) {
                    break;
                }
            }
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    let got_surface = ipc::take_newest(&surface_sub, &mut surface).unwrap() > 0;
    // Real-time pacing: simulated time advances like wall time.
    let (t_wall0, t_sim0) = first.expect("no contact frame received");
    let wall = t_wall0.elapsed().as_secs_f64();
    let simulated = frame.sim_time_s - t_sim0;

    // SAFETY: sending SIGTERM to our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("node did not stop on SIGTERM");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    println!("contact force {in_contact:?}, wall {wall:.2} s, simulated {simulated:.2} s, surface {got_surface}");
    assert!(status.success(), "exit status {status:?}");
    assert!(
        schedule_broken.is_empty(),
        "frames outside their announced schedule (sequence, promised, publish, next): {schedule_broken:?}"
    );
    let force = in_contact.expect("the device never drove the probe into contact");
    assert!(Vector3::from(force).dot(&n) > 0.0);
    assert!(got_surface && surface.vertex_count > 0 && surface.triangle_count > 0);
    assert!(
        (simulated - wall).abs() < 0.3 * wall + 0.1,
        "pacing: {simulated} s simulated in {wall} s"
    );
    let csv = std::fs::read_to_string(out_dir.join("contact_force.csv")).unwrap();
    assert!(csv.starts_with(physics_node::sim::ContactForceCsv::HEADER));
    assert!(csv.lines().count() > 50);
}
