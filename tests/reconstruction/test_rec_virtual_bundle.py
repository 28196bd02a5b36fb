"""Virtual calibration bundles: the maker on a tiny virtual device, and the committed bundles."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.profiles import load_profile, profile_from_dict
from thintact_sdk.reconstruction.bundle import CalibrationBundle, find_latest
from thintact_sdk.reconstruction.virtual_bundle import (
    VirtualCalibrationOptions,
    make_virtual_bundle,
)

REPO = Path(__file__).resolve().parents[2]


def _tiny_profile():
    d = load_profile("virtual-mini").contract_dict()
    d["name"] = "rec-tiny"
    d["sensor"].update(rows=40, cols=48)
    d["scene"].update(rows=14, cols=18)
    return profile_from_dict(d)


def test_make_virtual_bundle_on_a_tiny_device(tmp_path) -> None:
    profile = _tiny_profile()
    bundle = make_virtual_bundle(profile, VirtualCalibrationOptions(training_count=8, steps=2))
    meta = bundle.meta
    assert meta["source"] == "simulator" and meta["profile"] == "rec-tiny"
    assert meta["tau"] > 0 and meta["tau_t2s_closed_form"] > 0
    m = meta["metrics"]
    assert max(m["two_term_fit_relative_error"]) < 0.05
    for key in ("psnr_db", "t2s_closed_form_psnr_db", "iterative800_psnr_db", "flatcam_psnr_db"):
        assert set(m[key]) == {"white", "usaf", "gelsight-20", "gelsight-31", "smooth_color"}
    # the exact closed form is never worse than 800 Nesterov steps on the same objective
    assert np.mean(list(m["t2s_closed_form_psnr_db"].values())) >= \
        np.mean(list(m["iterative800_psnr_db"].values())) - 0.05
    out = bundle.save(tmp_path / "rec-tiny" / "20260101T000000")
    loaded = CalibrationBundle.load(out)
    assert loaded.matches_profile(profile)
    assert loaded.filter is not None and loaded.filter.sensor_shape == (40, 48)


@pytest.mark.parametrize("name", ["virtual-mini", "virtual-finger"])
def test_committed_virtual_bundles_load_and_decode(name) -> None:
    device_dir = REPO / "thintact_sdk" / "data" / "calibrations" / name
    if not device_dir.is_dir():
        pytest.skip(f"no committed bundle for {name}")
    latest = find_latest(device_dir)
    assert all(f.stat().st_size < 2 * 1024 * 1024 for f in latest.iterdir())
    profile = load_profile(name)
    bundle = CalibrationBundle.load(latest)
    assert bundle.matches_profile(profile), "profile changed since the bundle was made: regenerate it"
    reg = get_registry()
    for dec_name in ("thintact-noniterative", "t2s-closed-form", "flatcam"):
        dec = reg.create("decoder", dec_name, profile, {})
        x = np.full((profile.scene.rows, profile.scene.cols, 3), 0.5, np.float32)
        y = bundle.system_matrices.forward(x).astype(np.float32)
        xh = dec.decode(y)
        assert xh.shape == x.shape and np.isfinite(xh).all()
    assert reg.create("decoder", "thintact-noniterative", profile, {}).folded
