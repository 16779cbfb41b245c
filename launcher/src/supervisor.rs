//! The launcher: starts each enabled node as its own process, waits for `READY <node>`,
//! shows live status, restarts crashed nodes under the `[launcher]` restart policy, stops
//! everything in order (haptic first so the force goes to zero, recorder last so the file is
//! closed) on Ctrl-C / SIGTERM / the end of a timed run, and writes the session summary.
//!
//! Children live in their own process groups, so a terminal Ctrl-C reaches only the launcher,
//! which forwards SIGTERM in the stop order. Each child also gets `PR_SET_PDEATHSIG`, so a
//! launcher that is itself killed never leaves a node running.

use crate::status::StatusMonitor;
use indicatif::{ProgressBar, ProgressStyle};
use launch_config::{LaunchFile, LauncherConfig, RestartPolicy};
use serde::Serialize;
use session_metrics::summary::{summarize, SessionRecord, SessionSummary};
use std::io::{BufRead, BufReader, IsTerminal, Write};
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The node processes of a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum NodeKind {
    Physics,
    Haptic,
    Bridge,
    Recorder,
    Viewer,
}

impl NodeKind {
    /// Physics first (the others read its streams), the recorder before the haptic node so
    /// it sees every tick, haptic last.
    pub const START_ORDER: [NodeKind; 5] = [
        NodeKind::Physics,
        NodeKind::Recorder,
        NodeKind::Bridge,
        NodeKind::Viewer,
        NodeKind::Haptic,
    ];
    /// Haptic first (force ramps to zero while physics still answers), recorder last (it
    /// records the stop and closes its file).
    pub const STOP_ORDER: [NodeKind; 5] = [
        NodeKind::Haptic,
        NodeKind::Viewer,
        NodeKind::Bridge,
        NodeKind::Physics,
        NodeKind::Recorder,
    ];

    /// The name used by `arthrosim node <name>` and in `READY <name>`.
    pub fn name(self) -> &'static str {
        match self {
            NodeKind::Physics => "physics",
            NodeKind::Haptic => "haptic",
            NodeKind::Bridge => "bridge",
            NodeKind::Recorder => "recorder",
            NodeKind::Viewer => "viewer",
        }
    }

    pub fn from_name(name: &str) -> Option<NodeKind> {
        Self::START_ORDER.into_iter().find(|k| k.name() == name)
    }

    /// Whether the launch file enables this node.
    pub fn enabled_in(self, file: &LaunchFile) -> bool {
        match self {
            NodeKind::Physics => file.nodes.physics,
            NodeKind::Haptic => file.nodes.haptic,
            NodeKind::Bridge => file.nodes.bridge,
            NodeKind::Recorder => file.nodes.recorder && file.recording.enabled,
            NodeKind::Viewer => file.viewer.enabled,
        }
    }
}

/// What to do when a node process exits on its own.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ExitDecision {
    /// Start it again after this wait.
    Restart { after: Duration },
    /// End the session: `failed` when the node failed and may not be restarted.
    EndSession { failed: bool },
}

/// The restart policy as a pure function: a node that exits 0 has finished (e.g. the
/// protocol ended) and ends the session normally; a failing node is restarted with doubling
/// backoff while the policy and its restart budget allow.
pub fn decide_on_exit(
    config: &LauncherConfig,
    success: bool,
    restarts_so_far: u32,
) -> ExitDecision {
    if success {
        return ExitDecision::EndSession { failed: false };
    }
    match config.restart {
        RestartPolicy::OnFailure if restarts_so_far < config.max_restarts => {
            let factor = 2f64.powi(restarts_so_far.min(16) as i32);
            let secs = (config.restart_backoff_s * factor).clamp(0.0, 60.0);
            ExitDecision::Restart {
                after: Duration::from_secs_f64(secs),
            }
        }
        _ => ExitDecision::EndSession { failed: true },
    }
}

/// How the live status is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LiveMode {
    /// Progress bar on a terminal, plain lines otherwise.
    Auto,
    /// Plain status lines.
    Plain,
    /// No live status (node output still goes to the log files).
    Quiet,
}

/// Everything a session run needs.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// The launch file, paths already resolved (see [`launch_config::load`]).
    pub launch: LaunchFile,
    /// Where the launch file came from (for messages and the summary).
    pub origin: String,
    /// iceoryx2 session prefix.
    pub session: String,
    /// Session folder: resolved launch file, summary.json, node logs, recordings.
    pub out_dir: PathBuf,
    /// Bounded length, s; `None` runs until Ctrl-C or a node finishes.
    pub seconds: Option<f64>,
    /// Executable started for each node, and the arguments before the node name
    /// (`arthrosim` + `["node"]`).
    pub program: PathBuf,
    pub program_args: Vec<String>,
    pub live: LiveMode,
}

