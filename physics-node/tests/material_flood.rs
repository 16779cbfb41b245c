//! A flood of degeneration-grade commands (0 / 2 alternating, 1 kHz for 6 s) does not stall
//! the physics node: each change is prepared on a worker thread (factorization and compliance
//! cache) and swapped in at a step boundary, at most one per `material_change_interval_s`.
//! Watched like the haptic node does, polling at 1 kHz: the newest frame's age never reaches
//! the stall an inline rebuild causes, its p99 is printed (target: one physics period plus
//! one tick), and changes do get swapped in (the node's log says so).

use msgs::bridge_to_physics::MaterialCommand;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::Topic;
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
fn grade_flood_does_not_stall_the_step_loop() {
    let session = format!("material-flood-{}", std::process::id());
    let dir = std::env::temp_dir().join(&session);
    std::fs::create_dir_all(&dir).unwrap();
    let launch = dir.join("launch.toml");
    std::fs::write(&launch, "[scene]\nmaterial_change_interval_s = 0.5\n").unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_physics-node"))
        .args(["--session", &session, "--launch"])
        .arg(&launch)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let tx2 = tx.clone();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx2.send(line);
        }
    });
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        match rx.recv_timeout(Duration::from_secs(1)) {
            Ok(l) if l == "READY physics" => break,
            _ if Instant::now() > deadline => {
                let _ = child.kill();
                panic!("no READY line");
            }
            _ => {}
        }
    }

    let node = ipc::create_node("material-flood-test").unwrap();
    let device_pub = ipc::publisher::<DeviceState>(&node, &session).unwrap();
    let grade_pub = ipc::publisher::<MaterialCommand>(&node, &session).unwrap();
    let frame_sub = ipc::subscriber::<ContactFrame>(&node, &session, Queue::Newest).unwrap();
    let mut frame = boxed::<ContactFrame>();
    let mut ages_ms = Vec::new();
    let mut dt = 0.0;
    let mut newest_publish = 0u64;
    let start = Instant::now();
    let mut k = 0u64;
    let mut next = Instant::now();
    while start.elapsed() < Duration::from_secs(6) {
        k += 1;
        ipc::send_with(&device_pub, |d| {
            d.instance_id = 99;
            d.sequence = k;
            d.proxy_pose = msgs::Pose {
                position: [0.0, 0.0, 0.05],
                ..msgs::Pose::IDENTITY
            };
        })
        .unwrap();
        ipc::send_copy(
            &grade_pub,
            &MaterialCommand {
                sequence: k,
                publish_ns: msgs::clock::monotonic_ns(),
                // A pseudo-random grade per command: alternating 0/2 at 1 kHz phase-locked
                // with the 100 Hz step loop, which reads the newest command, so in some runs
                // it saw grade 0 at every step and never had a change to make (0 swaps).
                degeneration_grade: [0.0, 1.0, 2.0]
                    [(k.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 62) as usize % 3],
            },
        )
        .unwrap();
        if ipc::take_newest(&frame_sub, &mut frame).unwrap() > 0 {
            newest_publish = frame.publish_ns;
            dt = frame.dt_s;
        }
        // After the first second (start-up), sample the newest frame's age like a tick does.
        if newest_publish > 0 && start.elapsed() > Duration::from_secs(1) {
            let age = msgs::clock::monotonic_ns().saturating_sub(newest_publish);
            ages_ms.push(age as f64 * 1e-6);
        }
        next += Duration::from_millis(1);
        if let Some(wait) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    // SAFETY: SIGTERM to our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let status = child.wait().unwrap();
    let log: Vec<String> = rx.try_iter().collect();
    let swaps = log
        .iter()
        .filter(|l| l.contains("material swapped in"))
        .count();
    assert!(
        status.success(),
        "physics node failed: {status:?}\n{}",
        log.join("\n")
    );
    assert!(!ages_ms.is_empty(), "no frames");
    ages_ms.sort_by(f64::total_cmp);
    let p99 = ages_ms[(ages_ms.len() - 1) * 99 / 100];
    let max = *ages_ms.last().unwrap();
    // The speed target (p99 < period + tick) is reported as one JSON line, not asserted:
    // timing on a shared machine is not a test. What is asserted: no stall of the size an
    // inline rebuild causes (a factorization plus cache fill takes hundreds of ms to seconds).
    println!(
        "{{\"bench\":\"material_flood\",\"commands\":{k},\"swaps\":{swaps},\
         \"frame_age_p99_ms\":{p99:.3},\"frame_age_max_ms\":{max:.3},\
         \"target_ms\":{:.1}}}",
        dt * 1e3 + 1.0
    );
    assert!(
        swaps >= 2,
        "material changes were not swapped in:\n{}",
        log.join("\n")
    );
    assert!(
        max < 20.0 * dt * 1e3,
        "physics stalled under the grade flood: frame age reached {max:.1} ms (p99 {p99:.2} ms)"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
