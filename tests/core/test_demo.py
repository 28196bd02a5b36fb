"""The README's main job: ``thintact demo`` on the built-in virtual sensor."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from thintact_sdk.apps.cli.main import main


@pytest.mark.timeout(300)
def test_demo_runs_end_to_end_and_is_accurate(tmp_path: Path) -> None:
    assert main(["demo", "--out", str(tmp_path)]) == 0
    png = tmp_path / "demo.png"
    assert png.stat().st_size > 50_000
    summary = json.loads((tmp_path / "demo.json").read_text())
    assert summary["profile"] == "virtual-finger"
    assert summary["psnr_db"] > 18.0
    assert summary["contact"] is True
    assert summary["depth_rms_error_mm"] < 0.05
    assert summary["depth_rms_error_in_contact_mm"] < 0.08
    assert 0.3 < summary["depth_max_mm"]["estimated"] < 1.0
    assert summary["markers_tracked"] >= 40
    assert summary["marker_displacement_rms_error_mm"] < 0.06


def test_demo_refuses_a_real_camera_profile(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    # its own --out: `make demo` leaves ./demo-output behind, which the demo refuses first
    assert main(["demo", "--profile", "thintact-paper", "--out", str(tmp_path / "demo")]) == 2
    assert "virtual" in capsys.readouterr().err


def test_the_library_demo_is_the_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``run_demo`` measures what ``thintact demo`` writes to demo.json (the virtual camera's
    noise is seeded; only the wall-clock latency differs), and ``demo_figure`` draws it."""
    from thintact_sdk.apps.viewer.demo_figure import demo_figure
    from thintact_sdk.device.virtual_demo import run_demo
    from thintact_sdk.errors import ThinTactError
    from thintact_sdk.formats.profiles import load_profile

    assert main(["demo", "--profile", "virtual-mini", "--out", str(tmp_path / "cli")]) == 0
    printed = capsys.readouterr().out
    written = json.loads((tmp_path / "cli" / "demo.json").read_text())
    profile = load_profile("virtual-mini")
    demo = run_demo(profile)
    lib = json.loads(json.dumps(demo.summary))
    for summary in (written, lib):
        summary.pop("raw_to_tactile_latency_ms")
    assert lib == written
    assert f"scaled by {demo.scale:.3f}, depth {demo.depth_mm:.2f} mm" in printed
    assert demo_figure(tmp_path / "lib.png", demo, profile).stat().st_size > 10_000
    with pytest.raises(ThinTactError, match="--depth-mm"):
        run_demo(profile, depth_mm=3.0)
