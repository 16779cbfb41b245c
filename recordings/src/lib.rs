//! Recordings: every arthrosim session to one MCAP file with the ROS 2 profile (what
//! rosbag2 writes: `cdr` messages, `ros2msg` schemas, `offered_qos_profiles` channel
//! metadata, a `rosbag2` metadata record, optionally `metadata.yaml` beside it), so
//! `ros2 bag`, Foxglove and Python readers open it without arthrosim code; plus export and
//! repair. MCAP input and output only: the physics is not linked here (offline re-simulation
//! and the gap diagnosis read recordings through this crate from `gap-diagnosis`).
//!
//! Data comes in from the physics and haptic nodes over shared memory (the `recorder`
//! process) and goes out to files that ROS 2 tools, `arthrosim recordings` and the gap
//! diagnosis read.
//!
//! # Library functions (wired by the `arthrosim` CLI)
//! ```text
//! // arthrosim node recorder / bin `recorder`
//! recordings::recorder::run_node(args: recordings::recorder::NodeArgs) -> anyhow::Result<()>
//!     NodeArgs { launch_config::node::CommonArgs { --launch FILE, --session NAME, --out DIR (default ".") }, --seconds S (0: until signal) }
//!
//! // arthrosim recordings info FILE
//! recordings::info(path: &Path) -> Result<RecordingInfo, RecordingError>     // impl Display, Serialize
//! // arthrosim recordings export FILE --csv DIR
//! recordings::export_csv(path: &Path, dir: &Path) -> Result<ExportSummary, RecordingError>
//! recordings::export_replay_csv(path: &Path, out_csv: &Path) -> Result<usize, RecordingError>
//!     // device trajectory in the haptic node's replay format t_s,px_m,py_m,pz_m,qx,qy,qz,qw
//! // arthrosim recordings repair FILE [--out OUT]
//! recordings::repair(path: &Path, out: &Path) -> Result<RepairReport, RecordingError>
//! ```
//!
//! # What a recording contains
//! Topics and types (see [`channels`]): the bridge's topics `/arthrosim/probe/pose`
//! (geometry_msgs/PoseStamped, every physics step), `/arthrosim/probe/wrench`
//! (geometry_msgs/WrenchStamped: eq. (1) contact force and torque), `/arthrosim/device/wrench`
//! (WrenchStamped: rendered force, every tick), `/arthrosim/device/joint_states`
//! (sensor_msgs/JointState, every tick), `/arthrosim/device/buttons` (sensor_msgs/Joy, on
//! change), `/arthrosim/meniscus/mesh` (visualization_msgs/Marker TRIANGLE_LIST at
//! `[recording] mesh_rate_hz`), `/tf` (world→probe, world→proxy each step), `/diagnostics`
//! (haptic loop statistics); and the two lossless channels replay, export and the gap
//! diagnosis read: `/arthrosim/recording/contact_step` (arthrosim_msgs/msg/ContactStep) and
//! `/arthrosim/recording/device_tick` (arthrosim_msgs/msg/DeviceTick); ContactStep carries the
//! step's contact problem (H, δ_free, W, λ) only with `[recording] contact_problem = true`
//! (W is rows², up to 73 kB per step). Attachments
//! `launch.toml` and `scene.toml`; metadata `arthrosim_session` (start), `rosbag2` and
//! `arthrosim_session_end` (counters, dropped samples) at close.
//!
//! Chunks are zstd-compressed and finished every `[recording] flush_interval_s` (0.5 s), so
//! after `kill -9` the file is readable up to its last flush; [`repair`] rewrites it with a
//! summary and index.

pub mod channels;
pub mod error;
pub mod export;
pub mod length_guard;
pub mod read;
pub mod recorder;
pub mod repair;
pub mod resume;
pub mod rosbag2;
pub mod writer;

pub use error::RecordingError;
pub use export::{export_csv, export_replay_csv, session_summary, ExportSummary};
pub use read::{info, RecordingInfo};
pub use repair::{repair, RepairReport};
pub use writer::{SessionInfo, SessionWriter};
