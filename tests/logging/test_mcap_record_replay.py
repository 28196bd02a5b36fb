"""``thintact record --format mcap`` end to end, and the replay camera playing MCAP logs."""

from __future__ import annotations

import time

import numpy as np
import pytest
from mcap_testkit import PERIOD_NS, mini_profile, raw_frame, tactile_frame
from thintact_replay import EndOfRecording

import thintact_sdk as thintact
from thintact_sdk.apps.cli.main import main
from thintact_sdk.device.cameras import create_camera
from thintact_sdk.errors import DeviceTimeoutError
from thintact_sdk.formats.mcap import McapLog, McapLogWriter
from thintact_sdk.formats.mcap.attachments import calibration_bundle_dir
from thintact_sdk.formats.profiles import load_profile


def _replay_profile(path, base=None, **settings):
    base = base or mini_profile()
    cam = {"plugin": "replay", "bayer_pattern": "RGGB", "settings": {"path": str(path), **settings}}
    return base.model_copy(update={"camera": type(base.camera).model_validate(cam)})


def _log(path, n=4):
    with McapLogWriter(path, mini_profile(), attach_calibration=False) as log:
        for i in range(n):
            log.write_raw(raw_frame(i))
            log.write_tactile(tactile_frame(i))


def test_record_mcap_from_the_virtual_sensor(tmp_path, capsys):
    out = tmp_path / "press.mcap"
    # virtual-finger: the smallest profile the tactile pipeline runs on (it has a LUT)
    assert main(["record", "--profile", "virtual-finger", "--frames", "3", "--format", "mcap",
                 "--set", "fps=0", "--quiet", "--out", str(out)]) == 0
    assert "recorded 3 frame(s)" in capsys.readouterr().out
    log = McapLog(out)
    counts = log.message_counts()
    # the interpreter estimates force on every frame (zero without contact), slip only in contact
    assert counts.pop("/thintact/slip", 0) <= 3
    assert counts == {t: 3 for t in ("/thintact/raw", "/thintact/raw_preview", "/thintact/image",
                                     "/thintact/depth",
                                     "/thintact/markers", "/thintact/contact", "/thintact/force")}
    raws, frames = list(log.raw_frames()), list(log.tactile_frames())
    assert [r.frame_id for r in raws] == [f.frame_id for f in frames]
    assert [r.timestamp_ns for r in raws] == [f.timestamp_ns for f in frames]
    assert raws[0].pixel_format == "BayerRG12" and raws[0].data.shape == (512, 640)
    assert frames[0].image.shape == (100, 128, 3) and frames[0].depth_mm.shape == (100, 128)
    assert all(f.latency_ms is not None and f.latency_ms > 0 for f in frames)
    # the same raw frames through the replay camera give the same tactile frames
    finger_profile = load_profile("virtual-finger")
    profile = _replay_profile(out, finger_profile, rate="fast")
    decoder = finger_profile.decoder.model_copy(
        update={"settings": {"calibration": str(calibration_bundle_dir(finger_profile))}})
    profile = profile.model_copy(update={"decoder": decoder})
    with thintact.open(profile) as finger:
        again = [finger.read() for _ in range(3)]
    for a, b in zip(again, frames, strict=True):
        np.testing.assert_allclose(a.depth_mm, b.depth_mm, atol=1e-6)
        assert a.contact == b.contact


def test_record_mcap_refuses_directory_options_and_existing_files(tmp_path, capsys):
    out = tmp_path / "x.mcap"
    assert main(["record", "--profile", "virtual-mini", "--frames", "1", "--format", "mcap",
                 "--raw", "--out", str(out)]) == 2
    assert "--raw applies to --format recording only" in capsys.readouterr().err
    out.write_bytes(b"")
    assert main(["record", "--profile", "virtual-mini", "--frames", "1", "--format", "mcap",
                 "--quiet", "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err


def test_replay_plays_an_mcap_log_exactly(tmp_path):
    path = tmp_path / "log.mcap"
    _log(path)
    with create_camera(_replay_profile(path, rate="fast")) as cam:
        caps = cam.capabilities()
        raws = list(iter(lambda: _read_or_none(cam), None))
    assert (caps.width, caps.height, caps.pixel_format) == (320, 256, "BayerRG12")
    assert [r.frame_id for r in raws] == [100, 101, 102, 103]
    for i, raw in enumerate(raws):
        np.testing.assert_array_equal(raw.data, raw_frame(i).data)
        assert raw.pixel_format == "BayerRG12"
        assert raw.meta["recorded_timestamp_ns"] == raw_frame(i).timestamp_ns


def _read_or_none(cam):
    try:
        return cam.read(timeout_s=1.0)
    except EndOfRecording:
        return None


def test_replay_recorded_rate_speed_and_loop(tmp_path):
    path = tmp_path / "log.mcap"
    _log(path, n=4)
    with create_camera(_replay_profile(path, speed=2.0, loop=True)) as cam:
        t0 = time.monotonic()
        raws = [cam.read(timeout_s=1.0) for _ in range(9)]
        elapsed = time.monotonic() - t0
    # 8 periods of 33 ms at double speed
    assert elapsed == pytest.approx(8 * PERIOD_NS / 1e9 / 2, abs=0.05)
    assert [r.frame_id for r in raws] == [100, 101, 102, 103, 104, 105, 106, 107, 108]
    assert [r.meta["loop"] for r in raws] == [0, 0, 0, 0, 1, 1, 1, 1, 2]
    with create_camera(_replay_profile(path, speed=0.01)) as cam:
        cam.read(timeout_s=1.0)
        with pytest.raises(DeviceTimeoutError, match="beyond the read timeout"):
            cam.read(timeout_s=0.05)


def test_record_mcap_writes_the_raw_preview_unless_told_not_to(tmp_path):
    """The virtual camera's 16-bit Bayer frames get an rgb8 preview beside the raw (viewers
    without a 16-bit Bayer decoder show it); --no-raw-preview leaves it out, raw unchanged."""
    from thintact_sdk.formats.mcap import McapLog, schemas

    counts = {}
    for name, extra in (("with", []), ("without", ["--no-raw-preview"])):
        out = tmp_path / f"{name}.mcap"
        assert main(["record", "--profile", "virtual-mini", "--frames", "2", "--format", "mcap",
                     "--no-tactile", "--quiet", "--out", str(out), *extra]) == 0
        counts[name] = McapLog(out).message_counts()
    assert counts["with"][schemas.RAW_PREVIEW.name] == 2 == counts["with"][schemas.RAW.name]
    assert schemas.RAW_PREVIEW.name not in counts["without"]
    assert counts["without"][schemas.RAW.name] == 2
