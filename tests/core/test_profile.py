from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from thintact_sdk.errors import ProfileError
from thintact_sdk.formats.profiles import (
    SHIPPED_PROFILE_DIR,
    available_profiles,
    load_profile,
    profile_from_dict,
    read_profile_file,
    write_profile,
)


def _golden(golden_dir: Path, name: str) -> dict:
    return json.loads((golden_dir / name / "profile.json").read_text())


@pytest.mark.parametrize("name", ["mini", "wide"])
def test_golden_profiles_validate(golden_dir: Path, name: str) -> None:
    prof = read_profile_file(golden_dir / name / "profile.json")
    assert prof.name == f"golden-{name}"
    assert prof.sensor.rows == 128 and prof.sensor.cols == 160
    assert prof.mask.K == len(_golden(golden_dir, name)["mask"]["phi"])
    assert prof.physics == {}
    assert prof.geometry.total_mm == pytest.approx(5.8)


def test_shipped_profiles_validate_and_are_found_by_name() -> None:
    names = available_profiles()
    assert {"thintact-paper", "virtual-mini"} <= set(names)
    paper = load_profile("thintact-paper")
    assert (paper.sensor.rows, paper.sensor.cols) == (1024, 1280)
    assert (paper.scene.rows, paper.scene.cols) == (400, 512)
    assert paper.scene.pixel_pitch_um == 31.5
    assert paper.mask.feature_um == 20.0
    assert paper.geometry.scene_to_mask_mm == 4.8 and paper.geometry.mask_to_sensor_mm == 1.0
    assert paper.camera is not None and paper.camera.plugin == "genicam"
    for f in SHIPPED_PROFILE_DIR.glob("*.yaml"):
        read_profile_file(f)


def _mutate(d: dict, path: list[str], value: object) -> dict:
    d = json.loads(json.dumps(d))
    cur = d
    for k in path[:-1]:
        cur = cur[k]
    if value is KeyError:
        del cur[path[-1]]
    else:
        cur[path[-1]] = value
    return d


@pytest.mark.parametrize(
    ("path", "value", "expect"),
    [
        (["sensor", "rows"], "many", "sensor.rows"),
        (["sensor", "rows"], KeyError, "sensor.rows: field required"),
        (["geometry", "scene_to_mask_mm"], -1.0, "geometry.scene_to_mask_mm"),
        (["mask", "phi"], [1, 0, -1], "mask.phi"),
        (["noise"], KeyError, "noise: field required"),
        (["format"], "thintact-profile/9", "unknown profile format"),
    ],
)
def test_invalid_profiles_name_the_field(golden_dir: Path, path: list[str], value: object, expect: str) -> None:
    bad = _mutate(_golden(golden_dir, "mini"), path, value)
    with pytest.raises(ProfileError) as err:
        profile_from_dict(bad, where="bad.json")
    assert expect in str(err.value)


def test_per_rgb_effects_need_three_channels(golden_dir: Path) -> None:
    """Stray light's 3 values broadcast onto a four-plane sensor ended in ValueError (exit 1)."""
    planes = _mutate(_golden(golden_dir, "mini"), ["sensor", "channels"], ["R", "Gr", "Gb", "B"])
    assert profile_from_dict(planes, where="planes.json").sensor.channels == ["R", "Gr", "Gb", "B"]
    planes["physics"] = {"stray_light": {"mean_dn": [1.0, 2.0, 3.0]}}
    with pytest.raises(ProfileError, match="physics.stray_light: its parameters are per R, G, B; "
                                           "this sensor has 4 channels"):
        profile_from_dict(planes, where="planes.json")


def test_roundtrip_yaml_and_json(tmp_path: Path, golden_dir: Path) -> None:
    prof = read_profile_file(golden_dir / "mini" / "profile.json")
    for suffix in (".json", ".yaml"):
        out = write_profile(prof, tmp_path / f"p{suffix}")
        again = read_profile_file(out)
        assert again.contract_dict() == prof.contract_dict()
        assert again.content_hash() == prof.content_hash()
    data = yaml.safe_load((tmp_path / "p.yaml").read_text())
    assert data["format"] == "thintact-profile/1"


def test_unknown_name_lists_known_profiles() -> None:
    with pytest.raises(ProfileError, match="virtual-mini"):
        load_profile("no-such-device")


def test_relative_paths_resolve_next_to_profile(tmp_path: Path, golden_dir: Path) -> None:
    d = _golden(golden_dir, "mini")
    d["decoder"] = {"plugin": "x", "calibration": "cal/bundle"}
    (tmp_path / "p.json").write_text(json.dumps(d))
    prof = read_profile_file(tmp_path / "p.json")
    assert prof.resolve_path(prof.decoder.calibration) == (tmp_path / "cal" / "bundle").resolve()
