//! Test harness for the DDS interop tests: network namespaces that are removed on every path,
//! child processes that are stopped on every path, the Cyclone DDS peer, and a feeder that
//! plays physics and haptic over iceoryx2 with known values.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};

use msgs::bridge_to_physics::{MaterialCommand, ProbeTarget};
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, IpcNode, IpcPublisher, IpcSubscriber, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::Pose;

pub fn python() -> String {
    std::env::var("PYTHON").unwrap_or_else(|_| "python3".into())
}

pub fn peer_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/py/ros_peer.py")
}

/// Why the DDS tests cannot run here, if they cannot: not root, no `ip netns`, or no
/// cyclonedds for Python.
pub fn missing_prerequisite() -> Option<String> {
    // SAFETY: plain libc call without arguments.
    if unsafe { libc::geteuid() } != 0 {
        return Some("needs root for ip netns".into());
    }
    let ip = Command::new("ip")
        .args(["netns", "list"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    if !matches!(ip, Ok(s) if s.success()) {
        return Some("`ip netns` not available (install iproute2)".into());
    }
    let py = Command::new(python())
        .args(["-c", "import cyclonedds"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status();
    if !matches!(py, Ok(s) if s.success()) {
        return Some("Python module cyclonedds missing (pip install cyclonedds==11.0.1)".into());
    }
    None
}

/// Returns false (after a note) when the test must be skipped; panics under CI=true.
pub fn prerequisites_or_skip(test: &str) -> bool {
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

/// A network namespace, deleted on drop (also when the test panics).
pub struct NetNs {
    pub name: String,
}

impl NetNs {
    /// A namespace with only loopback, up and multicast-capable (DDS discovery stays inside).
    pub fn loopback(tag: &str) -> NetNs {
        let ns = NetNs::bare(tag);
        ip(&["-n", &ns.name, "link", "set", "lo", "up"]);
        ip(&["-n", &ns.name, "link", "set", "lo", "multicast", "on"]);
        ip(&["-n", &ns.name, "route", "add", "224.0.0.0/4", "dev", "lo"]);
        ns
    }

    pub fn bare(tag: &str) -> NetNs {
        let name = format!("arthro-{tag}-{}", std::process::id());
        let _ = Command::new("ip")
            .args(["netns", "del", &name])
            .stderr(Stdio::null())
            .status();
        ip(&["netns", "add", &name]);
        NetNs { name }
    }

    /// `ip netns exec NS program args…`
    pub fn command(&self, program: &str) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.name, program]);
        c
    }
}

impl Drop for NetNs {
    fn drop(&mut self) {
        let _ = Command::new("ip")
            .args(["netns", "del", &self.name])
            .status();
    }
}

/// Two namespaces joined by a veth pair: `a` has `10.200.<net>.1`, `b` has `10.200.<net>.2`.
pub fn veth_pair(tag: &str, net: u8) -> (NetNs, NetNs) {
    let a = NetNs::bare(&format!("{tag}a"));
    let b = NetNs::bare(&format!("{tag}b"));
    let (va, vb) = (
        format!("va{}", std::process::id() % 100000),
        format!("vb{}", std::process::id() % 100000),
    );
    ip(&[
        "link", "add", &va, "netns", &a.name, "type", "veth", "peer", "name", &vb, "netns", &b.name,
    ]);
    for (ns, dev, host) in [(&a, &va, 1), (&b, &vb, 2)] {
        ip(&["-n", &ns.name, "link", "set", "lo", "up"]);
        ip(&[
            "-n",
            &ns.name,
            "addr",
            "add",
            &format!("10.200.{net}.{host}/24"),
            "dev",
            dev,
        ]);
        ip(&["-n", &ns.name, "link", "set", dev, "up"]);
        ip(&["-n", &ns.name, "route", "add", "224.0.0.0/4", "dev", dev]);
    }
    (a, b)
}

/// Cyclone configuration: explicit unicast peers make discovery robust in either start order;
/// no peers leaves multicast discovery only.
pub fn cyclone_uri(peers: &[&str], interface: Option<&str>) -> String {
    let peers: String = peers
        .iter()
        .map(|p| format!("<Peer address=\"{p}\"/>"))
        .collect();
    // No peers: multicast discovery only.
    let peers = if peers.is_empty() {
        String::new()
    } else {
        format!("<Peers>{peers}</Peers>")
    };
    let iface = interface
        .map(|i| {
            format!("<General><Interfaces><NetworkInterface name=\"{i}\"/></Interfaces></General>")
        })
        .unwrap_or_default();
    format!(
        "<CycloneDDS><Domain Id=\"any\">{iface}<Discovery><ParticipantIndex>auto</ParticipantIndex>\
         {peers}</Discovery></Domain></CycloneDDS>"
    )
}

/// A child process whose stdout lines arrive on a channel; stopped (SIGTERM, then SIGKILL)
/// on drop.
pub struct Proc {
    pub name: String,
    pub child: Child,
    pub lines: Receiver<String>,
}

impl Proc {
    pub fn spawn(name: &str, mut cmd: Command) -> Proc {
        cmd.stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .stdin(Stdio::null());
        let mut child = cmd.spawn().unwrap_or_else(|e| panic!("spawn {name}: {e}"));
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = channel();
        let tag = name.to_string();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                eprintln!("[{tag}] {line}");
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Proc {
            name: name.into(),
            child,
            lines: rx,
        }
    }

    /// Waits for a line that starts with `prefix`; panics after `timeout`.
    pub fn wait_line(&self, prefix: &str, timeout: Duration) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) if line.starts_with(prefix) => return line,
                Ok(_) => {}
                Err(_) => panic!(
                    "{}: no line starting with {prefix:?} within {timeout:?}",
                    self.name
                ),
            }
        }
    }

    pub fn signal(&self, sig: libc::c_int) {
        // SAFETY: signalling our own child by pid.
        unsafe { libc::kill(self.child.id() as libc::pid_t, sig) };
    }

    /// SIGTERM and wait up to `timeout`, then SIGKILL.
    pub fn stop(&mut self, timeout: Duration) -> Option<ExitStatus> {
        if let Ok(Some(status)) = self.child.try_wait() {
            return Some(status);
        }
        self.signal(libc::SIGTERM);
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
        None
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.stop(Duration::from_secs(3));
    }
}

