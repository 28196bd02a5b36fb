"""The viewer's frame rate and latency as a browser sees them.

Runs ``thintact view``'s server in-process on the virtual finger (a ball pressed into the
membrane, moving each frame), pulls frames for ``--seconds`` with one client doing what the
page does (``/frame.jpg?after=SEQ`` long-poll), and prints the sensor rate, the served rate,
the median latency from the camera timestamp to the frame leaving the server, and the
median time to render and JPEG-encode one dashboard.

Usage: ``python tools/bench_viewer.py [--profile virtual-finger] [--seconds 20] [--fps 30]``
"""

from __future__ import annotations

import argparse
import os
import threading
import time
import urllib.request
import uuid

import numpy as np

import thintact_sdk as thintact
from thintact_sdk.apps.viewer import LiveView, ViewerServer
from thintact_sdk.apps.viewer.panels import encode_jpeg, render_dashboard
from thintact_sdk.tactile import Sphere, TactileSimulator
from thintact_sdk.tactile.calibration.device import scene_slot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="virtual-finger")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--fps", type=float, default=30.0, help="virtual camera rate (0: unpaced)")
    args = ap.parse_args()
    settings = {"slot": f"bench-{uuid.uuid4().hex[:6]}", "fps": args.fps}
    with thintact.open(args.profile, camera_settings=settings) as finger:
        slot = scene_slot(finger)
        sim = TactileSimulator.for_profile(finger.profile)
        slot.set(sim.flat().scene)
        presses = [sim.press(Sphere(2.0), 0.6, (x, 0.0), 0.0, shear_mm=(0.1, 0.0)).scene
                   for x in np.linspace(-2.0, 2.0, 5)]
        live = LiveView(finger)
        with ViewerServer(port=0) as server:
            server.start(live)
            first = live.wait_frame(-1, 120.0)
            assert first is not None, live.error
            stop = threading.Event()

            def move() -> None:
                k = 0
                while not stop.wait(0.2):
                    slot.set(presses[k % len(presses)])
                    k += 1

            mover = threading.Thread(target=move, daemon=True)
            mover.start()
            seq, received, t0 = first.seq, 0, time.monotonic()
            while time.monotonic() - t0 < args.seconds:
                with urllib.request.urlopen(f"{server.url}frame.jpg?after={seq}", timeout=30) as r:
                    seq = int(r.headers["X-Frame-Seq"])
                    r.read()
                    received += 1
            stop.set()
            stats = live.stats()
        slot.set(None)
        # render + encode cost on the last frame's data, outside the loop
        raw = finger.read_raw()
        frame = finger.process(raw)
        times = []
        for _ in range(10):
            t = time.perf_counter()
            encode_jpeg(render_dashboard(raw, frame, finger.profile, live.rates(), "bench"))
            times.append(time.perf_counter() - t)
    print(f"{args.profile}, camera {args.fps:g} fps, {args.seconds:g} s, load "
          f"{os.getloadavg()[0]:.2f}, {os.cpu_count()} cpus")
    print(f"client received {received} frames ({received / args.seconds:.1f} fps)")
    print(f"sensor {stats['sensor_fps']} fps, served {stats['served_fps']} fps, latency "
          f"{stats['latency_ms']} ms (camera stamp -> served, median), processing "
          f"{stats['processing_ms']} ms, render+JPEG {np.median(times) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
