"""Silent damage (issue 30): an output never overlaps an input, concurrent writers of one
``record --out`` leave exactly one winner, numeric options are validated, singular
calibration bundles are refused, and a saturated frame is data, not a dead one."""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rob_kit
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thintact_sdk.apps.cli.main import build_parser, main
from thintact_sdk.apps.cli.output_path import LOCK_NAME, claim_output, write_lock
from thintact_sdk.errors import CalibrationError, OutputError, RecordingError
from thintact_sdk.reconstruction.bundle import CalibrationBundle

FUZZ = settings(max_examples=30, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


def _digest(path: Path) -> str:
    """A hash of every file under ``path`` (names and bytes)."""
    h = hashlib.sha256()
    for p in sorted(path.rglob("*")) if path.is_dir() else [path]:
        if p.is_file():
            h.update(str(p.relative_to(path) if path.is_dir() else p.name).encode())
            h.update(p.read_bytes())
    return h.hexdigest()


def _one_error(capfd: pytest.CaptureFixture[str], *needles: str) -> str:
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    for n in needles:
        assert n in lines[0], err
    return lines[0]


# -- 1. outputs never overlap inputs ------------------------------------------------------

def test_reconstruct_into_the_recordings_own_measurements_is_refused_even_with_force(
        tiny: dict[str, Any], rec_copy: Path, capfd: Any) -> None:
    before = _digest(rec_copy)
    assert main(["reconstruct", str(rec_copy), "--calibration", str(tiny["bundle"]),
                 "--out", str(rec_copy / "measurements"), "--force", "--no-progress"]) == 2
    _one_error(capfd, "--out", "lies inside the input", "--force does not allow it")
    assert _digest(rec_copy) == before


def test_simulate_over_its_own_scenes_is_refused_even_with_force(tiny: dict[str, Any], tmp_path: Path,
                                                                 capfd: Any) -> None:
    scenes = tmp_path / "S.npy"
    scenes.write_bytes(tiny["scenes_file"].read_bytes())
    before = _digest(scenes)
    assert main(["simulate", "--profile", str(tiny["profile_file"]), "--scenes", str(scenes),
                 "--out", str(scenes), "--force"]) == 2
    _one_error(capfd, "is the input")
    assert _digest(scenes) == before


@pytest.mark.parametrize("where", ["bundle", "inside-bundle", "parent"])
def test_calibrate_export_never_writes_over_the_bundle(tiny: dict[str, Any], bundle_copy: Path,
                                                       where: str, capfd: Any) -> None:
    out = {"bundle": bundle_copy / "system_matrices.npz", "inside-bundle": bundle_copy / "m.npz",
           "parent": bundle_copy}[where]
    before = _digest(bundle_copy)
    assert main(["calibrate-export", str(bundle_copy), "--out", str(out), "--force"]) == 2
    _one_error(capfd, "the input")
    assert _digest(bundle_copy) == before


def test_diagnose_into_its_recording_is_refused(rec_copy: Path, capfd: Any) -> None:
    before = _digest(rec_copy)
    assert main(["diagnose", str(rec_copy), "--out", str(rec_copy), "--force", "--quiet"]) == 2
    _one_error(capfd, "is the input")
    assert _digest(rec_copy) == before


def test_record_over_its_profile_file_is_refused(tiny: dict[str, Any], tmp_path: Path, capfd: Any) -> None:
    profile = tmp_path / "p.json"
    profile.write_bytes(tiny["profile_file"].read_bytes())
    assert main(["record", "--profile", str(profile), "--frames", "1", "--format", "mcap",
                 "--out", str(profile), "--force", "--quiet"]) == 2
    _one_error(capfd, "is the input")
    assert profile.read_bytes() == tiny["profile_file"].read_bytes()


def _spellings(target: Path, base: Path, link: Path) -> list[str]:
    """Ways to name ``target`` (under ``base``): absolute, relative to the working directory,
    through ``..`` and ``.``, and through ``link`` (a symlink to ``base``)."""
    rel = target.relative_to(base)
    return [str(target), os.path.relpath(target), str(base / "x" / ".." / rel),
            str(base / "." / rel), str(link / rel), os.path.relpath(link / rel),
            str(link / "x" / ".." / rel)]


@FUZZ
@given(data=st.data())
def test_fuzz_overlap_spellings_are_refused(tmp_path: Path, data: st.DataObject) -> None:
    """Any spelling of an output that equals, lies inside or contains an input is refused,
    with or without --force; a sibling is not."""
    root = Path(os.path.realpath(tmp_path))
    base = root / "base"
    rec = base / "rec"
    if not rec.exists():
        (rec / "measurements").mkdir(parents=True)
        (rec / "measurements" / "000.npy").write_bytes(b"x")
        (base / "s.npy").write_bytes(b"s")
        (base / "x").mkdir()
        (root / "link").symlink_to(base, target_is_directory=True)
    link = root / "link"
    cwd = os.getcwd()
    os.chdir(root)
    try:
        inputs = [rec, base / "s.npy"]
        input_spelling = data.draw(st.sampled_from(_spellings(data.draw(st.sampled_from(inputs)), base, link)))
        src = Path(input_spelling)
        overlapping = [src, src / "measurements", src / "new" / "deeper", src.parent] \
            if Path(os.path.realpath(src)).is_dir() else [src, src.parent]
        out = data.draw(st.sampled_from(overlapping))
        out_spelling = data.draw(st.sampled_from(_spellings(Path(os.path.realpath(out)), base, link)
                                                 if Path(os.path.realpath(out)).is_relative_to(base)
                                                 else [str(out)]))
        kind = data.draw(st.sampled_from(["file", "directory"]))
        force = data.draw(st.booleans())
        with pytest.raises(OutputError, match="input"):
            claim_output(out_spelling, kind, force=force, inputs=[input_spelling])
        assert claim_output(base / "sibling", "directory", inputs=[input_spelling]) == base / "sibling"
    finally:
        os.chdir(cwd)


def test_a_hard_link_to_an_input_is_the_input(tmp_path: Path) -> None:
    (tmp_path / "s.npy").write_bytes(b"s")
    os.link(tmp_path / "s.npy", tmp_path / "t.npy")
    with pytest.raises(OutputError, match="is the input"):
        claim_output(tmp_path / "t.npy", "file", force=True, inputs=[tmp_path / "s.npy"])


def test_a_missing_input_is_no_overlap(tmp_path: Path) -> None:
    """Nothing that does not exist can be destroyed; the command names the missing input."""
    assert claim_output(tmp_path, "directory", force=True, inputs=[tmp_path / "nope"]) == tmp_path


# -- 2. concurrent writers: exactly one wins ----------------------------------------------

@pytest.fixture(scope="module")
def camera_profile(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tiny device with the virtual camera (random scenes, unpaced): quick to record."""
    from thintact_sdk.device.registry import get_registry

    if "virtual" not in get_registry().components("camera"):
        pytest.skip("virtual camera plugin not installed")
    d = rob_kit.tiny_profile_dict()
    d["camera"] = {"plugin": "virtual", "bayer_pattern": "RGGB",
                   "settings": {"scenes": "random", "fps": 0, "seed": 0}}
    path = tmp_path_factory.mktemp("cam") / "tiny-camera.json"
    path.write_text(json.dumps(d))
    return path


def _race(n: int, argv: list[str]) -> list[int]:
    """Run ``main(argv)`` on ``n`` threads released together; their exit statuses."""
    gate = threading.Barrier(n)
    codes: list[int] = []
    lock = threading.Lock()

    def run() -> None:
        gate.wait()
        rc = main(argv)
        with lock:
            codes.append(rc)

    threads = [threading.Thread(target=run) for _ in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert len(codes) == n
    return codes


@settings(max_examples=25, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(2, 4), frames=st.integers(1, 4), existing=st.sampled_from(["none", "empty"]))
def test_fuzz_racing_recorders_exactly_one_wins(camera_profile: Path, tmp_path_factory: pytest.TempPathFactory,
                                                n: int, frames: int, existing: str) -> None:
    out = tmp_path_factory.mktemp("race") / "rec"
    if existing == "empty":
        out.mkdir()
    codes = _race(n, ["record", "--profile", str(camera_profile), "--frames", str(frames),
                      "--out", str(out), "--quiet"])
    assert sorted(codes) == [0] + [2] * (n - 1)
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["frames"]) == frames  # one recording, never two merged
    assert not (out / LOCK_NAME).exists()


def test_racing_mcap_recorders_exactly_one_wins(camera_profile: Path, tmp_path: Path) -> None:
    out = tmp_path / "log.mcap"
    codes = _race(3, ["record", "--profile", str(camera_profile), "--frames", "2", "--format", "mcap",
                      "--no-tactile", "--out", str(out), "--quiet"])
    assert sorted(codes) == [0, 2, 2]
    assert out.stat().st_size > 0 and not (tmp_path / ".log.mcap.lock").exists()


def test_two_recorder_processes_exactly_one_wins(camera_profile: Path, tmp_path: Path) -> None:
    out = tmp_path / "rec"
    cmd = [sys.executable, "-m", "thintact_sdk.apps.cli.main", "record", "--profile", str(camera_profile),
           "--frames", "20", "--out", str(out), "--quiet"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    results = [(p.wait(timeout=300), p.stderr.read() if p.stderr else "") for p in procs]
    codes = sorted(rc for rc, _ in results)
    assert codes == [0, 2], results
    loser = next(err for rc, err in results if rc == 2)
    assert len(loser.strip().splitlines()) == 1 and "error:" in loser
    assert len(json.loads((out / "manifest.json").read_text())["frames"]) == 20


def test_the_write_lock_is_exclusive_and_released(tmp_path: Path) -> None:
    with write_lock(tmp_path / "d", "directory"):
        assert (tmp_path / "d" / LOCK_NAME).exists()
        with pytest.raises(OutputError, match="being written by another process"):
            with write_lock(tmp_path / "d", "directory"):
                pass
    assert not (tmp_path / "d" / LOCK_NAME).exists()
    with write_lock(tmp_path / "d", "directory"):  # free again
        pass


def test_a_recording_is_still_refused_without_append_under_the_lock(camera_profile: Path,
                                                                    tmp_path: Path) -> None:
    from thintact_sdk.device.capture_record import record
    from thintact_sdk.formats.profiles import load_profile

    profile = load_profile(str(camera_profile))
    record(profile, 1, tmp_path / "rec", progress=False)
    with pytest.raises(RecordingError, match="already holds a recording"):
        record(profile, 1, tmp_path / "rec", progress=False)
    assert record(profile, 2, tmp_path / "rec", append=True, progress=False).frames == 2
    assert len(json.loads((tmp_path / "rec" / "manifest.json").read_text())["frames"]) == 3


# -- 3. numeric options -------------------------------------------------------------------

@pytest.mark.parametrize("argv", [
    ["bench", "tactile", "--presses", "-1"],
    ["bench", "tactile", "--tau", "nan"],
    ["calibrate-import", "m.npz", "--profile", "virtual-mini", "--out", "o", "--tau", "-1"],
    ["calibrate-import", "m.npz", "--profile", "virtual-mini", "--out", "o", "--filter-steps", "-1"],
    ["mask", "show", "d.json", "--out", "o.png", "--cell-px", "100000"],
    ["mask", "show", "d.json", "--out", "o.png", "--cell-px", "0"],
    ["mask", "optimize", "--profile", "virtual-mini", "--out", "o", "--scale", "2"],
    ["mask", "optimize", "--profile", "virtual-mini", "--out", "o", "--population", "1"],
    ["mask", "compare", "--profile", "virtual-mini", "--frames", "0"],
    ["mask", "design", "--K", "7", "--feature-um", "inf", "--out", "d.json"],
    ["devices", "--timeout", "nan"],
])
def test_bad_numbers_are_refused_before_any_work(argv: list[str], capfd: Any) -> None:
    assert main(argv) == 2
    err = capfd.readouterr().err
    assert "argument" in err and ("must be" in err or "finite" in err), err


def _numeric_options(parser: argparse.ArgumentParser, path: str = "thintact") -> list[tuple[str, Any]]:
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += _numeric_options(sub, f"{path} {name}")
        elif action.type in (int, float):
            found.append((f"{path} {'/'.join(action.option_strings) or action.dest}", action.type))
    return found


def test_every_numeric_option_has_a_validating_type() -> None:
    bare = [(name, t.__name__) for name, t in _numeric_options(build_parser())]
    assert bare == []


def test_mask_show_bounds_the_image_before_allocating(tmp_path: Path, capfd: Any) -> None:
    assert main(["mask", "design", "--kind", "mls", "--K", "31", "--feature-um", "10",
                 "--out", str(tmp_path / "d.json")]) == 0
    capfd.readouterr()
    assert main(["mask", "show", str(tmp_path / "d.json"), "--out", str(tmp_path / "m.png"),
                 "--cell-px", "1000"]) == 2
    _one_error(capfd, "31000x31000", "limit is 16384 px a side")
    assert not (tmp_path / "m.png").exists()
    assert main(["mask", "show", str(tmp_path / "d.json"), "--out", str(tmp_path / "m.png"),
                 "--cell-px", "4"]) == 0


# -- 4. singular calibration bundles ------------------------------------------------------

def _rewrite_matrices(bundle: Path, **replace: np.ndarray) -> None:
    with np.load(bundle / "system_matrices.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(replace)
    np.savez(bundle / "system_matrices.npz", **arrays)


def _matrix(bundle: Path, key: str) -> np.ndarray:
    with np.load(bundle / "system_matrices.npz", allow_pickle=False) as z:
        return np.array(z[key])


@pytest.mark.parametrize("key", ["Pc", "Qc"])
def test_an_all_zero_coding_matrix_is_refused(bundle_copy: Path, key: str) -> None:
    _rewrite_matrices(bundle_copy, **{key: np.zeros_like(_matrix(bundle_copy, key))})
    with pytest.raises(CalibrationError, match=rf"system_matrices.npz: system matrix {key} \(channel 0.*all zero"):
        CalibrationBundle.load(bundle_copy)


@pytest.mark.parametrize("key", ["Pc", "Qc"])
def test_a_rank_deficient_coding_matrix_is_refused(bundle_copy: Path, key: str) -> None:
    a = _matrix(bundle_copy, key)
    a[1] = np.outer(a[1][:, 0], a[1][0])  # rank 1 in channel 1
    _rewrite_matrices(bundle_copy, **{key: a})
    with pytest.raises(CalibrationError, match=rf"system matrix {key} \(channel 1.*rank-deficient: rank 1 of"):
        CalibrationBundle.load(bundle_copy)


def test_zero_open_matrices_are_a_flatcam_model_and_load(bundle_copy: Path) -> None:
    _rewrite_matrices(bundle_copy, Po=np.zeros_like(_matrix(bundle_copy, "Po")),
                      Qo=np.zeros_like(_matrix(bundle_copy, "Qo")))
    CalibrationBundle.load(bundle_copy)


def test_reconstruct_with_an_all_zero_bundle_exits_2_and_writes_nothing(
        tiny: dict[str, Any], bundle_copy: Path, tmp_path: Path, capfd: Any) -> None:
    for key in ("Po", "Qo", "Pc", "Qc"):
        _rewrite_matrices(bundle_copy, **{key: np.zeros_like(_matrix(bundle_copy, key))})
    assert main(["reconstruct", str(tiny["recording"]), "--calibration", str(bundle_copy),
                 "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    _one_error(capfd, "system matrix Pc", "all zero")
    assert not any((tmp_path / "o").glob("*.npy"))


@pytest.mark.parametrize("tau", [0, -1.0])
def test_a_non_positive_tau_is_refused(bundle_copy: Path, tau: float) -> None:
    meta = json.loads((bundle_copy / "calibration.json").read_text())
    meta["tau"] = tau
    (bundle_copy / "calibration.json").write_text(json.dumps(meta))
    with pytest.raises(CalibrationError, match="calibration.json: field 'tau'"):
        CalibrationBundle.load(bundle_copy)


def test_the_shipped_bundles_load() -> None:
    root = Path(__file__).resolve().parents[2] / "thintact_sdk" / "data" / "calibrations"
    bundles = sorted(p.parent for p in root.glob("*/*/calibration.json"))
    assert bundles
    for b in bundles:
        assert CalibrationBundle.load(b).tau > 0


# -- 5. saturated is not dead -------------------------------------------------------------

SATURATION_DN = 900.0
"""Clip level of the saturated recording: below the white frame's dimmest pixel."""


@pytest.fixture(scope="module")
def saturated_recording(repo_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A concealed-dataset device whose ADC clips at :data:`SATURATION_DN` after the noise:
    the white frame reads that level at every pixel, the other frames clip in part."""
    import importlib.util

    from thintact_sdk.formats.recording import RecordingWriter
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    spec = importlib.util.spec_from_file_location("make_concealed_dataset",
                                                  repo_root / "tools" / "make_concealed_dataset.py")
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    prof = tool.base_profile()
    labels, scenes = tool.frame_scenes(prof.scene.rows, prof.scene.cols)
    keep = [i for i, lab in enumerate(labels) if lab in ("white", "checker_4", "random_pixels", "bars",
                                                          "grey_50", "red", "usaf", "random_1")]
    sim = Simulator(prof)
    fs = prof.noise.saturation_dn - prof.noise.black_level_dn
    white = sim.linear_batch(scenes[:1])[0]
    gains = [tool.WHITE_FRACTION * fs * g / float(white[..., c].max()) for c, g in enumerate(tool.CHANNEL_GAIN)]
    signal = sim.predict_signal_dn(scenes[keep], gains)
    rng = np.random.default_rng(3)
    out = tmp_path_factory.mktemp("saturated") / "rec"
    writer = RecordingWriter(out, prof)
    for k, i in enumerate(keep):
        dn = signal_to_dn(signal[k], prof.noise, rng, saturation_dn=SATURATION_DN)
        writer.add(np.round(dn).astype(np.uint16), scene=scenes[i], label=labels[i])
    return out


def test_a_saturated_white_frame_is_diagnosed_as_saturation(saturated_recording: Path) -> None:
    from thintact_sdk.diagnosis.imaging import DiagnoseOptions, diagnose, load_diagnosis_data
    from thintact_sdk.formats.recording import Recording

    white = Recording(saturated_recording).measurement(0)
    assert white.min() == white.max() == SATURATION_DN  # the case really is a saturated frame
    data = load_diagnosis_data(saturated_recording)
    assert data.saturated_frames == {"white": SATURATION_DN}
    d = diagnose(data, options=DiagnoseOptions(candidates=["saturation", "stray_light"]))
    found = {f["effect"]: f["params"] for f in d.report["findings"]}
    assert found.keys() == {"saturation"}
    assert found["saturation"]["level_dn"] == pytest.approx(SATURATION_DN, abs=2.0)


def test_a_dead_frame_in_that_recording_is_still_refused(saturated_recording: Path, tmp_path: Path) -> None:
    import shutil

    from thintact_sdk.diagnosis.imaging import load_diagnosis_data

    rec = Path(shutil.copytree(saturated_recording, tmp_path / "rec"))
    first = sorted((rec / "measurements").iterdir())[1]
    black = np.full_like(np.load(first), 64)
    np.save(first, black)
    with pytest.raises(RecordingError, match=r"frame 1 \(checker_4\).*at the black level.*a dead frame"):
        load_diagnosis_data(rec)
