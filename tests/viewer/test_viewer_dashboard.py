"""The viewer's dashboard image and its web server (no browser needed)."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
import uuid

import cv2
import numpy as np
import pytest

import thintact_sdk as thintact
from thintact_sdk.apps.viewer import LiveView, ViewerServer
from thintact_sdk.apps.viewer.panels import Rates, dashboard_size, panel_boxes, render_dashboard
from thintact_sdk.apps.viewer.server import TOKEN_HEADER
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.frames import RawFrame, TactileFrame

ARROW_RGB = np.array([255, 210, 60])


def _frames(contact: bool, shear_mm: float):
    profile = load_profile("virtual-finger")
    rng = np.random.default_rng(0)
    raw = RawFrame(rng.integers(64, 4000, (512, 640), dtype=np.uint16), 1, 7)
    yy, xx = np.mgrid[-2:2:25j, -3:3:25j]
    pos = np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float32)
    depth = np.zeros((100, 128), np.float32)
    depth[40:60, 50:70] = 0.5 if contact else 0.0
    frame = TactileFrame(
        image=rng.random((100, 128, 3), dtype=np.float32), depth_mm=depth,
        marker_positions_mm=pos, marker_displacements_mm=np.tile([shear_mm, 0.0], (len(pos), 1)),
        contact=contact, contact_area_mm2=12.0 if contact else 0.0, timestamp_ns=1, frame_id=7,
        shear_direction_rad=0.0 if shear_mm else float("nan"), latency_ms=50.0,
        force_n=np.array([0.1, 0.0, 2.0]) if contact else None)
    return profile, raw, frame


def _near(panel: np.ndarray, rgb: np.ndarray, tol: int = 30) -> int:
    return int(np.sum(np.all(np.abs(panel.astype(int) - rgb) < tol, axis=2)))


def test_every_panel_shows_something_and_follows_the_frame():
    profile, raw, pressed = _frames(contact=True, shear_mm=0.1)
    _, _, free = _frames(contact=False, shear_mm=0.0)
    rates = Rates(sensor_fps=10.0, served_fps=9.5, latency_ms=80.0, processing_ms=60.0)
    a = render_dashboard(raw, pressed, profile, rates, "test")
    b = render_dashboard(raw, free, profile, rates, "test")
    assert a.shape == (dashboard_size()[1], dashboard_size()[0], 3) and a.dtype == np.uint8
    boxes = panel_boxes()
    for name, (x, y, w, h) in boxes.items():
        assert a[y:y + h, x:x + w].std() > 10, f"panel {name!r} is blank"

    def crop(img, name):
        x, y, w, h = boxes[name]
        return img[y:y + h, x:x + w]

    # displacement arrows only where markers moved; contact banner red vs green
    assert _near(crop(a, "marker displacements"), ARROW_RGB) > 200
    assert _near(crop(b, "marker displacements"), ARROW_RGB) < 20
    assert _near(crop(a, "contact and shear")[12:44], np.array([230, 70, 60])) > 3000
    assert _near(crop(b, "contact and shear")[12:44], np.array([70, 190, 90])) > 3000
    changed = np.abs(crop(a, "depth map").astype(int) - crop(b, "depth map")).max(axis=2) > 50
    assert changed.sum() > 2000  # the 20 x 20 px pressed square, scaled 2.5x


@pytest.fixture
def finger():
    pytest.importorskip("thintact_virtual")
    slot = f"view-{uuid.uuid4().hex[:8]}"
    with thintact.open("virtual-finger", camera_settings={"slot": slot, "fps": 0}) as sensor:
        yield sensor


def _get(url: str, data: bytes | None = None, headers: dict[str, str] | None = None):
    with urllib.request.urlopen(urllib.request.Request(url, data=data, headers=headers or {}),
                                timeout=30) as r:
        return r.status, dict(r.headers), r.read()


def test_server_serves_page_frames_and_stats_on_loopback(finger):
    with ViewerServer(port=0) as server:
        server.start(LiveView(finger))
        assert server.url.startswith("http://127.0.0.1:")
        status, _, page = _get(server.url)
        assert status == 200 and b'id="live-0" src="/frame.jpg?sensor=0"' in page
        status, headers, jpeg = _get(server.url + "frame.jpg")
        first = int(headers["X-Frame-Seq"])
        image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape[:2] == (dashboard_size()[1], dashboard_size()[0])
        _, headers, _ = _get(server.url + f"frame.jpg?after={first}")
        assert int(headers["X-Frame-Seq"]) > first  # waits for the next frame
        _, _, body = _get(server.url + "stats.json")
        stats = json.loads(body)
        assert stats["profile"] == "virtual-finger" and stats["error"] is None
        assert stats["sensor_fps"] > 0 and stats["latency_ms"] > 0
        with pytest.raises(urllib.error.HTTPError, match="403"):
            _get(server.url + "reset", data=b"")  # no token: refused
        assert _get(server.url + "reset", data=b"", headers={TOKEN_HEADER: server.token})[0] == 200
        with pytest.raises(urllib.error.HTTPError, match="404"):
            _get(server.url + "nothing-here")


def test_raw_preview_keeps_the_bayer_phase():
    from thintact_sdk.apps.viewer.panels import preview_mosaic
    from thintact_sdk.pixels.bayer import bin_bayer

    mosaic = np.random.default_rng(1).integers(0, 4096, (2048, 2560), dtype=np.uint16)
    small = preview_mosaic(mosaic, max_cols=320)
    assert small.shape == (512, 640)  # every 4th 2 x 2 cell
    np.testing.assert_array_equal(bin_bayer(small, "GRBG"), bin_bayer(mosaic, "GRBG")[::4, ::4])
    assert preview_mosaic(mosaic[:512, :640], max_cols=320) is not None
    np.testing.assert_array_equal(preview_mosaic(mosaic[:512, :640], 320), mosaic[:512, :640])
