"""The replay camera for devices that are not ours: a declared tone curve is undone exactly
once (linear npy frames and tone-mapped JPEG frames alike), monochrome and R/Gr/Gb/B
recordings replay back to the recorded measurement."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thintact_sdk.device.cameras import create_camera, to_measurement
from thintact_sdk.formats.profiles import Profile, load_profile, profile_from_dict
from thintact_sdk.formats.recording import Recording, RecordingWriter


def _device(channels: list[str], curve: dict[str, Any] | None = None) -> Profile:
    d = load_profile("virtual-mini").contract_dict()
    d["sensor"]["channels"] = channels
    d["noise"].update(black_level_dn=4.0, saturation_dn=255.0)
    if curve is not None:
        d["sensor"]["tone_curve"] = curve
    return profile_from_dict(d)


def _replaying(profile: Profile, root: Path) -> Profile:
    d = profile.contract_dict()
    d["camera"] = {"plugin": "replay", "settings": {"path": str(root), "rate": "fast"}}
    return profile_from_dict(d)


def _replay(profile: Profile, root: Path, n: int) -> list[np.ndarray]:
    prof = _replaying(profile, root)
    with create_camera(prof) as cam:
        return [to_measurement(cam.read(), prof).data for _ in range(n)]


@pytest.mark.parametrize(("channels", "file_format"), [
    (["R", "G", "B"], "npy"), (["R", "G", "B"], "jpg"), (["mono"], "npy"), (["mono"], "jpg"),
    (["R", "Gr", "Gb", "B"], "npy"),
])
def test_replay_gives_the_recorded_linear_measurement(tmp_path: Path, channels: list[str],
                                                      file_format: str) -> None:
    prof = _device(channels, {"kind": "srgb"})
    rng = np.random.default_rng(1)
    w = RecordingWriter(tmp_path / "rec", prof)
    for i in range(3):
        m = rng.integers(4, 255, (128, 160, len(channels)))
        if file_format == "npy":
            w.add(m.astype(np.uint16), label=f"f{i}")  # linear DN, as `thintact record` writes
        else:
            w.add(m.astype(np.uint8), label=f"f{i}", file_format="jpg")  # as the camera encoded it
    rec = Recording(tmp_path / "rec")
    got = _replay(prof, tmp_path / "rec", 3)
    for i, g in enumerate(got):
        assert g.shape == (128, 160, len(channels))
        np.testing.assert_allclose(g, np.asarray(rec.measurement(i), np.float32), rtol=1e-4, atol=1e-3)
