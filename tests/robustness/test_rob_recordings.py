"""Recordings are read strictly: every bad file, path or field is one RecordingError naming
the frame; appending another device's frames is refused naming both profiles."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import rob_kit

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.recording import Recording, RecordingWriter


def _edit_frame(rec: Path, i: int, **fields: object) -> None:
    manifest = json.loads((rec / "manifest.json").read_text())
    manifest["frames"][i].update(fields)
    (rec / "manifest.json").write_text(json.dumps(manifest))


def _replace_measurement(rec: Path, i: int, array: np.ndarray) -> None:
    np.save(rec / "measurements" / f"{i:03d}.npy", array)


def test_paths_outside_the_recording_are_refused(rec_copy: Path, tmp_path: Path) -> None:
    outside = tmp_path / "outside.npy"
    np.save(outside, np.zeros((24, 30, 3), np.uint16))
    _edit_frame(rec_copy, 1, measurement="../outside.npy")
    with pytest.raises(RecordingError, match=r"frame 1 'measurement'.*outside the recording"):
        Recording(rec_copy)
    _edit_frame(rec_copy, 1, measurement=str(outside))
    with pytest.raises(RecordingError, match="relative to the recording"):
        Recording(rec_copy)
    _edit_frame(rec_copy, 1, measurement="measurements/001.npy", scene="scenes/link.npy")
    os.symlink(outside, rec_copy / "scenes" / "link.npy")
    with pytest.raises(RecordingError, match=r"frame 1 'scene'.*symlink"):
        Recording(rec_copy)


def test_a_symlink_inside_the_recording_is_fine(rec_copy: Path) -> None:
    os.symlink(rec_copy / "measurements" / "000.npy", rec_copy / "measurements" / "alias.npy")
    _edit_frame(rec_copy, 1, measurement="measurements/alias.npy")
    assert Recording(rec_copy).measurement(1).shape == (24, 30, 3)


@pytest.mark.parametrize(
    ("array", "message"),
    [
        (np.full((24, 30, 3), "7", dtype="<U3"), "dtype <U3 is not a number"),
        (np.zeros((24, 30), np.uint16), "1 channel"),
        (np.zeros((24, 30, 3, 1), np.uint16), "shape"),
        (np.zeros(720, np.uint16), "shape"),
        (-np.ones((24, 30, 3), np.float32), "negative"),
        (np.ones((24, 30, 3), bool), "dtype bool"),
        (np.zeros((0, 30, 3), np.float32), "shape"),
    ],
)
def test_bad_measurement_arrays_name_the_frame(rec_copy: Path, array: np.ndarray, message: str) -> None:
    _replace_measurement(rec_copy, 2, array)
    rec = Recording(rec_copy)
    with pytest.raises(RecordingError, match="frame 2 \\(f2\\)") as err:
        rec.measurement(2)
    assert message in str(err.value)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf_measurements_are_refused_with_the_frame(rec_copy: Path, tiny: dict, bad: float) -> None:
    m = tiny["meas"][1].astype(np.float32)
    m[3:13, 5:15, :] = bad  # a 10×10 patch
    _replace_measurement(rec_copy, 1, m)
    with pytest.raises(RecordingError, match=r"frame 1 \(f1\).*300 NaN/Inf"):
        Recording(rec_copy).check_frames()


def test_scenes_outside_zero_one_are_refused(rec_copy: Path, tiny: dict) -> None:
    s = tiny["scenes"][1].copy()
    s[0, 0, 0] = 1.5
    np.save(rec_copy / "scenes" / "001.npy", s)
    with pytest.raises(RecordingError, match=r"frame 1 \(f1\).*above"):
        Recording(rec_copy).scene(1)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"frame_id": "abc"}, "'frame_id' must be a non-negative integer"),
        ({"frame_id": True}, "'frame_id' must be a non-negative integer"),
        ({"timestamp_ns": -1}, "'timestamp_ns' must be a non-negative integer"),
        ({"exposure_us": 0}, "'exposure_us' must be a positive number"),
        ({"exposure_us": -10.0}, "'exposure_us' must be a positive number"),
        ({"exposure_us": "fast"}, "'exposure_us' must be a positive number"),
        ({"label": 5}, "'label' must be a string"),
        ({"measurement": 5}, "'measurement' must be a file name"),
        ({"scene": ["a"]}, "'scene' must be a file name"),
        ({"gain_db": float("nan")}, "'gain_db' must be a finite number"),
    ],
)
def test_bad_frame_metadata_names_frame_and_field(rec_copy: Path, fields: dict, message: str) -> None:
    _edit_frame(rec_copy, 2, **fields)
    with pytest.raises(RecordingError, match="frame 2") as err:
        Recording(rec_copy)
    assert message in str(err.value)


def test_an_empty_recording_is_an_error(rec_copy: Path) -> None:
    manifest = json.loads((rec_copy / "manifest.json").read_text())
    manifest["frames"] = []
    (rec_copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(RecordingError, match="holds no frames"):
        Recording(rec_copy)
    assert len(Recording(rec_copy, allow_empty=True)) == 0  # a resuming writer may open it


def test_append_with_another_device_is_refused_naming_both(tmp_path: Path, tiny: dict) -> None:
    RecordingWriter(tmp_path / "r", tiny["profile"]).add(tiny["meas"][0], label="a")
    other = rob_kit.tiny_profile_dict()
    other.update(name="robust-other", sensor={**other["sensor"], "rows": 48, "cols": 60})
    from thintact_sdk.formats.profiles import profile_from_dict

    with pytest.raises(RecordingError) as err:
        RecordingWriter(tmp_path / "r", profile_from_dict(other))
    msg = str(err.value)
    assert "'robust-tiny' (sensor 24×30×3" in msg and "'robust-other' (sensor 48×60×3" in msg
    assert len(Recording(tmp_path / "r")) == 1  # untouched
    RecordingWriter(tmp_path / "r", tiny["profile"]).add(tiny["meas"][1], label="b")  # same device: resumes
    assert [f.label for f in Recording(tmp_path / "r").frames] == ["a", "b"]


def test_the_writer_refuses_nan_and_cleans_a_killed_writers_temp_files(tmp_path: Path, tiny: dict) -> None:
    w = RecordingWriter(tmp_path / "r", tiny["profile"])
    w.add(tiny["meas"][0], label="a")
    bad = tiny["meas"][1].astype(np.float32)
    bad[0, 0, 0] = np.nan
    with pytest.raises(RecordingError, match=r"frame 1 \(b\).*NaN"):
        w.add(bad, label="b")
    stale = tmp_path / "r" / "measurements" / ".001_b.npy.x1y2.tmp"
    stale.write_bytes(b"half a frame")
    RecordingWriter(tmp_path / "r", tiny["profile"])
    assert not stale.exists()
    assert len(Recording(tmp_path / "r")) == 1
