"""Damaged calibration bundles are one CalibrationError naming the file and field."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.errors import CalibrationError
from thintact_sdk.reconstruction.bundle import CalibrationBundle


def _rewrite_npz(path: Path, **replace: np.ndarray) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(replace)
    np.savez(path, **arrays)


def test_the_clean_bundle_loads(bundle_copy: Path) -> None:
    b = CalibrationBundle.load(bundle_copy)
    assert b.tau > 0 and b.filter is not None


@pytest.mark.parametrize("name", ["system_matrices.npz", "filter.npz"])
def test_truncated_npz_is_named(bundle_copy: Path, name: str) -> None:
    data = (bundle_copy / name).read_bytes()
    (bundle_copy / name).write_bytes(data[: len(data) // 2])
    with pytest.raises(CalibrationError, match=f"{name}.*truncated or damaged"):
        CalibrationBundle.load(bundle_copy)


@pytest.mark.parametrize("name", ["system_matrices.npz", "filter.npz"])
def test_random_bytes_are_not_a_bundle_and_never_pickled(bundle_copy: Path, name: str) -> None:
    (bundle_copy / name).write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(CalibrationError, match="not a calibration bundle") as err:
        CalibrationBundle.load(bundle_copy)
    assert "pickle" not in str(err.value) and name in str(err.value)


def test_a_pickled_member_is_refused_without_unpickling(bundle_copy: Path) -> None:
    buf = io.BytesIO()
    np.save(buf, np.array([{"evil": 1}], dtype=object), allow_pickle=True)
    with zipfile.ZipFile(bundle_copy / "filter.npz", "w") as z:
        z.writestr("phi_f.npy", buf.getvalue())
        z.writestr("phi_s.npy", buf.getvalue())
    with pytest.raises(CalibrationError, match="filter.npz"):
        CalibrationBundle.load(bundle_copy)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize(("name", "key"), [("system_matrices.npz", "Pc"), ("filter.npz", "phi_s")])
def test_nan_and_inf_matrices_are_named(bundle_copy: Path, name: str, key: str, bad: float) -> None:
    with np.load(bundle_copy / name) as z:
        arr = z[key].copy()
    arr.flat[3] = bad
    _rewrite_npz(bundle_copy / name, **{key: arr})
    with pytest.raises(CalibrationError, match=f"{name}: array {key} holds 1 NaN/Inf"):
        CalibrationBundle.load(bundle_copy)


def test_text_and_wrongly_shaped_arrays_are_named(bundle_copy: Path) -> None:
    _rewrite_npz(bundle_copy / "system_matrices.npz", Qo=np.array(["x"]))
    with pytest.raises(CalibrationError, match="array Qo has dtype <U1"):
        CalibrationBundle.load(bundle_copy)
    _rewrite_npz(bundle_copy / "system_matrices.npz", Qo=np.ones((1, 2, 3, 4), np.float32))
    with pytest.raises(CalibrationError, match="system_matrices.npz: system matrix Qo"):
        CalibrationBundle.load(bundle_copy)


@pytest.mark.parametrize(
    ("field", "value"),
    [("tau", "big"), ("tau", -5), ("tau", 0), ("tau", True), ("exposure_us", -1.0),
     ("tau_t2s_closed_form", "NaN")],
)
def test_bad_meta_fields_are_invalid_not_missing(bundle_copy: Path, field: str, value: object) -> None:
    meta_path = bundle_copy / "calibration.json"
    meta = json.loads(meta_path.read_text())
    meta[field] = float("nan") if value == "NaN" else value
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(CalibrationError, match=f"field '{field}' is .*invalid") as err:
        CalibrationBundle.load(bundle_copy)
    assert "calibration.json" in str(err.value) and "has none" not in str(err.value)


def test_a_null_tau_means_none(bundle_copy: Path) -> None:
    meta_path = bundle_copy / "calibration.json"
    meta = json.loads(meta_path.read_text())
    meta["tau"] = None
    meta_path.write_text(json.dumps(meta))
    assert CalibrationBundle.load(bundle_copy).tau == 0.0
