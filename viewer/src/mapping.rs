//! The one place where session samples become viewer output: the Foxglove channels (ROS 2
//! messages, CDR-encoded, with the bridge's topic names, frames and conversions: the one
//! ROS 2 mapping, `msgs::ros_mapping`) and the trainee page's JSON events.

use std::sync::Arc;

use base64::Engine as _;
use msgs::haptic_to_monitor::HapticStats;
use msgs::haptic_to_physics::{fault, DeviceState};
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::ros::{
    self, DiagnosticArray, DiagnosticStatus, Header, JointState, KeyValue, Marker, MarkerArray,
    PoseStamped, RosMessage, TFMessage, WrenchStamped,
};
use msgs::ros_mapping::{full_topic_name, Mapping, StampClock, Topic};
use msgs::training::TrainingPrompt;
use msgs::{MAX_SURFACE_TRIANGLES, MAX_SURFACE_VERTICES};
use serde::Serialize;

/// Foxglove channels, in the order of [`Channel::ALL`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channel {
    ProbePose = 0,
    ProbeWrench,
    DeviceWrench,
    JointStates,
    Mesh,
    Contacts,
    Tf,
    Diagnostics,
}

pub const CHANNELS: usize = 8;

impl Channel {
    pub const ALL: [Channel; CHANNELS] = [
        Channel::ProbePose,
        Channel::ProbeWrench,
        Channel::DeviceWrench,
        Channel::JointStates,
        Channel::Mesh,
        Channel::Contacts,
        Channel::Tf,
        Channel::Diagnostics,
    ];

    /// The session topic this channel carries (the bridge's and the recorder's name).
    fn ros_topic(self) -> Topic {
        match self {
            Channel::ProbePose => Topic::ProbePose,
            Channel::ProbeWrench => Topic::ProbeWrench,
            Channel::DeviceWrench => Topic::DeviceWrench,
            Channel::JointStates => Topic::JointStates,
            Channel::Mesh => Topic::Mesh,
            Channel::Contacts => Topic::Contacts,
            Channel::Tf => Topic::Tf,
            Channel::Diagnostics => Topic::Diagnostics,
        }
    }

    /// Full topic name under `namespace` (the `[bridge] namespace`, default `/arthrosim`).
    pub fn topic(self, namespace: &str) -> String {
        full_topic_name(namespace, self.ros_topic().relative())
    }

    /// ROS 2 type name (`pkg/msg/Type`) and `ros2msg` schema text.
    pub fn schema(self) -> (String, String) {
        fn of<T: RosMessage>() -> (String, String) {
            (ros::type_name::<T>(), ros::schema_text::<T>())
        }
        match self {
            Channel::ProbePose => of::<PoseStamped>(),
            Channel::ProbeWrench | Channel::DeviceWrench => of::<WrenchStamped>(),
            Channel::JointStates => of::<JointState>(),
            Channel::Mesh => of::<Marker>(),
            Channel::Contacts => of::<MarkerArray>(),
            Channel::Tf => of::<TFMessage>(),
            Channel::Diagnostics => of::<DiagnosticArray>(),
        }
    }
}

/// One ROS 2 message for a Foxglove channel.
#[derive(Debug, Clone)]
pub enum RosOut {
    ProbePose(PoseStamped),
    ProbeWrench(WrenchStamped),
    DeviceWrench(WrenchStamped),
    JointStates(JointState),
    Mesh(Box<Marker>),
    Contacts(MarkerArray),
    Tf(TFMessage),
    Diagnostics(DiagnosticArray),
}

impl RosOut {
    pub fn channel(&self) -> Channel {
        match self {
            RosOut::ProbePose(_) => Channel::ProbePose,
            RosOut::ProbeWrench(_) => Channel::ProbeWrench,
            RosOut::DeviceWrench(_) => Channel::DeviceWrench,
            RosOut::JointStates(_) => Channel::JointStates,
            RosOut::Mesh(_) => Channel::Mesh,
            RosOut::Contacts(_) => Channel::Contacts,
            RosOut::Tf(_) => Channel::Tf,
            RosOut::Diagnostics(_) => Channel::Diagnostics,
        }
    }

