//! bridge-bench: probe pose + wrench at 1 kHz through the bridge to an Eclipse Cyclone DDS
//! peer (Python `cyclonedds`) for 30 s; prints one JSON line with messages lost and the
//! end-to-end latency (ContactFrame publish_ns → peer receipt) p50/p99.
//!
//! The bench plays the physics node over iceoryx2; `probe_pose.position.x` and
//! `contact_force.x` carry the sample number, so the peer counts exactly which samples
//! arrived. As root it runs bridge and peer in a private network namespace (loopback only);
//! otherwise on the host's loopback with a random domain id.
//!
//! `cargo build --release -p viz-bridge && target/release/bridge-bench [--seconds 30]`

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Parser;
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;

#[derive(Parser)]
#[command(name = "bridge-bench")]
struct Args {
    /// Measured duration, s.
    #[arg(long, default_value_t = 30.0)]
    seconds: f64,
    /// Physics frame rate, Hz.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// `reliable` or `best_effort` for probe/pose and probe/wrench.
    #[arg(long, default_value = "reliable")]
    reliability: String,
    /// Run on the host network even when root (no network namespace).
    #[arg(long)]
    no_netns: bool,
}

struct NetNs(String);

impl Drop for NetNs {
    fn drop(&mut self) {
        let _ = Command::new("ip").args(["netns", "del", &self.0]).status();
    }
}

fn ip(args: &[&str]) -> anyhow::Result<()> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .context("running ip")?;
    if !out.status.success() {
        bail!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(())
}

struct Proc {
    name: &'static str,
    child: Child,
    lines: Receiver<String>,
}

impl Proc {
    fn spawn(name: &'static str, mut cmd: Command) -> anyhow::Result<Proc> {
        cmd.stdout(Stdio::piped())
            .stderr(Stdio::null())
            .stdin(Stdio::null());
        let mut child = cmd.spawn().with_context(|| format!("starting {name}"))?;
        let stdout = child.stdout.take().context("child stdout")?;
        let (tx, lines) = channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Ok(Proc { name, child, lines })
    }

