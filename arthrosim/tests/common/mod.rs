//! Helpers shared by the command-line tests: run the built `arthrosim`, a scratch folder per
//! test, and the text a user sees.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

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

/// Waits for the viewer's `VIEWER http=… ws=…` line in the session's log.
// Only the tests that start a viewer use it.
#[allow(dead_code)]
pub fn viewer_urls(out: &Path, timeout: Duration) -> (String, String) {
    let log = out.join("logs/viewer.log");
    let start = Instant::now();
    while start.elapsed() < timeout {
        if let Ok(text) = std::fs::read_to_string(&log) {
            if let Some(line) = text.lines().find(|l| l.starts_with("VIEWER ")) {
                let mut http = None;
                let mut ws = None;
                for part in line.split_whitespace() {
                    if let Some(v) = part.strip_prefix("http=") {
                        http = Some(v.to_string());
                    }
                    if let Some(v) = part.strip_prefix("ws=") {
                        ws = Some(v.to_string());
                    }
                }
                return (http.unwrap(), ws.unwrap());
            }
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    panic!("no VIEWER line in {} within {timeout:?}", log.display());
}
