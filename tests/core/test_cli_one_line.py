"""Every refusal the CLI prints is one line (issue 30): pydantic errors that reach the user,
multi-line SDK errors, ``real2sim train --mm-per-px nan`` and ``thintact`` with no command."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest
from pydantic import ValidationError

import thintact_sdk.apps.cli.commands.profile as profile_cmd
from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import CameraSettingsError
from thintact_sdk.formats.profiles import SceneSpec, validation_error_line


def test_thintact_alone_says_why_in_one_line() -> None:
    r = subprocess.run([sys.executable, "-m", "thintact_sdk.apps.cli.main"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert r.stderr == "thintact: no command given; try 'thintact --help'\n"
    assert r.stdout == ""


@pytest.mark.parametrize(("value", "why"), [
    ("nan", "expected a finite number, got 'nan'"),
    ("inf", "expected a finite number, got 'inf'"),
    ("-1", "must be between 0.0001 and 10, got '-1'"),
    ("1e-9", "must be between 0.0001 and 10, got '1e-9'"),
])
def test_real2sim_mm_per_px_refused_at_the_argument(tmp_path, capsys: pytest.CaptureFixture[str],
                                                    value: str, why: str) -> None:
    rc = main(["real2sim", "train", "--real", str(tmp_path / "p.npz"), "--out", str(tmp_path / "o"),
               "--mm-per-px", value])
    assert rc == 2
    err = capsys.readouterr().err
    assert err == (f"thintact real2sim train: error: argument --mm-per-px: {why} "
                   "(see thintact real2sim train --help)\n")
    assert not (tmp_path / "o").exists()


def _scene_error() -> ValidationError:
    try:
        SceneSpec.model_validate({"rows": 0, "cols": "x", "pixel_pitch_um": float("nan")})
    except ValidationError as err:
        return err
    raise AssertionError("validated")


def test_validation_error_line_names_the_first_field_and_counts_the_rest() -> None:
    assert validation_error_line(_scene_error()) == (
        "rows: Input should be greater than 0 (and 2 more: cols, pixel_pitch_um)")


def test_a_pydantic_error_reaching_the_cli_is_one_line(monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    def boom(args: argparse.Namespace) -> int:
        raise _scene_error()

    monkeypatch.setattr(profile_cmd, "load_profile", boom)
    assert main(["profile", "show", "virtual-mini"]) == 2
    err = capsys.readouterr().err
    assert err == "thintact: error: rows: Input should be greater than 0 (and 2 more: cols, pixel_pitch_um)\n"


def test_a_multi_line_sdk_error_is_one_line(monkeypatch: pytest.MonkeyPatch,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    def boom(args: argparse.Namespace) -> int:
        raise CameraSettingsError("invalid virtual camera settings:\n  - camera.settings.fps: bad\n"
                                  "  - camera.settings.seed: bad\n  - camera.settings.x: unknown")

    monkeypatch.setattr(profile_cmd, "load_profile", boom)
    assert main(["profile", "show", "virtual-mini"]) == 2
    assert capsys.readouterr().err == (
        "thintact: error: invalid virtual camera settings: camera.settings.fps: bad (and 2 more)\n")
