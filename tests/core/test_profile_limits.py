"""Profile sanity limits (issue 18): sizes, distances, mask vs sensor, channels, physics,
LED levels, names that are not paths, broken files on the search path, --strict plugins."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import yaml

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import ProfileError
from thintact_sdk.formats.profiles import SHIPPED_PROFILE_DIR, load_profile, profile_from_dict
from thintact_sdk.simulation.effects import EFFECTS


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
        # issue 30: physically impossible values, refused with the field named
        ("sensor.pixel_pitch_um", 1e-30, "sensor.pixel_pitch_um: Input should be greater than or equal to 0.1"),
        ("sensor.pixel_pitch_um", -10.0, "sensor.pixel_pitch_um"),
        ("scene.pixel_pitch_um", 1e-9, "scene.pixel_pitch_um"),
        ("display.pixel_pitch_um", 0.0, "display.pixel_pitch_um"),
        ("mask.feature_um", 1e-30, "mask.feature_um"),
        ("geometry.scene_to_mask_mm", 1e-300, "geometry.scene_to_mask_mm"),
        ("tactile.mm_per_px", 1e-9, "tactile.mm_per_px: Input should be greater than or equal to 0.0001"),
        ("tactile.mm_per_px", 0.0, "tactile.mm_per_px"),
        ("tactile.mm_per_px", float("nan"), "tactile.mm_per_px"),
        ("tactile.elastomer_sigma_mm", 1e9, "tactile.elastomer_sigma_mm: expected a finite number in [0, 1000]"),
        ("tactile.elastomer_sigma_mm", float("nan"), "tactile.elastomer_sigma_mm"),
        ("tactile.elastomer_sigma_mm", "wide", "tactile.elastomer_sigma_mm"),
        ("tactile.elastomer_sigma_mm", True, "tactile.elastomer_sigma_mm"),
        ("tactile.elastomer_sigma_mm", 100.0, "wider than the 64 px scene grid it blurs"),
        ("tactile.elastomer_poisson", 0.7, "tactile.elastomer_poisson"),
        ("tactile.elastomer_youngs_mpa", -1.0, "tactile.elastomer_youngs_mpa"),
        ("tactile.force_shear_gain", float("inf"), "tactile.force_shear_gain"),
        ("tactile.marker_pitch_mm", 1e-6, "tactile.marker_pitch_mm: 1e-06 mm is below one pixel"),
        ("tactile.marker_diameter_mm", 2.0, "tactile.marker_diameter_mm: 2 mm is not below tactile.marker_pitch_mm"),
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


def test_tiny_tactile_pixel_refused_before_any_allocation(mini: dict) -> None:
    """``tactile.mm_per_px: 1e-9`` made the simulator's elastomer blur a 2e9-tap kernel."""
    at_floor = _set(mini, "tactile.mm_per_px", 1e-4)  # the floor itself: the default blur is too wide
    with pytest.raises(ProfileError, match=r"tactile\.elastomer_sigma_mm: 0\.25 mm \(the default\) is 2\.5e\+03 px"):
        profile_from_dict(at_floor)
    narrow = _set(at_floor, "tactile.elastomer_sigma_mm", 0.002)
    narrow = _set(narrow, "tactile.marker_diameter_mm", 0.001)
    assert profile_from_dict(narrow).tactile is not None


def test_elastomer_default_matches_the_simulator() -> None:
    from thintact_sdk.formats.profiles import ELASTOMER_SIGMA_MM
    from thintact_sdk.tactile.interpretation.grid import TactileParams

    assert TactileParams(rows=1, cols=1, mm_per_px=1.0).elastomer_sigma_mm == ELASTOMER_SIGMA_MM


@pytest.mark.parametrize(("field", "rows", "cols", "expect"), [
    ("sensor", 4096, 4096, "sensor.rows × sensor.cols: a 8192×8192 float64 raw frame of 512.0 MiB, "
                           "over the 128.0 MiB one array may take on this host (0.125 of 1.0 GiB memory)"),
    ("scene", 4096, 2048, "scene.rows × scene.cols: a 8192×4096 float64 tactile grid of 256.0 MiB, "
                          "over the 128.0 MiB one array may take on this host (0.125 of 1.0 GiB memory)"),
])
def test_arrays_beyond_the_memory_limit_refused(mini: dict, monkeypatch: pytest.MonkeyPatch,
                                                field: str, rows: int, cols: int, expect: str) -> None:
    import thintact_sdk.formats.profiles as prof

    monkeypatch.setattr(prof, "host_memory_bytes", lambda: 2**30)
    d = _set(_set(mini, f"{field}.rows", rows), f"{field}.cols", cols)
    with pytest.raises(ProfileError) as err:
        profile_from_dict(d, where="big.yaml")
    assert str(err.value) == f"invalid profile big.yaml: {expect}"
    monkeypatch.setattr(prof, "host_memory_bytes", lambda: 64 * 2**30)
    assert profile_from_dict(d).name == "virtual-mini"


def test_shipped_profiles_fit_a_small_host(monkeypatch: pytest.MonkeyPatch) -> None:
    import thintact_sdk.formats.profiles as prof

    monkeypatch.setattr(prof, "host_memory_bytes", lambda: 2 * 2**30)
    for f in sorted(SHIPPED_PROFILE_DIR.glob("*.yaml")):
        assert load_profile(f).source == f.resolve()


def test_many_problems_make_one_line(tmp_path: Path, mini: dict, capsys: pytest.CaptureFixture[str]) -> None:
    bad = _set(_set(_set(mini, "sensor.rows", -1), "scene.cols", "x"), "noise.read_noise_dn", None)
    bad = _set(_set(bad, "geometry.mask_to_sensor_mm", float("inf")), "mask.phi", [3] * 128)
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(bad))
    assert main(["profile", "validate", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err == (f"thintact: error: invalid profile {f}: sensor.rows: Input should be greater than 0 "
                   "(and 4 more: scene.cols, mask.phi, geometry.mask_to_sensor_mm, ...)\n")


def test_strict_plugin_problems_make_one_line(tmp_path: Path, mini: dict,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "typos.yaml"
    f.write_text(yaml.safe_dump(_set(_set(mini, "camera.plugin", "virtaul"), "decoder.plugin", "nope")))
    assert main(["profile", "validate", "--strict", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "camera.plugin" in err and err.endswith(" (and 1 more)\n"), err
