"""Camera settings (issue 18): every camera plugin refuses unknown and mistyped keys with the
same CameraSettingsError naming ``camera.settings.<key>``."""

from __future__ import annotations

import pytest

from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import CameraSettingsError, ProfileError
from thintact_sdk.formats.profiles import load_profile

GOOD = {
    "virtual": {},
    "replay": {"path": "some-recording"},
    "uvc": {"device": "clip.mp4"},
    "genicam": {},
}


@pytest.mark.parametrize("plugin", sorted(GOOD))
def test_unknown_key_is_named(plugin: str) -> None:
    settings = {**GOOD[plugin], "exposur_us": 100}
    with pytest.raises(CameraSettingsError, match=r"camera\.settings\.exposur_us: unknown") as err:
        get_registry().create("camera", plugin, load_profile("virtual-mini"), settings)
    assert isinstance(err.value, ProfileError) and "known:" in str(err.value)


@pytest.mark.parametrize(
    ("plugin", "key", "value"),
    [
        ("virtual", "fps", "fast"),
        ("virtual", "seed", 1.5),
        ("virtual", "noise", "yes"),
        ("virtual", "fps", float("inf")),
        ("replay", "speed", -1),
        ("replay", "rate", "slow"),
        ("replay", "loop", "no"),
        ("uvc", "width", "wide"),
        ("uvc", "loop", "no"),
        ("genicam", "num_buffers", "many"),
        ("genicam", "index", -1),
    ],
)
def test_mistyped_value_is_named(plugin: str, key: str, value: object) -> None:
    with pytest.raises(CameraSettingsError, match=rf"camera\.settings\.{key}:"):
        get_registry().create("camera", plugin, load_profile("virtual-mini"), {**GOOD[plugin], key: value})


def test_replay_without_path_names_it() -> None:
    with pytest.raises(CameraSettingsError, match=r"camera\.settings\.path: required"):
        get_registry().create("camera", "replay", load_profile("virtual-mini"), {})


def test_uvc_backend_error_in_read_is_device_lost(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A cv2.error raised inside VideoCapture.read becomes DeviceLostError."""
    import cv2
    import numpy as np

    from thintact_sdk.errors import DeviceLostError

    clip = tmp_path / "f_%03d.png"
    for i in range(2):
        cv2.imwrite(str(tmp_path / f"f_{i:03d}.png"), np.zeros((8, 8, 3), np.uint8))
    cam = get_registry().create("camera", "uvc", load_profile("virtual-mini"), {"device": str(clip)})
    with cam:
        class _Broken:
            def read(self):  # type: ignore[no-untyped-def]
                raise cv2.error("backend crashed")

            def __getattr__(self, name):  # type: ignore[no-untyped-def]
                return getattr(real, name)

        real = cam._cap
        cam._cap = _Broken()
        with pytest.raises(DeviceLostError, match="failed while reading"):
            cam.read(timeout_s=5.0)
        cam._cap = real


@pytest.mark.parametrize(("key", "value", "reason"), [
    ("exposur_us", 100, "unknown"),
    ("raw", True, "unknown"),  # a recording directory's option, meaningless for an MCAP log
    ("speed", 0, ""),
    ("rate", "slow", ""),
    ("loop", "no", ""),
])
def test_mcap_replay_settings_are_checked_like_every_camera(key: str, value: object, reason: str) -> None:
    """The MCAP source of the replay camera uses the same settings model discipline."""
    settings = {"path": "log.mcap", key: value}
    with pytest.raises(CameraSettingsError, match=rf"camera\.settings\.{key}: {reason}"):
        get_registry().create("camera", "replay", load_profile("virtual-mini"), settings)
