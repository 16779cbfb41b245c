//! Determinism: drive the physics library with a scripted proxy trajectory (a probing of
//! the meniscus), record it with the recorder's writer, replay the recording through a
//! fresh Simulation, and compare contact forces bit for bit. A replay with a different
//! material must not match (the comparison can fail).

// The recordings crate's test helpers (synthetic ticks and steps, the recorder process).
#[path = "../../recordings/tests/common/mod.rs"]
mod common;

use common::*;
use gap_diagnosis::replay::{replay, ReplayOptions};
use launch_config::{RecordingConfig, SceneConfig};
use msgs::haptic_to_physics::DeviceState;
use physics_node::sim::Simulation;
use recordings::{SessionInfo, SessionWriter};
use std::collections::BTreeMap;

const STEPS: u64 = 120;

/// Proxy pose at step k: above the first probing site, pressing 3 mm into the surface
/// along its normal, holding, then lifting off.
fn proxy_at(site_point: [f64; 3], normal: [f64; 3], k: u64) -> msgs::Pose {
    let t = k as f64 * 0.01;
    // height above the surface along the normal, m
    let h = if t < 0.5 {
        0.004 - 0.014 * t // from +4 mm to −3 mm
    } else if t < 0.8 {
        -0.003
    } else {
        -0.003 + 0.02 * (t - 0.8)
    };
    msgs::Pose {
        position: [
            site_point[0] + normal[0] * h,
            site_point[1] + normal[1] * h,
            site_point[2] + normal[2] * h,
        ],
        orientation: [0.0, 0.0, 0.0, 1.0],
    }
}

/// Records the scripted probing into `dir/session.mcap`; returns the forces per step.
fn record_scripted(dir: &std::path::Path) -> Vec<[f64; 3]> {
    let file = dir.join("session.mcap");
    let scene = SceneConfig::default();
    let data_dir = launch_config::data_dir();
    let mut sim = Simulation::new(&scene, &data_dir).expect("default scene builds");
    sim.set_instance_id(4242);
    let site = sim.probing_sites()[0];
    let point = [site.point.x, site.point.y, site.point.z];
    let normal = [site.normal.x, site.normal.y, site.normal.z];

    let info = SessionInfo {
        session: "determinism".into(),
        launch_path: None,
        launch_text: String::new(),
        scene_toml: toml::to_string(&scene).unwrap(),
        source: "test".into(),
    };
    let mut writer = SessionWriter::create(&file, &RecordingConfig::default(), &info).unwrap();
    let mut device = boxed_zeroed::<DeviceState>();
    let t0 = 1_800_000_000_000_000_000u64;
    let mut recorded = Vec::new();
    let mut contact_steps = 0;
    for k in 1..=STEPS {
        let pose = proxy_at(point, normal, k);
        device.sequence = k;
        device.instance_id = 7;
        device.proxy_pose = pose;
        device.region = site.region;
        device.probing_index = 1;
        writer
            .write_device_state(&device, t0 + k * 10_000_000)
            .unwrap();
        sim.set_device_sequence(k);
        sim.set_proxy_pose(&pose);
        sim.step().unwrap();
        let mut frame = boxed_zeroed::<msgs::physics_to_haptic::ContactFrame>();
        *frame = *sim.contact_frame();
        frame.publish_ns = msgs::clock::monotonic_ns();
        writer
            .write_contact_frame(&frame, t0 + k * 10_000_000)
            .unwrap();
        if frame.contact_count > 0 {
            contact_steps += 1;
        }
        recorded.push(sim.contact_force());
    }
    writer.finish(BTreeMap::new()).unwrap();
    assert!(
        contact_steps > 20,
        "the scripted probing touches the meniscus ({contact_steps} contact steps)"
    );
    assert!(
        recorded.iter().any(|f| f[2].abs() > 1e-3),
        "a contact force develops: {:?}",
        recorded
            .iter()
            .map(|f| f[2])
            .fold(0.0f64, |a, b| a.max(b.abs()))
    );

    recorded
}

