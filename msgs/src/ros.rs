//! ROS 2 message types used on the lab side: by the viz-bridge (DDS through ros2-client) and
//! by the recorder (MCAP with `ros2msg` schemas).
//!
//! CDR is positional: every struct lists its fields in the exact order of the ROS 2 `.msg`
//! definition (Humble and later), with the same primitive widths. Nothing here depends on
//! ros2-client; `impl ros2_client::Message` is behind this crate's `ros2` feature.
//!
//! Each type carries a [`MsgDef`]: its ROS type name (`geometry_msgs/msg/WrenchStamped`) and
//! its field list. [`schema_text`] assembles the `ros2msg` schema that rosbag2 / MCAP readers
//! expect: the type's fields, then for every dependency (depth first, once each) a line of
//! 80 `=`, `MSG: pkg/Type`, and that type's fields. All field types are fully qualified
//! (`std_msgs/Header`), so no reader has to resolve package-relative names.

use serde::{de::DeserializeOwned, Deserialize, Serialize};

/// Definition of one ROS 2 message type.
#[derive(Debug)]
pub struct MsgDef {
    /// Package name, e.g. `geometry_msgs`.
    pub package: &'static str,
    /// Type name inside the package, e.g. `WrenchStamped`.
    pub name: &'static str,
    /// The `.msg` field list (constants included, comments and default values left out).
    pub fields: &'static str,
    /// Message types this one's fields refer to directly.
    pub deps: &'static [&'static MsgDef],
}

impl MsgDef {
    /// `pkg/msg/Type`, as rosbag2 and MCAP channels name it.
    pub fn type_name(&self) -> String {
        format!("{}/msg/{}", self.package, self.name)
    }

    /// `pkg::msg::dds_::Type_`, the DDS type name on the wire.
    pub fn dds_type_name(&self) -> String {
        format!("{}::msg::dds_::{}_", self.package, self.name)
    }
}

/// A ROS 2 message: serde in `.msg` field order plus its definition.
pub trait RosMessage: Serialize + DeserializeOwned {
    const DEF: &'static MsgDef;
}

/// `pkg/msg/Type` of `T`.
pub fn type_name<T: RosMessage>() -> String {
    T::DEF.type_name()
}

/// The `ros2msg` schema text of `T` (MCAP schema encoding `ros2msg`, rosbag2 style).
pub fn schema_text<T: RosMessage>() -> String {
    schema_text_of(T::DEF)
}

/// The `ros2msg` schema text of a definition.
pub fn schema_text_of(def: &'static MsgDef) -> String {
    let mut text = String::from(def.fields.trim_end());
    text.push('\n');
    let mut seen: Vec<*const MsgDef> = vec![def as *const MsgDef];
    let mut order = Vec::new();
    collect_deps(def, &mut seen, &mut order);
    for dep in order {
        text.push_str(&"=".repeat(80));
        text.push('\n');
        text.push_str(&format!("MSG: {}/{}\n", dep.package, dep.name));
        text.push_str(dep.fields.trim_end());
        text.push('\n');
    }
    text
}

fn collect_deps(
    def: &'static MsgDef,
    seen: &mut Vec<*const MsgDef>,
    order: &mut Vec<&'static MsgDef>,
) {
    for &dep in def.deps {
        let ptr = dep as *const MsgDef;
        if !seen.contains(&ptr) {
            seen.push(ptr);
            order.push(dep);
            collect_deps(dep, seen, order);
        }
    }
}

/// Failure to encode or decode a CDR payload.
#[derive(Debug, thiserror::Error)]
pub enum CdrError {
    #[error("CDR encoding failed: {0}")]
    Encode(String),
    #[error("CDR payload too short ({0} bytes; need the 4-byte encapsulation header)")]
    Truncated(usize),
    #[error("CDR encapsulation {0:?} is not plain CDR little or big endian")]
    Encapsulation([u8; 2]),
    #[error("CDR decoding failed: {0}")]
    Decode(String),
}