impl RunOptions {
    /// Options that start the nodes through this executable's hidden `node` subcommand.
    pub fn for_current_exe(
        launch: LaunchFile,
        origin: String,
        session: String,
        out_dir: PathBuf,
        seconds: Option<f64>,
    ) -> Result<RunOptions, LauncherError> {
        let program = std::env::current_exe().map_err(|e| LauncherError::Io {
            what: "locate the current executable".into(),
            source: e,
        })?;
        Ok(RunOptions {
            launch,
            origin,
            session,
            out_dir,
            seconds,
            program,
            program_args: vec!["node".into()],
            live: LiveMode::Auto,
        })
    }
}

/// Failures of the launcher itself (a node failing is reported in [`SessionReport`]).
#[derive(Debug, thiserror::Error)]
pub enum LauncherError {
    #[error("cannot {what}: {source}")]
    Io {
        what: String,
        #[source]
        source: std::io::Error,
    },
    #[error("no node is enabled in {0}")]
    NothingToStart(String),
    #[error("cannot start node {node}: {source}")]
    Spawn {
        node: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("node {node} did not print `READY {node}` within {timeout_s} s (log: {log})")]
    ReadyTimeout {
        node: &'static str,
        timeout_s: f64,
        log: String,
    },
    #[error("node {node} exited during start-up ({status}) before it was ready (log: {log})")]
    DiedBeforeReady {
        node: &'static str,
        status: String,
        log: String,
    },
    #[error("interrupted while starting node {0}")]
    InterruptedDuringStart(&'static str),
    #[error("cannot subscribe to the session's streams: {0}")]
    Link(#[from] msgs::ipc::LinkError),
    #[error(
        "session {name:?} is already running ({holder}); its nodes would share shared-memory \
         services with this one. Stop it, or give this run another name (--session NAME or \
         [session] name)"
    )]
    SessionLive { name: String, holder: String },
}

/// Directory of the per-session lock files.
fn session_lock_dir() -> PathBuf {
    std::env::temp_dir().join("arthrosim-sessions")
}

/// Exclusive claim on a session name for the launcher's lifetime: an advisory `flock` on
/// `<tmp>/arthrosim-sessions/<name>.lock`. The kernel releases it when the launcher exits
/// in any way (also `kill -9`), so a dead session never blocks its name.
#[derive(Debug)]
pub struct SessionLock {
    _file: std::fs::File,
    pub path: PathBuf,
}

impl SessionLock {
    /// Claims `name`, or says who holds it.
    pub fn acquire(name: &str) -> Result<SessionLock, LauncherError> {
        use std::os::fd::AsRawFd;
        let dir = session_lock_dir();
        let io = |what: String| move |source| LauncherError::Io { what, source };
        std::fs::create_dir_all(&dir).map_err(io(format!("create {}", dir.display())))?;
        let path = dir.join(format!("{name}.lock"));
        let mut file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(io(format!("open {}", path.display())))?;
        // SAFETY: flock on a file descriptor we own.
        let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
        if rc != 0 {
            let holder = std::fs::read_to_string(&path)
                .ok()
                .map(|t| t.trim().to_string())
                .filter(|t| !t.is_empty())
                .unwrap_or_else(|| "holder unknown".into());
            return Err(LauncherError::SessionLive {
                name: name.to_string(),
                holder,
            });
        }
        file.set_len(0)
            .map_err(io(format!("write {}", path.display())))?;
        writeln!(
            file,
            "launcher pid {}, lock {}",
            std::process::id(),
            path.display()
        )
        .map_err(io(format!("write {}", path.display())))?;
        Ok(SessionLock { _file: file, path })
    }
}

/// Per-node outcome.
#[derive(Debug, Clone, Serialize)]
pub struct NodeReport {
    pub node: NodeKind,
    pub restarts: u32,
    /// Final exit: `exit 0`, `exit N`, `signal N`.
    pub exit: String,
    /// True when it had to be killed after the stop grace period.
    pub killed: bool,
    /// True when it stopped with exit 0 after SIGTERM (or finished on its own with 0).
    pub clean_stop: bool,
    pub log: String,
}

/// Why the session ended.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum EndReason {
    /// The `--seconds` bound was reached.
    Completed,
    /// Ctrl-C / SIGTERM.
    Interrupted,
    /// A node exited 0 on its own (its work was done).
    NodeFinished { node: NodeKind },
    /// A node failed and the restart policy gave up.
    NodeFailed { node: NodeKind, exit: String },
}

/// What `arthrosim run` writes to `summary.json` and prints.
#[derive(Debug, Clone, Serialize)]
pub struct SessionReport {
    pub session: String,
    pub launch_origin: String,
    pub out_dir: String,
    pub started_unix_s: f64,
    /// From the nodes being ready to the last one stopped, s.
    pub wall_seconds: f64,
    /// From the launcher's start until every node was ready, s.
    pub startup_seconds: f64,
    pub requested_seconds: Option<f64>,
    pub end: EndReason,
    pub nodes: Vec<NodeReport>,
    /// Physics steps the launcher missed because it fell behind (summary is then partial).
    pub frames_missed: u64,
    pub summary: SessionSummary,
}

