"""thintact.open_group: time pairing, skew bound, stalled / unplugged / ended members,
software trigger."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
from grp_fakes import scripted_sensor

import thintact_sdk as thintact
from thintact_sdk.device.group import SensorGroup
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import (
    DeviceError,
    DeviceLostError,
    EndOfStreamError,
    ThinTactError,
    UnsupportedFeatureError,
)
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.frames import TactileFrame


def _group(*sensors, **options):
    options.setdefault("process", False)
    return thintact.open_group(list(sensors), **options)


def test_two_fingers_are_paired_within_the_skew_bound():
    with _group(scripted_sensor(fps=100), scripted_sensor(fps=100), names=["left", "right"],
                max_skew_ms=8.0) as g:
        pairs = list(g.stream(max_frames=30))
        status = g.status()
    assert [p.index for p in pairs] == list(range(30))
    assert all(p.complete and set(p.frames) == {"left", "right"} for p in pairs)
    assert max(p.skew_ms for p in pairs) <= 8.0
    stamps = [p.timestamp_ns for p in pairs]
    assert stamps == sorted(stamps)
    assert {s.state for s in status.values()} == {"running"}
    assert {s.state for s in g.status().values()} == {"closed"}
    for s in status.values():
        assert s.delivered == 30 and s.captured >= 30 and s.stalls == 0
    assert g.skew_summary()["pairs"] == 30


def test_frames_farther_apart_than_max_skew_are_never_paired():
    # synthetic clocks: right's frames lie 4 ms after left's, both at 100 fps
    left = scripted_sensor(fps=100, synthetic=True)
    right = scripted_sensor(fps=100, synthetic=True, offset_ms=4.0)
    with _group(left, right, names=["l", "r"], max_skew_ms=5.0) as g:
        pairs = list(g.stream(max_frames=10))
    assert all(abs(p.skew_ms - 4.0) < 1e-6 for p in pairs)
    with _group(scripted_sensor(fps=100, synthetic=True),
                scripted_sensor(fps=100, synthetic=True, offset_ms=4.0),
                names=["l", "r"], max_skew_ms=3.0, startup_s=0.1) as g:
        with pytest.raises(DeviceError, match="no paired frame"):
            g.read(timeout_s=0.3)
        st = g.status()
    assert st["l"].unpaired > 0 and st["l"].delivered == 0


def test_default_names_and_bad_arguments():
    g = SensorGroup([scripted_sensor(), scripted_sensor()], process=False)
    assert g.names == ["scripted", "scripted#2"]
    with pytest.raises(ThinTactError, match="names must differ"):
        SensorGroup([scripted_sensor(), scripted_sensor()], names=["a", "a"])
    with pytest.raises(ThinTactError, match="at least one"):
        SensorGroup([])
    with pytest.raises(DeviceError, match="not open"):
        g.read()


def test_a_stalled_member_is_reported_and_the_other_keeps_running():
    stall = threading.Event()
    with _group(scripted_sensor(fps=100), scripted_sensor(fps=100, stall=stall),
                names=["a", "b"], stall_after_s=0.2) as g:
        assert g.read().complete
        stall.set()
        t0 = time.monotonic()
        while True:
            p = g.read(timeout_s=1.0)
            if p.missing:
                break
            assert time.monotonic() - t0 < 1.0
        assert p.missing == {"b": "stalled"} and p.frames["b"] is None
        assert p.frames["a"] is not None
        lone = [g.read(timeout_s=1.0) for _ in range(10)]  # 'a' alone, at its own rate
        assert all(q.missing == {"b": "stalled"} for q in lone)
        st = g.status()
        assert st["b"].state == "stalled" and st["b"].stalls == 1 and "scripted stall" in st["b"].error
        assert st["a"].state == "running"
        stall.clear()  # it comes back: pairs are complete again
        t0 = time.monotonic()
        while not g.read(timeout_s=1.0).complete:
            assert time.monotonic() - t0 < 2.0
        assert g.status()["b"].state == "running"


def test_an_unplugged_member_is_reported_and_the_other_keeps_running():
    with _group(scripted_sensor(fps=100), scripted_sensor(fps=100, lose_after=5),
                names=["a", "b"]) as g:
        pairs = [g.read() for _ in range(20)]
        st = g.status()
    assert pairs[0].complete and pairs[-1].missing == {"b": "lost"}
    assert all(p.frames["a"] is not None for p in pairs)
    assert st["b"].state == "lost" and "DeviceLostError: scripted unplug" in st["b"].error
    assert st["b"].delivered <= 5


def test_the_group_raises_only_when_no_member_is_left():
    with _group(scripted_sensor(fps=100, lose_after=3), scripted_sensor(fps=100, end_after=3),
                names=["a", "b"]) as g:
        with pytest.raises(DeviceLostError, match=r"a: lost .*b: ended"):
            for _ in range(100):
                g.read()
    with _group(scripted_sensor(fps=100, end_after=2)) as g:
        with pytest.raises(EndOfStreamError, match="every member"):
            for _ in range(100):
                g.read()


def test_software_trigger_fires_every_camera_together():
    a = scripted_sensor("grp-trigger-cam", fps=1000)
    b = scripted_sensor("grp-trigger-cam", fps=1000)
    with _group(a, b, names=["a", "b"], trigger="software", trigger_fps=40.0,
                max_skew_ms=5.0) as g:
        cams = (a.camera, b.camera)
        assert cams[0].source == "Software" and cams[1].source == "Software"
        pairs = list(g.stream(max_frames=12))
        fired = (cams[0].triggers, cams[1].triggers)
    assert all(p.complete for p in pairs)
    # one frame per trigger: consecutive pairs are one trigger period (25 ms) apart
    gaps_ms = np.diff([p.timestamp_ns for p in pairs]) / 1e6
    assert np.median(gaps_ms) == pytest.approx(25.0, abs=6.0)
    assert abs(fired[0] - fired[1]) <= 1
    assert cams[0].source is None and cams[1].source is None  # back to free running


def test_trigger_on_a_camera_without_one_names_the_member():
    with pytest.raises(UnsupportedFeatureError, match="member 'plain'.*has no trigger"):
        _group(scripted_sensor("grp-trigger-cam"), scripted_sensor(),
               names=["trig", "plain"], trigger="hardware")


@pytest.mark.slow
def test_group_of_tactile_frames_from_two_virtual_fingers():
    # each finger's first frame calibrates its simulated LUT: tens of seconds on 2 cores
    with thintact.open_group(["virtual-finger", "virtual-finger"],
                             sensor_options={"camera_settings": {"fps": 20.0}},
                             max_skew_ms=60.0, startup_s=120.0) as g:
        pair = g.read(timeout_s=5.0)
    left, right = pair.frames["virtual-finger"], pair.frames["virtual-finger#2"]
    assert left is not None and right is not None
    assert left.image.shape == right.image.shape and left.depth_mm.ndim == 2


def test_the_group_closes_what_it_opened_and_only_that():
    mine, theirs = scripted_sensor(), scripted_sensor().open()
    with _group(mine, theirs, names=["mine", "theirs"]) as g:
        g.read()
    assert not mine.is_open and theirs.is_open
    theirs.close()


def test_two_lens_fingers_give_paired_tactile_frames(tmp_path):
    import cv2

    data = Path(thintact.__file__).parent / "data" / "gelsight" / "gelsight_ball_presses.npz"
    with np.load(data, allow_pickle=False) as z:
        frames = [z["f0"]] + list(z["imgs"][:3])
    sensors = []
    for side in ("left", "right"):
        folder = tmp_path / side
        folder.mkdir()
        for i, rgb in enumerate(frames):
            big = np.repeat(np.repeat(rgb, 2, axis=0), 2, axis=1)[..., ::-1]
            cv2.imwrite(str(folder / f"img_{i:04d}.png"), np.ascontiguousarray(big))
        sensors.append(Sensor(load_profile("gelsight-mini"), camera_settings={
            "device": str(folder / "img_%04d.png"), "fps": 30.0, "loop": True}))
    with thintact.open_group(sensors, names=["left", "right"], max_skew_ms=20.0) as g:
        pairs = list(g.stream(max_frames=8))
    assert all(p.complete and p.skew_ms <= 20.0 for p in pairs)
    for p in pairs:
        left, right = p.frames["left"], p.frames["right"]
        assert isinstance(left, TactileFrame) and isinstance(right, TactileFrame)
        assert left.depth_mm.shape == (120, 160)
    assert any(p.frames["left"].contact for p in pairs)


def test_a_member_silent_from_the_start_is_stalled_after_startup_s():
    silent = threading.Event()
    silent.set()
    with _group(scripted_sensor(fps=100), scripted_sensor(fps=100, stall=silent),
                names=["a", "b"], startup_s=0.3) as g:
        t0 = time.monotonic()
        pair = g.read(timeout_s=0.1)  # waits up to startup_s for b's first frame, not longer
        waited = time.monotonic() - t0
        st = g.status()["b"]
    assert pair.missing == {"b": "stalled"} and pair.frames["a"] is not None
    assert 0.25 < waited < 1.5
    assert st.captured == 0 and st.stalls == 1
