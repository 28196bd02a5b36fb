"""Defective slit frames of a calibration recording are refused with the frame named."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rob_kit

from thintact_sdk.apps.cli.main import main
from thintact_sdk.calibration.collect import collect_slits
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.recording import Recording


@pytest.fixture
def slit_recording(tiny: dict[str, Any], tmp_path: Path) -> Path:
    """Two horizontal and two vertical slits of the tiny device, simulated."""
    scenes = np.zeros((4, 10, 12, 3), np.float32)
    scenes[0, 2], scenes[1, 7] = 1.0, 1.0
    scenes[2, :, 3], scenes[3, :, 9] = 1.0, 1.0
    meas = rob_kit.measurements(tiny["profile"], scenes)
    return rob_kit.write_recording(tmp_path / "slits", tiny["profile"], scenes, meas)


def test_the_clean_slits_are_collected(slit_recording: Path) -> None:
    out = collect_slits(Recording(slit_recording))
    assert out.slit_frames == 4


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_nan_or_inf_slit_names_the_frame(slit_recording: Path, tiny: dict, bad: float,
                                           tmp_path: Path, capfd: Any) -> None:
    m = np.load(slit_recording / "measurements" / "002.npy").astype(np.float32)
    m[4, 4, 1] = bad
    np.save(slit_recording / "measurements" / "002.npy", m)
    assert main(["calibrate", "--from-recording", str(slit_recording), "--out", str(tmp_path / "cal"),
                 "--no-progress"]) == 2
    err = capfd.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "frame 2 (f2)" in err and "NaN/Inf" in err, err
    assert "LinAlgError" not in err


@pytest.mark.parametrize("value", [0, 64])
def test_a_dead_slit_names_the_frame(slit_recording: Path, value: int) -> None:
    np.save(slit_recording / "measurements" / "001.npy", np.full((24, 30, 3), value, np.uint16))
    with pytest.raises(CalibrationError, match=rf"slit frame 1 \(f1\) is dead in channel R: every pixel reads {value} DN"):
        collect_slits(Recording(slit_recording))


@pytest.mark.parametrize("exposure", [0, -100.0])
def test_a_non_positive_exposure_names_the_frame(slit_recording: Path, exposure: float,
                                                 tmp_path: Path, capfd: Any) -> None:
    manifest = json.loads((slit_recording / "manifest.json").read_text())
    manifest["frames"][3]["exposure_us"] = exposure
    (slit_recording / "manifest.json").write_text(json.dumps(manifest))
    assert main(["calibrate", "--from-recording", str(slit_recording), "--out", str(tmp_path / "cal"),
                 "--no-progress"]) == 2
    err = capfd.readouterr().err.strip()
    assert "frame 3" in err and "'exposure_us' must be a positive number" in err, err
