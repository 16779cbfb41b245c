//! Inbound ROS 2 messages → physics commands, checked. Pure functions, so they are tested
//! without DDS. The outbound direction (session data → ROS 2 messages) is the one mapping in
//! `msgs::ros_mapping`, shared with the recorder.

use msgs::ros::*;

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
