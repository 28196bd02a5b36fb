"""The viewer as a person sees it: headless Chromium screenshots of the page while the
virtual finger is pressed at two places. Skipped where Chromium is not installed
(``tools/bootstrap.sh`` installs it on Debian as root)."""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid

import cv2
import numpy as np
import pytest

import thintact_sdk as thintact
from thintact_sdk.apps.viewer import LiveView, ViewerServer
from thintact_sdk.apps.viewer.page import HEADER_PX
from thintact_sdk.apps.viewer.panels import dashboard_size, panel_boxes
from thintact_sdk.tactile import Sphere, TactileSimulator
from thintact_sdk.tactile.calibration.device import scene_slot

BROWSER = shutil.which("chromium") or shutil.which("chromium-browser")


def screenshot(url: str, out, profile_dir) -> np.ndarray:
    """A 1000 × 640 px screenshot of ``url`` by headless Chromium, RGB."""
    width, height = dashboard_size()
    cmd = [BROWSER, "--headless", "--no-sandbox", "--disable-gpu",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--no-first-run", f"--user-data-dir={profile_dir}", "--force-device-scale-factor=1",
           f"--window-size={width + 40},{height + HEADER_PX + 30}", f"--screenshot={out}", url]
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    image = cv2.imread(str(out), cv2.IMREAD_COLOR)
    assert image is not None, f"no screenshot at {out}"
    return image[..., ::-1]


def _panel(shot: np.ndarray, name: str) -> np.ndarray:
    x, y, w, h = panel_boxes()[name]
    return shot[HEADER_PX + y:HEADER_PX + y + h, x:x + w].astype(int)


