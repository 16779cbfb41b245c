//! Helpers for end-to-end tests: real processes over real shared memory, bounded timeouts,
//! children killed on every exit path.
#![allow(dead_code)]

use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, IpcNode, IpcSubscriber, Queue};
use msgs::physics_to_haptic::ContactFrame;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

pub const MS: u64 = 1_000_000;

/// A child process killed (SIGKILL) and reaped when dropped.
pub struct Proc {
    pub name: String,
    pub child: Child,
}

impl Proc {
    /// Starts `exe args…` and waits (bounded) for its `READY` line on stdout.
    pub fn start(name: &str, exe: &Path, args: &[&str], ready_timeout: Duration) -> Proc {
        Self::start_with_env(name, exe, args, &[], ready_timeout)
    }

    /// As [`Proc::start`], with extra environment variables.
    pub fn start_with_env(
        name: &str,
        exe: &Path,
        args: &[&str],
        env: &[(&str, String)],
        ready_timeout: Duration,
    ) -> Proc {
        let mut child = Command::new(exe)
            .args(args)
            .envs(env.iter().map(|(k, v)| (*k, v.as_str())))
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", exe.display()));
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if line.starts_with("READY") {
                    let _ = tx.send(());
                }
            }
        });
        let mut p = Proc {
            name: name.into(),
            child,
        };
        if rx.recv_timeout(ready_timeout).is_err() {
            let status = p.child.try_wait().ok().flatten();
            p.kill9();
            panic!("{name} did not print READY within {ready_timeout:?} (exit status {status:?})");
        }
        p
    }

    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM, then wait (bounded); returns the exit code.
    pub fn terminate(&mut self, timeout: Duration) -> Option<i32> {
        // SAFETY: plain kill(2) on our own child.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
        let t0 = Instant::now();
        while t0.elapsed() < timeout {
            if let Ok(Some(s)) = self.child.try_wait() {
                return s.code();
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        self.kill9();
        None
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill9();
    }
}

/// Holds the binary's real-time rig for one test at a time. Tests in one binary run in
/// parallel, and each of these starts a SCHED_FIFO servo loop plus a physics publisher whose
/// timing it then asserts on; on a 2-core CI runner two such rigs starved each other's
/// publisher, the frame went stale mid-window and the node (rightly) ramped the force to zero.
pub fn one_rig_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static RIG: std::sync::Mutex<()> = std::sync::Mutex::new(());
    // A failed test poisons the lock; the next test still owns the rig alone.
    RIG.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

pub fn session(test: &str) -> String {
    format!("hn-{test}-{}", std::process::id())
}

pub fn haptic_exe() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_haptic-node"))
}

pub fn halfspace_exe() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_halfspace-physics"))
}

/// The physics-node binary of this profile, built first if needed.
pub fn physics_exe() -> PathBuf {
    tests::workspace_binary("physics-node", "physics-node")
}

/// What the test saw of a frame (the frame itself is ~80 kB).
#[derive(Debug, Clone, Copy)]
pub struct FrameSeen {
    pub instance: u64,
    pub sequence: u64,
    pub publish_ns: u64,
    pub contact_count: u32,
    pub contact_force: [f64; 3],
    pub proxy: [f64; 3],
}

/// Watches a session's device states (every one) and contact frames.
pub struct Watcher {
    _node: IpcNode,
    states: IpcSubscriber<DeviceState>,
    frames: IpcSubscriber<ContactFrame>,
    pub seen_states: Vec<DeviceState>,
    pub seen_frames: Vec<FrameSeen>,
}

impl Watcher {
    pub fn new(session: &str) -> Watcher {
        let node = ipc::create_node("test-watcher").unwrap();
        let states = ipc::subscriber::<DeviceState>(&node, session, Queue::Every).unwrap();
        let frames = ipc::subscriber::<ContactFrame>(&node, session, Queue::Every).unwrap();
        Watcher {
            _node: node,
            states,
            frames,
            seen_states: Vec::new(),
            seen_frames: Vec::new(),
        }
    }

    pub fn drain(&mut self) {
        let states = &mut self.seen_states;
        ipc::drain_each(&self.states, |s| states.push(*s)).unwrap();
        let frames = &mut self.seen_frames;
        ipc::drain_each(&self.frames, |f| {
            frames.push(FrameSeen {
                instance: f.instance_id,
                sequence: f.sequence,
                publish_ns: f.publish_ns,
                contact_count: f.contact_count,
                contact_force: f.contact_force,
                proxy: f.proxy_pose.position,
            })
        })
        .unwrap();
    }

    /// Drains for `d`.
    pub fn watch(&mut self, d: Duration) {
        let t0 = Instant::now();
        while t0.elapsed() < d {
            self.drain();
            std::thread::sleep(Duration::from_millis(2));
        }
        self.drain();
    }

