#!/usr/bin/env python3
"""Independent ROS 2 peer for the viz-bridge tests: Eclipse Cyclone DDS (PyPI `cyclonedds`)
with ROS 2 IDL types, i.e. exactly what a ROS 2 node on rmw_cyclonedds puts on the wire.

Modes
  check  --expect FILE : subscribe to the bridge's topics, compare values with FILE (JSON
                         written by the Rust test), publish a probe target pose and a
                         degeneration grade; print one JSON result line; exit 0 when all pass.
  drive --target x,y,z,qx,qy,qz,qw : publish a probe target pose at 20 Hz and record the
                         probe pose / wrench values received (compared by the Rust test with
                         what the real physics node published).
  capture --out FILE --seconds S : subscribe to every topic the bridge publishes and write
                         each type and each message described by ros_normal.describe to FILE
                         (compared by the Rust test with the session MCAP).
  flood                : an attacker on the lab network: for --seconds, publish probe target
                         poses at ~1 kHz cycling through far away (875 mm), NaN, a bad
                         quaternion, and in-and-out ±4 mm around the probe pose the bridge
                         publishes (near the tissue), plus degeneration grades alternating
                         0 / 2 at --grade-hz; print one JSON line with what was sent and the
                         newest /diagnostics values of the bridge.
  bench                : count probe pose / wrench samples (position.x / force.x carry the
                         sample number, -1 warm-up, -2 end), measure latency from the header
                         stamp to receipt; print one JSON line.

Prints READY once its entities exist. Discovery settings come from CYCLONEDDS_URI.
"""
import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field

from cyclonedds.core import Policy, Qos, ReadCondition, ViewState, InstanceState, SampleState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import byte, float32, float64, int32, sequence, uint8, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


def ros(pkg, name):
    return f"{pkg}::msg::dds_::{name}_"


@dataclass
class Time(IdlStruct, typename=ros("builtin_interfaces", "Time")):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename=ros("builtin_interfaces", "Duration")):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename=ros("std_msgs", "Header")):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Float64(IdlStruct, typename=ros("std_msgs", "Float64")):
    data: float64 = 0.0


@dataclass
class ColorRGBA(IdlStruct, typename=ros("std_msgs", "ColorRGBA")):
    r: float32 = 0.0
    g: float32 = 0.0
    b: float32 = 0.0
    a: float32 = 0.0


@dataclass
class Point(IdlStruct, typename=ros("geometry_msgs", "Point")):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Vector3(IdlStruct, typename=ros("geometry_msgs", "Vector3")):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename=ros("geometry_msgs", "Quaternion")):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename=ros("geometry_msgs", "Pose")):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped(IdlStruct, typename=ros("geometry_msgs", "PoseStamped")):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class Wrench(IdlStruct, typename=ros("geometry_msgs", "Wrench")):
    force: Vector3 = field(default_factory=Vector3)
    torque: Vector3 = field(default_factory=Vector3)


@dataclass
class WrenchStamped(IdlStruct, typename=ros("geometry_msgs", "WrenchStamped")):
    header: Header = field(default_factory=Header)
    wrench: Wrench = field(default_factory=Wrench)


@dataclass
class Transform(IdlStruct, typename=ros("geometry_msgs", "Transform")):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename=ros("geometry_msgs", "TransformStamped")):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename=ros("tf2_msgs", "TFMessage")):
    transforms: sequence[TransformStamped] = field(default_factory=list)


@dataclass
class JointState(IdlStruct, typename=ros("sensor_msgs", "JointState")):
    header: Header = field(default_factory=Header)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class Joy(IdlStruct, typename=ros("sensor_msgs", "Joy")):
    header: Header = field(default_factory=Header)
    axes: sequence[float32] = field(default_factory=list)
    buttons: sequence[int32] = field(default_factory=list)


@dataclass
class CompressedImage(IdlStruct, typename=ros("sensor_msgs", "CompressedImage")):
    header: Header = field(default_factory=Header)
    format: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class UVCoordinate(IdlStruct, typename=ros("visualization_msgs", "UVCoordinate")):
    u: float32 = 0.0
    v: float32 = 0.0


