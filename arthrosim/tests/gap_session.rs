//! `arthrosim gap` on session recordings: a short session (one probing per region, the real
//! physics, 1 kHz device ticks rendering 0.9 × the model force, saturated at 20 N) written
//! with the recorder's writer, diagnosed through the command line; and the errors a user
//! meets with recordings that cannot be used.

use launch_config::{RecordingConfig, SceneConfig};
use msgs::haptic_to_physics::{fault, DeviceState};
use msgs::Pose;
use physics_node::sim::Simulation;
use recordings::{SessionInfo, SessionWriter};
use std::path::Path;

const PEAK_N: f64 = 20.0;
const SCALE: f64 = 0.9;

mod common;
use common::{arthrosim, text};

fn scratch(name: &str) -> common::Scratch {
    common::scratch("gap", name)
}

fn zeroed_device() -> Box<DeviceState> {
    use msgs::Topic;
    let mut slot = Box::new(core::mem::MaybeUninit::<DeviceState>::uninit());
    DeviceState::zeroed_in(&mut slot);
    // SAFETY: zeroed_in initialised the value (plain old data).
    unsafe { Box::from_raw(Box::into_raw(slot) as *mut DeviceState) }
}

/// One probing per region with the study protocol (approach, press 0.5 mm, hold, release);
/// returns the file and the number of ticks that rendered a force.
fn write_session(file: &Path) -> usize {
    let dt = 0.01;
    let scene = SceneConfig {
        dt,
        ..SceneConfig::default()
    };
    let mut sim = Simulation::new(&scene, Path::new(".")).expect("default scene builds");
    sim.set_instance_id(5);
    let sites: Vec<_> = (1..=3u32)
        .filter_map(|r| sim.probing_sites().iter().find(|s| s.region == r).cloned())
        .collect();
    assert_eq!(sites.len(), 3);
    let mut plan: Vec<(Pose, u32, u32)> = Vec::new();
    for (j, s) in sites.iter().enumerate() {
        let n = [s.normal.x, s.normal.y, s.normal.z];
        let r = scene.probe.tip_radius;
        let at = |h: f64| Pose {
            position: [
                s.point.x + (r + h) * n[0],
                s.point.y + (r + h) * n[1],
                s.point.z + (r + h) * n[2],
            ],
            orientation: [0.0, 0.0, 0.0, 1.0],
        };
        plan.extend((0..10).map(|_| (at(0.02), 0, 0)));
        // 2 mm above → 0.5 mm deep in 1 s, hold 0.5 s, back up in 1 s
        for k in 0..250 {
            let t = k as f64 * dt;
            let h = if t < 1.0 {
                2e-3 - 2.5e-3 * t
            } else if t < 1.5 {
                -0.5e-3
            } else {
                -0.5e-3 + 2.5e-3 * (t - 1.5)
            };
            plan.push((at(h), j as u32 + 1, s.region));
        }
        plan.extend((0..10).map(|_| (at(0.02), 0, 0)));
    }
    let info = SessionInfo {
        session: "cli-gap".into(),
        launch_path: None,
        launch_text: format!("[device]\nforce_scale = {SCALE}\npeak_force_n = {PEAK_N}\n"),
        scene_toml: toml::to_string(&scene).unwrap(),
        source: "test".into(),
    };
    let mut w = SessionWriter::create(file, &RecordingConfig::default(), &info).unwrap();
    let t0 = 1_700_000_000_000_000_000u64;
    let mut last: Option<([f64; 3], u64, u64)> = None;
    let (mut seq, mut rendering) = (0u64, 0usize);
    sim.teleport_probe(&plan[0].0);
    for (k, (pose, probing, region)) in plan.iter().enumerate() {
        for j in 1..=10u64 {
            seq += 1;
            let mut d = zeroed_device();
            d.instance_id = 2;
            d.sequence = seq;
            d.proxy_pose = *pose;
            d.probing_index = *probing;
            d.region = *region;
            if let Some((f, inst, fseq)) = last {
                let c = f.map(|v| v * SCALE);
                let n = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
                d.commanded_force = c;
                d.rendered_force = if n > PEAK_N {
                    d.faults |= fault::FORCE_CLAMPED;
                    c.map(|v| v * PEAK_N / n)
                } else {
                    c
                };
                d.frame_instance_used = inst;
                d.frame_sequence_used = fseq;
                rendering += (n > 1e-3) as usize;
            }
            w.write_device_state(&d, t0 + (k as u64 * 10 + j) * 1_000_000)
                .unwrap();
        }
        sim.set_device_sequence(seq);
        sim.set_probe_kinematic(pose);
        sim.step().unwrap();
        let f = sim.contact_frame();
        w.write_contact_frame(f, t0 + (k as u64 + 1) * 10_000_000)
            .unwrap();
        last = Some((f.contact_force, f.instance_id, f.sequence));
    }
    w.finish(Default::default()).unwrap();
    rendering
}

