//! `probe-curve` on the default scene: the hook's tip carries the contact in the operator's
//! probing pose, degeneration grades scale the force by their modulus ratio, the curve is
//! quasi-static, and (issue 13, point 1) the curve against the cadaver table.

use physics_node::probe_curve::{self as pc, ForceTable, ProbeCurveOptions, Region};
use std::path::PathBuf;

const CADAVER: &str = "empirical/cadaver_probing_force_displacement.csv";

fn default_scene() -> launch_config::SceneConfig {
    launch_config::load_str(
        launch_config::DEFAULT_LAUNCH,
        launch_config::DEFAULT_LAUNCH_ORIGIN,
    )
    .expect("embedded default launch file")
    .scene
}

/// The cadaver table, required under CI (CI=true), skipped elsewhere when missing.
fn cadaver_table() -> Option<PathBuf> {
    let p = launch_config::data_dir().join(CADAVER);
    if p.is_file() {
        return Some(p);
    }
    assert!(
        std::env::var("CI").as_deref() != Ok("true"),
        "cadaver table missing in CI: {}",
        p.display()
    );
    eprintln!("skipped: {} not found (set ARTHROSIM_DATA)", p.display());
    None
}

#[test]
fn hook_tip_carries_the_contact_in_the_probing_pose() {
    let scene = default_scene();
    let data = launch_config::data_dir();
    for region in [Region::Posterior, Region::Mid, Region::Anterior] {
        let curve = pc::run(&scene, &data, &ProbeCurveOptions::new(region, 2.0e-3)).unwrap();
        // A rolled-back step is the last good state, not the tissue's response: a curve
        // through such steps measures the fault handling (it hid a diverging free-motion CG
        // on the soft fine mesh, every step rolled back).
        assert_eq!(
            curve.faulty_steps(),
            0,
            "{region:?}: physics faults in the press"
        );
        let loaded: Vec<_> = curve.points.iter().filter(|p| p.force_n > 0.0).collect();
        assert!(!loaded.is_empty(), "{region:?}: no force");
        // Every force-carrying contact lies on the tip ball or the hook next to it: within
        // 3.5 mm of the tip centre (ball radius 1.5 mm; the elbow is 3 mm away). The
        // 40 mm shaft, or an arm lying flat, would reach further.
        let reach = curve.max_active_reach_m();
        assert!(
            reach <= 3.5e-3,
            "{region:?}: a force-carrying contact {:.2} mm from the tip",
            reach * 1e3
        );
        // At first touch only the tip ball touches.
        let first = loaded[0];
        assert!(
            first.active_reach_m <= 1.6e-3,
            "{region:?}: first contact {:.2} mm from the tip centre",
            first.active_reach_m * 1e3
        );
    }
}

#[test]
fn grade_2_scales_the_force_by_the_modulus_ratio() {
    let scene = default_scene();
    let data = launch_config::data_dir();
    let depth = 1.0e-3;
    let force = |grade: f64| {
        let mut o = ProbeCurveOptions::new(Region::Mid, depth);
        o.grade = Some(grade);
        let c = pc::run(&scene, &data, &o).unwrap();
        c.force_at(depth).unwrap()
    };
    let (f0, f2) = (force(0.0), force(2.0));
    assert!(f0 > 0.0 && f2 > 0.0, "forces {f0} {f2}");
    let ratio = f2 / f0;
    // Fischenich et al. 2015: grade 2 = −41% equilibrium modulus.
    assert!(
        (ratio - 0.59).abs() <= 0.1 * 0.59,
        "grade 2 / grade 0 force at {} mm: {ratio:.3} (modulus ratio 0.59)",
        depth * 1e3
    );
}