    /// CDR payload with its encapsulation header, into `out` (capacity reused).
    pub fn encode(&self, out: &mut Vec<u8>) -> Result<(), ros::CdrError> {
        match self {
            RosOut::ProbePose(m) => ros::to_cdr(m, out),
            RosOut::ProbeWrench(m) | RosOut::DeviceWrench(m) => ros::to_cdr(m, out),
            RosOut::JointStates(m) => ros::to_cdr(m, out),
            RosOut::Mesh(m) => ros::to_cdr(&**m, out),
            RosOut::Contacts(m) => ros::to_cdr(m, out),
            RosOut::Tf(m) => ros::to_cdr(m, out),
            RosOut::Diagnostics(m) => ros::to_cdr(m, out),
        }
    }
}

/// Messages of one physics step (probe pose, contact wrench, contact markers, tf).
pub fn contact_messages(
    frame: &ContactFrame,
    mapping: &Mapping,
    clock: &StampClock,
    out: &mut Vec<RosOut>,
) {
    let stamp = clock.stamp(frame.publish_ns);
    let mut pose = PoseStamped::default();
    mapping.probe_pose_into(&mut pose, frame, stamp);
    out.push(RosOut::ProbePose(pose));
    let mut wrench = WrenchStamped::default();
    mapping.probe_wrench_into(&mut wrench, frame, stamp);
    out.push(RosOut::ProbeWrench(wrench));
    let mut markers = MarkerArray::default();
    mapping.contact_markers_into(&mut markers, frame, stamp);
    out.push(RosOut::Contacts(markers));
    let mut tf = TFMessage::default();
    mapping.transforms_into(&mut tf, frame, stamp);
    out.push(RosOut::Tf(tf));
}

/// Messages of one haptic tick (rendered force, joint states).
pub fn device_messages(
    state: &DeviceState,
    mapping: &Mapping,
    clock: &StampClock,
    out: &mut Vec<RosOut>,
) {
    let stamp = clock.stamp(state.publish_ns);
    let mut wrench = WrenchStamped::default();
    mapping.device_wrench_into(&mut wrench, state, stamp);
    out.push(RosOut::DeviceWrench(wrench));
    let mut joints = JointState::default();
    mapping.joint_states_into(&mut joints, state, stamp);
    out.push(RosOut::JointStates(joints));
}

/// The deformed surface as the bridge's TRIANGLE_LIST marker.
pub fn mesh_message(surface: &SurfaceFrame, mapping: &Mapping, clock: &StampClock) -> RosOut {
    let mut marker = Box::<Marker>::default();
    mapping.mesh_marker_into(&mut marker, surface, clock.stamp(surface.publish_ns));
    RosOut::Mesh(marker)
}

/// Session status as the viewer sees it: what `/diagnostics` and the page's status panel show.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Status {
    /// Region of the current probing (`posterior`, `mid`, `anterior`, or `none`).
    pub region: &'static str,
    /// Current probing index (0: not probing).
    pub probing: u32,
    /// Physics steps per second (from the frames' sequence numbers).
    pub physics_hz: f64,
    /// Haptic loop rate reported by the haptic node.
    pub haptic_hz: f64,
    /// Names of the fault bits of the newest device state.
    pub faults: Vec<&'static str>,
    /// Active contacts in the newest physics step.
    pub contacts: u32,
    /// Samples the viewer dropped because its outputs were behind (never waited for).
    pub dropped: u64,
    /// Shared-memory latency of the newest samples (publish → viewer), ms.
    pub ipc_latency_ms: f64,
}

pub const REGIONS: [&str; 4] = ["none", "posterior", "mid", "anterior"];

pub fn region_name(code: u32) -> &'static str {
    REGIONS.get(code as usize).copied().unwrap_or("none")
}

pub fn fault_names(bits: u32) -> Vec<&'static str> {
    const NAMES: [(u32, &str); 7] = [
        (fault::STALE_FRAME, "stale_frame"),
        (fault::NONFINITE_DEVICE, "nonfinite_device"),
        (fault::INVALID_FRAME, "invalid_frame"),
        (fault::NONFINITE_FORCE, "nonfinite_force"),
        (fault::FORCE_CLAMPED, "force_clamped"),
        (fault::RATE_LIMITED, "rate_limited"),
        (fault::DEVICE_ERROR, "device_error"),
    ];
    NAMES
        .iter()
        .filter(|(bit, _)| bits & bit != 0)
        .map(|(_, n)| *n)
        .collect()
}

