"""Camera settings (issue 18): every camera plugin refuses unknown and mistyped keys with the
same CameraSettingsError naming ``camera.settings.<key>``."""

from __future__ import annotations

import pytest

from thintact_sdk.errors import CameraSettingsError, ProfileError
from thintact_sdk.plugin_manager import get_registry
from thintact_sdk.profile import load_profile

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
