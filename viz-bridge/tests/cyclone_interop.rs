//! Interop with an independent DDS implementation: Eclipse Cyclone DDS (PyPI `cyclonedds`,
//! the DDS under rmw_cyclonedds) subscribes to every topic the bridge publishes with ROS 2 IDL
//! types and checks the values against what "physics" and "haptic" (this test, over iceoryx2)
//! published; it publishes a target pose and a degeneration grade that must arrive on
//! iceoryx2 as ProbeTarget / MaterialCommand (the target only because the session's launch
//! file opts in with `[bridge] accept_target_pose = true`).
//!
//! Runs in network namespaces the test creates (needs root; skipped with a note otherwise,
//! unless CI=true, where it fails).

mod common;

use std::time::{Duration, Instant};

use common::*;

const ALL_TOPICS: [&str; 9] = [
    "probe_pose",
    "probe_wrench",
    "device_wrench",
    "joint_states",
    "buttons",
    "mesh",
    "contacts",
    "tf",
    "diagnostics",
];

#[derive(Clone, Copy, Debug)]
enum Order {
    PeerFirst,
    BridgeFirst,
}

fn assert_pose_close(got: &msgs::Pose, want: &msgs::Pose) {
    for (g, w) in got
        .position
        .iter()
        .chain(got.orientation.iter())
        .zip(want.position.iter().chain(want.orientation.iter()))
    {
        assert!((g - w).abs() < 1e-12, "target pose {got:?} != {want:?}");
    }
}

/// Runs one session: bridge in `bridge_ns`, Cyclone peer in `peer_ns`, feeder here.
fn run_session(
    tag: &str,
    bridge_ns: &NetNs,
    peer_ns: &NetNs,
    cyclone_uri: &str,
    topics: &[&str],
    with_commands: bool,
    order: Order,
) {
    let sc = Scenario::standard();
    let session = session(tag);
    let dir = temp_dir(tag);
    let expect = dir.join("expect.json");
    std::fs::write(&expect, sc.expect_json(topics, with_commands).to_string()).unwrap();
    let mut feeder = Feeder::new(&session);

    let peer_cmd = || {
        peer_command(
            peer_ns,
            cyclone_uri,
            &[
                "check",
                "--expect",
                expect.to_str().unwrap(),
                "--timeout",
                "60",
                "--linger",
                "2",
            ],
        )
    };
    // The scenario's target is 19 mm from its probe, inside the surface box.
    let launch = dir.join("accept.toml");
    std::fs::write(
        &launch,
        "[bridge]\naccept_target_pose = true\n[bridge.target_pose]\nmax_jump_m = 0.03\n",
    )
    .unwrap();
    let start_bridge = || {
        let p = Proc::spawn(
            "bridge",
            bridge_command(
                bridge_ns,
                &session,
                with_commands.then_some(launch.as_path()),
            ),
        );
        p.wait_line("READY bridge", Duration::from_secs(30));
        p
    };
    let start_peer = || {
        let p = Proc::spawn("cyclone", peer_cmd());
        p.wait_line("READY", Duration::from_secs(30));
        p
    };
    let (mut bridge, mut peer) = match order {
        Order::PeerFirst => {
            let peer = start_peer();
            // Let Cyclone finish its initial discovery burst before the bridge appears:
            // the order that fails without peer configuration.
            std::thread::sleep(Duration::from_secs(2));
            (start_bridge(), peer)
        }
        Order::BridgeFirst => {
            let bridge = start_bridge();
            std::thread::sleep(Duration::from_secs(2));
            (bridge, start_peer())
        }
    };

    let deadline = Instant::now() + Duration::from_secs(75);
    let status = loop {
        feeder.tick(&sc);
        if let Some(status) = peer.child.try_wait().unwrap() {
            break status;
        }
        assert!(
            bridge.child.try_wait().unwrap().is_none(),
            "bridge exited during the session"
        );
        assert!(Instant::now() < deadline, "Cyclone peer did not finish");
        std::thread::sleep(Duration::from_millis(1));
    };
    // Commands published during the peer's last seconds may still be in flight.
    let settle = Instant::now();
    while with_commands
        && (feeder.target.is_none() || feeder.grade.is_none())
        && settle.elapsed() < Duration::from_secs(2)
    {
        feeder.tick(&sc);
        std::thread::sleep(Duration::from_millis(1));
    }
    let result: Vec<String> = peer.lines.try_iter().collect();
    let result = result
        .iter()
        .rev()
        .find(|l| l.starts_with('{'))
        .cloned()
        .unwrap_or_default();
    assert!(
        status.success(),
        "Cyclone peer failed ({order:?}): {result}"
    );
    let parsed: serde_json::Value = serde_json::from_str(&result).expect("peer result JSON");
    assert_eq!(parsed["ok"], true, "{result}");

    if with_commands {
        let target = feeder.target.expect("no ProbeTarget arrived over iceoryx2");
        assert_pose_close(&target.pose, &sc.target_pose);
        assert!(target.sequence >= 1);
        let grade = feeder
            .grade
            .expect("no MaterialCommand arrived over iceoryx2");
        assert_eq!(grade.degeneration_grade, sc.degeneration_grade);
    }

    let exit = bridge.stop(Duration::from_secs(10));
    assert!(
        matches!(exit, Some(s) if s.success()),
        "bridge did not stop cleanly on SIGTERM: {exit:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn cyclone_receives_every_topic_and_drives_the_probe_in_both_start_orders() {
    if !prerequisites_or_skip("cyclone interop") {
        return;
    }
    let with_peer = cyclone_uri(&["127.0.0.1"], None);
    let multicast_only = cyclone_uri(&[], None);
    let cases = [
        (Order::PeerFirst, &with_peer),
        (Order::BridgeFirst, &with_peer),
        // The namespace's loopback has MULTICAST on, so plain multicast discovery works too.
        (Order::PeerFirst, &multicast_only),
    ];
    for (i, (order, uri)) in cases.into_iter().enumerate() {
        let ns = NetNs::loopback(&format!("lo{i}"));
        run_session(
            &format!("interop{i}"),
            &ns,
            &ns,
            uri,
            &ALL_TOPICS,
            true,
            order,
        );
    }
}

#[test]
fn remote_viewer_across_a_veth_pair_receives_pose_wrench_and_mesh() {
    if !prerequisites_or_skip("remote viewer") {
        return;
    }
    let (session_ns, viewer_ns) = veth_pair("rv", 7);
    let uri = cyclone_uri(&["10.200.7.1"], None);
    run_session(
        "remote",
        &session_ns,
        &viewer_ns,
        &uri,
        &["probe_pose", "probe_wrench", "mesh"],
        false,
        Order::PeerFirst,
    );
}
