//! Experiment input: strict parsing with errors naming file and line.
use gap_diagnosis::experiment::{load_experiment, parse_trial_csv, read_force_displacement};
use gap_diagnosis::{GapError, Region};
use std::path::{Path, PathBuf};

const HEADER: &str = "t_s,fx_N,fy_N,fz_N,px_m,py_m,pz_m,qx,qy,qz,qw";

fn rows(n: usize) -> String {
    let mut s = String::from(HEADER);
    s.push('\n');
    for i in 0..n {
        s.push_str(&format!(
            "{},0,0,{},0,0,{},0,0,0,1\n",
            i as f64 * 0.026,
            i as f64 * 0.1,
            0.01 - i as f64 * 1e-4
        ));
    }
    s
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gap_parse_{}_{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn line_of(e: &GapError) -> Option<usize> {
    match e {
        GapError::Line { line, .. } => Some(*line),
        _ => None,
    }
}

#[test]
fn good_trial_parses() {
    let (t, f, p) = parse_trial_csv(&rows(10), Path::new("a.csv")).unwrap();
    assert_eq!(t.len(), 10);
    assert_eq!(f[3], [0.0, 0.0, 0.30000000000000004]);
    assert_eq!(p[0].orientation, [0.0, 0.0, 0.0, 1.0]);
    // columns in another order, extra column ignored
    let s = "qw,t_s,extra,fx_N,fy_N,fz_N,px_m,py_m,pz_m,qx,qy,qz\n1,0,9,1,2,3,0,0,0,0,0,0\n1,0.1,9,1,2,3,0,0,0,0,0,0\n1,0.2,9,1,2,3,0,0,0,0,0,0\n1,0.3,9,1,2,3,0,0,0,0,0,0\n1,0.4,9,1,2,3,0,0,0,0,0,0\n";
    let (t, f, _) = parse_trial_csv(s, Path::new("b.csv")).unwrap();
    assert_eq!(t[4], 0.4);
    assert_eq!(f[0], [1.0, 2.0, 3.0]);
}

#[test]
fn missing_column_is_named() {
    let s = rows(6).replacen("fy_N,", "", 1);
    let e = parse_trial_csv(&s, Path::new("x.csv")).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("x.csv:1") && msg.contains("missing column(s) fy_N"),
        "{msg}"
    );
}

#[test]
fn nan_row_names_line_and_column() {
    let mut s = rows(8);
    s = s.replacen("0.078,0,0,0.30000000000000004", "0.078,0,NaN,0.3", 1);
    let e = parse_trial_csv(&s, Path::new("n.csv")).unwrap_err();
    assert_eq!(line_of(&e), Some(5), "{e}");
    assert!(
        e.to_string().contains("fy_N") && e.to_string().contains("non-finite"),
        "{e}"
    );
    let s2 = rows(8).replacen("0.052,0,0,0.2", "0.052,0,zz,0.2", 1);
    let e2 = parse_trial_csv(&s2, Path::new("n.csv")).unwrap_err();
    assert_eq!(line_of(&e2), Some(4), "{e2}");
}

#[test]
fn non_monotonic_time_is_rejected() {
    let mut s = String::from(HEADER);
    s.push('\n');
    for t in [0.0, 0.1, 0.2, 0.15, 0.3, 0.4] {
        s.push_str(&format!("{t},0,0,0,0,0,0,0,0,0,1\n"));
    }
    let e = parse_trial_csv(&s, Path::new("m.csv")).unwrap_err();
    assert_eq!(line_of(&e), Some(5));
    assert!(e.to_string().contains("time not increasing"), "{e}");
}

#[test]
fn short_row_and_zero_quaternion() {
    let mut s = rows(6);
    s.push_str("0.5,0,0\n");
    assert_eq!(
        line_of(&parse_trial_csv(&s, Path::new("s.csv")).unwrap_err()),
        Some(8)
    );
    let z = rows(6).replacen(
        "0.026,0,0,0.1,0,0,0.0099,0,0,0,1",
        "0.026,0,0,0.1,0,0,0.0099,0,0,0,0",
        1,
    );
    let e = parse_trial_csv(&z, Path::new("z.csv")).unwrap_err();
    assert!(e.to_string().contains("zero quaternion"), "{e}");
}

#[test]
fn experiment_folder_errors_name_toml_line() {
    let data = gap_diagnosis::data_dir();
    // unknown region
    let d = dir("region");
    std::fs::write(d.join("a.csv"), rows(6)).unwrap();
    std::fs::write(
        d.join("experiment.toml"),
        "[specimen]\nmesh = \"default:lateral:coarse\"\n\n[[trial]]\nfile = \"a.csv\"\nregion = \"lateral\"\n",
    )
    .unwrap();
    let e = load_experiment(&d, &data).unwrap_err();
    assert!(
        e.to_string().contains("experiment.toml:6") && e.to_string().contains("unknown region"),
        "{e}"
    );
    // mesh not found
    std::fs::write(
        d.join("experiment.toml"),
        "[specimen]\nmesh = \"missing.msh\"\n\n[[trial]]\nfile = \"a.csv\"\n",
    )
    .unwrap();
    let e = load_experiment(&d, &data).unwrap_err();
    assert!(
        e.to_string().contains("experiment.toml:1") && e.to_string().contains("mesh not found"),
        "{e}"
    );
    std::fs::write(
        d.join("experiment.toml"),
        "[specimen]\nmesh = \"default:lateral:huge\"\n\n[[trial]]\nfile = \"a.csv\"\n",
    )
    .unwrap();
    assert!(load_experiment(&d, &data)
        .unwrap_err()
        .to_string()
        .contains("mesh not found"));
    // trial file missing
    std::fs::write(
        d.join("experiment.toml"),
        "[[trial]]\nfile = \"a.csv\"\n\n[[trial]]\nfile = \"b.csv\"\n",
    )
    .unwrap();
    let e = load_experiment(&d, &data).unwrap_err();
    assert!(
        e.to_string().contains("experiment.toml:4") && e.to_string().contains("b.csv"),
        "{e}"
    );
    // unknown key
    std::fs::write(
        d.join("experiment.toml"),
        "[material]\nyoung = 3\n[[trial]]\nfile = \"a.csv\"\n",
    )
    .unwrap();
    let e = load_experiment(&d, &data).unwrap_err();
    assert!(e.to_string().contains("experiment.toml:2"), "{e}");
    // bad CSV inside a good folder names the CSV
    std::fs::write(d.join("b.csv"), rows(6).replacen("0.104", "0.01", 1)).unwrap();
    std::fs::write(
        d.join("experiment.toml"),
        "[[trial]]\nfile = \"b.csv\"\nregion = \"mid\"\n",
    )
    .unwrap();
    let e = load_experiment(&d, &data).unwrap_err();
    assert!(e.to_string().contains("b.csv:6"), "{e}");
    // good folder
    std::fs::write(
        d.join("experiment.toml"),
        "[[trial]]\nfile = \"a.csv\"\nregion = \"Posterior\"\n",
    )
    .unwrap();
    let exp = load_experiment(&d, &data).unwrap();
    assert_eq!(exp.trials[0].region, Some(Region::Posterior));
    assert_eq!(exp.spec.specimen.mesh, "default:lateral:coarse");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn force_displacement_table() {
    let d = dir("fd");
    let p = d.join("fd.csv");
    std::fs::write(&p, "displacement_mm,force_N\n0,0.31\n1,0.5\n2,1.0\n3,2.0\n").unwrap();
    let t = read_force_displacement(&p).unwrap();
    assert_eq!(t.force_n[0], 0.31);
    std::fs::write(&p, "displacement_mm,force\n0,0.31\n").unwrap();
    assert!(read_force_displacement(&p)
        .unwrap_err()
        .to_string()
        .contains("missing column"));
    std::fs::write(&p, "displacement_mm,force_N\n0,0.31\n1,nan\n2,1\n3,2\n").unwrap();
    assert!(read_force_displacement(&p)
        .unwrap_err()
        .to_string()
        .contains("fd.csv:3"));
    let cadaver =
        gap_diagnosis::data_dir().join("empirical/cadaver_probing_force_displacement.csv");
    if cadaver.is_file() || std::env::var("CI").is_ok() {
        let t = read_force_displacement(&cadaver).unwrap();
        assert_eq!(t.displacement_mm.len(), 9);
        assert!((t.force_n[0] - 0.31).abs() < 1e-12);
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// An experiment names its indenter: a ball-tipped one is replayed as a ball, the default
/// stays the hook, and a model that is neither built in nor an OBJ file is refused naming
/// the experiment file.
#[test]
fn experiment_names_its_probe_model() {
    use gap_diagnosis::sim_model::SimForceModel;
    let data = gap_diagnosis::data_dir();
    let d = dir("probe_model");
    std::fs::write(d.join("a.csv"), rows(6)).unwrap();
    let toml = |probe: &str| format!("{probe}\n[[trial]]\nfile = \"a.csv\"\nregion = \"mid\"\n");
    std::fs::write(d.join("experiment.toml"), toml("")).unwrap();
    let exp = load_experiment(&d, &data).unwrap();
    assert_eq!(exp.spec.probe.model, "hook");
    let replay = SimForceModel::for_experiment(&exp, &data).unwrap();
    assert_eq!(replay.scene.probe.model, "hook");

    std::fs::write(
        d.join("experiment.toml"),
        toml("[probe]\nmodel = \"sphere\"\ntip_radius = 2.0e-3\n"),
    )
    .unwrap();
    let exp = load_experiment(&d, &data).unwrap();
    let replay = SimForceModel::for_experiment(&exp, &data).unwrap();
    assert_eq!(replay.scene.probe.model, "sphere");
    assert_eq!(replay.scene.probe.tip_radius, 2.0e-3);

    for (model, says) in [("ball", "`sphere`"), ("tip.obj", "not found")] {
        std::fs::write(
            d.join("experiment.toml"),
            toml(&format!("[probe]\nmodel = \"{model}\"\n")),
        )
        .unwrap();
        let e = load_experiment(&d, &data).unwrap_err().to_string();
        assert!(e.contains("experiment.toml") && e.contains(says), "{e}");
    }
    // An OBJ next to the experiment is the collision model, resolved against the folder.
    std::fs::write(
        d.join("tip.obj"),
        "v 0 0 0\nv 0 0 0.01\nv 0.003 0 0.012\nl 1 2\nl 2 3\n",
    )
    .unwrap();
    let exp = load_experiment(&d, &data).unwrap();
    let replay = SimForceModel::for_experiment(&exp, &data).unwrap();
    assert_eq!(
        replay.scene.probe.model,
        d.join("tip.obj").display().to_string()
    );
    let _ = std::fs::remove_dir_all(&d);
}

/// The replay step is bounded in the library, not only by the CLI flag: a library caller
/// asking for a 1e-9 s replay of a table gets an error, not a 564 GB allocation.
#[test]
fn a_replay_step_outside_the_scene_bounds_is_refused_by_the_library() {
    let d = dir("dt_bounds");
    let table = d.join("table.csv");
    std::fs::write(&table, "displacement_mm,force_N\n0,0.3\n1,0.5\n2,1.0\n").unwrap();
    for dt in [1e-300, 1e-9, 0.5, f64::NAN, -1.0] {
        let opts = gap_diagnosis::Options {
            dt,
            ..gap_diagnosis::Options::default()
        };
        let err = gap_diagnosis::diagnose_force_displacement(&table, &opts)
            .err()
            .unwrap_or_else(|| panic!("dt {dt} accepted"));
        let text = err.to_string();
        assert!(
            text.contains("dt") && text.contains("0.00001 to 0.1 s"),
            "{text}"
        );
    }
    let opts = gap_diagnosis::Options {
        min_shrink: f64::INFINITY,
        ..gap_diagnosis::Options::default()
    };
    assert!(opts.check().is_err());
    assert!(gap_diagnosis::Options::default().check().is_ok());
}
