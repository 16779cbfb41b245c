//! The `arthrosim` command line as a user meets it: exit codes and messages of `validate`,
//! `run` on a bad file, recordings commands on bad input, and the hidden `node` command.

use std::path::{Path, PathBuf};

mod common;
use common::{arthrosim, text};

fn scratch(name: &str) -> common::Scratch {
    common::scratch("cli", name)
}

fn examples() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../launch-config/launch")
}

#[test]
fn validate_accepts_the_shipped_examples() {
    let mut files = vec![
        examples().join("default.toml"),
        examples().join("replay.toml"),
        examples().join("remote_viewer.toml"),
    ];
    let study_present = std::env::var_os("ARTHROSIM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data")))
        .join("meniscus/lateral_meniscus_computation.msh")
        .is_file();
    if study_present {
        files.push(examples().join("study_lateral.toml"));
    }
    let args: Vec<&str> = std::iter::once("validate")
        .chain(files.iter().map(|p| p.to_str().unwrap()))
        .collect();
    let out = arthrosim(&args);
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).matches(": ok").count(),
        files.len()
    );
}

#[test]
fn validate_reports_every_broken_file_with_line_and_key_and_exits_1() {
    let dir = scratch("validate");
    let cases = [
        (
            "unknown.toml",
            "[scene]\ndt = 0.01\nstep = 2\n",
            "unknown.toml:3:1: key `scene.step`",
        ),
        (
            "type.toml",
            "[scene]\ndt = \"x\"\n",
            "type.toml:2:6: key `scene.dt`",
        ),
        (
            "mesh.toml",
            "[scene.meniscus]\nmesh = \"gone.msh\"\n",
            "mesh.toml:2:1: key `scene.meniscus.mesh`",
        ),
        (
            "dt.toml",
            "[scene]\ndt = -0.01\n",
            "dt.toml:2:1: key `scene.dt`",
        ),
    ];
    let mut args = vec!["validate".to_string()];
    for (name, body, _) in &cases {
        std::fs::write(dir.join(name), body).unwrap();
        args.push(dir.join(name).display().to_string());
    }
    let good = examples().join("default.toml");
    args.push(good.display().to_string());
    let out = arthrosim(&args.iter().map(String::as_str).collect::<Vec<_>>());
    let all = text(&out);
    assert_eq!(out.status.code(), Some(1), "{all}");
    for (_, _, expected) in &cases {
        assert!(all.contains(expected), "missing {expected:?} in:\n{all}");
    }
    assert!(all.contains("4 of 5 launch file(s) invalid"), "{all}");
    assert!(all.contains("default.toml: ok"), "{all}");
}

