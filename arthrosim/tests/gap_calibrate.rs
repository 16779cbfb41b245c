//! `arthrosim gap … --calibrate OUT.toml` as a user meets it: the default scene's tissue
//! parameters come out of the cadaver table (pinned against the embedded default launch
//! file), the written file validates, and bad input gets a clear message before any replay.

use std::path::PathBuf;

mod common;
use common::{arthrosim, text};

fn scratch(name: &str) -> common::Scratch {
    common::scratch("calibrate", name)
}

fn data_dir() -> PathBuf {
    std::env::var_os("ARTHROSIM_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data")))
}

fn cadaver_table() -> Option<PathBuf> {
    let f = data_dir().join("empirical/cadaver_probing_force_displacement.csv");
    if f.is_file() {
        return Some(f);
    }
    if std::env::var("CI").map(|v| v == "true").unwrap_or(false) {
        panic!("CI=true but the cadaver table is missing at {}", f.display());
    }
    None
}

#[test]
fn calibrate_refuses_an_output_folder_that_does_not_exist_before_any_replay() {
    let dir = scratch("no-parent");
    let out = dir.join("missing/calibrated.toml");
    let t = std::time::Instant::now();
    let o = arthrosim(&[
        "gap",
        "--force-displacement",
        "/nonexistent/table.csv",
        "--out",
        dir.join("report").to_str().unwrap(),
        "--calibrate",
        out.to_str().unwrap(),
    ]);
    let msg = text(&o);
    assert_eq!(o.status.code(), Some(1), "{msg}");
    assert!(
        msg.contains("--calibrate") && msg.contains("missing") && msg.contains("does not exist"),
        "{msg}"
    );
    assert!(!msg.contains("panicked"), "{msg}");
    assert!(t.elapsed().as_secs_f64() < 20.0, "checked before the replays");
    // a folder given as the file
    let o = arthrosim(&[
        "gap",
        "--force-displacement",
        "/nonexistent/table.csv",
        "--out",
        dir.join("report").to_str().unwrap(),
        "--calibrate",
        dir.to_str().unwrap(),
    ]);
    let msg = text(&o);
    assert_eq!(o.status.code(), Some(1), "{msg}");
    assert!(msg.contains("is a folder"), "{msg}");
}

#[test]
fn calibrate_names_an_unreadable_input_and_a_broken_base_launch_file() {
    let dir = scratch("bad-input");
    let out = dir.join("calibrated.toml");
    // a table that is not a table
    let table = dir.join("table.csv");
    std::fs::write(&table, "displacement_mm,force_N\n0.0,zero\n").unwrap();
    let o = arthrosim(&[
        "gap",
        "--force-displacement",
        table.to_str().unwrap(),
        "--out",
        dir.join("report").to_str().unwrap(),
        "--calibrate",
        out.to_str().unwrap(),
    ]);
    let msg = text(&o);
    assert_eq!(o.status.code(), Some(1), "{msg}");
    assert!(msg.contains("table.csv") && !msg.contains("panicked"), "{msg}");
    assert!(!out.exists(), "nothing written for a failed calibration");
    // an experiment folder that does not exist
    let o = arthrosim(&[
        "gap",
        dir.join("no-such-experiment").to_str().unwrap(),
        "--out",
        dir.join("report").to_str().unwrap(),
        "--calibrate",
        out.to_str().unwrap(),
    ]);
    let msg = text(&o);
    assert_eq!(o.status.code(), Some(1), "{msg}");
    assert!(msg.contains("no-such-experiment") && !msg.contains("panicked"), "{msg}");
    // a base launch file with an unknown key: file, line and key
    let base = dir.join("base.toml");
    std::fs::write(&base, "[scene]\ndt = 0.01\nstep = 2\n").unwrap();
    let o = arthrosim(&[
        "gap",
        "--force-displacement",
        table.to_str().unwrap(),
        "--out",
        dir.join("report").to_str().unwrap(),
        "--calibrate",
        out.to_str().unwrap(),
        "--launch",
        base.to_str().unwrap(),
    ]);
    let msg = text(&o);
    assert_eq!(o.status.code(), Some(1), "{msg}");
    assert!(msg.contains("base.toml:3:1") && msg.contains("scene.step"), "{msg}");
    // --launch without --calibrate is a usage error
    let o = arthrosim(&[
        "gap",
        "--force-displacement",
        table.to_str().unwrap(),
        "--out",
        dir.join("report").to_str().unwrap(),
        "--launch",
        base.to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}