/// `/diagnostics` for the viewer: the session status and the viewer's own counters.
pub fn diagnostics(status: &Status, haptic: Option<&HapticStats>, stamp: ros::Time) -> RosOut {
    let level = if status.faults.iter().any(|f| *f != "force_clamped") {
        DiagnosticStatus::WARN
    } else {
        DiagnosticStatus::OK
    };
    let mut values = vec![
        KeyValue::new("region", status.region),
        KeyValue::new("probing", status.probing),
        KeyValue::new("physics rate_hz", format!("{:.1}", status.physics_hz)),
        KeyValue::new("haptic rate_hz", format!("{:.1}", status.haptic_hz)),
        KeyValue::new("contacts", status.contacts),
        KeyValue::new("faults", status.faults.join(",")),
        KeyValue::new("viewer dropped", status.dropped),
        KeyValue::new(
            "viewer ipc_latency_ms",
            format!("{:.3}", status.ipc_latency_ms),
        ),
    ];
    if let Some(h) = haptic {
        values.push(KeyValue::new(
            "haptic period_err_p99_us",
            format!("{:.1}", h.period_err_p99_us),
        ));
        values.push(KeyValue::new(
            "haptic rendered_force_n",
            format!("{:.3}", h.rendered_force_norm_n),
        ));
    }
    RosOut::Diagnostics(DiagnosticArray {
        header: Header::new(stamp, ""),
        status: vec![DiagnosticStatus {
            level,
            name: "arthrosim/session".into(),
            message: if status.faults.is_empty() {
                "running".into()
            } else {
                format!("faults: {}", status.faults.join(", "))
            },
            hardware_id: "arthrosim".into(),
            values,
        }],
    })
}

// ---------------------------------------------------------------------------------------
// The trainee page's events (server-sent events, JSON).

/// `state` event: probe, force and status of the newest physics step.
#[derive(Debug, Clone, Serialize)]
pub struct PageState<'a> {
    /// Unix time of the sample's publication, ms (the page measures its latency from it).
    pub stamp_ms: f64,
    pub sim_time_s: f64,
    pub probe_position: [f64; 3],
    pub probe_orientation: [f64; 4],
    /// Eq. (1) contact force on the probe, world frame, N.
    pub force: [f64; 3],
    /// Its magnitude, N.
    pub force_n: f64,
    /// Force rendered on the device, N.
    pub rendered_n: f64,
    pub status: &'a Status,
}

