//! A synthetic session written with the recorder's writer, read back by `info`, the CSV
//! exports, and two independent Python readers (rosbags, mcap + mcap-ros2-support).

mod common;

use common::*;
use launch_config::RecordingConfig;
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use recordings::channels::*;
use recordings::{SessionInfo, SessionWriter};
use std::collections::BTreeMap;
use std::path::PathBuf;

// The session topics under the default mapping (pinned here: they are the lab's interface).
const TOPIC_PROBE_POSE: &str = "/arthrosim/probe/pose";
const TOPIC_PROBE_WRENCH: &str = "/arthrosim/probe/wrench";
const TOPIC_DEVICE_WRENCH: &str = "/arthrosim/device/wrench";
const TOPIC_JOINT_STATES: &str = "/arthrosim/device/joint_states";
const TOPIC_BUTTONS: &str = "/arthrosim/device/buttons";
const TOPIC_MESH: &str = "/arthrosim/meniscus/mesh";
const TOPIC_CONTACTS: &str = "/arthrosim/contacts";
const TOPIC_TF: &str = "/tf";
const TOPIC_DIAGNOSTICS: &str = "/diagnostics";

#[test]
fn pinned_topic_names_are_the_default_mapping() {
    use msgs::ros_mapping::{Mapping, Topic};
    let m = Mapping::default();
    for (topic, name) in [
        (Topic::ProbePose, TOPIC_PROBE_POSE),
        (Topic::ProbeWrench, TOPIC_PROBE_WRENCH),
        (Topic::DeviceWrench, TOPIC_DEVICE_WRENCH),
        (Topic::JointStates, TOPIC_JOINT_STATES),
        (Topic::Buttons, TOPIC_BUTTONS),
        (Topic::Mesh, TOPIC_MESH),
        (Topic::Contacts, TOPIC_CONTACTS),
        (Topic::Tf, TOPIC_TF),
        (Topic::Diagnostics, TOPIC_DIAGNOSTICS),
    ] {
        assert_eq!(m.topic(topic), name);
    }
}

const TICKS: u64 = 3000;
const STEPS: u64 = 300;
const STATS: u64 = 30;
const SURFACES: u64 = 30;

struct Written {
    file: PathBuf,
    frames: Vec<Box<ContactFrame>>,
    ticks: Vec<DeviceState>,
}

fn write_session(dir: &std::path::Path) -> Written {
    let file = dir.join("session.mcap");
    let info = SessionInfo {
        session: "roundtrip".into(),
        launch_path: Some("lab.toml".into()),
        launch_text: "[session]\nname = \"roundtrip\"\n".into(),
        scene_toml: toml::to_string(&launch_config::SceneConfig::default()).unwrap(),
        source: "test".into(),
    };
    let config = RecordingConfig {
        contact_problem: true,
        ..Default::default()
    };
    let mut w = SessionWriter::create(&file, &config, &info).unwrap();
    let t0 = 1_700_000_000_000_000_000u64;
    let mut frames = Vec::new();
    let mut ticks = Vec::new();
    let mut stats = boxed_zeroed::<HapticStats>();
    let mut surface = boxed_zeroed::<SurfaceFrame>();
    for seq in 1..=TICKS {
        let mut d = boxed_zeroed::<DeviceState>();
        fill_device(&mut d, seq, 77);
        let log = t0 + seq * 1_000_000;
        w.write_device_state(&d, log).unwrap();
        ticks.push(*d);
        if seq % 10 == 0 {
            let step = seq / 10;
            let mut f = boxed_zeroed::<ContactFrame>();
            fill_frame(&mut f, step, 99, seq);
            w.write_contact_frame(&f, log).unwrap();
            frames.push(f);
        }
        if seq % 100 == 0 {
            stats.sequence = seq / 100;
            stats.ticks = seq;
            stats.tick_hz = 1000.0;
            w.write_haptic_stats(&stats, log).unwrap();
            fill_surface(&mut surface, seq / 100);
            assert!(
                w.write_surface(&surface, log).unwrap(),
                "10 Hz surface at 10 Hz mesh rate"
            );
            // A second frame right after is below the viewer rate and skipped.
            assert!(!w.write_surface(&surface, log + 1).unwrap());
        }
        w.maybe_flush(log).unwrap();
    }
    let summary = w.finish(BTreeMap::new()).unwrap();
    assert_eq!(
        summary
            .topics
            .iter()
            .find(|t| t.topic == TOPIC_DEVICE_TICK)
            .unwrap()
            .count,
        TICKS
    );
    Written {
        file,
        frames,
        ticks,
    }
}

