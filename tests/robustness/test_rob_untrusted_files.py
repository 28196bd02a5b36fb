"""Files a user is handed are data, never code, and never exhaust memory.

Every loader of a user's ``.npy``/``.npz``/checkpoint/JSON file is given a crafted file whose
pickled member would create a marker file when unpickled: it must refuse with a
ThinTactError naming the file (and member) and the marker must not exist. Random bytes,
headers declaring terabytes and JSON nested 100 000 deep are clean refusals too.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
import tracemalloc
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import numpy.lib.format as npy_format
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import CalibrationError, ProfileError, RecordingError, ThinTactError
from thintact_sdk.formats.safe_arrays import ArrayFileError, read_npy, read_npz

REAL_PACK = Path(__file__).resolve().parents[2] / "thintact_sdk" / "data" / "gelsight" / \
    "gelsight_ball_presses.npz"
HUGE = (2**20, 2**20, 3)


class Payload:
    """Unpickling this creates ``marker`` (``open(marker, "w")``): proof that code ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (open, (str(self.marker), "w"))


def payload_npy(marker: Path) -> bytes:
    """A ``.npy`` of an object array whose element is a :class:`Payload`."""
    buf = io.BytesIO()
    arr = np.empty(1, dtype=object)
    arr[0] = Payload(marker)
    np.save(buf, arr, allow_pickle=True)
    return buf.getvalue()


