//! End to end, issue 14 point 2: an attacker on the lab network. A real Cyclone DDS peer
//! (Python `cyclonedds`, the DDS under rmw_cyclonedds) in the session's network namespace
//! floods `/arthrosim/probe/target_pose` at ~1 kHz (875 mm away, NaN, a bad quaternion, and
//! in and out ±4 mm around the probe near the tissue) and `material/degeneration_grade`
//! (0 / 2 alternating at 50 Hz) during a bounded `arthrosim run`. From the session's MCAP:
//! - the stylus force never exceeds the Touch's 3.3 N peak (datasheet);
//! - with the default launch file the probe does not follow: every physics step was driven by
//!   the session's own device, and the probe stays near the stylus;
//! - the physics loop is not stalled by the grade flood: the haptic ticks' frame age p99 is
//!   printed (target: one physics period plus one tick) and far from a stall;
//! - with `[bridge] accept_target_pose = true`, out-of-box, malformed and jumping poses are
//!   refused and counted on `/diagnostics`, and the device renders no force from frames whose
//!   probe followed a remote target.
//!
//! Needs root (network namespace) and Python cyclonedds; skipped with a note otherwise, unless
//! CI=true, where it fails.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// 3D Systems Touch datasheet: maximum exertable force at nominal position.
const TOUCH_PEAK_N: f64 = 3.3;
/// Physics period of the default scene (dt) and one haptic tick.
const PHYSICS_PERIOD_S: f64 = 0.01;
const TICK_S: f64 = 0.001;
/// DeviceState fault bit: frame not computed for this device (msgs::haptic_to_physics::fault).
const FOREIGN_FRAME: u32 = 1 << 7;
/// DeviceState fault bit: the frame in use is too old. Once the last own frame is older than
/// `stale_frame_s`, a tick that refuses a remote-driven frame carries this bit as well as
/// FOREIGN_FRAME.
const STALE_FRAME: u32 = 1 << 0;
/// The default `[device] stale_ramp_s`: a refused frame's force is zero this long after the
/// refusal began; 5 ms more for the stand-in clock's tick jitter.
const STALE_RAMP_S: f64 = 0.010 + 0.005;

fn python() -> String {
    std::env::var("PYTHON").unwrap_or_else(|_| "python3".into())
}

fn missing_prerequisite() -> Option<String> {
    let uid = Command::new("id").arg("-u").output().ok()?;
    if String::from_utf8_lossy(&uid.stdout).trim() != "0" {
        return Some("needs root for ip netns".into());
    }
    let ok = |c: &mut Command| {
        c.stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    };
    if !ok(Command::new("ip").args(["netns", "list"])) {
        return Some("`ip netns` not available (install iproute2)".into());
    }
    if !ok(Command::new(python()).args(["-c", "import cyclonedds"])) {
        return Some("Python module cyclonedds missing (pip install cyclonedds==11.0.1)".into());
    }
    None
}

fn prerequisites_or_skip(test: &str) -> bool {
    match missing_prerequisite() {
        None => true,
        Some(why) => {
            if std::env::var("CI").as_deref() == Ok("true") {
                panic!("{test}: {why} (CI=true: this test must run)");
            }
            eprintln!("SKIPPED {test}: {why}");
            false
        }
    }
}

fn ip(args: &[&str]) {
    let out = Command::new("ip").args(args).output().expect("run ip");
    assert!(
        out.status.success(),
        "ip {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A loopback-only namespace (multicast on), deleted on drop.
struct NetNs(String);

impl NetNs {
    fn new(tag: &str) -> NetNs {
        let name = format!("arthro-{tag}-{}", std::process::id());
        let _ = Command::new("ip")
            .args(["netns", "del", &name])
            .stderr(Stdio::null())
            .status();
        ip(&["netns", "add", &name]);
        ip(&["-n", &name, "link", "set", "lo", "up"]);
        ip(&["-n", &name, "link", "set", "lo", "multicast", "on"]);
        ip(&["-n", &name, "route", "add", "224.0.0.0/4", "dev", "lo"]);
        NetNs(name)
    }

    fn command(&self, program: &Path) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.0]).arg(program);
        c
    }
}

