//! End-to-end against the real `physics-node` binary (built by the test with
//! `cargo build -p physics-node --bins` if needed): default scene (parametric lateral
//! meniscus), the haptic node replaying a probing of a protocol site, over real shared memory.

mod common;
use common::*;
use msgs::haptic_to_physics::fault;
use std::path::PathBuf;
use std::time::Duration;

const READY: Duration = Duration::from_secs(90);

fn physics(session: &str) -> Proc {
    Proc::start(
        "physics-node",
        &physics_exe(),
        &["--session", session],
        READY,
    )
}

/// The haptic node replaying `trajectory` at `force_scale`. The virtual coupling is then
/// 1000 N/m / force_scale (tissue side) in series with the contact compliance.
fn haptic(session: &str, trajectory: &std::path::Path, force_scale: f64) -> Proc {
    let launch = trajectory.with_extension("toml");
    // No position play: the comparisons are at the exact proxy of a frame.
    std::fs::write(
        &launch,
        format!("[device]\nforce_scale = {force_scale}\nposition_hysteresis_m = 0.0\n"),
    )
    .unwrap();
    Proc::start(
        "haptic-node",
        &haptic_exe(),
        &[
            "--session",
            session,
            "--launch",
            launch.to_str().unwrap(),
            "--replay",
            trajectory.to_str().unwrap(),
        ],
        READY,
    )
}

/// A scale so small that the coupling (1000 N/m / scale = 10⁴ N/mm) is ~200× stiffer than
/// the default tissue under the probe: the re-solve reproduces the physics force to ~0.5%.
const TINY_SCALE: f64 = 1e-4;

/// A probing of the mid region's centre site: hover 6 mm above, descend to `depth` below the
/// undeformed surface, hold. `nan_from`: seconds of a NaN dropout (start, end) while holding.
fn probing(dir: &std::path::Path, depth: f64, nan: Option<(f64, f64)>) -> PathBuf {
    let sites =
        haptic_node::node::resolve_sites(&launch_config::DeviceConfig::default(), None).unwrap();
    let site = sites
        .iter()
        .filter(|s| s.region == 2)
        .nth(2)
        .expect("a mid-region site");
    let at = |h: f64| {
        [
            site.point[0] + site.normal[0] * h,
            site.point[1] + site.normal[1] * h,
            site.point[2] + site.normal[2] * h,
        ]
    };
    let mut rows = vec![(0.0, at(6e-3)), (1.0, at(6e-3)), (3.0, at(-depth))];
    if let Some((a, b)) = nan {
        rows.push((a - 0.001, at(-depth)));
        rows.push((a, [f64::NAN, 0.0, 0.0]));
        rows.push((b, [f64::NAN, 0.0, 0.0]));
        rows.push((b + 0.001, at(-depth)));
    }
    rows.push((120.0, at(-depth)));
    write_trajectory(dir, "probing.csv", &rows)
}

#[test]
fn haptic_force_matches_the_real_physics_force_at_the_same_proxy() {
    let _rig = one_rig_at_a_time();
    let s = session("real-match");
    let dir = temp_dir("real-match");
    let traj = probing(&dir, 1.0e-3, None);
    let mut w = Watcher::new(&s);
    let _phys = physics(&s);
    let mut hap = haptic(&s, &traj, TINY_SCALE);
    w.watch(Duration::from_millis(5000));
    assert_eq!(hap.terminate(Duration::from_secs(5)), Some(0));

    let mut compared = 0;
    let mut worst: f64 = 0.0;
    for st in &w.seen_states {
        if st.faults
            & (fault::STALE_FRAME
                | fault::INVALID_FRAME
                | fault::NONFINITE_DEVICE
                | fault::NONFINITE_FORCE)
            != 0
        {
            continue;
        }
        let Some(f) = w
            .seen_frames
            .iter()
            .find(|f| f.sequence == st.frame_sequence_used && f.instance == st.frame_instance_used)
        else {
            continue;
        };
        if f.contact_count > 0 && f.proxy == st.proxy_pose.position {
            compared += 1;
            let c = st.commanded_force.map(|v| v / TINY_SCALE);
            let d = norm([
                c[0] - f.contact_force[0],
                c[1] - f.contact_force[1],
                c[2] - f.contact_force[2],
            ]);
            worst = worst.max(d / norm(f.contact_force).max(0.1));
            assert!(
                d <= 0.02 + 0.02 * norm(f.contact_force),
                "haptic {:?} / scale vs physics {:?} at the same proxy",
                c,
                f.contact_force
            );
        }
    }
    let fmax = w
        .seen_frames
        .iter()
        .map(|f| norm(f.contact_force))
        .fold(0.0, f64::max);
    eprintln!("compared {compared} ticks, worst relative difference {worst:.4}, physics force up to {fmax:.3} N");
    assert!(fmax > 0.1, "the probing made contact ({fmax} N)");
    assert!(
        compared > 300,
        "ticks at the frame's proxy with contact: {compared}"
    );
    assert_rate_limited_and_clamped(&w);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn kill9_of_real_physics_ramps_to_zero_and_a_restart_is_picked_up() {
    let _rig = one_rig_at_a_time();
    let s = session("real-kill");
    let dir = temp_dir("real-kill");
    let traj = probing(&dir, 1.5e-3, None);
    let mut w = Watcher::new(&s);
    let mut phys = physics(&s);
    let _hap = haptic(&s, &traj, 1.0);
    w.until(Duration::from_secs(15), "contact force", |st| {
        norm(st.rendered_force) > 0.3 && st.contact_count > 0
    });
    w.watch(Duration::from_millis(300));
    let old_instance = w.seen_states.last().unwrap().frame_instance_used;
    let killed_ns = msgs::clock::monotonic_ns();
    phys.kill9();
    w.watch(Duration::from_millis(300));
    check_ramp_after_kill(&w, killed_ns);
    // Restart in the same session, no manual cleanup.
    let _phys2 = physics(&s);
    w.until(
        Duration::from_secs(30),
        "force from the restarted physics",
        |st| st.frame_instance_used != old_instance && norm(st.rendered_force) > 0.3,
    );
    w.watch(Duration::from_millis(200));
    assert_rate_limited_and_clamped(&w);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn nan_proxy_against_real_physics_produces_no_force() {
    let _rig = one_rig_at_a_time();
    let s = session("real-nan");
    let dir = temp_dir("real-nan");
    let traj = probing(&dir, 1.5e-3, Some((4.0, 4.5)));
    let mut w = Watcher::new(&s);
    let _phys = physics(&s);
    let mut hap = haptic(&s, &traj, 1.0);
    w.watch(Duration::from_millis(5500));
    assert_eq!(hap.terminate(Duration::from_secs(5)), Some(0));
    let nan: Vec<_> = w
        .seen_states
        .iter()
        .filter(|st| !st.proxy_pose.is_finite())
        .collect();
    assert!(nan.len() > 300, "{} NaN ticks", nan.len());
    for st in &nan {
        assert_eq!(st.rendered_force, [0.0; 3]);
        assert!(st.faults & fault::NONFINITE_DEVICE != 0);
    }
    let pressed = w
        .seen_states
        .iter()
        .filter(|st| st.proxy_pose.is_finite() && norm(st.rendered_force) > 0.3)
        .count();
    assert!(
        pressed > 300,
        "force while pressing outside the dropout: {pressed} ticks"
    );
    assert_rate_limited_and_clamped(&w);
    std::fs::remove_dir_all(dir).ok();
}
