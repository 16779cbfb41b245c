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

/// A fresh folder `arthrosim-<suite>-<pid>-<name>` under the temp dir, removed when the
/// test is done with it (kept when the test panics, for a look at what it wrote).
pub fn scratch(suite: &str, name: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("arthrosim-{suite}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    Scratch(dir)
}

/// A test's scratch folder (see [`scratch`]).
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = PathBuf;
    fn deref(&self) -> &PathBuf {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// stdout then stderr.
pub fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}