pub fn page_state(
    frame: &ContactFrame,
    rendered: Option<&DeviceState>,
    status: &Status,
    clock: &StampClock,
) -> String {
    let f = frame.contact_force;
    let rendered_n = rendered
        .map(|s| {
            let r = s.rendered_force;
            (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt()
        })
        .unwrap_or(0.0);
    let state = PageState {
        stamp_ms: clock.epoch_ns(frame.publish_ns) as f64 / 1e6,
        sim_time_s: frame.sim_time_s,
        probe_position: frame.probe_pose.position,
        probe_orientation: frame.probe_pose.orientation,
        force: f,
        force_n: (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt(),
        rendered_n,
        status,
    };
    serde_json::to_string(&state).unwrap_or_default()
}

/// Triangle indices of a surface: they change only when the mesh is rebuilt, so the page
/// gets them once (and again on a change), the positions every mesh frame.
pub fn topology_key(surface: &SurfaceFrame) -> (u64, u32, u32) {
    (
        surface.instance_id,
        surface.vertex_count,
        surface.triangle_count,
    )
}

/// `topology` event: vertex count and the triangle indices (base64 of little-endian u32),
/// triangles with an index past the vertex count left out (as the bridge does).
pub fn page_topology(surface: &SurfaceFrame) -> String {
    let vertices = (surface.vertex_count as usize).min(MAX_SURFACE_VERTICES);
    let triangles = (surface.triangle_count as usize).min(MAX_SURFACE_TRIANGLES);
    let mut bytes = Vec::with_capacity(triangles * 12);
    let mut kept = 0usize;
    for tri in &surface.triangles[..triangles] {
        if tri.iter().any(|&i| i as usize >= vertices) {
            continue;
        }
        kept += 1;
        for i in tri {
            bytes.extend_from_slice(&i.to_le_bytes());
        }
    }
    serde_json::json!({
        "vertices": vertices,
        "triangles": kept,
        "indices": base64::engine::general_purpose::STANDARD.encode(&bytes),
    })
    .to_string()
}

/// `mesh` event: the deformed vertex positions (base64 of little-endian f32 xyz).
pub fn page_mesh(surface: &SurfaceFrame, clock: &StampClock) -> String {
    let vertices = (surface.vertex_count as usize).min(MAX_SURFACE_VERTICES);
    let mut bytes = Vec::with_capacity(vertices * 12);
    for p in &surface.positions[..vertices] {
        for c in p {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    serde_json::json!({
        "stamp_ms": clock.epoch_ns(surface.publish_ns) as f64 / 1e6,
        "sequence": surface.sequence,
        "vertices": vertices,
        "positions": base64::engine::general_purpose::STANDARD.encode(&bytes),
    })
    .to_string()
}

/// `training` event: the driver's prompt (never the hidden grade).
pub fn page_prompt(prompt: &TrainingPrompt) -> String {
    let state = match prompt.state {
        msgs::training::state::PROBING => "probing",
        msgs::training::state::ANSWERED => "answered",
        msgs::training::state::FINISHED => "finished",
        _ => "idle",
    };
    serde_json::json!({
        "state": state,
        "case": prompt.case_index,
        "cases": prompt.case_count,
        "grades": prompt.grade_count,
        "probings": prompt.probings,
        "answered": prompt.answered,
        "correct": if prompt.state == msgs::training::state::FINISHED {
            Some(prompt.correct)
        } else {
            None
        },
    })
    .to_string()
}

/// A page event: SSE event name and JSON data.
#[derive(Debug, Clone)]
pub struct PageEvent {
    pub name: &'static str,
    pub data: Arc<str>,
}

impl PageEvent {
    pub fn new(name: &'static str, data: String) -> PageEvent {
        PageEvent {
            name,
            data: data.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_and_types_are_the_bridges() {
        assert_eq!(
            Channel::ProbeWrench.topic("/arthrosim"),
            "/arthrosim/probe/wrench"
        );
        assert_eq!(Channel::Tf.topic("/arthrosim"), "/tf");
        assert_eq!(Channel::Mesh.topic("/"), "/meniscus/mesh");
        let (name, text) = Channel::ProbeWrench.schema();
        assert_eq!(name, "geometry_msgs/msg/WrenchStamped");
        assert!(text.contains("geometry_msgs/Wrench wrench"), "{text}");
    }

    #[test]
    fn cdr_payload_round_trips_with_values() {
        let mut slot = Box::new(core::mem::MaybeUninit::<ContactFrame>::uninit());
        let frame = <ContactFrame as msgs::Topic>::zeroed_in(&mut slot);
        frame.dt_s = 0.01;
        frame.probe_pose = msgs::Pose::IDENTITY;
        frame.probe_pose.position = [0.01, -0.02, 0.03];
        frame.contact_force = [0.5, -1.0, -3.5];
        let mapping = launch_config::BridgeConfig::default().ros_mapping();
        let mut out = Vec::new();
        contact_messages(frame, &mapping, &StampClock::measure(), &mut out);
        let mut buf = Vec::new();
        out[1].encode(&mut buf).unwrap();
        let back: WrenchStamped = ros::from_cdr(&buf).unwrap();
        assert_eq!(back.wrench.force.z, -3.5);
        assert_eq!(back.header.frame_id, mapping.world_frame);
    }

    #[test]
    fn topology_skips_out_of_range_triangles() {
        let mut slot = Box::new(core::mem::MaybeUninit::<SurfaceFrame>::uninit());
        let s = <SurfaceFrame as msgs::Topic>::zeroed_in(&mut slot);
        s.vertex_count = 3;
        s.triangle_count = 2;
        s.triangles[0] = [0, 1, 2];
        s.triangles[1] = [0, 1, 7];
        let v: serde_json::Value = serde_json::from_str(&page_topology(s)).unwrap();
        assert_eq!(v["triangles"], 1);
        assert_eq!(v["vertices"], 3);
    }
}
