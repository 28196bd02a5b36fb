"""Kill the wizard with SIGKILL mid-run, run it again: every frame is there exactly once and
the calibration equals an uninterrupted run's (virtual-mini's optics with a 2× coarser scene
grid to keep the captures short; noiseless virtual camera so runs compare exactly). Only the
killed run is a process of its own; the uninterrupted and the resumed runs are the same
``thintact calibrate`` command called in this process (no interpreter start-up)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.apps.cli.main import main
from thintact_sdk.calibration.plan import build_plan
from thintact_sdk.formats.profiles import Profile, load_profile, write_profile
from thintact_sdk.formats.recording import Recording
from thintact_sdk.reconstruction.bundle import CalibrationBundle

pytest.importorskip("thintact_virtual.bench", reason="virtual sensor plugin not installed")


def _profile(tmp_path: Path) -> Path:
    d = load_profile("virtual-mini").contract_dict()
    d["name"] = "virtual-mini-coarse"
    d["scene"] = {"rows": 25, "cols": 32, "pixel_pitch_um": 63.0}
    d["display"] = {"plugin": "virtual", "pixel_pitch_um": 63.0, "settle_s": 0.0}
    return write_profile(Profile.model_validate(d), tmp_path / "virtual-mini-coarse.json")


def _cmd(out: Path) -> list[str]:
    return [
        sys.executable, "-m", "thintact_sdk.apps.cli.main", "calibrate", "--profile", "virtual-mini-coarse.json",
        "--out", str(out), "--frames", "1", "--flush", "0", "--camera-set", "fps=0",
        "--camera-set", "noise=false", "--filter-steps", "0", "--no-progress",
    ]


def _frames(capture: Path) -> int:
    try:
        return len(json.loads((capture / "manifest.json").read_text())["frames"])
    except (OSError, ValueError, KeyError):
        return 0


def test_sigkill_then_resume_loses_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    env = {**os.environ, "PYTHONHASHSEED": "0"}
    plan = [s.label for s in build_plan(load_profile(_profile(tmp_path)))]
    monkeypatch.chdir(tmp_path)
    assert main(_cmd(tmp_path / "a")[3:]) in (0, 1)
    proc = subprocess.Popen(_cmd(tmp_path / "b"), cwd=tmp_path, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while _frames(tmp_path / "b" / "capture") < 30 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    killed_at = _frames(tmp_path / "b" / "capture")
    assert 30 <= killed_at < len(plan), "the run was not killed mid-capture"
    assert not (tmp_path / "b" / "calibration.json").exists()
    assert main(_cmd(tmp_path / "b")[3:]) in (0, 1)
    rec = Recording(tmp_path / "b" / "capture")
    labels = [f.label for f in rec.frames]
    assert labels == plan  # every pattern exactly once, in order
    files = sorted(p.name for p in (tmp_path / "b" / "capture" / "measurements").iterdir())
    assert files == sorted(Path(f.measurement).name for f in rec.frames)  # no stray or partial files
    ref = Recording(tmp_path / "a" / "capture")
    for i in range(len(rec)):
        np.testing.assert_array_equal(rec.measurement(i), ref.measurement(i))
    a = CalibrationBundle.load(tmp_path / "a").system_matrices
    b = CalibrationBundle.load(tmp_path / "b").system_matrices
    for key in ("Po", "Qo", "Pc", "Qc"):
        np.testing.assert_allclose(getattr(b, key), getattr(a, key), rtol=1e-6, atol=1e-6)
