"""MATLAB ``.mat`` matrices (``calibrate-import``) are read strictly: variable headers first,
only the wanted numeric variables, their declared size bounded, and every damaged file one
CalibrationError (mutated files used to end in zlib.error, TypeError, IndexError or
MatReadError tracebacks)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.io import savemat

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.matrices import _read


def test_mutated_mat_files_are_read_or_refused_with_one_error(tmp_path: Path) -> None:
    good = tmp_path / "good.mat"
    savemat(good, {"Po": np.ones((8, 5)), "Qo": np.ones((7, 4)), "note": "kept out"},
            do_compression=True)
    assert sorted(_read(good)) == ["Po", "Qo"]  # only the matrices are read
    data = good.read_bytes()
    rng = np.random.default_rng(0)
    refused = 0
    for k in range(120):
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 6))):
            b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        if k % 3 == 0:
            b = b[: int(rng.integers(10, len(b)))]
        p = tmp_path / f"m{k}.mat"
        p.write_bytes(bytes(b))
        try:
            _read(p)
        except CalibrationError as err:
            assert str(p) in str(err)
            refused += 1
    assert refused > 60  # most mutations damage the file; none escapes as another exception


def test_a_mat_declaring_a_huge_matrix_is_refused_before_reading(tmp_path: Path) -> None:
    p = tmp_path / "huge.mat"
    savemat(p, {"Pc": np.ones((3, 2))}, do_compression=False)
    data = bytearray(p.read_bytes())
    # 128-byte header, the variable's tag (8), its array-flags subelement (16), the
    # dimensions' tag (8): then rows and columns as int32
    assert struct.unpack_from("<ii", data, 160) == (3, 2)
    struct.pack_into("<ii", data, 160, 100_000, 100_000)
    p.write_bytes(bytes(data))
    with pytest.raises(CalibrationError, match=r"huge.mat: the matrices declare 74.5 GiB"):
        _read(p)


def test_a_mat_matrix_that_is_not_numeric_is_refused_by_name(tmp_path: Path,
                                                             capfd: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "cell.mat"
    savemat(p, {"Phi_L": np.array([np.ones(2), "x"], dtype=object), "Phi_R": np.ones((2, 2))})
    with pytest.raises(CalibrationError, match=r"cell.mat: Phi_L is a MATLAB cell"):
        _read(p)
    other = tmp_path / "other.mat"
    savemat(other, {"A": np.ones(2)})
    assert main(["calibrate-import", str(other), "--profile", "virtual-mini", "--out",
                 str(tmp_path / "o")]) == 2
    err = capfd.readouterr().err
    assert "found arrays A; expected Po, Qo, Pc, Qc" in err and "Traceback" not in err