    fn wait_line(&self, prefix: &str, timeout: Duration) -> anyhow::Result<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) if line.starts_with(prefix) => return Ok(line),
                Ok(_) => {}
                Err(_) => bail!("{}: no {prefix:?} line within {timeout:?}", self.name),
            }
        }
    }

    fn has_line(&self, prefix: &str) -> bool {
        self.lines.try_iter().any(|l| l.starts_with(prefix))
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        // SAFETY: signalling our own child.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if !(args.seconds > 0.0 && args.rate > 0.0 && args.rate <= 10_000.0) {
        bail!("--seconds must be > 0 and --rate in (0, 10000]");
    }
    if args.reliability != "reliable" && args.reliability != "best_effort" {
        bail!("--reliability must be reliable or best_effort");
    }
    let exe_dir = std::env::current_exe()?
        .parent()
        .context("executable directory")?
        .to_path_buf();
    let bridge_exe = exe_dir.join("viz-bridge");
    if !bridge_exe.exists() {
        bail!(
            "{} not found (cargo build -p viz-bridge)",
            bridge_exe.display()
        );
    }
    let script = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/py/ros_peer.py"));
    let python = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    let pid = std::process::id();

    // SAFETY: plain libc call.
    let root = unsafe { libc::geteuid() } == 0;
    let netns = if root && !args.no_netns {
        let name = format!("arthro-bench-{pid}");
        let _ = Command::new("ip")
            .args(["netns", "del", &name])
            .stderr(Stdio::null())
            .status();
        ip(&["netns", "add", &name])?;
        let ns = NetNs(name);
        ip(&["-n", &ns.0, "link", "set", "lo", "up"])?;
        ip(&["-n", &ns.0, "link", "set", "lo", "multicast", "on"])?;
        ip(&["-n", &ns.0, "route", "add", "224.0.0.0/4", "dev", "lo"])?;
        Some(ns)
    } else {
        None
    };
    // Alone in a namespace domain 0 is private; on the host pick one nobody else uses.
    let domain = if netns.is_some() { 0 } else { 100 + pid % 100 };
    let in_ns = |program: &str| match &netns {
        Some(ns) => {
            let mut c = Command::new("ip");
            c.args(["netns", "exec", &ns.0, program]);
            c
        }
        None => Command::new(program),
    };

    let dir = std::env::temp_dir().join(format!("bridge-bench-{pid}"));
    std::fs::create_dir_all(&dir)?;
    let launch = dir.join("bench.toml");
    let depth = (args.rate as usize).max(100);
    let mut toml = format!(
        "[bridge]\ndomain_id = {domain}\nqueue_depth = 8192\n\
         [bridge.streams.probe_pose]\nreliability = \"{r}\"\ndepth = {depth}\n\
         [bridge.streams.probe_wrench]\nreliability = \"{r}\"\ndepth = {depth}\n",
        r = args.reliability
    );
    for off in [
        "device_wrench",
        "joint_states",
        "buttons",
        "mesh",
        "contacts",
        "tf",
    ] {
        toml.push_str(&format!("[bridge.streams.{off}]\nenabled = false\n"));
    }
    std::fs::write(&launch, toml)?;

    let session = format!("bench-{pid}");
    let node = ipc::create_node("bridge-bench")?;
    let frames = ipc::publisher::<ContactFrame>(&node, &session)?;
    // Keeps the service alive with the bridge's buffer size before the bridge opens it.
    let _keep = ipc::subscriber::<ContactFrame>(&node, &session, Queue::Newest)?;

    let uri = "<CycloneDDS><Domain Id=\"any\"><Discovery><ParticipantIndex>auto</ParticipantIndex>\
               <Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery></Domain></CycloneDDS>";
    let mut peer_cmd = in_ns(&python);
    peer_cmd
        .arg(&script)
        .args(["bench", "--domain", &domain.to_string()])
        .args(["--timeout", &format!("{}", args.seconds + 120.0)])
        .env("CYCLONEDDS_URI", uri);
    if args.reliability == "best_effort" {
        peer_cmd.arg("--best-effort");
    }
    let peer = Proc::spawn("cyclone peer", peer_cmd)?;
    peer.wait_line("READY", Duration::from_secs(30))?;
    let mut bridge_cmd = in_ns(bridge_exe.to_str().context("bridge path")?);
    bridge_cmd
        .args(["--session", &session, "--launch"])
        .arg(&launch);
    let bridge = Proc::spawn("viz-bridge", bridge_cmd)?;
    bridge.wait_line("READY bridge", Duration::from_secs(30))?;

    let send = |x: f64| -> anyhow::Result<()> {
        ipc::send_with(&frames, |f| {
            f.publish_ns = msgs::clock::monotonic_ns();
            f.dt_s = 1.0 / args.rate;
            f.probe_pose = msgs::Pose {
                position: [x, 0.0, 0.0],
                orientation: [0.0, 0.0, 0.0, 1.0],
            };
            f.contact_force = [x, 0.0, 1.0];
        })?;
        Ok(())
    };

    // Warm-up until the peer has matched both writers and sees samples.
    let warm_deadline = Instant::now() + Duration::from_secs(60);
    loop {
        send(-1.0)?;
        if peer.has_line("WARM") {
            break;
        }
        if Instant::now() > warm_deadline {
            bail!("the Cyclone peer never received the warm-up samples");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(500));

    let count = (args.seconds * args.rate).round() as u64;
    let period = Duration::from_secs_f64(1.0 / args.rate);
    let start = Instant::now();
    for n in 0..count {
        let due = start + period * n as u32;
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        send(n as f64)?;
    }
    let sent_seconds = start.elapsed().as_secs_f64();
    for _ in 0..150 {
        send(-2.0)?;
        std::thread::sleep(Duration::from_millis(10));
    }
    let result = peer.wait_line("{", Duration::from_secs(60))?;
    let peer_result: serde_json::Value =
        serde_json::from_str(&result).context("peer result JSON")?;
    drop(bridge);
    drop(peer);
    let _ = std::fs::remove_dir_all(&dir);
    drop(netns);

    let received = |k: &str| peer_result[k].as_u64().unwrap_or(0);
    // Publish → peer receipt, in the workspace's one latency histogram (up to 10 s).
    let mut latency = msgs::timing::LatencyHistogram::new(10_000_000_000);
    for v in peer_result["latencies_ns"].as_array().into_iter().flatten() {
        latency.record(v.as_i64().unwrap_or(0).max(0) as u64);
    }
    let us = |v: f64| (latency.count() > 0).then_some(v);
    let out = serde_json::json!({
        "bench": "viz-bridge pose+wrench to Cyclone DDS",
        "reliability": args.reliability,
        "rate_hz": args.rate,
        "seconds": args.seconds,
        "achieved_send_rate_hz": count as f64 / sent_seconds,
        "sent": count,
        "pose_received": received("pose_received"),
        "wrench_received": received("wrench_received"),
        "lost_pose": count.saturating_sub(received("pose_received")),
        "lost_wrench": count.saturating_sub(received("wrench_received")),
        "duplicates": peer_result["duplicates"],
        "latency_p50_us": us(latency.quantile_us(0.5)),
        "latency_p99_us": us(latency.quantile_us(0.99)),
        "latency_max_us": us(latency.max_ns() as f64 / 1e3),
        "network_namespace": root && !args.no_netns,
    });
    println!("{out}");
    Ok(())
}
