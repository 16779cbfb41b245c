//! The recorder node: its own process, reading the physics and haptic streams over iceoryx2
//! (every sample: `Queue::Every`) and writing them to one MCAP per session, so recording
//! never slows the 1 kHz loop.
//!
//! Lifecycle (copper-rs style): `Recorder::new` (config, file) → `start` (ports, on the
//! thread that will step) → `step` (drain queues, write, flush on schedule) → `stop`
//! (last drain, summary, index, `metadata.yaml`).

use crate::error::RecordingError;
use crate::resume::Progress;
use crate::writer::{SessionInfo, SessionWriter, WriteSummary};
use anyhow::Context;
use launch_config::{LaunchFile, RecordingConfig};
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, IpcNode, IpcSubscriber, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::ros_mapping::{Mapping, StampClock};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::Duration;

/// Command-line arguments of the recorder node (also `arthrosim node recorder`).
#[derive(Debug, Clone, clap::Args)]
pub struct NodeArgs {
    /// `--launch` (its `[recording]` section), `--session`, `--out` (the session folder the
    /// MCAP and metadata.yaml are written to; default: the current folder).
    #[command(flatten)]
    pub common: launch_config::node::CommonArgs,
    /// Stop by itself after this many seconds (0: run until SIGINT/SIGTERM).
    #[arg(long, default_value_t = 0.0)]
    pub seconds: f64,
}

/// Counters of one recorder run (printed as a JSON line at exit).
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct RecorderStats {
    pub contact_frames: u64,
    pub device_states: u64,
    pub haptic_stats: u64,
    pub surface_frames: u64,
    pub surface_frames_written: u64,
    /// Samples missing by their publishers' sequence numbers (queue overflow): target 0.
    pub contact_frames_dropped: u64,
    pub device_states_dropped: u64,
    /// Surface frames missing by the physics' surface sequence. The surface queue is short
    /// (`SurfaceFrame::MAX_BUFFER`, 4 frames of ~0.6 MB at the viewer's rate, about 160 ms),
    /// so a recorder starved of CPU for longer loses the oldest: counted here rather than
    /// lost unseen (a full test suite beside two diagnoses on 2 cores once recorded 243 of
    /// 268). Not in [`RecorderStats::dropped`], whose target is 0.
    pub surface_frames_dropped: u64,
    pub messages_written: u64,
    /// Samples received again after a restart (the publishers' history) that an earlier
    /// part already holds: not written twice.
    pub already_recorded: u64,
    /// Most samples found in one drain of the device queue (capacity 2048).
    pub max_device_backlog: u64,
    pub flushes: u64,
}

impl RecorderStats {
    pub fn dropped(&self) -> u64 {
        self.contact_frames_dropped + self.device_states_dropped
    }
}

/// Sequence continuity of one stream, per publisher instance.
#[derive(Default)]
struct Continuity {
    last: Option<(u64, u64)>,
}

impl Continuity {
    /// Returns how many samples are missing before this one.
    fn observe(&mut self, instance: u64, sequence: u64) -> u64 {
        let missing = match self.last {
            Some((i, s)) if i == instance && sequence > s + 1 => sequence - s - 1,
            _ => 0,
        };
        self.last = Some((instance, sequence));
        missing
    }
}

struct Ports {
    _node: IpcNode,
    contact: IpcSubscriber<ContactFrame>,
    device: IpcSubscriber<DeviceState>,
    stats: IpcSubscriber<HapticStats>,
    surface: IpcSubscriber<SurfaceFrame>,
}

/// The recorder.
pub struct Recorder {
    session: String,
    config: RecordingConfig,
    writer: Option<SessionWriter>,
    ports: Option<Ports>,
    /// The session's clock: turns publishers' monotonic stamps into ROS 2 / MCAP wall-clock
    /// times, exactly as the bridge does.
    clock: StampClock,
    contact_seq: Continuity,
    device_seq: Continuity,
    surface_seq: Continuity,
    /// What earlier parts hold (a restarted recorder skips it) and what this part holds as
    /// of its last flush (saved beside it for the next restart).
    earlier: Progress,
    progress: Progress,
    pub stats: RecorderStats,
}