/// Encapsulation header of plain CDR, little endian (what Cyclone and rosbag2 write).
pub const CDR_LE_HEADER: [u8; 4] = [0, 1, 0, 0];

/// Serialises `msg` as a ROS 2 payload into `out` (cleared first, capacity reused): the
/// 4-byte encapsulation header `[0, 1, 0, 0]` then little-endian CDR. Alignment counts from
/// after the header, as the DDS encapsulation rules require.
pub fn to_cdr<T: Serialize>(msg: &T, out: &mut Vec<u8>) -> Result<(), CdrError> {
    out.clear();
    out.extend_from_slice(&CDR_LE_HEADER);
    cdr_encoding::to_writer::<T, byteorder::LittleEndian, _>(&mut *out, msg)
        .map_err(|e| CdrError::Encode(e.to_string()))
}

/// Parses a ROS 2 payload with its encapsulation header (little or big endian plain CDR).
pub fn from_cdr<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, CdrError> {
    if bytes.len() < 4 {
        return Err(CdrError::Truncated(bytes.len()));
    }
    let body = &bytes[4..];
    let result = match [bytes[0], bytes[1]] {
        [0, 1] => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body),
        [0, 0] => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body),
        other => return Err(CdrError::Encapsulation(other)),
    };
    result
        .map(|(value, _)| value)
        .map_err(|e| CdrError::Decode(e.to_string()))
}

macro_rules! ros_message {
    ($ty:ident, $def:ident) => {
        impl RosMessage for $ty {
            const DEF: &'static MsgDef = &$def;
        }
        #[cfg(feature = "ros2")]
        impl ros2_client::Message for $ty {}
    };
}

// ---------------------------------------------------------------------------------------
// builtin_interfaces

/// builtin_interfaces/Time: seconds and nanoseconds since the Unix epoch.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// From nanoseconds since the Unix epoch (CLOCK_REALTIME).
    pub fn from_nanos(ns: u64) -> Time {
        Time {
            sec: (ns / 1_000_000_000) as i32,
            nanosec: (ns % 1_000_000_000) as u32,
        }
    }

    /// Nanoseconds since the Unix epoch (negative seconds give 0).
    pub fn to_nanos(&self) -> u64 {
        (self.sec.max(0) as u64) * 1_000_000_000 + self.nanosec as u64
    }
}

pub static TIME_DEF: MsgDef = MsgDef {
    package: "builtin_interfaces",
    name: "Time",
    fields: "int32 sec\nuint32 nanosec\n",
    deps: &[],
};
ros_message!(Time, TIME_DEF);

/// builtin_interfaces/Duration.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    pub sec: i32,
    pub nanosec: u32,
}

pub static DURATION_DEF: MsgDef = MsgDef {
    package: "builtin_interfaces",
    name: "Duration",
    fields: "int32 sec\nuint32 nanosec\n",
    deps: &[],
};
ros_message!(Duration, DURATION_DEF);

// ---------------------------------------------------------------------------------------
// std_msgs

/// std_msgs/Header.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    pub fn new(stamp: Time, frame_id: &str) -> Header {
        Header {
            stamp,
            frame_id: frame_id.to_string(),
        }
    }
}

pub static HEADER_DEF: MsgDef = MsgDef {
    package: "std_msgs",
    name: "Header",
    fields: "builtin_interfaces/Time stamp\nstring frame_id\n",
    deps: &[&TIME_DEF],
};
ros_message!(Header, HEADER_DEF);

/// std_msgs/Float64.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Float64 {
    pub data: f64,
}

pub static FLOAT64_DEF: MsgDef = MsgDef {
    package: "std_msgs",
    name: "Float64",
    fields: "float64 data\n",
    deps: &[],
};
ros_message!(Float64, FLOAT64_DEF);

/// std_msgs/String.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StringMsg {
    pub data: String,
}