#[test]
fn info_export_and_python_readers_agree_with_what_was_written() {
    let dir = test_dir("roundtrip");
    let w = write_session(&dir);

    // info
    let info = recordings::info(&w.file).unwrap();
    assert!(info.complete, "{info}");
    assert_eq!(info.profile, "ros2");
    let count = |topic: &str| {
        info.topics
            .iter()
            .find(|t| t.topic == topic)
            .map(|t| t.count)
            .unwrap_or(0)
    };
    assert_eq!(count(TOPIC_DEVICE_TICK), TICKS);
    assert_eq!(count(TOPIC_CONTACT_STEP), STEPS);
    assert_eq!(count(TOPIC_PROBE_POSE), STEPS);
    assert_eq!(count(TOPIC_PROBE_WRENCH), STEPS);
    assert_eq!(count(TOPIC_TF), STEPS);
    assert_eq!(count(TOPIC_DEVICE_WRENCH), TICKS);
    assert_eq!(count(TOPIC_JOINT_STATES), TICKS);
    assert_eq!(
        count(TOPIC_BUTTONS),
        7,
        "buttons only on change: 0 at 1, then every 500 ticks"
    );
    assert_eq!(count(TOPIC_DIAGNOSTICS), STATS);
    assert_eq!(count(TOPIC_MESH), SURFACES);
    let tick = info
        .topics
        .iter()
        .find(|t| t.topic == TOPIC_DEVICE_TICK)
        .unwrap();
    assert!((tick.rate_hz - 1000.0).abs() < 1e-6, "{}", tick.rate_hz);
    assert_eq!(tick.sequence_missing, Some(0));
    assert!(tick.gaps.is_empty());
    assert!(
        (info.duration_s - 2.999).abs() < 1e-9,
        "{}",
        info.duration_s
    );
    assert!(info.attachments.contains(&"launch.toml".to_string()));
    assert!(info.attachments.contains(&"scene.toml".to_string()));
    assert!(info.metadata.contains(&"rosbag2".to_string()));
    assert_eq!(
        info.session.get("session").map(String::as_str),
        Some("roundtrip")
    );
    let text = info.to_string();
    assert!(
        text.contains(TOPIC_CONTACT_STEP) && text.contains("complete"),
        "{text}"
    );

    // study CSV
    let csv_dir = dir.join("csv");
    let export = recordings::export_csv(&w.file, &csv_dir).unwrap();
    let names: Vec<String> = export
        .files
        .iter()
        .map(|f| f.path.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        [
            "session.csv",
            "region_posterior.csv",
            "region_mid.csv",
            "region_anterior.csv",
            "probing_001_posterior.csv",
            "probing_002_mid.csv",
            "probing_003_anterior.csv"
        ]
    );
    assert_eq!(export.files[0].rows as u64, STEPS);
    assert_eq!(export.unannotated_steps, 0);
    let session_csv = std::fs::read_to_string(&export.files[0].path).unwrap();
    let mut lines = session_csv.lines();
    assert_eq!(lines.next().unwrap(), recordings::export::STUDY_CSV_HEADER);
    for (line, f) in lines.zip(&w.frames) {
        let v: Vec<&str> = line.split(',').collect();
        assert_eq!(
            v[0].parse::<f64>().unwrap().to_bits(),
            f.sim_time_s.to_bits()
        );
        for k in 0..3 {
            assert_eq!(
                v[1 + k].parse::<f64>().unwrap().to_bits(),
                f.contact_force[k].to_bits(),
                "{line}"
            );
        }
        // The synthetic contacts carry impulse along +z: touching, F_n = −f_z.
        assert_eq!(v[4], if f.contact_count > 0 { "1" } else { "0" });
        let f_n = if f.contact_count > 0 {
            -f.contact_force[2]
        } else {
            0.0
        };
        assert_eq!(
            v[5].parse::<f64>().unwrap().to_bits(),
            f_n.to_bits(),
            "{line}"
        );
        assert_eq!(
            v[7].parse::<f64>().unwrap().to_bits(),
            f.probe_pose.position[1].to_bits()
        );
        let (region, probing, phase) = annotation(f.device_sequence_used);
        assert_eq!(
            v[13..16],
            [region.to_string(), probing.to_string(), phase.to_string()]
        );
    }
    for f in &export.files[1..] {
        assert_eq!(f.rows, 100, "{}", f.path.display());
    }

    // replay CSV of the device trajectory
    let replay_csv = dir.join("trajectory.csv");
    assert_eq!(
        recordings::export_replay_csv(&w.file, &replay_csv).unwrap() as u64,
        TICKS
    );
    let text = std::fs::read_to_string(&replay_csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next().unwrap(), "t_s,px_m,py_m,pz_m,qx,qy,qz,qw");
    let first: Vec<f64> = lines
        .next()
        .unwrap()
        .split(',')
        .map(|v| v.parse().unwrap())
        .collect();
    assert_eq!(first[0], 0.0);
    assert_eq!(
        first[1].to_bits(),
        w.ticks[0].proxy_pose.position[0].to_bits()
    );
    assert_eq!(
        first[7].to_bits(),
        w.ticks[0].proxy_pose.orientation[3].to_bits()
    );

    // Two independent Python readers, and rosbags on the rosbag2 folder (metadata.yaml).
    assert!(dir.join("metadata.yaml").exists());
    let Some(seen) = python_read(&w.file, true) else {
        return;
    };
    assert_python_counts(
        &seen,
        &[
            (TOPIC_DEVICE_TICK, TICKS),
            (TOPIC_CONTACT_STEP, STEPS),
            (TOPIC_PROBE_WRENCH, STEPS),
            (TOPIC_PROBE_POSE, STEPS),
            (TOPIC_JOINT_STATES, TICKS),
            (TOPIC_DEVICE_WRENCH, TICKS),
            (TOPIC_MESH, SURFACES),
            (TOPIC_DIAGNOSTICS, STATS),
            (TOPIC_TF, STEPS),
            (TOPIC_BUTTONS, 7),
        ],
    );
    for reader in ["rosbags", "mcap"] {
        let r = &seen[reader];
        let steps = r["contact_step"].as_array().unwrap();
        for (row, f) in steps.iter().zip(&w.frames) {
            assert_eq!(row[0].as_u64().unwrap(), f.sequence);
            for k in 0..3 {
                assert_eq!(
                    row[1 + k].as_u64().unwrap(),
                    f.contact_force[k].to_bits(),
                    "{reader}"
                );
            }
            assert_eq!(row[4].as_u64().unwrap(), f.contact_count as u64);
            assert_eq!(
                row[8].as_u64().unwrap(),
                (f.row_count * f.row_count) as u64,
                "W is rows²"
            );
        }
        let ticks = r["device_tick"].as_array().unwrap();
        for (row, d) in ticks.iter().zip(&w.ticks) {
            assert_eq!(row[0].as_u64().unwrap(), d.sequence);
            for k in 0..3 {
                assert_eq!(
                    row[1 + k].as_u64().unwrap(),
                    d.proxy_pose.position[k].to_bits(),
                    "{reader}"
                );
            }
            assert_eq!(
                (
                    row[4].as_u64().unwrap() as u32,
                    row[5].as_u64().unwrap() as u32,
                    row[6].as_u64().unwrap() as u32
                ),
                (d.region, d.probing_index, d.phase)
            );
            assert_eq!(row[7].as_u64().unwrap(), d.proxy_velocity[0].to_bits());
        }
        let wrench = r["probe_wrench"].as_array().unwrap();
        assert_eq!(
            wrench[2][2].as_u64().unwrap(),
            w.frames[2].contact_force[2].to_bits()
        );
        assert_eq!(r["joint_positions_first"].as_array().unwrap().len(), 6);
        assert_eq!(r["mesh_points_first"].as_u64(), Some(6), "two triangles");
        assert_eq!(
            r["tf_children"],
            serde_json::json!(["meniscus", "probe", "proxy", "touch_base"])
        );
        assert_eq!(r["diagnostics_keys"][1], "tick_hz");
        assert_eq!(
            r["joint_names"],
            serde_json::json!(msgs::ros_mapping::TOUCH_JOINTS)
        );
        assert_eq!(
            r["types"][TOPIC_CONTACT_STEP],
            "arthrosim_msgs/msg/ContactStep"
        );
    }
    let m = &seen["mcap"];
    assert_eq!(m["profile"], "ros2");
    assert_eq!(m["qos"][TOPIC_TF], OFFERED_QOS_PROFILES);
    assert!(m["metadata_names"]
        .as_array()
        .unwrap()
        .contains(&serde_json::json!("rosbag2")));
    assert_eq!(
        m["attachment_names"],
        serde_json::json!(["launch.toml", "scene.toml"])
    );
}
