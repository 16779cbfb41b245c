//! The shared-memory side of the bridge (the thread that owns the iceoryx2 ports): reads the
//! physics and haptic streams, turns them into ROS 2 messages and hands them to the DDS thread
//! through a bounded queue; forwards commands from ROS to physics.
//!
//! Lifecycle: `new` (checks the configuration) → `start` (opens ports, starts DDS) → `step`
//! (non-blocking, call in a loop) → `stop`.

use std::mem::MaybeUninit;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::Duration;

use launch_config::bridge::{BridgeConfig, BridgeConfigError};
use msgs::bridge_to_physics::{MaterialCommand, ProbeTarget};
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::DeviceState;
use msgs::ipc::{self, IpcNode, IpcPublisher, IpcSubscriber, LinkError, Queue};
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::Topic;

use msgs::ros::{JointState, Joy, Marker, MarkerArray, PoseStamped, TFMessage, WrenchStamped};
use msgs::ros_mapping::{ClockOffsetError, Mapping, StampClock};

use crate::dds::{self, DdsError, DdsThread, Envelope, Inbound, Outbound};
use crate::stats::BridgeStats;
// `msgs::Topic` is the shared-memory service trait; this is the ROS 2 session topic.
use crate::target_gate::TargetGate;
use msgs::ros_mapping::Topic as SessionTopic;

#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    #[error(transparent)]
    Config(#[from] BridgeConfigError),
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error(transparent)]
    Dds(#[from] DdsError),
    #[error(transparent)]
    Clock(#[from] ClockOffsetError),
    #[error("the DDS thread exited unexpectedly")]
    DdsExited,
    #[error("bridge not started")]
    NotStarted,
}

/// Ports and state that exist between `start` and `stop` (not `Send`: iceoryx2 ports).
struct Running {
    _node: IpcNode,
    contact_frames: IpcSubscriber<ContactFrame>,
    device_states: IpcSubscriber<DeviceState>,
    surfaces: IpcSubscriber<SurfaceFrame>,
    haptic_stats: IpcSubscriber<HapticStats>,
    probe_targets: IpcPublisher<ProbeTarget>,
    material: IpcPublisher<MaterialCommand>,
    outbound: SyncSender<Envelope>,
    inbound: Receiver<Inbound>,
    dds: Option<DdsThread>,
    surface: Box<MaybeUninit<SurfaceFrame>>,
    haptic: Box<MaybeUninit<HapticStats>>,
    /// Source time (monotonic ns) of the last publication per stream, for rate limits.
    last_emit: [Option<u64>; SessionTopic::COUNT],
    last_buttons: Option<u32>,
    target_sequence: u64,
    material_sequence: u64,
    targets: TargetGate,
}

pub struct Bridge {
    config: BridgeConfig,
    session: String,
    stats: Arc<BridgeStats>,
    clock: StampClock,
    /// The one session → ROS 2 mapping (shared with the recorder).
    mapping: Mapping,
    running: Option<Running>,
}

/// What one outbound stream needs to decide whether a sample is published.
struct Gate<'a> {
    config: &'a BridgeConfig,
    last_emit: &'a mut [Option<u64>; SessionTopic::COUNT],
}

impl Gate<'_> {
    fn open(&mut self, topic: SessionTopic, source_ns: u64) -> bool {
        let cfg = self.config.streams.of(topic);
        if !cfg.enabled {
            return false;
        }
        let last = &mut self.last_emit[topic as usize];
        let due = match *last {
            None => true,
            Some(t) => source_ns.saturating_sub(t) >= cfg.min_interval_ns() || source_ns < t,
        };
        if due {
            *last = Some(source_ns);
        }
        due
    }
}

fn enqueue(tx: &SyncSender<Envelope>, stats: &BridgeStats, source_ns: u64, msg: Outbound) {
    let counters = stats.stream(msg.topic());
    match tx.try_send(Envelope { source_ns, msg }) {
        Ok(()) => BridgeStats::add(&counters.enqueued, 1),
        // DDS side behind: drop, count, report in diagnostics; never wait.
        Err(TrySendError::Full(_)) => BridgeStats::add(&counters.dropped_queue, 1),
        Err(TrySendError::Disconnected(_)) => BridgeStats::add(&counters.dropped_dds, 1),
    }
}

impl Bridge {
    pub fn new(config: BridgeConfig, session: &str) -> Result<Bridge, BridgeError> {
        config.validate()?;
        let session = ipc::session_name(Some(session))?;
        Ok(Bridge {
            mapping: config.ros_mapping(),
            config,
            session,
            stats: Arc::new(BridgeStats::default()),
            clock: StampClock::for_session()?,
            running: None,
        })
    }

