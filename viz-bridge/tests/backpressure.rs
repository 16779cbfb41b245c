//! When the DDS side cannot keep up, the shared-memory side drops and counts instead of
//! waiting: a burst of 64 physics frames into a queue of depth 2 must be handled in one
//! `step` with every sample either queued or counted as dropped, and everything queued must
//! then be written. Runs the bridge in-process on a thread that entered a loopback-only
//! network namespace (the DDS threads it starts inherit it).

mod common;

use std::os::fd::AsRawFd;

use common::*;
use launch_config::BridgeConfig;
use msgs::ipc;
use msgs::physics_to_haptic::ContactFrame;
use msgs::ros_mapping::Topic;
use viz_bridge::stats::BridgeStats;
use viz_bridge::Bridge;

#[test]
fn a_full_queue_drops_and_counts_and_never_waits() {
    if !prerequisites_or_skip("backpressure") {
        return;
    }
    let ns = NetNs::loopback("bp");
    let ns_path = format!("/run/netns/{}", ns.name);
    let session = session("bp");
    let worker = std::thread::spawn(move || {
        let netns = std::fs::File::open(&ns_path).unwrap();
        // SAFETY: setns on this thread only, with a valid namespace fd.
        assert_eq!(
            unsafe { libc::setns(netns.as_raw_fd(), libc::CLONE_NEWNET) },
            0
        );

        let config = BridgeConfig {
            queue_depth: 2,
            ..Default::default()
        };
        let mut bridge = Bridge::new(config, &session).unwrap();
        bridge.start().unwrap();
        let stats = bridge.stats();

        let node = ipc::create_node("bridge-test-burst").unwrap();
        let frames = ipc::publisher::<ContactFrame>(&node, &session).unwrap();
        const BURST: u64 = 64;
        for seq in 1..=BURST {
            ipc::send_with(&frames, |f| {
                f.sequence = seq;
                f.publish_ns = msgs::clock::monotonic_ns();
                f.dt_s = 0.01;
                f.probe_pose = msgs::Pose::IDENTITY;
                f.contact_force = [0.0, 0.0, seq as f64];
            })
            .unwrap();
        }
        let handled = bridge.step().unwrap();
        assert_eq!(
            handled as u64, BURST,
            "every queued frame is handled in one step"
        );
        assert_eq!(BridgeStats::get(&stats.contact_frames), BURST);

        let pose = stats.stream(Topic::ProbePose);
        let wrench = stats.stream(Topic::ProbeWrench);
        let mut dropped = 0;
        for c in [pose, wrench] {
            let queued = BridgeStats::get(&c.enqueued);
            let lost = BridgeStats::get(&c.dropped_queue);
            assert_eq!(queued + lost, BURST, "each sample queued or counted");
            dropped += lost;
        }
        assert!(
            dropped > 0,
            "a depth-2 queue cannot take a 128-message burst"
        );

        // What was queued is written (no subscriber is needed for a write to succeed).
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
        while BridgeStats::get(&pose.published) < BridgeStats::get(&pose.enqueued)
            && std::time::Instant::now() < deadline
        {
            bridge.step().unwrap();
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        assert_eq!(
            BridgeStats::get(&pose.published),
            BridgeStats::get(&pose.enqueued)
        );
        bridge.stop();
    });
    let result = worker.join();
    drop(ns);
    if let Err(panic) = result {
        std::panic::resume_unwind(panic);
    }
}