pub static STRING_DEF: MsgDef = MsgDef {
    package: "std_msgs",
    name: "String",
    fields: "string data\n",
    deps: &[],
};
ros_message!(StringMsg, STRING_DEF);

/// std_msgs/ColorRGBA (components 0..1).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ColorRGBA {
    pub r: f32,
    pub g: f32,
    pub b: f32,
    pub a: f32,
}

pub static COLOR_RGBA_DEF: MsgDef = MsgDef {
    package: "std_msgs",
    name: "ColorRGBA",
    fields: "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n",
    deps: &[],
};
ros_message!(ColorRGBA, COLOR_RGBA_DEF);

// ---------------------------------------------------------------------------------------
// geometry_msgs

/// geometry_msgs/Point, m.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl From<[f64; 3]> for Point {
    fn from(v: [f64; 3]) -> Point {
        Point {
            x: v[0],
            y: v[1],
            z: v[2],
        }
    }
}

pub static POINT_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Point",
    fields: "float64 x\nfloat64 y\nfloat64 z\n",
    deps: &[],
};
ros_message!(Point, POINT_DEF);

/// geometry_msgs/Vector3.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl From<[f64; 3]> for Vector3 {
    fn from(v: [f64; 3]) -> Vector3 {
        Vector3 {
            x: v[0],
            y: v[1],
            z: v[2],
        }
    }
}

pub static VECTOR3_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Vector3",
    fields: "float64 x\nfloat64 y\nfloat64 z\n",
    deps: &[],
};
ros_message!(Vector3, VECTOR3_DEF);

/// geometry_msgs/Quaternion (`x, y, z, w`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

impl From<[f64; 4]> for Quaternion {
    /// From arthrosim's `[x, y, z, w]`.
    fn from(q: [f64; 4]) -> Quaternion {
        Quaternion {
            x: q[0],
            y: q[1],
            z: q[2],
            w: q[3],
        }
    }
}

pub static QUATERNION_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Quaternion",
    fields: "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    deps: &[],
};
ros_message!(Quaternion, QUATERNION_DEF);

/// geometry_msgs/Pose.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}

impl From<&crate::Pose> for Pose {
    fn from(p: &crate::Pose) -> Pose {
        Pose {
            position: p.position.into(),
            orientation: p.orientation.into(),
        }
    }
}

impl From<&Pose> for crate::Pose {
    fn from(p: &Pose) -> crate::Pose {
        crate::Pose {
            position: [p.position.x, p.position.y, p.position.z],
            orientation: [
                p.orientation.x,
                p.orientation.y,
                p.orientation.z,
                p.orientation.w,
            ],
        }
    }
}

pub static POSE_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Pose",
    fields: "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    deps: &[&POINT_DEF, &QUATERNION_DEF],
};
ros_message!(Pose, POSE_DEF);

/// geometry_msgs/PoseStamped.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

pub static POSE_STAMPED_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "PoseStamped",
    fields: "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    deps: &[&HEADER_DEF, &POSE_DEF],
};
ros_message!(PoseStamped, POSE_STAMPED_DEF);

/// geometry_msgs/Wrench: force (N) and torque (N·m).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Wrench {
    pub force: Vector3,
    pub torque: Vector3,
}

pub static WRENCH_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Wrench",
    fields: "geometry_msgs/Vector3 force\ngeometry_msgs/Vector3 torque\n",
    deps: &[&VECTOR3_DEF],
};
ros_message!(Wrench, WRENCH_DEF);

/// geometry_msgs/WrenchStamped.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct WrenchStamped {
    pub header: Header,
    pub wrench: Wrench,
}

pub static WRENCH_STAMPED_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "WrenchStamped",
    fields: "std_msgs/Header header\ngeometry_msgs/Wrench wrench\n",
    deps: &[&HEADER_DEF, &WRENCH_DEF],
};
ros_message!(WrenchStamped, WRENCH_STAMPED_DEF);

/// geometry_msgs/Transform.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

