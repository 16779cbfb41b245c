//! Shared-memory samples → ROS 2 messages. Pure functions, so the mapping is tested without
//! DDS. Every stamp comes from [`StampClock`]: the sample's own monotonic publish time moved
//! onto the Unix epoch with one offset taken at bridge start, so all topics share one clock
//! and a peer on the same machine can measure end-to-end latency from the header stamp.

use msgs::haptic_to_physics::DeviceState;
use msgs::physics_to_haptic::ContactFrame;
use msgs::physics_to_viz::SurfaceFrame;
use msgs::ros::*;
use msgs::{MAX_CONTACTS, MAX_SURFACE_TRIANGLES, MAX_SURFACE_VERTICES, ROWS_PER_CONTACT};

/// Joint names of the 3D Systems Touch (3 base joints, 3 gimbal joints).
pub const TOUCH_JOINTS: [&str; 6] = [
    "touch_waist",
    "touch_shoulder",
    "touch_elbow",
    "touch_yaw",
    "touch_pitch",
    "touch_roll",
];

/// Child frame names on `/tf`.
pub const MENISCUS_FRAME: &str = "meniscus";
pub const PROBE_FRAME: &str = "probe";
pub const TOUCH_BASE_FRAME: &str = "touch_base";

/// Maps CLOCK_MONOTONIC stamps (what every arthrosim process publishes) onto ROS time
/// (Unix epoch) with one offset, fixed at construction.
#[derive(Debug, Clone, Copy)]
pub struct StampClock {
    offset_ns: i64,
}

impl StampClock {
    pub fn new() -> StampClock {
        let mono = msgs::clock::monotonic_ns() as i64;
        let real = msgs::clock::realtime_ns() as i64;
        StampClock {
            offset_ns: real - mono,
        }
    }

    /// Unix-epoch nanoseconds of a monotonic stamp.
    pub fn epoch_ns(&self, monotonic_ns: u64) -> u64 {
        (monotonic_ns as i64 + self.offset_ns).max(0) as u64
    }

    pub fn stamp(&self, monotonic_ns: u64) -> Time {
        Time::from_nanos(self.epoch_ns(monotonic_ns))
    }
}

impl Default for StampClock {
    fn default() -> Self {
        StampClock::new()
    }
}

/// `probe/pose`: the corrected probe pose of a physics step.
pub fn probe_pose(frame: &ContactFrame, clock: &StampClock, world: &str) -> PoseStamped {
    PoseStamped {
        header: Header::new(clock.stamp(frame.publish_ns), world),
        pose: (&frame.probe_pose).into(),
    }
}

/// `probe/wrench`: contact force on the probe, eq. (1) f = Hᵀλ/dt, and its torque about the
/// probe position, world frame.
pub fn probe_wrench(frame: &ContactFrame, clock: &StampClock, world: &str) -> WrenchStamped {
    WrenchStamped {
        header: Header::new(clock.stamp(frame.publish_ns), world),
        wrench: Wrench {
            force: frame.contact_force.into(),
            torque: frame.contact_torque.into(),
        },
    }
}

/// `device/wrench`: the force sent to the Touch after clamping, world frame.
pub fn device_wrench(state: &DeviceState, clock: &StampClock, world: &str) -> WrenchStamped {
    WrenchStamped {
        header: Header::new(clock.stamp(state.publish_ns), world),
        wrench: Wrench {
            force: state.rendered_force.into(),
            torque: Vector3::default(),
        },
    }
}

/// `device/joint_states`: the Touch's six joint angles.
pub fn joint_states(state: &DeviceState, clock: &StampClock) -> JointState {
    JointState {
        header: Header::new(clock.stamp(state.publish_ns), TOUCH_BASE_FRAME),
        name: TOUCH_JOINTS.iter().map(|s| s.to_string()).collect(),
        position: state.joint_angles.to_vec(),
        velocity: Vec::new(),
        effort: Vec::new(),
    }
}

/// `device/buttons`: the Touch's two stylus buttons (bit 0 dark grey, bit 1 light grey).
pub fn buttons(state: &DeviceState, clock: &StampClock) -> Joy {
    Joy {
        header: Header::new(clock.stamp(state.publish_ns), TOUCH_BASE_FRAME),
        axes: Vec::new(),
        buttons: (0..2)
            .map(|bit| ((state.buttons >> bit) & 1) as i32)
            .collect(),
    }
}

/// `/tf`: world → meniscus, world → probe, world → touch_base, all stamped with `stamp_ns`.
pub fn transforms(
    probe: &msgs::Pose,
    meniscus: &msgs::Pose,
    touch_base: &msgs::Pose,
    stamp_ns: u64,
    clock: &StampClock,
    world: &str,
) -> TFMessage {
    let stamp = clock.stamp(stamp_ns);
    let tf = |child: &str, pose: &msgs::Pose| TransformStamped {
        header: Header::new(stamp, world),
        child_frame_id: child.to_string(),
        transform: pose.into(),
    };
    TFMessage {
        transforms: vec![
            tf(MENISCUS_FRAME, meniscus),
            tf(PROBE_FRAME, probe),
            tf(TOUCH_BASE_FRAME, touch_base),
        ],
    }
}

