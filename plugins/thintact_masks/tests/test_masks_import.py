"""``thintact mask import`` (issue 32): a mask drawn elsewhere becomes φ, φ_rows in the SDK's
convention, or is refused naming why."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from thintact_sdk.apps.cli.main import main


def _pattern(k: int = 12, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    phi, rows = rng.choice([-1, 1], k), rng.choice([-1, 1], k)
    phi[0] = 1
    return phi, rows, (np.outer(rows, phi) > 0)  # open where φ_rows[i]·φ[j] = +1


@pytest.mark.parametrize("kind", ["png", "csv", "npy", "vectors"])
def test_import_recovers_phi_and_phi_rows(tmp_path: Path, kind: str, capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    phi, rows, open_cells = _pattern()
    src = tmp_path / f"mask.{'csv' if kind == 'vectors' else kind}"
    extra: list[str] = []
    if kind == "png":  # 5 px per cell, open white
        Image.fromarray(np.kron(open_cells, np.ones((5, 5))).astype(np.uint8) * 255).save(src)
        extra = ["--K", "12"]
    elif kind == "csv":
        np.savetxt(src, open_cells.astype(int), fmt="%d", delimiter=",")
    elif kind == "npy":
        np.save(src, open_cells.astype(np.uint8))
    else:
        np.savetxt(src, np.stack([phi, rows]), fmt="%d", delimiter=",")
    out = tmp_path / "design.json"
    assert main(["mask", "import", str(src), "--feature-um", "40", "--out", str(out), *extra]) == 0
    rec = json.loads(out.read_text())
    assert rec["phi"] == phi.tolist() and rec["phi_rows"] == rows.tolist() and rec["feature_um"] == 40.0


def test_a_pattern_that_is_not_separable_is_refused(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    _, _, open_cells = _pattern()
    broken = open_cells.copy()
    broken[3, 4] = ~broken[3, 4]
    np.save(tmp_path / "m.npy", broken.astype(np.uint8))
    assert main(["mask", "import", str(tmp_path / "m.npy"), "--feature-um", "40", "--out",
                 str(tmp_path / "d.json")]) == 2
    assert "1 of 144 cells" in capsys.readouterr().err
