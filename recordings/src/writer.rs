//! `SessionWriter`: one MCAP per session, ROS 2 profile, CDR messages with `ros2msg`
//! schemas, zstd chunks finished at least every `flush_interval` so a killed recorder leaves
//! a file readable up to its last flush.
//!
//! Used by the recorder node (live streams), by replay (offline physics) and by tests.

use crate::channels::*;
use crate::error::RecordingError;
use launch_config::recording::{ChunkCompression, RecordingConfig};
use mcap::records::{MessageHeader, Metadata};
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::ros::{self, RosMessage};
use msgs::ros_mapping::{Mapping, Topic};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// What the session is, written once at the start (so a killed recorder keeps it).
#[derive(Debug, Clone, Default)]
pub struct SessionInfo {
    /// iceoryx2 session name.
    pub session: String,
    /// Path of the launch file, if any.
    pub launch_path: Option<PathBuf>,
    /// The launch file's text (empty launch file = defaults).
    pub launch_text: String,
    /// The scene section as TOML (after defaults).
    pub scene_toml: String,
    /// Where the messages come from: `recorder` (live) or `replay of FILE`.
    pub source: String,
}

/// Per-topic counters of a finished file.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TopicCount {
    pub topic: String,
    pub type_name: String,
    pub count: u64,
}

/// What `finish` reports.
#[derive(Debug, Clone, serde::Serialize)]
pub struct WriteSummary {
    pub path: PathBuf,
    pub messages: u64,
    pub bytes: u64,
    pub start_ns: u64,
    pub end_ns: u64,
    pub topics: Vec<TopicCount>,
}

struct Channel {
    id: u16,
    topic: String,
    type_name: String,
    count: u64,
}

/// Channel ids in a fixed order (index into `SessionWriter::channels`).
#[derive(Clone, Copy)]
enum Ch {
    ContactStep = 0,
    DeviceTick,
    ProbePose,
    ProbeWrench,
    DeviceWrench,
    JointStates,
    Buttons,
    Mesh,
    Tf,
    Diagnostics,
    Contacts,
}

/// Scratch messages reused for every write (no per-message allocation once warmed up).
#[derive(Default)]
struct Scratch {
    contact_step: ContactStep,
    device_tick: DeviceTick,
    pose: ros::PoseStamped,
    wrench: ros::WrenchStamped,
    joints: ros::JointState,
    joy: ros::Joy,
    tf: ros::TFMessage,
    marker: ros::Marker,
    contacts: ros::MarkerArray,
    diagnostics: ros::DiagnosticArray,
}

/// Writes one session MCAP.
pub struct SessionWriter {
    path: PathBuf,
    mcap: Option<mcap::Writer<BufWriter<File>>>,
    channels: Vec<Channel>,
    /// The one session → ROS 2 mapping (shared with the bridge).
    mapping: Mapping,
    scratch: Scratch,
    payload: Vec<u8>,
    flush_interval_ns: u64,
    mesh_period_ns: u64,
    last_flush_ns: Option<u64>,
    last_mesh_ns: Option<u64>,
    last_contacts_ns: Option<u64>,
    last_buttons: Option<u32>,
    bounds: Option<(u64, u64)>,
    messages: u64,
    write_rosbag2_folder: bool,
    contact_problem: bool,
}

/// True when a viewer-rate message at `log_ns` is due (`period_ns` after the last one).
fn due(last_ns: Option<u64>, log_ns: u64, period_ns: u64) -> bool {
    match last_ns {
        None => true,
        Some(last) => log_ns.saturating_sub(last) >= period_ns,
    }
}

fn mcap_err(path: &Path, e: mcap::McapError) -> RecordingError {
    RecordingError::write(path, e)
}

impl SessionWriter {
    /// [`create_with_mapping`](Self::create_with_mapping) with the default mapping
    /// (namespace `/arthrosim`, frame `world`, fixed frames at the origin).
    pub fn create(
        path: &Path,
        config: &RecordingConfig,
        info: &SessionInfo,
    ) -> Result<SessionWriter, RecordingError> {
        Self::create_with_mapping(path, config, info, Mapping::default())
    }