impl From<&crate::Pose> for Transform {
    fn from(p: &crate::Pose) -> Transform {
        Transform {
            translation: p.position.into(),
            rotation: p.orientation.into(),
        }
    }
}

pub static TRANSFORM_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Transform",
    fields: "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    deps: &[&VECTOR3_DEF, &QUATERNION_DEF],
};
ros_message!(Transform, TRANSFORM_DEF);

/// geometry_msgs/TransformStamped: `header.frame_id` is the parent, `child_frame_id` the child.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

pub static TRANSFORM_STAMPED_DEF: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "TransformStamped",
    fields: "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
    deps: &[&HEADER_DEF, &TRANSFORM_DEF],
};
ros_message!(TransformStamped, TRANSFORM_STAMPED_DEF);

// ---------------------------------------------------------------------------------------
// tf2_msgs

/// tf2_msgs/TFMessage.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}

pub static TF_MESSAGE_DEF: MsgDef = MsgDef {
    package: "tf2_msgs",
    name: "TFMessage",
    fields: "geometry_msgs/TransformStamped[] transforms\n",
    deps: &[&TRANSFORM_STAMPED_DEF],
};
ros_message!(TFMessage, TF_MESSAGE_DEF);

// ---------------------------------------------------------------------------------------
// sensor_msgs

/// sensor_msgs/JointState.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

pub static JOINT_STATE_DEF: MsgDef = MsgDef {
    package: "sensor_msgs",
    name: "JointState",
    fields: "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
    deps: &[&HEADER_DEF],
};
ros_message!(JointState, JOINT_STATE_DEF);

/// sensor_msgs/Joy.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Joy {
    pub header: Header,
    pub axes: Vec<f32>,
    pub buttons: Vec<i32>,
}

pub static JOY_DEF: MsgDef = MsgDef {
    package: "sensor_msgs",
    name: "Joy",
    fields: "std_msgs/Header header\nfloat32[] axes\nint32[] buttons\n",
    deps: &[&HEADER_DEF],
};
ros_message!(Joy, JOY_DEF);

/// sensor_msgs/CompressedImage (only as the Marker's texture field).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    pub data: Vec<u8>,
}

pub static COMPRESSED_IMAGE_DEF: MsgDef = MsgDef {
    package: "sensor_msgs",
    name: "CompressedImage",
    fields: "std_msgs/Header header\nstring format\nuint8[] data\n",
    deps: &[&HEADER_DEF],
};
ros_message!(CompressedImage, COMPRESSED_IMAGE_DEF);

// ---------------------------------------------------------------------------------------
// visualization_msgs

/// visualization_msgs/UVCoordinate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct UVCoordinate {
    pub u: f32,
    pub v: f32,
}

pub static UV_COORDINATE_DEF: MsgDef = MsgDef {
    package: "visualization_msgs",
    name: "UVCoordinate",
    fields: "float32 u\nfloat32 v\n",
    deps: &[],
};
ros_message!(UVCoordinate, UV_COORDINATE_DEF);

/// visualization_msgs/MeshFile.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshFile {
    pub filename: String,
    pub data: Vec<u8>,
}

pub static MESH_FILE_DEF: MsgDef = MsgDef {
    package: "visualization_msgs",
    name: "MeshFile",
    fields: "string filename\nuint8[] data\n",
    deps: &[],
};
ros_message!(MeshFile, MESH_FILE_DEF);

/// visualization_msgs/Marker (Humble and later: texture, UV and embedded-mesh fields).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    pub header: Header,
    pub ns: String,
    pub id: i32,
    pub r#type: i32,
    pub action: i32,
    pub pose: Pose,
    pub scale: Vector3,
    pub color: ColorRGBA,
    pub lifetime: Duration,
    pub frame_locked: bool,
    pub points: Vec<Point>,
    pub colors: Vec<ColorRGBA>,
    pub texture_resource: String,
    pub texture: CompressedImage,
    pub uv_coordinates: Vec<UVCoordinate>,
    pub text: String,
    pub mesh_resource: String,
    pub mesh_file: MeshFile,
    pub mesh_use_embedded_materials: bool,
}

