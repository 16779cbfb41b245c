//! The one mapping from session data to ROS 2: what the viz-bridge publishes live and what the
//! recorder writes into the session MCAP are built by the same functions here, so a recording
//! played back in RViz2 or Foxglove shows exactly what the live bridge showed.
//!
//! Input: the shared-memory samples ([`ContactFrame`] from physics, [`DeviceState`] and
//! [`HapticStats`] from the haptic node, [`SurfaceFrame`] from physics). Output: the messages
//! of [`crate::ros`] with their topic names, frame ids, joint names, tf edges and diagnostics
//! keys. Nothing here depends on DDS, so the recorder links it without ros2-client.
//!
//! Frames (REP-103, z up); `world` is configurable (`[bridge] world_frame`):
//!
//! ```text
//! world ─┬─ meniscus    fixed ([bridge] meniscus_pose)
//!        ├─ probe       corrected probe pose of the physics step
//!        ├─ proxy       device proxy pose the physics step used
//!        └─ touch_base  fixed ([bridge] touch_base_pose); joint states and buttons
//! ```
//!
//! Every transform is on `/tf`, stamped with the physics step. Stamps come from one
//! [`StampClock`] per session: a sample's monotonic `publish_ns` moved onto the Unix epoch by
//! an offset fixed once for the session, so the bridge and the recorder stamp the same sample
//! identically.
//!
//! Every `fill_*`/`*_into` function overwrites the whole message it is given and reuses its
//! strings and vectors, so a caller that keeps one message per topic does not allocate once
//! warmed up.

use crate::haptic_to_monitor::HapticStats;
use crate::haptic_to_physics::DeviceState;
use crate::physics_to_haptic::ContactFrame;
use crate::physics_to_viz::SurfaceFrame;
use crate::ros::*;
use crate::{MAX_CONTACTS, MAX_SURFACE_TRIANGLES, MAX_SURFACE_VERTICES, ROWS_PER_CONTACT};

/// Default namespace of the session topics (`/tf` and `/diagnostics` stay global).
pub const DEFAULT_NAMESPACE: &str = "/arthrosim";
/// Default fixed frame of every pose, wrench, marker and transform.
pub const DEFAULT_WORLD_FRAME: &str = "world";

/// Child frames on `/tf` (parent: the world frame).
pub const MENISCUS_FRAME: &str = "meniscus";
pub const PROBE_FRAME: &str = "probe";
pub const PROXY_FRAME: &str = "proxy";
pub const TOUCH_BASE_FRAME: &str = "touch_base";
/// The tf tree, in the order of every `/tf` message's transforms.
pub const TF_CHILDREN: [&str; 4] = [MENISCUS_FRAME, PROBE_FRAME, PROXY_FRAME, TOUCH_BASE_FRAME];

/// Joint names of the 3D Systems Touch (3 base joints, 3 gimbal joints), in
/// `DeviceState::joint_angles` order; prefixed so they cannot clash with another robot's
/// joints in a lab's `robot_state_publisher`.
pub const TOUCH_JOINTS: [&str; 6] = [
    "touch_waist",
    "touch_shoulder",
    "touch_elbow",
    "touch_yaw",
    "touch_pitch",
    "touch_roll",
];

/// Name of the haptic loop's status on `/diagnostics`.
pub const HAPTIC_STATUS_NAME: &str = "arthrosim/haptic";
/// Marker namespaces.
pub const MESH_MARKER_NS: &str = "meniscus";
pub const CONTACT_MARKER_NS: &str = "contacts";
/// Marker scale for contact forces: arrow length per newton of normal force, m/N.
pub const CONTACT_ARROW_M_PER_N: f64 = 0.01;
/// Shortest normal arrow (a contact with zero force still shows its normal), m.
pub const CONTACT_ARROW_MIN_M: f64 = 0.003;
/// Colour of the meniscus surface.
pub const MESH_COLOR: ColorRGBA = ColorRGBA {
    r: 0.93,
    g: 0.80,
    b: 0.74,
    a: 1.0,
};