impl Recorder {
    /// Creates the file and writes the session's launch file and scene into it. `mapping`
    /// and `clock` are the session's ROS 2 mapping and stamp clock (what the bridge uses).
    pub fn new(
        session: &str,
        config: &RecordingConfig,
        out_dir: &Path,
        info: &SessionInfo,
        mapping: Mapping,
        clock: StampClock,
    ) -> Result<Recorder, RecordingError> {
        config.validate().map_err(|detail| RecordingError::Launch {
            path: info.launch_path.clone().unwrap_or_default(),
            detail,
        })?;
        // A restarted recorder continues in a new part; it never reopens the first one.
        let path = crate::read::next_part_path(out_dir, &config.file_name);
        let writer = SessionWriter::create_with_mapping(&path, config, info, mapping)?;
        // Continuing after a crash: the samples the publishers kept for us that an earlier
        // part holds are skipped, and sequence gaps are counted from where it stopped.
        let earlier = Progress::of_earlier_parts(&path);
        let contact_seq = Continuity {
            last: earlier.contact_steps.last,
        };
        let device_seq = Continuity {
            last: earlier.device_ticks.last,
        };
        Ok(Recorder {
            session: session.to_string(),
            config: config.clone(),
            writer: Some(writer),
            ports: None,
            clock,
            contact_seq,
            device_seq,
            surface_seq: Continuity::default(),
            earlier,
            progress: Progress::default(),
            stats: RecorderStats::default(),
        })
    }

    pub fn path(&self) -> Option<&Path> {
        self.writer.as_ref().map(|w| w.path())
    }

    /// Opens the subscribers (on the calling thread: iceoryx2 ports are not Send).
    pub fn start(&mut self) -> Result<(), RecordingError> {
        let link = |e: ipc::LinkError| RecordingError::Link {
            path: self.path().map(Path::to_path_buf).unwrap_or_default(),
            detail: e.to_string(),
        };
        let node = ipc::create_node(&format!("recorder-{}", std::process::id())).map_err(link)?;
        let contact =
            ipc::subscriber::<ContactFrame>(&node, &self.session, Queue::Every).map_err(link)?;
        let device =
            ipc::subscriber::<DeviceState>(&node, &self.session, Queue::Every).map_err(link)?;
        let stats =
            ipc::subscriber::<HapticStats>(&node, &self.session, Queue::Every).map_err(link)?;
        let surface =
            ipc::subscriber::<SurfaceFrame>(&node, &self.session, Queue::Every).map_err(link)?;
        self.ports = Some(Ports {
            _node: node,
            contact,
            device,
            stats,
            surface,
        });
        Ok(())
    }

    fn log_time(&self, publish_ns: u64) -> u64 {
        self.clock.epoch_ns(publish_ns)
    }

    /// Drains every queue once and writes what it found; finishes a chunk when the flush
    /// interval has passed. Returns the number of samples taken.
    pub fn step(&mut self) -> Result<u64, RecordingError> {
        let (Some(ports), Some(writer)) = (self.ports.as_ref(), self.writer.as_mut()) else {
            return Ok(0);
        };
        let clock = self.clock;
        let to_log = |publish_ns: u64| -> u64 { clock.epoch_ns(publish_ns) };
        let path = writer.path().to_path_buf();
        let link = |e: ipc::LinkError| RecordingError::Link {
            path: path.clone(),
            detail: e.to_string(),
        };
        let mut first_error: Option<RecordingError> = None;
        let mut taken = 0u64;

        // Device ticks first: their queue is the one that fills fastest.
        let stats = &mut self.stats;
        let device_seq = &mut self.device_seq;
        let (earlier, progress) = (&self.earlier, &mut self.progress);
        let n = ipc::drain_each(&ports.device, |d| {
            if earlier.device_ticks.holds(d.instance_id, d.sequence) {
                stats.already_recorded += 1;
                return;
            }
            stats.device_states += 1;
            stats.device_states_dropped += device_seq.observe(d.instance_id, d.sequence);
            if first_error.is_none() {
                match writer.write_device_state(d, to_log(d.publish_ns)) {
                    Ok(()) => progress.device_ticks.wrote(d.instance_id, d.sequence),
                    Err(e) => first_error = Some(e),
                }
            }
        })
        .map_err(link)?;
        stats.max_device_backlog = stats.max_device_backlog.max(n as u64);
        taken += n as u64;

        let contact_seq = &mut self.contact_seq;
        taken += ipc::drain_each(&ports.contact, |f| {
            if earlier.contact_steps.holds(f.instance_id, f.sequence) {
                stats.already_recorded += 1;
                return;
            }
            stats.contact_frames += 1;
            stats.contact_frames_dropped += contact_seq.observe(f.instance_id, f.sequence);
            if first_error.is_none() {
                match writer.write_contact_frame(f, to_log(f.publish_ns)) {
                    Ok(()) => progress.contact_steps.wrote(f.instance_id, f.sequence),
                    Err(e) => first_error = Some(e),
                }
            }
        })
        .map_err(link)? as u64;

        taken += ipc::drain_each(&ports.stats, |h| {
            stats.haptic_stats += 1;
            if first_error.is_none() {
                if let Err(e) = writer.write_haptic_stats(h, to_log(h.publish_ns)) {
                    first_error = Some(e);
                }
            }
        })
        .map_err(link)? as u64;

        let surface_seq = &mut self.surface_seq;
        taken += ipc::drain_each(&ports.surface, |s| {
            stats.surface_frames += 1;
            stats.surface_frames_dropped += surface_seq.observe(s.instance_id, s.sequence);
            if first_error.is_none() {
                match writer.write_surface(s, to_log(s.publish_ns)) {
                    Ok(true) => stats.surface_frames_written += 1,
                    Ok(false) => {}
                    Err(e) => first_error = Some(e),
                }
            }
        })
        .map_err(link)? as u64;

        if let Some(e) = first_error {
            return Err(e);
        }
        if writer.maybe_flush(msgs::clock::monotonic_ns())? {
            stats.flushes += 1;
            // What is flushed is what a kill leaves in the file.
            progress.save(writer.path())?;
        }
        stats.messages_written = writer.messages();
        Ok(taken)
    }

