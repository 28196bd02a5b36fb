"""The viewer's record and snapshot buttons and several sensors on one page (issue 33):
the files written, the token they need, and the page's groups. Synthetic sensors (no
decoding) keep it fast; the CLI test runs two virtual fingers."""

from __future__ import annotations

import json
import re
import time

import cv2
import numpy as np
import pytest
from viewer_kit import FramesSensor, http

from thintact_sdk.apps.viewer import LiveView, ViewerServer
from thintact_sdk.apps.viewer.server import TOKEN_HEADER
from thintact_sdk.formats.recording import Recording


def _wait_frames(server: ViewerServer, sensor: int, frames: int) -> None:
    deadline = time.monotonic() + 60  # a bound on a hang, not a performance figure
    while time.monotonic() < deadline:
        stats = json.loads(http(server.port, "GET", f"/stats.json?sensor={sensor}")[1].split(b"\r\n\r\n", 1)[1])
        if (stats["frame_id"] or 0) >= frames:
            return
        time.sleep(0.05)
    raise AssertionError(f"sensor {sensor} made no {frames} frames")


def _post(server: ViewerServer, path: str, token: bool = True) -> tuple[int | None, dict]:
    status, reply = http(server.port, "POST", path, {TOKEN_HEADER: server.token} if token else {})
    body = reply.split(b"\r\n\r\n", 1)[1]
    try:
        return status, json.loads(body)
    except ValueError:
        return status, {"text": body.decode()}


@pytest.fixture()
def two(tmp_path):
    lives = [LiveView(FramesSensor(), title=f"finger {k}", out=tmp_path / "out", label=f"f{k}")  # type: ignore[arg-type]
             for k in range(2)]
    with ViewerServer(port=0) as server:
        server.start(lives)
        yield server, lives, tmp_path / "out"
    assert not server.internal_errors


def test_page_has_one_group_per_sensor(two):
    server, _, _ = two
    status, reply = http(server.port, "GET", "/")
    assert status == 200
    for k in range(2):
        for element in (f'id="live-{k}" src="/frame.jpg?sensor={k}"', f'id="reset-{k}"',
                        f'id="snapshot-{k}"', f'id="record-{k}"', f"finger {k}"):
            assert element.encode() in reply
    assert b'id="live-2"' not in reply
    _wait_frames(server, 1, 2)
    for k in range(2):
        status, reply = http(server.port, "GET", f"/frame.jpg?sensor={k}")
        assert status == 200
        jpeg = reply.split(b"\r\n\r\n", 1)[1]
        assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR) is not None
    for bad in ("2", "-1", "x", "99999", "0x1", "%EF%BC%91"):
        assert http(server.port, "GET", f"/frame.jpg?sensor={bad}")[0] == 404
        assert _post(server, f"/snapshot?sensor={bad}")[0] == 404


def test_snapshot_writes_the_reconstruction_png_and_the_depth(two):
    server, lives, out = two
    assert _post(server, "/snapshot?sensor=1", token=False)[0] == 403
    assert not out.exists()
    _wait_frames(server, 1, 1)
    status, body = _post(server, "/snapshot?sensor=1")
    assert status == 200, body
    png, npy = (p for p in map(__import__("pathlib").Path, body["files"]))
    assert png.parent == out and png.name.startswith("snapshot-f1-") and png.name.endswith("-image.png")
    assert npy.name == png.name.replace("-image.png", "-depth.npy")
    image = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    assert image.shape == (100, 128, 3) and image.dtype == np.uint8
    assert image[50, 60].tolist() == [191, 191, 191] and image[0, 0].tolist() == [64, 64, 64]
    depth = np.load(npy, allow_pickle=False)
    assert depth.dtype == np.float32 and depth.shape == (100, 128) and depth[50, 60] == 0.5
    status, again = _post(server, "/snapshot?sensor=1")  # never overwrites
    assert status == 200 and set(again["files"]).isdisjoint(body["files"])
    assert len(list(out.iterdir())) == 4


def test_record_writes_a_replayable_recording_of_the_live_frames(two):
    server, lives, out = two
    assert _post(server, "/record/start?sensor=0", token=False)[0] == 403
    status, started = _post(server, "/record/start?sensor=0")
    assert status == 200 and started["active"]
    assert _post(server, "/record/start?sensor=0")[0] == 409  # already recording
    first = lives[0].stats()["frame_id"] or 0
    _wait_frames(server, 0, first + 5)
    stats = lives[0].stats()["recording"]
    assert stats["active"] and stats["frames"] >= 1 and stats["path"] == started["path"]
    status, stopped = _post(server, "/record/stop?sensor=0")
    assert status == 200 and stopped["path"] == started["path"] and stopped["frames"] >= 3
    rec = Recording(stopped["path"])
    assert len(rec) == stopped["frames"]
    ids = [fr.extra["frame_id"] for fr in rec.frames]
    assert ids == list(range(ids[0], ids[0] + len(ids)))  # every live frame, in order
    assert rec.measurement(0).shape == (256, 320, 3)
    assert all("raw" in fr.extra for fr in rec.frames)
    time.sleep(0.2)
    assert len(Recording(stopped["path"])) == stopped["frames"]  # nothing after stop
    assert _post(server, "/record/stop?sensor=0")[1] == {"path": None, "frames": 0, "active": False}
    assert lives[1].recording() is None  # the other sensor was not recording


def test_snapshot_before_the_first_frame_and_an_unwritable_output_are_409(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    live = LiveView(FramesSensor(fps=0.5), out=blocker / "sub")  # type: ignore[arg-type]
    with ViewerServer(port=0) as server:
        server.start(live)
        status, body = _post(server, "/snapshot")
        assert status == 409 and "no frame yet" in body["error"]
        status, body = _post(server, "/record/start")
        assert status == 409 and "cannot create" in body["error"]
    assert not server.internal_errors


def test_stopping_the_viewer_closes_a_running_recording(tmp_path):
    live = LiveView(FramesSensor(), out=tmp_path)  # type: ignore[arg-type]
    with ViewerServer(port=0) as server:
        server.start(live)
        path = live.start_recording()
        _wait_frames(server, 0, 3)
    frames = len(Recording(path))
    assert frames >= 1 and live.recording()["active"] is False
    assert re.fullmatch(r"recording-virtual-finger-\d{8}-\d{6}", path.name)
