//! The bridge with the real physics node (its binary from this workspace): a Cyclone DDS peer
//! publishes a probe target pose, physics drives the probe toward it, and every probe pose and
//! wrench the peer receives must be bit-for-bit a pose / force that physics published over
//! iceoryx2 (watched here as well). External control is opt-in: the session's launch file
//! sets `[bridge] accept_target_pose = true` (and a jump limit the 5.5 mm move fits in).

mod common;

use std::collections::HashSet;
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use common::*;
use msgs::ipc::{self, Queue};
use msgs::physics_to_haptic::ContactFrame;

fn physics_exe() -> Option<PathBuf> {
    // tests run from target/<profile>/deps; node binaries sit in target/<profile>.
    let exe = std::env::current_exe().ok()?;
    let path = exe.parent()?.parent()?.join("physics-node");
    path.exists().then_some(path)
}

fn bits(values: &[f64]) -> Vec<u64> {
    values.iter().map(|v| v.to_bits()).collect()
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[test]
fn cyclone_target_pose_drives_the_physics_node_and_sees_its_pose_and_force() {
    if !prerequisites_or_skip("physics session") {
        return;
    }
    let Some(physics) = physics_exe() else {
        if std::env::var("CI").as_deref() == Ok("true") {
            panic!("physics-node binary not built next to the tests (cargo build -p physics-node)");
        }
        eprintln!(
            "SKIPPED physics session: physics-node binary not built (cargo build -p physics-node)"
        );
        return;
    };
    let session = session("physics");
    let ns = NetNs::loopback("phys");
    let node = ipc::create_node("bridge-test-watch").unwrap();
    let frames = ipc::subscriber::<ContactFrame>(&node, &session, Queue::Every).unwrap();

    let dir = temp_dir("physics-launch");
    let launch = dir.join("accept.toml");
    std::fs::write(
        &launch,
        "[bridge]\naccept_target_pose = true\n[bridge.target_pose]\n\
         workspace_margin_m = 0.06\nmax_jump_m = 0.01\n",
    )
    .unwrap();
    let mut cmd = Command::new(&physics);
    cmd.args(["--session", &session]);
    cmd.arg("--launch").arg(&launch);
    if let Ok(data) = std::env::var("ARTHROSIM_DATA") {
        cmd.args(["--data", &data]);
    }
    let mut physics = Proc::spawn("physics", cmd);
    physics.wait_line("READY physics", Duration::from_secs(120));
    let mut bridge = Proc::spawn("bridge", bridge_command(&ns, &session, Some(&launch)));
    bridge.wait_line("READY bridge", Duration::from_secs(30));

    let target = [0.002, 0.001, 0.045];
    let target_arg = format!("{},{},{},0,0,0,1", target[0], target[1], target[2]);
    let uri = cyclone_uri(&["127.0.0.1"], None);
    let mut peer = Proc::spawn(
        "cyclone",
        peer_command(
            &ns,
            &uri,
            &["drive", "--target", &target_arg, "--seconds", "8"],
        ),
    );
    peer.wait_line("READY", Duration::from_secs(30));

    let mut poses: HashSet<Vec<u64>> = HashSet::new();
    let mut wrenches: HashSet<Vec<u64>> = HashSet::new();
    let mut first_probe: Option<[f64; 3]> = None;
    let mut last: Option<(msgs::Pose, msgs::Pose)> = None;
    let deadline = Instant::now() + Duration::from_secs(60);
    let status = loop {
        ipc::drain_each(&frames, |f| {
            let p = f.probe_pose;
            poses.insert(bits(
                &[p.position.as_slice(), p.orientation.as_slice()].concat(),
            ));
            wrenches.insert(bits(&[f.contact_force, f.contact_torque].concat()));
            first_probe.get_or_insert(p.position);
            last = Some((f.proxy_pose, p));
        })
        .unwrap();
        if let Some(status) = peer.child.try_wait().unwrap() {
            break status;
        }
        assert!(
            physics.child.try_wait().unwrap().is_none(),
            "physics exited"
        );
        assert!(bridge.child.try_wait().unwrap().is_none(), "bridge exited");
        assert!(Instant::now() < deadline, "peer did not finish");
        std::thread::sleep(Duration::from_millis(1));
    };
    assert!(status.success(), "Cyclone peer failed");
    let line: Vec<String> = peer.lines.try_iter().collect();
    let result: serde_json::Value = serde_json::from_str(
        line.iter()
            .rev()
            .find(|l| l.starts_with('{'))
            .expect("peer result"),
    )
    .unwrap();

    let received_poses = result["poses"].as_array().unwrap();
    let received_wrenches = result["wrenches"].as_array().unwrap();
    assert!(
        received_poses.len() >= 50,
        "only {} poses over DDS",
        received_poses.len()
    );
    assert!(
        received_wrenches.len() >= 50,
        "only {} wrenches over DDS",
        received_wrenches.len()
    );
    let as_bits = |v: &serde_json::Value| -> Vec<u64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap().to_bits())
            .collect()
    };
    for p in received_poses {
        assert!(
            poses.contains(&as_bits(p)),
            "pose {p} over DDS was never published by physics"
        );
    }
    for w in received_wrenches {
        assert!(
            wrenches.contains(&as_bits(w)),
            "wrench {w} over DDS was never published by physics"
        );
    }

    // The target arrived as the proxy of physics and the probe followed it.
    let (proxy, probe) = last.expect("no contact frames from physics");
    assert!(
        distance(proxy.position, target) < 1e-12,
        "proxy {proxy:?} is not the target"
    );
    let start = distance(first_probe.unwrap(), target);
    let end = distance(probe.position, target);
    assert!(
        end < 0.5 * start,
        "probe did not follow the target: {start} m → {end} m"
    );

    for (name, proc) in [("bridge", &mut bridge), ("physics", &mut physics)] {
        let exit = proc.stop(Duration::from_secs(10));
        assert!(
            matches!(exit, Some(s) if s.success()),
            "{name} did not stop cleanly: {exit:?}"
        );
    }
}
