//! One ROS 2 mapping: a bounded session of the real physics and haptic (emulated Touch) nodes,
//! with the bridge watched by a Cyclone DDS peer (in a network namespace) and the recorder
//! writing the session MCAP. The live capture and the MCAP (read with the reference Python
//! `mcap` + `mcap-ros2-support` reader) are compared topic by topic: types, frame ids, joint
//! names, tf edges, and the whole value of every live message that has a recorded message with
//! the same stamp.
//!
//! Needs root (`ip netns`), Python `cyclonedds`, `mcap`, `mcap_ros2`, and the physics-node,
//! haptic-node and recorder binaries of this profile; skipped with a note otherwise, unless
//! CI=true, where it fails.

mod common;

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::*;
use msgs::ros_mapping::{self, StampClock, Topic, CLOCK_OFFSET_ENV};
use serde_json::Value;

/// Topic keys of the Python side (`ros_normal.TOPICS`), in `Topic::ALL` order.
const KEYS: [(&str, Topic); 9] = [
    ("probe_pose", Topic::ProbePose),
    ("probe_wrench", Topic::ProbeWrench),
    ("device_wrench", Topic::DeviceWrench),
    ("joint_states", Topic::JointStates),
    ("buttons", Topic::Buttons),
    ("mesh", Topic::Mesh),
    ("contacts", Topic::Contacts),
    ("tf", Topic::Tf),
    ("diagnostics", Topic::Diagnostics),
];

/// Topics published for every source sample (or a rate-limited subset of them) and recorded
/// for every one: each live message must have its recorded twin.
const DENSE: [&str; 7] = [
    "probe_pose",
    "probe_wrench",
    "device_wrench",
    "joint_states",
    "mesh",
    "contacts",
    "tf",
];

/// Non-identity fixed frames, so the recorder must take them from the launch file as the
/// bridge does.
const LAUNCH: &str = r#"
[bridge]
meniscus_pose = { position = [0.001, -0.002, 0.003], orientation = [0.0, 0.0, 0.25881904510252074, 0.9659258262890683] }
touch_base_pose = { position = [-0.12, 0.05, -0.02], orientation = [0.0, 0.0, 0.0, 1.0] }
[bridge.streams.mesh]
rate_hz = 5.0
[bridge.streams.contacts]
rate_hz = 50.0

[recording]
# Every surface and contact frame (1 ns apart at least: physics publishes bursts of steps
# when it catches up with real time), so each one the bridge published has its twin.
mesh_rate_hz = 1.0e9
"#;

fn node_exe(name: &str) -> Option<PathBuf> {
    // tests run from target/<profile>/deps; node binaries sit in target/<profile>.
    let exe = std::env::current_exe().ok()?;
    let path = exe.parent()?.parent()?.join(name);
    path.exists().then_some(path)
}

fn mcap_reader_missing() -> Option<String> {
    let ok = Command::new(python())
        .args(["-c", "import mcap, mcap_ros2.decoder"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    (!matches!(ok, Ok(s) if s.success())).then(|| {
        "Python mcap / mcap-ros2-support missing (pip install mcap mcap-ros2-support)".into()
    })
}

fn skip(why: &str) {
    if std::env::var("CI").as_deref() == Ok("true") {
        panic!("live vs recorded: {why} (CI=true: this test must run)");
    }
    eprintln!("SKIPPED live vs recorded: {why}");
}

fn read_json(path: &Path) -> Value {
    let text =
        std::fs::read_to_string(path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("parsing {}: {e}", path.display()))
}

fn messages<'a>(doc: &'a Value, key: &str) -> &'a [Value] {
    doc["messages"][key]
        .as_array()
        .map(Vec::as_slice)
        .unwrap_or(&[])
}

fn strings(v: &Value) -> Vec<String> {
    v.as_array()
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default()
}

fn frames(msgs: &[Value]) -> BTreeSet<String> {
    msgs.iter().flat_map(|m| strings(&m["frames"])).collect()
}