    /// Creates `path` and writes header, schemas, channels, the launch file and scene as
    /// attachments and the session metadata record. The ROS 2 topics, frames and tf tree
    /// come from `mapping` (the launch file's `[bridge]` section: what the bridge publishes).
    pub fn create_with_mapping(
        path: &Path,
        config: &RecordingConfig,
        info: &SessionInfo,
        mapping: Mapping,
    ) -> Result<SessionWriter, RecordingError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| RecordingError::io(dir, e))?;
        }
        // Never truncates: a recording that exists is an earlier part of a session (a
        // restarted recorder writes `session.N.mcap`, see `read::next_part_path`).
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|e| RecordingError::io(path, e))?;
        let compression = match config.compression {
            ChunkCompression::Zstd => Some(mcap::Compression::Zstd),
            ChunkCompression::None => None,
        };
        let options = mcap::WriteOptions::new()
            .profile(PROFILE)
            .library(format!(
                "arthrosim-recordings {}",
                env!("CARGO_PKG_VERSION")
            ))
            .compression(compression)
            .compression_level(config.zstd_level)
            // Single-threaded zstd: the recorder's CPU share stays its own thread's, and a
            // chunk is complete on disk when `flush` returns.
            .compression_threads(0)
            .chunk_size(Some(config.chunk_size_bytes));
        let mut mcap = options
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| mcap_err(path, e))?;

        let qos: BTreeMap<String, String> = [(
            "offered_qos_profiles".to_string(),
            OFFERED_QOS_PROFILES.to_string(),
        )]
        .into_iter()
        .collect();
        let mut channels = Vec::new();
        let mut add = |topic: String, def: &'static ros::MsgDef| -> Result<(), RecordingError> {
            let type_name = def.type_name();
            let schema = ros::schema_text_of(def);
            let schema_id = mcap
                .add_schema(&type_name, SCHEMA_ENCODING, schema.as_bytes())
                .map_err(|e| mcap_err(path, e))?;
            let id = mcap
                .add_channel(schema_id, &topic, MESSAGE_ENCODING, &qos)
                .map_err(|e| mcap_err(path, e))?;
            channels.push(Channel {
                id,
                topic,
                type_name,
                count: 0,
            });
            Ok(())
        };
        // Order must match `Ch`.
        add(TOPIC_CONTACT_STEP.into(), ContactStep::DEF)?;
        add(TOPIC_DEVICE_TICK.into(), DeviceTick::DEF)?;
        for topic in [
            Topic::ProbePose,
            Topic::ProbeWrench,
            Topic::DeviceWrench,
            Topic::JointStates,
            Topic::Buttons,
            Topic::Mesh,
            Topic::Tf,
            Topic::Diagnostics,
            Topic::Contacts,
        ] {
            add(mapping.topic(topic), topic.def())?;
        }

        let now = msgs::clock::realtime_ns();
        for (name, text) in [
            (ATTACHMENT_LAUNCH, info.launch_text.as_str()),
            (ATTACHMENT_SCENE, info.scene_toml.as_str()),
        ] {
            mcap.attach(&mcap::Attachment {
                log_time: now,
                create_time: now,
                name: name.to_string(),
                media_type: "application/toml".to_string(),
                data: std::borrow::Cow::Borrowed(text.as_bytes()),
            })
            .map_err(|e| mcap_err(path, e))?;
        }
        let mut meta = BTreeMap::new();
        meta.insert("session".to_string(), info.session.clone());
        meta.insert(
            "launch_path".to_string(),
            info.launch_path
                .as_ref()
                .map(|p| p.display().to_string())
                .unwrap_or_default(),
        );
        meta.insert("source".to_string(), info.source.clone());
        meta.insert("created_ns".to_string(), now.to_string());
        meta.insert(
            "writer".to_string(),
            format!("arthrosim-recordings {}", env!("CARGO_PKG_VERSION")),
        );
        meta.insert(
            "lossless_topics".to_string(),
            format!("{TOPIC_CONTACT_STEP} {TOPIC_DEVICE_TICK}"),
        );
        mcap.write_metadata(&Metadata {
            name: SESSION_METADATA.to_string(),
            metadata: meta,
        })
        .map_err(|e| mcap_err(path, e))?;
        // Make the header, channels and attachments durable right away.
        mcap.flush().map_err(|e| mcap_err(path, e))?;

        Ok(SessionWriter {
            path: path.to_path_buf(),
            mcap: Some(mcap),
            channels,
            mapping,
            scratch: Scratch::default(),
            payload: Vec::with_capacity(64 * 1024),
            flush_interval_ns: (config.flush_interval_s.max(0.01) * 1e9) as u64,
            mesh_period_ns: if config.mesh_rate_hz > 0.0 {
                (1e9 / config.mesh_rate_hz) as u64
            } else {
                u64::MAX
            },
            last_flush_ns: None,
            last_mesh_ns: None,
            last_contacts_ns: None,
            last_buttons: None,
            bounds: None,
            messages: 0,
            write_rosbag2_folder: config.rosbag2_folder,
            contact_problem: config.contact_problem,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Messages written so far.
    pub fn messages(&self) -> u64 {
        self.messages
    }

    fn put<T: RosMessage>(
        mcap: &mut mcap::Writer<BufWriter<File>>,
        payload: &mut Vec<u8>,
        channel: &mut Channel,
        path: &Path,
        msg: &T,
        log_ns: u64,
    ) -> Result<(), RecordingError> {
        ros::to_cdr(msg, payload).map_err(|e| RecordingError::write(path, e))?;
        channel.count += 1;
        mcap.write_to_known_channel(
            &MessageHeader {
                channel_id: channel.id,
                // Per-channel sequence (wraps at 2³²; the lossless channels carry u64 ones).
                sequence: channel.count as u32,
                log_time: log_ns,
                publish_time: log_ns,
            },
            payload,
        )
        .map_err(|e| mcap_err(path, e))
    }

    fn write_msg<T: RosMessage>(
        &mut self,
        ch: Ch,
        msg: &T,
        log_ns: u64,
    ) -> Result<(), RecordingError> {
        let mcap = self
            .mcap
            .as_mut()
            .ok_or_else(|| RecordingError::write(&self.path, "writer already finished"))?;
        Self::put(
            mcap,
            &mut self.payload,
            &mut self.channels[ch as usize],
            &self.path,
            msg,
            log_ns,
        )?;
        self.messages += 1;
        self.bounds = Some(match self.bounds {
            None => (log_ns, log_ns),
            Some((a, b)) => (a.min(log_ns), b.max(log_ns)),
        });
        Ok(())
    }

    /// One physics step: the lossless ContactStep, the probe pose and wrench, /tf, and the
    /// contact markers at the viewer rate.
    pub fn write_contact_frame(
        &mut self,
        f: &ContactFrame,
        log_ns: u64,
    ) -> Result<(), RecordingError> {
        let mut s = std::mem::take(&mut self.scratch);
        let result = (|| {
            s.contact_step.fill_from(f, log_ns, self.contact_problem);
            self.write_msg(Ch::ContactStep, &s.contact_step, log_ns)?;

            let stamp = ros::Time::from_nanos(log_ns);
            let map = &self.mapping;
            map.probe_pose_into(&mut s.pose, f, stamp);
            map.probe_wrench_into(&mut s.wrench, f, stamp);
            map.transforms_into(&mut s.tf, f, stamp);
            self.write_msg(Ch::ProbePose, &s.pose, log_ns)?;
            self.write_msg(Ch::ProbeWrench, &s.wrench, log_ns)?;
            self.write_msg(Ch::Tf, &s.tf, log_ns)?;

            // Contact markers are for viewers: at the viewer rate, like the surface.
            if due(self.last_contacts_ns, log_ns, self.mesh_period_ns) {
                self.last_contacts_ns = Some(log_ns);
                self.mapping.contact_markers_into(&mut s.contacts, f, stamp);
                self.write_msg(Ch::Contacts, &s.contacts, log_ns)?;
            }
            Ok(())
        })();
        self.scratch = s;
        result
    }

    /// One haptic tick: the lossless DeviceTick, the device wrench and joint states, and the
    /// buttons when they change.
    pub fn write_device_state(
        &mut self,
        d: &DeviceState,
        log_ns: u64,
    ) -> Result<(), RecordingError> {
        let mut s = std::mem::take(&mut self.scratch);
        let result = (|| {
            s.device_tick.fill_from(d, log_ns);
            self.write_msg(Ch::DeviceTick, &s.device_tick, log_ns)?;

            let stamp = ros::Time::from_nanos(log_ns);
            self.mapping.device_wrench_into(&mut s.wrench, d, stamp);
            self.write_msg(Ch::DeviceWrench, &s.wrench, log_ns)?;
            self.mapping.joint_states_into(&mut s.joints, d, stamp);
            self.write_msg(Ch::JointStates, &s.joints, log_ns)?;

            if self.last_buttons != Some(d.buttons) {
                self.last_buttons = Some(d.buttons);
                self.mapping.buttons_into(&mut s.joy, d, stamp);
                self.write_msg(Ch::Buttons, &s.joy, log_ns)?;
            }
            Ok(())
        })();
        self.scratch = s;
        result
    }

    /// Haptic loop statistics as a `/diagnostics` array.
    pub fn write_haptic_stats(
        &mut self,
        h: &HapticStats,
        log_ns: u64,
    ) -> Result<(), RecordingError> {
        let mut d = std::mem::take(&mut self.scratch.diagnostics);
        d.header = self
            .mapping
            .diagnostics_header(ros::Time::from_nanos(log_ns));
        d.status.resize_with(1, Default::default);
        self.mapping.haptic_status_into(&mut d.status[0], h);
        let result = self.write_msg(Ch::Diagnostics, &d, log_ns);
        self.scratch.diagnostics = d;
        result
    }

    /// True when a surface frame at `log_ns` is due at the configured viewer rate.
    pub fn mesh_due(&self, log_ns: u64) -> bool {
        due(self.last_mesh_ns, log_ns, self.mesh_period_ns)
    }

    /// The deformed surface as a TRIANGLE_LIST marker, at most at the viewer rate (frames in
    /// between are skipped). Returns whether it was written.
    pub fn write_surface(&mut self, s: &SurfaceFrame, log_ns: u64) -> Result<bool, RecordingError> {
        if !self.mesh_due(log_ns) {
            return Ok(false);
        }
        self.last_mesh_ns = Some(log_ns);
        let mut m = std::mem::take(&mut self.scratch.marker);
        // A corrupt index is skipped rather than trusted.
        self.mapping
            .mesh_marker_into(&mut m, s, ros::Time::from_nanos(log_ns));
        let result = self.write_msg(Ch::Mesh, &m, log_ns);
        self.scratch.marker = m;
        result.map(|_| true)
    }

    /// Finishes the current chunk if `flush_interval` has passed since the last one (call
    /// often; `now_ns` is any monotonic clock).
    pub fn maybe_flush(&mut self, now_ns: u64) -> Result<bool, RecordingError> {
        let due = match self.last_flush_ns {
            None => true,
            Some(last) => now_ns.saturating_sub(last) >= self.flush_interval_ns,
        };
        if !due {
            return Ok(false);
        }
        self.last_flush_ns = Some(now_ns);
        self.flush()?;
        Ok(true)
    }

    /// Finishes the current chunk and flushes it to the file.
    pub fn flush(&mut self) -> Result<(), RecordingError> {
        match self.mcap.as_mut() {
            Some(m) => m.flush().map_err(|e| mcap_err(&self.path, e)),
            None => Ok(()),
        }
    }

    fn topic_counts(&self) -> Vec<TopicCount> {
        self.channels
            .iter()
            .map(|c| TopicCount {
                topic: c.topic.clone(),
                type_name: c.type_name.clone(),
                count: c.count,
            })
            .collect()
    }

    /// Writes the rosbag2 metadata record and `extra` session counters, the summary and
    /// index, closes the file and (if configured) writes `metadata.yaml` beside it.
    pub fn finish(
        mut self,
        extra: BTreeMap<String, String>,
    ) -> Result<WriteSummary, RecordingError> {
        let mut mcap = self
            .mcap
            .take()
            .ok_or_else(|| RecordingError::write(&self.path, "writer already finished"))?;
        let (start_ns, end_ns) = self.bounds.unwrap_or((0, 0));
        let topics = self.topic_counts();
        let file_name = self
            .path
            .file_name()
            .map(|n| n.to_string_lossy().to_string())
            .unwrap_or_else(|| "session.mcap".into());
        let yaml = crate::rosbag2::metadata_yaml(&file_name, &topics, start_ns, end_ns);
        let mut rosbag2 = BTreeMap::new();
        rosbag2.insert("serialized_metadata".to_string(), yaml.clone());
        rosbag2.insert(
            "ROS_DISTRO".to_string(),
            crate::rosbag2::ROS_DISTRO.to_string(),
        );
        mcap.write_metadata(&Metadata {
            name: ROSBAG2_METADATA.to_string(),
            metadata: rosbag2,
        })
        .map_err(|e| mcap_err(&self.path, e))?;
        if !extra.is_empty() {
            mcap.write_metadata(&Metadata {
                name: format!("{SESSION_METADATA}_end"),
                metadata: extra,
            })
            .map_err(|e| mcap_err(&self.path, e))?;
        }
        mcap.finish().map_err(|e| mcap_err(&self.path, e))?;
        let mut inner = mcap.into_inner();
        std::io::Write::flush(&mut inner).map_err(|e| RecordingError::io(&self.path, e))?;
        drop(inner);
        if self.write_rosbag2_folder {
            let dir = self.path.parent().unwrap_or(Path::new("."));
            let yaml_path = dir.join("metadata.yaml");
            // A folder is one rosbag2 bag: never replace the metadata of another file in it
            // (e.g. a replay written beside the session it replays).
            let foreign = std::fs::read_to_string(&yaml_path)
                .map(|old| {
                    !old.contains(&format!(
                        "- path: {}",
                        serde_json::to_string(&file_name).unwrap_or_default()
                    ))
                })
                .unwrap_or(false);
            if foreign {
                tracing::warn!(
                    path = %yaml_path.display(),
                    "metadata.yaml belongs to another recording; not replaced"
                );
            } else {
                std::fs::write(&yaml_path, &yaml).map_err(|e| RecordingError::io(&yaml_path, e))?;
            }
        }
        let bytes = std::fs::metadata(&self.path)
            .map_err(|e| RecordingError::io(&self.path, e))?
            .len();
        Ok(WriteSummary {
            path: self.path.clone(),
            messages: self.messages,
            bytes,
            start_ns,
            end_ns,
            topics,
        })
    }
}
