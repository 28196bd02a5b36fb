"""thintact record: camera → recording → replay, bit-exact, drops reported, faults clear."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from thintact_genicam.producers import viky_producer

from thintact_sdk.apps.cli.main import main
from thintact_sdk.device.cameras import create_camera, to_measurement
from thintact_sdk.device.capture_record import storage_array
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.formats.recording import Recording, RecordingWriter


def _profile_file(tmp_path, name, camera, noise=None):
    d = load_profile("virtual-mini").contract_dict()
    d["name"] = name
    d["camera"] = camera
    if noise:
        d["noise"].update(noise)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(d), encoding="utf-8")
    return path


def _source_recording(root, n=6, ids=None):
    w = RecordingWriter(root, load_profile("virtual-mini"))
    rng = np.random.default_rng(7)
    meas = []
    for i in range(n):
        m = rng.integers(64, 4095, size=(128, 160, 3)).astype(np.uint16)
        scene = rng.random((50, 64, 3), dtype=np.float32)
        w.add(m, scene=scene, label=f"s{i}", timestamp_ns=i * 10_000_000,
              frame_id=ids[i] if ids else i, exposure_us=1234.0)
        meas.append(m)
    return meas


def _replay_profile(tmp_path, rec, name="replay-src", **settings):
    return _profile_file(tmp_path, name, {"plugin": "replay", "bayer_pattern": "RGGB",
                                          "settings": {"path": str(rec), "rate": "fast",
                                                       **settings}})


def test_storage_dtype_rule():
    assert storage_array(np.array([1.0, 2.0, 65535.0], np.float32)).dtype == np.uint16
    assert storage_array(np.array([1.5, 2.0], np.float32)).dtype == np.float32
    assert storage_array(np.array([-1.0, 2.0], np.float32)).dtype == np.float32
    assert storage_array(np.array([70000.0], np.float32)).dtype == np.float32


def test_record_then_replay_is_bit_exact(tmp_path, capsys):
    meas = _source_recording(tmp_path / "src")
    prof = _replay_profile(tmp_path, tmp_path / "src")
    out = tmp_path / "rec"
    assert main(["record", "--profile", str(prof), "--frames", "6", "--out", str(out),
                 "--raw", "--quiet"]) == 0
    assert "recorded 6 frame(s)" in capsys.readouterr().out
    rec = Recording(out)
    assert len(rec) == 6
    manifest = json.loads((out / "manifest.json").read_text())
    for i, fr in enumerate(manifest["frames"]):
        assert fr["frame_id"] == i and fr["exposure_us"] == 1234.0
        assert isinstance(fr["timestamp_ns"], int) and fr["raw"].startswith("raw/")
        assert fr["pixel_format"] == "BayerRG16"
    for i, m in enumerate(meas):
        got = rec.measurement(i)
        assert got.dtype == np.uint16
        np.testing.assert_array_equal(got, m)
        assert rec.scene(i) is not None
    # and the new recording replays to the same measurements, through raw and re-mosaic paths
    for use_raw in (True, False):
        p = load_profile(_replay_profile(tmp_path, out, name=f"again{use_raw}", raw=use_raw))
        with create_camera(p) as cam:
            got = [to_measurement(r, p).data for r in cam]
        assert len(got) == 6
        for g, m in zip(got, meas, strict=True):
            np.testing.assert_array_equal(g, m)


def test_the_library_record_writes_what_the_command_writes(tmp_path, capsys):
    """``thintact record`` only parses and prints: the library's ``record`` gives the same
    recording (manifest apart from capture times, and every stored file) from the same source."""
    from thintact_sdk.device.capture_record import record

    _source_recording(tmp_path / "src", n=4, ids=[0, 1, 3, 4])
    prof = _replay_profile(tmp_path, tmp_path / "src")
    assert main(["record", "--profile", str(prof), "--frames", "4", "--out", str(tmp_path / "cli"),
                 "--raw", "--quiet"]) == 0
    capsys.readouterr()
    summary = record(load_profile(str(prof)), 4, tmp_path / "lib", keep_raw=True, progress=False)
    assert (summary.frames, summary.dropped) == (4, 1)

    def content(root):  # the host's capture time is the one field that differs between runs
        manifest = json.loads((root / "manifest.json").read_text())
        for fr in manifest["frames"]:
            assert isinstance(fr.pop("timestamp_ns"), int)
        files = {str(f.relative_to(root)): f.read_bytes() for f in sorted(root.rglob("*"))
                 if f.is_file() and f.name != "manifest.json"}
        return manifest, files

    cli_manifest, cli_files = content(tmp_path / "cli")
    lib_manifest, lib_files = content(tmp_path / "lib")
    assert [fr["dropped_before"] for fr in cli_manifest["frames"] if "dropped_before" in fr] == [1]
    assert lib_manifest == cli_manifest
    assert lib_files.keys() == cli_files.keys() and len(cli_files) >= 8
    assert lib_files == cli_files


def test_dropped_frames_are_reported_and_can_fail(tmp_path, capsys):
    _source_recording(tmp_path / "src", n=4, ids=[5, 6, 9, 10])
    prof = _replay_profile(tmp_path, tmp_path / "src")
    assert main(["record", "--profile", str(prof), "--frames", "4", "--out",
                 str(tmp_path / "a"), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "dropped frames: 2" in captured.out
    assert "2 frame(s) dropped before frame id 9" in captured.err
    frames = json.loads((tmp_path / "a" / "manifest.json").read_text())["frames"]
    assert [f.get("dropped_before", 0) for f in frames] == [0, 0, 2, 0]
    assert main(["record", "--profile", str(prof), "--frames", "4", "--out",
                 str(tmp_path / "b"), "--quiet", "--fail-on-drop"]) == 2
    assert "dropped 2 frame(s)" in capsys.readouterr().err


def test_source_ending_early_and_existing_output(tmp_path, capsys):
    _source_recording(tmp_path / "src", n=3)
    prof = _replay_profile(tmp_path, tmp_path / "src")
    out = tmp_path / "rec"
    assert main(["record", "--profile", str(prof), "--frames", "10", "--out", str(out),
                 "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "recorded 3 frame(s)" in captured.out and "ended early" in captured.err
    assert main(["record", "--profile", str(prof), "--frames", "1", "--out", str(out),
                 "--quiet"]) == 2
    assert "already holds a recording" in capsys.readouterr().err
    assert main(["record", "--profile", str(prof), "--frames", "2", "--out", str(out),
                 "--quiet", "--append"]) == 0
    assert len(Recording(out)) == 5


def test_truncated_source_is_a_one_line_error(tmp_path, capsys):
    _source_recording(tmp_path / "src", n=3)
    victim = sorted((tmp_path / "src" / "measurements").iterdir())[1]
    victim.write_bytes(victim.read_bytes()[:500])
    prof = _replay_profile(tmp_path, tmp_path / "src")
    assert main(["record", "--profile", str(prof), "--frames", "3", "--out",
                 str(tmp_path / "rec"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "frame 1" in err and "truncated" in err
    assert not (tmp_path / "rec").exists()  # nothing is created for a camera that fails to open


@pytest.mark.skipif(viky_producer() is None, reason="genicam wheel without viky.cti")
def test_record_from_genicam_with_raw_mosaics(tmp_path, capsys):
    prof_path = _profile_file(tmp_path, "viky", {
        "plugin": "genicam", "bayer_pattern": "RGGB",
        "settings": {"cti": str(viky_producer()), "Width": 320, "Height": 256,
                     "PixelFormat": "Mono8", "AcquisitionFrameRate": 100.0}})
    out = tmp_path / "rec"
    assert main(["record", "--profile", str(prof_path), "--frames", "5", "--out", str(out),
                 "--raw", "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "recorded 5 frame(s)" in captured.out
    # a 12-bit noise model with an 8-bit camera is pointed out, as one plain line
    assert captured.err.count("Mono8 gives at most 255 DN") == 1
    assert "warning: genicam: pixel format Mono8" in captured.err
    rec = Recording(out)
    p = load_profile(_replay_profile(tmp_path, out, name="viky-replay"))
    with create_camera(p) as cam:
        for i, raw in enumerate(cam):
            assert raw.pixel_format == "Mono8" and raw.data.shape == (256, 320)
            np.testing.assert_array_equal(to_measurement(raw, p).data, rec.measurement(i))


@pytest.mark.skipif(viky_producer() is None, reason="genicam wheel without viky.cti")
def test_capture_thread_keeps_up_with_the_camera(tmp_path, capsys):
    prof_path = _profile_file(tmp_path, "viky-fast", {
        "plugin": "genicam", "bayer_pattern": "RGGB",
        "settings": {"cti": str(viky_producer()), "Width": 320, "Height": 256,
                     "PixelFormat": "Mono8", "AcquisitionFrameRate": 100.0}},
        noise={"black_level_dn": 4.0, "saturation_dn": 255.0})
    out = tmp_path / "rec"
    assert main(["record", "--profile", str(prof_path), "--frames", "50", "--out", str(out),
                 "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "dropped frames: 0" in text, text
    ids = [f["frame_id"] for f in json.loads((out / "manifest.json").read_text())["frames"]]
    assert ids == list(range(ids[0], ids[0] + 50))


def test_record_from_the_virtual_camera_and_replay_it(tmp_path, capsys):
    from thintact_sdk.device.registry import get_registry

    if "virtual" not in get_registry().components("camera"):
        pytest.skip("virtual camera plugin not installed")
    out = tmp_path / "rec"
    assert main(["record", "--profile", "virtual-mini", "--frames", "3", "--out", str(out),
                 "--set", "fps=0", "--quiet"]) == 0
    assert "recorded 3 frame(s)" in capsys.readouterr().out
    rec = Recording(out)
    for i in range(3):
        assert rec.measurement(i).dtype == np.uint16  # integral DN → uint16
        assert rec.scene(i).shape == (50, 64, 3)  # the camera's ground truth kept
    p = load_profile(_replay_profile(tmp_path, out, name="virtual-replay"))
    with create_camera(p) as cam:
        for i, raw in enumerate(cam):
            np.testing.assert_array_equal(to_measurement(raw, p).data, rec.measurement(i))
            np.testing.assert_array_equal(raw.meta["scene"], rec.scene(i))