def huge_npy(shape: tuple[int, ...] = HUGE, dtype: str = "u1", data: bytes = b"\0" * 64) -> bytes:
    """A ``.npy`` whose header declares ``shape`` (but holds only ``data``)."""
    buf = io.BytesIO()
    npy_format.write_array_header_1_0(
        buf, {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": shape})
    return buf.getvalue() + data


def write_npz(path: Path, members: dict[str, bytes | np.ndarray]) -> Path:
    """A zip archive of ``.npy`` members (raw bytes written as given)."""
    with zipfile.ZipFile(path, "w") as z:
        for name, value in members.items():
            if isinstance(value, np.ndarray):
                buf = io.BytesIO()
                np.save(buf, value, allow_pickle=value.dtype.hasobject)
                value = buf.getvalue()
            z.writestr(f"{name}.npy", value)
    return path


def pack_with(path: Path, member: str, value: bytes | np.ndarray) -> Path:
    """The shipped GelSight press pack with ``member`` replaced by ``value``."""
    with np.load(REAL_PACK, allow_pickle=False) as z:
        members: dict[str, bytes | np.ndarray] = {k: z[k] for k in z.files}
    members[member] = value
    return write_npz(path, members)


def test_the_payload_really_runs_code_when_unpickled(tmp_path: Path) -> None:
    """The crafted file is a real threat (so the refusals below are meaningful)."""
    marker = tmp_path / "ran"
    (tmp_path / "evil.npy").write_bytes(payload_npy(marker))
    np.load(tmp_path / "evil.npy", allow_pickle=True)
    assert marker.exists()


# -- press packs ------------------------------------------------------------------------------

def _load_pack(p: Path) -> object:
    from thintact_sdk.tactile.calibration.gelsight_eval import load_pack

    return load_pack(p)


def _from_pack(p: Path) -> object:
    from thintact_sdk.tactile.learning.domains import RealPresses

    return RealPresses.from_pack(p)


def _load_presses(p: Path) -> object:
    from thintact_sdk.diagnosis.tactile.press_data import load_presses

    return load_presses(p)


def _load_presses_dir(p: Path) -> object:
    return _load_presses(p.parent)


PACK_LOADERS: dict[str, Callable[[Path], object]] = {
    "gelsight_eval.load_pack": _load_pack, "RealPresses.from_pack": _from_pack,
    "sim_diagnosis.load_presses": _load_presses, "load_presses(directory)": _load_presses_dir,
}


def test_the_shipped_and_the_real_pack_still_load() -> None:
    pack = _load_pack(REAL_PACK)
    assert isinstance(pack, dict) and pack["names"].dtype.kind == "U"
    with np.load(REAL_PACK, allow_pickle=False) as z:
        assert sorted(pack) == sorted(z.files)
        for k in z.files:
            np.testing.assert_array_equal(pack[k], z[k])
    shared = Path(__file__).resolve().parents[3] / "shared" / "data" / \
        "taxim_gelsight_ball_small" / "dataPack_small.npz"
    if shared.is_file():
        assert _from_pack(shared).images.shape == (49, 120, 160, 3)  # type: ignore[attr-defined]


@pytest.mark.parametrize("member", ["imgs", "names"])
@pytest.mark.parametrize("loader", list(PACK_LOADERS))
def test_a_pickled_pack_member_is_refused_and_never_run(loader: str, member: str,
                                                        tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    pack = pack_with(_fresh(tmp_path), member, payload_npy(marker))
    if member == "names" and loader != "gelsight_eval.load_pack":
        PACK_LOADERS[loader](pack)  # members it does not read are not read at all
    else:
        with pytest.raises(ThinTactError) as err:
            PACK_LOADERS[loader](pack)
        assert str(pack) in str(err.value) and repr(member) in str(err.value)
        assert "Python objects" in str(err.value)
    assert not marker.exists()


def _fresh(tmp_path: Path) -> Path:
    d = tmp_path / "packdir"
    d.mkdir(exist_ok=True)
    return d / "dataPack.npz"


@pytest.mark.parametrize("loader", list(PACK_LOADERS))
@pytest.mark.parametrize("content", ["random", "zip-magic-random", "truncated", "empty"])
def test_a_damaged_pack_is_a_clean_error_naming_it(loader: str, content: str,
                                                   tmp_path: Path) -> None:
    p = _fresh(tmp_path)
    rng = np.random.default_rng(1)
    data = {"random": rng.bytes(4096), "zip-magic-random": b"PK\x03\x04" + rng.bytes(4096),
            "truncated": REAL_PACK.read_bytes()[:5000], "empty": b""}[content]
    p.write_bytes(data)
    with pytest.raises(ThinTactError) as err:
        PACK_LOADERS[loader](p)
    assert str(p) in str(err.value)
    assert "pickle" not in str(err.value).lower()


@pytest.mark.parametrize("loader", list(PACK_LOADERS))
def test_a_pack_declaring_terabytes_is_refused_before_reading(loader: str, tmp_path: Path) -> None:
    p = pack_with(_fresh(tmp_path), "imgs", huge_npy((2**20, 2**20, 3, 3)))
    tracemalloc.start()
    try:
        with pytest.raises(ThinTactError) as err:
            PACK_LOADERS[loader](p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    msg = str(err.value)
    assert str(p) in msg and "'imgs'" in msg and "limit" in msg and "TiB" in msg, msg
    assert peak < 64 * 2**20


# -- through the CLI ---------------------------------------------------------------------------

def _one_line(capfd: pytest.CaptureFixture[str]) -> str:
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "error:" in lines[0] and "internal error" not in lines[0], err
    return lines[0]


@pytest.mark.parametrize("command", ["diagnose-tactile", "real2sim train"])
@pytest.mark.parametrize("damage", ["pickled", "random", "huge"])
def test_cli_refuses_a_hostile_pack_with_one_line(command: str, damage: str, tmp_path: Path,
                                                  capfd: pytest.CaptureFixture[str]) -> None:
    marker = tmp_path / "ran"
    p = _fresh(tmp_path)
    if damage == "pickled":
        pack_with(p, "imgs", payload_npy(marker))
    elif damage == "random":
        p.write_bytes(np.random.default_rng(2).bytes(3000))
    else:
        pack_with(p, "f0", huge_npy())
    out = tmp_path / "out"
    argv = ({"diagnose-tactile": ["diagnose-tactile", str(p), "--out", str(out), "--quiet"],
             "real2sim train": ["real2sim", "train", "--real", str(p), "--out", str(out),
                                "--iterations", "1", "--device", "cpu"]})[command]
    assert main(argv) == 2
    line = _one_line(capfd)
    assert str(p) in line
    assert not marker.exists()


@pytest.mark.parametrize("damage", ["pickled", "huge", "random"])
def test_simulate_and_calibrate_pose_refuse_hostile_npy(damage: str, tiny: dict[str, Any],
                                                        tmp_path: Path,
                                                        capfd: pytest.CaptureFixture[str]) -> None:
    marker = tmp_path / "ran"
    bad = tmp_path / "bad.npy"
    bad.write_bytes({"pickled": payload_npy(marker), "huge": huge_npy(),
                     "random": np.random.default_rng(3).bytes(999)}[damage])
    needles = {"pickled": "Python objects", "huge": "limit", "random": "not a .npy"}[damage]
    for argv in (["simulate", "--profile", str(tiny["profile_file"]), "--scenes", str(bad),
                  "--out", str(tmp_path / "m.npy")],
                 ["calibrate-pose", str(bad), "--profile", str(tiny["profile_file"]),
                  "--out", str(tmp_path / "p.json")]):
        assert main(argv) == 2, argv
        line = _one_line(capfd)
        assert str(bad) in line and needles in line, line
        if damage == "huge":
            assert "1048576×1048576×3" in line and "3.0 TiB" in line, line
    assert not marker.exists()


# -- recordings, replay, reconstruct -----------------------------------------------------------

@pytest.mark.parametrize("damage", ["pickled", "huge", "random"])
def test_a_hostile_recording_frame_is_refused(damage: str, tiny: dict[str, Any], rec_copy: Path,
                                              tmp_path: Path,
                                              capfd: pytest.CaptureFixture[str]) -> None:
    from thintact_sdk.formats.recording import Recording

    marker = tmp_path / "ran"
    frame = rec_copy / "measurements" / "001.npy"
    frame.write_bytes({"pickled": payload_npy(marker), "huge": huge_npy(),
                       "random": np.random.default_rng(4).bytes(999)}[damage])
    rec = Recording(rec_copy)
    with pytest.raises(RecordingError) as err:
        rec.measurement(1)
    assert str(frame) in str(err.value)
    if damage == "huge":
        assert "3.0 TiB" in str(err.value) and "limit" in str(err.value)

    from thintact_replay.camera import ReplayCamera

    cam = ReplayCamera(rec.profile, {"path": str(rec_copy)})
    with pytest.raises(RecordingError, match="frame 1 file measurements/001.npy"):
        cam.open()

    assert main(["reconstruct", str(rec_copy), "--calibration", str(tiny["bundle"]), "--out",
                 str(tmp_path / "est"), "--no-progress", "--decoder", "flatcam"]) == 2
    assert "001.npy" in _one_line(capfd)
    assert not marker.exists()


def test_a_manifest_nested_100000_deep_is_refused(rec_copy: Path) -> None:
    from thintact_sdk.formats.recording import Recording

    manifest = rec_copy / "manifest.json"
    manifest.write_text('{"format": "thintact-recording/1", "x": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(RecordingError, match="manifest.json: JSON nested too deeply"):
        Recording(rec_copy)
    manifest.write_text('{"format": "thintact-recording/1", "x": ' + "[" * 500 + "]" * 500 + "}")
    with pytest.raises(RecordingError, match="manifest.json: JSON nested more than 64 levels"):
        Recording(rec_copy)


# -- calibration files -------------------------------------------------------------------------

def test_bundle_meta_json_nested_deeply_is_refused(bundle_copy: Path) -> None:
    from thintact_sdk.formats.bundle_npz import read_npz as read_bundle_npz

    path = bundle_copy / "filter.npz"
    with np.load(path, allow_pickle=False) as z:
        members: dict[str, bytes | np.ndarray] = {k: z[k] for k in z.files}
    members["meta_json"] = np.array("[" * 100_000 + "]" * 100_000)
    write_npz(path, members)
    with pytest.raises(CalibrationError, match="filter.npz: meta_json: JSON nested too deeply"):
        read_bundle_npz(path, "filter", ("phi_f", "phi_s"))


def test_calibration_loaders_refuse_pickled_members(bundle_copy: Path, tiny: dict[str, Any],
                                                    tmp_path: Path) -> None:
    from thintact_sdk.formats.matrices import import_matrices
    from thintact_sdk.reconstruction.bundle import CalibrationBundle
    from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT

    marker = tmp_path / "ran"
    evil = payload_npy(marker)
    write_npz(bundle_copy / "system_matrices.npz", {k: evil for k in ("Po", "Qo", "Pc", "Qc")})
    with pytest.raises(CalibrationError, match=r"system_matrices.npz member 'Po'.*Python objects"):
        CalibrationBundle.load(bundle_copy)
    lut = write_npz(tmp_path / "lut.npz", {"lo": np.zeros(3), "hi": np.ones(3), "table": evil,
                                           "counts": np.zeros((2, 2, 2))})
    with pytest.raises(CalibrationError, match=r"lut.npz member 'table'.*Python objects"):
        PhotometricLUT.load(lut)
    mats = write_npz(tmp_path / "m.npz", {"Phi_L": evil, "Phi_R": np.eye(3)})
    with pytest.raises(CalibrationError, match=r"m.npz member 'Phi_L'.*Python objects"):
        import_matrices(mats, tiny["profile"])
    assert not marker.exists()


def test_a_tone_curve_table_file_is_read_strictly(tmp_path: Path) -> None:
    from thintact_sdk.formats.profiles import (
        load_profile,
        profile_from_dict,
        read_profile_file,
        write_profile,
    )

    marker = tmp_path / "ran"
    d = load_profile("virtual-mini").contract_dict()
    d["sensor"]["tone_curve"] = {"kind": "table", "bits": 3, "file": "tone.npy"}
    np.save(tmp_path / "tone.npy", np.arange(8.0))
    write_profile(profile_from_dict(d), tmp_path / "p.json")
    read_profile_file(tmp_path / "p.json")  # the clean table loads
    for content, needle in ((payload_npy(marker), "Python objects"), (huge_npy(), "limit")):
        (tmp_path / "tone.npy").write_bytes(content)
        with pytest.raises(ProfileError, match=f"tone.npy.*{needle}"):
            read_profile_file(tmp_path / "p.json")
    assert not marker.exists()


# -- Real2Sim checkpoints and generators -------------------------------------------------------

def test_real2sim_checkpoint_and_generator_never_run_code(tmp_path: Path) -> None:
    from thintact_sdk.tactile.learning.model_file import load_generator
    from thintact_sdk.tactile.learning.train import CHECKPOINT_FORMAT, Real2SimTrainer, TrainConfig

    marker = tmp_path / "ran"
    rng = np.random.default_rng(0)
    real = rng.random((3, 24, 32, 3), dtype=np.float32)
    cfg = TrainConfig(iterations=1, batch=2, crop=16, width=4, blocks=1, edge_kernel=3)
    out = tmp_path / "run"
    trainer = Real2SimTrainer(real, real, out, cfg, "cpu")
    torch.save({"format": CHECKPOINT_FORMAT, "config": {}, "x": Payload(marker)},
               trainer.checkpoint_path)
    with pytest.raises(ThinTactError, match="checkpoint.pt: unreadable checkpoint"):
        trainer.resume()
    torch.save({"format": CHECKPOINT_FORMAT, "config": {"width": 4, "blocks": 1, "edge_kernel": 3,
                "batch": 2, "crop": 16, "seed": 0}, "model": "nope"}, trainer.checkpoint_path)
    with pytest.raises(ThinTactError, match="checkpoint.pt: damaged checkpoint"):
        trainer.resume()
    gen = tmp_path / "generator.pt"
    torch.save({"format": "thintact-real2sim/1", "x": Payload(marker)}, gen)
    with pytest.raises(ThinTactError, match="generator.pt: not a Real2Sim generator file"):
        load_generator(gen)
    torch.save({"format": "thintact-real2sim/1", "state_dict": {}, "meta": {},
                "config": {"width": 10**6, "blocks": 10**3, "edge_kernel": 3}}, gen)
    with pytest.raises(ThinTactError, match="does not fit the 0 stored weights"):
        load_generator(gen)
    assert not marker.exists()


def test_a_real_checkpoint_still_resumes(tmp_path: Path) -> None:
    from thintact_sdk.tactile.learning.train import Real2SimTrainer, TrainConfig

    real = np.random.default_rng(0).random((3, 24, 32, 3), dtype=np.float32)
    cfg = TrainConfig(iterations=1, batch=2, crop=16, width=4, blocks=1, edge_kernel=3,
                      checkpoint_every=1)
    Real2SimTrainer(real, real, tmp_path, cfg, "cpu").run()
    again = Real2SimTrainer(real, real, tmp_path, cfg, "cpu")
    assert again.resume() and again.iteration == 1


# -- mask designs and GA checkpoints -----------------------------------------------------------

@pytest.mark.parametrize("content", [b"\xff\xfe\x00garbage\x80\x81", b"[" * 100_000,
                                     b'{"format": "thintact-mask-design/1", "phi": [1, "x"]}',
                                     b'{"format": "thintact-mask-design/1", "phi": [1, -1], '
                                     b'"phi_rows": [1, 300]}',
                                     b'{"format": "thintact-mask-design/1", "phi": [1, -1], '
                                     b'"feature_um": "wide"}'])
def test_a_bad_design_file_is_a_clean_error_naming_it(content: bytes, tmp_path: Path) -> None:
    from thintact_masks.design_io import load_design
    from thintact_masks.errors import MaskDesignError

    p = tmp_path / "d.json"
    p.write_bytes(content)
    with pytest.raises(MaskDesignError, match="d.json"):
        load_design(p)


def test_a_pickled_ga_checkpoint_is_refused(tmp_path: Path) -> None:
    from thintact_masks.errors import MaskDesignError
    from thintact_masks.ga import CHECKPOINT_NAME, load_checkpoint

    marker = tmp_path / "ran"
    write_npz(tmp_path / CHECKPOINT_NAME, {
        "population": payload_npy(marker), "fitness": np.zeros(2), "best_history": np.zeros(1),
        "mean_history": np.zeros(1), "meta": np.array(json.dumps({"format": "x"}))})
    with pytest.raises(MaskDesignError, match=r"checkpoint.npz member 'population'.*Python objects"):
        load_checkpoint(tmp_path)
    (tmp_path / CHECKPOINT_NAME).write_bytes(os.urandom(300))
    with pytest.raises(MaskDesignError, match="checkpoint.npz"):
        load_checkpoint(tmp_path)
    assert not marker.exists()


# -- the reader itself -------------------------------------------------------------------------

def test_reader_refuses_a_large_declared_array_before_allocating(tmp_path: Path) -> None:
    p = tmp_path / "big.npy"
    np.save(p, np.zeros(8 * 2**20, np.uint8))
    tracemalloc.start()
    try:
        with pytest.raises(ArrayFileError, match=r"big.npy: declares a 8388608 uint8 array of "
                                                 r"8.0 MiB, more than the 1.0 MiB limit"):
            read_npy(p, limit=2**20)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2**20
    assert read_npy(p).shape == (8 * 2**20,)
    assert read_npy(p, mmap=True).shape == (8 * 2**20,)


def test_reader_counts_every_member_towards_the_limit(tmp_path: Path) -> None:
    p = write_npz(tmp_path / "two.npz", {"a": np.zeros(600_000, np.uint8),
                                         "b": np.zeros(600_000, np.uint8)})
    assert set(read_npz(p, limit=2**20, members=("a",))) == {"a"}
    with pytest.raises(ArrayFileError, match="two.npz member 'b'.*with 585.9 KiB of other arrays"):
        read_npz(p, limit=2**20)


def test_reader_refuses_a_member_declaring_more_than_it_holds(tmp_path: Path) -> None:
    p = write_npz(tmp_path / "short.npz", {"a": huge_npy((1000,), "f8", b"\0" * 80)})
    with pytest.raises(ArrayFileError, match=r"short.npz member 'a': declares a 1000 float64 "
                                             r"array of 8000 bytes but holds 80 bytes"):
        read_npz(p)
    (tmp_path / "short.npy").write_bytes(huge_npy((1000,), "f8", b"\0" * 80))
    with pytest.raises(ArrayFileError, match="short.npy: declares .* holds 80 bytes"):
        read_npy(tmp_path / "short.npy", mmap=True)


def test_reader_names_a_missing_member_and_a_non_array_member(tmp_path: Path) -> None:
    p = tmp_path / "odd.npz"
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("notes.txt", "hello")
        z.writestr("a.npy", _npy(np.arange(3)))
    with pytest.raises(ArrayFileError, match="odd.npz: missing arrays b"):
        read_npz(p, members=("a", "b"))
    with pytest.raises(ArrayFileError, match=r"odd.npz member 'notes.txt' is not a .npy array"):
        read_npz(p)
    np.testing.assert_array_equal(read_npz(p, members=("a",))["a"], np.arange(3))


def test_reader_names_a_path_the_file_system_cannot_take(tmp_path: Path) -> None:
    """A name longer than the file system allows (ENAMETOOLONG from the first look at it)
    is the reader's error naming the path, not an OSError from inside pathlib."""
    with pytest.raises(ArrayFileError, match="cannot read press pack .*bbbb"):
        read_npz(tmp_path / ("b" * 4000 + ".npz"), what="press pack")


def _npy(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=arr.dtype.hasobject)
    return buf.getvalue()


# -- fuzz: press-pack structure ----------------------------------------------------------------

_DTYPES = ["u1", "f4", "f8", "i8", "b1", "c8", "<U5", "S3", "O"]
_NAMES = ["imgs", "f0", "touch_center", "touch_radius", "names", "img_size", "x", "a.b", "ü"]


Damage = tuple[float | None, list[tuple[float, int]]]


@st.composite
def press_packs(draw: st.DrawFn) -> tuple[dict[str, tuple[str, tuple[int, ...]]], Damage]:
    names = draw(st.lists(st.sampled_from(_NAMES), min_size=0, max_size=6, unique=True))
    members = {}
    for n in names:
        dtype = draw(st.sampled_from(_DTYPES))
        shape = tuple(draw(st.lists(st.integers(0, 5), min_size=0, max_size=4)))
        if n in ("imgs", "f0") and draw(st.booleans()):
            shape = (3, 8, 8, 3) if n == "imgs" else (8, 8, 3)
        members[n] = (dtype, shape)
    cut = draw(st.one_of(st.none(), st.floats(0.0, 1.0)))
    flips = draw(st.lists(st.tuples(st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)),
                          max_size=4))
    return members, (cut, flips)


def _build(spec: dict[str, tuple[str, tuple[int, ...]]], marker: Path) -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    out = {}
    for name, (dtype, shape) in spec.items():
        if dtype == "O":
            arr = np.empty(shape, dtype=object)
            arr.fill(Payload(marker))
        elif dtype in ("<U5", "S3"):
            arr = np.full(shape, "ab", dtype=dtype)
        else:
            arr = (rng.random(shape) * 200).astype(dtype)
        out[name] = _npy(arr)
    return out


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(press_packs())
def test_fuzz_press_pack_structure(case: tuple[dict[str, tuple[str, tuple[int, ...]]],
                                               Damage]) -> None:
    """Member names, dtypes (object, unicode and bytes included), shapes, truncation and
    flipped bytes (a torn header, a torn zip directory): a press pack or one clean error."""
    spec, (cut, flips) = case
    with tempfile.TemporaryDirectory() as tmp:
        marker = Path(tmp) / "ran"
        p = Path(tmp) / "packdir" / "pack.npz"
        p.parent.mkdir()
        write_npz(p, _build(spec, marker))  # type: ignore[arg-type]
        data = bytearray(p.read_bytes())
        for where, value in flips:
            data[int(where * len(data))] = value
        p.write_bytes(bytes(data if cut is None else data[: int(len(data) * cut)]))
        for name, loader in PACK_LOADERS.items():
            try:
                result = loader(p)
            except ThinTactError as err:
                assert str(p) in str(err) or str(p.parent) in str(err), (name, str(err))
            else:
                wanted = ("imgs", "f0") if name != "gelsight_eval.load_pack" else tuple(spec)
                assert not any(spec[k][0] == "O" for k in wanted if k in spec), (name, spec)
                if name != "gelsight_eval.load_pack":
                    images = result.images  # type: ignore[attr-defined]
                    assert images.dtype == np.float32 and np.isfinite(images).all()
        assert not marker.exists()


def test_force_calibration_pack_and_loads_are_read_strictly(tmp_path: Path) -> None:
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.tactile.calibration.force_gains import load_loads, load_press_pack

    marker = tmp_path / "ran"
    profile = load_profile("virtual-finger")
    pack = pack_with(_fresh(tmp_path), "imgs", payload_npy(marker))
    with pytest.raises(CalibrationError, match=r"dataPack.npz member 'imgs'.*Python objects"):
        load_press_pack(pack, profile)
    pack_with(pack, "f0", huge_npy())
    with pytest.raises(CalibrationError, match=r"dataPack.npz member 'f0'.*3.0 TiB.*limit"):
        load_press_pack(pack, profile)
    loads = tmp_path / "loads.json"
    loads.write_text('{"loads_n": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(CalibrationError, match="loads.json: JSON nested too deeply"):
        load_loads(loads, 3)
    assert not marker.exists()


def test_bundle_metadata_nested_100000_deep_is_one_calibration_error(tmp_path: Path) -> None:
    from thintact_sdk.errors import CalibrationError
    from thintact_sdk.reconstruction.bundle import META_FILE, CalibrationBundle

    (tmp_path / META_FILE).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(CalibrationError, match="not a calibration bundle.*nested"):
        CalibrationBundle.load(tmp_path)