impl Marker {
    pub const ARROW: i32 = 0;
    pub const CUBE: i32 = 1;
    pub const SPHERE: i32 = 2;
    pub const CYLINDER: i32 = 3;
    pub const LINE_STRIP: i32 = 4;
    pub const LINE_LIST: i32 = 5;
    pub const CUBE_LIST: i32 = 6;
    pub const SPHERE_LIST: i32 = 7;
    pub const POINTS: i32 = 8;
    pub const TEXT_VIEW_FACING: i32 = 9;
    pub const MESH_RESOURCE: i32 = 10;
    pub const TRIANGLE_LIST: i32 = 11;
    pub const ADD: i32 = 0;
    pub const DELETE: i32 = 2;
    pub const DELETEALL: i32 = 3;
}

pub static MARKER_DEF: MsgDef = MsgDef {
    package: "visualization_msgs",
    name: "Marker",
    fields: "\
int32 ARROW=0
int32 CUBE=1
int32 SPHERE=2
int32 CYLINDER=3
int32 LINE_STRIP=4
int32 LINE_LIST=5
int32 CUBE_LIST=6
int32 SPHERE_LIST=7
int32 POINTS=8
int32 TEXT_VIEW_FACING=9
int32 MESH_RESOURCE=10
int32 TRIANGLE_LIST=11
int32 ARROW_STRIP=12
int32 ADD=0
int32 MODIFY=0
int32 DELETE=2
int32 DELETEALL=3
std_msgs/Header header
string ns
int32 id
int32 type
int32 action
geometry_msgs/Pose pose
geometry_msgs/Vector3 scale
std_msgs/ColorRGBA color
builtin_interfaces/Duration lifetime
bool frame_locked
geometry_msgs/Point[] points
std_msgs/ColorRGBA[] colors
string texture_resource
sensor_msgs/CompressedImage texture
visualization_msgs/UVCoordinate[] uv_coordinates
string text
string mesh_resource
visualization_msgs/MeshFile mesh_file
bool mesh_use_embedded_materials
",
    deps: &[
        &HEADER_DEF,
        &POSE_DEF,
        &VECTOR3_DEF,
        &COLOR_RGBA_DEF,
        &DURATION_DEF,
        &POINT_DEF,
        &COMPRESSED_IMAGE_DEF,
        &UV_COORDINATE_DEF,
        &MESH_FILE_DEF,
    ],
};
ros_message!(Marker, MARKER_DEF);

/// visualization_msgs/MarkerArray.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MarkerArray {
    pub markers: Vec<Marker>,
}

pub static MARKER_ARRAY_DEF: MsgDef = MsgDef {
    package: "visualization_msgs",
    name: "MarkerArray",
    fields: "visualization_msgs/Marker[] markers\n",
    deps: &[&MARKER_DEF],
};
ros_message!(MarkerArray, MARKER_ARRAY_DEF);

// ---------------------------------------------------------------------------------------
// diagnostic_msgs

/// diagnostic_msgs/KeyValue.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

impl KeyValue {
    pub fn new(key: &str, value: impl ToString) -> KeyValue {
        KeyValue {
            key: key.to_string(),
            value: value.to_string(),
        }
    }
}

pub static KEY_VALUE_DEF: MsgDef = MsgDef {
    package: "diagnostic_msgs",
    name: "KeyValue",
    fields: "string key\nstring value\n",
    deps: &[],
};
ros_message!(KeyValue, KEY_VALUE_DEF);

/// diagnostic_msgs/DiagnosticStatus.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

pub static DIAGNOSTIC_STATUS_DEF: MsgDef = MsgDef {
    package: "diagnostic_msgs",
    name: "DiagnosticStatus",
    fields: "\
byte OK=0
byte WARN=1
byte ERROR=2
byte STALE=3
byte level
string name
string message
string hardware_id
diagnostic_msgs/KeyValue[] values
",
    deps: &[&KEY_VALUE_DEF],
};
ros_message!(DiagnosticStatus, DIAGNOSTIC_STATUS_DEF);