impl SessionReport {
    /// True when no node failed and every node stopped cleanly.
    pub fn success(&self) -> bool {
        !matches!(self.end, EndReason::NodeFailed { .. }) && self.nodes.iter().all(|n| n.clean_stop)
    }
}

enum Event {
    Ready { node: NodeKind, generation: u32 },
    Line { node: NodeKind, line: String },
}

struct Running {
    kind: NodeKind,
    child: Option<Child>,
    generation: u32,
    restarts: u32,
    ready: bool,
    started: Instant,
    restart_at: Option<Instant>,
    exit: Option<ExitStatus>,
    killed: bool,
    stopped_by_us: bool,
    log: PathBuf,
}

fn describe(status: &ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit {c}"),
        (None, Some(s)) => format!("signal {s}"),
        _ => "unknown".into(),
    }
}

/// The printer for node output and status: through the progress bar when one is shown.
struct Display {
    bar: Option<ProgressBar>,
    plain: bool,
    last_plain: Instant,
    total_s: Option<f64>,
}

impl Display {
    fn new(live: LiveMode, seconds: Option<f64>) -> Display {
        let tty = std::io::stdout().is_terminal();
        let bar = match (live, tty) {
            (LiveMode::Auto, true) => {
                let bar = match seconds {
                    Some(s) => {
                        let bar = ProgressBar::new((s * 10.0).round().max(1.0) as u64);
                        bar.set_style(
                            ProgressStyle::with_template(
                                "{bar:30.cyan/blue} {elapsed:>4}/{len_s} {msg}",
                            )
                            .unwrap_or_else(|_| ProgressStyle::default_bar())
                            .with_key(
                                "len_s",
                                move |_: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                                    let _ = write!(w, "{s:.0}s");
                                },
                            )
                            .progress_chars("=> "),
                        );
                        bar
                    }
                    None => {
                        let bar = ProgressBar::new_spinner();
                        bar.set_style(
                            ProgressStyle::with_template("{spinner} {elapsed:>4} {msg}")
                                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
                        );
                        bar
                    }
                };
                Some(bar)
            }
            _ => None,
        };
        Display {
            plain: live != LiveMode::Quiet && bar.is_none(),
            bar,
            last_plain: Instant::now(),
            total_s: seconds,
        }
    }

    fn line(&self, text: &str) {
        match &self.bar {
            Some(bar) => bar.println(text),
            None => eprintln!("{text}"),
        }
    }

    fn status(&mut self, elapsed: Duration, status: &str) {
        if let Some(bar) = &self.bar {
            if self.total_s.is_some() {
                bar.set_position((elapsed.as_secs_f64() * 10.0) as u64);
            } else {
                bar.tick();
            }
            bar.set_message(status.to_string());
        } else if self.plain && self.last_plain.elapsed() >= Duration::from_secs(1) {
            self.last_plain = Instant::now();
            let mut out = std::io::stdout().lock();
            let _ = match self.total_s {
                Some(t) => writeln!(out, "[{:>5.1}/{t:.0} s] {status}", elapsed.as_secs_f64()),
                None => writeln!(out, "[{:>5.1} s] {status}", elapsed.as_secs_f64()),
            };
            let _ = out.flush();
        }
    }

    /// The session proper starts now (the nodes are ready): the bar counts from here.
    fn start(&mut self) {
        if let Some(bar) = &self.bar {
            bar.reset_elapsed();
            bar.set_position(0);
        }
        self.last_plain = Instant::now() - Duration::from_secs(1);
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// The CLOCK_REALTIME − CLOCK_MONOTONIC offset every node of this launcher's sessions gets
/// (fixed at the first spawn; an offset already in the environment is passed on).
fn session_clock_offset_ns() -> i64 {
    static OFFSET: std::sync::OnceLock<i64> = std::sync::OnceLock::new();
    *OFFSET.get_or_init(|| {
        msgs::ros_mapping::StampClock::for_session()
            .unwrap_or_else(|_| msgs::ros_mapping::StampClock::measure())
            .offset_ns()
    })
}

/// A session in progress.
struct Session<'a> {
    opts: &'a RunOptions,
    launch_path: PathBuf,
    nodes: Vec<Running>,
    events_tx: mpsc::Sender<Event>,
    events_rx: mpsc::Receiver<Event>,
    readers: Vec<std::thread::JoinHandle<()>>,
    display: Display,
}