/// The values the feeder publishes, and what the peer must therefore receive.
pub struct Scenario {
    pub probe_pose: Pose,
    pub contact_force: [f64; 3],
    pub contact_torque: [f64; 3],
    pub contact_points: Vec<[f64; 3]>,
    pub rendered_force: [f64; 3],
    pub joint_angles: [f64; 6],
    pub buttons: u32,
    pub surface_positions: Vec<[f32; 3]>,
    pub surface_triangles: Vec<[u32; 3]>,
    pub target_pose: Pose,
    pub degeneration_grade: f64,
}

impl Scenario {
    pub fn standard() -> Scenario {
        Scenario {
            probe_pose: Pose {
                position: [0.0125, -0.0025, 0.0375],
                orientation: [0.0, 0.0, 0.38268343236508984, 0.9238795325112867],
            },
            contact_force: [0.125, -0.25, 1.5],
            contact_torque: [0.001, -0.002, 0.0],
            contact_points: vec![[0.01, 0.0, 0.03], [0.015, -0.005, 0.031]],
            rendered_force: [0.5, -0.25, 0.75],
            joint_angles: [0.1, -0.2, 0.3, -0.4, 0.5, -0.6],
            buttons: 0b01,
            surface_positions: vec![
                [0.0, 0.0, 0.0],
                [0.5, 0.0, 0.0],
                [0.0, 0.25, 0.125],
                [0.5, 0.25, 0.0625],
            ],
            surface_triangles: vec![[0, 1, 2], [1, 3, 2]],
            target_pose: Pose {
                position: [0.02, 0.01, 0.05],
                // 60° about x.
                orientation: [0.5, 0.0, 0.0, 0.866_025_403_784_438_6],
            },
            degeneration_grade: 1.5,
        }
    }

    /// The expectation file for `ros_peer.py check`.
    pub fn expect_json(&self, topics: &[&str], with_commands: bool) -> serde_json::Value {
        let mesh: Vec<[f64; 3]> = self
            .surface_triangles
            .iter()
            .flat_map(|t| {
                t.iter()
                    .map(|&i| self.surface_positions[i as usize].map(|v| v as f64))
            })
            .collect();
        let mut v = serde_json::json!({
            "namespace": "/arthrosim",
            "topics": topics,
            "probe_pose": {"position": self.probe_pose.position, "orientation": self.probe_pose.orientation},
            "probe_wrench": {"force": self.contact_force, "torque": self.contact_torque},
            "device_wrench": {"force": self.rendered_force},
            "joint_positions": self.joint_angles,
            "buttons": (0..2).map(|b| (self.buttons >> b) & 1).collect::<Vec<_>>(),
            "mesh_points": mesh,
            "contact_points": self.contact_points,
        });
        if with_commands {
            v["target_pose"] = serde_json::json!({
                "position": self.target_pose.position,
                "orientation": self.target_pose.orientation,
            });
            v["degeneration_grade"] = serde_json::json!(self.degeneration_grade);
        }
        v
    }
}

/// Plays the physics and haptic nodes over iceoryx2 and watches the commands coming back.
pub struct Feeder {
    _node: IpcNode,
    frames: IpcPublisher<ContactFrame>,
    states: IpcPublisher<DeviceState>,
    surfaces: IpcPublisher<SurfaceFrame>,
    stats: IpcPublisher<HapticStats>,
    targets: IpcSubscriber<ProbeTarget>,
    material: IpcSubscriber<MaterialCommand>,
    sequence: u64,
    last_frame: Instant,
    last_surface: Instant,
    pub target: Option<ProbeTarget>,
    pub grade: Option<MaterialCommand>,
}