    pub fn stats(&self) -> Arc<BridgeStats> {
        self.stats.clone()
    }

    pub fn config(&self) -> &BridgeConfig {
        &self.config
    }

    /// Opens the shared-memory ports on the calling thread and starts the DDS thread.
    pub fn start(&mut self) -> Result<(), BridgeError> {
        let node = ipc::create_node("viz-bridge")?;
        let s = &self.session;
        let contact_frames = ipc::subscriber::<ContactFrame>(&node, s, Queue::Every)?;
        let device_states = ipc::subscriber::<DeviceState>(&node, s, Queue::Every)?;
        let surfaces = ipc::subscriber::<SurfaceFrame>(&node, s, Queue::Newest)?;
        let haptic_stats = ipc::subscriber::<HapticStats>(&node, s, Queue::Newest)?;
        let probe_targets = ipc::publisher::<ProbeTarget>(&node, s)?;
        let material = ipc::publisher::<MaterialCommand>(&node, s)?;
        let (outbound, outbound_rx) = sync_channel(self.config.queue_depth);
        let (inbound_tx, inbound) = sync_channel(64);
        let dds = dds::spawn(
            self.config.clone(),
            self.stats.clone(),
            self.clock,
            self.mapping.clone(),
            outbound_rx,
            inbound_tx,
        )?;
        let mut surface = Box::new(MaybeUninit::<SurfaceFrame>::uninit());
        SurfaceFrame::zeroed_in(&mut surface);
        let mut haptic = Box::new(MaybeUninit::<HapticStats>::uninit());
        HapticStats::zeroed_in(&mut haptic);
        self.running = Some(Running {
            _node: node,
            contact_frames,
            device_states,
            surfaces,
            haptic_stats,
            probe_targets,
            material,
            outbound,
            inbound,
            dds: Some(dds),
            surface,
            haptic,
            last_emit: [None; SessionTopic::COUNT],
            last_buttons: None,
            target_sequence: 0,
            material_sequence: 0,
            targets: TargetGate::new(self.config.accept_target_pose, &self.config.target_pose),
        });
        Ok(())
    }