@dataclass
class MeshFile(IdlStruct, typename=ros("visualization_msgs", "MeshFile")):
    filename: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class Marker(IdlStruct, typename=ros("visualization_msgs", "Marker")):
    header: Header = field(default_factory=Header)
    ns: str = ""
    id: int32 = 0
    type: int32 = 0
    action: int32 = 0
    pose: Pose = field(default_factory=Pose)
    scale: Vector3 = field(default_factory=Vector3)
    color: ColorRGBA = field(default_factory=ColorRGBA)
    lifetime: Duration = field(default_factory=Duration)
    frame_locked: bool = False
    points: sequence[Point] = field(default_factory=list)
    colors: sequence[ColorRGBA] = field(default_factory=list)
    texture_resource: str = ""
    texture: CompressedImage = field(default_factory=CompressedImage)
    uv_coordinates: sequence[UVCoordinate] = field(default_factory=list)
    text: str = ""
    mesh_resource: str = ""
    mesh_file: MeshFile = field(default_factory=MeshFile)
    mesh_use_embedded_materials: bool = False


@dataclass
class MarkerArray(IdlStruct, typename=ros("visualization_msgs", "MarkerArray")):
    markers: sequence[Marker] = field(default_factory=list)


@dataclass
class KeyValue(IdlStruct, typename=ros("diagnostic_msgs", "KeyValue")):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(IdlStruct, typename=ros("diagnostic_msgs", "DiagnosticStatus")):
    level: byte = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(IdlStruct, typename=ros("diagnostic_msgs", "DiagnosticArray")):
    header: Header = field(default_factory=Header)
    status: sequence[DiagnosticStatus] = field(default_factory=list)


def qos(depth=100, latched=False, best_effort=False):
    return Qos(
        Policy.Reliability.BestEffort if best_effort else Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
    )


def topic_of(ns, rel):
    if rel.startswith("/"):
        return "rt" + rel
    return "rt" + ("" if ns == "/" else ns) + "/" + rel


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def close(a, b, tol=0.0):
    return len(a) == len(b) and all(abs(x - y) <= tol for x, y in zip(a, b))


def vec(v):
    return [v.x, v.y, v.z]


def quat(q):
    return [q.x, q.y, q.z, q.w]


class Checker:
    """Per-topic check: value equality with what the physics side published."""

    def __init__(self, exp):
        self.exp = exp
        self.passed = {}
        self.failures = {}
        self.counts = {}

    def header_ok(self, header, frame):
        now = time.time_ns()
        return header.frame_id == frame and abs(now - stamp_ns(header)) < 30_000_000_000

    def check(self, key, msg):
        self.counts[key] = self.counts.get(key, 0) + 1
        if self.passed.get(key):
            return
        try:
            ok, why = getattr(self, "check_" + key)(msg)
        except Exception as e:  # malformed content is a failure, not a crash
            ok, why = False, f"{type(e).__name__}: {e}"
        if ok:
            self.passed[key] = True
            self.failures.pop(key, None)
        else:
            self.failures[key] = why

    def check_probe_pose(self, m):
        e = self.exp["probe_pose"]
        ok = (self.header_ok(m.header, "world") and close(vec(m.pose.position), e["position"])
              and close(quat(m.pose.orientation), e["orientation"]))
        return ok, f"got {vec(m.pose.position)} {quat(m.pose.orientation)} frame {m.header.frame_id!r}"

    def check_probe_wrench(self, m):
        e = self.exp["probe_wrench"]
        ok = (self.header_ok(m.header, "world") and close(vec(m.wrench.force), e["force"])
              and close(vec(m.wrench.torque), e["torque"]))
        return ok, f"got force {vec(m.wrench.force)} torque {vec(m.wrench.torque)}"

    def check_device_wrench(self, m):
        e = self.exp["device_wrench"]
        ok = self.header_ok(m.header, "world") and close(vec(m.wrench.force), e["force"])
        return ok, f"got force {vec(m.wrench.force)}"

    def check_joint_states(self, m):
        ok = len(m.name) == 6 and close(list(m.position), self.exp["joint_positions"])
        return ok, f"got {list(m.name)} {list(m.position)}"

    def check_buttons(self, m):
        ok = list(m.buttons) == self.exp["buttons"]
        return ok, f"got {list(m.buttons)}"

    def check_mesh(self, m):
        pts = [vec(p) for p in m.points]
        ok = (m.type == 11 and self.header_ok(m.header, "world") and len(pts) == len(self.exp["mesh_points"])
              and all(close(a, b, 1e-7) for a, b in zip(pts, self.exp["mesh_points"])))
        return ok, f"got type {m.type} with {len(pts)} points {pts[:3]}"

    def check_contacts(self, m):
        spheres = [mk for mk in m.markers if mk.type == 2]
        exp = self.exp["contact_points"]
        ok = (len(m.markers) > 0 and m.markers[0].action == 3 and len(spheres) == len(exp)
              and all(close(vec(s.pose.position), p) for s, p in zip(spheres, exp)))
        return ok, f"got {len(m.markers)} markers, spheres at {[vec(s.pose.position) for s in spheres]}"

    def check_tf(self, m):
        by_child = {t.child_frame_id: t for t in m.transforms}
        probe = by_child.get("probe")
        ok = (set(by_child) >= {"meniscus", "probe", "touch_base"}
              and all(t.header.frame_id == "world" for t in m.transforms)
              and probe is not None
              and close(vec(probe.transform.translation), self.exp["probe_pose"]["position"]))
        return ok, f"got children {sorted(by_child)}"

    def check_diagnostics(self, m):
        names = [s.name for s in m.status]
        bridge = next((s for s in m.status if s.name == "arthrosim/viz-bridge"), None)
        ok = bridge is not None and any(kv.key == "probe/pose rate_hz" for kv in bridge.values)
        return ok, f"got statuses {names}"


