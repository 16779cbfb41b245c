"""Plain-JSON form of a ROS 2 message from either reader: Cyclone DDS IDL dataclasses (the live
capture of ros_peer.py) or mcap_ros2 decoded messages (the recording, dump_mcap.py). Both name
fields as the .msg definitions do, so the same message gives the same plain value and digest.

`describe` reduces one message to what the live-vs-recorded test compares: header stamp and
frame id, joint names, tf edges, the haptic status of /diagnostics, and a digest of the whole
value (floats exactly: JSON repr round-trips a double)."""
import dataclasses
import hashlib
import json

# Topic key → name relative to the namespace (msgs::ros_mapping::Topic::relative).
TOPICS = {
    "probe_pose": "probe/pose",
    "probe_wrench": "probe/wrench",
    "device_wrench": "device/wrench",
    "joint_states": "device/joint_states",
    "buttons": "device/buttons",
    "mesh": "meniscus/mesh",
    "contacts": "contacts",
    "tf": "/tf",
    "diagnostics": "/diagnostics",
}

HAPTIC_STATUS = "arthrosim/haptic"


def full_name(ns, rel):
    if rel.startswith("/"):
        return rel
    return ("" if ns == "/" else ns) + "/" + rel


def plain(v):
    if isinstance(v, (bool, int, float, str)) or v is None:
        return v
    if isinstance(v, (bytes, bytearray)):
        return list(v)
    if isinstance(v, (list, tuple)):
        return [plain(x) for x in v]
    if dataclasses.is_dataclass(v):
        return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
    if hasattr(v, "tolist"):
        return plain(v.tolist())
    slots = getattr(type(v), "__slots__", None)
    if slots:
        return {k: plain(getattr(v, k)) for k in slots}
    if hasattr(v, "__dict__"):
        return {k: plain(x) for k, x in vars(v).items() if not k.startswith("_")}
    raise TypeError(f"cannot make {type(v).__name__} plain")


def digest(value):
    text = json.dumps(value, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def stamp_ns(header):
    return header["stamp"]["sec"] * 1_000_000_000 + header["stamp"]["nanosec"]


def describe(key, msg):
    d = plain(msg)
    out = {"digest": digest(d)}
    if "header" in d:
        out["stamp"] = stamp_ns(d["header"])
        out["frames"] = [d["header"]["frame_id"]]
    if key == "tf":
        ts = d["transforms"]
        out["stamp"] = stamp_ns(ts[0]["header"]) if ts else 0
        out["frames"] = sorted({t["header"]["frame_id"] for t in ts})
        out["edges"] = [[t["header"]["frame_id"], t["child_frame_id"]] for t in ts]
    elif key == "contacts":
        ms = d["markers"]
        out["stamp"] = stamp_ns(ms[0]["header"]) if ms else 0
        out["frames"] = sorted({m["header"]["frame_id"] for m in ms})
    elif key == "joint_states":
        out["joints"] = d["name"]
    elif key == "diagnostics":
        for s in d["status"]:
            # `byte level`: an int from one reader, a 1-byte string from another.
            if isinstance(s["level"], list):
                s["level"] = s["level"][0] if s["level"] else 0
            if s["name"] == HAPTIC_STATUS:
                seq = next((kv["value"] for kv in s["values"] if kv["key"] == "sequence"), None)
                if seq is not None:
                    out["haptic_sequence"] = seq
                    out["haptic_digest"] = digest(s)
    return out
