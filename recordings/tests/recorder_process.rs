//! The real `recorder` process, fed over iceoryx2 at full rate (1 kHz device ticks, 100 Hz
//! physics steps) by this test: zero drops on a clean stop, and a `kill -9` leaves a file
//! readable up to its last second that `repair` completes.

mod common;

use common::*;
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc;
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use recordings::channels::*;
use std::time::{Duration, Instant};

// Session topics of the default mapping (`msgs::ros_mapping`), as the recorder names them.
const TOPIC_PROBE_WRENCH: &str = "/arthrosim/probe/wrench";
const TOPIC_MESH: &str = "/arthrosim/meniscus/mesh";
const TOPIC_DIAGNOSTICS: &str = "/diagnostics";

/// Publishes like the haptic and physics nodes for `seconds`: 1 kHz device ticks, 100 Hz
/// steps, 10 Hz stats, 20 Hz surfaces. `on_tick(seq)` may end the run early by returning
/// false. Returns (ticks, steps, stats, surfaces) published.
fn publish(
    session: &str,
    seconds: f64,
    mut on_tick: impl FnMut(u64) -> bool,
) -> (u64, u64, u64, u64) {
    let node = ipc::create_node("rec-test-publisher").unwrap();
    let device_pub = ipc::publisher::<DeviceState>(&node, session).unwrap();
    let frame_pub = ipc::publisher::<ContactFrame>(&node, session).unwrap();
    let stats_pub = ipc::publisher::<HapticStats>(&node, session).unwrap();
    let surface_pub = ipc::publisher::<SurfaceFrame>(&node, session).unwrap();
    let start = Instant::now();
    let (mut ticks, mut steps, mut stats, mut surfaces) = (0u64, 0u64, 0u64, 0u64);
    while start.elapsed().as_secs_f64() < seconds {
        // Catch up to 1 kHz by wall clock (sleep granularity is coarser than 1 ms).
        let due = (start.elapsed().as_secs_f64() * 1000.0) as u64;
        while ticks < due {
            ticks += 1;
            ipc::send_with(&device_pub, |d| fill_device(d, ticks, 5)).unwrap();
            if ticks % 10 == 0 {
                steps += 1;
                ipc::send_with(&frame_pub, |f| fill_frame(f, steps, 6, ticks)).unwrap();
            }
            if ticks % 100 == 0 {
                stats += 1;
                ipc::send_with(&stats_pub, |h| {
                    h.sequence = stats;
                    h.ticks = ticks;
                    h.publish_ns = msgs::clock::monotonic_ns();
                })
                .unwrap();
            }
            if ticks % 50 == 0 {
                surfaces += 1;
                ipc::send_with(&surface_pub, |s| fill_surface(s, surfaces)).unwrap();
            }
            if !on_tick(ticks) {
                return (ticks, steps, stats, surfaces);
            }
        }
        std::thread::sleep(Duration::from_micros(500));
    }
    (ticks, steps, stats, surfaces)
}

fn count(info: &recordings::RecordingInfo, topic: &str) -> u64 {
    info.topics
        .iter()
        .find(|t| t.topic == topic)
        .map(|t| t.count)
        .unwrap_or(0)
}

