//! The DDS side: one thread that owns the ros2-client node, writes what the shared-memory side
//! queued, polls the inbound subscriptions and publishes `/diagnostics`. Nothing here can
//! block the shared-memory side: it only ever sees a bounded queue.

use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use launch_config::bridge::{self as cfg, BridgeConfig, StreamConfig};
use msgs::ros::*;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, Name, Node, NodeName, NodeOptions, Publisher, QosProfile, Subscription,
};
use serde::Serialize;

use msgs::ros_mapping::{self, Mapping, StampClock, Topic};

use crate::convert;
use crate::stats::{BridgeStats, LatencyWindow};
use crate::target_gate::Refusal;

/// A message for the DDS side, with the monotonic publish time of the sample it came from.
pub struct Envelope {
    pub source_ns: u64,
    pub msg: Outbound,
}

pub enum Outbound {
    ProbePose(PoseStamped),
    ProbeWrench(WrenchStamped),
    DeviceWrench(WrenchStamped),
    JointStates(JointState),
    Buttons(Joy),
    Mesh(Box<Marker>),
    Contacts(MarkerArray),
    Tf(TFMessage),
}

impl Outbound {
    pub fn topic(&self) -> Topic {
        match self {
            Outbound::ProbePose(_) => Topic::ProbePose,
            Outbound::ProbeWrench(_) => Topic::ProbeWrench,
            Outbound::DeviceWrench(_) => Topic::DeviceWrench,
            Outbound::JointStates(_) => Topic::JointStates,
            Outbound::Buttons(_) => Topic::Buttons,
            Outbound::Mesh(_) => Topic::Mesh,
            Outbound::Contacts(_) => Topic::Contacts,
            Outbound::Tf(_) => Topic::Tf,
        }
    }
}

/// A command from ROS for the physics node (forwarded over shared memory).
#[derive(Debug, Clone, Copy)]
pub enum Inbound {
    ProbeTarget(msgs::Pose),
    DegenerationGrade(f64),
}

/// Failure to bring up the DDS side.
#[derive(Debug, thiserror::Error)]
pub enum DdsError {
    #[error("bridge topic name {name:?}: {detail}")]
    Name { name: String, detail: String },
    #[error("DDS setup failed ({what}): {detail}")]
    Setup { what: String, detail: String },
}

fn setup<E: std::fmt::Debug>(what: impl Into<String>) -> impl FnOnce(E) -> DdsError {
    let what = what.into();
    move |e| DdsError::Setup {
        what,
        detail: format!("{e:?}"),
    }
}

/// The DDS QoS of a configured stream. Reliable writers never wait for a full send window
/// (`WhenFull::Fail`): the sample is dropped and counted instead.
pub fn qos(stream: &StreamConfig) -> QosProfile {
    let base = QosProfile::publisher_default().history(History::KeepLast {
        depth: stream.depth,
    });
    let base = match stream.reliability {
        cfg::Reliability::Reliable => base.reliability_reliable(WhenFull::Fail),
        cfg::Reliability::BestEffort => base.reliability_best_effort(),
    };
    base.durability(match stream.durability {
        cfg::Durability::Volatile => Durability::Volatile,
        cfg::Durability::TransientLocal => Durability::TransientLocal,
    })
}

/// Full ROS name of a topic ([`ros_mapping::full_topic_name`]), checked by ros2-client.
pub fn topic_name(namespace: &str, topic: &str) -> Result<Name, DdsError> {
    let full = ros_mapping::full_topic_name(namespace, topic);
    Name::parse(&full).map_err(|e| DdsError::Name {
        name: full,
        detail: format!("{e:?}"),
    })
}

/// The writer of one session topic, with the name and settings the topic has (none when the
/// launch file disables it).
fn publisher<M: RosMessage + ros2_client::Message>(
    node: &mut Node,
    config: &BridgeConfig,
    session_topic: Topic,
) -> Result<Option<Publisher<M>>, DdsError> {
    let stream = config.streams.of(session_topic);
    if !stream.enabled {
        return Ok(None);
    }
    let topic = session_topic.relative();
    let qos = qos(stream);
    let name = topic_name(&config.namespace, topic)?;
    let topic_handle = node
        .create_topic(&name, message_type_name::<M>(), &qos)
        .map_err(setup(format!("topic {topic}")))?;
    let publisher = node
        .create_publisher::<M>(&topic_handle, Some(qos))
        .map_err(setup(format!("publisher {topic}")))?;
    Ok(Some(publisher))
}

