//! Launch files: broken ones give errors naming file, line, column and key; the shipped
//! examples validate.

use launch_config::{load, load_str, LaunchError, LaunchFile};
use std::path::{Path, PathBuf};

fn scratch(name: &str) -> PathBuf {
    let dir =
        std::env::temp_dir().join(format!("launch-config-test-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write(dir: &Path, file: &str, text: &str) -> PathBuf {
    let p = dir.join(file);
    std::fs::write(&p, text).unwrap();
    p
}

/// The single issue of an invalid file, with its rendered message.
fn only_issue(err: LaunchError) -> (launch_config::Issue, String) {
    let text = err.to_string();
    let issues = err.issues().to_vec();
    assert_eq!(issues.len(), 1, "expected one issue, got: {text}");
    (issues[0].clone(), text)
}

#[test]
fn unknown_key_names_file_line_key_and_allowed_keys() {
    let dir = scratch("unknown");
    let path = write(
        &dir,
        "bad.toml",
        "[session]\nname = \"x\"\n\n[scene]\ndt = 0.01\ntime_step = 0.02\n",
    );
    let (issue, text) = only_issue(load(&path).unwrap_err());
    assert_eq!(issue.key, "scene.time_step");
    assert_eq!((issue.line, issue.column), (Some(6), Some(1)));
    assert!(text.contains("bad.toml:6:1"), "{text}");
    assert!(text.contains("unknown field `time_step`"), "{text}");
    assert!(
        text.contains("`dt`") && text.contains("`meniscus`"),
        "allowed keys listed: {text}"
    );
}

#[test]
fn unknown_nested_key_and_unknown_section() {
    let (issue, _) = only_issue(
        load_str(
            "[scene.contact]\nfriction = 0.1\nmu = 0.2\n",
            Path::new("x/nested.toml"),
        )
        .unwrap_err(),
    );
    assert_eq!(issue.key, "scene.contact.mu");
    assert_eq!(issue.line, Some(3));
    let (issue, text) =
        only_issue(load_str("[physics]\ndt = 1\n", Path::new("sect.toml")).unwrap_err());
    assert_eq!(issue.key, "physics");
    assert_eq!(issue.line, Some(1));
    assert!(
        text.contains("`scene`") && text.contains("`launcher`"),
        "{text}"
    );
}

#[test]
fn wrong_type_names_key_and_expected_type() {
    let (issue, text) =
        only_issue(load_str("[scene]\ndt = \"fast\"\n", Path::new("dir/wrong.toml")).unwrap_err());
    assert_eq!(issue.key, "scene.dt");
    assert_eq!(issue.line, Some(2));
    assert!(text.starts_with("dir/wrong.toml:2:"), "{text}");
    assert!(
        text.contains("invalid type") && text.contains("f64"),
        "{text}"
    );

    let (issue, _) = only_issue(
        load_str(
            "[scene]\ngravity = [0.0, 0.0, \"down\"]\n",
            Path::new("g.toml"),
        )
        .unwrap_err(),
    );
    assert_eq!(issue.key, "scene.gravity[2]");
    assert_eq!(issue.line, Some(2));
}

#[test]
fn negative_dt_is_a_named_semantic_error() {
    let dir = scratch("dt");
    let path = write(&dir, "neg.toml", "# comment\n[scene]\n\n  dt = -0.01\n");
    let (issue, text) = only_issue(load(&path).unwrap_err());
    assert_eq!(issue.key, "scene.dt");
    assert_eq!((issue.line, issue.column), (Some(4), Some(3)));
    assert!(text.contains("neg.toml:4:3"), "{text}");
    assert!(text.contains("> 0"), "says what is allowed: {text}");
    let err = load_str("scene.dt = nan\n", Path::new("nan.toml")).unwrap_err();
    assert_eq!(err.issues()[0].key, "scene.dt");
}

/// The built-in probe models load as themselves; `sphere` (an indentation test's ball) used
/// to be read as a relative OBJ path and refused.
#[test]
fn builtin_probe_models_are_not_paths() {
    let dir = scratch("probe-model");
    for model in ["default", "hook", "sphere"] {
        let text = format!("[scene.probe]\nmodel = \"{model}\"\n");
        let file = load(write(&dir, "probe.toml", &text)).unwrap();
        assert_eq!(file.scene.probe.model, model);
    }
    let (issue, text) = only_issue(
        load(write(
            &dir,
            "ball.toml",
            "[scene.probe]\nmodel = \"ball\"\n",
        ))
        .unwrap_err(),
    );
    assert_eq!(issue.key, "scene.probe.model");
    assert!(
        text.contains("`sphere`"),
        "names the built-in models: {text}"
    );
}

#[test]
fn missing_mesh_is_resolved_against_the_launch_file_folder() {
    let dir = scratch("mesh");
    let path = write(
        &dir,
        "m.toml",
        "[scene.meniscus]\nmesh = \"meshes/absent.msh\"\n",
    );
    let (issue, text) = only_issue(load(&path).unwrap_err());
    assert_eq!(issue.key, "scene.meniscus.mesh");
    assert_eq!(issue.line, Some(2));
    let expected = std::path::absolute(dir.join("meshes/absent.msh")).unwrap();
    assert!(text.contains(&expected.display().to_string()), "{text}");
    assert!(text.contains("does not exist"), "{text}");

    // Once it exists, the file loads and the path it carries is absolute.
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    std::fs::write(
        dir.join("meshes/absent.msh"),
        "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n",
    )
    .unwrap();
    let file = load(&path).unwrap();
    assert_eq!(Path::new(&file.scene.meniscus.mesh), expected);
}

#[test]
fn bad_specs_and_ranges_are_all_reported_with_lines() {
    let text = "[session]\nname = \"a b\"\n[nodes]\nphysics = true\n[scene.meniscus]\nmesh = \"default:lateral:huge\"\n\
                [scene.material]\npoisson_ratio = 0.5\n[scene.contact]\nfriction = -0.1\n[scene.probe]\nmass = 0.0\n\
                [device]\nbackend = \"joystick\"\n[launcher]\nrestart = \"on-failure\"\nstop_grace_s = 0\n";
    let err = load_str(text, Path::new("many.toml")).unwrap_err();
    let keys: Vec<(&str, Option<usize>)> = err
        .issues()
        .iter()
        .map(|i| (i.key.as_str(), i.line))
        .collect();
    for (key, line) in [
        ("session.name", 2),
        ("scene.meniscus.mesh", 6),
        ("scene.material.poisson_ratio", 8),
        ("scene.contact.friction", 10),
        ("scene.probe.mass", 12),
        ("device.backend", 14),
        ("launcher.stop_grace_s", 17),
    ] {
        assert!(
            keys.contains(&(key, Some(line))),
            "{key} at line {line} missing in {keys:?}"
        );
    }
    let rendered = err.to_string();
    assert!(
        rendered.contains("`touch`, `emulated`, `replay`"),
        "{rendered}"
    );
}

#[test]
fn chosen_mesh_divisions_are_a_mesh_spec_within_bounds() {
    // A convergence study names its divisions; they load like `coarse`.
    for spec in [
        "default:lateral:44x3x2",
        "default:medial:22x3x2",
        "default:lateral:1x1x1",
    ] {
        let text = format!("[scene.meniscus]\nmesh = \"{spec}\"\n");
        let file = load_str(&text, Path::new("divisions.toml")).unwrap();
        assert_eq!(file.scene.meniscus.mesh, spec);
    }
    // Zero, signs, missing or extra parts, and a mesh beyond the node bound are refused at
    // the key's line, naming what is allowed.
    for bad in [
        "0x3x2",
        "44x3",
        "44x3x2x1",
        "44x-3x2",
        "44x+3x2",
        "44x3x",
        "x3x2",
        "400x400x400",
        "18446744073709551615x2x2",
    ] {
        let text = format!(
            "[session]\nname = \"d\"\n[scene.meniscus]\nmesh = \"default:lateral:{bad}\"\n"
        );
        let (issue, rendered) =
            only_issue(load_str(&text, Path::new("divisions.toml")).unwrap_err());
        assert_eq!(issue.key, "scene.meniscus.mesh", "{bad}");
        assert_eq!(issue.line, Some(4), "{bad}");
        assert!(
            rendered.contains("ARCxRADIALxVERTICAL"),
            "{bad}: {rendered}"
        );
    }
    assert_eq!(
        launch_config::scene::parse_mesh_divisions("44x3x2"),
        Some([44, 3, 2])
    );
    // 45 × 4 × 3 = 540 nodes; the bound is on nodes, not on any one count.
    assert!(launch_config::scene::parse_mesh_divisions("1000x1x1").is_some());
    assert!(launch_config::scene::parse_mesh_divisions("100000x1x1").is_none());
}

#[test]
fn solver_matrix_precision_and_stiffness_tolerance_are_checked() {
    let text = "[scene.solver]\ncg_matrix = \"f16\"\nstiffness_rotation_tolerance = 1.0\n";
    let err = load_str(text, Path::new("solver.toml")).unwrap_err();
    let keys: Vec<(&str, Option<usize>)> = err
        .issues()
        .iter()
        .map(|i| (i.key.as_str(), i.line))
        .collect();
    assert!(
        keys.contains(&("scene.solver.cg_matrix", Some(2))),
        "{keys:?}"
    );
    assert!(
        keys.contains(&("scene.solver.stiffness_rotation_tolerance", Some(3))),
        "{keys:?}"
    );
    let rendered = err.to_string();
    assert!(rendered.contains("`f32`, `f64`"), "{rendered}");
    assert!(rendered.contains("too lax"), "{rendered}");
    let ok = "[scene.solver]\ncg_matrix = \"f64\"\nstiffness_rotation_tolerance = 0.0\n";
    let file = load_str(ok, Path::new("solver.toml")).unwrap();
    assert_eq!(
        file.scene.solver.cg_matrix,
        launch_config::scene::CgMatrix::F64
    );
}

#[test]
fn unknown_restart_policy_lists_the_variants() {
    let (issue, text) = only_issue(
        load_str("[launcher]\nrestart = \"always\"\n", Path::new("r.toml")).unwrap_err(),
    );
    assert_eq!(issue.key, "launcher.restart");
    assert!(
        text.contains("never") && text.contains("on-failure"),
        "{text}"
    );
}

#[test]
fn syntax_error_has_line_and_column() {
    let (issue, text) = only_issue(
        load_str(
            "[scene]\ndt = 0.01\nfriction = = 2\n",
            Path::new("syn.toml"),
        )
        .unwrap_err(),
    );
    assert_eq!(issue.line, Some(3));
    assert!(text.contains("syn.toml:3:"), "{text}");
    assert!(text.contains("TOML syntax error"), "{text}");
}

#[test]
fn unreadable_file_names_the_path() {
    let err = load("/nonexistent/launch.toml").unwrap_err();
    assert!(err.to_string().contains("/nonexistent/launch.toml"));
}

#[test]
fn empty_file_is_the_defaults() {
    let file = load_str("", Path::new("empty.toml")).unwrap();
    assert_eq!(file, LaunchFile::default());
}

#[test]
fn embedded_default_validates() {
    let file = load_str(
        launch_config::DEFAULT_LAUNCH,
        launch_config::DEFAULT_LAUNCH_ORIGIN,
    )
    .unwrap();
    assert!(file.nodes.physics && file.nodes.haptic && file.nodes.bridge && file.nodes.recorder);
    assert_eq!(
        file.device.backend,
        launch_config::device::DeviceBackend::Emulated
    );
}

fn examples_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("launch")
}

fn study_data_present() -> bool {
    launch_config::data_dir()
        .join("meniscus/lateral_meniscus_computation.msh")
        .is_file()
}

#[test]
fn shipped_examples_validate() {
    let mut checked = 0;
    for entry in std::fs::read_dir(examples_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("toml") {
            continue;
        }
        let needs_study = std::fs::read_to_string(&path).unwrap().contains("\"study:");
        if needs_study && !study_data_present() {
            assert!(std::env::var("CI").is_err(), "study data missing in CI");
            eprintln!("skipping {} (study data not found)", path.display());
            continue;
        }
        if let Err(e) = load(&path) {
            panic!("{e}");
        }
        checked += 1;
    }
    assert!(
        checked >= 3,
        "expected the example launch files, checked {checked}"
    );
}

#[test]
fn study_specs_are_checked() {
    let file = load_str(
        "[scene.meniscus]\nmesh = \"study:medial\"\n",
        Path::new("s.toml"),
    );
    if study_data_present() {
        assert!(file.is_ok(), "{:?}", file.err());
    }
    let (issue, _) = only_issue(
        load_str(
            "[scene.meniscus]\nmesh = \"study:knee\"\n",
            Path::new("s.toml"),
        )
        .unwrap_err(),
    );
    assert_eq!(issue.key, "scene.meniscus.mesh");
}

#[test]
fn resolved_file_round_trips_through_toml() {
    let file = load(examples_dir().join("default.toml")).unwrap();
    let text = toml::to_string(&file).unwrap();
    let again = load_str(&text, Path::new("resolved.toml")).unwrap();
    assert_eq!(again, file);
}

#[test]
fn every_bad_choice_is_reported_at_once_with_its_line_and_allowed_values() {
    let text = "[scene.material]\nmodel = \"mooney\"\n[scene.solver]\nkind = \"gmres\"\nrotation = \"large\"\n\
                [device]\nbackend = \"joystick\"\ndisplacement_reference = \"probe\"\n\
                [device.emulated]\nsites = 'mesh'\n[launcher]\nrestart = \"always\"\n";
    let err = load_str(text, Path::new("choices.toml")).unwrap_err();
    let keys: Vec<(&str, Option<usize>)> = err
        .issues()
        .iter()
        .map(|i| (i.key.as_str(), i.line))
        .collect();
    assert_eq!(
        keys,
        [
            ("scene.material.model", Some(2)),
            ("scene.solver.kind", Some(4)),
            ("scene.solver.rotation", Some(5)),
            ("device.backend", Some(7)),
            ("device.displacement_reference", Some(8)),
            ("device.emulated.sites", Some(10)),
            ("launcher.restart", Some(12)),
        ]
    );
    let rendered = err.to_string();
    for line in [
        "choices.toml:2:1: key `scene.material.model`: \"mooney\" is not allowed; allowed: `corotational`, `neo-hookean`",
        "choices.toml:7:1: key `device.backend`: \"joystick\" is not allowed; allowed: `touch`, `emulated`, `replay`",
        "choices.toml:10:1: key `device.emulated.sites`: \"mesh\" is not allowed; allowed: `scene`, `plane`",
        "key `launcher.restart`: \"always\" is not allowed; allowed: `never`, `on-failure`",
    ] {
        assert!(rendered.contains(line), "{line}\nnot in\n{rendered}");
    }
    // A good choice parses into its enum, once.
    let file = load_str(
        "[scene.solver]\nkind = \"cg-warped-cholesky\"\n[device.emulated]\nsites = \"plane\"\n",
        Path::new("ok.toml"),
    )
    .unwrap();
    assert_eq!(
        file.scene.solver.kind,
        launch_config::scene::SolverKind::CgWarpedCholesky
    );
    assert_eq!(
        file.device.emulated.sites,
        launch_config::device::SiteSource::Plane
    );
}

/// Device limits are invariants: a launch file may lower them, a raise is an error naming
/// the key, the value and the device's limit (the review's `peak_force_n = 30`).
#[test]
fn raising_a_device_limit_is_refused_with_key_value_and_limit() {
    let dir = scratch("limits");
    for (key, value, limit) in [
        ("peak_force_n", "30", "3.3"),
        ("continuous_force_n", "2.5", "0.88"),
        ("max_force_rate_n_per_s", "5000", "400"),
        ("max_stiffness_n_per_m", "2310", "1020"),
    ] {
        let path = write(&dir, "raise.toml", &format!("[device]\n{key} = {value}\n"));
        let (issue, text) = only_issue(load(&path).unwrap_err());
        assert_eq!(issue.key, format!("device.{key}"), "{text}");
        assert_eq!(issue.line, Some(2), "{text}");
        assert!(
            text.contains(value) && text.contains(limit) && text.contains("Touch"),
            "names the value, the limit and the device: {text}"
        );
    }
    // Lowering is fine, and so is the limit itself.
    let path = write(
        &dir,
        "lower.toml",
        "[device]\npeak_force_n = 2.0\ncontinuous_force_n = 0.5\nmax_force_rate_n_per_s = 100\nmax_stiffness_n_per_m = 1020\n",
    );
    let f = load(&path).unwrap();
    assert_eq!(f.device.peak_force_n, 2.0);
    // The rendering follows the lowered limits: felt stiffness bound = scale × coupling.
    let r = f.device.rendering();
    assert!((r.force_scale * r.coupling_stiffness_n_per_m - 1020.0).abs() < 1e-9);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn servo_watchdog_and_force_scale_are_bounded() {
    let dir = scratch("watchdog");
    for (text, key) in [
        (
            "[device.touch]\nservo_watchdog_s = 5.0\n",
            "device.touch.servo_watchdog_s",
        ),
        (
            "[device.touch]\nservo_watchdog_s = 0.0\n",
            "device.touch.servo_watchdog_s",
        ),
        (
            "[device.touch]\nservo_watchdog_s = nan\n",
            "device.touch.servo_watchdog_s",
        ),
        ("[device]\nforce_scale = 3.0\n", "device.force_scale"),
        ("[device]\nforce_scale = -1.0\n", "device.force_scale"),
    ] {
        let path = write(&dir, "w.toml", text);
        let (issue, msg) = only_issue(load(&path).unwrap_err());
        assert_eq!(issue.key, key, "{msg}");
        assert!(msg.contains("allowed") || msg.contains("within"), "{msg}");
    }
    std::fs::remove_dir_all(dir).ok();
}

/// The automatic force scale from the cadaver table and the Touch: the table's 7.2 N range
/// inside the 0.88 N continuous range, the coupling 4× stiffer than the table's steepest
/// 3.1 N/mm, and the felt stiffness bounded by the 1.0 N/mm default limit.
#[test]
fn automatic_scale_maps_the_cadaver_table_into_the_touch() {
    let d = launch_config::DeviceConfig::default();
    let r = d.rendering();
    assert!(r.automatic);
    // Reference numbers from outside the project: table 0.31 → 7.51 N, last segment
    // 7.20 → 7.51 N over 7.52 → 7.62 mm; Touch 0.88 N continuous.
    let range = 7.51 - 0.31;
    let steepest = (7.51 - 7.20) / (7.62e-3 - 7.52e-3);
    assert!(r.force_scale * range <= 0.88 + 1e-12, "{r:?}");
    assert!(
        r.coupling_stiffness_n_per_m >= 4.0 * steepest * (1.0 - 1e-12),
        "{r:?}"
    );
    assert!((r.force_scale * r.coupling_stiffness_n_per_m - 1000.0).abs() < 1e-9);
    // The steepest table tissue is felt far below the limit.
    let felt = r.force_scale / (1.0 / steepest + 1.0 / r.coupling_stiffness_n_per_m);
    assert!(felt < 0.3 * r.felt_stiffness_limit_n_per_m, "{felt}");
    // An explicit scale keeps the bound through the coupling.
    let fixed = launch_config::DeviceConfig {
        force_scale: 0.2,
        ..d
    }
    .rendering();
    assert!(!fixed.automatic);
    assert!((fixed.coupling_stiffness_n_per_m - 5000.0).abs() < 1e-9);
}

/// `[scene.solver] offline` and `offline_tolerance`: a value out of bounds or an unknown
/// solver is an issue naming the key, its line and what is allowed.
#[test]
fn offline_solver_keys_are_checked() {
    let (issue, text) = only_issue(
        load_str(
            "[scene.solver]\noffline = \"cg\"\noffline_tolerance = 0.01\n",
            Path::new("off.toml"),
        )
        .unwrap_err(),
    );
    assert_eq!(issue.key, "scene.solver.offline_tolerance");
    assert_eq!(issue.line, Some(3));
    assert!(
        text.contains("allowed: 1e-12 ≤ offline_tolerance ≤ 1e-4"),
        "{text}"
    );
    let (issue, text) = only_issue(
        load_str("[scene.solver]\noffline = \"lu\"\n", Path::new("off.toml")).unwrap_err(),
    );
    assert_eq!(issue.key, "scene.solver.offline");
    assert!(
        text.contains("`direct`") && text.contains("`cg`") && text.contains("`scene`"),
        "{text}"
    );
    let ok = load_str(
        "[scene.solver]\noffline = \"direct\"\noffline_tolerance = 1e-10\n",
        Path::new("off.toml"),
    )
    .unwrap();
    assert_eq!(
        ok.scene.solver.offline,
        launch_config::scene::OfflineSolver::Direct
    );
}
