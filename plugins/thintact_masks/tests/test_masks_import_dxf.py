"""``thintact mask import`` of DXF drawings and ``mask apply`` keeping the profile's text
(issue 32 item 4)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from thintact_sdk.apps.cli.main import main

ezdxf = pytest.importorskip("ezdxf")


def _pattern(k: int = 10, seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    phi, rows = rng.choice([-1, 1], k), rng.choice([-1, 1], k)
    phi[0] = 1
    return phi, rows, np.outer(rows, phi) > 0


def _write_dxf(path: Path, open_cells: np.ndarray, pitch: float, how: str, units: int = 4) -> None:
    """Open cells drawn the way a mask drawing does: one closed polyline, solid or hatch per
    cell, or one polyline per horizontal run of open cells; a line and an open polyline as
    clutter. Row 0 at the top."""
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = units
    msp = doc.modelspace()
    k = open_cells.shape[0]
    msp.add_line((0, -pitch), (k * pitch, -pitch))  # a dimension line: ignored
    msp.add_lwpolyline([(0, -2 * pitch), (pitch, -3 * pitch)])  # open polyline: ignored
    for i in range(k):
        y1 = (k - i) * pitch
        y0 = y1 - pitch
        j = 0
        while j < k:
            if not open_cells[i, j]:
                j += 1
                continue
            end = j + 1
            if how == "runs":
                while end < k and open_cells[i, end]:
                    end += 1
            x0, x1 = j * pitch, end * pitch
            if how == "solid":
                msp.add_solid([(x0, y0), (x1, y0), (x0, y1), (x1, y1)])
            elif how == "hatch":
                h = msp.add_hatch()
                h.paths.add_polyline_path([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], is_closed=True)
            else:
                msp.add_lwpolyline([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], close=True)
            j = end
    doc.saveas(path)


@pytest.mark.parametrize("how", ["polyline", "runs", "solid", "hatch"])
def test_dxf_open_cells_give_phi_and_phi_rows(tmp_path: Path, how: str, capsys) -> None:  # type: ignore[no-untyped-def]
    phi, rows, open_cells = _pattern()
    src = tmp_path / "mask.dxf"
    _write_dxf(src, open_cells, 0.04, how)  # 40 um cells in mm: K from $INSUNITS and the feature size
    out = tmp_path / "design.json"
    assert main(["mask", "import", str(src), "--feature-um", "40", "--out", str(out)]) == 0
    rec = json.loads(out.read_text())
    assert rec["phi"] == phi.tolist() and rec["phi_rows"] == rows.tolist()


def test_dxf_closed_cells_drawn_and_unknown_units(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    phi, rows, open_cells = _pattern(8, 11)
    src = tmp_path / "closed.dxf"
    _write_dxf(src, ~open_cells, 1.0, "polyline", units=0)
    out = tmp_path / "d.json"
    # no unit and no --K: refused naming what to give
    assert main(["mask", "import", str(src), "--feature-um", "40", "--out", str(out)]) == 2
    assert "--K" in capsys.readouterr().err
    assert main(["mask", "import", str(src), "--feature-um", "40", "--K", "8", "--open-dark",
                 "--out", str(out)]) == 0
    rec = json.loads(out.read_text())
    assert rec["phi"] == phi.tolist() and rec["phi_rows"] == rows.tolist()


def test_dxf_off_pitch_or_not_separable_is_refused(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    _, _, open_cells = _pattern()
    src = tmp_path / "mask.dxf"
    _write_dxf(src, open_cells, 0.04, "polyline")
    assert main(["mask", "import", str(src), "--feature-um", "37", "--out", str(tmp_path / "a.json")]) == 2
    assert "cells of 37 um" in capsys.readouterr().err
    broken = open_cells.copy()
    broken[4, 5] = ~broken[4, 5]
    _write_dxf(src, broken, 0.04, "polyline")
    assert main(["mask", "import", str(src), "--feature-um", "40", "--out", str(tmp_path / "b.json")]) == 2
    assert "1 of 100 cells" in capsys.readouterr().err


def test_apply_keeps_the_profiles_comments_and_writes_phi_in_flow_style(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    from thintact_sdk.formats.profiles import available_profiles, load_profile

    src_text = available_profiles()["virtual-mini"].read_text()
    profile_file = tmp_path / "unit.yaml"
    profile_file.write_text(src_text.replace("noise:", "# our unit's noise, measured by hand\nnoise:", 1))
    k = load_profile(profile_file).mask.K
    phi, rows, open_cells = _pattern(k, 2)
    np.save(tmp_path / "m.npy", open_cells.astype(np.uint8))
    design = tmp_path / "design.json"
    assert main(["mask", "import", str(tmp_path / "m.npy"), "--feature-um", "30", "--out", str(design)]) == 0
    out = tmp_path / "applied.yaml"
    assert main(["mask", "apply", str(design), "--profile", str(profile_file), "--out", str(out)]) == 0
    text = out.read_text()
    before = [ln for ln in profile_file.read_text().splitlines() if ln.lstrip().startswith("#")]
    after = [ln for ln in text.splitlines() if ln.lstrip().startswith("#")]
    assert before and set(before) <= set(after)
    assert "  phi: [1, " in text and "\n  - " not in text.split("mask:")[1].split("\n\n")[0]
    got = load_profile(out)
    assert got.mask.phi == phi.tolist() and got.mask.rows_vector == rows.tolist()
    assert got.mask.feature_um == 30.0 and got.name == load_profile(profile_file).name
    # outside the mask section the text is unchanged
    strip = [ln for ln in text.splitlines() if not ln.startswith("  ") and not ln.startswith("mask:")]
    orig = [ln for ln in profile_file.read_text().splitlines() if not ln.startswith("  ")
            and not ln.startswith("mask:")]
    assert strip == orig
    assert yaml.safe_load(text)["mask"]["phi"] == phi.tolist()