#[test]
fn the_press_is_quasi_static() {
    // Halving the probe's travel per step must not change the curve: the tissue relaxes
    // within a step.
    let scene = default_scene();
    let data = launch_config::data_dir();
    let at = |step: f64| {
        let mut o = ProbeCurveOptions::new(Region::Mid, 1.0e-3);
        o.step_m = step;
        pc::run(&scene, &data, &o)
            .unwrap()
            .force_at(1.0e-3)
            .unwrap()
    };
    let (a, b) = (at(0.02e-3), at(0.01e-3));
    assert!(
        (a - b).abs() <= 0.03 * b.abs(),
        "force at 1 mm: {a:.4} N (0.02 mm steps) vs {b:.4} N (0.01 mm steps)"
    );
}

#[test]
fn table_errors_name_the_file_and_line() {
    let path = std::path::Path::new("lab/table.csv");
    let e = ForceTable::parse("displacement_mm,force_N\n0,0.3\n1.0,abc\n", path).unwrap_err();
    let s = e.to_string();
    assert!(s.contains("lab/table.csv:3") && s.contains("abc"), "{s}");
    let e = ForceTable::parse("displacement_mm,force_N\n0,0.3\n1,0.5\n0.5,0.7\n", path)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("lab/table.csv:4") && e.contains("increase"),
        "{e}"
    );
    let e = ForceTable::parse("disp,force\n0,0\n", path)
        .unwrap_err()
        .to_string();
    assert!(e.contains("lab/table.csv:1") && e.contains("header"), "{e}");
    let e = ForceTable::parse("displacement_mm,force_N\n0,0.3\n", path)
        .unwrap_err()
        .to_string();
    assert!(e.contains("lab/table.csv") && e.contains("rows"), "{e}");
    let t = ForceTable::parse("displacement_mm,force_N\n0.00,0.31\n7.62,7.51\n", path).unwrap();
    assert!((t.peak_n() - 7.20).abs() < 1e-12 && (t.max_displacement_m() - 7.62e-3).abs() < 1e-15);
}

/// Issue 13, point 1: the default scene reproduces the cadaver table (first row's 0.31 N
/// subtracted, displacement as measured) within 10% of its peak at every point, at the
/// mid-body site, with no step rolled back. The table is an outside reference: the scene's
/// support and stiffening were fitted to it, but the curve is the FEM's response.
#[test]
fn default_scene_reproduces_the_cadaver_table_at_mid() {
    let Some(path) = cadaver_table() else { return };
    let table = ForceTable::load(&path).unwrap();
    let scene = default_scene();
    let curve = pc::run(
        &scene,
        &launch_config::data_dir(),
        &ProbeCurveOptions::new(Region::Mid, table.max_displacement_m()),
    )
    .unwrap();
    assert_eq!(curve.faulty_steps(), 0, "physics faults in the press");
    let cmp = pc::compare(&curve, &table).unwrap();
    for p in &cmp.points {
        eprintln!(
            "{:.2} mm: table {:.2} N, simulated {:.2} N, error {:+.1}% of peak",
            p.displacement_m * 1e3,
            p.table_n,
            p.simulated_n,
            p.error_percent_of_peak
        );
    }
    assert!(
        cmp.max_error_percent_of_peak <= 10.0,
        "max error {:.2} N = {:.1}% of the table's peak {:.2} N",
        cmp.max_error_n,
        cmp.max_error_percent_of_peak,
        cmp.peak_n
    );
}