/// Result of turning a surface frame into a triangle-list marker.
pub struct MeshMarker {
    pub marker: Marker,
    /// Triangles left out because an index pointed past the vertex count.
    pub skipped_triangles: usize,
}

/// `meniscus/mesh`: the deformed surface as a TRIANGLE_LIST (three points per triangle).
/// Counts beyond capacity are clamped; triangles with out-of-range indices are skipped.
pub fn mesh_marker(surface: &SurfaceFrame, clock: &StampClock, world: &str) -> MeshMarker {
    let vertex_count = (surface.vertex_count as usize).min(MAX_SURFACE_VERTICES);
    let triangle_count = (surface.triangle_count as usize).min(MAX_SURFACE_TRIANGLES);
    let mut points = Vec::with_capacity(triangle_count * 3);
    let mut skipped = 0;
    for tri in &surface.triangles[..triangle_count] {
        if tri.iter().any(|&i| i as usize >= vertex_count) {
            skipped += 1;
            continue;
        }
        for &i in tri {
            let p = surface.positions[i as usize];
            points.push(Point {
                x: p[0] as f64,
                y: p[1] as f64,
                z: p[2] as f64,
            });
        }
    }
    MeshMarker {
        marker: Marker {
            header: Header::new(clock.stamp(surface.publish_ns), world),
            ns: "meniscus".into(),
            id: 0,
            r#type: Marker::TRIANGLE_LIST,
            action: Marker::ADD,
            pose: Pose::default(),
            scale: Vector3 {
                x: 1.0,
                y: 1.0,
                z: 1.0,
            },
            color: ColorRGBA {
                r: 0.93,
                g: 0.80,
                b: 0.74,
                a: 1.0,
            },
            points,
            ..Default::default()
        },
        skipped_triangles: skipped,
    }
}

/// Marker scale for contact forces: arrow length per newton of normal force, m/N.
pub const CONTACT_ARROW_M_PER_N: f64 = 0.01;
/// Shortest normal arrow (a contact with zero force still shows its normal), m.
pub const CONTACT_ARROW_MIN_M: f64 = 0.003;

/// `contacts`: a DELETEALL (clears the previous step's contacts), then per contact a sphere at
/// the contact point and an arrow along the contact normal scaled by the normal force λₙ/dt.
pub fn contact_markers(frame: &ContactFrame, clock: &StampClock, world: &str) -> MarkerArray {
    let header = Header::new(clock.stamp(frame.publish_ns), world);
    let count = (frame.contact_count as usize).min(MAX_CONTACTS);
    let mut markers = Vec::with_capacity(1 + 2 * count);
    markers.push(Marker {
        header: header.clone(),
        ns: "contacts".into(),
        action: Marker::DELETEALL,
        ..Default::default()
    });
    let dt = if frame.dt_s > 0.0 { frame.dt_s } else { 1.0 };
    for k in 0..count {
        let p = frame.contact_points[k];
        let row = k * ROWS_PER_CONTACT;
        let n = &frame.constraint_directions[row];
        let normal_force = frame.lambda[row] / dt;
        let length = (normal_force.abs() * CONTACT_ARROW_M_PER_N).max(CONTACT_ARROW_MIN_M);
        markers.push(Marker {
            header: header.clone(),
            ns: "contacts".into(),
            id: (2 * k) as i32,
            r#type: Marker::SPHERE,
            action: Marker::ADD,
            pose: Pose {
                position: p.into(),
                orientation: Quaternion::default(),
            },
            scale: Vector3 {
                x: 0.0015,
                y: 0.0015,
                z: 0.0015,
            },
            color: ColorRGBA {
                r: 1.0,
                g: 0.2,
                b: 0.1,
                a: 1.0,
            },
            ..Default::default()
        });
        markers.push(Marker {
            header: header.clone(),
            ns: "contacts".into(),
            id: (2 * k + 1) as i32,
            r#type: Marker::ARROW,
            action: Marker::ADD,
            scale: Vector3 {
                x: 0.0005,
                y: 0.001,
                z: 0.0,
            },
            color: ColorRGBA {
                r: 0.1,
                g: 0.4,
                b: 1.0,
                a: 1.0,
            },
            points: vec![
                p.into(),
                [
                    p[0] + n[0] * length,
                    p[1] + n[1] * length,
                    p[2] + n[2] * length,
                ]
                .into(),
            ],
            ..Default::default()
        });
    }
    MarkerArray { markers }
}

/// A target pose from ROS as a physics command, or `None` when it is not finite or its
/// quaternion is far from unit length (quarantined, never forwarded).
pub fn probe_target(msg: &PoseStamped) -> Option<msgs::Pose> {
    let pose: msgs::Pose = (&msg.pose).into();
    let norm: f64 = pose.orientation.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !pose.is_finite() || (norm - 1.0).abs() > 1e-3 {
        return None;
    }
    let mut pose = pose;
    for q in &mut pose.orientation {
        *q /= norm;
    }
    Some(pose)
}

/// Largest degeneration grade physics understands.
pub const MAX_DEGENERATION_GRADE: f64 = 2.0;

