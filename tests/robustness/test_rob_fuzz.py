"""Property-based fuzzing (hypothesis) of recordings, calibration bundles and the CLI entry
points, in process through ``main(argv)``, against the one rule of :mod:`fuzz_harness`.

Bounded time: every test is derandomized with a fixed number of examples and no example
database. The calibration and diagnosis HTML reports are replaced by a one-line stub here
(they are matplotlib rendering, 90 % of those commands' time, and tested elsewhere).
Count-like options are fuzzed with small integers so that a *valid* request never asks for
minutes of work (``record --frames 100000`` is legitimate, not a bug).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import pytest
import rob_kit
from fuzz_harness import assert_nothing_outside, judge, run_cli, snapshot
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.recording import Recording
from thintact_sdk.reconstruction.bundle import CalibrationBundle

SCALE = max(1, int(os.environ.get("THINTACT_FUZZ_SCALE", "1")))
"""Multiplies every test's number of examples (a longer campaign: THINTACT_FUZZ_SCALE=10)."""

FUZZ = settings(deadline=None, derandomize=True, database=None, print_blob=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                       HealthCheck.data_too_large])

JSON_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(), st.text(max_size=8),
    st.sampled_from(["../outside.npy", "/etc/hostname", "measurements/000.npy", "scenes/001.npy",
                     "", ".", "measurements", "profile.json", "measurements/../../outside.npy"]),
    st.lists(st.integers(-3, 3), max_size=2), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2),
)
DTYPES = st.sampled_from(["uint8", "uint16", "int32", "float32", "float64", "bool", "<U3", "complex64",
                          "int8"])
INJECT = st.one_of(st.none(), st.sampled_from([np.nan, np.inf, -np.inf, -1.0, 0.0, 1.5, 4095.0, 65535.0,
                                               1e30, 1e-30]))


def _shapes(full: tuple[int, ...]) -> list[tuple[int, ...]]:
    """Nine shapes around ``full`` (R × S × C): itself, 2-D, 1 or 4 channels, transposed, 4-D, empty, flat."""
    r, c, ch = full
    return [full, (r, c), (r, c, 1), (c, r, ch), (r, c, ch, 1), (0,), (r * c,), (r, c, 4), (r, c, 0)]


def _array(dtype: str, shape: tuple[int, ...], inject: float | None, base: np.ndarray | None,
           seed: int) -> np.ndarray:
    """An array of ``dtype`` and ``shape``: ``base``'s values when the shape matches, else
    random ones at ``base``'s scale; ``inject`` written at one position."""
    numeric = base is not None and base.dtype.kind in "uif" and base.size > 0
    if numeric and base is not None and shape == base.shape:
        arr = base.astype(np.float64)
    else:
        scale = 200.0 if numeric and base is not None and float(base.max()) > 1 else 1.0
        arr = np.random.default_rng(seed).uniform(0, 1, shape) * scale
    if inject is not None and arr.size:
        arr.flat[seed % arr.size] = inject
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return arr.astype(dtype)


@contextmanager
def _workspace(tiny: dict[str, Any]) -> Iterator[tuple[Path, Path]]:
    """``(inputs, work)``: a copy of the tiny recording and bundle, and an empty cwd."""
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        inputs = root / "inputs"
        shutil.copytree(tiny["recording"], inputs / "rec")
        shutil.copytree(tiny["bundle"], inputs / "cal")
        np.save(root / "outside.npy", tiny["meas"][0])
        work = root / "work"
        work.mkdir()
        yield inputs, work


def _check_reconstruction(out: Path, rec_dir: Path) -> Any:
    def check() -> None:
        rec = Recording(rec_dir)
        for fr in rec.frames:
            est = np.load(out / f"{Path(fr.measurement).stem}.npy")
            assert est.shape == (10, 12, 3), est.shape
            assert np.isfinite(est).all()
    return check


