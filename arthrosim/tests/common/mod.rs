//! Helpers shared by the command-line tests: run the built `arthrosim`, a scratch folder per
//! test, and the text a user sees.

use std::path::PathBuf;
use std::process::{Command, Output};

pub fn arthrosim(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_arthrosim"))
        .args(args)
        .output()
        .expect("run arthrosim")
}

/// A fresh folder `arthrosim-<suite>-<pid>-<name>` under the temp dir.
pub fn scratch(suite: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("arthrosim-{suite}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// stdout then stderr.
pub fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}
