//! End to end, issue 13 point 5: degeneration you can feel. The default session (real
//! physics, haptic and recorder processes, the emulated Touch with its quantisation, inertia
//! and grip) is run at grade 0 and at grade 2 with the operator pressing to the same depth.
//! From each session's MCAP, the force rendered to the hand at equal stylus depth on the two
//! presses must differ by the modulus ratio (Fischenich et al. 2015: grade 2 = −41%, ratio
//! 0.59) within 10%, inside the Touch's continuous range. At the holds the ratio is ≈ 0.66:
//! the grip lets the stylus sit 0.17 mm deeper on the softer tissue for the same hand target
//! (printed, not asserted).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// The wire codes of the press and the hold.
const PRESS: u32 = msgs::protocol::Phase::Press as u32;
const HOLD: u32 = msgs::protocol::Phase::Hold as u32;
/// Stylus depth every probing presses to, m.
const DEPTH_M: f64 = 0.004;
/// The Touch's continuous force, N.
const TOUCH_CONTINUOUS_N: f64 = 0.88;

/// The embedded default launch file with the value of each `key = …` line replaced.
fn default_with(keys: &[(&str, String)]) -> String {
    let mut text = String::new();
    let mut found = vec![false; keys.len()];
    for line in launch_config::DEFAULT_LAUNCH.lines() {
        let hit = keys
            .iter()
            .position(|(k, _)| line.trim_start().starts_with(&format!("{k} =")));
        match hit {
            Some(i) => {
                found[i] = true;
                text.push_str(&format!("{} = {}\n", keys[i].0, keys[i].1));
            }
            None => {
                text.push_str(line);
                text.push('\n');
            }
        }
    }
    for (i, f) in found.iter().enumerate() {
        assert!(f, "the default launch file sets no `{}`", keys[i].0);
    }
    text
}

