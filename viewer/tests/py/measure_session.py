#!/usr/bin/env python3
"""Measures a default session with the trainee page open in headless Chromium, and prints one
JSON line: what a lab reports for the live viewer (issue 16's closing note).

  measure_session.py --arthrosim target/release/arthrosim [--seconds 30] [--watch 20] [--out DIR]

1. Runs `arthrosim run` on the default launch file (the viewer's ports set to 0, so it never
   collides with another session) for --seconds, in DIR/session.
2. Subscribes a Foxglove WebSocket client (foxglove_check.py) to every channel and, at the
   same time, opens the page in headless Chromium (page_check.py) for --watch seconds: data
   frames/s and mesh frames/s received, the page's render frames/s, and its latency
   (receive time − the sample's session stamp, the page's median over its last 120 state
   events; median and p90 of the readings); the Foxglove client's rates and latency per topic
   (receipt − the message's log time).
3. After the session: the haptic loop's rate, ticks, overruns and period error (summary.json,
   haptic-stats.json: the MCAP's device ticks), what the bridge read and published to DDS
   per topic and dropped (`BRIDGED` in logs/bridge.log), the recorder's and the viewer's
   counts and drops (`RECORDED`, `VIEWED`), and the machine's load before and after.
Exits 1 when the session, the browser or the Foxglove client fails.
"""
import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
WORKSPACE = os.path.normpath(os.path.join(HERE, "..", "..", ".."))


def loadavg():
    with open("/proc/loadavg") as f:
        return [float(x) for x in f.read().split()[:3]]


def tagged_json(path, tag):
    """The JSON after `TAG ` on the last such line of a node's log (None: no line)."""
    try:
        with open(path) as f:
            lines = [l for l in f if l.startswith(tag + " ")]
    except FileNotFoundError:
        return None
    return json.loads(lines[-1][len(tag) + 1:]) if lines else None


def viewer_url(log, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            with open(log) as f:
                for line in f:
                    if line.startswith("VIEWER "):
                        parts = dict(p.split("=", 1) for p in line.split()[1:])
                        return parts["http"]
        except FileNotFoundError:
            pass
        time.sleep(0.2)
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--arthrosim", required=True, help="the arthrosim binary")
    ap.add_argument("--seconds", type=float, default=30.0, help="session length")
    ap.add_argument("--watch", type=float, default=20.0, help="seconds the browser watches")
    ap.add_argument("--out", default=None, help="folder (default: a new one in /tmp)")
    ap.add_argument("--no-foxglove", action="store_true",
                    help="no Foxglove WebSocket client beside the browser")
    args = ap.parse_args()
    out = args.out or f"/tmp/arthrosim-measure-{os.getpid()}"
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(WORKSPACE, "launch-config/launch/default.toml")) as f:
        text = f.read()
    text = text.replace("http_port = 8080", "http_port = 0").replace("ws_port = 8765", "ws_port = 0")
    launch = os.path.join(out, "launch.toml")
    with open(launch, "w") as f:
        f.write(text)
    session_dir = os.path.join(out, "session")
    load_before = loadavg()
    run = subprocess.Popen(
        [args.arthrosim, "run", launch, "--seconds", str(args.seconds), "--quiet",
         "--out", session_dir, "--session", f"measure-{os.getpid()}"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    result = {"session_dir": session_dir, "load_before": load_before}
    url = viewer_url(os.path.join(session_dir, "logs/viewer.log"), 180)
    if url is None:
        run.kill()
        sys.exit(f"no VIEWER line in {session_dir}/logs/viewer.log")
    ws = None
    with open(os.path.join(session_dir, "logs/viewer.log")) as f:
        for line in f:
            if line.startswith("VIEWER "):
                ws = dict(p.split("=", 1) for p in line.split()[1:])["ws"]
    # A Foxglove client beside the browser (the lab's other watcher), for its latency.
    fox = subprocess.Popen(
        [sys.executable, os.path.join(HERE, "foxglove_check.py"), "--ws", ws,
         "--seconds", str(args.watch), "--session-dir", session_dir],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) if not args.no_foxglove else None
    page = subprocess.run(
        [sys.executable, os.path.join(HERE, "page_check.py"), "--url", url,
         "--seconds", str(args.watch), "--screenshot", os.path.join(out, "viewer.png")],
        capture_output=True, text=True)
    result["load_during"] = loadavg()
    session_log, _ = run.communicate()
    result["load_after"] = loadavg()
    ok = run.returncode == 0 and page.returncode == 0
    if fox is not None:
        fox_out, fox_err = fox.communicate()
        try:
            f = json.loads(fox_out.strip().splitlines()[-1])
            result["foxglove"] = {k: f.get(k) for k in ("rates_hz", "latency_ms", "failures")}
        except (IndexError, ValueError):
            ok = False
            result["foxglove_error"] = (fox_out + fox_err)[-2000:]
    try:
        p = json.loads(page.stdout.strip().splitlines()[-1])
        result["browser"] = p.get("watch")
        result["browser_first_frame_s"] = p.get("first_frame_s")
        result["vertices"] = int(p["status"]["vertices"])
    except (IndexError, KeyError, ValueError, TypeError):
        ok = False
        result["browser_error"] = (page.stdout + page.stderr)[-2000:]
    try:
        with open(os.path.join(session_dir, "summary.json")) as f:
            summary = json.load(f)
        s = summary["summary"]
        result["haptic"] = {"hz": s.get("haptic_hz"), "ticks": s.get("haptic_ticks"),
                            "frames_missed": summary.get("frames_missed")}
        result["physics_hz"] = s.get("physics_hz")
    except (FileNotFoundError, KeyError, ValueError):
        ok = False
        result["session_log"] = session_log[-2000:]
    try:
        with open(os.path.join(session_dir, "haptic-stats.json")) as f:
            hs = json.load(f)
        result.setdefault("haptic", {}).update(
            overruns=hs.get("overruns"), period_err_p99_us=hs.get("period_err_p99_us"),
            period_err_max_us=hs.get("period_err_max_us"))
    except (FileNotFoundError, ValueError):
        pass
    bridged = tagged_json(os.path.join(session_dir, "logs/bridge.log"), "BRIDGED")
    if bridged:
        w = bridged["topics"].get("device/wrench", {})
        result["bridge"] = {
            "seconds": round(bridged["seconds"], 2),
            "device_states_read": bridged["device_states"],
            "device_wrench_published": w.get("published"),
            "device_wrench_hz": round(w.get("published_hz", 0.0), 1),
            "dropped": bridged["dropped"],
        }
    recorded = tagged_json(os.path.join(session_dir, "logs/recorder.log"), "RECORDED")
    if recorded:
        result["recorder"] = {k: recorded.get(k) for k in (
            "device_states", "device_states_dropped", "contact_frames", "contact_frames_dropped")}
    viewed = tagged_json(os.path.join(session_dir, "logs/viewer.log"), "VIEWED")
    if viewed:
        result["viewer"] = viewed
    result["ok"] = ok
    print(json.dumps(result))
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