#[test]
fn replayed_contact_forces_are_bit_identical_to_the_recording() {
    let dir = test_dir("determinism");
    let file = dir.join("session.mcap");
    let scene = SceneConfig::default();
    let data_dir = launch_config::data_dir();
    let recorded = record_scripted(&dir);

    // Replay: the scene comes from the recording's scene.toml attachment.
    let out = dir.join("replay.mcap");
    let report = replay(
        &file,
        &ReplayOptions {
            out: Some(out.clone()),
            data_dir: Some(data_dir.clone()),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(report.scene_source, "recording");
    assert_eq!(report.steps, STEPS);
    assert!(report.bit_identical(), "{report:#?}");
    assert_eq!(report.max_force_difference_n, 0.0);

    // The replay was written beside the session: the folder's metadata.yaml still
    // describes the session, not the replay.
    let yaml = std::fs::read_to_string(dir.join("metadata.yaml")).unwrap();
    assert!(yaml.contains("- path: \"session.mcap\""), "{yaml}");
    assert!(!yaml.contains("replay.mcap"));

    // The replay's own recording carries the same forces, bit for bit.
    let (steps, ticks) = recordings::export::read_lossless(&out).unwrap();
    assert_eq!(steps.len() as u64, STEPS);
    assert_eq!(ticks.len() as u64, STEPS, "device trajectory re-recorded");
    for (s, f) in steps.iter().zip(&recorded) {
        assert_eq!(
            [
                s.contact_force.x.to_bits(),
                s.contact_force.y.to_bits(),
                s.contact_force.z.to_bits()
            ],
            [f[0].to_bits(), f[1].to_bits(), f[2].to_bits()]
        );
    }

    // A stiffer meniscus gives different forces: the comparison is able to fail.
    let mut stiffer = scene.clone();
    stiffer.material.modulus_scale = 1.5;
    let changed = replay(
        &file,
        &ReplayOptions {
            scene: Some(stiffer),
            data_dir: Some(data_dir),
            ..Default::default()
        },
    )
    .unwrap();
    assert!(!changed.bit_identical());
    assert!(changed.first_mismatch.is_some());
    assert!(changed.max_force_difference_n > 0.0);

    // The device trajectory exports to the haptic node's replay CSV.
    let csv = dir.join("trajectory.csv");
    assert_eq!(
        recordings::export_replay_csv(&file, &csv).unwrap() as u64,
        STEPS
    );
}

/// Replay re-publishes over iceoryx2 (as for a bridge); the real recorder process records
/// the replayed session, and its contact forces equal the original recording's bit for bit.
#[test]
fn replay_republished_through_the_recorder_process_is_bit_identical() {
    let dir = test_dir("determinism-live");
    let recorded = record_scripted(&dir);
    let live_dir = dir.join("live");
    let session = unique_session("replay-live");
    let recorder = Recorder::start(&session, &live_dir);
    let report = replay(
        &dir.join("session.mcap"),
        &ReplayOptions {
            publish_session: Some(session.clone()),
            data_dir: Some(launch_config::data_dir()),
            ..Default::default()
        },
    )
    .unwrap();
    assert!(report.bit_identical(), "{report:#?}");
    std::thread::sleep(std::time::Duration::from_millis(300));
    let stats = recorder.stop();
    assert_eq!(stats["contact_frames_dropped"].as_u64(), Some(0), "{stats}");
    let (steps, ticks) = recordings::export::read_lossless(&live_dir.join("session.mcap")).unwrap();
    assert_eq!(
        steps.len() as u64,
        STEPS,
        "every replayed step went through shared memory"
    );
    assert_eq!(ticks.len() as u64, STEPS, "and every recorded device state");
    for (s, f) in steps.iter().zip(&recorded) {
        assert_eq!(
            [
                s.contact_force.x.to_bits(),
                s.contact_force.y.to_bits(),
                s.contact_force.z.to_bits()
            ],
            [f[0].to_bits(), f[1].to_bits(), f[2].to_bits()],
            "step {}",
            s.sequence
        );
    }
}