/// Issue 13, point 1 (a mesh fine enough where the probe touches): the calibrated response
/// is the tissue's, not the coarse mesh's. With the facets under the probe halved along the
/// arc (`default:lateral:44x3x2`, 5.8 → 2.9 mm; the support per inferior node scaled so its
/// total stays the same) the mid-site curve stays within 10% of the table's peak of the
/// default's at every table point, holds the tip's contact to the table's depth and still
/// reproduces the table. Measured: 6.6% against the table, against the default's 3.4%.
#[test]
fn the_calibrated_curve_holds_on_a_mesh_with_half_the_facet_length() {
    let Some(path) = cadaver_table() else { return };
    let table = ForceTable::load(&path).unwrap();
    let data = launch_config::data_dir();
    let opts = ProbeCurveOptions::new(Region::Mid, table.max_displacement_m());
    let default = default_scene();
    assert_eq!(default.meniscus.mesh, "default:lateral:coarse");
    let mut refined = default.clone();
    refined.meniscus.mesh = "default:lateral:44x3x2".into();
    // Inferior nodes: (arc + 1) × (radial + 1), 23 × 4 on the coarse mesh, 45 × 4 here.
    refined.meniscus.support_stiffness = default.meniscus.support_stiffness * 92.0 / 180.0;
    let coarse = pc::run(&default, &data, &opts).unwrap();
    let fine = pc::run(&refined, &data, &opts).unwrap();
    assert_eq!(fine.faulty_steps(), 0, "physics faults on the refined mesh");
    // The tip keeps the surface: the force never falls back by more than 10% on the way in.
    let mut peak: f64 = 0.0;
    for p in &fine.points {
        assert!(
            p.force_n >= 0.9 * peak - 0.05,
            "contact lost at {:.2} mm: {:.2} N after {:.2} N",
            p.displacement_m * 1e3,
            p.force_n,
            peak
        );
        peak = peak.max(p.force_n);
    }
    let cmp = pc::compare(&fine, &table).unwrap();
    for p in &cmp.points {
        let d = p.displacement_m;
        let (a, b) = (coarse.force_at(d).unwrap(), fine.force_at(d).unwrap());
        eprintln!(
            "{:.2} mm: table {:.2} N, coarse {a:.2} N, 44x3x2 {b:.2} N",
            d * 1e3,
            p.table_n
        );
        assert!(
            (b - a).abs() <= 0.10 * cmp.peak_n,
            "{:.2} mm: coarse {a:.2} N against 44x3x2 {b:.2} N",
            d * 1e3
        );
    }
    assert!(
        cmp.max_error_percent_of_peak <= 10.0,
        "refined mesh: max error {:.1}% of the table's peak",
        cmp.max_error_percent_of_peak
    );
}

#[test]
fn strain_stiffening_law_and_its_launch_keys() {
    use physics_node::fem::material::MAX_STIFFENING_FACTOR;
    use physics_node::fem::StrainStiffening;
    let law = StrainStiffening::new(4.0).unwrap();
    assert_eq!(law.factor(0.0), 1.0);
    assert!((law.factor(0.25) - 1.0f64.exp()).abs() < 1e-12);
    assert!(law.factor(0.5) > law.factor(0.25));
    assert_eq!(law.factor(100.0), MAX_STIFFENING_FACTOR);
    assert_eq!(StrainStiffening::NONE.factor(1.0), 1.0);
    assert!(StrainStiffening::new(-1.0).is_err());

    // Out-of-range launch keys name the key and the allowed range.
    let bad = with_key(launch_config::DEFAULT_LAUNCH, "strain_stiffening", "80.0");
    let e = launch_config::load_str(&bad, "bad.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("scene.material.strain_stiffening") && e.contains("50"),
        "{e}"
    );
    let bad = with_key(launch_config::DEFAULT_LAUNCH, "support_stiffness", "-1.0");
    let e = launch_config::load_str(&bad, "bad.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("scene.meniscus.support_stiffness") && e.contains("allowed"),
        "{e}"
    );
}

/// `text` with the value of the line that sets `key` replaced (the default launch file sets
/// each tissue key once).
fn with_key(text: &str, key: &str, value: &str) -> String {
    let mut found = false;
    let out: Vec<String> = text
        .lines()
        .map(|l| {
            if l.trim_start().starts_with(&format!("{key} =")) {
                found = true;
                format!("{key} = {value}")
            } else {
                l.to_string()
            }
        })
        .collect();
    assert!(found, "the default launch file sets no `{key}`");
    out.join("\n")
}