/// Inbound topics (bridge only), relative to the namespace.
pub const TOPIC_TARGET_POSE: &str = "probe/target_pose";
pub const TOPIC_DEGENERATION_GRADE: &str = "material/degeneration_grade";

/// The outbound session topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Topic {
    ProbePose = 0,
    ProbeWrench,
    DeviceWrench,
    JointStates,
    Buttons,
    Mesh,
    Contacts,
    Tf,
    Diagnostics,
}

impl Topic {
    /// How many session topics there are (the length of [`Topic::ALL`]).
    pub const COUNT: usize = 9;

    pub const ALL: [Topic; Topic::COUNT] = [
        Topic::ProbePose,
        Topic::ProbeWrench,
        Topic::DeviceWrench,
        Topic::JointStates,
        Topic::Buttons,
        Topic::Mesh,
        Topic::Contacts,
        Topic::Tf,
        Topic::Diagnostics,
    ];

    /// The topics the bridge streams from shared memory, in [`Topic::ALL`] order: all but
    /// `/diagnostics` (last in `ALL`), which it writes itself from its counters.
    pub const STREAMED: &'static [Topic] = Topic::ALL.split_at(Topic::COUNT - 1).0;

    /// Name relative to the namespace; `/tf` and `/diagnostics` are absolute.
    pub fn relative(self) -> &'static str {
        match self {
            Topic::ProbePose => "probe/pose",
            Topic::ProbeWrench => "probe/wrench",
            Topic::DeviceWrench => "device/wrench",
            Topic::JointStates => "device/joint_states",
            Topic::Buttons => "device/buttons",
            Topic::Mesh => "meniscus/mesh",
            Topic::Contacts => "contacts",
            Topic::Tf => "/tf",
            Topic::Diagnostics => "/diagnostics",
        }
    }

    /// The ROS 2 message type.
    pub fn def(self) -> &'static MsgDef {
        match self {
            Topic::ProbePose => &POSE_STAMPED_DEF,
            Topic::ProbeWrench | Topic::DeviceWrench => &WRENCH_STAMPED_DEF,
            Topic::JointStates => &JOINT_STATE_DEF,
            Topic::Buttons => &JOY_DEF,
            Topic::Mesh => &MARKER_DEF,
            Topic::Contacts => &MARKER_ARRAY_DEF,
            Topic::Tf => &TF_MESSAGE_DEF,
            Topic::Diagnostics => &DIAGNOSTIC_ARRAY_DEF,
        }
    }
}

/// Full ROS name of a topic: absolute names stay, others go below `namespace` (`/` = none).
pub fn full_topic_name(namespace: &str, relative: &str) -> String {
    if relative.starts_with('/') {
        relative.to_string()
    } else if namespace == "/" {
        format!("/{relative}")
    } else {
        format!("{namespace}/{relative}")
    }
}

/// Environment variable carrying the session's CLOCK_REALTIME − CLOCK_MONOTONIC offset, ns.
/// The launcher fixes it once and passes it to every node, so every process turns the same
/// `publish_ns` into the same ROS stamp (a per-process measurement differs by the few tens of
/// nanoseconds between its two clock reads).
pub const CLOCK_OFFSET_ENV: &str = "ARTHROSIM_CLOCK_OFFSET_NS";

/// Failure to read [`CLOCK_OFFSET_ENV`].
#[derive(Debug, thiserror::Error)]
#[error("{CLOCK_OFFSET_ENV} = {0:?}: not an integer number of nanoseconds")]
pub struct ClockOffsetError(pub String);

/// Maps CLOCK_MONOTONIC stamps (what every arthrosim process publishes) onto ROS time (Unix
/// epoch) with one offset.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StampClock {
    offset_ns: i64,
}

