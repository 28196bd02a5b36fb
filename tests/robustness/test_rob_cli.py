"""The CLI's one rule: bad input → one line and exit 2, before any work and without writing;
valid input → a finite result; nothing existing is overwritten without --force."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from thintact_sdk.apps.cli.main import main


def one_error(capfd: pytest.CaptureFixture[str], *needles: str) -> str:
    """The single stderr line of a refused command (asserting there is exactly one)."""
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "error:" in lines[0] and "internal error" not in lines[0], err
    for n in needles:
        assert n in lines[0], err
    return lines[0]


def _reconstruct(tiny: dict[str, Any], rec: Path, out: Path, *extra: str) -> int:
    return main(["reconstruct", str(rec), "--calibration", str(tiny["bundle"]), "--out", str(out),
                 "--no-progress", "--decoder", "flatcam", *extra])


# -- arguments ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["reconstruct", "R", "--calibration", "C", "--out", "O", "--tau", "-1"], "--tau: must be > 0"),
        (["reconstruct", "R", "--calibration", "C", "--out", "O", "--tau", "nan"], "finite"),
        (["simulate", "--profile", "P", "--scenes", "S", "--out", "O", "--seed", "-1"], "--seed"),
        (["simulate", "--profile", "P", "--scenes", "S", "--out", "O", "--gain", "0"], "--gain"),
        (["diagnose", "R", "--out", "O", "--sys-frac", "nan"], "--sys-frac: expected a finite number"),
        (["diagnose", "R", "--out", "O", "--time-budget", "inf"], "--time-budget"),
        (["diagnose", "R", "--out", "O", "--max-effects", "-2"], "--max-effects"),
        (["record", "--profile", "P", "--frames", "0", "--out", "O"], "--frames"),
        (["record", "--profile", "P", "--frames", "3", "--out", "O", "--timeout", "0"], "--timeout"),
        (["calibrate-tactile", "--profile", "P", "--bins", "3"], "--bins"),
    ],
)
def test_bad_arguments_are_one_line_exit_2(argv: list[str], needle: str, capfd: Any) -> None:
    assert main(argv) == 2
    one_error(capfd, needle)


@pytest.mark.parametrize("frames", ["0", "-1", "x"])
def test_calibrate_bad_frames_leaves_no_capture_directory(frames: str, tmp_path: Path, monkeypatch: Any,
                                                          capfd: Any) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", "--profile", "virtual-mini", "--frames", frames]) == 2
    one_error(capfd, "--frames")
    assert list(tmp_path.iterdir()) == []


# -- output paths ---------------------------------------------------------------------------
def test_empty_out_is_refused_everywhere(tiny: dict[str, Any], tmp_path: Path, monkeypatch: Any,
                                         capfd: Any) -> None:
    monkeypatch.chdir(tmp_path)
    rec, cal, prof = str(tiny["recording"]), str(tiny["bundle"]), str(tiny["profile_file"])
    for argv in (
        ["reconstruct", rec, "--calibration", cal, "--out", ""],
        ["diagnose", rec, "--out", " "],
        ["simulate", "--profile", prof, "--scenes", str(tiny["scenes_file"]), "--out", ""],
        ["calibrate", "--from-recording", rec, "--out", ""],
        ["calibrate", "--profile", "virtual-mini", "--out", ""],
        ["record", "--profile", "virtual-mini", "--frames", "1", "--out", ""],
        ["calibrate-tactile", "--profile", "virtual-finger", "--out", ""],
        ["demo", "--out", ""],
    ):
        assert main(argv) == 2, argv
        one_error(capfd, "--out is empty")
    assert list(tmp_path.iterdir()) == []


def test_existing_outputs_need_force(tiny: dict[str, Any], tmp_path: Path, capfd: Any) -> None:
    out = tmp_path / "o"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert _reconstruct(tiny, tiny["recording"], out) == 2
    one_error(capfd, "already exists and is not empty", "--force")
    assert _reconstruct(tiny, tiny["recording"], out, "--force") == 0
    assert (out / "keep.txt").read_text() == "mine" and len(list(out.glob("*.npy"))) == 3
    capfd.readouterr()
    target = tmp_path / "y.npy"
    target.write_bytes(b"old")
    argv = ["simulate", "--profile", str(tiny["profile_file"]), "--scenes", str(tiny["scenes_file"]),
            "--out", str(target)]
    assert main(argv) == 2
    one_error(capfd, "already exists", "--force")
    assert target.read_bytes() == b"old"
    assert main([*argv, "--force"]) == 0
    assert np.isfinite(np.load(target)).all()


def test_simulate_writes_exactly_the_named_file(tiny: dict[str, Any], tmp_path: Path) -> None:
    target = tmp_path / "y.out"
    assert main(["simulate", "--profile", str(tiny["profile_file"]), "--scenes",
                 str(tiny["scenes_file"]), "--out", str(target)]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["y.out"]  # not y.out.npy
    assert np.load(target).shape == (3, 24, 30, 3)


@pytest.mark.parametrize("command", ["diagnose", "calibrate"])
def test_out_is_checked_before_any_work(command: str, tiny: dict[str, Any], tmp_path: Path,
                                        capfd: Any, monkeypatch: Any) -> None:
    out = tmp_path / "o"
    out.mkdir()
    (out / "report.json").write_text("{}")
    called: list[str] = []
    import thintact_sdk.formats.recording as recording

    monkeypatch.setattr(recording.Recording, "__init__", lambda *a, **k: called.append("read"))
    argv = (["diagnose", str(tiny["recording"]), "--out", str(out)] if command == "diagnose"
            else ["calibrate", "--from-recording", str(tiny["recording"]), "--out", str(out)])
    assert main(argv) == 2
    one_error(capfd, str(out), "--force")
    assert called == []  # refused before the recording was even opened


def test_calibrate_tactile_never_overwrites_the_shipped_lut(tmp_path: Path, monkeypatch: Any,
                                                             capfd: Any, repo_root: Path) -> None:
    shipped = repo_root / "thintact_sdk" / "data" / "calibrations" / "virtual-finger" / "tactile" / "lut.npz"
    before = hashlib.sha256(shipped.read_bytes()).hexdigest()
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("THINTACT_CALIBRATION_PATH", raising=False)
    mine = tmp_path / "calibrations" / "virtual-finger" / "tactile" / "lut.npz"
    mine.parent.mkdir(parents=True)
    mine.write_bytes(b"an earlier calibration")
    assert main(["calibrate-tactile", "--profile", "virtual-finger", "--presses", "1"]) == 2
    one_error(capfd, str(mine), "--force")
    assert mine.read_bytes() == b"an earlier calibration"
    assert hashlib.sha256(shipped.read_bytes()).hexdigest() == before


def test_record_refuses_an_existing_recording_without_append(tiny: dict[str, Any], capfd: Any) -> None:
    assert main(["record", "--profile", "virtual-mini", "--frames", "1", "--out",
                 str(tiny["recording"]), "--force"]) == 2
    one_error(capfd, "already holds a recording", "--append")


# -- NaN / Inf / empty data -------------------------------------------------------------------
def _nan_patch(rec: Path, tiny: dict[str, Any], value: float = np.nan, frames: tuple[int, ...] = (1,)) -> None:
    for i in frames:
        m = tiny["meas"][i].astype(np.float32)
        if len(frames) == 1:
            m[5:15, 5:15, :] = value
        else:
            m[:] = value
        np.save(rec / "measurements" / f"{i:03d}.npy", m)


def test_reconstruct_refuses_a_nan_patch_naming_the_frame_and_writes_nothing(
        tiny: dict[str, Any], rec_copy: Path, tmp_path: Path, capfd: Any) -> None:
    _nan_patch(rec_copy, tiny)
    out = tmp_path / "o"
    assert _reconstruct(tiny, rec_copy, out) == 2
    one_error(capfd, "frame 1 (f1)", "NaN/Inf")
    assert not out.exists()


def test_reconstruct_gives_finite_estimates_on_clean_data(tiny: dict[str, Any], tmp_path: Path) -> None:
    assert _reconstruct(tiny, tiny["recording"], tmp_path / "o") == 0
    white = np.load(tmp_path / "o" / "000.npy")
    assert white.shape == (10, 12, 3) and np.isfinite(white).all()
    assert abs(float(white.mean()) - 1.0) < 0.3  # the white frame comes back near white


@pytest.mark.parametrize("frames", [(1,), (0, 1, 2)], ids=["patch", "all-nan"])
def test_diagnose_refuses_nan_before_any_lapack_call(tiny: dict[str, Any], rec_copy: Path,
                                                     tmp_path: Path, capfd: Any,
                                                     frames: tuple[int, ...]) -> None:
    _nan_patch(rec_copy, tiny, frames=frames)
    assert main(["diagnose", str(rec_copy), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    line = one_error(capfd, f"frame {frames[0]} (f{frames[0]})", "NaN/Inf")
    assert "LinAlgError" not in line and "DLASCL" not in line and "no structure" not in line
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["reconstruct", "diagnose", "calibrate"])
def test_an_empty_recording_is_exit_2(command: str, tiny: dict[str, Any], rec_copy: Path,
                                     tmp_path: Path, capfd: Any) -> None:
    manifest = json.loads((rec_copy / "manifest.json").read_text())
    (rec_copy / "manifest.json").write_text(json.dumps({**manifest, "frames": []}))
    argv = {"reconstruct": ["reconstruct", str(rec_copy), "--calibration", str(tiny["bundle"])],
            "diagnose": ["diagnose", str(rec_copy)],
            "calibrate": ["calibrate", "--from-recording", str(rec_copy)]}[command]
    assert main([*argv, "--out", str(tmp_path / "o")]) == 2
    one_error(capfd, "holds no frames")


@pytest.mark.parametrize("content", [b"", "no-frames"], ids=["zero-bytes", "zero-scenes"])
def test_simulate_on_an_empty_scenes_file(content: Any, tiny: dict[str, Any], tmp_path: Path,
                                          capfd: Any) -> None:
    scenes = tmp_path / "s.npy"
    if content == b"":
        scenes.write_bytes(b"")
    else:
        np.save(scenes, np.zeros((0, 10, 12, 3), np.float32))
    assert main(["simulate", "--profile", str(tiny["profile_file"]), "--scenes", str(scenes),
                 "--out", str(tmp_path / "y.npy")]) == 2
    one_error(capfd, str(scenes))
    assert not (tmp_path / "y.npy").exists()


@pytest.mark.parametrize(("value", "needle"), [(0, "reads 0 DN at every pixel, at the black level"),
                                               (64, "a dead frame (no light"),
                                               (500, "reads 500 DN at every pixel although its scene is lit, "
                                                     "neither the black level")])
def test_diagnose_refuses_dead_and_stuck_frames(value: int, needle: str, tiny: dict[str, Any],
                                                    rec_copy: Path, tmp_path: Path, capfd: Any) -> None:
    np.save(rec_copy / "measurements" / "001.npy", np.full((24, 30, 3), value, np.uint16))
    assert main(["diagnose", str(rec_copy), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    line = one_error(capfd, "frame 1 (f1)", needle)
    assert "no structure" not in line.lower()
    assert not (tmp_path / "o").exists()


def test_diagnose_keeps_a_saturated_frame_as_data(tiny: dict[str, Any], rec_copy: Path, tmp_path: Path,
                                                  capfd: Any) -> None:
    """Saturated is not dead: a frame at saturation_dn everywhere is flagged and diagnosed."""
    np.save(rec_copy / "measurements" / "001.npy", np.full((24, 30, 3), 4095, np.uint16))
    assert main(["diagnose", str(rec_copy), "--out", str(tmp_path / "o"), "--quiet"]) == 0
    err = capfd.readouterr().err
    assert "1 frame(s) saturated at every pixel: f1 (4095 DN)" in err and "dead" not in err
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["saturated_frames"] == {"f1": 4095.0}


def test_diagnose_never_writes_a_report_with_nan_figures() -> None:
    from thintact_sdk.diagnosis.imaging.from_recording import check_finite_report as _check_finite
    from thintact_sdk.errors import ThinTactError

    good = {"noise_rms_dn": 2.0, "baseline": {"rms_dn": 3.0, "chi2_per_dof": 1.2},
            "final": {"rms_dn": 2.1, "chi2_per_dof": 1.0}}
    _check_finite(good)
    with pytest.raises(ThinTactError, match=r"non-finite baseline.rms_dn, baseline.chi2_per_dof"):
        _check_finite({**good, "baseline": {"rms_dn": float("nan"), "chi2_per_dof": float("nan")}})


def test_record_append_of_another_device_is_refused_before_the_camera_opens(
        tiny: dict[str, Any], rec_copy: Path, capfd: Any, monkeypatch: Any) -> None:
    import thintact_sdk.device.capture_record as record_cmd

    monkeypatch.setattr(record_cmd, "create_camera", lambda *a, **k: pytest.fail("camera opened"))
    manifest_before = (rec_copy / "manifest.json").read_text()
    assert main(["record", "--profile", "virtual-mini", "--frames", "1", "--out", str(rec_copy),
                 "--append", "--quiet"]) == 2
    one_error(capfd, "'robust-tiny' (sensor 24×30×3", "'virtual-mini' (sensor 128×160×3")
    assert (rec_copy / "manifest.json").read_text() == manifest_before


def test_claim_output_policy(tmp_path: Path) -> None:
    from thintact_sdk.apps.cli.output_path import claim_output
    from thintact_sdk.errors import OutputError

    (tmp_path / "f.npy").write_bytes(b"x")
    (tmp_path / "empty").mkdir()
    assert claim_output(tmp_path / "new", "directory") == tmp_path / "new"
    assert claim_output(tmp_path / "empty", "directory") == tmp_path / "empty"
    assert claim_output(tmp_path / "f.npy", "file", force=True) == tmp_path / "f.npy"
    for path, kind, needle in [("", "file", "is empty"), (tmp_path / "empty", "file", "is a directory"),
                               (tmp_path / "f.npy", "directory", "is a file"),
                               (tmp_path / "f.npy", "file", "already exists"),
                               (tmp_path, "directory", "not empty")]:
        with pytest.raises(OutputError, match=needle):
            claim_output(path, kind)  # type: ignore[arg-type]


def test_new_luts_go_to_the_users_calibrations_never_the_checkout(tmp_path: Path, monkeypatch: Any,
                                                                   repo_root: Path) -> None:
    from thintact_sdk.tactile.calibration.store import calibration_roots, user_calibrations_root

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("THINTACT_CALIBRATION_PATH", raising=False)
    assert user_calibrations_root() == tmp_path / "calibrations"
    assert calibration_roots()[-1] == repo_root / "thintact_sdk" / "data" / "calibrations"  # packaged, last
    monkeypatch.setenv("THINTACT_CALIBRATION_PATH", f"{tmp_path / 'a'}:{tmp_path / 'b'}")
    assert user_calibrations_root() == tmp_path / "a"


def test_an_output_that_is_a_dangling_link_or_a_device_is_refused(tmp_path):
    """A dangling link wrote its target elsewhere without --force; ``--force`` onto /dev/full
    made the MCAP writer unlink the device node and put a file there."""
    import os

    from thintact_sdk.apps.cli.output_path import claim_output
    from thintact_sdk.errors import OutputError

    link = tmp_path / "out.json"
    os.symlink(tmp_path / "elsewhere" / "x.json", link)
    with pytest.raises(OutputError, match="symbolic link .*does not exist"):
        claim_output(link, "file")
    assert claim_output(link, "file", force=True) == link
    for device in ("/dev/null", "/dev/full"):
        if os.path.exists(device):
            for force in (False, True):
                with pytest.raises(OutputError, match="not a regular file"):
                    claim_output(device, "file", force=force)
    os.mkfifo(tmp_path / "pipe")
    with pytest.raises(OutputError, match="not a regular file"):
        claim_output(tmp_path / "pipe", "directory", force=True)
