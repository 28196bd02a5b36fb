"""`thintact tactile import | depth | evaluate` on a folder of JPEGs written from the vendored
real GelSight presses (Taxim, MIT), and the progress lines when stderr is not a terminal."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thintact_sdk.apps.cli.main import main
from thintact_sdk.host.progress import stage_reporter
from thintact_sdk.tactile.calibration.press_pack import import_folder, load_press_pack

VENDORED = Path(__file__).resolve().parents[2] / "thintact_sdk" / "data" / "gelsight" / \
    "gelsight_ball_presses.npz"


def _folder(tmp_path: Path, bgr_files: bool = False, border: int = 0) -> Path:
    with np.load(VENDORED, allow_pickle=False) as z:
        f0, imgs = z["f0"], z["imgs"]
    d = tmp_path / "gel"
    d.mkdir(parents=True)

    def write(name: str, rgb: np.ndarray) -> None:
        rgb = np.pad(rgb, ((border, border), (border, border), (0, 0)), constant_values=7)
        arr = rgb if bgr_files else rgb[..., ::-1]  # OpenCV writes B, G, R
        assert cv2.imwrite(str(d / name), np.ascontiguousarray(arr),
                           [cv2.IMWRITE_JPEG_QUALITY, 95])

    write("ref.jpg", f0)
    for i, img in enumerate(imgs):
        write(f"sample_{i + 1}.jpg", img)
    return d


def test_import_declares_colour_order_and_crop(tmp_path):
    with np.load(VENDORED, allow_pickle=False) as z:
        f0 = z["f0"].astype(np.float64)
    plain = import_folder(_folder(tmp_path / "a"))
    swapped = import_folder(_folder(tmp_path / "b", bgr_files=True, border=3),
                            colour_order="bgr", crop=(3, 3, 3, 3))
    for pack in (plain, swapped):
        assert pack.images.shape == (8, 120, 160, 3) and pack.reference.shape == (120, 160, 3)
        assert pack.names[:3] == ["sample_1.jpg", "sample_2.jpg", "sample_3.jpg"]
        assert float(np.abs(pack.reference - f0).mean()) < 3.0  # JPEG loss only
    wrong = import_folder(_folder(tmp_path / "c"), colour_order="bgr")
    assert float(np.abs(wrong.reference - f0).mean()) > 3 * float(
        np.abs(plain.reference - f0).mean())


def test_cli_evaluate_takes_the_ball_model_as_calibrate_tactile_does(tmp_path, capsys):
    pack = tmp_path / "pack.npz"
    assert main(["tactile", "import", str(_folder(tmp_path)), "--out", str(pack), "--mm-per-px", "0.1245",
                 "--ball-radius-mm", "2"]) == 0
    capsys.readouterr()
    for shape in ("sink-in", "rigid"):
        out = tmp_path / f"{shape}.json"
        assert main(["tactile", "evaluate", str(pack), "--model", "lut", "--ball-model", shape, "--quiet",
                     "--json", str(out)]) == 0
        res = json.loads(out.read_text())
        assert res["ball_model"]["model"] == shape
        # rigid has no parameter; with four presses the sink-in skirt's length is not fitted
        assert (res["ball_model"]["skirt_length_mm"] > 0) == (shape == "sink-in")
        assert f"ball model: {shape}" in capsys.readouterr().out
    # four training presses: auto keeps the rigid cap and says why
    out = tmp_path / "auto.json"
    assert main(["tactile", "evaluate", str(pack), "--model", "lut", "--quiet", "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["ball_model"]["model"] == "rigid" and res["ball_model"]["chosen_by"].startswith("default")


def _no_constant(token):
    raise AssertionError(f"{token} in JSON output (strict readers refuse it)")


def test_cli_import_evaluate_depth(tmp_path, capsys):
    folder = _folder(tmp_path)
    pack = tmp_path / "pack.npz"
    assert main(["tactile", "import", str(folder), "--out", str(pack), "--mm-per-px", "0.1245",
                 "--ball-radius-mm", "2"]) == 0
    loaded = load_press_pack(pack)
    assert loaded.mm_per_px == 0.1245 and loaded.ball_radius_mm == 2.0
    out = tmp_path / "ev.json"
    assert main(["tactile", "evaluate", str(pack), "--model", "lut", "--json", str(out)]) == 0
    text = capsys.readouterr()
    assert "fitted sphere radius" in text.out and "[" in text.err  # progress lines on stderr
    assert "skirt included" in text.out and "under 45 deg" in text.out
    assert "the calibration's ball model pressed as deep reads" in text.out
    res = json.loads(out.read_text(), parse_constant=_no_constant)  # strict JSON: no NaN
    assert 0 < res["summary"]["contact_ratio_taught_median"] < 1
    assert all(0 < p["contact_ratio_taught"] < 1 for p in res["presses"])
    assert res["train"] == [0, 2, 4, 6] and res["test"] == [1, 3, 5, 7]
    assert res["gradient_model"] == "lut" and len(res["presses"]) == 4
    lut = tmp_path / "lut.npz"
    from thintact_sdk.tactile.calibration.press_pack import evaluate_pack

    evaluate_pack(loaded, 2.0, 0.1245, model="lut")["lut"].save(lut)
    depth = tmp_path / "depth"
    assert main(["tactile", "depth", "--pack", str(pack), "--lut", str(lut), "--out",
                 str(depth), "--quiet"]) == 0
    frames = json.loads((depth / "frames.json").read_text())["frames"]
    assert len(frames) == 8 and all(f["contact"] for f in frames)
    d0 = np.load(depth / "depth_0000.npy")
    assert d0.shape == (120, 160) and abs(float(d0.max()) - frames[0]["peak_depth_mm"]) < 1e-3
    png = cv2.imread(str(depth / "depth_0000.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint16 and abs(int(png.max()) - round(float(d0.max()) * 1000)) <= 1


@pytest.mark.parametrize("argv, needle", [
    (["tactile", "import", "/no/such/folder", "--out", "{tmp}/p.npz"], "not a folder"),
    (["tactile", "import", "{folder}", "--out", "{tmp}/p.npz", "--crop", "1,2"], "--crop"),
    (["tactile", "import", "{folder}", "--out", "{tmp}/p.npz", "--reference", "nope*"],
     "matches 0 images"),
    (["tactile", "evaluate", "{tmp}/pack.npz", "--train", "0,99"], "not in the pack"),
    (["tactile", "depth", "--pack", "{tmp}/pack.npz", "--out", "{tmp}/d"], "needs --lut"),
])
def test_cli_errors_are_one_line(tmp_path, capsys, argv, needle):
    folder = _folder(tmp_path)
    assert main(["tactile", "import", str(folder), "--out", str(tmp_path / "pack.npz"),
                 "--mm-per-px", "0.1245", "--ball-radius-mm", "2"]) == 0
    capsys.readouterr()
    args = [a.format(tmp=tmp_path, folder=folder) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0]


def test_pack_with_pickled_member_is_refused(tmp_path, capsys):
    p = tmp_path / "bad.npz"
    np.savez(p, imgs=np.array([object()], dtype=object), f0=np.zeros((10, 10, 3), np.uint8))
    assert main(["tactile", "evaluate", str(p), "--ball-radius-mm", "2", "--mm-per-px",
                 "0.1"]) == 2
    assert "imgs" in capsys.readouterr().err


def test_progress_lines_when_not_a_terminal():
    buf = io.StringIO()
    with stage_reporter(stream=buf) as say:
        say("first")
        say("second")
    lines = buf.getvalue().splitlines()
    assert len(lines) == 2 and lines[0].endswith("] first") and lines[0].startswith("[")
    quiet = io.StringIO()
    with stage_reporter(quiet=True, stream=quiet) as say:
        say("nothing")
    assert quiet.getvalue() == ""


@pytest.mark.parametrize("argv", [
    ["tactile", "import", "{folder}", "--out", ""],
    ["tactile", "depth", "--pack", "{vendored}", "--lut", "x.npz", "--out", " "],
    ["tactile", "evaluate", "{vendored}", "--ball-radius-mm", "2", "--mm-per-px", "0.1245",
     "--json", ""],
])
def test_empty_outputs_are_refused_before_any_work(tmp_path, capsys, monkeypatch, argv):
    folder = _folder(tmp_path)
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main([a.format(folder=folder, vendored=VENDORED) for a in argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "empty" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def _gelsight_recording(tmp_path: Path, presses: int) -> Path:
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.formats.recording import RecordingWriter

    prof = load_profile("gelsight-mini")
    with np.load(VENDORED, allow_pickle=False) as z:
        f0, imgs = z["f0"], z["imgs"]

    def raw(a: np.ndarray) -> np.ndarray:
        return cv2.resize(a, (prof.sensor.cols, prof.sensor.rows),
                          interpolation=cv2.INTER_LINEAR).astype(np.uint16)

    rec = RecordingWriter(tmp_path / "rec", prof)
    rec.add(raw(f0), label="reference")
    for im in imgs[:presses]:
        rec.add(raw(im), label="press")
    return tmp_path / "rec"


def test_cli_depth_of_a_recording(tmp_path, capsys):
    rec = _gelsight_recording(tmp_path, 3)
    out = tmp_path / "out"
    assert main(["tactile", "depth", "--recording", str(rec), "--profile", "gelsight-mini",
                 "--out", str(out)]) == 0
    assert "frame 4/4" in capsys.readouterr().err  # progress lines, stderr not a terminal
    frames = json.loads((out / "frames.json").read_text())["frames"]
    assert [f["contact"] for f in frames] == [False, True, True, True]
    assert frames[0]["peak_depth_mm"] == 0.0 and frames[0]["force_n"] == [0.0, 0.0, 0.0]
    assert all(0.5 < f["peak_depth_mm"] < 2.0 and f["force_n"][2] > 0 for f in frames[1:])
    assert sorted(p.name for p in out.glob("depth_*.npy")) == [f"depth_{k:04d}.npy" for k in range(4)]


def test_the_library_depth_maps_are_the_commands(tmp_path, capsys):
    """``interpret_frames`` (and ``write_depth_maps``) give the frames and maps that
    ``thintact tactile depth --recording`` writes."""
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.interpretation.depth_maps import frame_entry, interpret_frames

    rec = _gelsight_recording(tmp_path, 2)
    out = tmp_path / "out"
    assert main(["tactile", "depth", "--recording", str(rec), "--profile", "gelsight-mini",
                 "--out", str(out), "--quiet"]) == 0
    assert "3 depth maps (2 in contact)" in capsys.readouterr().out
    written = json.loads((out / "frames.json").read_text())
    assert written["format"] == "thintact-depth-frames/1"
    lib = list(interpret_frames(recording=rec, profile=load_profile("gelsight-mini")))
    assert [frame_entry(k, name, frame) for k, name, frame, _ in lib] == written["frames"]
    for k, _, frame, n in lib:
        assert n == 3
        np.testing.assert_array_equal(np.load(out / f"depth_{k:04d}.npy"), frame.depth_mm.astype(np.float32))


def test_calibrate_tactile_prints_the_press_report(tmp_path, capsys):
    rec = _gelsight_recording(tmp_path, 4)
    out = tmp_path / "lut.npz"
    assert main(["calibrate-tactile", "--profile", "gelsight-mini", "--recording", str(rec),
                 "--ball-radius-mm", "2", "--model", "auto", "--out", str(out)]) == 0
    text = capsys.readouterr()
    assert text.out.count("warning: circle radius") == 4  # every press wider than the ball
    assert "press 3: circle at" in text.out and "reconstructed" in text.err
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["gradient_model"] == "lut" and len(meta["press_report"]) == 4
    # the contact rim each press's taught shape shows, and their median, stored and printed
    rims = [e["contact_rim_mm"] for e in meta["press_report"]]
    assert all(r is not None for r in rims)
    assert meta["contact_rim_mm"] == pytest.approx(max(0.0, float(np.median(rims))), abs=1e-4)
    assert f"contact regions grown by {meta['contact_rim_mm']:.3f} mm" in text.out
    assert text.out.count(" mm inside it") + text.out.count(" mm outside it") == 4


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(min_value=0, max_value=4000), junk=st.binary(min_size=0, max_size=64))
def test_damaged_pack_is_one_line_exit_2(tmp_path, capsys, cut, junk):
    good = VENDORED.read_bytes()
    p = tmp_path / "damaged.npz"
    p.write_bytes(good[:cut] + junk)
    rc = main(["tactile", "evaluate", str(p), "--ball-radius-mm", "2", "--mm-per-px", "0.1245",
               "--model", "lut", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "damaged.npz" in err[0]


@settings(max_examples=40, deadline=None)
@given(text=st.text(alphabet="0123456789,-x ", max_size=12))
def test_crop_option_is_parsed_or_refused(text):
    from thintact_sdk.errors import CalibrationError
    from thintact_sdk.tactile.calibration.press_pack import parse_crop

    try:
        crop = parse_crop(text)
    except CalibrationError as err:
        assert "--crop" in str(err)
    else:
        assert len(crop) == 4 and min(crop) >= 0
        assert crop == tuple(int(v) for v in text.split(","))


def test_calibrate_tactile_ball_model_option(tmp_path, capsys):
    """--ball-model sink-in with 4 presses (too few to choose the length on held-out
    presses): the middle candidate length, stored; no 'not physical' warning."""
    rec = _gelsight_recording(tmp_path, 4)
    out = tmp_path / "lut.npz"
    assert main(["calibrate-tactile", "--profile", "gelsight-mini", "--recording", str(rec),
                 "--ball-radius-mm", "2", "--model", "lut", "--ball-model", "sink-in",
                 "--quiet", "--out", str(out)]) == 0
    assert "warning: circle radius" not in capsys.readouterr().out
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["ball_model"]["model"] == "sink-in"
    assert meta["ball_model"]["skirt_length_mm"] == pytest.approx(0.9)
    assert all("sink_in_mm" in e for e in meta["press_report"])


def test_a_file_name_that_is_not_utf8_is_imported(tmp_path):
    """OpenCV's own reader crashed the process (segmentation fault) on such a name; the bytes
    are now read by Python and decoded from memory."""
    d = _folder(tmp_path)
    os_dir = bytes(d)
    (d / "sample_2.jpg").rename(Path(os.fsdecode(os_dir + b"/sample_\xff.jpg")))
    pack = import_folder(d)
    assert pack.images.shape[0] == 8
    assert any("\udcff" in n for n in pack.names)


def test_a_video_name_that_is_not_utf8_is_refused_naming_it(tmp_path):
    from thintact_sdk.errors import RecordingError
    from thintact_sdk.formats.safe_images import opencv_path

    bad = Path(os.fsdecode(bytes(tmp_path) + b"/clip_\xff.avi"))
    with pytest.raises(RecordingError, match=r"clip_\\xff\.avi.*not valid UTF-8"):
        opencv_path(bad, RecordingError)
    assert opencv_path(tmp_path / "clip.avi") == str(tmp_path / "clip.avi")


def test_import_out_must_be_an_npz_and_nothing_is_overwritten(tmp_path, capsys):
    victim = tmp_path / "victim.npz"
    victim.write_bytes(b"precious")
    assert main(["tactile", "import", str(_folder(tmp_path)), "--out", str(tmp_path / "victim")]) == 2
    err = capsys.readouterr().err
    assert "must name a .npz file" in err and len(err.strip().splitlines()) == 1
    assert victim.read_bytes() == b"precious"


def test_a_ball_too_large_for_the_frame_is_refused_and_a_large_one_is_quick(capsys):
    """The press grid ran to 0.95 R: 1e9 mm ended in a 283 GiB MemoryError, 1000 mm took
    minutes. It now stops at the cap whose contact spans the frame's diagonal."""
    from thintact_sdk.errors import CalibrationError
    from thintact_sdk.tactile.calibration.ball_press import BallModel

    rigid = BallModel("rigid")
    assert rigid.parameters(2.0)[-1] == pytest.approx(1.9, abs=0.025)
    capped = rigid.parameters(1000.0, reach_mm=12.5)
    assert 0.05 <= capped[-1] <= 12.5**2 / 2000 + 1e-9 and len(capped) <= 4
    with pytest.raises(CalibrationError, match="ball radius 1e\\+09 mm"):
        rigid.parameters(1e9, reach_mm=12.5)
    argv = ["tactile", "evaluate", str(VENDORED), "--model", "lut", "--ball-model", "rigid", "--quiet",
            "--mm-per-px", "0.0623", "--ball-radius-mm"]
    assert main([*argv, "1e9"]) == 2
    err = capsys.readouterr().err
    assert "check the ball radius" in err and len(err.strip().splitlines()) == 1