TOPICS = {
    "probe_pose": ("probe/pose", PoseStamped, False),
    "probe_wrench": ("probe/wrench", WrenchStamped, False),
    "device_wrench": ("device/wrench", WrenchStamped, False),
    "joint_states": ("device/joint_states", JointState, False),
    "buttons": ("device/buttons", Joy, False),
    "mesh": ("meniscus/mesh", Marker, True),
    "contacts": ("contacts", MarkerArray, False),
    "tf": ("/tf", TFMessage, False),
    "diagnostics": ("/diagnostics", DiagnosticArray, False),
}


def run_check(args):
    with open(args.expect) as f:
        exp = json.load(f)
    ns = exp.get("namespace", "/arthrosim")
    keys = exp.get("topics", list(TOPICS))
    dp = DomainParticipant(args.domain)
    readers = {}
    for key in keys:
        rel, typ, latched = TOPICS[key]
        readers[key] = DataReader(dp, Topic(dp, topic_of(ns, rel), typ), qos=qos(100, latched))
    target_writer = grade_writer = None
    if "target_pose" in exp:
        target_writer = DataWriter(dp, Topic(dp, topic_of(ns, "probe/target_pose"), PoseStamped), qos=qos(10))
    if "degeneration_grade" in exp:
        grade_writer = DataWriter(dp, Topic(dp, topic_of(ns, "material/degeneration_grade"), Float64), qos=qos(1))
    print("READY", flush=True)

    checker = Checker(exp)
    start = time.monotonic()
    deadline = start + args.timeout
    next_cmd = start
    all_passed_at = None
    while time.monotonic() < deadline:
        for key, reader in readers.items():
            for msg in reader.take(N=64):
                checker.check(key, msg)
        now = time.monotonic()
        if now >= next_cmd:
            next_cmd = now + 0.1
            if target_writer is not None:
                t = exp["target_pose"]
                ts = time.time_ns()
                target_writer.write(PoseStamped(
                    header=Header(stamp=Time(ts // 1_000_000_000, ts % 1_000_000_000), frame_id="world"),
                    pose=Pose(position=Point(*t["position"]), orientation=Quaternion(*t["orientation"]))))
            if grade_writer is not None:
                grade_writer.write(Float64(exp["degeneration_grade"]))
        if all_passed_at is None and all(checker.passed.get(k) for k in keys):
            all_passed_at = now
        # Keep commanding for a while after the checks pass so the test sees the target.
        if all_passed_at is not None and now - all_passed_at >= args.linger:
            break
        time.sleep(0.005)

    missing = [k for k in keys if not checker.passed.get(k)]
    result = {
        "ok": not missing,
        "missing": missing,
        "failures": {k: checker.failures.get(k, "nothing received") for k in missing},
        "received": checker.counts,
        "seconds": round(time.monotonic() - start, 3),
    }
    print(json.dumps(result), flush=True)
    return 0 if not missing else 1


def run_bench(args):
    ns = args.namespace
    dp = DomainParticipant(args.domain)
    depth = 100000
    # A reliable reader matches only reliable writers; follow the bench's setting.
    be = args.best_effort
    pose_r = DataReader(dp, Topic(dp, topic_of(ns, "probe/pose"), PoseStamped), qos=qos(depth, best_effort=be))
    wrench_r = DataReader(dp, Topic(dp, topic_of(ns, "probe/wrench"), WrenchStamped), qos=qos(depth, best_effort=be))
    ws = WaitSet(dp)
    for r in (pose_r, wrench_r):
        ws.attach(ReadCondition(r, SampleState.Any | ViewState.Any | InstanceState.Any))
    print("READY", flush=True)
    seen = {"pose": set(), "wrench": set()}
    dup = {"pose": 0, "wrench": 0}
    lat = []
    warm = False
    ended = False
    deadline = time.monotonic() + args.timeout
    end_at = None
    while time.monotonic() < deadline:
        ws.wait(duration(milliseconds=50))
        for key, reader, val in (("pose", pose_r, lambda m: m.pose.position.x),
                                 ("wrench", wrench_r, lambda m: m.wrench.force.x)):
            msgs = reader.take(N=512)
            now = time.time_ns()
            for m in msgs:
                x = val(m)
                if x == -1.0:
                    if not warm:
                        warm = True
                        print("WARM", flush=True)
                elif x == -2.0:
                    if end_at is None:
                        end_at = time.monotonic()
                elif x >= 0:
                    n = int(x)
                    if n in seen[key]:
                        dup[key] += 1
                    seen[key].add(n)
                    lat.append(now - stamp_ns(m.header))
        # Reliable delivery may still be retransmitting right after the end marker.
        if end_at is not None and time.monotonic() - end_at > 1.0:
            ended = True
            break
    # The raw latencies go back to bridge-bench, which takes the percentiles with the
    # workspace's one latency histogram (msgs::timing), like every other benchmark.
    print(json.dumps({
        "ended": ended,
        "pose_received": len(seen["pose"]),
        "wrench_received": len(seen["wrench"]),
        "pose_max": max(seen["pose"]) if seen["pose"] else -1,
        "duplicates": dup,
        "latencies_ns": lat,
    }), flush=True)
    return 0


def run_drive(args):
    """Drive the probe: publish a target pose at 20 Hz; record the pose and wrench samples the
    bridge publishes (values only), for comparison with what physics published."""
    ns = args.namespace
    target = [float(v) for v in args.target.split(",")]
    dp = DomainParticipant(args.domain)
    pose_r = DataReader(dp, Topic(dp, topic_of(ns, "probe/pose"), PoseStamped), qos=qos(1000))
    wrench_r = DataReader(dp, Topic(dp, topic_of(ns, "probe/wrench"), WrenchStamped), qos=qos(1000))
    writer = DataWriter(dp, Topic(dp, topic_of(ns, "probe/target_pose"), PoseStamped), qos=qos(10))
    print("READY", flush=True)
    poses, wrenches = [], []
    end = time.monotonic() + args.seconds
    next_cmd = 0.0
    while time.monotonic() < end:
        now = time.monotonic()
        if now >= next_cmd:
            next_cmd = now + 0.05
            ts = time.time_ns()
            writer.write(PoseStamped(
                header=Header(stamp=Time(ts // 1_000_000_000, ts % 1_000_000_000), frame_id="world"),
                pose=Pose(position=Point(*target[:3]), orientation=Quaternion(*target[3:7]))))
        for m in pose_r.take(N=256):
            poses.append(vec(m.pose.position) + quat(m.pose.orientation))
        for m in wrench_r.take(N=256):
            wrenches.append(vec(m.wrench.force) + vec(m.wrench.torque))
        time.sleep(0.005)
    print(json.dumps({"poses": poses[-400:], "wrenches": wrenches[-400:],
                      "pose_count": len(poses), "wrench_count": len(wrenches)}), flush=True)
    return 0


def run_capture(args):
    """Record every message of every session topic (described, not stored whole)."""
    from ros_normal import describe

    ns = args.namespace
    dp = DomainParticipant(args.domain)
    readers = {}
    types = {}
    for key, (rel, typ, _latched) in TOPICS.items():
        # Volatile readers match volatile and transient-local writers alike.
        readers[key] = DataReader(dp, Topic(dp, topic_of(ns, rel), typ), qos=qos(5000))
        # IDL name pkg::msg::dds_::Type_ → ROS name pkg/msg/Type.
        pkg, _, _, name = typ.__idl_typename__.split("::")
        types[key] = f"{pkg}/msg/{name[:-1]}"
    ws = WaitSet(dp)
    for r in readers.values():
        ws.attach(ReadCondition(r, SampleState.Any | ViewState.Any | InstanceState.Any))
    print("READY", flush=True)
    messages = {key: [] for key in TOPICS}
    end = time.monotonic() + args.seconds
    while time.monotonic() < end:
        ws.wait(duration(milliseconds=20))
        for key, reader in readers.items():
            for m in reader.take(N=1024):
                messages[key].append(describe(key, m))
    with open(args.out, "w") as f:
        json.dump({"types": types, "messages": messages}, f)
    print(json.dumps({k: len(v) for k, v in messages.items()}), flush=True)
def run_flood(args):
    ns = args.namespace
    dp = DomainParticipant(args.domain)
    pose_r = DataReader(dp, Topic(dp, topic_of(ns, "probe/pose"), PoseStamped), qos=qos(10))
    diag_r = DataReader(dp, Topic(dp, topic_of(ns, "/diagnostics"), DiagnosticArray), qos=qos(10))
    writer = DataWriter(dp, Topic(dp, topic_of(ns, "probe/target_pose"), PoseStamped), qos=qos(10))
    grade_w = DataWriter(dp, Topic(dp, topic_of(ns, "material/degeneration_grade"), Float64), qos=qos(1))
    print("READY", flush=True)
    probe = None
    diag = {}
    sent = {"far": 0, "nan": 0, "bad_quaternion": 0, "in_out": 0, "grades": 0}
    end = time.monotonic() + args.seconds
    next_grade = 0.0
    k = 0
    while time.monotonic() < end:
        for m in pose_r.take(N=64):
            if hasattr(m, "pose"):  # skip InvalidSample (instance state changes)
                probe = vec(m.pose.position)
        for m in diag_r.take(N=16):
            for st in getattr(m, "status", []):
                if st.name == "arthrosim/viz-bridge/inputs":
                    diag = {kv.key: kv.value for kv in st.values}
        ts = time.time_ns()
        hdr = Header(stamp=Time(ts // 1_000_000_000, ts % 1_000_000_000), frame_id="world")
        kind = k % 4
        q = [0.0, 0.0, 0.0, 1.0]
        if kind == 0:
            p, name = [0.875, 0.0, 0.0], "far"
        elif kind == 1:
            p, name = [float("nan"), 0.0, 0.0], "nan"
        elif kind == 2:
            p, name = (probe or [0.0, 0.0, 0.05]), "bad_quaternion"
            q = [0.0, 0.0, 0.0, 3.0]
        else:
            base = probe or [0.0, 0.0, 0.05]
            # in and out across the surface every 20 ms
            dz = 0.004 if (k // 80) % 2 == 0 else -0.004
            p, name = [base[0], base[1], base[2] + dz], "in_out"
        writer.write(PoseStamped(header=hdr, pose=Pose(position=Point(*p), orientation=Quaternion(*q))))
        sent[name] += 1
        k += 1
        now = time.monotonic()
        if args.grade_hz > 0 and now >= next_grade:
            next_grade = now + 1.0 / args.grade_hz
            grade_w.write(Float64(2.0 if sent["grades"] % 2 == 0 else 0.0))
            sent["grades"] += 1
        time.sleep(0.001)
    # Let the bridge's next /diagnostics (1 Hz) report the last of the flood.
    settle = time.monotonic() + 2.5
    while time.monotonic() < settle:
        for m in diag_r.take(N=16):
            for st in getattr(m, "status", []):
                if st.name == "arthrosim/viz-bridge/inputs":
                    diag = {kv.key: kv.value for kv in st.values}
        time.sleep(0.05)
    print(json.dumps({"sent": sent, "diagnostics": diag, "saw_probe": probe is not None}), flush=True)
    return 0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=["check", "bench", "drive", "capture", "flood"])
    ap.add_argument("--out", help="capture: where to write the described messages")
    ap.add_argument("--grade-hz", type=float, default=0.0)
    ap.add_argument("--target", default="0,0,0.05,0,0,0,1")
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--expect")
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--namespace", default="/arthrosim")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--linger", type=float, default=2.0)
    ap.add_argument("--best-effort", action="store_true", help="bench: best-effort readers")
    args = ap.parse_args()
    if args.mode == "check":
        if not args.expect:
            ap.error("check needs --expect FILE")
        return run_check(args)
    if args.mode == "drive":
        return run_drive(args)
    if args.mode == "capture":
        if not args.out:
            ap.error("capture needs --out FILE")
        return run_capture(args)
    if args.mode == "flood":
        return run_flood(args)
    return run_bench(args)


if __name__ == "__main__":
    sys.exit(main())
