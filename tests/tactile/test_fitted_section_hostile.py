"""A fitted tactile section (``diagnose-tactile``'s ``fitted_tactile.yaml``, read by
``real2sim train --sim-model``) is a file a user may be handed: hostile YAML and every malformed,
non-finite or unphysical field are one ThinTactError naming the file and the field, before any
array is built from it. Nothing here simulates or trains."""

from __future__ import annotations

import copy
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from thintact_sdk.apps.cli.main import main
from thintact_sdk.diagnosis.tactile.press_model import TactileModel
from thintact_sdk.diagnosis.tactile.report import model_from_section, model_section
from thintact_sdk.errors import ThinTactError
from thintact_sdk.tactile.learning.fitted_domain import fitted_section, fitted_simulated_presses

DATA = resources.files("thintact_sdk") / "data" / "gelsight"
SHIPPED = Path(str(DATA / "gelsight-fitted-tactile.yaml"))
PACK = Path(str(DATA / "gelsight_ball_presses.npz"))
FRAME = (120, 160)  # the shipped press pack's grid, at the shipped section's 0.1245 mm/px
TEXT = SHIPPED.read_text(encoding="utf-8")
BASE = yaml.safe_load(TEXT)
FX = "tactile.simulation_effects."

LAUGHS = "a: &a [1.0,1.0,1.0,1.0,1.0,1.0,1.0,1.0,1.0,1.0]\n" + "".join(
    f"{chr(98 + i)}: &{chr(98 + i)} [{','.join(['*' + chr(97 + i)] * 10)}]\n" for i in range(8))
_F0, _F1 = TEXT.index("    field_coef:"), TEXT.index("    texture_strength:")

# name -> (YAML text, what the one-line refusal must say)
HOSTILE_YAML: dict[str, tuple[str, str]] = {
    "alias_bomb_field_coef": (LAUGHS + TEXT[:_F0] + "    field_coef: *i\n" + TEXT[_F1:],
                              "1000000 nodes"),
    "alias_bomb_effects": (LAUGHS + TEXT.replace("    effects:\n", "    effects: *h\n    old:\n", 1),
                           "1000000 nodes"),
    "recursive_alias_effects": (TEXT.replace("    effects:\n", "    effects: &r [*r]\n    old:\n", 1),
                                "recursive"),
    "recursive_alias_field_coef": (TEXT[:_F0] + "    field_coef: &r [*r]\n" + TEXT[_F1:], "recursive"),
    "deep_nesting": ("tactile: " + "[" * 10000 + "]" * 10000 + "\n", "nested too deeply"),
    "huge_int": (TEXT.replace("gamma: 0.45", "gamma: 1" + "0" * 5000), "digits"),
    "duplicate_key": (TEXT.replace("tactile:\n", "tactile:\n  mm_per_px: 0.2\n", 1),
                      "duplicate key 'mm_per_px'"),
    "merge_key": ("base: &b {mm_per_px: 0.1245}\n" + TEXT.replace("tactile:\n", "tactile:\n  <<: *b\n", 1),
                  "merge key"),
    "python_tag": ("tactile: !!python/object/apply:os.system ['echo pwned']\n", "!!python/object"),
}


@pytest.mark.parametrize("name", list(HOSTILE_YAML))
def test_hostile_yaml_is_one_refusal_naming_the_file(tmp_path: Path, name: str) -> None:
    text, says = HOSTILE_YAML[name]
    p = tmp_path / f"{name}.yaml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ThinTactError) as err:
        fitted_section(p, FRAME)
    msg = str(err.value)
    assert str(p) in msg and says in msg and "\n" not in msg


def _set(*path: str, value: Any) -> Callable[[dict], None]:
    def f(d: dict) -> None:
        x = d
        for k in path[:-1]:
            x = x[k]
        x[path[-1]] = value
    return f


def _drop(*path: str) -> Callable[[dict], None]:
    def f(d: dict) -> None:
        x = d
        for k in path[:-1]:
            x = x[k]
        del x[path[-1]]
    return f


