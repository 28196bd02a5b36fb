"""MCAP logs read back with the standard readers: the ``mcap`` seeking reader and the
ROS 2 (CDR) decoder of ``mcap-ros2-support``; summary, chunk index, metadata, attachments."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_testkit import PERIOD_NS, T0_NS, mini_profile, raw_frame, tactile_frame

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.mcap import McapLog, McapLogWriter

N = 5


def _write(path, with_force=False, **kwargs):
    with McapLogWriter(path, mini_profile(), **kwargs) as log:
        for i in range(N):
            log.write_raw(raw_frame(i))
            log.write_tactile(tactile_frame(i, with_force=with_force and i >= 2))
    return log.stats


def _decoded(path):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(s.name, c.topic, m, d) for s, c, m, d in reader.iter_decoded_messages()]


def test_standard_readers_decode_every_topic_with_camera_stamps(tmp_path):
    path = tmp_path / "log.mcap"  # the layout of older logs: capture clock, DN as delivered
    stats = _write(path, stamps="monotonic", msb_align=False, raw_preview=False)
    assert stats.finished and stats.frames == N
    with open(path, "rb") as f:  # uncompressed chunks by default
        assert {ci.compression for ci in make_reader(f).get_summary().chunk_indexes} == {""}
    msgs = _decoded(path)
    by_topic: dict[str, list] = {}
    for schema, topic, message, decoded in msgs:
        by_topic.setdefault(topic, []).append((schema, message, decoded))
    assert set(by_topic) == {"/thintact/raw", "/thintact/image", "/thintact/depth",
                             "/thintact/markers", "/thintact/contact"}
    for i, (schema, message, img) in enumerate(by_topic["/thintact/raw"]):
        assert schema == "sensor_msgs/msg/Image"
        assert img.encoding == "bayer_rggb16" and img.is_bigendian == 0
        assert (img.height, img.width, img.step) == (256, 320, 640)
        got = np.frombuffer(img.data, "<u2").reshape(256, 320)
        np.testing.assert_array_equal(got, raw_frame(i).data)
        stamp = img.header.stamp.sec * 10**9 + img.header.stamp.nanosec
        assert stamp == message.log_time == T0_NS + i * PERIOD_NS
        assert message.sequence == 100 + i
        assert img.header.frame_id == "virtual-mini"
    for i, (_, _, img) in enumerate(by_topic["/thintact/image"]):
        assert img.encoding == "rgb8" and img.step == 64 * 3
        got = np.frombuffer(img.data, np.uint8).reshape(50, 64, 3)
        assert np.abs(got / 255.0 - tactile_frame(i).image).max() <= 0.5 / 255 + 1e-6
    for i, (_, _, img) in enumerate(by_topic["/thintact/depth"]):
        assert img.encoding == "32FC1"
        np.testing.assert_array_equal(np.frombuffer(img.data, "<f4").reshape(50, 64),
                                      tactile_frame(i).depth_mm)
    for i, (schema, _, m) in enumerate(by_topic["/thintact/markers"]):
        assert schema == "thintact_msgs/msg/Markers" and m.count == 6
        np.testing.assert_array_equal(np.reshape(m.displacements_mm, (6, 2)),
                                      tactile_frame(i).marker_displacements_mm)
        assert np.isnan(m.positions_mm[0]) and np.isnan(m.positions_mm[1])
    for i, (schema, _, c) in enumerate(by_topic["/thintact/contact"]):
        want = tactile_frame(i)
        assert schema == "thintact_msgs/msg/Contact"
        assert c.contact == want.contact and c.camera_frame_id == 100 + i
        assert c.contact_area_mm2 == pytest.approx(want.contact_area_mm2)
        assert c.max_depth_mm == pytest.approx(float(want.depth_mm.max()))
        assert c.shear_direction_rad == pytest.approx(want.shear_direction_rad)
        assert c.mean_displacement_mm.x == pytest.approx(
            float(want.marker_displacements_mm[:, 0].mean()), abs=1e-6)
        assert c.latency_ms == pytest.approx(12.5)


def test_summary_chunk_index_and_statistics(tmp_path):
    path = tmp_path / "log.mcap"
    _write(path, chunk_bytes=200_000, compression="lz4", stamps="monotonic", raw_preview=False)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    stats = summary.statistics
    counts = {summary.channels[c].topic: n for c, n in stats.channel_message_counts.items()}
    assert counts == {t: N for t in ("/thintact/raw", "/thintact/image", "/thintact/depth",
                                     "/thintact/markers", "/thintact/contact")}
    assert stats.message_count == 5 * N
    assert stats.message_start_time == T0_NS
    assert stats.message_end_time == T0_NS + (N - 1) * PERIOD_NS
    # a raw frame is 160 kB, so 200 kB chunks hold about one frame each, all indexed
    assert len(summary.chunk_indexes) == stats.chunk_count >= N - 1
    assert all(ci.compression == "lz4" for ci in summary.chunk_indexes)
    assert summary.chunk_indexes[0].message_start_time == T0_NS
    assert all(ci.message_index_offsets for ci in summary.chunk_indexes)


def test_profile_calibration_and_metadata_travel_with_the_log(tmp_path):
    path = tmp_path / "log.mcap"
    _write(path)
    log = McapLog(path)
    meta = log.metadata["thintact"]
    assert meta["format"] == "thintact-mcap/1" and meta["profile"] == "virtual-mini"
    assert meta["depth_unit"] == "mm" and meta["clock"].startswith("wall clock")
    assert meta["stamps"] == "wall"
    assert int(meta["wall_minus_clock_ns"]) == int(meta["stamp_minus_capture_ns"]) > 0
    assert log.metadata["thintact.raw"] == {"pixel_format": "BayerRG12", "encoding": "bayer_rggb16",
                                            "bit_depth": "12", "msb_shift": "4"}
    assert json.loads(log.attachments["profile.json"]) == mini_profile().contract_dict()
    assert "calibration/calibration.json" in log.attachments
    assert "calibration/system_matrices.npz" in log.attachments


def test_force_and_slip_are_written_only_when_the_frame_has_them(tmp_path):
    path = tmp_path / "log.mcap"
    _write(path, with_force=True)
    log = McapLog(path)
    counts = log.message_counts()
    assert counts["/thintact/force"] == counts["/thintact/slip"] == N - 2
    forces = [m for m in log.messages(["/thintact/force"])]
    assert forces[0].schema == "geometry_msgs/msg/WrenchStamped"
    w = forces[0].message.wrench
    assert (w.force.x, w.force.y, w.force.z) == pytest.approx((0.2, -0.2, 3.0))
    assert (w.torque.x, w.torque.y, w.torque.z) == (0.0, 0.0, 0.0)
    frames = list(log.tactile_frames())
    assert frames[0].force_n is None and frames[0].slip_ratio is None
    np.testing.assert_allclose(frames[3].force_n, [0.3, -0.2, 4.0])
    assert frames[3].slip_ratio == pytest.approx(0.3)


def test_exact_reconstruction_round_trip_with_32fc3(tmp_path):
    path = tmp_path / "log.mcap"
    _write(path, image_encoding="32FC3", compression="zstd")
    frames = list(McapLog(path).tactile_frames())
    assert len(frames) == N
    for i, got in enumerate(frames):
        want = tactile_frame(i)
        np.testing.assert_array_equal(got.image, want.image)
        np.testing.assert_array_equal(got.depth_mm, want.depth_mm)
        np.testing.assert_array_equal(got.marker_positions_mm, want.marker_positions_mm)
        assert (got.timestamp_ns, got.frame_id, got.contact) == (
            want.timestamp_ns, want.frame_id, want.contact)
    raws = list(McapLog(path).raw_frames())
    assert [r.frame_id for r in raws] == [100 + i for i in range(N)]
    assert all(r.pixel_format == "BayerRG12" for r in raws)


def test_bad_inputs_are_one_line_errors(tmp_path):
    with pytest.raises(RecordingError, match="compression"):
        McapLogWriter(tmp_path / "a.mcap", mini_profile(), compression="gzip")
    with pytest.raises(RecordingError, match="32FC3"):
        McapLogWriter(tmp_path / "b.mcap", mini_profile(), image_encoding="bgr8")
    (tmp_path / "c.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="not an MCAP"):
        McapLog(tmp_path / "c.mcap")
    with pytest.raises(RecordingError, match="not found"):
        McapLog(tmp_path / "missing.mcap")