impl Drop for NetNs {
    fn drop(&mut self) {
        let _ = Command::new("ip").args(["netns", "del", &self.0]).status();
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// What one flooded session left behind.
struct Flooded {
    out: PathBuf,
    peer: serde_json::Value,
    summary: serde_json::Value,
    context: String,
}

/// Runs `arthrosim run --seconds 14` in a fresh namespace with the flooding peer in it.
fn flooded_session(tag: &str, launch: Option<&str>) -> Flooded {
    let bin = tests::workspace_binary("arthrosim", "arthrosim");
    let ns = NetNs::new(tag);
    let session = format!("{tag}-{}", std::process::id());
    let out = std::env::temp_dir().join(format!("arthrosim-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();

    let mut run = ns.command(&bin);
    run.args(["run", "--seconds", "14", "--plain", "--out"])
        .arg(out.join("session"))
        .args(["--session", &session]);
    if let Some(text) = launch {
        let path = out.join("launch.toml");
        std::fs::write(&path, text).unwrap();
        run.arg(&path);
    }
    let mut child = run
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start arthrosim run");
    let stdout = child.stdout.take().unwrap();
    let stderr = child.stderr.take().unwrap();
    let out_reader =
        std::thread::spawn(move || std::io::read_to_string(stdout).unwrap_or_default());
    let err_reader =
        std::thread::spawn(move || std::io::read_to_string(stderr).unwrap_or_default());

    // The peer floods for most of the session (the run's start-up takes a few seconds; the
    // flood starts at once and keeps going through it).
    let uri = "<CycloneDDS><Domain Id=\"any\"><Discovery><ParticipantIndex>auto</ParticipantIndex>\
               <Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery></Domain></CycloneDDS>";
    let peer = ns
        .command(Path::new(&python()))
        .arg(tests::workspace_root().join("viz-bridge/tests/py/ros_peer.py"))
        .args(["flood", "--seconds", "12", "--grade-hz", "50"])
        .env("CYCLONEDDS_URI", uri)
        .stdin(Stdio::null())
        .output()
        .expect("run the Cyclone peer");

    let deadline = Instant::now() + Duration::from_secs(300);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("arthrosim run did not finish within 300 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    for (pid, _) in tests::processes_of_session(&session) {
        let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
    }
    let context = format!(
        "--- run stdout\n{}\n--- run stderr\n{}\n--- peer stdout\n{}\n--- peer stderr\n{}",
        out_reader.join().unwrap(),
        err_reader.join().unwrap(),
        String::from_utf8_lossy(&peer.stdout),
        String::from_utf8_lossy(&peer.stderr),
    );
    assert!(
        status.success(),
        "arthrosim run failed: {status}\n{context}"
    );
    assert!(peer.status.success(), "Cyclone peer failed\n{context}");
    let line = String::from_utf8_lossy(&peer.stdout)
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .map(str::to_string)
        .unwrap_or_else(|| panic!("no peer result\n{context}"));
    let peer: serde_json::Value = serde_json::from_str(&line).unwrap();
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("session/summary.json"))
            .unwrap_or_else(|e| panic!("summary.json: {e}\n{context}")),
    )
    .unwrap();
    Flooded {
        out,
        peer,
        summary,
        context,
    }
}

/// What the device rendered while it had no frame of its own to render: frames not computed
/// for its own state (the probe driven by a remote target, or not yet by this device), or
/// none recent enough.
#[derive(Debug, Default)]
struct Refusing {
    /// Ticks flagged FOREIGN_FRAME or STALE_FRAME, all of the session.
    ticks: usize,
    /// Of those, flagged FOREIGN_FRAME.
    foreign: usize,
    /// Of those, ticks whose force rose over the previous tick's: must be none.
    rises: usize,
    /// Largest force on a refusing tick past the stale ramp since the refusal began, N: 0.
    after_ramp_max_n: f64,
    /// Largest force on any refusing tick (the ramp from the last own force), N.
    max_n: f64,
}

/// Reads the MCAP; returns (max stylus force, max probe–stylus distance, frame age p99 s,
/// ticks with FOREIGN_FRAME, steps driven by our device / all steps, the refusing ticks).
fn measure(session_dir: &Path, context: &str) -> (f64, f64, f64, usize, (usize, usize), Refusing) {
    let (steps, ticks) = recordings::export::read_lossless(&session_dir.join("session.mcap"))
        .unwrap_or_else(|e| panic!("reading the MCAP: {e}\n{context}"));
    assert!(
        ticks.len() > 5_000,
        "{} device ticks\n{context}",
        ticks.len()
    );
    assert!(
        steps.len() > 500,
        "{} physics steps\n{context}",
        steps.len()
    );
    let norm = |v: &msgs::ros::Vector3| (v.x * v.x + v.y * v.y + v.z * v.z).sqrt();
    let max_force = ticks
        .iter()
        .map(|t| norm(&t.rendered_force))
        .fold(0.0, f64::max);
    // The stylus (device proxy) each physics step was driven by, by tick sequence.
    let by_seq: std::collections::HashMap<(u64, u64), [f64; 3]> = ticks
        .iter()
        .map(|t| {
            let p = &t.proxy_pose.position;
            ((t.instance_id, t.sequence), [p.x, p.y, p.z])
        })
        .collect();
    let instances: std::collections::HashSet<u64> = ticks.iter().map(|t| t.instance_id).collect();
    let mut own = 0;
    let mut max_distance: f64 = 0.0;
    let mut newest_stylus: Option<[f64; 3]> = None;
    let mut first_driven = false;
    let mut tick_i = 0;
    let mut ticks_by_time: Vec<&recordings::channels::DeviceTick> = ticks.iter().collect();
    ticks_by_time.sort_by_key(|t| t.publish_ns);
    for s in &steps {
        // The stylus at the time of the step: newest tick published before the step.
        while tick_i < ticks_by_time.len() && ticks_by_time[tick_i].publish_ns <= s.publish_ns {
            let p = &ticks_by_time[tick_i].proxy_pose.position;
            newest_stylus = Some([p.x, p.y, p.z]);
            tick_i += 1;
        }
        let probe = [
            s.probe_pose.position.x,
            s.probe_pose.position.y,
            s.probe_pose.position.z,
        ];
        let driven = instances
            .iter()
            .any(|&i| by_seq.contains_key(&(i, s.device_sequence_used)));
        if driven {
            own += 1;
            first_driven = true;
        }
        // From the first step a device sample drove on: before it the probe waits at its start
        // pose wherever the stylus is (46 mm from the hand's hover pose at the first step of
        // a default session, with or without a flood).
        if let (true, Some(stylus)) = (first_driven, newest_stylus) {
            max_distance = max_distance.max(distance(probe, stylus));
        }
    }
    let mut ages: Vec<f64> = ticks
        .iter()
        .filter(|t| t.frame_sequence_used > 0)
        .map(|t| t.frame_age_ns as f64 * 1e-9)
        .collect();
    assert!(!ages.is_empty(), "no tick used a frame\n{context}");
    let p99 = percentile(&mut ages, 0.99);
    // From the first tick that rendered an own frame: before it, the physics's opening frames
    // were computed before any device state reached it (used sequence 0) and are refused
    // as not this device's, which is right and not the flood's doing.
    let first_own = ticks
        .iter()
        .position(|t| t.frame_sequence_used > 0 && t.faults & FOREIGN_FRAME == 0)
        .unwrap_or(ticks.len());
    let foreign = ticks[first_own..]
        .iter()
        .filter(|t| t.faults & FOREIGN_FRAME != 0)
        .count();
    // While the probe is not driven by this device, the device renders zero force: from
    // the first refusing tick the force only falls, and is zero once the stale ramp is over.
    // (A refusing tick says FOREIGN_FRAME; once the last own frame is older than the
    // staleness limit it also says STALE_FRAME.)
    let mut refusing = Refusing::default();
    let mut since: Option<u64> = None;
    let mut previous_n = 0.0;
    for t in &ticks_by_time {
        let f = norm(&t.rendered_force);
        if t.faults & (FOREIGN_FRAME | STALE_FRAME) != 0 {
            let start = *since.get_or_insert(t.publish_ns);
            refusing.ticks += 1;
            refusing.foreign += (t.faults & FOREIGN_FRAME != 0) as usize;
            refusing.max_n = refusing.max_n.max(f);
            if f > previous_n + 1e-9 {
                refusing.rises += 1;
            }
            if (t.publish_ns - start) as f64 * 1e-9 > STALE_RAMP_S {
                refusing.after_ramp_max_n = refusing.after_ramp_max_n.max(f);
            }
        } else {
            since = None;
        }
        previous_n = f;
    }
    (
        max_force,
        max_distance,
        p99,
        foreign,
        (own, steps.len()),
        refusing,
    )
}

#[test]
fn dds_flood_neither_moves_the_probe_nor_pushes_the_hand_nor_stalls_physics() {
    if !prerequisites_or_skip("dds flood") {
        return;
    }
    // Default launch file: external targets are refused.
    let f = flooded_session("flood", None);
    let (max_force, max_distance, age_p99, foreign, (own, steps), _) =
        measure(&f.out.join("session"), &f.context);
    let sent = &f.peer["sent"];
    let diag = &f.peer["diagnostics"];
    eprintln!(
        "default session under flood: sent {sent}, max stylus force {max_force:.3} N, \
         max probe–stylus distance {:.2} mm, frame age p99 {:.2} ms, {own}/{steps} steps \
         driven by the device, physics_faults {}, diagnostics {diag}",
        max_distance * 1e3,
        age_p99 * 1e3,
        f.summary["summary"]["physics_faults"]
    );
    assert!(
        sent["far"].as_u64().unwrap() > 500 && sent["grades"].as_u64().unwrap() > 100,
        "the peer did not flood: {sent}\n{}",
        f.context
    );
    assert!(
        diag["targets_refused_disabled"]
            .as_str()
            .and_then(|v| v.parse::<u64>().ok())
            .is_some_and(|n| n > 500),
        "refusals not reported on /diagnostics: {diag}\n{}",
        f.context
    );
    assert!(max_force <= TOUCH_PEAK_N, "stylus force {max_force} N");
    // Pressing 1 mm (the hand sinking a few mm on the anterior horn) keeps the probe within
    // millimetres of the stylus; a probe following the remote targets went 875 mm away.
    assert!(
        max_distance < 0.015,
        "probe {:.1} mm from the stylus\n{}",
        max_distance * 1e3,
        f.context
    );
    assert!(
        own as f64 >= 0.95 * steps as f64,
        "only {own} of {steps} steps driven by the session's device"
    );
    assert_eq!(foreign, 0, "ticks saw frames not computed for the device");
    // The p99 target (one period plus one tick) is a speed figure, printed above and not
    // asserted on a shared machine; a stall of the size an inline rebuild causes (hundreds of
    // ms per command) is.
    assert!(
        age_p99 < 10.0 * (PHYSICS_PERIOD_S + TICK_S),
        "physics stalled under the grade flood: frame age p99 {:.2} ms",
        age_p99 * 1e3
    );
    let _ = std::fs::remove_dir_all(&f.out);

    // Opted in: only bounded targets pass; the rest are refused and counted.
    let f = flooded_session("floodacc", Some("[bridge]\naccept_target_pose = true\n"));
    let (max_force, max_distance, age_p99, foreign, (own, steps), refusing) =
        measure(&f.out.join("session"), &f.context);
    let diag = &f.peer["diagnostics"];
    eprintln!(
        "accepting session under flood: max stylus force {max_force:.3} N, max probe–stylus \
         distance {:.2} mm, frame age p99 {:.2} ms, {own}/{steps} steps driven by the device, \
         {foreign} ticks refused foreign frames, refusing {refusing:?}, diagnostics {diag}",
        max_distance * 1e3,
        age_p99 * 1e3,
    );
    let count = |key: &str| {
        diag[key]
            .as_str()
            .and_then(|v| v.parse::<u64>().ok())
            .unwrap_or_else(|| panic!("{key} missing from /diagnostics: {diag}\n{}", f.context))
    };
    // What arrives depends on how fast the peer and the bridge ran (a starved machine sent
    // ~1,080 per kind and the bridge counted 926 outside the workspace), so the refusals are
    // compared with what the peer sent: most of each kind, and never none.
    let sent = &f.peer["sent"];
    let sent_of = |kinds: &[&str]| {
        kinds
            .iter()
            .map(|k| {
                sent[*k]
                    .as_u64()
                    .unwrap_or_else(|| panic!("{k} not in {sent}"))
            })
            .sum::<u64>()
    };
    let far = sent_of(&["far"]);
    let malformed = sent_of(&["nan", "bad_quaternion"]);
    assert!(
        far > 500 && malformed > 1000,
        "the peer did not flood: {sent}"
    );
    assert!(
        count("targets_refused_outside_workspace") * 2 > far,
        "{diag}, sent {sent}"
    );
    assert!(
        count("targets_refused_malformed") * 2 > malformed,
        "{diag}, sent {sent}"
    );
    assert!(
        count("targets_refused_jump") + count("targets_refused_rate") > 100,
        "{diag}"
    );
    assert_eq!(count("targets_refused_disabled"), 0, "{diag}");
    assert!(max_force <= TOUCH_PEAK_N, "stylus force {max_force} N");
    // Issue 14 point 2: while the probe is driven externally the device renders zero force.
    assert!(
        own < steps && refusing.foreign > 100 && refusing.ticks > 5000,
        "the remote targets never drove the probe ({own}/{steps} own steps, {refusing:?})"
    );
    assert_eq!(
        refusing.rises, 0,
        "force rose on refusing ticks: {refusing:?}"
    );
    assert!(
        refusing.after_ramp_max_n == 0.0,
        "force rendered while the probe was driven externally: {refusing:?}"
    );
    let _ = std::fs::remove_dir_all(&f.out);
}