    /// Last drain, then summary, index, rosbag2 metadata; closes the file.
    pub fn stop(&mut self) -> Result<Option<WriteSummary>, RecordingError> {
        if self.ports.is_some() {
            self.step()?;
        }
        self.ports = None;
        let Some(writer) = self.writer.take() else {
            return Ok(None);
        };
        let part = writer.path().to_path_buf();
        let mut extra = BTreeMap::new();
        if let Ok(serde_json::Value::Object(map)) = serde_json::to_value(&self.stats) {
            for (k, v) in map {
                extra.insert(k, v.to_string());
            }
        }
        extra.insert(
            "closed_ns".into(),
            self.log_time(msgs::clock::monotonic_ns()).to_string(),
        );
        let summary = writer.finish(extra)?;
        self.progress.save(&part)?;
        Ok(Some(summary))
    }

    /// The drain period from the configuration.
    pub fn drain_period(&self) -> Duration {
        Duration::from_secs_f64(self.config.drain_period_s)
    }
}

/// Reads the launch file (None: defaults). Returns the parsed file and its text.
pub fn read_launch(path: Option<&Path>) -> Result<(LaunchFile, String), RecordingError> {
    match path {
        None => Ok((LaunchFile::default(), String::new())),
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| RecordingError::io(p, e))?;
            let launch = launch_config::load(p).map_err(|e| RecordingError::Launch {
                path: p.to_path_buf(),
                detail: e.to_string(),
            })?;
            Ok((launch, text))
        }
    }
}

/// Entry point of the `recorder` binary and of `arthrosim node recorder`.
pub fn run_node(args: NodeArgs) -> anyhow::Result<()> {
    launch_config::node::init_tracing("info");
    let out = args.common.out.as_deref().unwrap_or(Path::new("."));
    let stop = msgs::lifecycle::install_stop_flag();
    let session = ipc::session_name(args.common.session.as_deref())?;
    let (launch, launch_text) = read_launch(args.common.launch.as_deref())?;
    let scene_toml = toml::to_string(&launch.scene).context("serialising the scene section")?;
    let info = SessionInfo {
        session: session.clone(),
        launch_path: args.common.launch.clone(),
        launch_text,
        scene_toml,
        source: "recorder".into(),
    };
    if !launch.recording.enabled {
        // Keep the process contract (READY, exit 0 on stop) without writing a file.
        msgs::lifecycle::announce_ready("recorder");
        while !stop.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(50));
        }
        return Ok(());
    }
    let mut recorder = Recorder::new(
        &session,
        &launch.recording,
        out,
        &info,
        launch.bridge.ros_mapping(),
        StampClock::for_session()?,
    )?;
    recorder.start()?;
    msgs::lifecycle::announce_ready("recorder");
    let period = recorder.drain_period();
    let started = std::time::Instant::now();
    let mut result = Ok(());
    while !stop.load(Ordering::SeqCst) {
        if args.seconds > 0.0 && started.elapsed().as_secs_f64() >= args.seconds {
            break;
        }
        if let Err(e) = recorder.step() {
            result = Err(e);
            break;
        }
        std::thread::sleep(period);
    }
    let summary = recorder.stop();
    let stats = serde_json::to_string(&recorder.stats).unwrap_or_default();
    println!("RECORDED {stats}");
    result?;
    let summary = summary?;
    if let Some(s) = summary {
        tracing::info!(path = %s.path.display(), messages = s.messages, bytes = s.bytes, "recording closed");
    }
    Ok(())
}