E = ("tactile", "simulation_effects")
NAN, INF = float("nan"), float("inf")
# name -> (mutation of the shipped section, the dotted field the refusal names)
BAD_FIELDS: dict[str, tuple[Callable[[dict], None], str]] = {
    "field_coef_empty": (_set(*E, "field_coef", value=[]), FX + "field_coef"),
    "field_coef_scalar": (_set(*E, "field_coef", value=1.0), FX + "field_coef"),
    "field_coef_1x1": (_set(*E, "field_coef", value=[[1.0]]), FX + "field_coef"),
    "field_coef_3x1000": (_set(*E, "field_coef", value=[[0.0] * 1000] * 3), FX + "field_coef"),
    "field_coef_3x4": (_set(*E, "field_coef", value=[[0.5, 0.0, 0.0, 0.0]] * 3), FX + "field_coef"),
    "field_coef_ragged": (_set(*E, "field_coef", value=[[1.0, 0, 0], [1.0], [1.0]]), FX + "field_coef"),
    "field_coef_nan": (_set(*E, "field_coef", value=[[NAN] * 15] * 3), FX + "field_coef"),
    "field_coef_text": (_set(*E, "field_coef", value=[["a"] * 15] * 3), FX + "field_coef"),
    "light_3x1": (_set(*E, "light", value=[[0.0], [0.0], [0.0]]), FX + "light"),
    "light_1x2": (_set(*E, "light", value=[[1.0, 2.0]]), FX + "light"),
    "light_nan": (_set(*E, "light", value=[[NAN, 0.0, 1.0]] * 3), FX + "light"),
    "specular_2": (_set(*E, "specular", value=[0.1, 0.1]), FX + "specular"),
    "specular_big_int": (_set(*E, "specular", value=[10**400, 0, 0]), FX + "specular"),
    "texture_strength_2": (_set(*E, "texture_strength", value=[1.0, 1.0]), FX + "texture_strength"),
    "texture_strength_nan": (_set(*E, "texture_strength", value=[NAN] * 3), FX + "texture_strength"),
    "crosstalk_1x2": (_set(*E, "crosstalk", value=[[1.0, 0.0]]), FX + "crosstalk"),
    "crosstalk_nan": (_set(*E, "crosstalk", value=[[NAN, 0, 0], [0, 1, 0], [0, 0, 1]]), FX + "crosstalk"),
    "gamma_nan": (_set(*E, "gamma", value=NAN), FX + "gamma"),
    "gamma_inf": (_set(*E, "gamma", value=INF), FX + "gamma"),
    "gamma_negative": (_set(*E, "gamma", value=-1.0), FX + "gamma"),
    "gamma_zero": (_set(*E, "gamma", value=0.0), FX + "gamma"),
    "gamma_25": (_set(*E, "gamma", value=25.0), FX + "gamma"),
    "gamma_bool": (_set(*E, "gamma", value=True), FX + "gamma"),
    "gamma_missing": (_drop(*E, "gamma"), FX + "gamma"),
    "shininess_nan": (_set(*E, "shininess", value=NAN), FX + "shininess"),
    "shininess_1e308": (_set(*E, "shininess", value=1e308), FX + "shininess"),
    "shininess_zero": (_set(*E, "shininess", value=0.0), FX + "shininess"),
    "sigma_1e9": (_set("tactile", "elastomer_sigma_mm", value=1e9), "tactile.elastomer_sigma_mm"),
    "sigma_nan": (_set("tactile", "elastomer_sigma_mm", value=NAN), "tactile.elastomer_sigma_mm"),
    "sigma_negative": (_set("tactile", "elastomer_sigma_mm", value=-1.0), "tactile.elastomer_sigma_mm"),
    "sigma_zero": (_set("tactile", "elastomer_sigma_mm", value=0.0), "tactile.elastomer_sigma_mm"),
    "sigma_wider_than_frame": (_set("tactile", "elastomer_sigma_mm", value=5.0),
                               "tactile.elastomer_sigma_mm"),
    "spread_1e9": (_set(*E, "optical_spread_mm", value=1e9), FX + "optical_spread_mm"),
    "spread_nan": (_set(*E, "optical_spread_mm", value=NAN), FX + "optical_spread_mm"),
    "spread_wider_than_frame": (_set(*E, "optical_spread_mm", value=5.0), FX + "optical_spread_mm"),
    "skirt_negative": (_set(*E, "sink_in_skirt_mm", value=-5.0), FX + "sink_in_skirt_mm"),
    "skirt_1e9": (_set(*E, "sink_in_skirt_mm", value=1e9), FX + "sink_in_skirt_mm"),
    "effects_unknown": (_set(*E, "effects", value=["illumination_field", "nope"]), FX + "effects"),
    "effects_not_names": (_set(*E, "effects", value=["nope", 3, None]), FX + "effects"),
    "effects_text": (_set(*E, "effects", value="illumination_field"), FX + "effects"),
    "effects_mapping": (_set(*E, "effects", value={"a": 1}), FX + "effects"),
    "effects_twice": (_set(*E, "effects", value=["camera_gamma", "camera_gamma"]), FX + "effects"),
    "mm_per_px_nan": (_set("tactile", "mm_per_px", value=NAN), "tactile.mm_per_px"),
    "mm_per_px_text": (_set("tactile", "mm_per_px", value="0.1245"), "tactile.mm_per_px"),
    "mm_per_px_missing": (_drop("tactile", "mm_per_px"), "tactile.mm_per_px"),
    "simulation_effects_missing": (_drop(*E), "tactile.simulation_effects"),
}