    /// Handles everything queued on both sides; never blocks. Returns how many samples and
    /// commands were handled (0: idle).
    pub fn step(&mut self) -> Result<usize, BridgeError> {
        let run = self.running.as_mut().ok_or(BridgeError::NotStarted)?;
        if run.dds.as_ref().is_some_and(|d| d.handle.is_finished()) {
            return Err(BridgeError::DdsExited);
        }
        let stats = &*self.stats;
        let clock = &self.clock;
        let map = &self.mapping;
        let tx = &run.outbound;
        let mut gate = Gate {
            config: &self.config,
            last_emit: &mut run.last_emit,
        };
        let mut handled = 0;

        let now = msgs::clock::monotonic_ns();
        let targets = &mut run.targets;
        let frames = ipc::drain_each(&run.contact_frames, |frame| {
            stats.record_ipc_latency(now.saturating_sub(frame.publish_ns));
            targets.set_probe_position(frame.probe_pose.position);
            stats
                .physics_step_ns
                .store(frame.step_duration_ns, Ordering::Relaxed);
            let src = frame.publish_ns;
            let stamp = clock.stamp(src);
            if gate.open(SessionTopic::ProbePose, src) {
                let mut m = PoseStamped::default();
                map.probe_pose_into(&mut m, frame, stamp);
                enqueue(tx, stats, src, Outbound::ProbePose(m));
            }
            if gate.open(SessionTopic::ProbeWrench, src) {
                let mut m = WrenchStamped::default();
                map.probe_wrench_into(&mut m, frame, stamp);
                enqueue(tx, stats, src, Outbound::ProbeWrench(m));
            }
            if gate.open(SessionTopic::Contacts, src) {
                let mut m = MarkerArray::default();
                map.contact_markers_into(&mut m, frame, stamp);
                enqueue(tx, stats, src, Outbound::Contacts(m));
            }
            if gate.open(SessionTopic::Tf, src) {
                let mut m = TFMessage::default();
                map.transforms_into(&mut m, frame, stamp);
                enqueue(tx, stats, src, Outbound::Tf(m));
            }
        })?;
        BridgeStats::add(&stats.contact_frames, frames as u64);
        handled += frames;

        let last_buttons = &mut run.last_buttons;
        let states = ipc::drain_each(&run.device_states, |state| {
            stats.record_ipc_latency(now.saturating_sub(state.publish_ns));
            let src = state.publish_ns;
            let stamp = clock.stamp(src);
            if gate.open(SessionTopic::DeviceWrench, src) {
                let mut m = WrenchStamped::default();
                map.device_wrench_into(&mut m, state, stamp);
                enqueue(tx, stats, src, Outbound::DeviceWrench(m));
            }
            if gate.open(SessionTopic::JointStates, src) {
                let mut m = JointState::default();
                map.joint_states_into(&mut m, state, stamp);
                enqueue(tx, stats, src, Outbound::JointStates(m));
            }
            // Buttons: at their rate, and always at once when they change.
            let changed = *last_buttons != Some(state.buttons);
            let due = gate.open(SessionTopic::Buttons, src);
            if (due || changed) && self.config.streams.buttons.enabled {
                *last_buttons = Some(state.buttons);
                let mut m = Joy::default();
                map.buttons_into(&mut m, state, stamp);
                enqueue(tx, stats, src, Outbound::Buttons(m));
            }
        })?;
        BridgeStats::add(&stats.device_states, states as u64);
        handled += states;

        // SAFETY: zeroed in `start`, and only ever overwritten with whole samples.
        let surface = unsafe { run.surface.assume_init_mut() };
        let surfaces = ipc::take_newest(&run.surfaces, surface)?;
        if surfaces > 0 {
            BridgeStats::add(&stats.surfaces, surfaces as u64);
            handled += surfaces;
            if run.targets.needs_workspace() {
                let n = (surface.vertex_count as usize).min(surface.positions.len());
                run.targets.set_scene_points(
                    surface.positions[..n]
                        .iter()
                        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]),
                );
            }
            let src = surface.publish_ns;
            if gate.open(SessionTopic::Mesh, src) {
                let mut mesh = Box::<Marker>::default();
                let skipped = map.mesh_marker_into(&mut mesh, surface, clock.stamp(src));
                BridgeStats::add(&stats.skipped_triangles, skipped as u64);
                enqueue(tx, stats, src, Outbound::Mesh(mesh));
            }
        }

        // SAFETY: as above.
        let haptic = unsafe { run.haptic.assume_init_mut() };
        if ipc::take_newest(&run.haptic_stats, haptic)? > 0 {
            if let Ok(mut slot) = stats.haptic.lock() {
                *slot = Some(*haptic);
            }
            handled += 1;
        }

        while let Ok(cmd) = run.inbound.try_recv() {
            handled += 1;
            match cmd {
                Inbound::ProbeTarget(pose) => {
                    let now_s = msgs::clock::monotonic_ns() as f64 * 1e-9;
                    let pose = match run.targets.check(&pose, now_s) {
                        Ok(pose) => pose,
                        Err(why) => {
                            BridgeStats::add(&stats.targets_refused[why as usize], 1);
                            if run.targets.refused(why) == 1 {
                                tracing::warn!(
                                    reason = why.name(),
                                    "probe target refused (counted on /diagnostics; logged once per reason)"
                                );
                            }
                            continue;
                        }
                    };
                    run.target_sequence += 1;
                    let target = ProbeTarget {
                        sequence: run.target_sequence,
                        publish_ns: msgs::clock::monotonic_ns(),
                        pose,
                    };
                    ipc::send_copy(&run.probe_targets, &target)?;
                    BridgeStats::add(&stats.targets_forwarded, 1);
                }
                Inbound::DegenerationGrade(grade) => {
                    run.material_sequence += 1;
                    let cmd = MaterialCommand {
                        sequence: run.material_sequence,
                        publish_ns: msgs::clock::monotonic_ns(),
                        degeneration_grade: grade,
                    };
                    ipc::send_copy(&run.material, &cmd)?;
                    BridgeStats::add(&stats.grades_forwarded, 1);
                }
            }
        }
        Ok(handled)
    }

    /// Steps until `stop` is raised; sleeps briefly only when there was nothing to do.
    pub fn run(&mut self, stop: &AtomicBool) -> Result<(), BridgeError> {
        if self.running.is_none() {
            self.start()?;
        }
        while !stop.load(Ordering::Relaxed) {
            match self.step() {
                Ok(0) => std::thread::sleep(Duration::from_micros(250)),
                Ok(_) => {}
                Err(BridgeError::Link(e)) => {
                    // A receive error on one port (e.g. a publisher that died mid-sample)
                    // must not end the session: count, report, go on.
                    BridgeStats::add(&self.stats.ipc_errors, 1);
                    tracing::warn!("shared-memory link: {e}");
                    std::thread::sleep(Duration::from_millis(1));
                }
                Err(e) => return Err(e),
            }
        }
        self.stop();
        Ok(())
    }

    /// Closes the queue (the DDS thread then drops its node and exits) and the ports.
    pub fn stop(&mut self) {
        if let Some(mut run) = self.running.take() {
            let dds = run.dds.take();
            drop(run);
            if let Some(dds) = dds {
                let _ = dds.handle.join();
            }
        }
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.stop();
    }
}