/// diagnostic_msgs/DiagnosticArray.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

pub static DIAGNOSTIC_ARRAY_DEF: MsgDef = MsgDef {
    package: "diagnostic_msgs",
    name: "DiagnosticArray",
    fields: "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n",
    deps: &[&HEADER_DEF, &DIAGNOSTIC_STATUS_DEF],
};
ros_message!(DiagnosticArray, DIAGNOSTIC_ARRAY_DEF);

#[cfg(feature = "ros2")]
/// The ros2-client type name of `T` (becomes `pkg::msg::dds_::Type_` on the wire).
pub fn message_type_name<T: RosMessage>() -> ros2_client::MessageTypeName {
    ros2_client::MessageTypeName::new(T::DEF.package, T::DEF.name)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stamped_wrench() -> WrenchStamped {
        WrenchStamped {
            header: Header::new(
                Time {
                    sec: 7,
                    nanosec: 500,
                },
                "world",
            ),
            wrench: Wrench {
                force: [0.25, -1.5, 3.0].into(),
                torque: [0.0, 0.0, -0.125].into(),
            },
        }
    }

    #[test]
    fn wrench_stamped_byte_layout_is_plain_cdr_le() {
        let mut buf = Vec::new();
        to_cdr(&stamped_wrench(), &mut buf).unwrap();
        let mut expected = vec![0u8, 1, 0, 0];
        expected.extend_from_slice(&7i32.to_le_bytes());
        expected.extend_from_slice(&500u32.to_le_bytes());
        // string: u32 length including the NUL, bytes, NUL
        expected.extend_from_slice(&6u32.to_le_bytes());
        expected.extend_from_slice(b"world\0");
        // pad to 8 (offset after header: 4+4+4+6 = 18 → 24)
        expected.extend_from_slice(&[0u8; 6]);
        for v in [0.25f64, -1.5, 3.0, 0.0, 0.0, -0.125] {
            expected.extend_from_slice(&v.to_le_bytes());
        }
        assert_eq!(buf, expected);
    }

    #[test]
    fn messages_round_trip_through_cdr() {
        let mut buf = Vec::new();
        let w = stamped_wrench();
        to_cdr(&w, &mut buf).unwrap();
        assert_eq!(from_cdr::<WrenchStamped>(&buf).unwrap(), w);

        let marker = Marker {
            header: Header::new(Time::from_nanos(1_700_000_000_123_456_789), "world"),
            ns: "meniscus".into(),
            id: 3,
            r#type: Marker::TRIANGLE_LIST,
            points: vec![
                [0.0, 0.0, 0.0].into(),
                [1.0, 0.0, 0.0].into(),
                [0.0, 1.0, 0.0].into(),
            ],
            colors: vec![ColorRGBA {
                r: 1.0,
                g: 0.5,
                b: 0.25,
                a: 1.0,
            }],
            frame_locked: true,
            mesh_use_embedded_materials: true,
            ..Default::default()
        };
        to_cdr(&marker, &mut buf).unwrap();
        assert_eq!(from_cdr::<Marker>(&buf).unwrap(), marker);

        let diag = DiagnosticArray {
            header: Header::default(),
            status: vec![DiagnosticStatus {
                level: DiagnosticStatus::WARN,
                name: "viz-bridge".into(),
                values: vec![KeyValue::new("dropped", 4)],
                ..Default::default()
            }],
        };
        to_cdr(&diag, &mut buf).unwrap();
        assert_eq!(from_cdr::<DiagnosticArray>(&buf).unwrap(), diag);
        assert!(matches!(
            from_cdr::<Marker>(&buf[..3]),
            Err(CdrError::Truncated(3))
        ));
    }

    #[test]
    fn schema_text_lists_each_dependency_once_depth_first() {
        assert_eq!(
            type_name::<WrenchStamped>(),
            "geometry_msgs/msg/WrenchStamped"
        );
        assert_eq!(
            WRENCH_STAMPED_DEF.dds_type_name(),
            "geometry_msgs::msg::dds_::WrenchStamped_"
        );
        let sep = "=".repeat(80);
        let expected = format!(
            "std_msgs/Header header\ngeometry_msgs/Wrench wrench\n\
             {sep}\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n\
             {sep}\nMSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n\
             {sep}\nMSG: geometry_msgs/Wrench\ngeometry_msgs/Vector3 force\ngeometry_msgs/Vector3 torque\n\
             {sep}\nMSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
        );
        assert_eq!(schema_text::<WrenchStamped>(), expected);
        let marker = schema_text::<MarkerArray>();
        assert_eq!(marker.matches("MSG: std_msgs/Header\n").count(), 1);
        for dep in [
            "MSG: visualization_msgs/MeshFile",
            "MSG: sensor_msgs/CompressedImage",
        ] {
            assert!(marker.contains(dep), "{dep} missing");
        }
    }

    /// Every definition this module exports, for whole-set checks.
    fn all_defs() -> Vec<&'static MsgDef> {
        vec![
            &TIME_DEF,
            &DURATION_DEF,
            &HEADER_DEF,
            &FLOAT64_DEF,
            &STRING_DEF,
            &COLOR_RGBA_DEF,
            &POINT_DEF,
            &VECTOR3_DEF,
            &QUATERNION_DEF,
            &POSE_DEF,
            &POSE_STAMPED_DEF,
            &WRENCH_DEF,
            &WRENCH_STAMPED_DEF,
            &TRANSFORM_DEF,
            &TRANSFORM_STAMPED_DEF,
            &TF_MESSAGE_DEF,
            &JOINT_STATE_DEF,
            &JOY_DEF,
            &COMPRESSED_IMAGE_DEF,
            &UV_COORDINATE_DEF,
            &MESH_FILE_DEF,
            &MARKER_DEF,
            &MARKER_ARRAY_DEF,
            &KEY_VALUE_DEF,
            &DIAGNOSTIC_STATUS_DEF,
            &DIAGNOSTIC_ARRAY_DEF,
        ]
    }

    #[test]
    fn every_complex_field_type_has_its_definition_in_the_schema() {
        const PRIMITIVES: [&str; 14] = [
            "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64",
            "uint64", "float32", "float64", "string",
        ];
        for def in all_defs() {
            let text = schema_text_of(def);
            // Optional: dump for external parsers (rosbags, mcap_ros2) to check.
            if let Ok(dir) = std::env::var("ARTHROSIM_SCHEMA_DUMP") {
                let file = format!("{dir}/{}__{}.msg", def.package, def.name);
                std::fs::write(file, &text).unwrap();
            }
            let sections: Vec<&str> = text.split(&"=".repeat(80)).collect();
            let defined: Vec<&str> = sections[1..]
                .iter()
                .map(|s| {
                    s.trim_start()
                        .lines()
                        .next()
                        .unwrap()
                        .trim_start_matches("MSG: ")
                })
                .collect();
            for line in text
                .lines()
                .filter(|l| !l.is_empty() && !l.starts_with('=') && !l.starts_with("MSG:"))
            {
                let mut parts = line.split_whitespace();
                let ty = parts.next().unwrap().trim_end_matches("[]");
                let name = parts
                    .next()
                    .unwrap_or_else(|| panic!("{}: bad line {line:?}", def.name));
                if name.contains('=') || PRIMITIVES.contains(&ty) {
                    continue;
                }
                assert!(
                    defined.contains(&ty),
                    "{}: {ty} used but not defined",
                    def.name
                );
            }
            assert_eq!(
                defined.len(),
                {
                    let mut d = defined.clone();
                    d.sort();
                    d.dedup();
                    d.len()
                },
                "{}: a dependency is listed twice",
                def.name
            );
        }
    }
}
