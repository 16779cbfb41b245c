//! What a session recording contains: topics, ROS 2 types, `ros2msg` schemas, QoS, and the
//! two lossless arthrosim channels.
//!
//! Lossless channels (full rate, float64 bit-exact, ROS-typed so any ROS 2 tool opens them):
//! - `/arthrosim/recording/contact_step` (`arthrosim_msgs/msg/ContactStep`): one per physics
//!   step: proxy pose, probe free/corrected pose, contact force (eq. (1)) and torque, contact
//!   count, and (with `[recording] contact_problem`) the step's contact problem (H rows,
//!   δ_free, W, λ) for the active rows.
//! - `/arthrosim/recording/device_tick` (`arthrosim_msgs/msg/DeviceTick`): one per haptic
//!   tick: proxy pose/twist, joint angles, commanded and rendered force, frame used, faults,
//!   and the protocol annotations (probing index, region, phase).
//!
//! The bridge's topics are written beside them, built by the same mapping the bridge uses
//! (`msgs::ros_mapping`: names, types, frames, joint names, tf tree, diagnostics), so
//! Foxglove / `ros2 bag play` show exactly what the live bridge showed, without arthrosim code.

use msgs::ros::{self, Header, MsgDef, RosMessage};
use serde::{Deserialize, Serialize};
use session_metrics::ContactSample;

pub const PROFILE: &str = "ros2";
pub const MESSAGE_ENCODING: &str = "cdr";
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// World frame id of the lossless channels' headers (the ROS 2 topics take theirs from
/// `msgs::ros_mapping`).
pub const WORLD_FRAME: &str = msgs::ros_mapping::DEFAULT_WORLD_FRAME;

pub const TOPIC_CONTACT_STEP: &str = "/arthrosim/recording/contact_step";
pub const TOPIC_DEVICE_TICK: &str = "/arthrosim/recording/device_tick";

pub const TYPE_CONTACT_STEP: &str = "arthrosim_msgs/msg/ContactStep";
pub const TYPE_DEVICE_TICK: &str = "arthrosim_msgs/msg/DeviceTick";

/// Name of the metadata record rosbag2 writes into its MCAP files.
pub const ROSBAG2_METADATA: &str = "rosbag2";
/// Name of arthrosim's own metadata record (session, launch file path, versions, counters).
pub const SESSION_METADATA: &str = "arthrosim_session";
/// Attachment names.
pub const ATTACHMENT_LAUNCH: &str = "launch.toml";
pub const ATTACHMENT_SCENE: &str = "scene.toml";

/// The QoS profile every channel was offered with (reliable, volatile, keep-all), in the
/// exact YAML form rosbag2 (Humble and later) stores in channel metadata
/// `offered_qos_profiles`. `metadata.yaml` repeats this string byte for byte: rosbags
/// silently yields no messages when the two differ.
pub const OFFERED_QOS_PROFILES: &str = "- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n  deadline:\n    sec: 2147483647\n    nsec: 4294967295\n  lifespan:\n    sec: 2147483647\n    nsec: 4294967295\n  liveliness: 1\n  liveliness_lease_duration:\n    sec: 2147483647\n    nsec: 4294967295\n  avoid_ros_namespace_conventions: false";

/// `arthrosim_msgs/msg/ContactStep` fields.
pub const DEF_CONTACT_STEP: &str = "\
# One physics step of an arthrosim session, lossless (float64 bit-exact).
# Rows are grouped per contact (normal, tangent 1, tangent 2); row_count = 3 * contact_count.
std_msgs/Header header
uint64 instance_id
uint64 sequence
uint64 publish_ns
float64 sim_time
float64 dt
uint64 step_duration_ns
uint32 contact_count
uint32 row_count
float64 friction_mu
uint32 lcp_iterations
float64 lcp_residual
uint64 device_sequence_used
geometry_msgs/Pose proxy_pose
geometry_msgs/Pose probe_free_pose
geometry_msgs/Pose probe_pose
# eq. (1): f = H^T lambda / dt on the probe, world frame, N
geometry_msgs/Vector3 contact_force
geometry_msgs/Vector3 contact_torque
# some constraint carries a normal impulse (session-metrics' definition of contact)
bool touching
# impulse-weighted outward tissue normal (zero without contact)
geometry_msgs/Vector3 contact_normal
# the contact problem below is recorded when [recording] contact_problem = true, else empty
# contact points on the tissue, world m: 3 per contact
float64[] contact_points
# H rows [linear xyz, angular xyz]: 6 per row
float64[] constraint_directions
# free violation per row, m
float64[] free_violation
# W, row_count x row_count, row-major, m/(N s)
float64[] compliance
# impulses per row, N s
float64[] lambda";

