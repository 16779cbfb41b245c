#!/usr/bin/env python3
"""Loads a page in headless Chromium (Debian's chromium-headless-shell, or chromium) through
the DevTools protocol (PyPI `websockets`), waits, reads state from the DOM, and saves a
screenshot that is checked loosely against the expected layout.

  page_check.py --url http://127.0.0.1:8080/ --seconds 5 --screenshot shot.png [--mode viewer|report|answer]

viewer mode: reads #viewer-status's data attributes (frames, vertices, force-n, fps, latency,
painted pixels) twice, a second apart; the layout check finds, in the screenshot, the 3D
view (meniscus-coloured pixels inside the scene box), the force plot (its orange trace or
background inside the plot box) and the side panel (its background colour).
report mode: reads the report's tables and the learning curve's size.
answer mode (--grade G): clicks grade G's button once for each specimen the training offers,
until the page says the training is finished or --seconds pass.
Prints one JSON line; exit 1 when Chromium cannot load the page.
"""
import argparse
import asyncio
import base64
import json
import os
import signal
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
import zlib

import websockets


def find_chromium():
    for name in ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    sys.exit("no Chromium found (apt-get install chromium-headless-shell)")


def decode_png(data):
    """RGBA/RGB 8-bit non-interlaced PNG → (width, height, channels, rows of bytes)."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, w = 8, b"", 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, color, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and interlace == 0 and color in (2, 6), (depth, color, interlace)
            ch = 4 if color == 6 else 3
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    stride = w * ch
    rows, prev, i = [], bytearray(stride), 0
    for _ in range(h):
        f = raw[i]
        line = bytearray(raw[i + 1:i + 1 + stride])
        i += 1 + stride
        for x in range(stride):
            a = line[x - ch] if x >= ch else 0
            b = prev[x]
            c = prev[x - ch] if x >= ch else 0
            if f == 1:
                line[x] = (line[x] + a) & 255
            elif f == 2:
                line[x] = (line[x] + b) & 255
            elif f == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif f == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[x] = (line[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(bytes(line))
        prev = line
    return w, h, ch, rows


def box_colours(png, box, dpr, want, tol=48, step=3):
    """Fraction of sampled pixels in `box` near each wanted colour."""
    w, h, ch, rows = png
    x0, y0 = int(box["x"] * dpr), int(box["y"] * dpr)
    x1, y1 = min(w, int((box["x"] + box["width"]) * dpr)), min(h, int((box["y"] + box["height"]) * dpr))
    counts = {k: 0 for k in want}
    total = 0
    for y in range(max(0, y0), y1, step):
        row = rows[y]
        for x in range(max(0, x0), x1, step):
            r, g, b = row[x * ch], row[x * ch + 1], row[x * ch + 2]
            total += 1
            for k, (cr, cg, cb) in want.items():
                if abs(r - cr) + abs(g - cg) + abs(b - cb) <= tol:
                    counts[k] += 1
    return {k: (v / total if total else 0.0) for k, v in counts.items()}


class Cdp:
    def __init__(self, ws):
        self.ws, self.next_id = ws, 0

    async def call(self, method, **params):
        self.next_id += 1
        my = self.next_id
        await self.ws.send(json.dumps({"id": my, "method": method, "params": params}))
        while True:
            msg = json.loads(await self.ws.recv())
            if msg.get("id") == my:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    async def eval(self, expr):
        r = await self.call("Runtime.evaluate", expression=expr, returnByValue=True, awaitPromise=True)
        return r.get("result", {}).get("value")


STATUS_JS = """(() => { const e = document.getElementById('viewer-status');
  if (!e) return null; const d = {...e.dataset}; d.text = e.textContent; return d; })()"""
RECTS_JS = """(() => { const r = (id) => { const e = document.getElementById(id); if (!e) return null;
  const b = e.getBoundingClientRect(); return {x: b.x, y: b.y, width: b.width, height: b.height}; };
  return {scene: r('scene'), plot: r('plot'), side: r('side'), dpr: window.devicePixelRatio}; })()"""
REPORT_JS = """(() => ({
  trainee: document.getElementById('trainee')?.textContent,
  overall: document.getElementById('overall-accuracy')?.textContent,
  sessions: document.querySelectorAll('#sessions tr').length - 1,
  confusion: [...document.querySelectorAll('#confusion tr')].slice(1).map(
      (tr) => [...tr.querySelectorAll('td')].map((td) => +td.textContent)),
  curve: (() => { const s = document.getElementById('learning-curve'); if (!s) return null;
      const b = s.getBoundingClientRect(); return {width: b.width, height: b.height,
      points: s.querySelectorAll('circle').length}; })(),
}))()"""


def sample(t, status):
    """One reading of #viewer-status: seconds since navigation, frames, fps, latency ms."""
    lat = status.get("latencyMs")
    return {"t": round(t, 3), "frames": int(status.get("frames", 0)),
            "mesh_frames": int(status.get("meshFrames", 0)),
            "fps": float(status.get("fps") or 0),
            "latency_ms": float(lat) if lat else None}


