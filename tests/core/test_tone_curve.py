"""Declared tone curves (``sensor.tone_curve``): validation naming the field, exact inverses,
and the capture path (virtual camera → to_measurement) delivering linear DN."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thintact_sdk.device.cameras import open_camera, to_measurement
from thintact_sdk.errors import DeviceError, ProfileError
from thintact_sdk.formats.profiles import (
    Profile,
    load_profile,
    profile_from_dict,
    read_profile_file,
    write_profile,
)
from thintact_sdk.frames import RawFrame
from thintact_sdk.pixels.tone_curve import encode, linearize


def _with_curve(curve: dict[str, Any] | None, **noise: float) -> Profile:
    d = load_profile("virtual-mini").contract_dict()
    d["noise"].update(noise)
    if curve is not None:
        d["sensor"]["tone_curve"] = curve
    return profile_from_dict(d)


def _srgb_table_8bit(black: float, full: float) -> list[float]:
    v = np.arange(256) / 255.0
    lin = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    return (black + full * lin).tolist()


@pytest.mark.parametrize(("curve", "needle"), [
    ({"kind": "gamma"}, "needs 'gamma'"),
    ({"kind": "gamma", "gamma": 0.0}, "gamma"),
    ({"kind": "table", "values": [0.0, 1.0]}, "needs 'bits'"),
    ({"kind": "table", "bits": 2, "values": [0.0, 1.0, 2.0]}, "needs exactly 4"),
    ({"kind": "table", "bits": 2, "values": [0.0, 2.0, 1.0, 3.0]}, "not monotonic, entry 2"),
    ({"kind": "table", "bits": 2, "values": [0.0, 1.0, float("inf"), 3.0]}, "entry 2 is NaN/Inf"),
    ({"kind": "table", "bits": 2, "values": [1.0, 1.0, 1.0, 1.0]}, "constant"),
    ({"kind": "srgb", "bits": 8}, "belong to kind 'table'"),
    ({"kind": "log"}, "kind"),
])
def test_a_bad_curve_is_refused_naming_the_field(curve: dict[str, Any], needle: str) -> None:
    with pytest.raises(ProfileError) as err:
        _with_curve(curve)
    assert "sensor.tone_curve" in str(err.value) and needle in str(err.value)


def test_a_bad_table_file_is_refused_at_load_naming_the_field(tmp_path: Path) -> None:
    prof = _with_curve({"kind": "table", "bits": 3, "file": "tone.csv"})
    write_profile(prof, tmp_path / "p.json")
    with pytest.raises(ProfileError, match=r"sensor\.tone_curve\.file: .*tone\.csv not found"):
        read_profile_file(tmp_path / "p.json")
    (tmp_path / "tone.csv").write_text("0,1,2,3,4,5,6\n")
    with pytest.raises(ProfileError, match=r"sensor\.tone_curve\.file .*7 entries.*needs exactly 8"):
        read_profile_file(tmp_path / "p.json")
    (tmp_path / "tone.csv").write_text("0,1,2,3,4,5,7,6\n")
    with pytest.raises(ProfileError, match=r"sensor\.tone_curve\.file .*not monotonic, entry 7"):
        read_profile_file(tmp_path / "p.json")
    np.save(tmp_path / "tone.npy", np.arange(8.0) ** 2)
    prof = _with_curve({"kind": "table", "bits": 3, "file": "tone.npy"})
    write_profile(prof, tmp_path / "q.json")
    loaded = read_profile_file(tmp_path / "q.json")
    np.testing.assert_allclose(linearize(np.array([0, 3, 7], np.uint8), loaded), [0.0, 9.0, 49.0])


@pytest.mark.parametrize("curve", [
    {"kind": "gamma", "gamma": 0.45}, {"kind": "gamma", "gamma": 1.8}, {"kind": "srgb"},
    {"kind": "table", "bits": 8, "values": _srgb_table_8bit(4.0, 251.0)},
])
def test_linearize_inverts_the_encoding(curve: dict[str, Any]) -> None:
    prof = _with_curve(curve, black_level_dn=4.0, saturation_dn=255.0)
    linear = np.linspace(4.0, 255.0, 500)
    back = linearize(encode(linear, prof), prof)
    np.testing.assert_allclose(back, linear, rtol=1e-4, atol=1e-3)
    # integer codes go through the cached table and agree with the float path
    codes = np.arange(256, dtype=np.uint8)
    np.testing.assert_allclose(linearize(codes, prof), linearize(codes.astype(np.float32), prof),
                               rtol=1e-5, atol=1e-4)
    assert np.all(np.diff(linearize(codes, prof)) >= 0)
    assert abs(float(encode(np.array([255.0]), prof)[0]) - 255.0) < 1e-3  # full scale kept


def test_codes_beyond_a_table_name_the_frame() -> None:
    prof = _with_curve({"kind": "table", "bits": 8, "values": _srgb_table_8bit(0.0, 255.0)},
                       black_level_dn=0.0, saturation_dn=255.0)
    d = prof.contract_dict()
    d["sensor"].update(rows=2, cols=2)
    prof = profile_from_dict(d)
    raw = RawFrame(data=np.full((4, 4), 300, np.uint16), timestamp_ns=0, frame_id=7,
                   pixel_format="BayerRG16", exposure_us=None, gain_db=None)
    with pytest.raises(DeviceError, match=r"frame 7.*300.*8-bit sensor\.tone_curve"):
        to_measurement(raw, prof)


@pytest.mark.parametrize("curve", [{"kind": "gamma", "gamma": 0.45}, {"kind": "srgb"}])
def test_the_capture_path_delivers_linear_dn(curve: dict[str, Any]) -> None:
    """The virtual camera encodes with the declared curve (as an ISP would); ``to_measurement``
    undoes it before binning, so the measurement matches the linear camera's."""
    linear_prof = load_profile("virtual-mini")
    d = linear_prof.contract_dict()
    d["sensor"]["tone_curve"] = curve
    toned_prof = profile_from_dict(d)
    settings = {"noise": False, "scenes": "gelsight"}
    with open_camera(linear_prof, settings=settings) as cam:
        ref = to_measurement(cam.read(), linear_prof).data
    with open_camera(toned_prof, settings=settings) as cam:
        raw = cam.read()
        got = to_measurement(raw, toned_prof)
    assert got.meta["tone_curve"] == curve["kind"]
    # undone: within the encoded integer's quantisation (slope of the inverse ≤ 2.4 at the top)
    assert float(np.max(np.abs(got.data - ref))) < 2.0
    # not undone (the same frames read as if linear): hundreds of DN off
    as_linear = to_measurement(raw, linear_prof).data
    assert float(np.max(np.abs(as_linear - ref))) > 200.0