#[test]
fn gap_diagnoses_a_session_recording_with_its_rendering_gap() {
    let dir = scratch("session");
    let file = dir.join("session.mcap");
    let rendering = write_session(&file);
    assert!(rendering > 100, "the session touches the tissue");
    let out_dir = dir.join("report");
    let out = arthrosim(&[
        "gap",
        file.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--no-pairs",
        "--json",
    ]);
    let all = text(&out);
    assert_eq!(out.status.code(), Some(0), "{all}");
    let verdict: serde_json::Value = serde_json::from_str(
        String::from_utf8_lossy(&out.stdout)
            .trim()
            .lines()
            .last()
            .unwrap(),
    )
    .expect("a JSON verdict line");
    assert!(verdict["effect"].is_string(), "{verdict}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).unwrap())
            .unwrap();
    assert_eq!(report["trials"].as_u64(), Some(3));
    let regions: Vec<&str> = report["trial_reports"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["region"].as_str().unwrap_or("-"))
        .collect();
    assert_eq!(regions, ["posterior", "mid", "anterior"]);
    let g = &report["rendering_gap"];
    assert!(g["contact_ticks"].as_u64().unwrap() > 100, "{g}");
    assert_eq!(g["limits"]["peak_force_n"].as_f64(), Some(PEAK_N));
    let k = g["force_scale_fit_unclamped"].as_f64().unwrap();
    assert!((k - SCALE).abs() < 1e-9, "{k}");
    let html = std::fs::read_to_string(out_dir.join("report.html")).unwrap();
    assert!(html.contains("Rendering gap"));

    // the same recording beside an experiment: only its rendering gap is read, first, so
    // a bad --session fails at once
    let csv = dir.join("trial.csv");
    std::fs::write(&csv, "t_s,fx_N\n").unwrap();
    let out = arthrosim(&[
        "gap",
        dir.join("no-such-experiment").to_str().unwrap(),
        "--session",
        csv.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let all = text(&out);
    assert_eq!(out.status.code(), Some(1), "{all}");
    assert!(
        all.contains("trial.csv") && all.contains("not an MCAP session recording"),
        "{all}"
    );
}

#[test]
fn gap_rejects_unusable_recordings_with_the_file_and_the_problem() {
    let dir = scratch("bad");
    let fake = dir.join("fake.mcap");
    std::fs::write(&fake, b"not a recording").unwrap();
    // a recording without physics steps (the haptic node alone)
    let ticks = dir.join("ticks.mcap");
    let mut w = SessionWriter::create(&ticks, &RecordingConfig::default(), &SessionInfo::default())
        .unwrap();
    for seq in 1..=20u64 {
        let mut d = zeroed_device();
        d.sequence = seq;
        d.proxy_pose.orientation = [0.0, 0.0, 0.0, 1.0];
        w.write_device_state(&d, 1_000_000_000 + seq * 1_000_000)
            .unwrap();
    }
    w.finish(Default::default()).unwrap();
    let two = dir.join("two");
    std::fs::create_dir_all(&two).unwrap();
    std::fs::copy(&ticks, two.join("a.mcap")).unwrap();
    std::fs::copy(&ticks, two.join("b.mcap")).unwrap();
    for (input, expect) in [
        (&fake, "not an MCAP file"),
        (&ticks, "/arthrosim/recording/contact_step"),
        (&two, "a.mcap, b.mcap"),
    ] {
        let name = input.file_name().unwrap().to_str().unwrap().to_string();
        let out = arthrosim(&[
            "gap",
            input.to_str().unwrap(),
            "--out",
            dir.join("r").to_str().unwrap(),
        ]);
        let all = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {all}");
        assert!(all.contains(&name) && all.contains(expect), "{all}");
        assert!(!all.contains("panicked"), "{all}");
    }
}