/// `arthrosim_msgs/msg/DeviceTick` fields.
pub const DEF_DEVICE_TICK: &str = "\
# One haptic tick of an arthrosim session, lossless (float64 bit-exact).
std_msgs/Header header
uint64 instance_id
uint64 sequence
uint64 publish_ns
uint32 device_kind
uint32 buttons
geometry_msgs/Pose proxy_pose
# linear m/s then angular rad/s, world frame
float64[6] proxy_velocity
float64[6] joint_angles
geometry_msgs/Vector3 commanded_force
geometry_msgs/Vector3 rendered_force
uint64 frame_sequence_used
uint64 frame_instance_used
uint64 frame_age_ns
uint32 contact_count
uint32 faults
uint32 lcp_iterations
# protocol annotations: probing index (0 none), region (0 none, 1 posterior, 2 mid, 3 anterior), phase
uint32 probing_index
uint32 region
uint32 phase";

pub static CONTACT_STEP_DEF: MsgDef = MsgDef {
    package: "arthrosim_msgs",
    name: "ContactStep",
    fields: DEF_CONTACT_STEP,
    deps: &[&ros::HEADER_DEF, &ros::POSE_DEF, &ros::VECTOR3_DEF],
};

pub static DEVICE_TICK_DEF: MsgDef = MsgDef {
    package: "arthrosim_msgs",
    name: "DeviceTick",
    fields: DEF_DEVICE_TICK,
    deps: &[&ros::HEADER_DEF, &ros::POSE_DEF, &ros::VECTOR3_DEF],
};

impl RosMessage for ContactStep {
    const DEF: &'static MsgDef = &CONTACT_STEP_DEF;
}

impl RosMessage for DeviceTick {
    const DEF: &'static MsgDef = &DEVICE_TICK_DEF;
}

fn stamp_header(header: &mut Header, stamp_ns: u64) {
    header.stamp = ros::Time::from_nanos(stamp_ns);
    if header.frame_id != WORLD_FRAME {
        header.frame_id = WORLD_FRAME.to_string();
    }
}

/// `arthrosim_msgs/msg/ContactStep`, fields in .msg order (CDR is positional).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ContactStep {
    pub header: Header,
    pub instance_id: u64,
    pub sequence: u64,
    pub publish_ns: u64,
    pub sim_time: f64,
    pub dt: f64,
    pub step_duration_ns: u64,
    pub contact_count: u32,
    pub row_count: u32,
    pub friction_mu: f64,
    pub lcp_iterations: u32,
    pub lcp_residual: f64,
    pub device_sequence_used: u64,
    pub proxy_pose: ros::Pose,
    pub probe_free_pose: ros::Pose,
    pub probe_pose: ros::Pose,
    pub contact_force: ros::Vector3,
    pub contact_torque: ros::Vector3,
    pub touching: bool,
    pub contact_normal: ros::Vector3,
    pub contact_points: Vec<f64>,
    pub constraint_directions: Vec<f64>,
    pub free_violation: Vec<f64>,
    pub compliance: Vec<f64>,
    pub lambda: Vec<f64>,
}