impl Feeder {
    pub fn new(session: &str) -> Feeder {
        let node = ipc::create_node("bridge-test-feeder").unwrap();
        Feeder {
            frames: ipc::publisher(&node, session).unwrap(),
            states: ipc::publisher(&node, session).unwrap(),
            surfaces: ipc::publisher(&node, session).unwrap(),
            stats: ipc::publisher(&node, session).unwrap(),
            targets: ipc::subscriber(&node, session, Queue::Newest).unwrap(),
            material: ipc::subscriber(&node, session, Queue::Newest).unwrap(),
            _node: node,
            sequence: 0,
            last_frame: Instant::now() - Duration::from_secs(1),
            last_surface: Instant::now() - Duration::from_secs(1),
            target: None,
            grade: None,
        }
    }

    /// One millisecond tick: a device state every call, a contact frame every 5 ms, the
    /// surface every 33 ms; collects commands.
    pub fn tick(&mut self, sc: &Scenario) {
        self.sequence += 1;
        let seq = self.sequence;
        ipc::send_with(&self.states, |s| {
            s.sequence = seq;
            s.publish_ns = msgs::clock::monotonic_ns();
            s.device_kind = 2;
            s.buttons = sc.buttons;
            s.proxy_pose = sc.probe_pose;
            s.joint_angles = sc.joint_angles;
            s.rendered_force = sc.rendered_force;
            s.commanded_force = sc.rendered_force;
        })
        .unwrap();
        if self.last_frame.elapsed() >= Duration::from_millis(5) {
            self.last_frame = Instant::now();
            ipc::send_with(&self.frames, |f| {
                f.sequence = seq;
                f.publish_ns = msgs::clock::monotonic_ns();
                f.dt_s = 0.01;
                f.sim_time_s = seq as f64 * 1e-3;
                f.probe_pose = sc.probe_pose;
                f.probe_free_pose = sc.probe_pose;
                f.proxy_pose = sc.probe_pose;
                f.contact_force = sc.contact_force;
                f.contact_torque = sc.contact_torque;
                f.contact_count = sc.contact_points.len() as u32;
                f.row_count = 3 * sc.contact_points.len() as u32;
                for (k, p) in sc.contact_points.iter().enumerate() {
                    f.contact_points[k] = *p;
                    f.constraint_directions[3 * k] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
                    f.lambda[3 * k] = 0.0075;
                }
            })
            .unwrap();
            ipc::send_with(&self.stats, |h| {
                h.sequence = seq;
                h.publish_ns = msgs::clock::monotonic_ns();
                h.tick_hz = 1000.0;
            })
            .unwrap();
        }
        if self.last_surface.elapsed() >= Duration::from_millis(33) {
            self.last_surface = Instant::now();
            ipc::send_with(&self.surfaces, |s| {
                s.sequence = seq;
                s.publish_ns = msgs::clock::monotonic_ns();
                s.vertex_count = sc.surface_positions.len() as u32;
                s.triangle_count = sc.surface_triangles.len() as u32;
                s.positions[..sc.surface_positions.len()].copy_from_slice(&sc.surface_positions);
                s.triangles[..sc.surface_triangles.len()].copy_from_slice(&sc.surface_triangles);
            })
            .unwrap();
        }
        let mut target = ProbeTarget {
            sequence: 0,
            publish_ns: 0,
            pose: Pose::IDENTITY,
        };
        if ipc::take_newest(&self.targets, &mut target).unwrap() > 0 {
            self.target = Some(target);
        }
        let mut grade = MaterialCommand {
            sequence: 0,
            publish_ns: 0,
            degeneration_grade: 0.0,
        };
        if ipc::take_newest(&self.material, &mut grade).unwrap() > 0 {
            self.grade = Some(grade);
        }
    }
}

/// Unique session name per test (iceoryx2 services are machine-wide).
pub fn session(tag: &str) -> String {
    format!("bridge-{tag}-{}", std::process::id())
}

pub fn bridge_command(ns: &NetNs, session: &str, launch: Option<&Path>) -> Command {
    let mut c = ns.command(env!("CARGO_BIN_EXE_viz-bridge"));
    c.args(["--session", session]);
    if let Some(l) = launch {
        c.arg("--launch").arg(l);
    }
    c
}

pub fn peer_command(ns: &NetNs, uri: &str, args: &[&str]) -> Command {
    let mut c = ns.command(&python());
    c.arg(peer_script()).args(args).env("CYCLONEDDS_URI", uri);
    c
}

pub fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("viz-bridge-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}