impl Session<'_> {
    fn spawn(&mut self, index: usize) -> Result<(), LauncherError> {
        let opts = self.opts;
        let kind = self.nodes[index].kind;
        let mut cmd = Command::new(&opts.program);
        cmd.args(&opts.program_args)
            .arg(kind.name())
            .arg("--launch")
            .arg(&self.launch_path)
            .arg("--session")
            .arg(&opts.session)
            .arg("--out")
            .arg(&opts.out_dir)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            // Plain text in the logs and through the launcher's pipes.
            .env("NO_COLOR", "1")
            // One stamp clock for the session: the bridge and the recorder turn a sample's
            // publish time into the same ROS stamp.
            .env(
                msgs::ros_mapping::CLOCK_OFFSET_ENV,
                session_clock_offset_ns().to_string(),
            )
            .process_group(0);

        let parent = std::process::id() as libc::pid_t;
        // SAFETY: only async-signal-safe calls (prctl, getppid, _exit) between fork and exec.
        unsafe {
            cmd.pre_exec(move || {
                libc::prctl(
                    libc::PR_SET_PDEATHSIG,
                    libc::SIGTERM as libc::c_ulong,
                    0,
                    0,
                    0,
                );
                if libc::getppid() != parent {
                    libc::_exit(1); // the launcher died before the death signal was armed
                }
                Ok(())
            });
        }
        let mut child = cmd.spawn().map_err(|source| LauncherError::Spawn {
            node: kind.name(),
            source,
        })?;
        let node = &mut self.nodes[index];
        node.generation += 1;
        node.ready = false;
        node.started = Instant::now();
        node.restart_at = None;
        node.exit = None;
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&node.log)
            .map_err(|source| LauncherError::Io {
                what: format!("open log {}", node.log.display()),
                source,
            })?;
        let generation = node.generation;
        if let Some(out) = child.stdout.take() {
            let log = log.try_clone().ok();
            self.readers.push(forward_lines(
                out,
                kind,
                generation,
                log,
                self.events_tx.clone(),
                true,
            ));
        }
        if let Some(err) = child.stderr.take() {
            self.readers.push(forward_lines(
                err,
                kind,
                generation,
                Some(log),
                self.events_tx.clone(),
                false,
            ));
        }
        node.child = Some(child);
        Ok(())
    }

    /// Prints node output and marks nodes ready; returns when the channel is empty.
    fn pump_events(&mut self, wait: Duration) {
        let mut first = true;
        loop {
            let event = if first {
                first = false;
                match self.events_rx.recv_timeout(wait) {
                    Ok(e) => e,
                    Err(_) => return,
                }
            } else {
                match self.events_rx.try_recv() {
                    Ok(e) => e,
                    Err(_) => return,
                }
            };
            match event {
                Event::Ready { node, generation } => {
                    if let Some(n) = self.nodes.iter_mut().find(|n| n.kind == node) {
                        if n.generation == generation {
                            n.ready = true;
                        }
                    }
                }
                Event::Line { node, line } => {
                    if self.opts.live != LiveMode::Quiet && !is_iceoryx_config_notice(&line) {
                        self.display.line(&format!("[{}] {line}", node.name()));
                    }
                }
            }
        }
    }

    /// Starts node `index` and waits for its READY line, applying the restart policy to a
    /// node that dies while starting.
    fn start_and_wait(
        &mut self,
        index: usize,
        drain: &mut dyn FnMut(),
    ) -> Result<(), LauncherError> {
        let stop = msgs::lifecycle::stop_flag();
        let cfg = &self.opts.launch.launcher;
        self.spawn(index)?;
        loop {
            if stop.load(Ordering::SeqCst) {
                return Err(LauncherError::InterruptedDuringStart(
                    self.nodes[index].kind.name(),
                ));
            }
            self.pump_events(Duration::from_millis(20));
            drain();
            let node = &mut self.nodes[index];
            if node.ready {
                return Ok(());
            }
            let kind = node.kind;
            if let Some(child) = node.child.as_mut() {
                if let Ok(Some(status)) = child.try_wait() {
                    node.child = None;
                    node.exit = Some(status);
                    // Collect the rest of its output before deciding.
                    self.pump_events(Duration::from_millis(100));
                    let node = &mut self.nodes[index];
                    match decide_on_exit(cfg, false, node.restarts) {
                        ExitDecision::Restart { after } => {
                            node.restarts += 1;
                            self.display.line(&format!(
                                "launcher: {} exited during start-up ({}); restart {}/{} in {:.1} s",
                                kind.name(),
                                describe(&status),
                                node.restarts,
                                cfg.max_restarts,
                                after.as_secs_f64()
                            ));
                            std::thread::sleep(after);
                            self.spawn(index)?;
                            continue;
                        }
                        ExitDecision::EndSession { .. } => {
                            return Err(LauncherError::DiedBeforeReady {
                                node: kind.name(),
                                status: describe(&status),
                                log: node.log.display().to_string(),
                            });
                        }
                    }
                }
            }
            let node = &self.nodes[index];
            if node.started.elapsed().as_secs_f64() > cfg.ready_timeout_s {
                return Err(LauncherError::ReadyTimeout {
                    node: kind.name(),
                    timeout_s: cfg.ready_timeout_s,
                    log: node.log.display().to_string(),
                });
            }
        }
    }

    /// SIGTERM, wait up to the grace period (draining the streams meanwhile), then SIGKILL
    /// the node's process group.
    fn stop_node(&mut self, index: usize, mut drain: impl FnMut()) {
        let grace = Duration::from_secs_f64(self.opts.launch.launcher.stop_grace_s);
        let node = &mut self.nodes[index];
        node.restart_at = None;
        let Some(child) = node.child.as_mut() else {
            return;
        };
        node.stopped_by_us = true;
        let pid = child.id() as libc::pid_t;
        // SAFETY: signalling our own child by pid.
        unsafe { libc::kill(pid, libc::SIGTERM) };
        let deadline = Instant::now() + grace;
        loop {
            match child.try_wait() {
                Ok(Some(status)) => {
                    node.exit = Some(status);
                    break;
                }
                Ok(None) if Instant::now() < deadline => {
                    drain();
                    std::thread::sleep(Duration::from_millis(10));
                }
                _ => {
                    // SAFETY: the child leads its own process group (process_group(0)).
                    unsafe { libc::kill(-pid, libc::SIGKILL) };
                    let _ = child.kill();
                    node.exit = child.wait().ok();
                    node.killed = true;
                    break;
                }
            }
        }
        // Grandchildren (if a node forked) go with the group.
        // SAFETY: as above; ESRCH when the group is already gone.
        unsafe { libc::kill(-pid, libc::SIGKILL) };
        node.child = None;
    }
}

