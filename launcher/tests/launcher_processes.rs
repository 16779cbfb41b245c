//! The launcher against stand-in node processes (shell scripts that speak the node
//! contract: `READY <node>` on stdout, clean exit on SIGTERM), so start order, readiness,
//! restarts, stop order and straggler handling are tested without the real nodes.

use launch_config::{LaunchFile, RestartPolicy};
use launcher::{self, EndReason, LauncherError, LiveMode, NodeKind, RunOptions};
use std::path::{Path, PathBuf};

/// A well-behaved node: records its pid, prints READY, stops on SIGTERM and notes the order.
const GOOD: &str = r#"
name=$1; dir=$7
echo $$ >> "$dir/pids"
trap 'echo "$name" >> "$dir/stops"; exit 0' TERM
echo "starting $name" >&2
echo "READY $name"
while true; do sleep 0.02; done
"#;

fn session_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("launcher-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn options(
    name: &str,
    script: &str,
    seconds: Option<f64>,
    tweak: impl FnOnce(&mut LaunchFile),
) -> RunOptions {
    let mut launch = LaunchFile::default();
    launch.launcher.ready_timeout_s = 5.0;
    launch.launcher.stop_grace_s = 1.0;
    launch.launcher.restart_backoff_s = 0.1;
    launch.launcher.status_period_s = 0.05;
    tweak(&mut launch);
    RunOptions {
        launch,
        origin: format!("{name}.toml"),
        session: format!("launcher-test-{}-{name}", std::process::id()),
        out_dir: session_dir(name),
        seconds,
        program: PathBuf::from("/bin/sh"),
        program_args: vec!["-c".into(), script.into(), "node".into()],
        live: LiveMode::Quiet,
    }
}

fn lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .map(str::to_string)
        .collect()
}

/// Every pid a stand-in recorded is gone (not running, not a zombie).
fn assert_no_node_left(dir: &Path) {
    let pids = lines(&dir.join("pids"));
    assert!(!pids.is_empty(), "no node recorded its pid");
    for pid in pids {
        let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
        assert!(stat.is_empty(), "node process {pid} still exists: {stat}");
    }
}

#[test]
fn session_starts_all_nodes_and_stops_them_haptic_first_recorder_last() {
    let opts = options("order", GOOD, Some(0.5), |_| {});
    let report = launcher::run(&opts).unwrap();
    assert_eq!(report.end, EndReason::Completed);
    assert!(report.success(), "{report:?}");
    // The default session's five nodes: the viewer (trainee page) is on by default.
    assert_eq!(report.nodes.len(), 5);
    assert!(report.nodes.iter().all(|n| n.clean_stop && n.restarts == 0));
    assert_eq!(
        lines(&opts.out_dir.join("stops")),
        ["haptic", "viewer", "bridge", "physics", "recorder"]
    );
    assert_no_node_left(&opts.out_dir);
    // Session folder: resolved launch file, summary, one log per node with its output.
    let launch = launch_config::load(opts.out_dir.join("launch.toml")).unwrap();
    assert_eq!(launch.launcher.stop_grace_s, 1.0);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(opts.out_dir.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["end"]["kind"], "completed");
    assert_eq!(summary["summary"]["regions"][0]["region"], "posterior");
    let log = std::fs::read_to_string(opts.out_dir.join("logs/physics.log")).unwrap();
    assert!(
        log.contains("starting physics") && log.contains("READY physics"),
        "{log}"
    );
}

#[test]
fn disabled_nodes_are_not_started() {
    let opts = options("subset", GOOD, Some(0.3), |l| {
        l.nodes.haptic = false;
        l.nodes.bridge = false;
        l.recording.enabled = false; // recorder off through [recording] too
        l.viewer.enabled = false; // and the viewer through [viewer]
    });
    let report = launcher::run(&opts).unwrap();
    assert_eq!(report.nodes.len(), 1);
    assert_eq!(report.nodes[0].node, NodeKind::Physics);
    assert_eq!(lines(&opts.out_dir.join("stops")), ["physics"]);
}

/// Physics crashes once after it is ready; the policy restarts it.
const CRASH_ONCE: &str = r#"
name=$1; dir=$7
echo $$ >> "$dir/pids"
trap 'echo "$name" >> "$dir/stops"; exit 0' TERM
echo "READY $name"
if [ "$name" = physics ] && [ ! -e "$dir/crashed" ]; then
  touch "$dir/crashed"; sleep 0.3; echo "physics: simulated crash" >&2; exit 3
fi
while true; do sleep 0.02; done
"#;

#[test]
fn crashed_node_is_restarted_under_on_failure() {
    let opts = options("restart", CRASH_ONCE, Some(1.5), |l| {
        l.launcher.restart = RestartPolicy::OnFailure;
        l.launcher.max_restarts = 2;
    });
    let report = launcher::run(&opts).unwrap();
    assert_eq!(report.end, EndReason::Completed);
    let physics = report
        .nodes
        .iter()
        .find(|n| n.node == NodeKind::Physics)
        .unwrap();
    assert_eq!(physics.restarts, 1);
    assert!(physics.clean_stop, "the restarted instance stops cleanly");
    assert!(report.success());
    // Five nodes and a second physics pid (the crashed one and its replacement); all gone.
    assert_eq!(lines(&opts.out_dir.join("pids")).len(), 6);
    assert_no_node_left(&opts.out_dir);
}

