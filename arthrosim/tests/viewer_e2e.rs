//! End to end: a bounded default session (physics, haptic, bridge, recorder and the viewer as
//! real processes) watched at the same time by
//! - a Foxglove WebSocket client in Python (PyPI `websockets`), whose mesh, poses and forces
//!   must equal the session's own MCAP recording, and
//! - headless Chromium on the trainee page, which must receive frames, draw the mesh (vertex
//!   count, a canvas that is not blank) and match the expected layout loosely.
//!
//! Needs python3 with `websockets` and `mcap-ros2-support`, and Chromium (`.ci/run` installs
//! them); outside CI a missing tool skips the test with a message.

// The CLI tests' shared helpers; this test uses only some of them.
#[allow(dead_code)]
mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

fn in_ci() -> bool {
    std::env::var_os("CI").is_some_and(|v| !v.is_empty() && v != "false")
}

/// Whether the external tools are there; outside CI a missing one skips the test.
fn tools_present(need_chromium: bool) -> bool {
    let py = Command::new("python3")
        .args(["-c", "import websockets, mcap_ros2"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    let chromium = !need_chromium
        || ["chromium-headless-shell", "chromium"].iter().any(|c| {
            Command::new("which")
                .arg(c)
                .output()
                .is_ok_and(|o| o.status.success())
        });
    if py && chromium {
        return true;
    }
    let what = format!("python3 websockets/mcap_ros2: {py}, chromium: {chromium}");
    assert!(!in_ci(), "required tools missing in CI ({what})");
    eprintln!("skipping: {what}");
    false
}

/// The default launch file with the viewer on free ports (parallel tests, other sessions).
pub fn default_launch_on_free_ports(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(workspace().join("launch-config/launch/default.toml"))
        .unwrap()
        .replace("http_port = 8080", "http_port = 0")
        .replace("ws_port = 8765", "ws_port = 0");
    assert!(text.contains("http_port = 0") && text.contains("ws_port = 0"));
    let path = dir.join("launch.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn json_of(out: &std::process::Output) -> serde_json::Value {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout
        .lines()
        .rev()
        .find(|l| l.starts_with('{'))
        .unwrap_or_else(|| {
            panic!(
                "no JSON line; stdout {stdout}\nstderr {}",
                String::from_utf8_lossy(&out.stderr)
            )
        });
    serde_json::from_str(line).unwrap()
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_str()
        .and_then(|s| s.parse().ok())
        .or_else(|| v.as_f64())
        .unwrap_or(f64::NAN)
}

#[test]
fn foxglove_client_and_chromium_watch_a_default_session() {
    if !tools_present(true) {
        return;
    }
    let dir = common::scratch("viewer", "e2e");
    let launch = default_launch_on_free_ports(&dir);
    let out = dir.join("session");
    let session = format!("viewer-e2e-{}", std::process::id());
    let mut run = Command::new(env!("CARGO_BIN_EXE_arthrosim"))
        .args([
            "run",
            launch.to_str().unwrap(),
            "--seconds",
            "16",
            "--quiet",
        ])
        .args(["--out", out.to_str().unwrap(), "--session", &session])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (http, ws) = common::viewer_urls(&out, Duration::from_secs(180));
    assert!(
        http.starts_with("http://127.0.0.1:"),
        "loopback by default: {http}"
    );
    assert!(ws.starts_with("ws://127.0.0.1:"), "{ws}");

    let py = workspace().join("viewer/tests/py");
    let fox = Command::new("python3")
        .arg(py.join("foxglove_check.py"))
        .args([
            "--ws",
            &ws,
            "--seconds",
            "5",
            "--session-dir",
            out.to_str().unwrap(),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let shot = dir.join("viewer.png");
    let page = Command::new("python3")
        .arg(py.join("page_check.py"))
        .args([
            "--url",
            &http,
            "--seconds",
            "7",
            "--screenshot",
            shot.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let fox = fox.wait_with_output().unwrap();
    let run = {
        let status = run.wait().unwrap();
        let mut s = String::new();
        use std::io::Read;
        run.stdout.take().unwrap().read_to_string(&mut s).unwrap();
        (status, s)
    };
    assert!(run.0.success(), "session failed:\n{}", run.1);

    // Foxglove: channels, values equal to the recording.
    let fj = json_of(&fox);
    eprintln!("foxglove: {fj}");
    assert!(fox.status.success(), "foxglove check failed: {fj}");
    assert!(fj["matched"]["wrench"].as_u64().unwrap() >= 20, "{fj}");
    assert!(
        fj["peak_force_n"].as_f64().unwrap() > 0.1,
        "the probe touched: {fj}"
    );

    // Chromium: frames, mesh, force, canvas, layout.
    let pj = json_of(&page);
    eprintln!("page: {pj}");
    let status = &pj["status"];
    let frames = f(&status["frames"]);
    let vertices = f(&status["vertices"]);
    let force = f(&status["forceN"]);
    assert!(frames >= 20.0, "frames received: {pj}");
    assert!(vertices >= 100.0, "mesh drawn: {pj}");
    assert!(force.is_finite() && (0.0..200.0).contains(&force), "{pj}");
    assert!(f(&status["painted"]) >= 20.0, "canvas not blank: {pj}");
    let layout = &pj["layout"];
    assert!(
        f(&layout["scene"]["meniscus"]) > 0.01,
        "meniscus in the 3D view: {layout}"
    );
    assert!(
        f(&layout["scene"]["background"]) > 0.3,
        "3D background: {layout}"
    );
    assert!(f(&layout["plot"]["background"]) > 0.5, "plot: {layout}");
    assert!(
        f(&layout["side"]["background"]) > 0.5,
        "side panel: {layout}"
    );
    assert!(shot.is_file());

    // The 1 kHz loop kept its rate with both watchers connected, and the recorder and the
    // bridge read every device tick (the 1 kHz stream): the viewer reads beside them without
    // slowing anything.
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let haptic_hz = summary["summary"]["haptic_hz"].as_f64().unwrap();
    let ticks = summary["summary"]["haptic_ticks"].as_u64().unwrap();
    let recorded = tagged_json(&out.join("logs/recorder.log"), "RECORDED");
    let bridged = tagged_json(&out.join("logs/bridge.log"), "BRIDGED");
    let viewed = tagged_json(&out.join("logs/viewer.log"), "VIEWED");
    eprintln!(
        "haptic: {haptic_hz:.1} Hz, {ticks} ticks\nrecorder: {recorded}\nbridge: {bridged}\nviewer: {viewed}"
    );
    // A sanity bound, not the servo's timing target (`haptic-bench` measures that): a loop
    // blocked by a watcher would fall far below it. With Chromium, the Foxglove client and
    // six nodes sharing CI's 2 cores the loop skips deadlines it was descheduled through:
    // 946 Hz in CI's run of stop 24, against 985–998 Hz here.
    assert!(haptic_hz > 900.0, "haptic rate {haptic_hz} Hz");
    assert_eq!(recorded["device_states_dropped"], 0, "{recorded}");
    let read = bridged["device_states"].as_u64().unwrap();
    // The bridge may subscribe a few ticks after the haptic node's first.
    assert!(
        read as f64 >= 0.995 * ticks as f64,
        "the bridge read {read} of {ticks} device ticks"
    );
    // Every tick read is accounted for on DDS: published, or dropped and counted. Drops are
    // not failed here: they come when the bridge's DDS thread is starved of CPU (359 of
    // 15,980 at a load average of 7.6 on 2 cores, none in five runs at 3–6), a path the
    // viewer takes no part in; the log line above shows them.
    let wrench = &bridged["topics"]["device/wrench"];
    let n = |k: &str| wrench[k].as_u64().unwrap();
    assert_eq!(
        n("published") + n("dropped_queue") + n("dropped_dds"),
        read,
        "{bridged}"
    );
    assert_eq!(viewed["ipc_errors"], 0, "{viewed}");
}

/// The JSON of the last `TAG {json}` line of a node's log (the nodes' end-of-run totals).
fn tagged_json(log: &Path, tag: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let line = text
        .lines()
        .rev()
        .find_map(|l| l.strip_prefix(tag)?.strip_prefix(' '))
        .unwrap_or_else(|| panic!("no {tag} line in {}:\n{text}", log.display()));
    serde_json::from_str(line).unwrap()
}

/// `[viewer] bind = "0.0.0.0"` is the explicit way to serve other machines: the viewer then
/// listens on every interface (reached here through loopback, as the only address a test may
/// use), says in its log what that exposes, and serves the page with relative URLs only, so
/// a browser on another machine loads its script and stream from the same host.
#[test]
fn a_lan_bind_serves_every_interface_and_says_what_it_exposes() {
    let dir = common::scratch("viewer", "lan");
    let launch = default_launch_on_free_ports(&dir);
    let text = std::fs::read_to_string(&launch)
        .unwrap()
        .replace("bind = \"127.0.0.1\"", "bind = \"0.0.0.0\"");
    assert!(text.contains("bind = \"0.0.0.0\""));
    std::fs::write(&launch, text).unwrap();
    let mut node = Command::new(env!("CARGO_BIN_EXE_arthrosim"))
        .args(["node", "viewer", "--launch", launch.to_str().unwrap()])
        .args(["--session", &format!("viewer-lan-{}", std::process::id())])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The VIEWER line comes once the servers listen.
    let mut stdout = std::io::BufReader::new(node.stdout.take().unwrap());
    let mut line = String::new();
    use std::io::{BufRead, Read, Write};
    while !line.starts_with("VIEWER ") {
        line.clear();
        if stdout.read_line(&mut line).unwrap() == 0 {
            break;
        }
    }
    let http = line
        .split_whitespace()
        .find_map(|p| p.strip_prefix("http="))
        .unwrap_or_else(|| panic!("no VIEWER line: {line:?}"))
        .to_string();
    assert!(http.starts_with("http://0.0.0.0:"), "{http}");
    let port: u16 = http
        .trim_end_matches('/')
        .rsplit(':')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let get = |path: &str| {
        let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        write!(s, "GET {path} HTTP/1.1\r\nHost: lab-pc:{port}\r\n\r\n").unwrap();
        let mut body = String::new();
        s.read_to_string(&mut body).unwrap();
        body
    };
    let page = get("/");
    let script = get("/viewer.js");
    let _ = Command::new("kill")
        .args(["-TERM", &node.id().to_string()])
        .status();
    let status = node.wait().unwrap();
    let mut stderr = String::new();
    node.stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    assert!(status.success(), "viewer exit {status}: {stderr}");
    assert!(
        stderr.contains("bound to 0.0.0.0") && stderr.contains("visible to every machine"),
        "the exposure is said: {stderr}"
    );
    assert!(page.starts_with("HTTP/1.1 200"), "{page}");
    assert!(page.contains("id=\"viewer-status\""), "{page}");
    assert!(page.contains("<script src=\"/viewer.js\">"), "{page}");
    assert!(
        !page.contains("127.0.0.1") && !page.contains("localhost"),
        "no address of this machine in the page: {page}"
    );
    assert!(script.starts_with("HTTP/1.1 200"));
    assert!(script.contains("/events") && !script.contains("127.0.0.1:"));
}