def quantile(values, q):
    v = sorted(values)
    return v[min(len(v) - 1, int(q * len(v)))] if v else None


def watch_summary(series):
    """Rates over the watch from the first reading with frames on: data frames/s (all
    events, and mesh events), the page's render frames/s and its latency (median and p90
    of the readings)."""
    on = [s for s in series if s["frames"] > 0]
    if len(on) < 2 or on[-1]["t"] <= on[0]["t"]:
        return None
    span = on[-1]["t"] - on[0]["t"]
    lat = [s["latency_ms"] for s in on if s["latency_ms"] is not None]
    fps = [s["fps"] for s in on if s["fps"] > 0]
    return {
        "seconds": round(span, 2),
        "frames_per_s": round((on[-1]["frames"] - on[0]["frames"]) / span, 1),
        "mesh_frames_per_s": round((on[-1]["mesh_frames"] - on[0]["mesh_frames"]) / span, 1),
        "render_fps_median": quantile(fps, 0.5),
        "render_fps_min": min(fps) if fps else None,
        "latency_ms_median": quantile(lat, 0.5),
        "latency_ms_p90": quantile(lat, 0.9),
        "readings": len(on),
    }

ANSWER_JS = """(() => { const t = window.arthrosimViewer && window.arthrosimViewer.training;
  if (!t) return null;
  if (t.state === 'probing' && !%(answered)s.includes(t.case)) {
    const b = document.getElementById('answer-%(grade)d');
    if (b && !b.disabled) { b.click(); return {state: t.state, clicked: t.case}; }
  }
  return {state: t.state, case: t.case}; })()"""