#[test]
fn run_refuses_an_invalid_launch_file_without_starting_anything() {
    let dir = scratch("run-bad");
    let file = dir.join("bad.toml");
    std::fs::write(&file, "[nodes]\nphysics = \"yes\"\n").unwrap();
    let out_dir = dir.join("session");
    let out = arthrosim(&[
        "run",
        file.to_str().unwrap(),
        "--seconds",
        "1",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let all = text(&out);
    assert_eq!(out.status.code(), Some(1), "{all}");
    assert!(
        all.contains("bad.toml:2:") && all.contains("nodes.physics"),
        "{all}"
    );
    assert!(!out_dir.exists(), "no session folder for a refused file");
}

#[test]
fn run_rejects_bad_session_names_and_seconds() {
    let out = arthrosim(&["run", "--session", "a/b", "--seconds", "1"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out).contains("session name"), "{}", text(&out));
    let out = arthrosim(&["run", "--seconds", "-3"]);
    assert_ne!(out.status.code(), Some(0));
    // `--seconds -3` stops at clap (a flag-like value); these reach the bound itself, which
    // keeps a huge or non-finite session length from the launcher's `Duration`s.
    let dir = scratch("run-seconds");
    let out_dir = dir.join("session");
    for value in ["-3", "1e300", "2592001", "inf", "nan"] {
        let out = arthrosim(&[
            "run",
            &format!("--seconds={value}"),
            "--out",
            out_dir.to_str().unwrap(),
        ]);
        let all = text(&out);
        assert_eq!(out.status.code(), Some(1), "--seconds={value}: {all}");
        assert!(
            all.contains("--seconds") && all.contains("2592000"),
            "--seconds={value} names the flag and the bound: {all}"
        );
        assert!(!out_dir.exists(), "no session folder for --seconds={value}");
    }
}

/// `train --cases` is bounded before anything is opened or started. Run with a deadline:
/// without the bound, 1001 cases would start a session of hours (and 4e9 allocated 16 GB).
#[test]
fn train_refuses_zero_or_too_many_cases_before_touching_anything() {
    let dir = scratch("train-cases");
    let db = dir.join("trainees.sqlite");
    let out_dir = dir.join("session");
    for cases in ["0", "1001", "4000000000"] {
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_arthrosim"))
            .args(["train", "--trainee", "bound", "--cases", cases, "--db"])
            .arg(&db)
            .arg("--out")
            .arg(&out_dir)
            .args(["--session", &format!("cli-cases-{}", std::process::id())])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
        while child.try_wait().unwrap().is_none() {
            if std::time::Instant::now() > deadline {
                let _ = child.kill();
                let _ = child.wait();
                panic!("train --cases {cases} was not refused within 30 s");
            }
            std::thread::sleep(std::time::Duration::from_millis(50));
        }
        let out = child.wait_with_output().unwrap();
        let all = text(&out);
        assert_eq!(out.status.code(), Some(1), "--cases {cases}: {all}");
        assert!(
            all.contains(&format!("--cases {cases}")) && all.contains("1 to 1000"),
            "--cases {cases} names the value and the bound: {all}"
        );
        assert!(!db.exists(), "--cases {cases}: database created");
        assert!(!out_dir.exists(), "--cases {cases}: session folder created");
    }
}

/// `gap --dt` is the replay's physics step: bounded like `[scene] dt` before anything is
/// read (1e-300 panicked on an add overflow, 1e-9 aborted on a 564 GB allocation).
#[test]
fn gap_refuses_a_replay_step_outside_the_scene_bounds() {
    let dir = scratch("gap-dt");
    for dt in ["1e-300", "1e-9", "0.5", "1e300", "nan", "-1"] {
        let all = gap_refused_with(&dir, &format!("--dt={dt}"));
        assert!(
            all.contains("--dt") && all.contains("0.00001 to 0.1 s"),
            "--dt={dt} names the flag and the bounds: {all}"
        );
    }
}

/// `arthrosim gap` on a small force–displacement table with `flag`: it must exit 1 without
/// writing a report; returns what it printed.
fn gap_refused_with(dir: &Path, flag: &str) -> String {
    let table = dir.join("table.csv");
    std::fs::write(&table, "displacement_mm,force_N\n0,0.3\n1,0.5\n2,1.0\n").unwrap();
    let report = dir.join("report");
    let out = arthrosim(&[
        "gap",
        "--force-displacement",
        table.to_str().unwrap(),
        "--out",
        report.to_str().unwrap(),
        flag,
    ]);
    let all = text(&out);
    assert_eq!(out.status.code(), Some(1), "{flag}: {all}");
    assert!(!report.exists(), "{flag}: report written");
    all
}

/// `gap --level-band LO,HI` must hold 1 with a positive lower end, and be two numbers: the
/// error names the flag before anything is replayed.
#[test]
fn gap_refuses_a_level_band_that_does_not_hold_one() {
    let dir = scratch("gap-level-band");
    for band in [
        "1.1,1.4", "0.7,0.9", "0,1.2", "nan,1.2", "0.7", "a,b", "0.7,inf",
    ] {
        let all = gap_refused_with(&dir, &format!("--level-band={band}"));
        assert!(
            all.contains("level-band") || all.contains("level band"),
            "--level-band={band} names the flag: {all}"
        );
    }
}

/// `gap selftest --cases` is bounded: a huge count panicked (capacity overflow) or aborted
/// out of memory building the case labels.
#[test]
fn gap_selftest_refuses_zero_or_too_many_cases() {
    for cases in ["0", "1001", "100000000", "18446744073709551615"] {
        let out = arthrosim(&["gap", "selftest", "--cases", cases]);
        let all = text(&out);
        assert_eq!(out.status.code(), Some(1), "--cases {cases}: {all}");
        assert!(
            all.contains(&format!("--cases {cases}")) && all.contains("1 to 1000"),
            "--cases {cases} names the value and the bound: {all}"
        );
    }
}

#[test]
fn recordings_commands_fail_cleanly_on_files_that_are_not_mcap() {
    let dir = scratch("rec");
    let file = dir.join("not.mcap");
    std::fs::write(&file, b"this is not an MCAP file").unwrap();
    for cmd in [
        vec!["recordings", "info", file.to_str().unwrap()],
        vec![
            "recordings",
            "export",
            file.to_str().unwrap(),
            "--csv",
            dir.to_str().unwrap(),
        ],
        vec!["replay", file.to_str().unwrap()],
    ] {
        let out = arthrosim(&cmd);
        let all = text(&out);
        assert_eq!(out.status.code(), Some(1), "{cmd:?}: {all}");
        assert!(all.contains("not.mcap"), "{cmd:?} names the file: {all}");
        assert!(!all.contains("panicked"), "{cmd:?}: {all}");
    }
}

#[test]
fn reality_keeps_the_truth_outside_the_experiment_folder() {
    let dir = scratch("reality");
    let exp = dir.join("exp");
    let out = arthrosim(&[
        "reality",
        "--effect",
        "friction",
        "--out",
        exp.to_str().unwrap(),
        "--truth",
        exp.join("truth.json").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out).contains("inside the experiment folder"),
        "{}",
        text(&out)
    );
}

#[test]
fn node_command_is_hidden_but_runs_nodes() {
    let help = arthrosim(&["--help"]);
    let help = text(&help);
    assert!(help.contains("run") && help.contains("validate") && help.contains("gap"));
    assert!(!help.contains("\n  node"), "node is hidden: {help}");
    let out = arthrosim(&["node", "physics", "--help"]);
    assert!(out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("--launch") && text(&out).contains("--session"));
    // A node given a broken launch file fails with the launch file's error.
    let dir = scratch("node");
    let file = dir.join("broken.toml");
    std::fs::write(&file, "[scene]\ndt = 0\n").unwrap();
    let out = arthrosim(&[
        "node",
        "physics",
        "--launch",
        file.to_str().unwrap(),
        "--session",
        "cli-node-test",
    ]);
    assert_ne!(out.status.code(), Some(0));
    assert!(text(&out).contains("scene.dt"), "{}", text(&out));
}
