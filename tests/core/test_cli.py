from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from thintact_sdk import __version__
from thintact_sdk.apps.cli.main import main


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "thintact_sdk.apps.cli.main", *args], capture_output=True, text=True, timeout=120
    )


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_validate_accepts_shipped_and_golden(golden_dir: Path, repo_root: Path) -> None:
    files = [str(p) for p in sorted((repo_root / "thintact_sdk" / "profiles").glob("*.yaml"))]
    files += [str(golden_dir / n / "profile.json") for n in ("mini", "wide")]
    assert main(["profile", "validate", *files]) == 0


def test_validate_rejects_bad_profile_with_field_and_exit_2(tmp_path: Path, golden_dir: Path) -> None:
    d = json.loads((golden_dir / "mini" / "profile.json").read_text())
    d["scene"]["cols"] = "sixty-four"
    del d["geometry"]["mask_to_sensor_mm"]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    r = run_cli("profile", "validate", str(bad))
    assert r.returncode == 2
    assert "scene.cols" in r.stderr
    assert "geometry.mask_to_sensor_mm" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize(
    "args",
    [
        ["profile", "validate", "/nonexistent/profile.yaml"],
        ["profile", "show", "no-such-device"],
        ["no-such-command"],
    ],
)
def test_bad_input_is_one_message_exit_2(args: list[str]) -> None:
    r = run_cli(*args)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert r.stderr.strip()


def test_unparseable_profile(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("sensor: [unclosed\n")
    r = run_cli("profile", "validate", str(bad))
    assert r.returncode == 2 and "cannot parse" in r.stderr and "Traceback" not in r.stderr


def test_profile_show(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["profile", "show", "thintact-paper", "--json"]) == 0
    out = capsys.readouterr().out
    data = json.loads(out[: out.rindex("}") + 1])
    assert data["name"] == "thintact-paper" and data["scene"]["pixel_pitch_um"] == 31.5


def test_two_word_commands_name_the_hyphenated_ones() -> None:
    from thintact_sdk.apps.cli.main import join_two_word_command

    names = ["calibrate", "calibrate-pose", "calibrate-import", "diagnose"]
    assert join_two_word_command(["calibrate", "pose", "flat.npy"], names) == ["calibrate-pose", "flat.npy"]
    assert join_two_word_command(["calibrate", "import", "-h"], names) == ["calibrate-import", "-h"]
    assert join_two_word_command(["calibrate", "--profile", "p.json"], names) == ["calibrate", "--profile", "p.json"]
    assert join_two_word_command(["calibrate", "wizard"], names) == ["calibrate", "wizard"]
    assert join_two_word_command(["diagnose", "rec"], names) == ["diagnose", "rec"]


def test_calibrate_import_spelt_as_two_words_reaches_its_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["calibrate", "import", "--help"])
    assert done.value.code == 0
    assert "calibrate-import" in capsys.readouterr().out