/// iceoryx2 prints a warning when it runs without a config file, which is how arthrosim runs
/// it; the launcher keeps it in the logs but not on the terminal.
fn is_iceoryx_config_notice(line: &str) -> bool {
    line.contains("\"Config::global_config()\"") || line.contains("No config file was loaded")
}

/// Loads iceoryx2's global config with warnings muted, so the launcher's own terminal does
/// not start with the config notice (unless the user asked for a log level).
fn load_iceoryx_config_quietly() {
    use iceoryx2::prelude::{set_log_level, Config, LogLevel};
    if std::env::var_os("IOX2_LOG_LEVEL").is_none() {
        set_log_level(LogLevel::Error);
        let _ = Config::global_config();
    }
}

fn forward_lines(
    stream: impl std::io::Read + Send + 'static,
    node: NodeKind,
    generation: u32,
    mut log: Option<std::fs::File>,
    tx: mpsc::Sender<Event>,
    watch_ready: bool,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let ready_line = format!("READY {}", node.name());
        let mut record = String::new();
        for line in BufReader::new(stream).lines() {
            let Ok(line) = line else { break };
            if let Some(f) = log.as_mut() {
                // One write per line: the node's stdout and stderr readers append to the same
                // log, and `writeln!` wrote the text and its newline in two calls, so a stderr
                // line could land between them (the bridge's `BRIDGED {json}` totals line was
                // read back with a warning glued to its end, and its test failed to parse it).
                record.clear();
                record.push_str(&line);
                record.push('\n');
                let _ = f.write_all(record.as_bytes());
            }
            if watch_ready && line.trim() == ready_line {
                let _ = tx.send(Event::Ready { node, generation });
            } else {
                let _ = tx.send(Event::Line { node, line });
            }
        }
    })
}

/// `sessions/<UTC timestamp>` relative to the working directory, unique: the folder is
/// created here, and a run that finds its second's folder taken (another run started in the
/// same second) takes `<stamp>-2`, `<stamp>-3`, … (`create_dir` is atomic, so two runs never
/// get the same one).
pub fn default_out_dir() -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    unique_dir(Path::new("sessions"), &utc_stamp(secs))
}

/// Creates and returns `parent/stem`, or `parent/stem-N` for the first N ≥ 2 that does not
/// exist yet. Falls back to the plain path (and lets the session's own create report the
/// problem) when the parent cannot be created.
pub fn unique_dir(parent: &Path, stem: &str) -> PathBuf {
    if std::fs::create_dir_all(parent).is_err() {
        return parent.join(stem);
    }
    for n in 1..10_000u32 {
        let name = if n == 1 {
            stem.to_string()
        } else {
            format!("{stem}-{n}")
        };
        let dir = parent.join(name);
        match std::fs::create_dir(&dir) {
            Ok(()) => return dir,
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(_) => return dir,
        }
    }
    parent.join(format!("{stem}-{}", std::process::id()))
}

/// `YYYYMMDD-HHMMSS` (UTC) of a Unix time.
pub fn utc_stamp(unix_s: u64) -> String {
    let days = (unix_s / 86_400) as i64;
    let rem = unix_s % 86_400;
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + if m <= 2 { 1 } else { 0 };
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        rem / 3600,
        (rem / 60) % 60,
        rem % 60
    )
}