def _mutated(tmp_path: Path, name: str, mutate: Callable[[dict], None]) -> Path:
    d = copy.deepcopy(BASE)
    mutate(d)
    p = tmp_path / f"{name}.yaml"
    p.write_text(yaml.safe_dump(d), encoding="utf-8")
    return p


@pytest.mark.parametrize("name", list(BAD_FIELDS))
def test_bad_field_is_one_refusal_naming_the_file_and_the_field(tmp_path: Path, name: str) -> None:
    mutate, field = BAD_FIELDS[name]
    p = _mutated(tmp_path, name, mutate)
    with pytest.raises(ThinTactError) as err:
        fitted_section(p, FRAME)
    msg = str(err.value)
    assert msg.startswith(f"{p}: {field}:"), msg
    assert "expected" in msg and "\n" not in msg


def test_frame_bounds_apply_where_the_model_is_rendered(tmp_path: Path) -> None:
    """5 mm is a plausible gel blur (so the section alone passes) but its Gaussian would reach
    beyond the 120 × 160 px frame at 0.1245 mm/px: refused before anything is simulated."""
    p = _mutated(tmp_path, "wide", _set("tactile", "elastomer_sigma_mm", value=5.0))
    assert fitted_section(p)["tactile"]["elastomer_sigma_mm"] == 5.0
    reference = np.full(FRAME + (3,), 0.5)
    with pytest.raises(ThinTactError, match=r"wide\.yaml: tactile\.elastomer_sigma_mm: 5 mm is .*"
                                            r"at most 1\.867 mm on the 120 × 160 px frame"):
        fitted_simulated_presses(p, reference, 1, 2.0, 0.1245)


def test_a_section_in_memory_is_checked_too() -> None:
    d = copy.deepcopy(BASE)
    d["tactile"]["simulation_effects"]["crosstalk"] = [[1.0, 0.0]]
    with pytest.raises(ThinTactError, match=r"^tactile\.simulation_effects\.crosstalk: expected 3 lists of 3"):
        model_from_section(d)
    with pytest.raises(ThinTactError, match=r"^tactile: expected a mapping"):
        model_from_section([1, 2])  # type: ignore[arg-type]


def test_the_shipped_section_and_what_diagnose_writes_still_load(tmp_path: Path) -> None:
    m = model_from_section(fitted_section(SHIPPED, FRAME), FRAME)
    assert m.field_coef.shape == (3, 15) and m.light is not None and m.gamma == 0.45
    # every field diagnose-tactile can write, at its extremes: field order 0 and 4, no light
    # (baseline Phong), the lengths' scan ranges, an empty effect list
    for order_k, light, effects in ((1, None, []), (15, np.eye(3), ["illumination_field",
                                    "led_directions", "optical_spread", "gel_sink_in"])):
        model = TactileModel(effects=list(effects), field_coef=np.full((3, order_k), 0.4),
                             light=light, gamma=1.5, shininess=30.0, sigma_mm=1.5,
                             spread_mm=1.5, skirt_mm=1.8)
        p = tmp_path / f"written_{order_k}.yaml"
        p.write_text(yaml.safe_dump(model_section(model, 0.1245, "test")), encoding="utf-8")
        back = model_from_section(fitted_section(p, FRAME), FRAME)
        assert back.field_coef.shape == (3, order_k) and back.effects == effects
        assert (back.light is None) == (light is None)
        assert (back.sigma_mm, back.spread_mm, back.skirt_mm) == (1.5, 1.5, 1.8)


def test_cli_refuses_a_hostile_section_in_one_line(tmp_path: Path,
                                                   capfd: pytest.CaptureFixture[str]) -> None:
    p = _mutated(tmp_path, "bad_light", _set(*E, "light", value=[[0.0], [0.0], [0.0]]))
    out = tmp_path / "r2s"
    assert main(["real2sim", "train", "--real", str(PACK), "--out", str(out), "--iterations", "1",
                 "--sim-presses", "1", "--sim-model", str(p), "--device", "cpu", "--quiet"]) == 2
    lines = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1, lines
    assert "error:" in lines[0] and "internal error" not in lines[0]
    assert "bad_light.yaml" in lines[0] and "tactile.simulation_effects.light" in lines[0]
    assert not (out / "generator.pt").exists()