#[test]
fn live_bridge_and_recording_say_the_same() {
    if let Some(why) = missing_prerequisite().or_else(mcap_reader_missing) {
        return skip(&why);
    }
    let (Some(physics), Some(haptic), Some(recorder)) = (
        node_exe("physics-node"),
        node_exe("haptic-node"),
        node_exe("recorder"),
    ) else {
        return skip(
            "node binaries not built (cargo build -p physics-node -p haptic-node -p recordings --bins)",
        );
    };
    let session = session("mapping");
    let dir = temp_dir("mapping");
    let launch = dir.join("launch.toml");
    std::fs::write(&launch, LAUNCH).unwrap();
    let config = launch_config::load(&launch).expect("test launch file");
    let mapping = config.bridge.ros_mapping();
    // What the launcher does: one stamp clock for every node of the session.
    let offset = StampClock::measure().offset_ns().to_string();
    let data = std::env::var("ARTHROSIM_DATA").ok();
    let node = |exe: &Path, extra: &[&str]| {
        let mut c = Command::new(exe);
        c.args(["--session", &session, "--launch"])
            .arg(&launch)
            .args(extra)
            .env(CLOCK_OFFSET_ENV, &offset);
        c
    };

    let ns = NetNs::loopback("map");
    let mut physics_cmd = node(&physics, &[]);
    if let Some(d) = &data {
        physics_cmd.args(["--data", d]);
    }
    let mut physics = Proc::spawn("physics", physics_cmd);
    physics.wait_line("READY physics", Duration::from_secs(120));
    let out = dir.join("rec");
    let mut recorder = Proc::spawn(
        "recorder",
        node(&recorder, &["--out", out.to_str().unwrap()]),
    );
    recorder.wait_line("READY recorder", Duration::from_secs(30));
    let mut bridge_cmd = bridge_command(&ns, &session, Some(&launch));
    bridge_cmd.env(CLOCK_OFFSET_ENV, &offset);
    let mut bridge = Proc::spawn("bridge", bridge_cmd);
    bridge.wait_line("READY bridge", Duration::from_secs(30));

    let live_path = dir.join("live.json");
    let seconds = 6.0;
    let uri = cyclone_uri(&["127.0.0.1"], None);
    let mut peer = Proc::spawn(
        "cyclone",
        peer_command(
            &ns,
            &uri,
            &[
                "capture",
                "--out",
                live_path.to_str().unwrap(),
                "--seconds",
                &format!("{}", seconds + 4.0),
            ],
        ),
    );
    peer.wait_line("READY", Duration::from_secs(30));
    // Let discovery settle so the peer sees the session from its first tick.
    std::thread::sleep(Duration::from_secs(2));
    let mut haptic_cmd = node(
        &haptic,
        &["--no-realtime", "--seconds", &seconds.to_string()],
    );
    if let Some(d) = &data {
        haptic_cmd.env("ARTHROSIM_DATA", d);
    }
    let mut haptic = Proc::spawn("haptic", haptic_cmd);

    let deadline = Instant::now() + Duration::from_secs(90);
    let status = loop {
        if let Some(status) = peer.child.try_wait().unwrap() {
            break status;
        }
        for p in [&mut physics, &mut bridge, &mut recorder] {
            assert!(p.child.try_wait().unwrap().is_none(), "{} exited", p.name);
        }
        assert!(Instant::now() < deadline, "Cyclone peer did not finish");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "Cyclone peer failed");
    let haptic_exit = haptic.stop(Duration::from_secs(10));
    assert!(
        matches!(haptic_exit, Some(s) if s.success()),
        "haptic: {haptic_exit:?}"
    );
    for p in [&mut bridge, &mut recorder, &mut physics] {
        let exit = p.stop(Duration::from_secs(20));
        assert!(
            matches!(exit, Some(s) if s.success()),
            "{} did not stop cleanly: {exit:?}",
            p.name
        );
    }

    let mcap = out.join("session.mcap");
    let recorded_path = dir.join("recorded.json");
    let dump = Command::new(python())
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/dump_mcap.py"))
        .arg(&mcap)
        .arg("--out")
        .arg(&recorded_path)
        .args(["--namespace", &mapping.namespace])
        .status()
        .expect("run dump_mcap.py");
    assert!(dump.success(), "reading {} failed", mcap.display());
    let live = read_json(&live_path);
    let recorded = read_json(&recorded_path);

    compare(&live, &recorded, &mapping);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The topic-by-topic comparison (panics with the first difference).
fn compare(live: &Value, recorded: &Value, mapping: &ros_mapping::Mapping) {
    let world = mapping.world_frame.as_str();
    let mut report = BTreeMap::new();
    for (key, topic) in KEYS {
        let (l, r) = (messages(live, key), messages(recorded, key));
        assert!(!l.is_empty(), "{key}: nothing received live");
        assert!(!r.is_empty(), "{key}: nothing recorded");
        // Types: what the peer subscribed with (so what the bridge offered) and the schema in
        // the MCAP are both the mapping's.
        let want = topic.def().type_name();
        assert_eq!(live["types"][key], want.as_str(), "{key}: live type");
        assert_eq!(
            recorded["types"][key],
            want.as_str(),
            "{key}: recorded type"
        );
        // Frames of every message.
        let expected_frame = match topic {
            Topic::JointStates | Topic::Buttons => ros_mapping::TOUCH_BASE_FRAME,
            _ => world,
        };
        for (side, msgs) in [("live", l), ("recorded", r)] {
            let f = frames(msgs);
            assert_eq!(
                f,
                BTreeSet::from([expected_frame.to_string()]),
                "{key}: {side} frame ids"
            );
        }
        report.insert(key, (l.len(), r.len()));
    }

    // Joint names and tf edges, on both sides, are the mapping's.
    let joints: Vec<String> = ros_mapping::TOUCH_JOINTS.map(String::from).to_vec();
    let edges: Vec<Vec<String>> = mapping
        .tf_edges()
        .iter()
        .map(|(p, c)| vec![p.to_string(), c.to_string()])
        .collect();
    for (side, doc) in [("live", live), ("recorded", recorded)] {
        for m in messages(doc, "joint_states") {
            assert_eq!(strings(&m["joints"]), joints, "{side} joint names");
        }
        for m in messages(doc, "tf") {
            let got: Vec<Vec<String>> =
                m["edges"].as_array().unwrap().iter().map(strings).collect();
            assert_eq!(got, edges, "{side} tf edges");
        }
    }

    // Values: every live message with a recorded twin (same topic, same stamp) is identical.
    let mut matched_counts = BTreeMap::new();
    for (key, _) in KEYS {
        if key == "diagnostics" {
            continue;
        }
        let by_stamp: HashMap<u64, &Value> = messages(recorded, key)
            .iter()
            .map(|m| (m["stamp"].as_u64().unwrap(), m))
            .collect();
        let (first, last) = by_stamp
            .keys()
            .fold((u64::MAX, 0), |(a, b), &s| (a.min(s), b.max(s)));
        let mut matched = 0;
        let mut unmatched = Vec::new();
        for m in messages(live, key) {
            let stamp = m["stamp"].as_u64().unwrap();
            match by_stamp.get(&stamp) {
                Some(rec) => {
                    assert_eq!(
                        m["digest"], rec["digest"],
                        "{key} at stamp {stamp}: live and recorded values differ"
                    );
                    matched += 1;
                }
                None if (first..=last).contains(&stamp) => unmatched.push(stamp),
                None => {}
            }
        }
        assert!(matched > 0, "{key}: no live message has a recorded twin");
        if DENSE.contains(&key) {
            assert!(
                unmatched.is_empty(),
                "{key}: {} live messages inside the recording have no recorded twin (first at \
                 stamp {})",
                unmatched.len(),
                unmatched[0]
            );
        }
        matched_counts.insert(key, matched);
    }

    // Diagnostics: the haptic status of each live array equals the recorded one of the same
    // haptic statistics sample (the array itself also carries the bridge's own statuses and
    // the bridge's publication time).
    let recorded_haptic: HashMap<String, &Value> = messages(recorded, "diagnostics")
        .iter()
        .filter_map(|m| Some((m["haptic_sequence"].as_str()?.to_string(), m)))
        .collect();
    let mut haptic_matched = 0;
    for m in messages(live, "diagnostics") {
        let Some(seq) = m["haptic_sequence"].as_str() else {
            continue;
        };
        if let Some(rec) = recorded_haptic.get(seq) {
            assert_eq!(
                m["haptic_digest"], rec["haptic_digest"],
                "haptic status of statistics sample {seq}: live and recorded differ"
            );
            haptic_matched += 1;
        }
    }
    assert!(
        haptic_matched > 0,
        "no live haptic status has a recorded twin"
    );
    matched_counts.insert("diagnostics", haptic_matched);
    eprintln!("live/recorded messages per topic: {report:?}; matched by stamp: {matched_counts:?}");
}
