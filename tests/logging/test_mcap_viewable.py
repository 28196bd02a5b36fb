"""Raw frames common viewers display (MSB-aligned 16 bit, rgb8 preview) and wall-time stamps;
older logs (capture-clock stamps, unshifted DN) still read exactly."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap_ros2.writer import Writer
from mcap_testkit import PERIOD_NS, T0_NS, mini_profile, raw_frame, tactile_frame

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.mcap import McapLog, McapLogWriter, images, schemas
from thintact_sdk.formats.mcap.writer import raw_messages
from thintact_sdk.frames import RawFrame

N = 3


def _write(path, **kwargs):
    with McapLogWriter(path, mini_profile(), attach_calibration=False, **kwargs) as log:
        for i in range(N):
            log.write_raw(raw_frame(i))
            log.write_tactile(tactile_frame(i))
    return log


def test_raw_is_msb_aligned_with_a_preview_and_reads_back_exact(tmp_path):
    path = tmp_path / "log.mcap"
    _write(path)
    log = McapLog(path)
    stored = [m.message for m in log.messages([schemas.RAW.name])]
    previews = [m.message for m in log.messages([schemas.RAW_PREVIEW.name])]
    assert len(stored) == len(previews) == N
    for i, (img, prev) in enumerate(zip(stored, previews, strict=True)):
        want = raw_frame(i).data
        assert img.encoding == "bayer_rggb16"
        got = np.frombuffer(img.data, "<u2").reshape(256, 320)
        np.testing.assert_array_equal(got, want << 4)  # 12 significant bits fill 16
        assert (prev.encoding, prev.height, prev.width, prev.step) == ("rgb8", 128, 160, 480)
        rgb = np.frombuffer(prev.data, np.uint8).reshape(128, 160, 3)
        r = want[0::2, 0::2].astype(np.float64)
        g = (want[0::2, 1::2].astype(np.float64) + want[1::2, 0::2]) / 2
        b = want[1::2, 1::2].astype(np.float64)
        expect = np.rint(np.stack([r, g, b], -1) * (255 / 4095))
        assert np.abs(rgb - expect).max() <= 1
    raws = list(log.raw_frames())
    for i, raw in enumerate(raws):
        np.testing.assert_array_equal(raw.data, raw_frame(i).data)
        assert raw.pixel_format == "BayerRG12" and raw.data.dtype == np.uint16


def test_stamps_are_wall_time_and_the_capture_clock_is_kept(tmp_path):
    path = tmp_path / "log.mcap"
    writer = _write(path)
    log = McapLog(path)
    offset = log.stamp_offset_ns
    assert offset == writer.wall_minus_clock_ns == writer.stamp_offset_ns
    assert int(log.metadata["thintact"]["wall_minus_clock_ns"]) == offset
    for m in log.messages():
        i = m.sequence - 100
        assert m.log_time_ns == images.stamp_ns(m.message.header) == T0_NS + i * PERIOD_NS + offset
        assert m.log_time_ns > 1_600_000_000 * 10**9  # ns since the Unix epoch, not since boot
    raws, frames = list(log.raw_frames()), list(log.tactile_frames())
    assert [r.timestamp_ns for r in raws] == [T0_NS + i * PERIOD_NS for i in range(N)]
    assert [f.timestamp_ns for f in frames] == [T0_NS + i * PERIOD_NS for i in range(N)]
    assert [r.meta["stamp_ns"] for r in raws] == [T0_NS + i * PERIOD_NS + offset for i in range(N)]


def test_monotonic_stamps_and_no_preview_on_request(tmp_path):
    path = tmp_path / "log.mcap"
    _write(path, stamps="monotonic", raw_preview=False)
    log = McapLog(path)
    assert log.stamp_offset_ns == 0 and log.metadata["thintact"]["stamps"] == "monotonic"
    assert schemas.RAW_PREVIEW.name not in log.message_counts()
    assert [m.log_time_ns for m in log.messages([schemas.RAW.name])] == [
        T0_NS + i * PERIOD_NS for i in range(N)]
    with pytest.raises(RecordingError, match="stamps must be 'wall' or 'monotonic'"):
        McapLogWriter(tmp_path / "x.mcap", mini_profile(), stamps="gps")


def test_a_log_written_before_msb_alignment_and_wall_stamps_reads_unchanged(tmp_path):
    """The layout of thintact-mcap/1 logs written before: no msb_shift, capture-clock stamps."""
    path = tmp_path / "old.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        sch = w.register_msgdef(schemas.IMAGE, schemas.DEFINITIONS[schemas.IMAGE])
        w.add_metadata("thintact", {"format": "thintact-mcap/1", "profile": "virtual-mini",
                                    "clock": "host monotonic clock, ns (time.monotonic_ns)",
                                    "wall_minus_clock_ns": "123456789"})
        w.add_metadata("thintact.raw", {"pixel_format": "BayerRG12", "encoding": "bayer_rggb16"})
        for i in range(N):
            raw = raw_frame(i)
            msg = images.image_message(raw.data, "bayer_rggb16", raw.timestamp_ns, "virtual-mini")
            w.write_message(schemas.RAW.name, sch, msg, log_time=raw.timestamp_ns,
                            publish_time=raw.timestamp_ns, sequence=raw.frame_id)
        w.finish()
    log = McapLog(path)
    assert log.stamp_offset_ns == 0
    for i, raw in enumerate(log.raw_frames()):
        np.testing.assert_array_equal(raw.data, raw_frame(i).data)
        assert raw.timestamp_ns == T0_NS + i * PERIOD_NS


def test_values_beyond_the_pixel_formats_bits_are_refused_by_frame(tmp_path):
    bad = RawFrame(data=np.full((4, 4), 4096, np.uint16), timestamp_ns=1, frame_id=7,
                   pixel_format="BayerRG12")
    with McapLogWriter(tmp_path / "l.mcap", mini_profile(), attach_calibration=False) as log:
        with pytest.raises(RecordingError, match=r"raw frame 7 \(BayerRG12\): value 4096"):
            log.write_raw(bad)


def test_bit_depth_of_pixel_formats():
    u16, u8 = np.dtype(np.uint16), np.dtype(np.uint8)
    assert images.bit_depth("BayerRG12", u16) == 12
    assert images.bit_depth("Mono10", u16) == 10
    assert images.bit_depth("Mono16", u16) == 16
    assert images.bit_depth("RGB8", u8) == 8
    assert images.bit_depth("BayerGB12", u8) == 8  # more bits than the dtype holds: its width
    assert images.bit_depth("Mono", u16) == 16


@settings(max_examples=40, deadline=None)
@given(bits=st.integers(1, 16), fmt=st.sampled_from(["BayerRG", "BayerGB", "Mono", "RGB"]),
       seed=st.integers(0, 2**32 - 1))
def test_msb_alignment_round_trips_every_bit_depth(tmp_path_factory, bits, fmt, seed):
    rng = np.random.default_rng(seed)
    shape = (6, 8, 3) if fmt == "RGB" else (6, 8)
    data = rng.integers(0, 2**bits, size=shape, dtype=np.uint16)
    raw = RawFrame(data=data, timestamp_ns=5, frame_id=1, pixel_format=f"{fmt}{bits}")
    messages, meta = raw_messages(raw, "f", 5)
    img = messages[0][1]
    stored = np.frombuffer(img["data"], "<u2").reshape(shape)
    assert int(meta["msb_shift"]) == 16 - bits
    np.testing.assert_array_equal(stored >> (16 - bits), data)
    want = [schemas.RAW.name] + ([schemas.RAW_PREVIEW.name] if fmt != "Mono" else [])
    assert [t.name for t, _ in messages] == want
    path = tmp_path_factory.mktemp("fuzz") / "l.mcap"
    with McapLogWriter(path, mini_profile(), attach_calibration=False) as log:
        log.write_raw(raw)
    (back,) = list(McapLog(path).raw_frames())
    np.testing.assert_array_equal(back.data, data)