#[test]
fn crashed_node_ends_the_session_under_never() {
    let opts = options("never", CRASH_ONCE, Some(5.0), |l| {
        l.launcher.restart = RestartPolicy::Never;
    });
    let started = std::time::Instant::now();
    let report = launcher::run(&opts).unwrap();
    assert!(
        started.elapsed().as_secs_f64() < 4.0,
        "session should end at the crash"
    );
    assert_eq!(
        report.end,
        EndReason::NodeFailed {
            node: NodeKind::Physics,
            exit: "exit 3".into()
        }
    );
    assert!(!report.success());
    // The others were still stopped in order.
    assert_eq!(
        lines(&opts.out_dir.join("stops")),
        ["haptic", "viewer", "bridge", "recorder"]
    );
    assert_no_node_left(&opts.out_dir);
}

/// The recorder never says READY.
const SILENT_RECORDER: &str = r#"
name=$1; dir=$7
echo $$ >> "$dir/pids"
trap 'echo "$name" >> "$dir/stops"; exit 0' TERM
[ "$name" = recorder ] || echo "READY $name"
while true; do sleep 0.02; done
"#;

#[test]
fn ready_timeout_names_the_node_and_stops_the_started_ones() {
    let opts = options("timeout", SILENT_RECORDER, Some(5.0), |l| {
        l.launcher.ready_timeout_s = 0.5;
    });
    let err = launcher::run(&opts).unwrap_err();
    assert!(
        matches!(
            err,
            LauncherError::ReadyTimeout {
                node: "recorder",
                ..
            }
        ),
        "{err}"
    );
    assert!(err.to_string().contains("READY recorder"), "{err}");
    // Physics had started (it is first) and was stopped; haptic never started.
    assert_eq!(lines(&opts.out_dir.join("stops")), ["physics", "recorder"]);
    assert_no_node_left(&opts.out_dir);
}

/// The bridge ignores SIGTERM (and keeps a child process of its own).
const STUBBORN_BRIDGE: &str = r#"
name=$1; dir=$7
echo $$ >> "$dir/pids"
if [ "$name" = bridge ]; then trap '' TERM; else trap 'echo "$name" >> "$dir/stops"; exit 0' TERM; fi
echo "READY $name"
while true; do sleep 0.02; done
"#;

#[test]
fn straggler_is_killed_after_the_grace_period() {
    let opts = options("straggler", STUBBORN_BRIDGE, Some(0.3), |l| {
        l.launcher.stop_grace_s = 0.3;
    });
    let report = launcher::run(&opts).unwrap();
    let bridge = report
        .nodes
        .iter()
        .find(|n| n.node == NodeKind::Bridge)
        .unwrap();
    assert!(bridge.killed, "{bridge:?}");
    assert!(!bridge.clean_stop);
    assert!(!report.success(), "a killed node is not a clean session");
    assert_eq!(
        lines(&opts.out_dir.join("stops")),
        ["haptic", "viewer", "physics", "recorder"]
    );
    assert_no_node_left(&opts.out_dir);
}

/// A node that exits 0 by itself (its protocol ended) ends the session normally.
const HAPTIC_FINISHES: &str = r#"
name=$1; dir=$7
echo $$ >> "$dir/pids"
trap 'echo "$name" >> "$dir/stops"; exit 0' TERM
echo "READY $name"
if [ "$name" = haptic ]; then sleep 0.3; exit 0; fi
while true; do sleep 0.02; done
"#;

#[test]
fn node_that_finishes_ends_the_session_cleanly() {
    let opts = options("finish", HAPTIC_FINISHES, None, |_| {});
    let report = launcher::run(&opts).unwrap();
    assert_eq!(
        report.end,
        EndReason::NodeFinished {
            node: NodeKind::Haptic
        }
    );
    assert!(report.success(), "{report:?}");
    assert_eq!(
        lines(&opts.out_dir.join("stops")),
        ["viewer", "bridge", "physics", "recorder"]
    );
}

#[test]
fn node_that_dies_before_ready_is_reported_with_its_log() {
    let script = r#"name=$1; dir=$7; echo $$ >> "$dir/pids"; echo "cannot open mesh" >&2; exit 2"#;
    let opts = options("early", script, Some(1.0), |l| {
        l.launcher.restart = RestartPolicy::Never;
    });
    let err = launcher::run(&opts).unwrap_err();
    assert!(
        matches!(
            err,
            LauncherError::DiedBeforeReady {
                node: "physics",
                ..
            }
        ),
        "{err}"
    );
    let log = std::fs::read_to_string(opts.out_dir.join("logs/physics.log")).unwrap();
    assert!(log.contains("cannot open mesh"));
}
