#!/usr/bin/env python3
"""A Foxglove WebSocket protocol client (PyPI `websockets`, ROS 2 CDR decoded with
`mcap-ros2-support`'s dynamic decoder) that subscribes to a live arthrosim session and checks
what arrives against the session's own MCAP recording.

  foxglove_check.py --ws ws://127.0.0.1:8765 --seconds 4 --session-dir DIR

1. Connects with subprotocol foxglove.sdk.v1 (the SDK's name of the protocol), reads the advertised channels, subscribes
   to every one, and collects messages for --seconds.
2. Waits for the session to end (DIR/summary.json), opens DIR/session.mcap and matches each
   received probe wrench and pose to the recorded message with the nearest stamp: values must
   be equal (same physics step). The mesh's triangle-list length must equal the recorded one.
   /diagnostics must carry region, probing, the rates (haptic near 1 kHz) and faults.
Also reports, per topic, the rate received and the latency (receipt − log time, ms).
Prints one JSON line with the counts and findings; exits 1 on any failed check.
"""
import argparse
import asyncio
import json
import math
import os
import struct
import sys
import time

import websockets
from mcap_ros2._dynamic import generate_dynamic

NS = "/arthrosim"
WANT = {
    f"{NS}/probe/pose": "geometry_msgs/msg/PoseStamped",
    f"{NS}/probe/wrench": "geometry_msgs/msg/WrenchStamped",
    f"{NS}/device/wrench": "geometry_msgs/msg/WrenchStamped",
    f"{NS}/device/joint_states": "sensor_msgs/msg/JointState",
    f"{NS}/meniscus/mesh": "visualization_msgs/msg/Marker",
    f"{NS}/contacts": "visualization_msgs/msg/MarkerArray",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


async def collect(url, seconds):
    got = {}
    channels = {}
    decoders = {}
    latency_ms = {}
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                                  max_size=None, open_timeout=10) as ws:
        subscribed = False
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=max(0.05, deadline - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg.get("op") == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        channels[ch["id"]] = ch
                        if ch["topic"] in WANT and ch["encoding"] == "cdr" \
                                and ch["schemaEncoding"] == "ros2msg":
                            decoders[ch["id"]] = generate_dynamic(ch["schemaName"], ch["schema"])[ch["schemaName"]]
                            subs.append({"id": ch["id"], "channelId": ch["id"]})
                    if subs:
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                        subscribed = True
                continue
            if raw[0] != 0x01 or not subscribed:
                continue
            received_ns = time.time_ns()
            sub_id, log_time = struct.unpack_from("<IQ", raw, 1)
            payload = raw[13:]
            ch = channels[sub_id]
            # Latency: receipt − the message's log time (the sample's session stamp, Unix ns).
            latency_ms.setdefault(ch["topic"], []).append((received_ns - log_time) / 1e6)
            got.setdefault(ch["topic"], []).append((log_time, decoders[sub_id](payload), ch["schemaName"]))
    return channels, got, latency_ms


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ws", required=True)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--session-dir", required=True)
    ap.add_argument("--wait-end", type=float, default=120.0)
    args = ap.parse_args()

    channels, got, latency_ms = asyncio.run(collect(args.ws, args.seconds))
    failures = []
    advertised = {c["topic"]: c["schemaName"] for c in channels.values()}
    for topic, schema in WANT.items():
        if advertised.get(topic) != schema:
            failures.append(f"channel {topic} advertised as {advertised.get(topic)}, expected {schema}")
    counts = {t: len(v) for t, v in got.items()}
    for topic in [f"{NS}/probe/pose", f"{NS}/probe/wrench", f"{NS}/meniscus/mesh", "/tf",
                  f"{NS}/device/wrench", f"{NS}/device/joint_states"]:
        if counts.get(topic, 0) == 0:
            failures.append(f"no message on {topic}")

    tf_children = sorted({t.child_frame_id for _, m, _ in got.get("/tf", []) for t in m.transforms})
    # The stylus is the proxy frame (under touch_base), the probe the physics' tool.
    if not {"meniscus", "probe", "proxy", "touch_base"} <= set(tf_children):
        failures.append(f"tf children {tf_children}")
    diag_keys = sorted({kv.key for _, m, _ in got.get("/diagnostics", []) for s in m.status for kv in s.values})
    # Session status on /diagnostics: region, probing, rates and faults.
    status_keys = {"region", "probing", "physics rate_hz", "haptic rate_hz", "faults"}
    if not status_keys <= set(diag_keys):
        failures.append(f"/diagnostics lacks {sorted(status_keys - set(diag_keys))}")
    haptic_rates = [float(kv.value) for _, m, _ in got.get("/diagnostics", []) for s in m.status
                    for kv in s.values if kv.key == "haptic rate_hz"]
    if haptic_rates and not 900.0 < max(haptic_rates) < 1100.0:
        failures.append(f"/diagnostics haptic rate_hz {haptic_rates}: not the 1 kHz loop")
    forces = [m.wrench.force for _, m, _ in got.get(f"{NS}/probe/wrench", [])]
    peak = max((math.sqrt(f.x ** 2 + f.y ** 2 + f.z ** 2) for f in forces), default=0.0)

    # Against the recording of the same session.
    summary = os.path.join(args.session_dir, "summary.json")
    deadline = time.monotonic() + args.wait_end
    while not os.path.exists(summary) and time.monotonic() < deadline:
        time.sleep(0.2)
    matched = {"wrench": 0, "pose": 0}
    mesh_points = {"live": None, "recorded": None}
    if not os.path.exists(summary):
        failures.append("the session did not end (no summary.json)")
    else:
        from mcap_ros2.reader import read_ros2_messages
        rec = {f"{NS}/probe/wrench": [], f"{NS}/probe/pose": [], f"{NS}/meniscus/mesh": []}
        for m in read_ros2_messages(os.path.join(args.session_dir, "session.mcap"), topics=list(rec)):
            rec[m.channel.topic].append(m.ros_msg)
        for topic, key in [(f"{NS}/probe/wrench", "wrench"), (f"{NS}/probe/pose", "pose")]:
            recorded = sorted(((stamp_ns(r.header), r) for r in rec[topic]), key=lambda x: x[0])
            stamps = [s for s, _ in recorded]
            import bisect
            for _, live, _ in got.get(topic, []):
                s = stamp_ns(live.header)
                i = bisect.bisect_left(stamps, s)
                near = [j for j in (i - 1, i) if 0 <= j < len(stamps)]
                if not near:
                    failures.append(f"{topic}: no recorded message")
                    break
                j = min(near, key=lambda j: abs(stamps[j] - s))
                if abs(stamps[j] - s) > 2_000_000:
                    failures.append(f"{topic}: live stamp {s} has no recorded step within 2 ms")
                    break
                r = recorded[j][1]
                if key == "wrench":
                    a, b = live.wrench.force, r.wrench.force
                else:
                    a, b = live.pose.position, r.pose.position
                if max(abs(a.x - b.x), abs(a.y - b.y), abs(a.z - b.z)) > 1e-9:
                    failures.append(f"{topic}: live {a} != recorded {b} at stamp {s}")
                    break
                matched[key] += 1
        live_mesh = got.get(f"{NS}/meniscus/mesh", [])
        if live_mesh and rec[f"{NS}/meniscus/mesh"]:
            mesh_points["live"] = len(live_mesh[-1][1].points)
            mesh_points["recorded"] = len(rec[f"{NS}/meniscus/mesh"][-1].points)
            if mesh_points["live"] != mesh_points["recorded"] or mesh_points["live"] < 3:
                failures.append(f"mesh points live {mesh_points['live']} vs recorded {mesh_points['recorded']}")
        for key in matched:
            if matched[key] == 0:
                failures.append(f"no live {key} matched the recording")

    print(json.dumps({
        "counts": counts, "tf_children": tf_children, "diagnostics_keys": diag_keys,
        "peak_force_n": peak, "matched": matched, "mesh_points": mesh_points,
        "rates_hz": {t: round(n / args.seconds, 1) for t, n in counts.items()},
        "latency_ms": {t: {"median": round(sorted(v)[len(v) // 2], 2),
                           "p90": round(sorted(v)[min(len(v) - 1, int(0.9 * len(v)))], 2)}
                       for t, v in latency_ms.items() if v},
        "failures": failures,
    }))
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