impl ContactStep {
    /// Copies a physics step into `self`, reusing its vectors (the recorder keeps one).
    /// Counts are clamped to the wire capacity, so a corrupt frame cannot index out of range.
    /// `with_problem`: also copy H, δ_free, W and λ of the active rows (else left empty).
    pub fn fill_from(
        &mut self,
        f: &msgs::physics_to_haptic::ContactFrame,
        stamp_ns: u64,
        with_problem: bool,
    ) {
        let contacts = if with_problem {
            (f.contact_count as usize).min(msgs::MAX_CONTACTS)
        } else {
            0
        };
        let rows = if with_problem {
            (f.row_count as usize).min(msgs::MAX_ROWS)
        } else {
            0
        };
        stamp_header(&mut self.header, stamp_ns);
        self.instance_id = f.instance_id;
        self.sequence = f.sequence;
        self.publish_ns = f.publish_ns;
        self.sim_time = f.sim_time_s;
        self.dt = f.dt_s;
        self.step_duration_ns = f.step_duration_ns;
        self.contact_count = f.contact_count;
        self.row_count = f.row_count;
        self.friction_mu = f.friction_mu;
        self.lcp_iterations = f.lcp_iterations;
        self.lcp_residual = f.lcp_residual;
        self.device_sequence_used = f.device_sequence_used;
        self.proxy_pose = (&f.proxy_pose).into();
        self.probe_free_pose = (&f.probe_free_pose).into();
        self.probe_pose = (&f.probe_pose).into();
        self.contact_force = f.contact_force.into();
        self.contact_torque = f.contact_torque.into();
        let sample = ContactSample::from_frame(f);
        self.touching = sample.touching;
        self.contact_normal = sample.normal.into();
        self.contact_points.clear();
        for p in &f.contact_points[..contacts] {
            self.contact_points.extend_from_slice(p);
        }
        self.constraint_directions.clear();
        for h in &f.constraint_directions[..rows] {
            self.constraint_directions.extend_from_slice(h);
        }
        self.free_violation.clear();
        self.free_violation
            .extend_from_slice(&f.free_violation[..rows]);
        self.compliance.clear();
        for i in 0..rows {
            let start = i * msgs::MAX_ROWS;
            self.compliance
                .extend_from_slice(&f.compliance[start..start + rows]);
        }
        self.lambda.clear();
        self.lambda.extend_from_slice(&f.lambda[..rows]);
    }
}

impl ContactStep {
    /// The session-metrics view of this step (contact, normal force, the tick it used).
    pub fn sample(&self) -> ContactSample {
        ContactSample {
            instance_id: self.instance_id,
            sequence: self.sequence,
            publish_ns: self.publish_ns,
            sim_time_s: self.sim_time,
            dt_s: self.dt,
            step_duration_ns: self.step_duration_ns,
            contact_count: self.contact_count.min(msgs::MAX_CONTACTS as u32),
            device_sequence_used: self.device_sequence_used,
            normal: [
                self.contact_normal.x,
                self.contact_normal.y,
                self.contact_normal.z,
            ],
            touching: self.touching,
            contact_force: [
                self.contact_force.x,
                self.contact_force.y,
                self.contact_force.z,
            ],
            probe_position: [
                self.probe_pose.position.x,
                self.probe_pose.position.y,
                self.probe_pose.position.z,
            ],
            // The recording's ContactStep does not carry the fault bits (yet): a recorded
            // step reads as good.
            physics_faults: 0,
        }
    }
}

/// `arthrosim_msgs/msg/DeviceTick`, fields in .msg order.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct DeviceTick {
    pub header: Header,
    pub instance_id: u64,
    pub sequence: u64,
    pub publish_ns: u64,
    pub device_kind: u32,
    pub buttons: u32,
    pub proxy_pose: ros::Pose,
    pub proxy_velocity: [f64; 6],
    pub joint_angles: [f64; 6],
    pub commanded_force: ros::Vector3,
    pub rendered_force: ros::Vector3,
    pub frame_sequence_used: u64,
    pub frame_instance_used: u64,
    pub frame_age_ns: u64,
    pub contact_count: u32,
    pub faults: u32,
    pub lcp_iterations: u32,
    pub probing_index: u32,
    pub region: u32,
    pub phase: u32,
}

