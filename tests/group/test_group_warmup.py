"""open_group warms its members up before pairing; skew statistics count complete pairs only."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest
from grp_fakes import REGISTRY

import thintact_sdk as thintact
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import CameraConfig, load_profile
from thintact_sdk.frames import RawFrame

COLD_FIRST_FRAME_S = 0.8
"""What the first processed frame of a member that was not warmed up costs (the decoder build)."""


class ColdSensor(Sensor):
    """A scripted sensor whose first ``process`` builds its 'decoder' (sleeps) unless
    :meth:`warm_up` ran; ``process`` hands the raw frame back."""

    log: list[tuple[str, str, float]] = []
    lock = threading.Lock()

    def __init__(self, label: str, fail: bool = False, **settings: Any) -> None:
        base = load_profile("virtual-mini")
        prof = base.model_copy(update={"name": "cold",
                                       "camera": CameraConfig(plugin="grp-test-cam", settings={})})
        super().__init__(prof, registry=REGISTRY, camera_settings=settings, read_timeout_s=0.1)
        self.label, self.fail, self.warm_calls = label, fail, 0

    def _note(self, what: str) -> None:
        with self.lock:
            self.log.append((self.label, what, time.monotonic()))

    def warm_up(self) -> float:
        self.warm_calls += 1
        self._note("warm-start")
        if self.fail:
            raise CalibrationError("no calibration bundle for 'cold'")
        time.sleep(0.2)
        self.decode_ms = 1.0
        self._note("warm-end")
        return 0.2

    def process(self, raw: RawFrame) -> RawFrame:  # type: ignore[override]
        if self.decode_ms is None:
            time.sleep(COLD_FIRST_FRAME_S)
            self.decode_ms = 1.0
        return raw


def _pairs(warm_up: bool, n: int = 6) -> tuple[list[Any], dict[str, float], ColdSensor]:
    fast, cold = ColdSensor("fast", fps=100), ColdSensor("cold", fps=100)
    fast.decode_ms = 1.0  # already warm: the group must not warm it again
    with thintact.open_group([fast, cold], names=["fast", "cold"], startup_s=0.3,
                             stall_after_s=0.3, max_skew_ms=15.0, warm_up=warm_up) as g:
        pairs = list(g.stream(max_frames=n, timeout_s=3.0))
        summary = g.skew_summary()
    assert fast.warm_calls == 0
    return pairs, summary, cold


def test_members_are_warmed_up_before_pairing_so_the_first_pairs_are_complete() -> None:
    pairs, summary, cold = _pairs(warm_up=True)
    assert cold.warm_calls == 1
    assert [p.missing for p in pairs] == [{}] * len(pairs)
    assert all(p.complete and p.skew_ms <= 15.0 for p in pairs)
    assert summary["pairs"] == len(pairs) and summary["incomplete"] == 0


def test_without_warm_up_the_cold_member_is_stalled_and_its_pairs_are_not_counted_as_skew() -> None:
    pairs, summary, cold = _pairs(warm_up=False)
    assert cold.warm_calls == 0
    incomplete = [p for p in pairs if not p.complete]
    assert incomplete and incomplete[0].missing == {"cold": "stalled"}
    assert all(p.skew_ns == 0 for p in incomplete)
    assert summary["incomplete"] == len(incomplete)
    assert summary["pairs"] == len(pairs) - len(incomplete)
    complete = [p.skew_ms for p in pairs if p.complete]
    if complete:
        assert summary["max_ms"] == pytest.approx(max(complete))
    else:
        assert summary["pairs"] == 0


def test_members_warm_up_one_after_the_other() -> None:
    ColdSensor.log = []
    a, b = ColdSensor("a", fps=100), ColdSensor("b", fps=100)
    with thintact.open_group([a, b], names=["a", "b"]) as g:
        g.read(timeout_s=3.0)
        took = dict(g.warm_up_s)
    events = [(who, what) for who, what, _ in ColdSensor.log]
    assert events == [("a", "warm-start"), ("a", "warm-end"), ("b", "warm-start"), ("b", "warm-end")]
    assert took == {"a": 0.2, "b": 0.2}


def test_raw_groups_warm_no_decoder() -> None:
    a, b = ColdSensor("a", fps=100), ColdSensor("b", fps=100)
    with thintact.open_group([a, b], names=["a", "b"], process=False) as g:
        g.read(timeout_s=3.0)
    assert a.warm_calls == b.warm_calls == 0


def test_a_failed_warm_up_names_the_member_and_closes_what_the_group_opened() -> None:
    ok, bad = ColdSensor("ok", fps=100), ColdSensor("bad", fail=True, fps=100)
    with pytest.raises(CalibrationError, match="group member 'right': warm-up failed: no calibration"):
        thintact.open_group([ok, bad], names=["left", "right"])
    assert not ok.is_open and not bad.is_open


def test_a_slow_member_is_not_a_stalled_one() -> None:
    # 4 frames/s: every interval is longer than stall_after_s, but the member keeps its pace
    fast, slow = ColdSensor("fast", fps=100), ColdSensor("slow", fps=4)
    with thintact.open_group([fast, slow], names=["fast", "slow"], stall_after_s=0.1,
                             max_skew_ms=15.0, process=False) as g:
        pairs = list(g.stream(max_frames=4, timeout_s=3.0))
        status = g.status()
    assert all(p.complete for p in pairs)
    assert status["slow"].stalls == 0 and status["slow"].state == "running"


def test_the_virtual_camera_renders_its_cycle_ahead_and_then_shows_it_from_the_start() -> None:
    from thintact_sdk.device.cameras import create_camera
    from thintact_sdk.device.group import WarmableCamera
    from thintact_sdk.device.registry import get_registry

    profile = load_profile("virtual-mini")  # scenes: tactile, a cycle of 9
    cam = create_camera(profile, get_registry(), {"fps": 0})
    cam.open()
    try:
        assert isinstance(cam, WarmableCamera)
        assert cam.warm_up() >= 0.0
        rendered = dict(cam._linear_cache)  # noqa: SLF001 - what the warm-up rendered
        assert sorted(rendered) == [("tactile", k) for k in range(9)]
        sources = [cam.read().meta["scene_source"] for _ in range(10)]
        assert sources == [f"tactile:{k % 9}" for k in range(10)]
        assert all(cam._linear_cache[key] is lin for key, lin in rendered.items())  # noqa: SLF001
    finally:
        cam.close()
