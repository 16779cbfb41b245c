//! End-to-end: the haptic-node binary against the `halfspace-physics` publisher (an analytic
//! elastic half-space publishing real contact frames), over real shared memory.

mod common;
use common::*;
use msgs::haptic_to_physics::fault;
use std::time::Duration;

const READY: Duration = Duration::from_secs(20);

fn physics(session: &str, stiffness: f64) -> Proc {
    Proc::start(
        "halfspace-physics",
        &halfspace_exe(),
        &["--session", session, "--stiffness", &stiffness.to_string()],
        READY,
    )
}

/// Force scale 1 and the Touch's default 1000 N/m stiffness limit: the virtual coupling is
/// 1000 N/m in series with the half-space.
const COUPLING: f64 = 1000.0;

/// Closed form of the rendered force: the half-space k in series with the coupling.
fn felt(k: f64, depth: f64) -> f64 {
    depth.max(0.0) / (1.0 / k + 1.0 / COUPLING)
}

fn haptic(session: &str, trajectory: &std::path::Path) -> Proc {
    let launch = trajectory.with_extension("toml");
    std::fs::write(
        &launch,
        format!(
            "[device]\nforce_scale = 1.0\nmax_stiffness_n_per_m = {COUPLING}\nposition_hysteresis_m = 0.0\n"
        ),
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

#[test]
fn haptic_force_matches_the_physics_force_at_the_same_proxy() {
    let _rig = one_rig_at_a_time();
    let s = session("match");
    let dir = temp_dir("match");
    let k = 500.0;
    // Hold 1 mm deep, then descend slowly from 1 mm deep to 1.6 mm deep.
    let traj = write_trajectory(
        &dir,
        "t.csv",
        &[
            (0.0, [0.0, 0.0, -1e-3]),
            (1.0, [0.0, 0.0, -1e-3]),
            (2.0, [0.0, 0.0, -1.6e-3]),
            (60.0, [0.0, 0.0, -1.6e-3]),
        ],
    );
    let mut w = Watcher::new(&s);
    let _phys = physics(&s, k);
    let mut hap = haptic(&s, &traj);
    w.watch(Duration::from_millis(2500));
    assert_eq!(
        hap.terminate(Duration::from_secs(5)),
        Some(0),
        "clean stop on SIGTERM"
    );

    // 1. While the proxy rests where the physics frame was computed, the haptic force is the
    //    physics force of that frame through the coupling: k_c/(k + k_c) of it.
    let mut same_proxy = 0;
    for st in &w.seen_states {
        let Some(f) = w
            .seen_frames
            .iter()
            .find(|f| f.sequence == st.frame_sequence_used && f.instance == st.frame_instance_used)
        else {
            continue;
        };
        if f.contact_count == 1 && f.proxy == st.proxy_pose.position && st.faults == 0 {
            same_proxy += 1;
            assert!(
                (st.rendered_force[2] - f.contact_force[2] * COUPLING / (k + COUPLING)).abs()
                    < 1e-6,
                "haptic {:?} vs physics {:?}",
                st.rendered_force,
                f.contact_force
            );
        }
    }
    assert!(
        same_proxy > 300,
        "ticks with the frame's proxy: {same_proxy}"
    );
    // 2. While the proxy moves, the local update δ = δ_free + H·Δx gives the force for the
    //    proxy's *current* position (exact for a half-space, closed form with the coupling).
    let mut moving = 0;
    for st in &w.seen_states {
        let z = st.proxy_pose.position[2];
        if st.contact_count == 1 && st.faults & fault::STALE_FRAME == 0 && z < -1.05e-3 {
            moving += 1;
            assert!(
                (st.commanded_force[2] - felt(k, -z)).abs() < 1e-6,
                "z {z}: {:?}",
                st.commanded_force
            );
        }
    }
    assert!(moving > 300, "ticks while descending: {moving}");
    // Ticks at 1 kHz and every state within the clamp.
    assert!(
        w.seen_states.len() > 2000,
        "{} states in 2.5 s",
        w.seen_states.len()
    );
    assert!(w.seen_states.iter().all(|s| norm(s.rendered_force) <= PEAK));
    std::fs::remove_dir_all(dir).ok();
}

/// Pushes into a stiff half-space until the force is established; returns the watcher.
fn established_contact(
    s: &str,
    traj: &std::path::Path,
    phys: &mut Option<Proc>,
) -> (Watcher, Proc) {
    let mut w = Watcher::new(s);
    *phys = Some(physics(s, 1500.0));
    let hap = haptic(s, traj);
    w.until(Duration::from_secs(5), "contact force", |st| {
        st.rendered_force[2] > 0.6
    });
    w.watch(Duration::from_millis(200));
    (w, hap)
}

#[test]
fn kill9_of_physics_mid_contact_ramps_force_to_zero_within_10ms_of_staleness() {
    let _rig = one_rig_at_a_time();
    let s = session("kill");
    let dir = temp_dir("kill");
    let traj = write_trajectory(
        &dir,
        "t.csv",
        &[(0.0, [0.0, 0.0, -2e-3]), (60.0, [0.0, 0.0, -2e-3])],
    );
    let mut phys = None;
    let (mut w, _hap) = established_contact(&s, &traj, &mut phys);
    let killed_ns = msgs::clock::monotonic_ns();
    phys.take().unwrap().kill9();
    w.watch(Duration::from_millis(300));

    check_ramp_after_kill(&w, killed_ns);
    assert_rate_limited_and_clamped(&w);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn restarted_physics_is_picked_up_without_cleanup_and_without_a_force_step() {
    let _rig = one_rig_at_a_time();
    let s = session("restart");
    let dir = temp_dir("restart");
    let traj = write_trajectory(
        &dir,
        "t.csv",
        &[(0.0, [0.0, 0.0, -2e-3]), (60.0, [0.0, 0.0, -2e-3])],
    );
    let mut phys = None;
    let (mut w, _hap) = established_contact(&s, &traj, &mut phys);
    let old_instance = w.seen_states.last().unwrap().frame_instance_used;
    phys.take().unwrap().kill9();
    w.until(Duration::from_secs(2), "zero force after the kill", |st| {
        st.rendered_force == [0.0; 3]
    });
    w.watch(Duration::from_millis(100));
    // Same session, no manual cleanup of the dead process's shared memory.
    let _phys2 = physics(&s, 1500.0);
    w.until(
        Duration::from_secs(5),
        "force from the new physics instance",
        |st| st.frame_instance_used != old_instance && st.rendered_force[2] > 0.6,
    );
    w.watch(Duration::from_millis(100));
    assert_rate_limited_and_clamped(&w);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn nan_proxy_position_produces_no_force() {
    let _rig = one_rig_at_a_time();
    let s = session("nan");
    let dir = temp_dir("nan");
    let nan = f64::NAN;
    let traj = write_trajectory(
        &dir,
        "t.csv",
        &[
            (0.0, [0.0, 0.0, -2e-3]),
            (0.999, [0.0, 0.0, -2e-3]),
            (1.0, [nan, 0.0, -2e-3]),
            (1.5, [nan, 0.0, -2e-3]),
            (1.501, [0.0, 0.0, -2e-3]),
            (60.0, [0.0, 0.0, -2e-3]),
        ],
    );
    let mut w = Watcher::new(&s);
    let _phys = physics(&s, 800.0);
    let mut hap = haptic(&s, &traj);
    w.watch(Duration::from_millis(2300));
    assert_eq!(hap.terminate(Duration::from_secs(5)), Some(0));
    let nan_states: Vec<_> = w
        .seen_states
        .iter()
        .filter(|st| !st.proxy_pose.is_finite())
        .collect();
    assert!(nan_states.len() > 300, "{} NaN ticks", nan_states.len());
    for st in &nan_states {
        assert_eq!(st.rendered_force, [0.0; 3]);
        assert!(st.faults & fault::NONFINITE_DEVICE != 0);
    }
    let before = w
        .seen_states
        .iter()
        .filter(|st| st.proxy_pose.is_finite() && st.rendered_force[2] > 0.6)
        .count();
    assert!(
        before > 100,
        "force before and after the NaN stretch: {before} ticks"
    );
    let after = w
        .seen_states
        .iter()
        .rev()
        .take(200)
        .filter(|st| st.rendered_force[2] > 0.6)
        .count();
    assert!(after > 100, "force resumed after the NaN stretch");
    std::fs::remove_dir_all(dir).ok();
}
