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
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Names of the Touch's six joints, in `DeviceState::joint_angles` order.
pub const JOINT_NAMES: [&str; 6] = ["waist", "shoulder", "elbow", "yaw", "pitch", "roll"];

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
    topic: &'static str,
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
    diagnostics: ros::DiagnosticArray,
}

/// Writes one session MCAP.
pub struct SessionWriter {
    path: PathBuf,
    mcap: Option<mcap::Writer<BufWriter<File>>>,
    channels: Vec<Channel>,
    scratch: Scratch,
    payload: Vec<u8>,
    flush_interval_ns: u64,
    mesh_period_ns: u64,
    last_flush_ns: Option<u64>,
    last_mesh_ns: Option<u64>,
    last_buttons: Option<u32>,
    bounds: Option<(u64, u64)>,
    messages: u64,
    write_rosbag2_folder: bool,
    contact_problem: bool,
}

fn mcap_err(path: &Path, e: mcap::McapError) -> RecordingError {
    RecordingError::write(path, e)
}

impl SessionWriter {
    /// Creates `path` and writes header, schemas, channels, the launch file and scene as
    /// attachments and the session metadata record.
    pub fn create(
        path: &Path,
        config: &RecordingConfig,
        info: &SessionInfo,
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
        let mut add =
            |topic: &'static str, def: &'static ros::MsgDef| -> Result<(), RecordingError> {
                let type_name = def.type_name();
                let schema = ros::schema_text_of(def);
                let schema_id = mcap
                    .add_schema(&type_name, SCHEMA_ENCODING, schema.as_bytes())
                    .map_err(|e| mcap_err(path, e))?;
                let id = mcap
                    .add_channel(schema_id, topic, MESSAGE_ENCODING, &qos)
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
        add(TOPIC_CONTACT_STEP, ContactStep::DEF)?;
        add(TOPIC_DEVICE_TICK, DeviceTick::DEF)?;
        add(TOPIC_PROBE_POSE, ros::PoseStamped::DEF)?;
        add(TOPIC_PROBE_WRENCH, ros::WrenchStamped::DEF)?;
        add(TOPIC_DEVICE_WRENCH, ros::WrenchStamped::DEF)?;
        add(TOPIC_JOINT_STATES, ros::JointState::DEF)?;
        add(TOPIC_BUTTONS, ros::Joy::DEF)?;
        add(TOPIC_MESH, ros::Marker::DEF)?;
        add(TOPIC_TF, ros::TFMessage::DEF)?;
        add(TOPIC_DIAGNOSTICS, ros::DiagnosticArray::DEF)?;

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

        let mut scratch = Scratch::default();
        scratch.joints.name = JOINT_NAMES.iter().map(|s| s.to_string()).collect();
        scratch.joints.header.frame_id = WORLD_FRAME.into();
        scratch.pose.header.frame_id = WORLD_FRAME.into();
        scratch.wrench.header.frame_id = WORLD_FRAME.into();
        scratch.joy.header.frame_id = WORLD_FRAME.into();
        scratch.tf.transforms = vec![
            ros::TransformStamped {
                header: ros::Header::new(ros::Time::default(), WORLD_FRAME),
                child_frame_id: "probe".into(),
                transform: ros::Transform::default(),
            },
            ros::TransformStamped {
                header: ros::Header::new(ros::Time::default(), WORLD_FRAME),
                child_frame_id: "proxy".into(),
                transform: ros::Transform::default(),
            },
        ];
        let m = &mut scratch.marker;
        m.header.frame_id = WORLD_FRAME.into();
        m.ns = "meniscus".into();
        m.id = 0;
        m.r#type = ros::Marker::TRIANGLE_LIST;
        m.action = ros::Marker::ADD;
        m.scale = [1.0, 1.0, 1.0].into();
        m.color = ros::ColorRGBA {
            r: 0.93,
            g: 0.85,
            b: 0.72,
            a: 1.0,
        };
        m.frame_locked = true;

        Ok(SessionWriter {
            path: path.to_path_buf(),
            mcap: Some(mcap),
            channels,
            scratch,
            payload: Vec::with_capacity(64 * 1024),
            flush_interval_ns: (config.flush_interval_s.max(0.01) * 1e9) as u64,
            mesh_period_ns: if config.mesh_rate_hz > 0.0 {
                (1e9 / config.mesh_rate_hz) as u64
            } else {
                u64::MAX
            },
            last_flush_ns: None,
            last_mesh_ns: None,
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

    /// One physics step: the lossless ContactStep, the probe pose and wrench, and /tf.
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
            s.pose.header.stamp = stamp;
            s.pose.pose = (&f.probe_pose).into();
            self.write_msg(Ch::ProbePose, &s.pose, log_ns)?;

            s.wrench.header.stamp = stamp;
            s.wrench.wrench.force = f.contact_force.into();
            s.wrench.wrench.torque = f.contact_torque.into();
            self.write_msg(Ch::ProbeWrench, &s.wrench, log_ns)?;

            s.tf.transforms[0].header.stamp = stamp;
            s.tf.transforms[0].transform = (&f.probe_pose).into();
            s.tf.transforms[1].header.stamp = stamp;
            s.tf.transforms[1].transform = (&f.proxy_pose).into();
            self.write_msg(Ch::Tf, &s.tf, log_ns)
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
            s.wrench.header.stamp = stamp;
            s.wrench.wrench.force = d.rendered_force.into();
            s.wrench.wrench.torque = [0.0; 3].into();
            self.write_msg(Ch::DeviceWrench, &s.wrench, log_ns)?;

            s.joints.header.stamp = stamp;
            s.joints.position.clear();
            s.joints.position.extend_from_slice(&d.joint_angles);
            self.write_msg(Ch::JointStates, &s.joints, log_ns)?;

            if self.last_buttons != Some(d.buttons) {
                self.last_buttons = Some(d.buttons);
                s.joy.header.stamp = stamp;
                s.joy.buttons.clear();
                s.joy
                    .buttons
                    .extend((0..2).map(|b| ((d.buttons >> b) & 1) as i32));
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
        let level = if h.faults != 0 {
            ros::DiagnosticStatus::WARN
        } else {
            ros::DiagnosticStatus::OK
        };
        let values = [
            ("ticks", h.ticks.to_string()),
            ("tick_hz", h.tick_hz.to_string()),
            ("period_err_p50_us", h.period_err_p50_us.to_string()),
            ("period_err_p99_us", h.period_err_p99_us.to_string()),
            ("period_err_max_us", h.period_err_max_us.to_string()),
            ("lcp_p50_us", h.lcp_p50_us.to_string()),
            ("lcp_p99_us", h.lcp_p99_us.to_string()),
            ("lcp_iterations_mean", h.lcp_iterations_mean.to_string()),
            ("frame_age_p50_us", h.frame_age_p50_us.to_string()),
            ("frame_age_p99_us", h.frame_age_p99_us.to_string()),
            ("transport_p50_us", h.transport_p50_us.to_string()),
            ("transport_p99_us", h.transport_p99_us.to_string()),
            ("rendered_force_norm_n", h.rendered_force_norm_n.to_string()),
            ("fault_count", h.fault_count.to_string()),
            ("faults", format!("{:#x}", h.faults)),
            ("realtime", h.realtime.to_string()),
            ("sequence", h.sequence.to_string()),
        ];
        let mut d = std::mem::take(&mut self.scratch.diagnostics);
        d.header = ros::Header::new(ros::Time::from_nanos(log_ns), "");
        d.status.clear();
        d.status.push(ros::DiagnosticStatus {
            level,
            name: "arthrosim/haptic".into(),
            message: if level == ros::DiagnosticStatus::OK {
                "ok".into()
            } else {
                "faults".into()
            },
            hardware_id: format!("{:016x}", h.instance_id),
            values: values
                .iter()
                .map(|(k, v)| ros::KeyValue::new(k, v))
                .collect(),
        });
        let result = self.write_msg(Ch::Diagnostics, &d, log_ns);
        self.scratch.diagnostics = d;
        result
    }

    /// True when a surface frame at `log_ns` is due at the configured viewer rate.
    pub fn mesh_due(&self, log_ns: u64) -> bool {
        match self.last_mesh_ns {
            None => true,
            Some(last) => log_ns.saturating_sub(last) >= self.mesh_period_ns,
        }
    }

    /// The deformed surface as a TRIANGLE_LIST marker, at most at the viewer rate (frames in
    /// between are skipped). Returns whether it was written.
    pub fn write_surface(&mut self, s: &SurfaceFrame, log_ns: u64) -> Result<bool, RecordingError> {
        if !self.mesh_due(log_ns) {
            return Ok(false);
        }
        self.last_mesh_ns = Some(log_ns);
        let vertices = (s.vertex_count as usize).min(msgs::MAX_SURFACE_VERTICES);
        let triangles = (s.triangle_count as usize).min(msgs::MAX_SURFACE_TRIANGLES);
        let mut m = std::mem::take(&mut self.scratch.marker);
        m.header.stamp = ros::Time::from_nanos(log_ns);
        m.points.clear();
        for t in &s.triangles[..triangles] {
            // A corrupt index is skipped rather than trusted.
            if t.iter().all(|&i| (i as usize) < vertices) {
                for &i in t {
                    let p = s.positions[i as usize];
                    m.points
                        .push([p[0] as f64, p[1] as f64, p[2] as f64].into());
                }
            }
        }
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
                topic: c.topic.to_string(),
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