/// Runs the session of `launch` for `seconds` and returns its folder.
fn run_session(bin: &Path, name: &str, launch: &str, seconds: u32) -> PathBuf {
    let out = std::env::temp_dir().join(format!("arthrosim-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    std::fs::create_dir_all(&out).unwrap();
    let file = out.with_extension("toml");
    std::fs::write(&file, launch).unwrap();
    let session = format!("{name}-{}", std::process::id());
    let mut command = Command::new(bin);
    command
        .arg("run")
        .arg(&file)
        .args(["--seconds", &seconds.to_string(), "--plain", "--out"])
        .arg(&out)
        .args(["--session", &session]);
    let output = tests::run_bounded(command, &session, Duration::from_secs(180));
    let context = format!(
        "--- stdout\n{}\n--- stderr\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(output.status.success(), "{name}: {context}");
    assert!(
        tests::processes_of_session(&session).is_empty(),
        "{name}: node processes left running\n{context}"
    );
    out
}

/// One probing's felt force against stylus position, from its press and hold ticks in
/// contact: (stylus position, |rendered force|), in tick order.
struct Probing {
    region: u32,
    samples: Vec<([f64; 3], f64)>,
    hold_from: usize,
    /// Press and hold ticks in contact left out because the envelope faded or zeroed their
    /// force, and all of them.
    faded: usize,
    ticks: usize,
}

/// A tick whose force is the safety envelope's fade or quarantine, not the tissue's (stale or
/// invalid frame, a physics fault, non-finite input): what the hand feels there is asserted
/// by the safety tests, not here. A CI run once read 0 N at the last crossing of the press
/// depth in one region at grade 2, where a rerun felt 0.094 N.
const FADE: u32 = msgs::haptic_to_physics::fault::STALE_FRAME
    | msgs::haptic_to_physics::fault::INVALID_FRAME
    | msgs::haptic_to_physics::fault::FOREIGN_FRAME
    | msgs::haptic_to_physics::fault::PHYSICS_FAULT
    | msgs::haptic_to_physics::fault::NONFINITE_DEVICE
    | msgs::haptic_to_physics::fault::NONFINITE_FORCE;

/// The first probing of each region (1 posterior, 2 mid, 3 anterior).
fn probings(session_dir: &Path) -> Vec<Probing> {
    let (_, ticks) = recordings::export::read_lossless(&session_dir.join("session.mcap"))
        .unwrap_or_else(|e| panic!("reading {}: {e}", session_dir.display()));
    let mut out = Vec::new();
    for region in 1..=3 {
        let Some(first) = ticks
            .iter()
            .find(|t| t.region == region && t.phase == PRESS)
            .map(|t| t.probing_index)
        else {
            continue;
        };
        let mut p = Probing {
            region,
            samples: Vec::new(),
            hold_from: 0,
            faded: 0,
            ticks: 0,
        };
        for t in ticks.iter().filter(|t| {
            t.probing_index == first && (t.phase == PRESS || t.phase == HOLD) && t.contact_count > 0
        }) {
            p.ticks += 1;
            if t.faults & FADE != 0 {
                p.faded += 1;
                continue;
            }
            if t.phase == HOLD && p.hold_from == 0 {
                p.hold_from = p.samples.len();
            }
            let q = &t.proxy_pose.position;
            let f = &t.rendered_force;
            p.samples
                .push(([q.x, q.y, q.z], (f.x * f.x + f.y * f.y + f.z * f.z).sqrt()));
        }
        if p.hold_from > 0 && p.hold_from < p.samples.len() {
            out.push(p);
        }
    }
    out
}

fn mean_of(samples: &[([f64; 3], f64)]) -> ([f64; 3], f64) {
    let n = samples.len() as f64;
    let mut p = [0.0; 3];
    let mut f = 0.0;
    for (q, g) in samples {
        for k in 0..3 {
            p[k] += q[k] / n;
        }
        f += g / n;
    }
    (p, f)
}

/// Felt force of `probing` at stylus depth `depth` along `dir` from `origin`, m: linear
/// between the press's samples (the hand's grip lets a softer tissue's stylus sit a little
/// deeper at the same hand target, so equal depth is taken on the press, not at the hold).
fn felt_at(probing: &Probing, origin: [f64; 3], dir: [f64; 3], depth: f64) -> Option<f64> {
    let along = |q: [f64; 3]| (0..3).map(|k| (q[k] - origin[k]) * dir[k]).sum::<f64>();
    let mut best: Option<(f64, f64)> = None;
    for w in probing.samples.windows(2) {
        let (a, b) = (along(w[0].0), along(w[1].0));
        if (a - depth) * (b - depth) <= 0.0 && (b - a).abs() > 1e-9 {
            let u = (depth - a) / (b - a);
            let f = w[0].1 + u * (w[1].1 - w[0].1);
            // The last crossing: the press ends there, after any grip oscillation.
            best = Some((a, f));
        }
    }
    best.map(|(_, f)| f)
}

#[test]
fn grade_2_is_felt_by_its_modulus_ratio_at_equal_stylus_depth() {
    let bin = tests::workspace_binary("arthrosim", "arthrosim");
    let mut measured = Vec::new();
    for grade in [0.0, 2.0] {
        let launch = default_with(&[
            ("degeneration_grade", format!("{grade:.1}")),
            // To a depth, not to a force: the same hand target at both grades.
            ("press_force_n", "0.0".into()),
            ("press_depth_m", format!("{DEPTH_M}")),
            ("probings_per_region", "1".into()),
            ("hold_s", "1.0".into()),
        ]);
        let dir = run_session(&bin, &format!("felt-grade{grade}"), &launch, 14);
        let p = probings(&dir);
        let _ = std::fs::remove_dir_all(&dir);
        // and the launch file written beside it (56 were left in /tmp before)
        let _ = std::fs::remove_file(dir.with_extension("toml"));
        measured.push(p);
    }
    let (g0, g2) = (&measured[0], &measured[1]);
    let mut compared = 0;
    let mut off = Vec::new();
    for p0 in g0 {
        let Some(p2) = g2.iter().find(|p| p.region == p0.region) else {
            continue;
        };
        for p in [p0, p2] {
            // a fade is the exception: the felt curve is the tissue's
            assert!(
                p.faded * 5 <= p.ticks,
                "region {}: {} of {} press and hold ticks faded by the envelope",
                p.region,
                p.faded,
                p.ticks
            );
        }
        // Depth along grade 0's press direction (first contact → mean hold position), at
        // grade 0's hold: the same stylus position for both grades.
        let origin = p0.samples[0].0;
        let (hold0, f0) = mean_of(&p0.samples[p0.hold_from..]);
        let d: Vec<f64> = (0..3).map(|k| hold0[k] - origin[k]).collect();
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!(
            len > 1e-3,
            "region {}: a press of {:.3} mm",
            p0.region,
            len * 1e3
        );
        let dir = [d[0] / len, d[1] / len, d[2] / len];
        let (hold2, f2_hold) = mean_of(&p2.samples[p2.hold_from..]);
        // Inside both presses: 90% of grade 0's hold depth.
        let depth = 0.9 * len;
        let at = |p: &Probing, grade: u32| {
            felt_at(p, origin, dir, depth).unwrap_or_else(|| {
                panic!(
                    "region {}: grade {grade}'s press never reached {:.3} mm",
                    p0.region,
                    depth * 1e3
                )
            })
        };
        let (f0_press, f2) = (at(p0, 0), at(p2, 2));
        let ratio = f2 / f0_press;
        let apart = ((hold0[0] - hold2[0]).powi(2)
            + (hold0[1] - hold2[1]).powi(2)
            + (hold0[2] - hold2[2]).powi(2))
        .sqrt();
        eprintln!(
            "region {}: at {:.3} mm felt {f0_press:.4} N at grade 0 and {f2:.4} N at grade 2, \
             ratio {ratio:.3} (holds {:.3} mm apart: {f0:.4} and {f2_hold:.4} N, ratio {:.3})",
            p0.region,
            depth * 1e3,
            apart * 1e3,
            f2_hold / f0
        );
        assert!(
            f0 > 0.02 && f0 <= TOUCH_CONTINUOUS_N,
            "region {}: felt {f0:.4} N at grade 0, outside (0.02, 0.88] N",
            p0.region
        );
        if (ratio - 0.59).abs() > 0.1 * 0.59 {
            off.push(format!("region {}: {ratio:.3}", p0.region));
        }
        compared += 1;
    }
    assert!(
        off.is_empty(),
        "grade 2 / grade 0 felt force outside the modulus ratio 0.59 ± 10%: {}",
        off.join(", ")
    );
    assert!(
        compared >= 2,
        "holds in fewer than two regions at both grades"
    );
}