impl StampClock {
    /// The session's clock: the offset from [`CLOCK_OFFSET_ENV`] when set, else measured now.
    pub fn for_session() -> Result<StampClock, ClockOffsetError> {
        match std::env::var(CLOCK_OFFSET_ENV) {
            Ok(text) => text
                .trim()
                .parse::<i64>()
                .map(StampClock::with_offset)
                .map_err(|_| ClockOffsetError(text)),
            Err(_) => Ok(StampClock::measure()),
        }
    }

    /// The offset measured now: the tightest of a few monotonic–realtime–monotonic brackets.
    pub fn measure() -> StampClock {
        let mut best: Option<(u64, i64)> = None;
        for _ in 0..16 {
            let a = crate::clock::monotonic_ns();
            let real = crate::clock::realtime_ns();
            let b = crate::clock::monotonic_ns();
            let width = b.saturating_sub(a);
            let offset = real as i64 - (a / 2 + b / 2) as i64;
            if best.is_none_or(|(w, _)| width < w) {
                best = Some((width, offset));
            }
        }
        StampClock::with_offset(best.map_or(0, |(_, o)| o))
    }

    pub fn with_offset(offset_ns: i64) -> StampClock {
        StampClock { offset_ns }
    }

    pub fn offset_ns(&self) -> i64 {
        self.offset_ns
    }

    /// Unix-epoch nanoseconds of a monotonic stamp. A sample without a publish time (0) is
    /// stamped with the current wall clock.
    pub fn epoch_ns(&self, monotonic_ns: u64) -> u64 {
        if monotonic_ns == 0 {
            return crate::clock::realtime_ns();
        }
        (monotonic_ns as i64).saturating_add(self.offset_ns).max(0) as u64
    }

    pub fn stamp(&self, monotonic_ns: u64) -> Time {
        Time::from_nanos(self.epoch_ns(monotonic_ns))
    }
}

/// The session-specific part of the mapping (from the launch file's `[bridge]` section).
#[derive(Debug, Clone, PartialEq)]
pub struct Mapping {
    /// Namespace of the session topics, absolute (`/arthrosim`).
    pub namespace: String,
    /// Fixed frame of every pose, wrench, marker and transform.
    pub world_frame: String,
    /// world → meniscus.
    pub meniscus_pose: crate::Pose,
    /// world → touch_base.
    pub touch_base_pose: crate::Pose,
}

impl Default for Mapping {
    fn default() -> Self {
        Mapping {
            namespace: DEFAULT_NAMESPACE.into(),
            world_frame: DEFAULT_WORLD_FRAME.into(),
            meniscus_pose: crate::Pose::IDENTITY,
            touch_base_pose: crate::Pose::IDENTITY,
        }
    }
}

fn set_str(s: &mut String, v: &str) {
    if s != v {
        s.clear();
        s.push_str(v);
    }
}

fn set_header(h: &mut Header, stamp: Time, frame: &str) {
    h.stamp = stamp;
    set_str(&mut h.frame_id, frame);
}

/// Resets a marker to its defaults, keeping the allocations of the fields the mapping uses.
fn reuse_marker(m: &mut Marker) {
    let mut header = std::mem::take(&mut m.header);
    let mut ns = std::mem::take(&mut m.ns);
    let mut points = std::mem::take(&mut m.points);
    header.frame_id.clear();
    ns.clear();
    points.clear();
    *m = Marker {
        header,
        ns,
        points,
        ..Default::default()
    };
}

impl Mapping {
    /// Full topic name of `topic` in this session.
    pub fn topic(&self, topic: Topic) -> String {
        full_topic_name(&self.namespace, topic.relative())
    }