/// A degeneration grade from ROS, or `None` when outside 0..=2 or not finite.
pub fn degeneration_grade(msg: &Float64) -> Option<f64> {
    (msg.data.is_finite() && (0.0..=MAX_DEGENERATION_GRADE).contains(&msg.data)).then_some(msg.data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use msgs::Topic;
    use std::mem::MaybeUninit;

    fn zeroed<T: Topic>() -> Box<MaybeUninit<T>> {
        let mut slot = Box::new(MaybeUninit::<T>::uninit());
        T::zeroed_in(&mut slot);
        slot
    }

    #[test]
    fn contact_frame_maps_to_pose_wrench_and_markers() {
        let clock = StampClock { offset_ns: 1_000 };
        let mut slot = zeroed::<ContactFrame>();
        let frame = ContactFrame::zeroed_in(&mut slot);
        frame.publish_ns = 2_000_000_500;
        frame.dt_s = 0.01;
        frame.probe_pose = msgs::Pose {
            position: [0.01, 0.02, 0.03],
            orientation: [0.0, 0.0, 0.0, 1.0],
        };
        frame.contact_force = [0.1, -0.2, 1.5];
        frame.contact_torque = [0.0, 0.01, 0.0];
        frame.contact_count = 1;
        frame.row_count = 3;
        frame.contact_points[0] = [0.0, 0.0, 0.02];
        frame.constraint_directions[0] = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        frame.lambda[0] = 0.015; // 1.5 N over 10 ms

        let pose = probe_pose(frame, &clock, "world");
        assert_eq!(
            pose.header.stamp,
            Time {
                sec: 2,
                nanosec: 1_500
            }
        );
        assert_eq!(pose.header.frame_id, "world");
        assert_eq!(
            pose.pose.position,
            Point {
                x: 0.01,
                y: 0.02,
                z: 0.03
            }
        );
        let wrench = probe_wrench(frame, &clock, "world");
        assert_eq!(
            wrench.wrench.force,
            Vector3 {
                x: 0.1,
                y: -0.2,
                z: 1.5
            }
        );
        assert_eq!(wrench.wrench.torque.y, 0.01);

        let markers = contact_markers(frame, &clock, "world");
        assert_eq!(markers.markers.len(), 3);
        assert_eq!(markers.markers[0].action, Marker::DELETEALL);
        let arrow = &markers.markers[2];
        assert_eq!(arrow.r#type, Marker::ARROW);
        assert!((arrow.points[1].z - (0.02 + 1.5 * CONTACT_ARROW_M_PER_N)).abs() < 1e-12);
    }

    #[test]
    fn surface_becomes_triangle_list_and_bad_triangles_are_skipped() {
        let clock = StampClock { offset_ns: 0 };
        let mut slot = zeroed::<SurfaceFrame>();
        let surface = SurfaceFrame::zeroed_in(&mut slot);
        surface.vertex_count = 3;
        surface.triangle_count = 2;
        surface.positions[0] = [0.0, 0.0, 0.0];
        surface.positions[1] = [0.5, 0.0, 0.0];
        surface.positions[2] = [0.0, 0.25, 0.0];
        surface.triangles[0] = [0, 1, 2];
        surface.triangles[1] = [0, 1, 7];
        let mesh = mesh_marker(surface, &clock, "world");
        assert_eq!(mesh.skipped_triangles, 1);
        assert_eq!(mesh.marker.r#type, Marker::TRIANGLE_LIST);
        assert_eq!(mesh.marker.points.len(), 3);
        assert_eq!(
            mesh.marker.points[2],
            Point {
                x: 0.0,
                y: 0.25,
                z: 0.0
            }
        );
    }

    #[test]
    fn device_state_maps_to_wrench_joints_and_buttons() {
        let clock = StampClock { offset_ns: 0 };
        let mut slot = zeroed::<DeviceState>();
        let state = DeviceState::zeroed_in(&mut slot);
        state.rendered_force = [0.5, 0.25, -0.125];
        state.joint_angles = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6];
        state.buttons = 0b10;
        assert_eq!(device_wrench(state, &clock, "world").wrench.force.z, -0.125);
        let joints = joint_states(state, &clock);
        assert_eq!(joints.name.len(), 6);
        assert_eq!(joints.position[5], 0.6);
        assert_eq!(buttons(state, &clock).buttons, vec![0, 1]);
    }

    #[test]
    fn inbound_commands_are_quarantined() {
        let mut target = PoseStamped::default();
        target.pose.position.x = 0.01;
        assert!(probe_target(&target).is_some());
        target.pose.position.y = f64::NAN;
        assert!(probe_target(&target).is_none());
        target.pose.position.y = 0.0;
        target.pose.orientation.w = 0.0;
        assert!(probe_target(&target).is_none(), "zero quaternion");
        assert_eq!(degeneration_grade(&Float64 { data: 2.0 }), Some(2.0));
        assert_eq!(degeneration_grade(&Float64 { data: 2.5 }), None);
        assert_eq!(degeneration_grade(&Float64 { data: f64::NAN }), None);
    }
}
