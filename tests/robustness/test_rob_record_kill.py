"""Kill ``thintact record`` at random moments (SIGKILL, several trials): the recording stays
readable up to its last complete frame, no temp file breaks a reader, and ``--append``
resumes it (the calibration wizard's equivalent is tests/calibration/test_cal_kill_resume.py)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from thintact_sdk.apps.cli.main import main
from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.recording import Recording

TRIALS = 3


def _cmd(out: Path, frames: int) -> list[str]:
    return [sys.executable, "-m", "thintact_sdk.apps.cli.main", "record", "--profile", "virtual-mini",
            "--frames", str(frames), "--out", str(out), "--set", "fps=0", "--quiet"]


def _listed(out: Path) -> int:
    try:
        return len(json.loads((out / "manifest.json").read_text())["frames"])
    except (OSError, ValueError, KeyError):
        return 0


def _kill_once(out: Path, rng: random.Random) -> int:
    """Start a recording, SIGKILL it a random time after its first frame; frames listed then."""
    proc = subprocess.Popen(_cmd(out, 500), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONHASHSEED": "0"})
    deadline = time.monotonic() + 120
    while _listed(out) < 1 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(rng.uniform(0.0, 1.2))
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, "the recorder ended before it was killed"
    return _listed(out)


def test_sigkill_at_random_points_leaves_a_readable_recording(tmp_path: Path) -> None:
    if "virtual" not in get_registry().components("camera"):
        pytest.skip("virtual camera plugin not installed")
    rng = random.Random(18)
    for trial in range(TRIALS):
        out = tmp_path / f"rec{trial}"
        listed = _kill_once(out, rng)
        assert listed >= 1
        rec = Recording(out)  # the manifest is whole: it is only ever replaced atomically
        assert len(rec) == listed
        rec.check_frames()  # every listed frame is complete and valid
        names = {p.name for p in (out / "measurements").iterdir() if not p.name.endswith(".tmp")}
        assert {Path(f.measurement).name for f in rec.frames} <= names
    # resume the last one: temp files of the kill are removed, frames continue
    assert main(["record", "--profile", "virtual-mini", "--frames", "2", "--out", str(out),
                 "--set", "fps=0", "--quiet", "--append"]) == 0
    rec = Recording(out)
    assert len(rec) == listed + 2
    rec.check_frames()
    assert not list(out.rglob("*.tmp"))


def test_killed_before_the_first_frame_is_a_clean_error(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    (out / "measurements").mkdir(parents=True)
    (out / "measurements" / ".000_frame000000.npy.abc.tmp").write_bytes(b"\x93NUMPY half")
    with pytest.raises(RecordingError, match="no manifest.json"):
        Recording(out)
