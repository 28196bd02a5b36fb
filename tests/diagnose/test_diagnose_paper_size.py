"""Issue 17, full-size recordings: the paper's device (1024×1280 sensor, 400×512 scene, 12
frames) with a concealed effect is diagnosed right within 10 minutes and 8 GiB (slow: about
2.5 min to render and 4-6 min to diagnose on the 2-core reference host)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import pytest


def _tool(repo_root: Path, name: str) -> Any:
    spec = importlib.util.spec_from_file_location(name, repo_root / "tools" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
@pytest.mark.timeout(1800)  # render (~2.5-3 min) + the diagnosis's own 10-minute bound
def test_paper_size_concealed_case_is_diagnosed_within_limits(repo_root: Path, tmp_path: Path) -> None:
    tool = _tool(repo_root, "diagnose_paper_size")
    rc = tool.main(["--out", str(tmp_path), "--case", "pixel_angular_response"])
    result = json.loads((tmp_path / "result.json").read_text())
    assert rc == 0, result["problems"]
    assert result["findings"][0]["effect"] == "pixel_angular_response"
    assert result["diagnose_s"] <= 600 and result["peak_rss_gib"] <= 8
    assert result["binned"]["factor"] == 8


@pytest.mark.slow
@pytest.mark.timeout(1800)  # render (~2.5-3 min) + the diagnosis's own 10-minute bound
def test_paper_size_mask_shift_is_named_with_the_angle_held(repo_root: Path, tmp_path: Path) -> None:
    """A pure mask shift (7, -4) um at the paper's size: the rotated family is too large
    there, so the angle is held at 0 during the 8×8 selection; the shift is screened on the
    plain separable kernel and named (its binned change is under the amplitude floor, its
    unbinned one above it), and the angle, screened afterwards on 32×32 blocks, stays 0."""
    tool = _tool(repo_root, "diagnose_paper_size")
    rc = tool.main(["--out", str(tmp_path), "--case", "mask_shift"])
    result = json.loads((tmp_path / "result.json").read_text())
    assert rc == 0, result["problems"]
    f = result["findings"][0]
    assert f["effect"] == "mask_misalignment" and f["params"]["angle_deg"] == 0.0
    assert "mask_misalignment.angle_deg" not in result["binned"]["not_screened"]
    coarse = result["binned"]["coarse_angle"]
    assert coarse["ran"] and not coarse["accepted"] and coarse["factor"] == 32
    assert result["diagnose_s"] <= 600 and result["peak_rss_gib"] <= 8


@pytest.mark.slow
@pytest.mark.timeout(2400)  # render (~7.5 min, 48 windows streamed) + the diagnosis's 10-minute bound
def test_paper_size_mask_rotation_is_named(repo_root: Path, tmp_path: Path) -> None:
    """A 0.1° mask rotation at the paper's size (measured: 0.1013°, 142.5 s, 4.09 GiB): held in
    the 8×8 selection, fitted on 32×32 blocks, its change measured on windows of the unbinned
    sensor (1.3e-3 of the signal, over the floor; 1.1e-4 on the blocks), confirmed on the 8×8
    data. The full-size check says why the whole sensor was not evaluated (48 windows, 6.6 GiB)
    and checks the fit on 6 of its windows instead."""
    tool = _tool(repo_root, "diagnose_paper_size")
    rc = tool.main(["--out", str(tmp_path), "--case", "mask_rotation"])
    result = json.loads((tmp_path / "result.json").read_text())
    assert rc == 0, result["problems"]
    coarse = result["binned"]["coarse_angle"]
    assert coarse["accepted"] and coarse["fine_amplitude"] > 6e-4 > coarse["amplitude_fraction"]
    assert result["diagnose_s"] <= 600 and result["peak_rss_gib"] <= 8
    # the whole sensor's rotated kernel is refused, so the fit is checked on unbinned windows
    full = result["full_size"]
    assert "windows" in full["not_evaluated"]
    assert full["windows"]["chi2_per_dof"] < 1.01, full["windows"]


@pytest.mark.slow
@pytest.mark.timeout(3600)  # 17 effects, up to ~3 min each under load
def test_every_effect_simulates_at_paper_size_or_refuses_cleanly(repo_root: Path, tmp_path: Path) -> None:
    """Each single effect simulates 12 paper-size frames within 8 GiB, except the rotated
    mask and refraction, whose tabulated families do not fit: those refuse with a
    ThinTactError at once (no MemoryError, no swap storm)."""
    tool = _tool(repo_root, "bench_paper_effects")
    out = tmp_path / "rows.json"
    tool.main(["--json", str(out)])
    rows = json.loads(out.read_text())
    for row in rows:
        assert "failed" not in row, row
        assert row["peak_rss_gib"] <= 8, row
        if "refused" in row:
            assert row["case"] in {"refraction", "mask_misalignment", "mask_rotation_035"}, row
            assert row["after_s"] < 60, row
        else:
            assert row["build_s"] + row["simulate_s"] < 600, row


@pytest.mark.slow
@pytest.mark.timeout(1800)
@pytest.mark.parametrize("case", ["sensor_blur", "subfloor_leakage"])
def test_paper_size_sub_block_and_sub_floor_cases(repo_root: Path, tmp_path: Path, case: str) -> None:
    """A 10 um sensor blur (binned it looks like a scene blur; the unbinned stage puts the
    blur in its place) and a 3 % leakage under the amplitude floor (named because its fit is
    decisive and stable under refit), each within the limits."""
    tool = _tool(repo_root, "diagnose_paper_size")
    rc = tool.main(["--out", str(tmp_path), "--case", case])
    result = json.loads((tmp_path / "result.json").read_text())
    assert rc == 0, result["problems"]
    assert result["diagnose_s"] <= 600 and result["peak_rss_gib"] <= 8