fn subscription<M: RosMessage + ros2_client::Message + 'static>(
    node: &mut Node,
    namespace: &str,
    topic: &str,
    stream: &StreamConfig,
) -> Result<Option<Subscription<M>>, DdsError> {
    if !stream.enabled {
        return Ok(None);
    }
    let qos = qos(stream);
    let name = topic_name(namespace, topic)?;
    let topic_handle = node
        .create_topic(&name, message_type_name::<M>(), &qos)
        .map_err(setup(format!("topic {topic}")))?;
    let subscription = node
        .create_subscription::<M>(&topic_handle, Some(qos))
        .map_err(setup(format!("subscription {topic}")))?;
    Ok(Some(subscription))
}

struct Publishers {
    probe_pose: Option<Publisher<PoseStamped>>,
    probe_wrench: Option<Publisher<WrenchStamped>>,
    device_wrench: Option<Publisher<WrenchStamped>>,
    joint_states: Option<Publisher<JointState>>,
    buttons: Option<Publisher<Joy>>,
    mesh: Option<Publisher<Marker>>,
    contacts: Option<Publisher<MarkerArray>>,
    tf: Option<Publisher<TFMessage>>,
    diagnostics: Option<Publisher<DiagnosticArray>>,
}

/// The DDS side's state (lives on its own thread).
struct DdsSide {
    config: BridgeConfig,
    stats: Arc<BridgeStats>,
    clock: StampClock,
    mapping: Mapping,
    // Field order matters for drop: endpoints before the node, the node before the context.
    publishers: Publishers,
    target_pose: Option<Subscription<PoseStamped>>,
    degeneration_grade: Option<Subscription<Float64>>,
    _node: Node,
    _context: Context,
    _spinner: JoinHandle<()>,
    inbound: SyncSender<Inbound>,
    /// Source publish → DDS write latency per stream in the current window, ns.
    latency_ns: [LatencyWindow; Topic::COUNT],
    window_start: Instant,
    last_published: [u64; Topic::COUNT],
    last_dropped: [u64; Topic::COUNT],
    last_inputs: [u64; 3],
}

/// Handle of the running DDS thread.
pub struct DdsThread {
    pub handle: JoinHandle<()>,
}

