//! The rosbag2 side of a recording: the `metadata.yaml` of a rosbag2 folder and the
//! `rosbag2` metadata record rosbag2 writes inside its MCAP files (same YAML).
//!
//! Version 5 layout (readable by rosbag2 Humble and later and by rosbags). Each topic's
//! `offered_qos_profiles` is the exact string of the MCAP channel metadata.

use crate::channels::{MESSAGE_ENCODING, OFFERED_QOS_PROFILES};
use crate::writer::TopicCount;

/// The ROS distribution whose message definitions the schemas follow.
pub const ROS_DISTRO: &str = "humble";

/// A YAML double-quoted scalar (JSON string syntax is valid YAML).
fn quoted(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

/// `metadata.yaml` for a rosbag2 folder holding the single MCAP `file_name`.
pub fn metadata_yaml(file_name: &str, topics: &[TopicCount], start_ns: u64, end_ns: u64) -> String {
    let total: u64 = topics.iter().map(|t| t.count).sum();
    let duration = end_ns.saturating_sub(start_ns);
    let mut y = String::new();
    y.push_str("rosbag2_bagfile_information:\n");
    y.push_str("  version: 5\n");
    y.push_str("  storage_identifier: mcap\n");
    y.push_str(&format!("  duration:\n    nanoseconds: {duration}\n"));
    y.push_str(&format!(
        "  starting_time:\n    nanoseconds_since_epoch: {start_ns}\n"
    ));
    y.push_str(&format!("  message_count: {total}\n"));
    y.push_str("  topics_with_message_count:\n");
    for t in topics {
        y.push_str("    - topic_metadata:\n");
        y.push_str(&format!("        name: {}\n", quoted(&t.topic)));
        y.push_str(&format!("        type: {}\n", quoted(&t.type_name)));
        y.push_str(&format!(
            "        serialization_format: {MESSAGE_ENCODING}\n"
        ));
        y.push_str(&format!(
            "        offered_qos_profiles: {}\n",
            quoted(OFFERED_QOS_PROFILES)
        ));
        y.push_str(&format!("      message_count: {}\n", t.count));
    }
    y.push_str("  compression_format: \"\"\n");
    y.push_str("  compression_mode: \"\"\n");
    y.push_str(&format!(
        "  relative_file_paths:\n    - {}\n",
        quoted(file_name)
    ));
    y.push_str("  files:\n");
    y.push_str(&format!("    - path: {}\n", quoted(file_name)));
    y.push_str(&format!(
        "      starting_time:\n        nanoseconds_since_epoch: {start_ns}\n"
    ));
    y.push_str(&format!(
        "      duration:\n        nanoseconds: {duration}\n"
    ));
    y.push_str(&format!("      message_count: {total}\n"));
    y
}
