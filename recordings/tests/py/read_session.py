#!/usr/bin/env python3
"""Reads an arthrosim session recording with two independent ROS 2 readers from PyPI and
prints what each saw as one JSON document, which the Rust test compares with what it wrote.

    read_session.py FILE.mcap [--folder]

Readers:
  rosbags  rosbags.highlevel.AnyReader on the bare .mcap (and, with --folder, on the
           rosbag2 folder holding metadata.yaml; its QoS strings must match the channels)
  mcap     mcap.reader.make_reader with mcap_ros2.decoder.DecoderFactory

Exit status 3 when a reader package is missing (the Rust test decides whether that is a
skip or a failure), 1 on any read error.
"""

import json
import struct
import sys
from pathlib import Path

CONTACT_STEP = "/arthrosim/recording/contact_step"
DEVICE_TICK = "/arthrosim/recording/device_tick"
PROBE_WRENCH = "/arthrosim/probe/wrench"
PROBE_POSE = "/arthrosim/probe/pose"
JOINT_STATES = "/arthrosim/device/joint_states"
MESH = "/arthrosim/meniscus/mesh"
DIAGNOSTICS = "/diagnostics"
TF = "/tf"


def bits(x):
    """IEEE-754 bits of a double: exact through JSON whatever the parser does with decimals."""
    return struct.unpack("<Q", struct.pack("<d", float(x)))[0]


def empty():
    return {
        "counts": {},
        "types": {},
        "contact_step": [],
        "device_tick": [],
        "probe_wrench": [],
        "probe_pose": [],
        "joint_positions_first": None,
        "mesh_points_first": None,
        "diagnostics_keys": None,
        "tf_children": None,
    }


def collect(out, topic, msgtype, msg):
    out["counts"][topic] = out["counts"].get(topic, 0) + 1
    out["types"][topic] = msgtype
    if topic == CONTACT_STEP:
        f = msg.contact_force
        out["contact_step"].append(
            [int(msg.sequence), bits(f.x), bits(f.y), bits(f.z), int(msg.contact_count),
             bits(msg.sim_time), bits(msg.proxy_pose.position.x), bits(msg.proxy_pose.position.z),
             len(msg.compliance)]
        )
    elif topic == DEVICE_TICK:
        p = msg.proxy_pose.position
        out["device_tick"].append(
            [int(msg.sequence), bits(p.x), bits(p.y), bits(p.z), int(msg.region),
             int(msg.probing_index), int(msg.phase), bits(msg.proxy_velocity[0]),
             bits(msg.rendered_force.z)]
        )
    elif topic == PROBE_WRENCH:
        f = msg.wrench.force
        out["probe_wrench"].append([bits(f.x), bits(f.y), bits(f.z)])
    elif topic == PROBE_POSE:
        p = msg.pose.position
        out["probe_pose"].append([bits(p.x), bits(p.y), bits(p.z), msg.header.frame_id])
    elif topic == JOINT_STATES and out["joint_positions_first"] is None:
        out["joint_positions_first"] = [float(v) for v in msg.position]
        out["joint_names"] = list(msg.name)
    elif topic == MESH and out["mesh_points_first"] is None:
        out["mesh_points_first"] = len(msg.points)
        out["mesh_type"] = int(msg.type)
    elif topic == DIAGNOSTICS and out["diagnostics_keys"] is None:
        out["diagnostics_keys"] = [kv.key for kv in msg.status[0].values]
    elif topic == TF and out["tf_children"] is None:
        out["tf_children"] = [t.child_frame_id for t in msg.transforms]


def read_rosbags(path):
    from rosbags.highlevel import AnyReader

    out = empty()
    with AnyReader([Path(path)]) as reader:
        for conn, _t, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            collect(out, conn.topic, conn.msgtype, msg)
    return out


def read_mcap(path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = empty()
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        out["profile"] = header.profile
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            collect(out, channel.topic, schema.name, decoded)
            out.setdefault("qos", {})[channel.topic] = channel.metadata.get("offered_qos_profiles")
        summary = reader.get_summary()
        out["metadata_names"] = [m.name for m in reader.iter_metadata()]
        out["attachment_names"] = [a.name for a in reader.iter_attachments()]
        out["has_summary"] = summary is not None
    return out


def main():
    if len(sys.argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    path = sys.argv[1]
    try:
        import rosbags  # noqa: F401
        import mcap  # noqa: F401
        import mcap_ros2  # noqa: F401
    except ImportError as e:
        print(f"missing reader package: {e}", file=sys.stderr)
        return 3
    result = {"rosbags": read_rosbags(path), "mcap": read_mcap(path)}
    if "--folder" in sys.argv[2:]:
        result["rosbags_folder"] = read_rosbags(str(Path(path).parent))
    json.dump(result, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
