"""A stored tactile table (``lut.npz`` + ``lut.json``) and its networks are untrusted files:
whatever they hold is refused when they are read, naming the file and the member, never
turned into NaN depth, an out-of-bounds read or an exception from numpy or pathlib."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.errors import CalibrationError
from thintact_sdk.tactile.interpretation.gradient_model import ConvGradient, MLPGradient
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT

SHIPPED = Path(__file__).resolve().parents[2] / "thintact_sdk" / "data" / "gelsight"


def _copy(tmp_path: Path) -> tuple[Path, dict[str, np.ndarray], dict]:
    shutil.copy(SHIPPED / "gelsight-mini-lut.npz", tmp_path / "lut.npz")
    shutil.copy(SHIPPED / "gelsight-mini-lut.json", tmp_path / "lut.json")
    with np.load(tmp_path / "lut.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return tmp_path / "lut.npz", arrays, json.loads((tmp_path / "lut.json").read_text())


def _damage(arrays: dict[str, np.ndarray], how: str) -> dict[str, np.ndarray]:
    a = {k: v.copy() for k, v in arrays.items()}
    b = a["table"].shape[0]
    if how == "table nan":
        a["table"][1, 2, 3, 0] = np.nan
    elif how == "table inf":
        a["table"][0, 0, 0, 1] = np.inf
    elif how == "table huge":
        a["table"] = np.full_like(a["table"], 3e38)
    elif how == "table empty":
        a["table"], a["counts"] = np.zeros((0, 0, 0, 2), np.float32), np.zeros((0, 0, 0), np.float32)
    elif how == "table one bin":
        a["table"], a["counts"] = np.zeros((1, 1, 1, 2), np.float32), np.ones((1, 1, 1), np.float32)
    elif how == "table 300 bins":
        a["table"], a["counts"] = np.zeros((300, 300, 300, 2), np.float16), np.zeros((1,), np.float32)
    elif how == "lo nan":
        a["lo"] = np.full(3, np.nan)
    elif how == "lo -inf":
        a["lo"] = np.full(3, -np.inf)
    elif how == "lo two values":
        a["lo"] = a["lo"][:2]
    elif how == "lo 3x3":
        a["lo"] = np.tile(a["lo"], (3, 1))
    elif how == "hi below lo":
        a["lo"], a["hi"] = a["hi"], a["lo"]
    elif how == "hi 1e308":
        a["hi"] = np.full(3, 1e308)
    elif how == "counts shape":
        a["counts"] = np.ones(5, np.float32)
    elif how == "counts negative":
        a["counts"] = -np.ones((b, b, b), np.float32)
    return a


@pytest.mark.parametrize("how, match", [
    ("table nan", "not finite"), ("table inf", "not finite"), ("table huge", "beyond"),
    ("table empty", "B from 2"), ("table one bin", "B from 2"), ("table 300 bins", "B from 2"),
    ("lo nan", "lo holds"), ("lo -inf", "lo holds"), ("lo two values", "lo has shape"),
    ("lo 3x3", "lo has shape"), ("hi below lo", "not below hi"), ("hi 1e308", "hi holds"),
    ("counts shape", "counts has shape"), ("counts negative", "counts holds"),
])
def test_a_damaged_table_is_refused_naming_the_member(tmp_path, how, match):
    p, arrays, _ = _copy(tmp_path)
    assert PhotometricLUT.load(p).bins == arrays["table"].shape[0]  # the shipped one loads
    np.savez_compressed(p, **_damage(arrays, how))
    with pytest.raises(CalibrationError, match=rf"lut\.npz: .*{match}"):
        PhotometricLUT.load(p)


@pytest.mark.parametrize("text, match", [
    ('"contact_rim_mm": ' + "1" * 5000, "an integer of 5000 digits"),
    ('"contact_rim_mm": 1' + "0" * 400, "an integer of 401 digits"),
    ('"contact_rim_mm": 1' + "0" * 300, "contact_rim_mm must be a number"),
])
def test_numbers_json_cannot_hold_as_a_float_are_refused(tmp_path, text, match):
    p, _, meta = _copy(tmp_path)
    body = json.dumps(meta)
    (tmp_path / "lut.json").write_text(body[:-1] + ", " + text + "}")
    with pytest.raises(CalibrationError, match=rf"lut\.json: .*{match}"):
        PhotometricLUT.load(p)


def test_metadata_that_is_a_directory_is_refused(tmp_path):
    p, _, _ = _copy(tmp_path)
    (tmp_path / "lut.json").unlink()
    (tmp_path / "lut.json").mkdir()
    with pytest.raises(CalibrationError, match=r"lut\.json: not a file"):
        PhotometricLUT.load(p)


@pytest.mark.parametrize("kind", ["mlp", "cnn"])
@pytest.mark.parametrize("value", [3e38, np.nan, -2e4])
def test_network_weights_that_would_overflow_are_refused(tmp_path, kind, value):
    """3e38 weights passed a finiteness check, overflowed to inf in the last product and the
    no-contact subtraction made the whole depth map NaN."""
    rng = np.random.default_rng(0)
    p = tmp_path / f"lut.{kind}.npz"
    if kind == "mlp":
        w = {"w0": rng.normal(0, .2, (8, 4)), "b0": np.zeros(4), "w1": rng.normal(0, .2, (4, 4)),
             "b1": np.zeros(4), "w2": np.full((4, 2), value), "b2": np.zeros(2)}
        extra = {"shape": np.array([6, 8])}
        loader = MLPGradient.load
    else:
        w = {"w0": rng.normal(0, .2, (3, 3, 8, 4)), "b0": np.zeros(4), "w1": np.full((4, 2), value),
             "b1": np.zeros(2)}
        extra = {"dilations": np.array([1]), "shape": np.array([6, 8])}
        loader = ConvGradient.load
    np.savez(p, **{k: np.asarray(v, np.float32) for k, v in w.items()}, **extra)
    with pytest.raises(CalibrationError, match=rf"lut\.{kind}\.npz: the network's w[12] holds"):
        loader(p)