def test_a_gamma_curve_undoes_the_contract_sensor_gamma_effect() -> None:
    """``tone_curve: {kind: gamma, gamma: g}`` is the inverse of the ``sensor_gamma`` effect with
    the same g, so a ``thintact diagnose`` finding can be declared as it is reported."""
    from thintact_sdk.simulation.scenes import make_scene
    from thintact_sdk.simulation.simulator import Simulator

    linear_prof = load_profile("virtual-mini")
    g = 0.6
    toned = linear_prof.with_physics({"sensor_gamma": {"gamma": g}})
    scene = make_scene("gelsight", linear_prof.scene.rows, linear_prof.scene.cols, 0)
    lin_sim = Simulator(linear_prof)
    gain = lin_sim.reference_gain()
    black = linear_prof.noise.black_level_dn
    expected = lin_sim.predict_signal_dn(scene, gain) + black
    delivered = Simulator(toned).predict_signal_dn(scene, gain) + black
    assert float(np.max(np.abs(delivered - expected))) > 100.0
    d = linear_prof.contract_dict()
    d["sensor"]["tone_curve"] = {"kind": "gamma", "gamma": g}
    np.testing.assert_allclose(linearize(delivered, profile_from_dict(d)), expected, rtol=1e-4, atol=1e-2)
