"""Profile sanity limits (issue 18): sizes, distances, mask vs sensor, channels, physics,
LED levels, names that are not paths, broken files on the search path, --strict plugins."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import yaml

from thintact_sdk.cli.main import main
from thintact_sdk.errors import ProfileError
from thintact_sdk.physics import EFFECTS
from thintact_sdk.profile import SHIPPED_PROFILE_DIR, load_profile, profile_from_dict


@pytest.fixture(scope="module")
def mini() -> dict:
    return yaml.safe_load((SHIPPED_PROFILE_DIR / "virtual-mini.yaml").read_text())


def _set(d: dict, dotted: str, value: object) -> dict:
    d = copy.deepcopy(d)
    *head, last = dotted.split(".")
    cur = d
    for k in head:
        cur = cur.setdefault(k, {})
    cur[last] = value
    return d


def _first_bounded_param() -> tuple[str, str, float]:
    """An effect parameter with a finite upper bound, read from the effect SPECs."""
    for effect, spec in EFFECTS.items():
        for name, p in spec.params.items():
            if not p.shape and p.default is not None and p.bounds[1] < float("inf"):
                return effect, name, p.bounds[1]
    raise AssertionError("no scalar effect parameter with a finite bound")


_EFFECT, _PARAM, _HIGH = _first_bounded_param()


@pytest.mark.parametrize(
    ("field", "value", "expect"),
    [
        ("sensor.rows", 10**6, "sensor.rows"),
        ("sensor.rows", 10**30, "sensor.rows"),
        ("sensor.rows", True, "sensor.rows"),
        ("sensor.cols", 160.0, "sensor.cols"),
        ("scene.rows", 0, "scene.rows"),
        ("sensor.pixel_pitch_um", float("inf"), "sensor.pixel_pitch_um"),
        ("geometry.scene_to_mask_mm", float("inf"), "geometry.scene_to_mask_mm"),
        ("geometry.mask_to_sensor_mm", float("nan"), "geometry.mask_to_sensor_mm"),
        ("noise.read_noise_dn", float("nan"), "noise.read_noise_dn"),
        ("mask.phi_rows", [1, -1, 1], "phi_rows has 3 entries but phi has 128"),
        ("mask.phi", [True] * 128, "mask.phi"),
        ("sensor.channels", ["R", "G", "X"], "unknown channel"),
        ("sensor.channels", ["R", "R"], "channels repeat"),
        ("physics", {"wobble": {}}, "unknown effect 'wobble'"),
        ("physics", {_EFFECT: {_PARAM: _HIGH * 10 + 1}}, f"physics.{_EFFECT}.{_PARAM}"),
        ("light", {"plugin": "serial-led", "intensities": [0.5, 2.0]}, "light.intensities.1"),
        ("light", {"plugin": "serial-led", "intensities": [float("nan")]}, "light.intensities.0"),
        ("name", "../x", "not a profile name"),
        ("name", "/tmp/abs", "not a profile name"),
        ("name", "a/b", "not a profile name"),
        ("name", "..", "not a profile name"),
        ("camera.plugin", "../evil", "camera.plugin"),
    ],
)
def test_out_of_range_fields_are_refused_by_name(mini: dict, field: str, value: object, expect: str) -> None:
    with pytest.raises(ProfileError) as err:
        profile_from_dict(_set(mini, field, value), where="bad.yaml")
    msg = str(err.value)
    assert "bad.yaml" in msg and expect in msg, msg


def test_valid_limits_still_accepted(mini: dict) -> None:
    ok = _set(mini, "light", {"plugin": "serial-led", "intensities": [0.0, 1.0]})
    ok = _set(ok, "physics", {_EFFECT: {_PARAM: _HIGH}})
    ok = _set(ok, "camera.plugin", "acme:virtual")
    prof = profile_from_dict(ok)
    assert prof.light is not None and prof.light.intensities == [0.0, 1.0]
    assert profile_from_dict(_set(mini, "sensor.channels", ["mono"])).sensor.channels == ["mono"]


def test_cli_validate_exits_2_naming_file_and_field(tmp_path: Path, mini: dict,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "huge.json"
    f.write_text(json.dumps(_set(mini, "sensor.rows", 10**30)))
    assert main(["profile", "validate", str(f)]) == 2
    err = capsys.readouterr().err
    assert str(f) in err and "sensor.rows" in err and "Traceback" not in err


def test_broken_file_on_search_path_does_not_hide_others(tmp_path: Path, mini: dict,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "latin1.yaml").write_bytes(b"name: caf\xe9\n\xff\xfe")
    (tmp_path / "mine.yaml").write_text(yaml.safe_dump(_set(mini, "name", "mine")))
    monkeypatch.setenv("THINTACT_PROFILE_PATH", str(tmp_path))
    with pytest.warns(UserWarning, match="latin1.yaml"):
        assert load_profile("virtual-mini").name == "virtual-mini"
        assert load_profile("mine").name == "mine"
    with pytest.raises(ProfileError, match=r"latin1\.yaml.*not UTF-8"):
        load_profile("latin1")


def test_strict_validate_names_misspelt_plugin(tmp_path: Path, mini: dict,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "typo.yaml"
    f.write_text(yaml.safe_dump(_set(mini, "camera.plugin", "virtaul")))
    assert main(["profile", "validate", str(f)]) == 0  # names are only checked with --strict
    capsys.readouterr()
    assert main(["profile", "validate", "--strict", str(f)]) == 2
    err = capsys.readouterr().err
    assert "camera.plugin" in err and "virtaul" in err and "available:" in err and "virtual" in err
    assert main(["profile", "validate", "--strict", str(SHIPPED_PROFILE_DIR / "virtual-mini.yaml")]) == 0
