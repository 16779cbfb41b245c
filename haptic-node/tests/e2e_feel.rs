//! End-to-end: what the emulated hand feels. The haptic-node binary with the emulated Touch
//! (its quantisation, inertia, friction and grip) and its operator pressing to a force,
//! against the `halfspace-physics` publisher (an elastic half-space of a given stiffness),
//! over real shared memory. Everything is measured from the published device states.
//!
//! References from outside the project: the Touch's stiffness limit (datasheet, 1.0 N/mm
//! default), the cadaver table's stiffness under the probe (0.3–3.1 N/mm, typical 1.7 N/mm),
//! the study's examiner force (4.16 N) and Fischenich et al. 2015's −41% modulus at grade 2
//! (1 − 0.205·grade).

mod common;
use common::*;
use msgs::haptic_to_physics::{fault, DeviceState};
use std::time::Duration;

const READY: Duration = Duration::from_secs(20);
/// `operator::Phase` codes.
const PRESS: u32 = 2;
const HOLD: u32 = 3;

struct Run {
    states: Vec<DeviceState>,
    scale: f64,
    limit: f64,
}

/// One pass of the protocol (one site per region on the plane z = 0) against a half-space of
/// stiffness `k`, with the default `[device]` rendering. Returns every device state seen.
fn feel(test: &str, k: f64, press_force_n: f64) -> Run {
    let s = session(test);
    let dir = temp_dir(test);
    let launch = dir.join("feel.toml");
    std::fs::write(
        &launch,
        format!(
            "[device]\nbackend = \"emulated\"\n\n[device.emulated]\nsites = \"plane\"\n\
             plane_height_m = 0.0\nprobings_per_region = 1\nhover_m = 0.004\n\
             approach_speed_m_per_s = 0.04\npress_speed_m_per_s = 0.008\nhold_s = 1.0\n\
             press_force_n = {press_force_n}\nrepeat = false\n"
        ),
    )
    .unwrap();
    let config = launch_config::load(&launch).unwrap().device;
    let rendering = config.rendering();
    let mut w = Watcher::new(&s);
    let _phys = Proc::start(
        "halfspace-physics",
        &halfspace_exe(),
        &["--session", &s, "--stiffness", &k.to_string()],
        READY,
    );
    let mut hap = Proc::start(
        "haptic-node",
        &haptic_exe(),
        &["--session", &s, "--launch", launch.to_str().unwrap()],
        READY,
    );
    // The protocol ends by itself (repeat = false): the node exits.
    let t0 = std::time::Instant::now();
    while t0.elapsed() < Duration::from_secs(40) {
        w.watch(Duration::from_millis(100));
        if hap.child.try_wait().unwrap().is_some() {
            break;
        }
    }
    assert_eq!(
        hap.terminate(Duration::from_secs(5)),
        Some(0),
        "the protocol ran to its end"
    );
    std::fs::remove_dir_all(dir).ok();
    Run {
        states: std::mem::take(&mut w.seen_states),
        scale: rendering.force_scale,
        limit: rendering.felt_stiffness_limit_n_per_m,
    }
}

/// Consecutive ticks (by sequence) in contact with a fresh frame, neither limited by the
/// clamp nor the rate limit: the rendered force is then the renderer's force at the
/// stylus position.
fn clean_pairs(states: &[DeviceState]) -> impl Iterator<Item = (&DeviceState, &DeviceState)> {
    let bad = fault::STALE_FRAME
        | fault::INVALID_FRAME
        | fault::FORCE_CLAMPED
        | fault::RATE_LIMITED
        | fault::NONFINITE_DEVICE;
    states.windows(2).filter_map(move |p| {
        let (a, b) = (&p[0], &p[1]);
        (b.sequence == a.sequence + 1
            && a.contact_count > 0
            && b.contact_count > 0
            && (a.faults | b.faults) & bad == 0)
            .then_some((a, b))
    })
}

/// Largest |ΔF|/|Δz| between consecutive ticks whose stylus heights differ, N/m.
fn max_felt_stiffness(states: &[DeviceState]) -> f64 {
    clean_pairs(states)
        .filter(|(a, b)| a.proxy_pose.position[2] != b.proxy_pose.position[2])
        .map(|(a, b)| {
            (b.rendered_force[2] - a.rendered_force[2]).abs()
                / (b.proxy_pose.position[2] - a.proxy_pose.position[2]).abs()
        })
        .fold(0.0, f64::max)
}

/// Per hold (probing): standard deviation of the rendered normal force after the first
/// 100 ms, N, and the mean.
fn hold_stats(states: &[DeviceState]) -> Vec<(u32, f64, f64)> {
    let mut out = Vec::new();
    for probing in 1..=3u32 {
        let hold: Vec<&DeviceState> = states
            .iter()
            .filter(|s| s.probing_index == probing && s.phase == HOLD)
            .collect();
        if hold.len() < 300 {
            continue;
        }
        let t0 = hold[0].publish_ns;
        let f: Vec<f64> = hold
            .iter()
            .filter(|s| s.publish_ns >= t0 + 100 * MS)
            .map(|s| s.rendered_force[2])
            .collect();
        let n = f.len() as f64;
        let mean = f.iter().sum::<f64>() / n;
        let var = f.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
        out.push((probing, var.sqrt(), mean));
    }
    out
}