async def run(args):
    chromium = find_chromium()
    profile = tempfile.mkdtemp(prefix="arthrosim-chromium-")
    proc = subprocess.Popen([
        chromium, "--headless", "--no-sandbox", "--disable-gpu-sandbox", "--no-first-run",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--use-gl=angle",
        "--remote-debugging-port=0", f"--user-data-dir={profile}",
        f"--window-size={args.width},{args.height}", "about:blank",
    ], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        # Its own process group: Chromium's GPU and renderer children outlive a terminated
        # browser process (four left spinning at ~45% CPU each after a test run).
        start_new_session=True)
    try:
        port_file = os.path.join(profile, "DevToolsActivePort")
        deadline = time.monotonic() + 30
        # Chromium creates the file before it writes the port into it: wait for the port,
        # not for the file (an empty file was read once under load).
        port = None
        while port is None and time.monotonic() < deadline:
            try:
                with open(port_file) as f:
                    words = f.read().split()
                port = int(words[0]) if words else None
            except (FileNotFoundError, ValueError):
                port = None
            if port is None:
                time.sleep(0.1)
        if port is None:
            raise RuntimeError(f"Chromium wrote no DevTools port into {port_file} within 30 s")
        targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list"))
        page = next(t for t in targets if t["type"] == "page")
        async with websockets.connect(page["webSocketDebuggerUrl"], max_size=None) as ws:
            cdp = Cdp(ws)
            await cdp.call("Page.enable")
            await cdp.call("Emulation.setDeviceMetricsOverride", width=args.width,
                           height=args.height, deviceScaleFactor=1, mobile=False)
            t0 = time.monotonic()
            await cdp.call("Page.navigate", url=args.url)
            result = {"url": args.url}
            if args.mode == "viewer":
                first = None
                # Every half second: frames received, the page's render rate and its latency
                # (median over its last 120 state events of receive time − the sample's
                # session stamp), for the watch's rates below.
                series = []
                while time.monotonic() - t0 < args.seconds:
                    await asyncio.sleep(0.5)
                    s = await cdp.eval(STATUS_JS)
                    if s and first is None and int(s.get("frames", 0)) > 0:
                        first = time.monotonic() - t0
                    if s:
                        series.append(sample(time.monotonic() - t0, s))
                a = await cdp.eval(STATUS_JS)
                await asyncio.sleep(1.0)
                b = await cdp.eval(STATUS_JS)
                series.append(sample(time.monotonic() - t0, b))
                result.update(status=b, first_frame_s=first,
                              frames_per_s=(int(b["frames"]) - int(a["frames"])) / 1.0 if a and b else 0,
                              watch=watch_summary(series))
                result["rects"] = await cdp.eval(RECTS_JS)
            elif args.mode == "answer":
                # A trainee on the page: each specimen offered for probing is answered once,
                # with the grade button --grade, until the training is finished.
                answered, state = [], None
                while time.monotonic() - t0 < args.seconds and state != "finished":
                    await asyncio.sleep(0.3)
                    t = await cdp.eval(ANSWER_JS % {"grade": args.grade,
                                                    "answered": json.dumps(answered)})
                    if not t:
                        continue
                    state = t.get("state")
                    if t.get("clicked") is not None:
                        answered.append(t["clicked"])
                result.update(answered=answered, training=state)
            else:
                await asyncio.sleep(args.seconds)
                result["report"] = await cdp.eval(REPORT_JS)
            shot = await cdp.call("Page.captureScreenshot", format="png")
            data = base64.b64decode(shot["data"])
            with open(args.screenshot, "wb") as f:
                f.write(data)
            result["screenshot"] = args.screenshot
            if args.mode == "viewer" and result.get("rects"):
                png = decode_png(data)
                r = result["rects"]
                dpr = r.get("dpr") or 1
                result["layout"] = {
                    "size": [png[0], png[1]],
                    "scene": box_colours(png, r["scene"], dpr, {
                        "background": (0x1b, 0x24, 0x30), "meniscus": (0xd8, 0xb0, 0xa0)}, tol=90),
                    "plot": box_colours(png, r["plot"], dpr, {
                        "background": (0x0b, 0x0f, 0x14), "trace": (0xff, 0xb3, 0x47)}),
                    "side": box_colours(png, r["side"], dpr, {"background": (0x15, 0x1c, 0x25)}),
                }
            return result
    finally:
        group = proc.pid
        try:
            os.killpg(group, signal.SIGTERM)
            proc.wait(timeout=10)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
        # Whatever of the group is left (children ignore or outlive the browser's TERM).
        try:
            os.killpg(group, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
        shutil.rmtree(profile, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--screenshot", required=True)
    ap.add_argument("--mode", choices=["viewer", "report", "answer"], default="viewer")
    ap.add_argument("--grade", type=int, default=0, help="answer mode: the grade clicked")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=800)
    args = ap.parse_args()
    print(json.dumps(asyncio.run(run(args))))


if __name__ == "__main__":
    main()
