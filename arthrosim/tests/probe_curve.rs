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
    assert_meets_table(&curve, &table);
}

/// Issue 13 point 1: no physics fault in the press, and within 10% of the table's peak at
/// every table point (printed either way).
fn assert_meets_table(curve: &pc::ProbeCurve, table: &ForceTable) {
    assert_eq!(curve.faulty_steps(), 0, "physics faults in the press");
    let cmp = pc::compare(curve, table).unwrap();
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

/// The shipped study-scene calibration (`launch-config/launch/study_lateral_calibrated.toml`).
fn study_calibrated_scene() -> launch_config::SceneConfig {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../launch-config/launch/study_lateral_calibrated.toml"
    );
    launch_config::load(std::path::Path::new(path))
        .expect("study_lateral_calibrated.toml")
        .scene
}

/// Issue 13: the study scenes get the same calibration as an option. On the study's mesh the
/// table is pressed at the posterior site (its mid body is a 45–52° wall the frictionless tip
/// slides down past 6.8 mm; see the launch file).
#[test]
fn the_calibrated_study_scene_reproduces_the_cadaver_table_at_posterior() {
    let Some(path) = cadaver_table() else { return };
    let table = ForceTable::load(&path).unwrap();
    let scene = study_calibrated_scene();
    assert_eq!(scene.meniscus.mesh, "study:lateral");
    let data = launch_config::data_dir();
    let curve = pc::run(
        &scene,
        &data,
        &ProbeCurveOptions::new(Region::Posterior, table.max_displacement_m()),
    )
    .unwrap();
    assert_meets_table(&curve, &table);
    // the grade still scales the tissue by its modulus ratio on this mesh
    let depth = 1.0e-3;
    let force = |grade: f64| {
        let mut o = ProbeCurveOptions::new(Region::Posterior, depth);
        o.grade = Some(grade);
        pc::run(&scene, &data, &o).unwrap().force_at(depth).unwrap()
    };
    let ratio = force(2.0) / force(0.0);
    assert!(
        (ratio - 0.59).abs() <= 0.1 * 0.59,
        "grade 2 / grade 0 at 1 mm: {ratio:.3}"
    );
}

/// The default scene on chosen divisions `ARCxRADIALxVERTICAL`, with its support per inferior
/// node scaled so that the total support stays the default's ((arc + 1) × (radial + 1)
/// inferior nodes).
fn on_divisions(default: &launch_config::SceneConfig, spec: &str) -> launch_config::SceneConfig {
    let inferior = |mesh: &str| {
        let divisions = mesh.rsplit(':').next().unwrap();
        let [arc, radial, _] = launch_config::scene::parse_mesh_divisions(divisions)
            .unwrap_or_else(|| panic!("{mesh}: not chosen divisions"));
        ((arc + 1) * (radial + 1)) as f64
    };
    let mut refined = default.clone();
    refined.meniscus.mesh = format!("default:lateral:{spec}");
    refined.meniscus.support_stiffness = default.meniscus.support_stiffness
        * inferior(&default.meniscus.mesh)
        / inferior(&refined.meniscus.mesh);
    refined
}

/// Issue 13, point 1 (a mesh fine enough where the probe touches): the calibrated response
/// is the tissue's, not the default mesh's. Refined once more along the arc (`88x3x2`, facets
/// 2.9 → 1.45 mm) and through the thickness (`44x3x3`), with the total support kept, the
/// mid-site curve stays within 5% of the table's peak of the default's at every table point,
/// holds the tip's contact to the table's depth and still reproduces the table. Measured:
/// at most 2.4% of the peak between the meshes.
#[test]
fn the_default_curve_is_mesh_converged_at_mid() {
    let Some(path) = cadaver_table() else { return };
    let table = ForceTable::load(&path).unwrap();
    let data = launch_config::data_dir();
    let opts = ProbeCurveOptions::new(Region::Mid, table.max_displacement_m());
    let default = default_scene();
    let base = pc::run(&default, &data, &opts).unwrap();
    for spec in ["88x3x2", "44x3x3"] {
        let refined = on_divisions(&default, spec);
        let fine = pc::run(&refined, &data, &opts).unwrap();
        assert_eq!(
            fine.faulty_steps(),
            0,
            "{spec}: physics faults in the press"
        );
        // The tip keeps the surface: the force never falls back by more than 10% on the way in.
        let mut peak: f64 = 0.0;
        for p in &fine.points {
            assert!(
                p.force_n >= 0.9 * peak - 0.05,
                "{spec}: contact lost at {:.2} mm: {:.2} N after {:.2} N",
                p.displacement_m * 1e3,
                p.force_n,
                peak
            );
            peak = peak.max(p.force_n);
        }
        let cmp = pc::compare(&fine, &table).unwrap();
        for p in &cmp.points {
            let d = p.displacement_m;
            let (a, b) = (base.force_at(d).unwrap(), fine.force_at(d).unwrap());
            eprintln!(
                "{:.2} mm: table {:.2} N, default {a:.2} N, {spec} {b:.2} N",
                d * 1e3,
                p.table_n
            );
            assert!(
                (b - a).abs() <= 0.05 * cmp.peak_n,
                "{:.2} mm: default {a:.2} N against {spec} {b:.2} N",
                d * 1e3
            );
        }
        assert!(
            cmp.max_error_percent_of_peak <= 10.0,
            "{spec}: max error {:.1}% of the table's peak",
            cmp.max_error_percent_of_peak
        );
    }
}

/// What broke: with undamped free motions (`rayleigh_stiffness` 0) the nearly free body
/// sprang back by the whole press in every free motion, the contact's linearisation failed on
/// facets shorter than that rebound, and on the default mesh the posterior press lost the
/// tip's force past 7 mm (4.6 N at 7.62 mm, −35% of the table's peak). With the default's
/// damping both horns follow the mid-body table within 10% of its peak.
#[test]
fn undamped_free_motion_lost_the_tip_on_the_default_mesh() {
    let Some(path) = cadaver_table() else { return };
    let table = ForceTable::load(&path).unwrap();
    let data = launch_config::data_dir();
    let default = default_scene();
    assert!(default.material.rayleigh_stiffness > 0.0);
    for region in [Region::Posterior, Region::Anterior] {
        let opts = ProbeCurveOptions::new(region, table.max_displacement_m());
        let curve = pc::run(&default, &data, &opts).unwrap();
        assert_eq!(curve.faulty_steps(), 0, "{region:?}: physics faults");
        let cmp = pc::compare(&curve, &table).unwrap();
        // The table is a mid-body site's; the horns differ from it by less than 10% of its peak.
        assert!(
            cmp.max_error_percent_of_peak <= 10.0,
            "{region:?}: max error {:.1}% of the table's peak",
            cmp.max_error_percent_of_peak
        );
    }
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