def test_annotated_circles_that_cannot_be_evaluated_are_said_so(tmp_path, capsys):
    with np.load(VENDORED, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["touch_radius"] = np.zeros_like(arrays["touch_radius"])
    np.savez(tmp_path / "zero.npz", **arrays)
    assert main(["tactile", "evaluate", str(tmp_path / "zero.npz"), "--model", "lut", "--ball-model", "rigid",
                 "--quiet", "--mm-per-px", "0.0623", "--ball-radius-mm", "2"]) == 0
    assert "against the annotated circles: none could be evaluated" in capsys.readouterr().out


def test_depth_maps_into_a_folder_whose_name_is_not_utf8(tmp_path, capsys):
    """cv2.imwrite crashed the process on such a path; the PNGs are encoded in memory."""
    lut = VENDORED.with_name("gelsight-mini-lut.npz")
    out = Path(os.fsdecode(bytes(tmp_path) + b"/depth_\xff"))
    assert main(["tactile", "depth", "--pack", str(VENDORED), "--lut", str(lut), "--out", str(out),
                 "--mm-per-px", "0.1245"]) == 0
    png = cv2.imdecode(np.fromfile(out / "depth_0000.png", np.uint8), cv2.IMREAD_UNCHANGED)
    npy = np.load(out / "depth_0000.npy")
    assert png.dtype == np.uint16 and png.shape == npy.shape
    np.testing.assert_array_equal(png, np.clip(np.round(npy.astype(np.float64) * 1000), 0, 65535))
