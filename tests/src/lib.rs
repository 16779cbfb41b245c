//! End-to-end tests of arthrosim with real processes (`tests/`), and the one helper every
//! crate's process tests share: [`workspace_binary`], a workspace binary of the test's own
//! profile, built first when it is another package's.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The workspace folder (this crate sits one level below it).
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests crate inside the workspace")
        .to_path_buf()
}

/// Binary `bin` of workspace package `package` in the calling test's profile directory
/// (`target/<profile>`), built (or brought up to date) first, bounded at 15 minutes. Cargo
/// gives a test `CARGO_BIN_EXE_*` only for its own package's binaries; process tests across
/// packages come here. Every caller builds all the workspace's binaries at once (`--workspace
/// --bins`): one feature unification for all of them, so dependencies are built once, not
/// once per package asked for. Panics with what failed.
pub fn workspace_binary(package: &str, bin: &str) -> PathBuf {
    // target/<profile>/deps/<test>-… → target/<profile>
    let exe = std::env::current_exe().expect("test executable path");
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("test executable inside target/<profile>/deps")
        .to_path_buf();
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut build = Command::new(cargo);
    build
        .current_dir(workspace_root())
        .args(["build", "--workspace", "--bins"]);
    if profile_dir.file_name().is_some_and(|n| n == "release") {
        build.arg("--release");
    }
    let ok = match build.stdout(Stdio::null()).stderr(Stdio::inherit()).spawn() {
        Ok(mut child) => {
            let t0 = Instant::now();
            loop {
                match child.try_wait() {
                    Ok(Some(status)) => break status.success(),
                    Ok(None) if t0.elapsed() < Duration::from_secs(900) => {
                        std::thread::sleep(Duration::from_millis(200))
                    }
                    _ => {
                        let _ = child.kill();
                        let _ = child.wait();
                        break false;
                    }
                }
            }
        }
        Err(_) => false,
    };
    let path = profile_dir.join(bin);
    assert!(
        path.is_file(),
        "{bin} binary missing at {} (package {package}, cargo build --workspace --bins {})",
        path.display(),
        if ok {
            "succeeded but produced no binary"
        } else {
            "failed"
        }
    );
    if !ok {
        eprintln!(
            "warning: cargo build --workspace --bins failed; using the existing {}",
            path.display()
        );
    }
    path
}

/// Processes whose command line names `session` (the launcher passes `--session NAME` to
/// every node), with their arguments; the calling test itself is left out. Zombies and
/// exiting processes have an empty command line and are not found.
pub fn processes_of_session(session: &str) -> Vec<(u32, Vec<String>)> {
    let mut found = Vec::new();
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return found;
    };
    for entry in entries.flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        if pid == std::process::id() {
            continue;
        }
        let Ok(raw) = std::fs::read(entry.path().join("cmdline")) else {
            continue;
        };
        let args: Vec<String> = raw
            .split(|b| *b == 0)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect();
        if args
            .windows(2)
            .any(|w| w[0] == "--session" && w[1] == session)
        {
            found.push((pid, args));
        }
    }
    found
}

/// Runs `command` (an `arthrosim run … --session SESSION`) with stdin closed and stdout and
/// stderr captured on a thread, so full pipes never stall the session, for at most `timeout`.
/// Past it, the command and every process of `session` are killed and the test panics.
pub fn run_bounded(mut command: Command, session: &str, timeout: Duration) -> Output {
    let child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("starting {command:?}: {e}"));
    let pid = child.id();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    match rx.recv_timeout(timeout) {
        Ok(output) => output.unwrap_or_else(|e| panic!("waiting for {command:?}: {e}")),
        Err(_) => {
            let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            for (pid, _) in processes_of_session(session) {
                let _ = Command::new("kill").args(["-9", &pid.to_string()]).status();
            }
            panic!(
                "{command:?} did not finish within {} s",
                timeout.as_secs_f64()
            )
        }
    }
}