/// Writes the resolved launch file into the session folder and returns its path.
pub fn write_resolved_launch(
    out_dir: &Path,
    file: &LaunchFile,
    origin: &str,
) -> Result<PathBuf, LauncherError> {
    let text = toml::to_string(file).map_err(|e| LauncherError::Io {
        what: "serialise the resolved launch file".into(),
        source: std::io::Error::other(e.to_string()),
    })?;
    let path = out_dir.join("launch.toml");
    let header = format!(
        "# Resolved launch file of this session (from {origin}); paths are absolute.\n\
         # Re-run with: arthrosim run {}\n\n",
        path.display()
    );
    std::fs::write(&path, header + &text).map_err(|source| LauncherError::Io {
        what: format!("write {}", path.display()),
        source,
    })?;
    Ok(path)
}

/// Runs a whole session and returns its report (also written to `summary.json`).
pub fn run(opts: &RunOptions) -> Result<SessionReport, LauncherError> {
    let kinds: Vec<NodeKind> = NodeKind::START_ORDER
        .into_iter()
        .filter(|k| k.enabled_in(&opts.launch))
        .collect();
    if kinds.is_empty() {
        return Err(LauncherError::NothingToStart(opts.origin.clone()));
    }
    // One live session per name: two sessions with the same name would share their
    // iceoryx2 services (each haptic node rendering the other's physics).
    let _session_lock = SessionLock::acquire(&opts.session)?;
    let logs = opts.out_dir.join("logs");
    std::fs::create_dir_all(&logs).map_err(|source| LauncherError::Io {
        what: format!("create session folder {}", logs.display()),
        source,
    })?;
    // Absolute, so nodes resolve it regardless of their working directory.
    let out_dir = std::path::absolute(&opts.out_dir).unwrap_or_else(|_| opts.out_dir.clone());
    let launch_path = write_resolved_launch(&out_dir, &opts.launch, &opts.origin)?;
    let opts = &RunOptions {
        out_dir,
        ..opts.clone()
    };
    let stop = msgs::lifecycle::install_stop_flag();
    let started_unix_s = msgs::clock::realtime_ns() as f64 * 1e-9;
    let started = Instant::now();

    let (events_tx, events_rx) = mpsc::channel();
    let mut session = Session {
        opts,
        launch_path,
        nodes: kinds
            .iter()
            .map(|&kind| Running {
                kind,
                child: None,
                generation: 0,
                restarts: 0,
                ready: false,
                started: Instant::now(),
                restart_at: None,
                exit: None,
                killed: false,
                stopped_by_us: false,
                log: opts
                    .out_dir
                    .join("logs")
                    .join(format!("{}.log", kind.name())),
            })
            .collect(),
        events_tx,
        events_rx,
        readers: Vec::new(),
        display: Display::new(opts.live, opts.seconds),
    };

    load_iceoryx_config_quietly();
    // Subscribe before any node starts, so the summary sees the first step.
    let mut monitor = StatusMonitor::new(&opts.session)?;
    let mut record = SessionRecord::default();

    let mut start_error = None;
    for index in 0..session.nodes.len() {
        // Keep reading the streams of the nodes already running while the next one starts.
        let mut drain = || {
            let _ = monitor.poll(&mut record);
        };
        if let Err(e) = session.start_and_wait(index, &mut drain) {
            start_error = Some(e);
            break;
        }
    }

    let mut end = EndReason::Completed;
    let mut session_start = Instant::now();
    if start_error.is_none() {
        if opts.live != LiveMode::Quiet {
            session.display.line(&format!(
                "launcher: session {:?} running ({}), folder {}",
                opts.session,
                kinds
                    .iter()
                    .map(|k| k.name())
                    .collect::<Vec<_>>()
                    .join(", "),
                opts.out_dir.display()
            ));
        }
        session_start = Instant::now();
        session.display.start();
        let deadline = opts
            .seconds
            .map(|s| session_start + Duration::from_secs_f64(s));
        let cfg = &opts.launch.launcher;
        let period = Duration::from_secs_f64(cfg.status_period_s.clamp(0.02, 5.0));
        let mut next_status = Instant::now();
        'session: loop {
            if stop.load(Ordering::SeqCst) {
                end = EndReason::Interrupted;
                break;
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                end = EndReason::Completed;
                break;
            }
            session.pump_events(Duration::from_millis(20));
            for index in 0..session.nodes.len() {
                let node = &mut session.nodes[index];
                let kind = node.kind;
                if let Some(at) = node.restart_at {
                    if Instant::now() >= at {
                        if let Err(e) = session.spawn(index) {
                            session.display.line(&format!("launcher: {e}"));
                            end = EndReason::NodeFailed {
                                node: kind,
                                exit: "restart failed".into(),
                            };
                            break 'session;
                        }
                    }
                    continue;
                }
                let Some(child) = node.child.as_mut() else {
                    continue;
                };
                let Ok(Some(status)) = child.try_wait() else {
                    if !node.ready && node.started.elapsed().as_secs_f64() > cfg.ready_timeout_s {
                        session.display.line(&format!(
                            "launcher: restarted {} not ready within {} s",
                            kind.name(),
                            cfg.ready_timeout_s
                        ));
                        end = EndReason::NodeFailed {
                            node: kind,
                            exit: "not ready after restart".into(),
                        };
                        break 'session;
                    }
                    continue;
                };
                node.child = None;
                node.exit = Some(status);
                match decide_on_exit(cfg, status.success(), node.restarts) {
                    ExitDecision::Restart { after } => {
                        node.restarts += 1;
                        node.restart_at = Some(Instant::now() + after);
                        let line = format!(
                            "launcher: {} crashed ({}); restart {}/{} in {:.1} s",
                            kind.name(),
                            describe(&status),
                            node.restarts,
                            cfg.max_restarts,
                            after.as_secs_f64()
                        );
                        session.display.line(&line);
                    }
                    ExitDecision::EndSession { failed } => {
                        end = if failed {
                            EndReason::NodeFailed {
                                node: kind,
                                exit: describe(&status),
                            }
                        } else {
                            EndReason::NodeFinished { node: kind }
                        };
                        let line = format!(
                            "launcher: {} {} ({}); ending the session",
                            kind.name(),
                            if failed { "failed" } else { "finished" },
                            describe(&status)
                        );
                        session.display.line(&line);
                        break 'session;
                    }
                }
            }
            if Instant::now() >= next_status {
                next_status = Instant::now() + period;
                match monitor.poll(&mut record) {
                    Ok(status) => {
                        let text = status.to_string();
                        session.display.status(session_start.elapsed(), &text);
                    }
                    Err(e) => session.display.line(&format!("launcher: status: {e}")),
                }
            }
        }
    }

    // Stop in order, draining the streams meanwhile so the summary sees the last steps.
    for kind in NodeKind::STOP_ORDER {
        if let Some(index) = session.nodes.iter().position(|n| n.kind == kind) {
            let mut drain = || {
                let _ = monitor.poll(&mut record);
            };
            session.stop_node(index, &mut drain);
        }
    }
    let _ = monitor.poll(&mut record);
    session.display.finish();
    // Readers end at EOF of their pipes, now that every child is gone.
    drop(session.events_tx);
    for reader in session.readers.drain(..) {
        let _ = reader.join();
    }
    while let Ok(event) = session.events_rx.try_recv() {
        if let (Event::Line { node, line }, false) = (event, opts.live == LiveMode::Quiet) {
            if !is_iceoryx_config_notice(&line) {
                eprintln!("[{}] {line}", node.name());
            }
        }
    }

    if let Some(e) = start_error {
        return Err(e);
    }

    let nodes: Vec<NodeReport> = session
        .nodes
        .iter()
        .map(|n| {
            let exit = n
                .exit
                .as_ref()
                .map(describe)
                .unwrap_or_else(|| "not started".into());
            let clean_stop = !n.killed && n.exit.as_ref().is_some_and(|s| s.success());
            NodeReport {
                node: n.kind,
                restarts: n.restarts,
                exit,
                killed: n.killed,
                clean_stop,
                log: n.log.display().to_string(),
            }
        })
        .collect();
    let report = SessionReport {
        session: opts.session.clone(),
        launch_origin: opts.origin.clone(),
        out_dir: opts.out_dir.display().to_string(),
        started_unix_s,
        wall_seconds: session_start.elapsed().as_secs_f64(),
        startup_seconds: session_start
            .saturating_duration_since(started)
            .as_secs_f64(),
        requested_seconds: opts.seconds,
        end,
        nodes,
        frames_missed: monitor.frames_missed,
        summary: {
            let mut s = summarize(&record);
            if opts.launch.nodes.haptic {
                let r = opts.launch.device.rendering();
                s.rendering = Some(session_metrics::summary::RenderingSummary {
                    force_scale: r.force_scale,
                    automatic: r.automatic,
                    coupling_stiffness_n_per_m: r.coupling_stiffness_n_per_m,
                    felt_stiffness_limit_n_per_m: r.felt_stiffness_limit_n_per_m,
                });
            }
            s
        },
    };
    let json = serde_json::to_string_pretty(&report).map_err(|e| LauncherError::Io {
        what: "serialise summary.json".into(),
        source: std::io::Error::other(e.to_string()),
    })?;
    let path = opts.out_dir.join("summary.json");
    std::fs::write(&path, json + "\n").map_err(|source| LauncherError::Io {
        what: format!("write {}", path.display()),
        source,
    })?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: a node's stdout and stderr readers append to one log, and a stderr line
    /// could land between a stdout line's text and its newline (the bridge's `BRIDGED {json}`
    /// line came back with a warning glued to its end). Both streams at once, many long
    /// lines: every line of the log is one of the lines sent, whole.
    #[test]
    fn stdout_and_stderr_lines_reach_the_log_whole() {
        let dir = std::env::temp_dir().join(format!("arthrosim_log_lines_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("node.log");
        let _ = std::fs::remove_file(&path);
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .unwrap();
        let lines = |tag: &str| -> String {
            (0..4000)
                .map(|k| format!("{tag} {k} {}\n", "x".repeat(300)))
                .collect()
        };
        let (tx, rx) = mpsc::channel();
        let readers = [("OUT", log.try_clone().unwrap()), ("ERR", log)].map(|(tag, file)| {
            forward_lines(
                std::io::Cursor::new(lines(tag).into_bytes()),
                NodeKind::Bridge,
                1,
                Some(file),
                tx.clone(),
                false,
            )
        });
        drop(tx);
        for r in readers {
            r.join().unwrap();
        }
        assert_eq!(rx.iter().count(), 8000);
        let text = std::fs::read_to_string(&path).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        let whole = |l: &str| {
            let mut parts = l.splitn(3, ' ');
            matches!(parts.next(), Some("OUT" | "ERR"))
                && parts.next().is_some_and(|k| k.parse::<u32>().is_ok())
                && parts
                    .next()
                    .is_some_and(|x| x.len() == 300 && x.bytes().all(|b| b == b'x'))
        };
        let broken: Vec<&str> = text.lines().filter(|l| !whole(l)).take(3).collect();
        assert!(broken.is_empty(), "lines broken in the log: {broken:?}");
        assert_eq!(text.lines().count(), 8000);
    }

    fn cfg(policy: RestartPolicy, max: u32) -> LauncherConfig {
        LauncherConfig {
            restart: policy,
            max_restarts: max,
            restart_backoff_s: 0.5,
            ..LauncherConfig::default()
        }
    }

    #[test]
    fn restart_policy_on_failure_backs_off_then_gives_up() {
        let c = cfg(RestartPolicy::OnFailure, 2);
        assert_eq!(
            decide_on_exit(&c, false, 0),
            ExitDecision::Restart {
                after: Duration::from_millis(500)
            }
        );
        assert_eq!(
            decide_on_exit(&c, false, 1),
            ExitDecision::Restart {
                after: Duration::from_millis(1000)
            }
        );
        assert_eq!(
            decide_on_exit(&c, false, 2),
            ExitDecision::EndSession { failed: true }
        );
    }

    #[test]
    fn restart_policy_never_and_clean_exit_end_the_session() {
        let never = cfg(RestartPolicy::Never, 5);
        assert_eq!(
            decide_on_exit(&never, false, 0),
            ExitDecision::EndSession { failed: true }
        );
        let on = cfg(RestartPolicy::OnFailure, 5);
        assert_eq!(
            decide_on_exit(&on, true, 0),
            ExitDecision::EndSession { failed: false }
        );
    }

    #[test]
    fn stop_order_is_haptic_first_recorder_last() {
        assert_eq!(NodeKind::STOP_ORDER[0], NodeKind::Haptic);
        assert_eq!(NodeKind::STOP_ORDER[4], NodeKind::Recorder);
        assert_eq!(NodeKind::START_ORDER[0], NodeKind::Physics);
        for k in NodeKind::START_ORDER {
            assert_eq!(NodeKind::from_name(k.name()), Some(k));
        }
    }

    #[test]
    fn utc_stamps_are_civil_dates() {
        assert_eq!(utc_stamp(0), "19700101-000000");
        // 2026-11-22 03:04:05 UTC
        assert_eq!(utc_stamp(1_795_316_645), "20261122-030405");
        assert_eq!(utc_stamp(951_782_400), "20000229-000000");
    }

    /// Runs started in the same second (threads racing here, like two `arthrosim run`
    /// processes) each get a folder of their own, created, and never one another's.
    #[test]
    fn output_folders_of_runs_in_the_same_second_are_unique() {
        let parent = std::env::temp_dir().join(format!("arthrosim-unique-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&parent);
        let stamp = utc_stamp(1_795_316_645);
        let dirs: Vec<PathBuf> = std::thread::scope(|s| {
            let racers: Vec<_> = (0..8)
                .map(|_| s.spawn(|| unique_dir(&parent, &stamp)))
                .collect();
            racers.into_iter().map(|r| r.join().unwrap()).collect()
        });
        let mut names: Vec<String> = dirs
            .iter()
            .map(|d| {
                assert!(d.is_dir(), "{} not created", d.display());
                assert_eq!(d.parent(), Some(parent.as_path()));
                d.file_name().unwrap().to_string_lossy().into_owned()
            })
            .collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), 8, "two runs share a folder: {names:?}");
        assert!(names.contains(&stamp), "{names:?}");
        assert!(names.contains(&format!("{stamp}-8")), "{names:?}");
        std::fs::remove_dir_all(&parent).unwrap();
    }
}
