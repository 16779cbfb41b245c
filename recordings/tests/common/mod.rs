//! Helpers shared by the recordings integration tests.
#![allow(dead_code)]

use msgs::haptic_to_physics::DeviceState;
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::Topic;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub fn boxed_zeroed<T: Topic>() -> Box<T> {
    let mut slot = Box::new(core::mem::MaybeUninit::<T>::uninit());
    T::zeroed_in(&mut slot);
    // SAFETY: zeroed_in initialised the value (plain old data).
    unsafe { Box::from_raw(Box::into_raw(slot) as *mut T) }
}

/// A fresh directory under the target dir for one test.
pub fn test_dir(name: &str) -> PathBuf {
    let dir =
        PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A session name no other test (or test run) uses.
pub fn unique_session(name: &str) -> String {
    format!(
        "rec-{name}-{}-{}",
        std::process::id(),
        msgs::clock::monotonic_ns() % 1_000_000
    )
}

/// Protocol annotation of device tick `seq` in the synthetic sessions: three probings of
/// 1000 ticks, posterior, mid, anterior.
pub fn annotation(seq: u64) -> (u32, u32, u32) {
    let probing = ((seq - 1) / 1000 + 1) as u32;
    let region = ((probing - 1) % 3) + 1;
    let phase = ((seq / 250) % 4) as u32;
    (region, probing, phase)
}

/// Deterministic synthetic device tick (values chosen to exercise every bit of a double).
pub fn fill_device(d: &mut DeviceState, seq: u64, instance: u64) {
    let t = seq as f64 * 1e-3;
    d.instance_id = instance;
    d.sequence = seq;
    d.publish_ns = msgs::clock::monotonic_ns();
    d.device_kind = 2;
    d.buttons = ((seq / 500) % 2) as u32;
    d.proxy_pose.position = [
        0.01 * (t * 1.3).sin(),
        -0.004 + 1e-17 * seq as f64,
        0.02 - t / 3.0,
    ];
    d.proxy_pose.orientation = [0.0, 0.0, (t * 0.1).sin(), (t * 0.1).cos()];
    d.proxy_velocity = [t.cos() / 7.0, 0.0, -1.0 / 3.0, 0.0, 0.0, 0.1];
    d.joint_angles = [0.1, 0.2, 0.3, t, -t, 1.0 / 3.0];
    d.commanded_force = [0.0, 0.0, t / 9.0];
    d.rendered_force = [0.0, 0.0, (t / 9.0).min(0.88)];
    let (region, probing, phase) = annotation(seq);
    d.region = region;
    d.probing_index = probing;
    d.phase = phase;
}

/// Deterministic synthetic physics step: `contacts` contacts every third step.
pub fn fill_frame(f: &mut ContactFrame, seq: u64, instance: u64, device_seq: u64) {
    let t = seq as f64 * 0.01;
    f.instance_id = instance;
    f.sequence = seq;
    f.publish_ns = msgs::clock::monotonic_ns();
    f.sim_time_s = t;
    f.dt_s = 0.01;
    let contacts = if seq.is_multiple_of(3) { 2 } else { 0 };
    f.contact_count = contacts;
    f.row_count = contacts * 3;
    f.device_sequence_used = device_seq;
    f.proxy_pose.position = [0.001 * t, 0.0, 0.02 - t / 7.0];
    f.proxy_pose.orientation = [0.0, 0.0, 0.0, 1.0];
    f.probe_pose.position = [0.001 * t, 1e-300, 0.02 - t / 7.1];
    f.probe_pose.orientation = [0.0, 0.0, 0.0, 1.0];
    f.probe_free_pose = f.probe_pose;
    f.contact_force = if contacts > 0 {
        [0.1 / 3.0, -t / 11.0, 0.5 + t.sin()]
    } else {
        [0.0; 3]
    };
    f.contact_torque = [0.0, 0.0, f.contact_force[2] * 1e-3];
    for r in 0..(contacts as usize * 3) {
        f.free_violation[r] = -1e-4 * r as f64;
        f.lambda[r] = 1e-3 / (r + 1) as f64;
        f.constraint_directions[r] = [0.0, 0.0, 1.0, 0.0, 0.0, r as f64];
        for c in 0..(contacts as usize * 3) {
            f.compliance[r * msgs::MAX_ROWS + c] = 1e-4 / (1 + r + c) as f64;
        }
    }
}

pub fn fill_surface(s: &mut SurfaceFrame, seq: u64) {
    s.sequence = seq;
    s.publish_ns = msgs::clock::monotonic_ns();
    s.vertex_count = 4;
    s.triangle_count = 2;
    s.positions[..4].copy_from_slice(&[
        [0.0, 0.0, 0.0],
        [0.01, 0.0, 0.0],
        [0.0, 0.01, 0.0],
        [0.01, 0.01, 0.001],
    ]);
    s.triangles[..2].copy_from_slice(&[[0, 1, 2], [1, 3, 2]]);
}

/// Runs tests/py/read_session.py on `file`. None = readers unavailable and not in CI (the
/// caller skips with a note); in CI (CI=true) missing readers fail the test.
pub fn python_read(file: &Path, folder: bool) -> Option<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/read_session.py");
    let mut cmd = Command::new("python3");
    cmd.arg(&script).arg(file);
    if folder {
        cmd.arg("--folder");
    }
    let in_ci = std::env::var("CI").map(|v| v == "true").unwrap_or(false);
    let output = match cmd.output() {
        Ok(o) => o,
        Err(e) => {
            assert!(!in_ci, "CI=true but python3 cannot run: {e}");
            eprintln!("NOTE: skipping Python reader check: python3 unavailable ({e})");
            return None;
        }
    };
    if output.status.code() == Some(3) {
        let why = String::from_utf8_lossy(&output.stderr);
        assert!(!in_ci, "CI=true but Python readers are missing: {why}");
        eprintln!("NOTE: skipping Python reader check ({why}); pip install rosbags mcap mcap-ros2-support");
        return None;
    }
    assert!(
        output.status.success(),
        "read_session.py failed on {}:\n{}",
        file.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    Some(serde_json::from_slice(&output.stdout).expect("read_session.py printed JSON"))
}

/// Both readers (and the folder reader when present) saw exactly these counts.
pub fn assert_python_counts(seen: &serde_json::Value, expected: &[(&str, u64)]) {
    for reader in ["rosbags", "mcap", "rosbags_folder"] {
        let Some(r) = seen.get(reader) else { continue };
        for (topic, count) in expected {
            let got = r["counts"]
                .get(*topic)
                .and_then(|v| v.as_u64())
                .unwrap_or(0);
            assert_eq!(got, *count, "{reader}: {topic}");
        }
    }
}

/// The real `recorder` binary of this crate, started and stopped like the launcher does.
pub struct Recorder {
    pub child: Child,
    pub stdout: BufReader<std::process::ChildStdout>,
}

impl Recorder {
    pub fn start(session: &str, out: &Path) -> Recorder {
        // Cargo names the binary only to this package's own tests; the gap crate's tests
        // (which include this file) build it.
        let exe = option_env!("CARGO_BIN_EXE_recorder")
            .map(PathBuf::from)
            .unwrap_or_else(|| tests::workspace_binary("recordings", "recorder"));
        let mut child = Command::new(exe)
            .args(["--session", session, "--out"])
            .arg(out)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("recorder starts");
        let mut stdout = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            line.clear();
            let n = stdout.read_line(&mut line).unwrap();
            assert!(n > 0, "recorder exited before READY");
            if line.trim() == "READY recorder" {
                break;
            }
            assert!(Instant::now() < deadline, "no READY line");
        }
        Recorder { child, stdout }
    }

    pub fn signal(&self, sig: libc::c_int) {
        // SAFETY: sending a signal to our own child process by its pid.
        unsafe { libc::kill(self.child.id() as libc::pid_t, sig) };
    }

    /// SIGTERM, bounded wait, the RECORDED line as JSON.
    pub fn stop(mut self) -> serde_json::Value {
        self.signal(libc::SIGTERM);
        let deadline = Instant::now() + Duration::from_secs(30);
        let mut stats = None;
        let mut line = String::new();
        while stats.is_none() {
            line.clear();
            if self.stdout.read_line(&mut line).unwrap() == 0 {
                break;
            }
            if let Some(json) = line.trim().strip_prefix("RECORDED ") {
                stats = Some(serde_json::from_str(json).unwrap());
            }
            assert!(Instant::now() < deadline);
        }
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                assert!(status.success(), "recorder exit status {status}");
                break;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                panic!("recorder did not stop within 30 s of SIGTERM");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        stats.expect("RECORDED line")
    }
}