@pytest.mark.skipif(BROWSER is None, reason="chromium is not installed")
def test_screenshots_show_the_panels_following_the_press(tmp_path):
    pytest.importorskip("thintact_virtual")
    slot_key = f"view-{uuid.uuid4().hex[:8]}"
    with thintact.open("virtual-finger", camera_settings={"slot": slot_key, "fps": 0}) as finger:
        slot = scene_slot(finger)
        sim = TactileSimulator.for_profile(finger.profile)
        slot.set(sim.flat().scene)  # the first frame is the no-contact reference
        live = LiveView(finger)
        shots = []
        with ViewerServer(port=0) as server:
            server.start(live)
            for k, centre in enumerate([(-2.5, -1.5), (2.5, 1.5)]):
                before = live.wait_frame(-1, 120.0)
                assert before is not None, live.error
                slot.set(sim.press(Sphere(2.0), 0.8, centre, 0.0, shear_mm=(0.15, 0.05)).scene)
                pressed = live.wait_frame(live.wait_frame(before.seq, 60.0).seq, 60.0)
                assert pressed is not None and pressed.contact, live.error
                shots.append(screenshot(server.url, tmp_path / f"shot{k}.png", tmp_path / "chromium"))
            stats = live.stats()
        slot.set(None)
    if os.environ.get("THINTACT_KEEP_SCREENSHOTS"):
        for k in range(2):
            shutil.copy(tmp_path / f"shot{k}.png", os.environ["THINTACT_KEEP_SCREENSHOTS"] + f"-{k}.png")
    first, second = shots
    for name in panel_boxes():
        for shot in shots:
            assert _panel(shot, name).std() > 8, f"panel {name!r} is not visible"
    # the press moved from the upper left to the lower right: the depth and marker panels follow
    for name in ("depth map", "reconstruction", "marker displacements"):
        moved = np.abs(_panel(first, name) - _panel(second, name)).max(axis=2) > 40
        assert moved.sum() > 500, f"panel {name!r} did not change between the screenshots"
    depth_a, depth_b = _panel(first, "depth map"), _panel(second, "depth map")
    w = depth_a.shape[1]
    assert depth_a[:, : w // 2].sum() > depth_a[:, w // 2:].sum()  # bright where pressed
    assert depth_b[:, w // 2:].sum() > depth_b[:, : w // 2].sum()
    # the red CONTACT banner is on the page
    banner = _panel(second, "contact and shear")[12:44]
    assert np.sum(np.all(np.abs(banner - [230, 70, 60]) < 40, axis=2)) > 3000
    assert stats["served_fps"] is not None and stats["latency_ms"] > 0


@pytest.mark.skipif(BROWSER is None, reason="chromium is not installed")
def test_page_buttons_work_in_chromium_and_a_foreign_page_cannot_reset(tmp_path):
    """The page's own script sends the token (its reset button works); a page of another
    origin that POSTs to /reset, with or without CORS, changes nothing."""
    import http.server
    import threading
    import time

    from viewer_kit import CountingLive, HeadlessChromium

    evil_dir = tmp_path / "evil"
    evil_dir.mkdir()
    live = CountingLive()
    with ViewerServer(port=0) as server:
        server.start(live)
        (evil_dir / "index.html").write_text(
            "<!doctype html><title>evil</title>")
        evil = http.server.ThreadingHTTPServer(
            ("127.0.0.1", 0), lambda *a: http.server.SimpleHTTPRequestHandler(*a, directory=str(evil_dir)))
        threading.Thread(target=evil.serve_forever, daemon=True).start()
        browser = HeadlessChromium(BROWSER, str(tmp_path / "chromium"))
        try:
            attack = (f"Promise.allSettled([fetch('{server.url}reset', {{method: 'POST', mode: 'no-cors'}}),"
                      f" fetch('{server.url}reset', {{method: 'POST', headers: {{'X-ThinTact-Token': 'x'}}}})"
                      "]).then(() => 'sent')")
            assert browser.evaluate(f"http://127.0.0.1:{evil.server_address[1]}/", attack) == "sent"
            assert live.changes == 0
            clicked = browser.evaluate(server.url, "document.getElementById('reset-0').click(), 'clicked'")
            assert clicked == "clicked"
            deadline = time.monotonic() + 30  # a timeout only: the click's fetch is asynchronous
            while live.changes == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert live.changes == 1
        finally:
            browser.close()
            evil.shutdown()
            evil.server_close()
    assert not server.internal_errors


@pytest.mark.skipif(BROWSER is None, reason="chromium is not installed")
def test_snapshot_and_record_buttons_work_in_chromium(tmp_path):
    """Issue 33: the page's snapshot button writes the PNG and depth; record starts and, on a
    second click, stops a recording of the live frames; the page says where they went."""
    import time

    from viewer_kit import FramesSensor, HeadlessChromium

    from thintact_sdk.formats.recording import Recording

    def until(check, what):
        deadline = time.monotonic() + 30  # a bound on a hang: the clicks' fetches are asynchronous
        while not check():
            assert time.monotonic() < deadline, what
            time.sleep(0.05)

    live = LiveView(FramesSensor(), out=tmp_path / "out", label="finger")
    with ViewerServer(port=0) as server:
        server.start(live)
        until(lambda: live.latest() is not None, "no frame")
        browser = HeadlessChromium(BROWSER, str(tmp_path / "chromium"))
        try:
            click = ("new Promise(ok => {{ document.getElementById('{0}').click(); "
                     "setTimeout(() => ok(document.getElementById('msg-0').textContent), 1500); }})")
            said = browser.evaluate(server.url, click.format("snapshot-0"))
            until(lambda: len(list((tmp_path / "out").glob("snapshot-finger-*"))) == 2, "no snapshot")
            assert said.startswith("saved ") and "-image.png" in said
            said = browser.evaluate(server.url, click.format("record-0") + ".then(m => m + ' | ' + "
                                    "document.getElementById('record-0').className)")
            assert said.startswith("recording into ") and said.endswith("| on")
            until(lambda: (live.recording() or {}).get("frames", 0) >= 3, "no frames recorded")
            said = browser.evaluate(
                server.url, "new Promise(ok => setTimeout(ok, 800)).then(() => " + click.format("record-0") + ")")
            until(lambda: not live.recording()["active"], "recording not stopped")
            assert said.startswith("saved ") and "frames in" in said
        finally:
            browser.close()
    rec = live.recording()
    assert len(Recording(rec["path"])) == rec["frames"] >= 3
    assert not server.internal_errors