impl DeviceTick {
    pub fn fill_from(&mut self, d: &msgs::haptic_to_physics::DeviceState, stamp_ns: u64) {
        stamp_header(&mut self.header, stamp_ns);
        self.instance_id = d.instance_id;
        self.sequence = d.sequence;
        self.publish_ns = d.publish_ns;
        self.device_kind = d.device_kind;
        self.buttons = d.buttons;
        self.proxy_pose = (&d.proxy_pose).into();
        self.proxy_velocity = d.proxy_velocity;
        self.joint_angles = d.joint_angles;
        self.commanded_force = d.commanded_force.into();
        self.rendered_force = d.rendered_force.into();
        self.frame_sequence_used = d.frame_sequence_used;
        self.frame_instance_used = d.frame_instance_used;
        self.frame_age_ns = d.frame_age_ns;
        self.contact_count = d.contact_count;
        self.faults = d.faults;
        self.lcp_iterations = d.lcp_iterations;
        self.probing_index = d.probing_index;
        self.region = d.region;
        self.phase = d.phase;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schema_lists_dependencies_after_separator() {
        let s = ros::schema_text::<ContactStep>();
        assert!(s.starts_with("# One physics step"));
        assert!(s.contains(&format!("\n{}\nMSG: std_msgs/Header\n", "=".repeat(80))));
        for dep in ["Header", "Time", "Pose", "Point", "Quaternion", "Vector3"] {
            assert!(s.matches(&format!("/{dep}\n")).count() >= 1, "{dep}");
        }
        assert_eq!(ros::type_name::<DeviceTick>(), TYPE_DEVICE_TICK);
        assert_eq!(ros::type_name::<ContactStep>(), TYPE_CONTACT_STEP);
    }

    #[test]
    fn device_tick_round_trips_bit_exact() {
        let mut t = DeviceTick::default();
        t.proxy_pose.position.z = f64::from_bits(0x3ff0_0000_0000_0001);
        t.region = 2;
        t.header.frame_id = "world".into();
        let mut buf = Vec::new();
        ros::to_cdr(&t, &mut buf).unwrap();
        assert_eq!(&buf[..4], &ros::CDR_LE_HEADER);
        let back: DeviceTick = ros::from_cdr(&buf).unwrap();
        assert_eq!(back.proxy_pose.position.z.to_bits(), 0x3ff0_0000_0000_0001);
        assert_eq!(back, t);
    }

    #[test]
    fn contact_problem_is_copied_only_when_asked() {
        let mut slot = Box::new(core::mem::MaybeUninit::<
            msgs::physics_to_haptic::ContactFrame,
        >::uninit());
        let f = <msgs::physics_to_haptic::ContactFrame as msgs::Topic>::zeroed_in(&mut slot);
        f.contact_count = 2;
        f.row_count = 6;
        f.compliance[msgs::MAX_ROWS + 1] = 2.5;
        f.contact_force = [0.0, 0.0, 1.5];
        let mut step = ContactStep::default();
        step.fill_from(f, 1, true);
        assert_eq!(step.compliance.len(), 36);
        assert_eq!(
            step.compliance[6 + 1],
            2.5,
            "row-major with stride row_count"
        );
        assert_eq!(step.contact_points.len(), 6);
        step.fill_from(f, 1, false);
        assert!(
            step.compliance.is_empty() && step.lambda.is_empty() && step.contact_points.is_empty()
        );
        assert_eq!((step.contact_count, step.contact_force.z), (2, 1.5));
    }

    #[test]
    fn truncated_payload_is_an_error() {
        let t = ContactStep {
            compliance: vec![1.0; 9],
            ..Default::default()
        };
        let mut buf = Vec::new();
        ros::to_cdr(&t, &mut buf).unwrap();
        for cut in [0, 3, 4, 20, buf.len() - 1] {
            assert!(
                ros::from_cdr::<ContactStep>(&buf[..cut]).is_err(),
                "cut {cut}"
            );
        }
    }
}
