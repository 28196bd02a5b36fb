"""Image files a user is handed (press folders, recordings' frames, imported stills) are sized
from their headers before anything is decoded: a few kilobytes of PNG that declare gigabytes
of pixels are refused with one line naming the file, and a folder whose images together
would not fit in memory is refused before the first is decoded."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import CalibrationError, RecordingError
from thintact_sdk.formats import safe_images
from thintact_sdk.formats.safe_images import check_image_budget, declared_image_bytes


def header_only_png(width: int, height: int, colour: bool = True) -> bytes:
    """A PNG declaring ``width × height`` px (8-bit RGB or grey) whose data is a few
    hundred zero bytes: decoding it would allocate the whole image before finding it short."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack(">I", len(data)) + kind + data
                + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2 if colour else 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 600))
            + chunk(b"IEND", b""))


def _one_line(capfd: pytest.CaptureFixture[str]) -> str:
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "error:" in lines[0] and "Traceback" not in err, err
    return lines[0]


def _press_folder(root: Path, n: int = 3, size: int = 64) -> Path:
    root.mkdir()
    rng = np.random.default_rng(0)
    cv2.imwrite(str(root / "ref.png"), rng.integers(0, 255, (size, size, 3), np.uint8))
    for k in range(n):
        cv2.imwrite(str(root / f"sample_{k}.png"), rng.integers(0, 255, (size, size, 3), np.uint8))
    return root


def test_the_header_gives_the_decoded_size_without_decoding(tmp_path: Path) -> None:
    rgb, grey = tmp_path / "rgb.png", tmp_path / "grey.png"
    cv2.imwrite(str(rgb), np.zeros((40, 50, 3), np.uint8))
    cv2.imwrite(str(grey), np.zeros((40, 50), np.uint16))
    assert declared_image_bytes(rgb) == 40 * 50 * 3
    assert declared_image_bytes(grey) == 40 * 50 * 3 * 2  # read as colour at most: 3 channels
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(header_only_png(12_000, 10_000))
    assert bomb.stat().st_size < 1000
    assert declared_image_bytes(bomb) == 12_000 * 10_000 * 3
    with pytest.raises(RecordingError, match="bomb.png"):
        check_image_budget([bomb], RecordingError, limit_bytes=2**28)
    with pytest.raises(CalibrationError, match="not a readable image"):
        declared_image_bytes(tmp_path / "missing.png", CalibrationError)
    junk = tmp_path / "junk.jpg"
    junk.write_bytes(np.random.default_rng(1).bytes(700))
    with pytest.raises(CalibrationError, match="junk.jpg: not a readable image"):
        declared_image_bytes(junk, CalibrationError)


def test_tactile_import_refuses_a_bomb_in_one_line(tmp_path: Path,
                                                   capfd: pytest.CaptureFixture[str]) -> None:
    folder = _press_folder(tmp_path / "presses")
    (folder / "ref.png").write_bytes(header_only_png(30_000, 30_000))  # 0.9 Gpx: Pillow's bound
    assert main(["tactile", "import", str(folder), "--out", str(tmp_path / "p.npz")]) == 2
    line = _one_line(capfd)
    assert "ref.png" in line and "too many pixels" in line
    assert not (tmp_path / "p.npz").exists()


def test_a_press_folder_that_would_not_fit_is_refused_before_decoding(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]) -> None:
    folder = _press_folder(tmp_path / "presses", n=3, size=64)
    (folder / "sample_9.png").write_bytes(header_only_png(4000, 3000))  # 36 MB declared
    decoded: list[str] = []
    real = safe_images.read_image

    def spy(path, *args, **kwargs):  # type: ignore[no-untyped-def]
        decoded.append(Path(path).name)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(safe_images, "read_image", spy)
    monkeypatch.setattr(safe_images, "array_size_limit", lambda: 16 * 2**20)
    assert main(["tactile", "import", str(folder), "--out", str(tmp_path / "p.npz")]) == 2
    line = _one_line(capfd)
    assert "5 images" in line and "sample_9.png" in line and "16.0 MiB" in line, line
    assert decoded == []  # refused from the headers alone
    (folder / "sample_9.png").unlink()  # the same folder without it imports
    assert main(["tactile", "import", str(folder), "--out", str(tmp_path / "p.npz")]) == 0
    assert len(decoded) == 4


def test_a_recording_frame_declaring_a_bomb_is_refused(tmp_path: Path) -> None:
    from thintact_sdk.formats.recording import read_array

    frame = tmp_path / "001.png"
    frame.write_bytes(header_only_png(30_000, 30_000, colour=False))
    for scene in (False, True):
        with pytest.raises(RecordingError, match="001.png"):
            read_array(frame, is_scene=scene)
    ok = tmp_path / "002.png"
    cv2.imwrite(str(ok), np.full((6, 8), 513, np.uint16))
    assert read_array(ok, is_scene=False).shape == (6, 8, 1)


def test_a_video_whose_frames_would_not_fit_is_refused_before_decoding(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from thintact_sdk.formats import recording, recording_import

    video = tmp_path / "press.avi"
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for k in range(3):
        out.write(np.full((48, 64, 3), 40 * k, np.uint8))
    out.release()
    assert len(list(recording_import._video_frames(video, None))) == 3
    assert recording.read_video_frame(video, 1, gray=False).shape == (48, 64, 3)
    monkeypatch.setattr(safe_images, "array_size_limit", lambda: 64 * 48 * 3 - 1)
    with pytest.raises(RecordingError, match=r"press.avi: the video's 64×48 px frames"):
        next(recording_import._video_frames(video, None))
    with pytest.raises(RecordingError, match=r"press.avi: the video's 64×48 px frames"):
        recording.read_video_frame(video, 1, gray=False)