# -- recordings: frame JSON and npy mutations -------------------------------------------------
REC_OPS = st.one_of(
    st.tuples(st.just("field"), st.integers(0, 2),
              st.sampled_from(["measurement", "scene", "label", "frame_id", "exposure_us", "timestamp_ns",
                               "gain_db", "dropped_before", "saturated_fraction"]), JSON_VALUES),
    st.tuples(st.just("delete"), st.integers(0, 2), st.sampled_from(["measurement", "scene", "label"])),
    st.tuples(st.just("manifest"), st.sampled_from(["format", "profile", "frames"]), JSON_VALUES),
    st.tuples(st.just("array"), st.integers(0, 2), st.sampled_from(["measurements", "scenes"]), DTYPES,
              st.integers(0, 8), INJECT, st.integers(0, 10_000)),
    st.tuples(st.just("bytes"), st.integers(0, 2), st.sampled_from(["measurements", "scenes"]),
              st.sampled_from(["truncate", "random", "empty"])),
    st.tuples(st.just("symlink"), st.integers(0, 2), st.sampled_from(["measurements", "scenes"])),
    st.tuples(st.just("drop_frames"), st.integers(1, 3)),
)


def _mutate_recording(rec: Path, ops: list[tuple[Any, ...]], tiny: dict[str, Any]) -> None:
    manifest = json.loads((rec / "manifest.json").read_text())
    for op in ops:
        kind = op[0]
        frames = manifest.get("frames") if isinstance(manifest, dict) else None
        if kind == "field" and isinstance(frames, list) and op[1] < len(frames) and isinstance(frames[op[1]], dict):
            frames[op[1]][op[2]] = op[3]
        elif kind == "delete" and isinstance(frames, list) and op[1] < len(frames) and isinstance(frames[op[1]], dict):
            frames[op[1]].pop(op[2], None)
        elif kind == "manifest" and isinstance(manifest, dict):
            manifest[op[1]] = op[2]
        elif kind == "drop_frames" and isinstance(frames, list):
            del frames[: op[1]]
        elif kind in ("array", "bytes", "symlink"):
            f = rec / op[2] / f"{op[1]:03d}.npy"
            if kind == "array":
                base = (tiny["meas"] if op[2] == "measurements" else tiny["scenes"])[op[1]]
                np.save(f, _array(op[3], _shapes(base.shape)[op[4]], op[5], base, op[6]))
            elif kind == "bytes":
                data = f.read_bytes()
                f.write_bytes({"truncate": data[: len(data) // 2], "empty": b"",
                               "random": np.random.default_rng(len(data)).bytes(len(data))}[op[3]])
            else:
                f.unlink()
                f.symlink_to(rec.parent.parent / "outside.npy")
    (rec / "manifest.json").write_text(json.dumps(manifest))


@settings(FUZZ, max_examples=70 * SCALE)
@given(ops=st.lists(REC_OPS, min_size=1, max_size=3))
def test_fuzz_recordings_through_reconstruct(ops: list[tuple[Any, ...]], tiny: dict[str, Any], capfd: Any) -> None:
    with _workspace(tiny) as (inputs, work):
        _mutate_recording(inputs / "rec", ops, tiny)
        before = snapshot(inputs)
        argv = ["reconstruct", str(inputs / "rec"), "--calibration", str(inputs / "cal"), "--out", "out",
                "--decoder", "flatcam", "--no-progress"]
        rc, err = run_cli(argv, work, capfd)
        judge("recording → reconstruct", [*argv, f"mutations={ops}"], rc, err,
              _check_reconstruction(work / "out", inputs / "rec"))
        assert_nothing_outside(work, inputs, before, "out")


# -- calibration bundles: npz mutations --------------------------------------------------------
BUNDLE_OPS = st.one_of(
    st.tuples(st.just("member"), st.sampled_from([("system_matrices.npz", k) for k in ("Po", "Qo", "Pc", "Qc")]
                                                 + [("filter.npz", k) for k in ("phi_f", "phi_s")]),
              DTYPES, st.integers(0, 5), INJECT, st.integers(0, 10_000)),
    st.tuples(st.just("drop"), st.sampled_from([("system_matrices.npz", "Pc"), ("filter.npz", "phi_s"),
                                                ("system_matrices.npz", "meta_json")])),
    st.tuples(st.just("bytes"), st.sampled_from(["system_matrices.npz", "filter.npz", "calibration.json"]),
              st.sampled_from(["truncate", "random", "empty", "flip"]), st.integers(0, 10_000)),
    st.tuples(st.just("meta"), st.sampled_from(["tau", "exposure_us", "format", "profile", "profile_hash",
                                                "tau_t2s_closed_form", "metrics"]), JSON_VALUES),
    st.tuples(st.just("remove"), st.sampled_from(["system_matrices.npz", "filter.npz", "calibration.json"])),
)


def _mutate_bundle(cal: Path, ops: list[tuple[Any, ...]]) -> None:
    for op in ops:
        kind = op[0]
        if kind in ("member", "drop"):
            name, key = op[1]
            try:
                with np.load(cal / name, allow_pickle=False) as z:
                    arrays = {k: z[k] for k in z.files}
            except Exception:  # noqa: BLE001 - already damaged by an earlier op
                continue
            if kind == "drop":
                arrays.pop(key, None)
            else:
                base = arrays.get(key, np.ones((3, 4, 5)))
                shapes = [base.shape, base.shape[1:], (*base.shape, 1), base.shape[::-1], (0,), (1, 2, 3)]
                arrays[key] = _array(op[2], shapes[op[3]], op[4], base, op[5])
            np.savez(cal / name, **arrays)
        elif kind == "bytes":
            f = cal / op[1]
            if not f.is_file():
                continue
            data = bytearray(f.read_bytes())
            if op[2] == "truncate":
                data = data[: len(data) // 2]
            elif op[2] == "empty":
                data = bytearray()
            elif op[2] == "random":
                data = bytearray(np.random.default_rng(op[3]).bytes(max(len(data), 8)))
            elif data:
                data[op[3] % len(data)] ^= 0xFF
            f.write_bytes(bytes(data))
        elif kind == "meta":
            f = cal / "calibration.json"
            try:
                meta = json.loads(f.read_text())
            except (OSError, ValueError):
                continue
            if isinstance(meta, dict):
                meta[op[1]] = op[2]
                f.write_text(json.dumps(meta))
        else:
            (cal / op[1]).unlink(missing_ok=True)


@settings(FUZZ, max_examples=60 * SCALE)
@given(ops=st.lists(BUNDLE_OPS, min_size=1, max_size=3))
def test_fuzz_bundles_through_reconstruct(ops: list[tuple[Any, ...]], tiny: dict[str, Any], capfd: Any) -> None:
    with _workspace(tiny) as (inputs, work):
        _mutate_bundle(inputs / "cal", ops)
        before = snapshot(inputs)
        decoder = "flatcam" if len(ops) % 2 else "thintact-noniterative"
        argv = ["reconstruct", str(inputs / "rec"), "--calibration", str(inputs / "cal"), "--out", "out",
                "--decoder", decoder, "--no-progress"]
        rc, err = run_cli(argv, work, capfd)
        judge("bundle → reconstruct", [*argv, f"mutations={ops}"], rc, err,
              _check_reconstruction(work / "out", inputs / "rec"))
        assert_nothing_outside(work, inputs, before, "out")


# -- CLI arguments --------------------------------------------------------------------------
NUMBER_TOKENS = st.one_of(
    st.sampled_from(["0", "-1", "1", "2", "nan", "inf", "-inf", "1e309", "", " ", "abc", "0x10", "1e-300",
                     "3.5", "-0", "+2", "1_0", "--force", "-"]),
    st.integers(-3, 3).map(str), st.floats().map(repr),
    st.text(alphabet=st.characters(exclude_categories=("Nd", "Cs")), max_size=6),
)
PATH_TOKENS = st.sampled_from(["", " ", "out", "out/sub", "missing/../out", "/dev/null/x", "existing_file",
                               "existing_dir", "nonexistent"])


def _argv(base: dict[str, str], fixed: list[str], draws: dict[str, Any]) -> tuple[list[str], str | None]:
    """``fixed + [--opt value ...]`` with options replaced, dropped or added by ``draws``."""
    opts = dict(base)
    for opt, token in draws.get("replace", {}).items():
        opts[opt] = token
    for opt in draws.get("drop", []):
        opts.pop(opt, None)
    argv = list(fixed)
    for opt, value in opts.items():
        argv += [opt] if value is None else [opt, value]
    argv += draws.get("extra", [])
    return argv, opts.get("--out")


def _draws(options: list[str]) -> st.SearchStrategy[dict[str, Any]]:
    """One or two mutations of a valid command line: an option's value replaced by a token,
    ``--out`` replaced by a path token, an option dropped, or an argument added."""
    mutation = st.one_of(
        st.tuples(st.just("replace"), st.sampled_from(options), NUMBER_TOKENS),
        st.tuples(st.just("replace"), st.just("--out"), PATH_TOKENS),
        st.tuples(st.just("drop"), st.sampled_from([*options, "--out"]), st.none()),
        st.tuples(st.just("extra"), st.sampled_from(["--force", "--bogus", "extra-positional"]), st.none()),
    )

    def collect(muts: list[tuple[str, str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {"replace": {}, "drop": [], "extra": []}
        for kind, opt, token in muts:
            if kind == "replace":
                out["replace"][opt] = token
            elif kind == "drop":
                out["drop"].append(opt)
            else:
                out["extra"].append(opt)
        return out

    return st.lists(mutation, min_size=1, max_size=2).map(collect)


def _prepare_work(work: Path) -> None:
    (work / "existing_file").write_text("keep")
    (work / "existing_dir").mkdir()
    (work / "existing_dir" / "keep.txt").write_text("keep")


def _fuzz_cli(target: str, tiny: dict[str, Any], capfd: Any, fixed: list[str], base: dict[str, str],
              draws: dict[str, Any], check: Any, result_codes: tuple[int, ...] = (0,)) -> None:
    with _workspace(tiny) as (inputs, work):
        _prepare_work(work)
        pre_existing = snapshot(work)
        before = snapshot(inputs)
        base = {k: v if v is None else v.replace("{in}", str(inputs)) for k, v in base.items()}
        argv, out = _argv(base, [a.replace("{in}", str(inputs)) for a in fixed], draws)
        rc, err = run_cli(argv, work, capfd)
        judge(target, argv, rc, err, lambda: check(work / (out or "out"), inputs), result_codes)
        for name, stat in pre_existing.items():  # nothing existing overwritten without --force
            if "--force" not in argv:
                assert snapshot(work).get(name) == stat, f"{name} was overwritten without --force: {argv}"
        for keep in ("existing_file", "existing_dir/keep.txt"):
            (work / keep).unlink(missing_ok=True)
        assert_nothing_outside(work, inputs, before, out)


@settings(FUZZ, max_examples=35 * SCALE)
@given(draws=_draws(["--tau", "--dark", "--decoder"]))
def test_fuzz_reconstruct_arguments(draws: dict[str, Any], tiny: dict[str, Any], capfd: Any) -> None:
    _fuzz_cli("argv → reconstruct", tiny, capfd, ["reconstruct", "{in}/rec", "--no-progress"],
              {"--calibration": "{in}/cal", "--out": "out", "--decoder": "flatcam", "--tau": "100", "--dark": "auto"},
              draws,
              lambda out, inputs: _check_reconstruction(out, inputs / "rec")())


@settings(FUZZ, max_examples=35 * SCALE)
@given(draws=_draws(["--seed", "--gain", "--scenes", "--profile"]), noise=st.booleans())
def test_fuzz_simulate_arguments(draws: dict[str, Any], noise: bool, tiny: dict[str, Any], capfd: Any) -> None:
    def check(out: Path, inputs: Path) -> None:
        y = np.load(out)
        assert y.shape == (3, 24, 30, 3) and np.isfinite(y).all()
        assert (y >= 0).all() if noise else True

    base = {"--profile": str(tiny["profile_file"]), "--scenes": str(tiny["scenes_file"]), "--out": "y.npy",
            "--seed": "0"}
    if noise:
        base["--noise"] = None  # type: ignore[assignment]
    _fuzz_cli("argv → simulate", tiny, capfd, ["simulate"], base, draws, check)


@settings(FUZZ, max_examples=8 * SCALE)
@given(draws=_draws(["--time-budget", "--sys-frac", "--max-effects"]))
def test_fuzz_diagnose_arguments(draws: dict[str, Any], tiny: dict[str, Any], capfd: Any) -> None:
    def check(out: Path, inputs: Path) -> None:
        rep = json.loads((out / "report.json").read_text())
        for part in ("baseline", "final"):
            assert np.isfinite(rep[part]["rms_dn"]) and np.isfinite(rep[part]["chi2_per_dof"])
        assert (out / "fitted_profile.json").is_file()

    with mock.patch("thintact_sdk.diagnosis.imaging.outputs.write_html", _stub_html):
        _fuzz_cli("argv → diagnose", tiny, capfd, ["diagnose", "{in}/rec", "--quiet"],
                  {"--out": "out", "--time-budget": "3", "--sys-frac": "0.001", "--max-effects": "1"},
                  draws, check)


def _stub_html(_: Any, path: Path, *args: Any, **kwargs: Any) -> Path:
    path.write_text("<html>stub</html>\n")
    return path


@pytest.fixture(scope="module")
def slit_recording(tiny: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A complete slit scan of the tiny device (dark, 10 row and 12 column slits, white, one test)."""
    scenes = [np.zeros((10, 12, 3), np.float32)]
    for r in range(10):
        s = np.zeros((10, 12, 3), np.float32)
        s[r] = 1.0
        scenes.append(s)
    for c in range(12):
        s = np.zeros((10, 12, 3), np.float32)
        s[:, c] = 1.0
        scenes.append(s)
    scenes.append(np.ones((10, 12, 3), np.float32))
    v = np.zeros((10, 12, 3), np.float32)
    v[3:6, 4:8] = 1.0
    scenes.append(v)
    stack = np.stack(scenes)
    meas = rob_kit.measurements(tiny["profile"], stack)
    return rob_kit.write_recording(tmp_path_factory.mktemp("slits") / "rec", tiny["profile"], stack, meas)


@settings(FUZZ, max_examples=5 * SCALE)
@given(draws=_draws(["--filter-steps", "--max-iter", "--tau", "--frame-gains", "--method"]))
def test_fuzz_calibrate_from_recording_arguments(draws: dict[str, Any], tiny: dict[str, Any],
                                                 slit_recording: Path, capfd: Any) -> None:
    def check(out: Path, inputs: Path) -> None:
        b = CalibrationBundle.load(out)
        assert np.isfinite(b.system_matrices.Pc).all() and b.tau > 0

    def stub_report(outcome: Any, profile: Any, path: Path) -> Path:
        return _stub_html(None, path)

    with mock.patch("thintact_sdk.calibration.unit_report.write_report", stub_report):
        # exit 1 is the documented validation FAIL verdict, with a complete bundle
        _fuzz_cli("argv → calibrate --from-recording", tiny, capfd,
                  ["calibrate", "--from-recording", str(slit_recording), "--no-progress"],
                  {"--out": "out", "--filter-steps": "0", "--max-iter": "2"}, draws, check,
                  result_codes=(0, 1))


@settings(FUZZ, max_examples=8 * SCALE)
@given(draws=_draws(["--frames", "--timeout", "--buffer-mb", "--set"]))
def test_fuzz_record_arguments(draws: dict[str, Any], tiny: dict[str, Any], capfd: Any) -> None:
    if "virtual" not in get_registry().components("camera"):
        pytest.skip("virtual camera plugin not installed")

    def check(out: Path, inputs: Path) -> None:
        rec = Recording(out)
        rec.check_frames()
        assert len(rec) >= 1

    _fuzz_cli("argv → record", tiny, capfd, ["record", "--profile", "virtual-mini", "--quiet"],
              {"--out": "out", "--frames": "2", "--set": "fps=0"}, draws, check)


NO_MUTATION: dict[str, Any] = {"replace": {}, "drop": [], "extra": []}


def test_the_unmutated_inputs_give_correct_results(tiny: dict[str, Any], capfd: Any) -> None:
    """The fuzz bases are valid: without mutations each target gives a correct result (so a
    harness that only ever produced clean errors would be noticed)."""
    runs = [
        ("recording → reconstruct", lambda: test_fuzz_recordings_through_reconstruct.hypothesis.inner_test(
            ops=[("drop_frames", 0)], tiny=tiny, capfd=capfd)),
        ("argv → reconstruct", lambda: test_fuzz_reconstruct_arguments.hypothesis.inner_test(
            draws=NO_MUTATION, tiny=tiny, capfd=capfd)),
        ("argv → simulate", lambda: test_fuzz_simulate_arguments.hypothesis.inner_test(
            draws=NO_MUTATION, noise=True, tiny=tiny, capfd=capfd)),
    ]
    for target, run in runs:
        before = rob_kit.FUZZ_OUTCOMES.get(target, {}).get("correct result", 0)
        run()
        assert rob_kit.FUZZ_OUTCOMES[target]["correct result"] == before + 1, target