/// The limit cycle of main (0.35 ↔ 0.88 N between two position quanta at ≈ 10 N/mm on the
/// 57 N/mm default tissue) is gone: on a stiff and a soft half-space the felt stiffness stays
/// under the device limit and the force holds still while the hand holds still.
#[test]
fn felt_stiffness_is_bounded_and_holds_are_steady_on_stiff_and_soft_tissue() {
    let _rig = one_rig_at_a_time();
    for (name, k) in [("feel-stiff", 57e3), ("feel-soft", 1.0e3)] {
        let run = feel(name, k, 4.16);
        let kf = max_felt_stiffness(&run.states);
        let holds = hold_stats(&run.states);
        eprintln!(
            "{name}: k {k} N/m, scale {:.4}, max felt stiffness {:.1} N/m (limit {}), holds (probing, std N, mean N): {holds:?}",
            run.scale, kf, run.limit
        );
        assert!(kf > 0.0, "{name}: contact pairs measured");
        assert!(
            kf <= run.limit * 1.001,
            "{name}: felt stiffness {kf} N/m above the limit {}",
            run.limit
        );
        assert_eq!(holds.len(), 3, "{name}: three holds: {holds:?}");
        for (probing, std, mean) in holds {
            assert!(
                std <= 0.02,
                "{name}: probing {probing}: hold std {std} N (mean {mean} N)"
            );
            assert!(mean > 0.1, "{name}: probing {probing} pressed: {mean} N");
        }
    }
}

/// Felt normal force per stylus height quantum (key: height in µm), contact ticks of presses
/// and holds only, inside the device's range.
fn force_by_depth(states: &[DeviceState]) -> std::collections::BTreeMap<i64, (f64, u32)> {
    let mut m = std::collections::BTreeMap::new();
    for (_, b) in clean_pairs(states) {
        if b.phase != PRESS && b.phase != HOLD {
            continue;
        }
        let z_um = (b.proxy_pose.position[2] * 1e6).round() as i64;
        let e = m.entry(z_um).or_insert((0.0, 0));
        e.0 += b.rendered_force[2];
        e.1 += 1;
    }
    m
}

/// Grades 0/1/2 (modulus × 1, 0.795, 0.59) change the felt force at equal stylus depth by
/// their modulus ratio within 10%, on the table's typical stiffness under the probe.
#[test]
fn degeneration_grades_change_the_felt_force_by_their_modulus_ratio() {
    let _rig = one_rig_at_a_time();
    let k0 = 1.7e3;
    let grades = [(0, 1.0), (1, 1.0 - 0.205), (2, 1.0 - 0.41)];
    let runs: Vec<_> = grades
        .iter()
        .map(|(g, m)| (g, m, feel(&format!("feel-grade{g}"), k0 * m, 4.16)))
        .collect();
    let base = force_by_depth(&runs[0].2.states);
    for (g, m, run) in &runs[1..] {
        let by = force_by_depth(&run.states);
        // Common depths where both are well inside the device's range (> 0.1 N, < 0.88 N).
        let mut ratios: Vec<f64> = base
            .iter()
            .filter_map(|(z, (f0, n0))| {
                let (f, n) = by.get(z)?;
                let (f0, f) = (f0 / *n0 as f64, f / *n as f64);
                (f0 > 0.1 && f0 < 0.88 && f > 0.0).then_some(f / f0)
            })
            .collect();
        ratios.sort_by(f64::total_cmp);
        assert!(
            ratios.len() >= 5,
            "grade {g}: {} common depths",
            ratios.len()
        );
        let median = ratios[ratios.len() / 2];
        eprintln!(
            "grade {g}: felt force ratio to grade 0 at equal depth {median:.4} (modulus ratio {m}, {} depths, scale {:.4})",
            ratios.len(),
            run.scale
        );
        assert!(
            (median / **m - 1.0).abs() <= 0.10,
            "grade {g}: ratio {median} vs modulus ratio {m}"
        );
    }
}

/// The operator presses to a force as the study's examiner did: the hold force it feels is
/// the target through the scale, whatever the tissue's stiffness, and the stylus goes as deep
/// as the tissue lets it.
#[test]
fn the_operator_presses_to_a_felt_force_not_to_a_depth() {
    let _rig = one_rig_at_a_time();
    let target = 4.16;
    let mut depths = Vec::new();
    for (name, k) in [("press-soft", 0.8e3), ("press-stiff", 3.0e3)] {
        let run = feel(name, k, target);
        let felt_target = target * run.scale;
        let holds = hold_stats(&run.states);
        assert_eq!(holds.len(), 3, "{name}: {holds:?}");
        let deepest = run
            .states
            .iter()
            .map(|s| -s.proxy_pose.position[2])
            .fold(0.0, f64::max);
        eprintln!(
            "{name}: felt target {felt_target:.3} N, holds {holds:?}, deepest stylus {:.2} mm",
            deepest * 1e3
        );
        for (probing, _, mean) in holds {
            assert!(
                (mean / felt_target - 1.0).abs() < 0.15,
                "{name}: probing {probing} held {mean} N, target {felt_target} N"
            );
        }
        depths.push(deepest);
    }
    // Softer tissue, deeper press (not a fixed depth).
    assert!(depths[0] > 2.0 * depths[1], "{depths:?}");
}