    /// Drains until `cond` holds on the newest state (bounded).
    pub fn until(&mut self, timeout: Duration, what: &str, cond: impl Fn(&DeviceState) -> bool) {
        let t0 = Instant::now();
        while t0.elapsed() < timeout {
            self.drain();
            if self.seen_states.last().is_some_and(&cond) {
                return;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        panic!(
            "timed out after {timeout:?} waiting for {what}; last state: {:?}",
            self.seen_states.last().map(|s| (
                s.rendered_force,
                s.commanded_force,
                s.faults,
                s.proxy_pose.position
            ))
        );
    }
}

pub fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Writes a replay CSV of (t, position) rows with identity orientation.
pub fn write_trajectory(dir: &Path, name: &str, rows: &[(f64, [f64; 3])]) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let mut text = String::from("t_s,px_m,py_m,pz_m,qx,qy,qz,qw\n");
    for (t, p) in rows {
        text.push_str(&format!("{t},{},{},{},0,0,0,1\n", p[0], p[1], p[2]));
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

pub fn temp_dir(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("haptic-e2e-{test}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

pub const PEAK: f64 = 3.3;
/// Default rate limit 400 N/s at 1 kHz.
pub const MAX_STEP: f64 = 0.4 + 1e-9;

/// Rate limit in newtons per second (`MAX_STEP` per 1 ms tick).
pub const MAX_RATE_N_PER_S: f64 = 400.0;

/// The stale ramp's step: the force lowered along itself (`b` = s·`a`, 0 ≤ s < 1).
fn is_ramp_step(a: [f64; 3], b: [f64; 3]) -> bool {
    let na = norm(a);
    if norm(b) >= na || na == 0.0 {
        return false;
    }
    let s = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (na * na);
    norm([b[0] - s * a[0], b[1] - s * a[1], b[2] - s * a[2]]) <= 1e-9 && s >= -1e-12
}

/// Every rendered force within the clamp; consecutive ticks never step more than the rate
/// limit (except quarantine, which zeroes at once). The stale ramp keeps a wall-time
/// schedule, so on a starved loop (ticks 2 ms apart) it may lower the force by the rate
/// limit over the time between the two ticks.
pub fn assert_rate_limited_and_clamped(w: &Watcher) {
    for pair in w.seen_states.windows(2) {
        let (a, b) = (&pair[0], &pair[1]);
        assert!(norm(b.rendered_force) <= PEAK);
        if b.sequence == a.sequence + 1
            && b.faults
                & (msgs::haptic_to_physics::fault::NONFINITE_DEVICE
                    | msgs::haptic_to_physics::fault::NONFINITE_FORCE)
                == 0
        {
            let d = [
                b.rendered_force[0] - a.rendered_force[0],
                b.rendered_force[1] - a.rendered_force[1],
                b.rendered_force[2] - a.rendered_force[2],
            ];
            let allowed = if is_ramp_step(a.rendered_force, b.rendered_force) {
                let elapsed_s = b.publish_ns.saturating_sub(a.publish_ns) as f64 * 1e-9;
                MAX_STEP.max(MAX_RATE_N_PER_S * elapsed_s + 1e-9)
            } else {
                MAX_STEP
            };
            assert!(
                norm(d) <= allowed,
                "step {} N between ticks {} and {} (allowed {allowed} N)",
                norm(d),
                a.sequence,
                b.sequence
            );
        }
    }
}

/// After a `kill -9` of the physics at `killed_ns`: every tick more than 20 ms after the
/// last frame flags the frame stale, and every tick 10 ms after the first stale one renders
/// zero.
///
/// Each tick is judged at its own time (a state's `publish_ns` is its tick's clock reading),
/// not by when the first such tick came: on a loaded 2-core CI runner the loop itself may be
/// descheduled for milliseconds (CI's run of stop 24 failed this test; here, at idle, the
/// first stale tick once came 22.8 ms after the last frame, past the bound of 22 ms this
/// check used to put on it), and how late ticks come is the servo's period
/// error, which `haptic-bench` measures. What the node controls, and what is asserted here,
/// is that no tick that does run past a deadline renders force it should not.
pub fn check_ramp_after_kill(w: &Watcher, killed_ns: u64) {
    use msgs::haptic_to_physics::fault;
    const STALE_NS: u64 = 20 * MS;
    const RAMP_NS: u64 = 10 * MS;
    let last_frame = w.seen_frames.iter().map(|f| f.publish_ns).max().unwrap();
    assert!(last_frame <= killed_ns);
    let after: Vec<_> = w
        .seen_states
        .iter()
        .filter(|st| st.publish_ns > last_frame)
        .collect();
    // Not vacuous: the watch ran well past the stale limit and the ramp.
    let newest = after.last().expect("ticks after the last frame").publish_ns;
    assert!(
        newest > last_frame + STALE_NS + RAMP_NS + 50 * MS,
        "only {:.1} ms of ticks after the last frame",
        (newest - last_frame) as f64 / 1e6
    );
    for st in &after {
        if st.publish_ns > last_frame + STALE_NS {
            assert!(
                st.faults & fault::STALE_FRAME != 0,
                "tick {} at {:.1} ms after the last frame is not flagged stale",
                st.sequence,
                (st.publish_ns - last_frame) as f64 / 1e6
            );
        }
    }
    let first_stale = after
        .iter()
        .find(|st| st.faults & fault::STALE_FRAME != 0)
        .expect("frame goes stale")
        .publish_ns;
    for st in after
        .iter()
        .filter(|st| st.publish_ns >= first_stale + RAMP_NS)
    {
        assert_eq!(
            st.rendered_force, [0.0; 3],
            "force zero 10 ms after staleness (tick {})",
            st.sequence
        );
    }
    let zero_at = after
        .iter()
        .find(|st| st.publish_ns > killed_ns && st.rendered_force == [0.0; 3])
        .expect("force reaches zero")
        .publish_ns;
    eprintln!(
        "kill → zero {:.1} ms (last frame → stale {:.1} ms, stale → zero {:.1} ms)",
        (zero_at - killed_ns) as f64 / 1e6,
        (first_stale - last_frame) as f64 / 1e6,
        (zero_at - first_stale) as f64 / 1e6
    );
}
