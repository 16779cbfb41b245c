//! Regression: a ball pressed deep into the study's anterior horn made the force alternate
//! step to step (48 ↔ 108 … 72 ↔ 141 N, the contact count 1 ↔ 4–13) with no physics fault
//! raised. Under the ball the horn was crushed so thin that its held inferior face was nearer
//! the ball's centre than the dent the ball sat in; the nearest-feature test then called the
//! centre inside the tissue, and detection kept only the tracked triangle for that step. The
//! gap diagnosis' deep replay knots carried it unflagged (3–5% of the proxy sets' replays).

use physics_node::probe_curve::{self, ProbeCurveOptions, Region};

/// One-sample swings: a step whose force is more than 20% and 1 N off both neighbours, on the
/// same side of both, while the neighbours agree with each other to within that.
fn swings(forces: &[f64]) -> Vec<usize> {
    let off = |x: f64, y: f64| (x - y).abs() > (0.2 * x.abs().max(y.abs())).max(1.0);
    (1..forces.len().saturating_sub(1))
        .filter(|&k| {
            let (a, f, b) = (forces[k - 1], forces[k], forces[k + 1]);
            off(f, a) && off(f, b) && (f - a).signum() == (f - b).signum() && !off(a, b)
        })
        .collect()
}

#[test]
fn a_ball_crushing_the_anterior_horn_does_not_chatter() {
    let Some(data) = physics_node::fem::test_meshes::study_data("deep_press_chatter") else {
        return;
    };
    let launch = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../launch-config/launch/study_lateral.toml"
    );
    let mut scene = launch_config::load(launch).unwrap().scene;
    // As the gap diagnosis replays a ball-tipped indenter: the ball alone, 20 ms steps.
    scene.probe.model = "sphere".into();
    scene.dt = 0.02;
    let mut opts = ProbeCurveOptions::new(Region::Anterior, 4e-3);
    opts.step_m = 0.04e-3;
    let curve = probe_curve::run(&scene, &data, &opts).unwrap();
    // Up to the crushing limit, where the physics' own checks take over (a faulty step is
    // rolled back and flagged, not rendered).
    let sound: Vec<_> = curve
        .points
        .iter()
        .take_while(|p| p.physics_faults == 0)
        .collect();
    for p in &sound {
        println!(
            "{:.2} mm  {:8.2} N  {:2} contacts",
            p.displacement_m * 1e3,
            p.force_n,
            p.contacts
        );
    }
    let deepest = sound.last().map_or(0.0, |p| p.displacement_m);
    assert!(
        deepest > 2.5e-3,
        "the press went only {:.2} mm without a fault",
        deepest * 1e3
    );
    let forces: Vec<f64> = sound.iter().map(|p| p.force_n).collect();
    let bad = swings(&forces);
    assert!(
        bad.is_empty(),
        "the force swings step to step at {:?} mm: {:?} N",
        bad.iter()
            .map(|&k| sound[k].displacement_m * 1e3)
            .collect::<Vec<_>>(),
        bad.iter().map(|&k| forces[k]).collect::<Vec<_>>()
    );
    // In contact from first touch to the deepest sound step.
    let first = forces.iter().position(|&f| f > 0.0).unwrap();
    assert!(
        forces[first..].iter().all(|&f| f > 0.0),
        "contact lost during the press"
    );
}

#[test]
fn the_swing_check_finds_an_alternation() {
    let mut f: Vec<f64> = (0..20).map(|k| 10.0 + k as f64).collect();
    assert!(swings(&f).is_empty());
    f[9] = 40.0;
    assert_eq!(swings(&f), vec![9]);
    f[9] = 3.0;
    assert_eq!(swings(&f), vec![9]);
}
