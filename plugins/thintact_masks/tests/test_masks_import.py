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


def _png_declaring(width: int, height: int) -> bytes:
    """A PNG header declaring ``width × height`` grey pixels, with almost no data."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 100)) + chunk(b"IEND", b""))


@pytest.mark.parametrize(("name", "content", "says"), [
    ("bomb.png", _png_declaring(16000, 16000), "declares too many pixels"),
    ("short.png", _png_declaring(300, 300), "not a readable PNG"),
    ("junk.png", b"\x89PNG but not really" * 9, "not a readable PNG"),
    ("latin.csv", b"1,\xff\xfe,1\n", "not UTF-8 text"),
])
def test_a_damaged_design_file_is_one_line_naming_it(tmp_path: Path, name: str, content: bytes, says: str,
                                                     capsys) -> None:  # type: ignore[no-untyped-def]
    """A bomb's header, a truncated or foreign PNG and a non-UTF-8 CSV exit 2 in one line
    (the bomb and the CSV were internal errors, exit 1)."""
    path = tmp_path / name
    path.write_bytes(content)
    assert main(["mask", "import", str(path), "--K", "11", "--feature-um", "60",
                 "--out", str(tmp_path / "d.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and name in err and says in err and "internal" not in err, err
