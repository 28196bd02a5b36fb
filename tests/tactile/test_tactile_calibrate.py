"""Device LUT calibration: from a recording through the sensor's decoder, and the CLI."""

from __future__ import annotations

import numpy as np
import pytest
from tac_fakes import GAIN_DN, block_profile, make_registry

from thintact_sdk.apps.cli.main import main
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.formats.recording import RecordingWriter
from thintact_sdk.tactile import Sphere, TactileSimulator, random_ball_presses
from thintact_sdk.tactile.calibration.device import calibrate_recording
from thintact_sdk.tactile.interpretation.interpreter import colour_change


def _measurement(scene: np.ndarray) -> np.ndarray:
    up = np.kron(scene, np.ones((2, 2, 1), np.float32))
    return np.round(64.0 + GAIN_DN * up).astype(np.uint16)


def test_lut_from_a_recording_of_ball_presses(tmp_path):
    profile = block_profile()
    sim = TactileSimulator.for_profile(profile)
    rec = RecordingWriter(tmp_path / "rec", profile)
    rec.add(_measurement(sim.flat().scene), label="reference")
    for scene, press in random_ball_presses(profile, count=8, seed=5):
        rec.add(_measurement(scene.scene), label="press", **press)
    sensor = Sensor(profile, registry=make_registry())
    done = []
    lut = calibrate_recording(sensor, tmp_path / "rec", progress=lambda i, n: done.append(i))
    assert done == list(range(1, 9))
    assert lut.meta["source"] == "recording" and lut.meta["slopes_from"] == "ball model"
    test = sim.press(Sphere(2.0), 0.7, (1.0, -1.0))
    gx, gy = lut.lookup(colour_change(test.scene, sim.flat().scene, None, 1.0, 1.0))
    inside = test.depth_mm > 0.2
    err = np.hypot(gx - test.grad_x, gy - test.grad_y)[inside]
    scale = np.hypot(test.grad_x, test.grad_y)[inside]
    assert float(np.sqrt(np.mean(err**2))) < 0.35 * float(np.sqrt(np.mean(scale**2)))


def test_cli_refuses_bad_arguments_in_one_line(capsys):
    rc = main(["calibrate-tactile", "--profile", "virtual-finger", "--presses", "0"])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--presses" in err[0]


def test_cli_unknown_profile(capsys):
    assert main(["calibrate-tactile", "--profile", "no-such-device"]) == 2
    assert "no profile named" in capsys.readouterr().err


@pytest.mark.slow
def test_cli_calibrates_the_virtual_finger(tmp_path, monkeypatch, capsys):
    from thintact_sdk.device.registry import get_registry
    from thintact_sdk.errors import CalibrationError
    from thintact_sdk.formats.profiles import load_profile

    prof = load_profile("virtual-finger")
    try:
        get_registry().create("decoder", prof.decoder.plugin, prof, prof.decoder.settings)
    except CalibrationError as err:
        pytest.skip(f"no decoder for the virtual finger: {err}")
    monkeypatch.setenv("THINTACT_CALIBRATION_PATH", str(tmp_path))
    out = tmp_path / "lut.npz"
    rc = main(["calibrate-tactile", "--profile", "virtual-finger", "--presses", "6",
               "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert out.is_file() and out.with_suffix(".json").is_file()