#[test]
fn recorder_process_records_every_sample_at_full_rate() {
    let dir = test_dir("recorder-full-rate");
    let session = unique_session("full");
    let recorder = Recorder::start(&session, &dir);
    let (ticks, steps, stats, surfaces) = publish(&session, 3.0, |_| true);
    // Let the recorder drain the last samples before stopping it.
    std::thread::sleep(Duration::from_millis(200));
    let rec = recorder.stop();
    assert_eq!(rec["device_states"].as_u64(), Some(ticks), "{rec}");
    assert_eq!(rec["contact_frames"].as_u64(), Some(steps), "{rec}");
    assert_eq!(rec["device_states_dropped"].as_u64(), Some(0), "{rec}");
    assert_eq!(rec["contact_frames_dropped"].as_u64(), Some(0), "{rec}");
    // Every surface is either received or counted missing (its queue is short: a starved
    // recorder loses the oldest, and says so).
    assert_eq!(
        rec["surface_frames"].as_u64().unwrap() + rec["surface_frames_dropped"].as_u64().unwrap(),
        surfaces,
        "{rec}"
    );
    assert!(ticks >= 2500, "publisher too slow: {ticks} ticks in 3 s");

    let file = dir.join("session.mcap");
    let info = recordings::info(&file).unwrap();
    assert!(info.complete, "{info}");
    assert_eq!(count(&info, TOPIC_DEVICE_TICK), ticks);
    assert_eq!(count(&info, TOPIC_CONTACT_STEP), steps);
    assert_eq!(count(&info, TOPIC_PROBE_WRENCH), steps);
    assert_eq!(count(&info, TOPIC_DIAGNOSTICS), stats);
    let mesh = count(&info, TOPIC_MESH);
    assert!(
        mesh >= 1 && mesh <= surfaces,
        "mesh {mesh} of {surfaces} (10 Hz of 20 Hz)"
    );
    let tick = info
        .topics
        .iter()
        .find(|t| t.topic == TOPIC_DEVICE_TICK)
        .unwrap();
    assert_eq!(tick.sequence_missing, Some(0));

    let Some(seen) = python_read(&file, true) else {
        return;
    };
    assert_python_counts(
        &seen,
        &[
            (TOPIC_DEVICE_TICK, ticks),
            (TOPIC_CONTACT_STEP, steps),
            (TOPIC_DIAGNOSTICS, stats),
        ],
    );
    // Values as the publisher wrote them (synthetic, reproducible from the sequence).
    for reader in ["rosbags", "mcap"] {
        for row in seen[reader]["contact_step"].as_array().unwrap() {
            let seq = row[0].as_u64().unwrap();
            let mut f = boxed_zeroed::<ContactFrame>();
            fill_frame(&mut f, seq, 6, seq * 10);
            for k in 0..3 {
                assert_eq!(
                    row[1 + k].as_u64().unwrap(),
                    f.contact_force[k].to_bits(),
                    "{reader} step {seq}"
                );
            }
        }
        for row in seen[reader]["device_tick"].as_array().unwrap() {
            let seq = row[0].as_u64().unwrap();
            let mut d = boxed_zeroed::<DeviceState>();
            fill_device(&mut d, seq, 5);
            assert_eq!(
                row[3].as_u64().unwrap(),
                d.proxy_pose.position[2].to_bits(),
                "{reader} tick {seq}"
            );
            assert_eq!(row[4].as_u64().unwrap() as u32, d.region);
        }
    }
}

#[test]
fn kill_9_leaves_a_file_readable_up_to_its_last_second_and_repair_completes_it() {
    let dir = test_dir("recorder-kill9");
    let session = unique_session("kill9");
    let recorder = Recorder::start(&session, &dir);
    let mut killed_at = 0u64;
    let kill_after = 3000u64;
    let pid = recorder.child.id();
    publish(&session, 10.0, |seq| {
        if seq == kill_after {
            // SAFETY: SIGKILL to our own child.
            unsafe { libc::kill(pid as libc::pid_t, libc::SIGKILL) };
            killed_at = seq;
            return false;
        }
        true
    });
    let mut child = recorder.child;
    let status = child.wait().unwrap();
    assert!(!status.success(), "killed by SIGKILL");
    assert_eq!(killed_at, kill_after);

    let file = dir.join("session.mcap");
    let info = recordings::info(&file).unwrap();
    assert!(
        !info.complete,
        "a killed recorder leaves no summary: {info}"
    );
    let ticks = count(&info, TOPIC_DEVICE_TICK);
    // Flushed at least every 0.5 s: at most ~1 s of ticks may be lost.
    assert!(
        ticks + 1000 >= killed_at && ticks <= killed_at,
        "read {ticks} ticks of {killed_at} published before kill -9\n{info}"
    );
    let tick = info
        .topics
        .iter()
        .find(|t| t.topic == TOPIC_DEVICE_TICK)
        .unwrap();
    assert_eq!(
        tick.sequence_missing,
        Some(0),
        "readable part is contiguous"
    );
    assert!(count(&info, TOPIC_CONTACT_STEP) + 100 >= killed_at / 10);
    assert!(info.attachments.contains(&"scene.toml".to_string()));

    // The study CSV works on the torn file too.
    let export = recordings::export_csv(&file, &dir.join("csv")).unwrap();
    assert_eq!(
        export.files[0].rows as u64,
        count(&info, TOPIC_CONTACT_STEP)
    );

    let repaired = dir.join("repaired.mcap");
    let report = recordings::repair(&file, &repaired).unwrap();
    assert!(report.input_stopped_early.is_some());
    let fixed = recordings::info(&repaired).unwrap();
    assert!(fixed.complete, "{fixed}");
    assert_eq!(count(&fixed, TOPIC_DEVICE_TICK), ticks);
    assert_eq!(fixed.messages, info.messages);
    assert!(fixed.metadata.contains(&"rosbag2".to_string()));

    if let Some(seen) = python_read(&repaired, false) {
        assert_python_counts(&seen, &[(TOPIC_DEVICE_TICK, ticks)]);
        assert_eq!(seen["mcap"]["has_summary"], true);
    }
}