/// Starts the DDS thread; returns once its node, publishers and subscriptions exist (or
/// with the error that prevented it).
pub fn spawn(
    config: BridgeConfig,
    stats: Arc<BridgeStats>,
    clock: StampClock,
    mapping: Mapping,
    outbound: Receiver<Envelope>,
    inbound: SyncSender<Inbound>,
) -> Result<DdsThread, DdsError> {
    let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel::<Result<(), DdsError>>(1);
    let handle = std::thread::Builder::new()
        .name("viz-bridge-dds".into())
        .spawn(
            move || match DdsSide::new(config, stats, clock, mapping, inbound) {
                Ok(mut side) => {
                    let _ = ready_tx.send(Ok(()));
                    side.run(outbound);
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            },
        )
        .map_err(setup("spawn DDS thread"))?;
    match ready_rx.recv() {
        Ok(Ok(())) => Ok(DdsThread { handle }),
        Ok(Err(e)) => {
            let _ = handle.join();
            Err(e)
        }
        Err(_) => Err(DdsError::Setup {
            what: "DDS thread".into(),
            detail: "exited before it was ready".into(),
        }),
    }
}

impl DdsSide {
    fn new(
        config: BridgeConfig,
        stats: Arc<BridgeStats>,
        clock: StampClock,
        mapping: Mapping,
        inbound: SyncSender<Inbound>,
    ) -> Result<DdsSide, DdsError> {
        let context = Context::with_options(ContextOptions::new().domain_id(config.domain_id))
            .map_err(setup("DDS participant"))?;
        let node_name =
            NodeName::new(&config.namespace, "viz_bridge").map_err(|e| DdsError::Name {
                name: config.namespace.clone(),
                detail: format!("{e:?}"),
            })?;
        let mut node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(false))
            .map_err(setup("ROS 2 node"))?;
        // The spinner answers ROS graph queries (node/topic listing); it ends when the node
        // is dropped.
        let spinner = node.spinner().map_err(setup("spinner"))?;
        let spinner = std::thread::Builder::new()
            .name("viz-bridge-spin".into())
            .spawn(move || {
                if let Err(e) = futures_executor::block_on(spinner.spin()) {
                    tracing::warn!("ROS 2 spinner stopped: {e:?}");
                }
            })
            .map_err(setup("spawn spinner"))?;
        let publishers = Publishers {
            probe_pose: publisher(&mut node, &config, Topic::ProbePose)?,
            probe_wrench: publisher(&mut node, &config, Topic::ProbeWrench)?,
            device_wrench: publisher(&mut node, &config, Topic::DeviceWrench)?,
            joint_states: publisher(&mut node, &config, Topic::JointStates)?,
            buttons: publisher(&mut node, &config, Topic::Buttons)?,
            mesh: publisher(&mut node, &config, Topic::Mesh)?,
            contacts: publisher(&mut node, &config, Topic::Contacts)?,
            tf: publisher(&mut node, &config, Topic::Tf)?,
            diagnostics: publisher(&mut node, &config, Topic::Diagnostics)?,
        };
        let ns = &config.namespace;
        let s = &config.streams;
        let target_pose = subscription(
            &mut node,
            ns,
            ros_mapping::TOPIC_TARGET_POSE,
            &s.target_pose,
        )?;
        let degeneration_grade = subscription(
            &mut node,
            ns,
            ros_mapping::TOPIC_DEGENERATION_GRADE,
            &s.degeneration_grade,
        )?;
        Ok(DdsSide {
            config,
            stats,
            clock,
            mapping,
            publishers,
            target_pose,
            degeneration_grade,
            _node: node,
            _context: context,
            _spinner: spinner,
            inbound,
            latency_ns: Default::default(),
            window_start: Instant::now(),
            last_published: [0; Topic::COUNT],
            last_dropped: [0; Topic::COUNT],
            last_inputs: [0; 3],
        })
    }

    /// Runs until the shared-memory side drops its sender.
    fn run(&mut self, outbound: Receiver<Envelope>) {
        let diag_interval = Duration::from_nanos(
            self.config
                .streams
                .diagnostics
                .min_interval_ns()
                .max(1_000_000),
        );
        let mut next_diag = Instant::now() + diag_interval;
        loop {
            match outbound.recv_timeout(Duration::from_millis(2)) {
                Ok(envelope) => {
                    self.write(envelope);
                    // Drain what else is queued before polling inputs, bounded so inbound
                    // commands are still served under a flood.
                    for _ in 0..256 {
                        match outbound.try_recv() {
                            Ok(envelope) => self.write(envelope),
                            Err(_) => break,
                        }
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            self.poll_inbound();
            let now = Instant::now();
            if now >= next_diag {
                self.publish_diagnostics();
                next_diag = now + diag_interval;
            }
        }
        // Endpoints, node (which stops the spinner) and participant drop with `self`.
    }

    fn write(&mut self, envelope: Envelope) {
        let stream = envelope.msg.topic();
        let p = &self.publishers;
        let ok = match envelope.msg {
            Outbound::ProbePose(m) => put(&p.probe_pose, m),
            Outbound::ProbeWrench(m) => put(&p.probe_wrench, m),
            Outbound::DeviceWrench(m) => put(&p.device_wrench, m),
            Outbound::JointStates(m) => put(&p.joint_states, m),
            Outbound::Buttons(m) => put(&p.buttons, m),
            Outbound::Mesh(m) => put(&p.mesh, *m),
            Outbound::Contacts(m) => put(&p.contacts, m),
            Outbound::Tf(m) => put(&p.tf, m),
        };
        let counters = self.stats.stream(stream);
        if ok {
            BridgeStats::add(&counters.published, 1);
            let latency = msgs::clock::monotonic_ns().saturating_sub(envelope.source_ns);
            self.latency_ns[stream as usize].record(latency);
        } else {
            BridgeStats::add(&counters.dropped_dds, 1);
        }
    }

    fn poll_inbound(&mut self) {
        if let Some(sub) = &self.target_pose {
            while let Ok(Some((msg, _info))) = sub.take() {
                if !self.config.accept_target_pose {
                    // Counted, never forwarded: external control is opt-in.
                    BridgeStats::add(&self.stats.targets_refused[Refusal::Disabled as usize], 1);
                    continue;
                }
                match convert::probe_target(&msg) {
                    Some(pose) => forward(&self.inbound, &self.stats, Inbound::ProbeTarget(pose)),
                    None => BridgeStats::add(
                        &self.stats.targets_refused[Refusal::Malformed as usize],
                        1,
                    ),
                }
            }
        }
        if let Some(sub) = &self.degeneration_grade {
            while let Ok(Some((msg, _info))) = sub.take() {
                match convert::degeneration_grade(&msg) {
                    Some(g) => forward(&self.inbound, &self.stats, Inbound::DegenerationGrade(g)),
                    None => BridgeStats::add(&self.stats.inbound_rejected, 1),
                }
            }
        }
    }

    fn publish_diagnostics(&mut self) {
        let elapsed = self.window_start.elapsed().as_secs_f64().max(1e-3);
        self.window_start = Instant::now();
        let msg = self.diagnostics(elapsed);
        if let Some(p) = &self.publishers.diagnostics {
            let _ = p.publish(msg);
        }
    }

    /// Builds the diagnostics of the last window (and starts a new one).
    fn diagnostics(&mut self, elapsed_s: f64) -> DiagnosticArray {
        let stats = &self.stats;
        let mut bridge = DiagnosticStatus {
            level: DiagnosticStatus::OK,
            name: "arthrosim/viz-bridge".into(),
            message: "publishing".into(),
            hardware_id: "arthrosim".into(),
            values: Vec::new(),
        };
        let mut dropped_now = 0;
        for &stream in Topic::STREAMED {
            let i = stream as usize;
            let c = stats.stream(stream);
            let published = BridgeStats::get(&c.published);
            let dropped_queue = BridgeStats::get(&c.dropped_queue);
            let dropped_dds = BridgeStats::get(&c.dropped_dds);
            let rate = (published - self.last_published[i]) as f64 / elapsed_s;
            dropped_now += dropped_queue + dropped_dds - self.last_dropped[i];
            self.last_published[i] = published;
            self.last_dropped[i] = dropped_queue + dropped_dds;
            let (p50, p99) = self.latency_ns[i].take_p50_p99_us();
            let t = stream.relative().trim_start_matches('/');
            bridge.values.extend([
                KeyValue::new(&format!("{t} rate_hz"), format!("{rate:.1}")),
                KeyValue::new(&format!("{t} published"), published),
                KeyValue::new(&format!("{t} dropped_queue"), dropped_queue),
                KeyValue::new(&format!("{t} dropped_dds"), dropped_dds),
                KeyValue::new(&format!("{t} latency_p50_us"), format!("{p50:.1}")),
                KeyValue::new(&format!("{t} latency_p99_us"), format!("{p99:.1}")),
            ]);
        }
        if dropped_now > 0 {
            bridge.level = DiagnosticStatus::WARN;
            bridge.message =
                format!("DDS stalled: {dropped_now} messages dropped in the last window");
        }

        let inputs = [
            BridgeStats::get(&stats.contact_frames),
            BridgeStats::get(&stats.device_states),
            BridgeStats::get(&stats.surfaces),
        ];
        let rates: Vec<f64> = inputs
            .iter()
            .zip(self.last_inputs.iter())
            .map(|(now, before)| (now - before) as f64 / elapsed_s)
            .collect();
        self.last_inputs = inputs;
        let (ipc_p50, ipc_p99) = match stats.ipc_latency_ns.lock() {
            Ok(mut w) => w.take_p50_p99_us(),
            Err(_) => (0.0, 0.0),
        };
        let mut inputs_status = DiagnosticStatus {
            level: DiagnosticStatus::OK,
            name: "arthrosim/viz-bridge/inputs".into(),
            message: "receiving".into(),
            hardware_id: "arthrosim".into(),
            values: vec![
                KeyValue::new("contact_frame rate_hz", format!("{:.1}", rates[0])),
                KeyValue::new("device_state rate_hz", format!("{:.1}", rates[1])),
                KeyValue::new("surface rate_hz", format!("{:.1}", rates[2])),
                KeyValue::new("ipc latency_p50_us", format!("{ipc_p50:.1}")),
                KeyValue::new("ipc latency_p99_us", format!("{ipc_p99:.1}")),
                KeyValue::new(
                    "physics step_ms",
                    format!(
                        "{:.3}",
                        BridgeStats::get(&stats.physics_step_ns) as f64 / 1e6
                    ),
                ),
                KeyValue::new(
                    "targets_forwarded",
                    BridgeStats::get(&stats.targets_forwarded),
                ),
                KeyValue::new(
                    "grades_forwarded",
                    BridgeStats::get(&stats.grades_forwarded),
                ),
                KeyValue::new(
                    "inbound_rejected",
                    BridgeStats::get(&stats.inbound_rejected),
                ),
                KeyValue::new(
                    "skipped_triangles",
                    BridgeStats::get(&stats.skipped_triangles),
                ),
                KeyValue::new("ipc_errors", BridgeStats::get(&stats.ipc_errors)),
            ],
        };
        inputs_status.values.push(KeyValue::new(
            "accept_target_pose",
            self.config.accept_target_pose,
        ));
        let mut refused_total = 0;
        for why in Refusal::ALL {
            let n = BridgeStats::get(&stats.targets_refused[why as usize]);
            refused_total += n;
            inputs_status
                .values
                .push(KeyValue::new(&format!("targets_refused_{}", why.name()), n));
        }
        inputs_status
            .values
            .push(KeyValue::new("targets_refused", refused_total));
        if refused_total > 0 {
            inputs_status.level = DiagnosticStatus::WARN;
            inputs_status.message = format!("{refused_total} probe targets refused so far");
        }
        if rates[0] == 0.0 && rates[1] == 0.0 {
            inputs_status.level = DiagnosticStatus::STALE;
            inputs_status.message = "no physics or haptic samples in the last window".into();
        }

        let haptic = stats.haptic.lock().ok().and_then(|h| *h);
        let haptic_status = match haptic {
            Some(h) => {
                let mut status = DiagnosticStatus::default();
                self.mapping.haptic_status_into(&mut status, &h);
                status
            }
            None => DiagnosticStatus {
                level: DiagnosticStatus::STALE,
                name: ros_mapping::HAPTIC_STATUS_NAME.into(),
                message: "no haptic statistics received".into(),
                hardware_id: String::new(),
                values: Vec::new(),
            },
        };
        DiagnosticArray {
            header: self
                .mapping
                .diagnostics_header(self.clock.stamp(msgs::clock::monotonic_ns())),
            status: vec![bridge, inputs_status, haptic_status],
        }
    }
}

fn put<M: Serialize>(publisher: &Option<Publisher<M>>, msg: M) -> bool {
    match publisher {
        Some(p) => p.publish(msg).is_ok(),
        None => true,
    }
}

fn forward(inbound: &SyncSender<Inbound>, stats: &BridgeStats, cmd: Inbound) {
    match inbound.try_send(cmd) {
        Ok(()) => {}
        Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
            BridgeStats::add(&stats.inbound_rejected, 1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_names_follow_the_namespace() {
        let n = topic_name("/arthrosim", "probe/pose").unwrap();
        assert_eq!(format!("{n}"), "/arthrosim/probe/pose");
        assert_eq!(
            format!("{}", topic_name("/arthrosim", "/tf").unwrap()),
            "/tf"
        );
        assert_eq!(
            format!("{}", topic_name("/", "contacts").unwrap()),
            "/contacts"
        );
        assert!(topic_name("/arthrosim", "probe//pose").is_err());
    }

    #[test]
    fn stream_qos_maps_reliability_and_durability() {
        let streams = launch_config::bridge::BridgeStreams::default();
        let mesh = qos(&streams.mesh);
        assert_eq!(mesh.durability, Durability::TransientLocal);
        assert_eq!(mesh.history, History::KeepLast { depth: 1 });
        let mut pose = streams.probe_pose.clone();
        pose.reliability = cfg::Reliability::BestEffort;
        assert_eq!(
            qos(&pose).reliability,
            ros2_client::qos::Reliability::BestEffort
        );
    }
}