    /// The tf edges `(parent, child)` of every `/tf` message, in order.
    pub fn tf_edges(&self) -> [(&str, &'static str); 4] {
        TF_CHILDREN.map(|c| (self.world_frame.as_str(), c))
    }

    /// `probe/pose`: the corrected probe pose of a physics step, world frame.
    pub fn probe_pose_into(&self, out: &mut PoseStamped, f: &ContactFrame, stamp: Time) {
        set_header(&mut out.header, stamp, &self.world_frame);
        out.pose = (&f.probe_pose).into();
    }

    /// `probe/wrench`: contact force on the probe, eq. (1) f = Hᵀλ/dt, and its torque about the
    /// probe position, world frame.
    pub fn probe_wrench_into(&self, out: &mut WrenchStamped, f: &ContactFrame, stamp: Time) {
        set_header(&mut out.header, stamp, &self.world_frame);
        out.wrench.force = f.contact_force.into();
        out.wrench.torque = f.contact_torque.into();
    }

    /// `device/wrench`: the force sent to the Touch after clamping, world frame.
    pub fn device_wrench_into(&self, out: &mut WrenchStamped, d: &DeviceState, stamp: Time) {
        set_header(&mut out.header, stamp, &self.world_frame);
        out.wrench.force = d.rendered_force.into();
        out.wrench.torque = Vector3::default();
    }

    /// `device/joint_states`: the Touch's six joint angles, rad, in the `touch_base` frame.
    pub fn joint_states_into(&self, out: &mut JointState, d: &DeviceState, stamp: Time) {
        set_header(&mut out.header, stamp, TOUCH_BASE_FRAME);
        if out.name.len() != TOUCH_JOINTS.len()
            || out.name.iter().zip(TOUCH_JOINTS).any(|(a, b)| a != b)
        {
            out.name = TOUCH_JOINTS.iter().map(|s| s.to_string()).collect();
        }
        out.position.clear();
        out.position.extend_from_slice(&d.joint_angles);
        out.velocity.clear();
        out.effort.clear();
    }

    /// `device/buttons`: the Touch's two stylus buttons (bit 0 dark grey, bit 1 light grey).
    pub fn buttons_into(&self, out: &mut Joy, d: &DeviceState, stamp: Time) {
        set_header(&mut out.header, stamp, TOUCH_BASE_FRAME);
        out.axes.clear();
        out.buttons.clear();
        out.buttons
            .extend((0..2).map(|bit| ((d.buttons >> bit) & 1) as i32));
    }

    /// `/tf` of a physics step: world → meniscus, probe, proxy, touch_base ([`TF_CHILDREN`]).
    pub fn transforms_into(&self, out: &mut TFMessage, f: &ContactFrame, stamp: Time) {
        out.transforms
            .resize_with(TF_CHILDREN.len(), Default::default);
        let poses = [
            &self.meniscus_pose,
            &f.probe_pose,
            &f.proxy_pose,
            &self.touch_base_pose,
        ];
        for ((t, child), pose) in out.transforms.iter_mut().zip(TF_CHILDREN).zip(poses) {
            set_header(&mut t.header, stamp, &self.world_frame);
            set_str(&mut t.child_frame_id, child);
            t.transform = pose.into();
        }
    }

    /// `meniscus/mesh`: the deformed surface as a TRIANGLE_LIST (three points per triangle),
    /// world frame. Counts beyond capacity are clamped; a triangle with an index past the
    /// vertex count is skipped, never trusted. Returns the number skipped.
    pub fn mesh_marker_into(&self, out: &mut Marker, s: &SurfaceFrame, stamp: Time) -> usize {
        reuse_marker(out);
        let vertex_count = (s.vertex_count as usize).min(MAX_SURFACE_VERTICES);
        let triangle_count = (s.triangle_count as usize).min(MAX_SURFACE_TRIANGLES);
        let mut skipped = 0;
        for tri in &s.triangles[..triangle_count] {
            if tri.iter().any(|&i| i as usize >= vertex_count) {
                skipped += 1;
                continue;
            }
            for &i in tri {
                let p = s.positions[i as usize];
                out.points
                    .push([p[0] as f64, p[1] as f64, p[2] as f64].into());
            }
        }
        set_header(&mut out.header, stamp, &self.world_frame);
        out.ns.push_str(MESH_MARKER_NS);
        out.id = 0;
        out.r#type = Marker::TRIANGLE_LIST;
        out.action = Marker::ADD;
        out.scale = [1.0, 1.0, 1.0].into();
        out.color = MESH_COLOR;
        skipped
    }

    /// `contacts`: a DELETEALL (clears the previous step's contacts), then per contact a
    /// sphere at the contact point and an arrow along the contact normal scaled by the normal
    /// force λₙ/dt ([`CONTACT_ARROW_M_PER_N`]), world frame.
    pub fn contact_markers_into(&self, out: &mut MarkerArray, f: &ContactFrame, stamp: Time) {
        let count = (f.contact_count as usize).min(MAX_CONTACTS);
        out.markers.resize_with(1 + 2 * count, Default::default);
        for m in out.markers.iter_mut() {
            reuse_marker(m);
            set_header(&mut m.header, stamp, &self.world_frame);
            m.ns.push_str(CONTACT_MARKER_NS);
        }
        out.markers[0].action = Marker::DELETEALL;
        let dt = if f.dt_s > 0.0 { f.dt_s } else { 1.0 };
        for k in 0..count {
            let p = f.contact_points[k];
            let row = k * ROWS_PER_CONTACT;
            let n = &f.constraint_directions[row];
            let normal_force = f.lambda[row] / dt;
            let length = (normal_force.abs() * CONTACT_ARROW_M_PER_N).max(CONTACT_ARROW_MIN_M);
            let sphere = &mut out.markers[1 + 2 * k];
            sphere.id = (2 * k) as i32;
            sphere.r#type = Marker::SPHERE;
            sphere.action = Marker::ADD;
            sphere.pose.position = p.into();
            sphere.scale = [0.0015, 0.0015, 0.0015].into();
            sphere.color = ColorRGBA {
                r: 1.0,
                g: 0.2,
                b: 0.1,
                a: 1.0,
            };
            let arrow = &mut out.markers[2 + 2 * k];
            arrow.id = (2 * k + 1) as i32;
            arrow.r#type = Marker::ARROW;
            arrow.action = Marker::ADD;
            arrow.scale = [0.0005, 0.001, 0.0].into();
            arrow.color = ColorRGBA {
                r: 0.1,
                g: 0.4,
                b: 1.0,
                a: 1.0,
            };
            arrow.points.push(p.into());
            arrow.points.push(
                [
                    p[0] + n[0] * length,
                    p[1] + n[1] * length,
                    p[2] + n[2] * length,
                ]
                .into(),
            );
        }
    }

    /// The haptic loop's status on `/diagnostics` ([`HAPTIC_STATUS_NAME`]): WARN while any
    /// fault bit is set; `hardware_id` is the haptic process instance (changes on restart);
    /// values at full precision (shortest round-trip decimal), so the recording keeps them.
    pub fn haptic_status_into(&self, out: &mut DiagnosticStatus, h: &HapticStats) {
        out.level = if h.faults != 0 {
            DiagnosticStatus::WARN
        } else {
            DiagnosticStatus::OK
        };
        set_str(&mut out.name, HAPTIC_STATUS_NAME);
        out.message = if h.faults != 0 {
            format!("faults {:#x}", h.faults)
        } else {
            format!("{:.0} Hz", h.tick_hz)
        };
        out.hardware_id = format!("{:016x}", h.instance_id);
        let values: [(&str, String); 17] = [
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
        out.values.resize_with(values.len(), Default::default);
        for (kv, (k, v)) in out.values.iter_mut().zip(values) {
            set_str(&mut kv.key, k);
            kv.value = v;
        }
    }

    /// A `/diagnostics` array header: stamped `stamp`, world frame.
    pub fn diagnostics_header(&self, stamp: Time) -> Header {
        Header::new(stamp, &self.world_frame)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Topic as _;
    use std::mem::MaybeUninit;

    fn zeroed<T: crate::Topic>() -> Box<MaybeUninit<T>> {
        let mut slot = Box::new(MaybeUninit::<T>::uninit());
        T::zeroed_in(&mut slot);
        slot
    }

    #[test]
    fn the_bridge_streams_every_topic_but_diagnostics() {
        assert_eq!(Topic::ALL.len(), Topic::COUNT);
        assert_eq!(Topic::STREAMED.len(), Topic::COUNT - 1);
        assert!(!Topic::STREAMED.contains(&Topic::Diagnostics));
    }

    #[test]
    fn topic_names_follow_the_namespace() {
        let m = Mapping::default();
        assert_eq!(m.topic(Topic::ProbePose), "/arthrosim/probe/pose");
        assert_eq!(m.topic(Topic::Tf), "/tf");
        assert_eq!(m.topic(Topic::Diagnostics), "/diagnostics");
        assert_eq!(full_topic_name("/", "contacts"), "/contacts");
        assert_eq!(
            Topic::Contacts.def().type_name(),
            "visualization_msgs/msg/MarkerArray"
        );
    }

    #[test]
    fn stamp_clock_maps_monotonic_onto_the_epoch() {
        let clock = StampClock::with_offset(1_000);
        assert_eq!(
            clock.stamp(2_000_000_500),
            Time {
                sec: 2,
                nanosec: 1_500
            }
        );
        let measured = StampClock::measure();
        let direct = crate::clock::realtime_ns() as i64 - crate::clock::monotonic_ns() as i64;
        assert!((measured.offset_ns() - direct).abs() < 1_000_000);
    }

    #[test]
    fn contact_frame_maps_to_pose_wrench_tf_and_markers() {
        let map = Mapping {
            meniscus_pose: crate::Pose {
                position: [0.0, 0.0, 0.01],
                orientation: [0.0, 0.0, 0.0, 1.0],
            },
            ..Mapping::default()
        };
        let stamp = Time { sec: 3, nanosec: 7 };
        let mut slot = zeroed::<ContactFrame>();
        let f = ContactFrame::zeroed_in(&mut slot);
        f.dt_s = 0.01;
        f.probe_pose = crate::Pose {
            position: [0.01, 0.02, 0.03],
            orientation: [0.0, 0.0, 0.0, 1.0],
        };
        f.proxy_pose = crate::Pose {
            position: [0.01, 0.02, 0.025],
            orientation: [0.0, 0.0, 0.0, 1.0],
        };
        f.contact_force = [0.1, -0.2, 1.5];
        f.contact_torque = [0.0, 0.01, 0.0];
        f.contact_count = 1;
        f.row_count = 3;
        f.contact_points[0] = [0.0, 0.0, 0.02];
        f.constraint_directions[0] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        f.lambda[0] = 0.015; // 1.5 N over 10 ms

        let mut pose = PoseStamped::default();
        map.probe_pose_into(&mut pose, f, stamp);
        assert_eq!(
            (pose.header.stamp, pose.header.frame_id.as_str()),
            (stamp, "world")
        );
        assert_eq!(
            pose.pose.position,
            Point {
                x: 0.01,
                y: 0.02,
                z: 0.03
            }
        );
        let mut wrench = WrenchStamped::default();
        map.probe_wrench_into(&mut wrench, f, stamp);
        assert_eq!(
            wrench.wrench.force,
            Vector3 {
                x: 0.1,
                y: -0.2,
                z: 1.5
            }
        );
        assert_eq!(wrench.wrench.torque.y, 0.01);

        let mut tf = TFMessage::default();
        map.transforms_into(&mut tf, f, stamp);
        let edges: Vec<(&str, &str)> = tf
            .transforms
            .iter()
            .map(|t| (t.header.frame_id.as_str(), t.child_frame_id.as_str()))
            .collect();
        assert_eq!(edges, map.tf_edges().to_vec());
        assert_eq!(tf.transforms[0].transform.translation.z, 0.01);
        assert_eq!(tf.transforms[2].transform.translation.z, 0.025);

        let mut markers = MarkerArray::default();
        map.contact_markers_into(&mut markers, f, stamp);
        assert_eq!(markers.markers.len(), 3);
        assert_eq!(markers.markers[0].action, Marker::DELETEALL);
        let arrow = &markers.markers[2];
        assert_eq!(arrow.r#type, Marker::ARROW);
        assert!((arrow.points[1].z - (0.02 + 1.5 * CONTACT_ARROW_M_PER_N)).abs() < 1e-12);

        // Reused with fewer contacts: nothing of the previous step is left.
        f.contact_count = 0;
        map.contact_markers_into(&mut markers, f, stamp);
        assert_eq!(markers.markers.len(), 1);
        f.contact_count = 1;
        map.contact_markers_into(&mut markers, f, stamp);
        assert_eq!(markers.markers[2].points.len(), 2);
    }

    #[test]
    fn surface_becomes_triangle_list_and_bad_triangles_are_skipped() {
        let mut slot = zeroed::<SurfaceFrame>();
        let s = SurfaceFrame::zeroed_in(&mut slot);
        s.vertex_count = 3;
        s.triangle_count = 2;
        s.positions[1] = [0.5, 0.0, 0.0];
        s.positions[2] = [0.0, 0.25, 0.0];
        s.triangles[0] = [0, 1, 2];
        s.triangles[1] = [0, 1, 7];
        let mut m = Marker::default();
        let skipped = Mapping::default().mesh_marker_into(&mut m, s, Time::default());
        assert_eq!(skipped, 1);
        assert_eq!(m.r#type, Marker::TRIANGLE_LIST);
        assert_eq!(m.points.len(), 3);
        assert_eq!(
            m.points[2],
            Point {
                x: 0.0,
                y: 0.25,
                z: 0.0
            }
        );
        assert_eq!(
            (m.ns.as_str(), m.header.frame_id.as_str()),
            ("meniscus", "world")
        );
    }

    #[test]
    fn device_state_maps_to_wrench_joints_and_buttons() {
        let map = Mapping::default();
        let mut slot = zeroed::<DeviceState>();
        let d = DeviceState::zeroed_in(&mut slot);
        d.rendered_force = [0.5, 0.25, -0.125];
        d.joint_angles = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6];
        d.buttons = 0b10;
        let stamp = Time::default();
        let mut w = WrenchStamped::default();
        map.device_wrench_into(&mut w, d, stamp);
        assert_eq!(w.wrench.force.z, -0.125);
        let mut j = JointState::default();
        map.joint_states_into(&mut j, d, stamp);
        assert_eq!(j.name, TOUCH_JOINTS.map(String::from).to_vec());
        assert_eq!(
            (j.position[5], j.header.frame_id.as_str()),
            (0.6, "touch_base")
        );
        let mut joy = Joy::default();
        map.buttons_into(&mut joy, d, stamp);
        assert_eq!(joy.buttons, vec![0, 1]);
    }

    #[test]
    fn haptic_status_warns_on_faults_and_keeps_full_precision() {
        let mut slot = zeroed::<HapticStats>();
        let h = HapticStats::zeroed_in(&mut slot);
        h.tick_hz = 999.875;
        h.instance_id = 0xab;
        let mut s = DiagnosticStatus::default();
        let map = Mapping::default();
        map.haptic_status_into(&mut s, h);
        assert_eq!(
            (s.level, s.message.as_str()),
            (DiagnosticStatus::OK, "1000 Hz")
        );
        assert_eq!(s.hardware_id, "00000000000000ab");
        let tick = s.values.iter().find(|kv| kv.key == "tick_hz").unwrap();
        assert_eq!(tick.value, "999.875");
        h.faults = 0x4;
        map.haptic_status_into(&mut s, h);
        assert_eq!(
            (s.level, s.message.as_str()),
            (DiagnosticStatus::WARN, "faults 0x4")
        );
        assert_eq!(s.values.len(), 17);
    }
}
