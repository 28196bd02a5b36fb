"""The stages of a calibration after the capture: timed, measured, announced and checkpointed.

:class:`StageLog` wraps each stage of :func:`~thintact_sdk.calibration.pipeline.calibrate_recording`
(slit frames and solve, joint filter, health, decoder and τ, prediction, bundle): it announces
``[k/N] stage`` through the status callback with the time spent so far and the time the
remaining stages are estimated to take (each stage's share of the work, :data:`STAGE_WEIGHTS`,
scaled by the time the finished stages took), and records each stage's wall time (s) and the
process's peak resident memory (MiB) at its end (``calibration.json`` → ``metrics.stages`` and
the report).

Checkpoints (``<bundle>/stages/``, removed once the bundle is written): the slit collection
and the solved matrices (``solve.npz`` + ``solve.json``), the joint filter (``filter.npz``),
the health report (``health.json`` + ``health.npz``), the decoder and τ selection
(``selection.json`` + ``selection.npz``), its reported GCV and discrepancy curves
(``noise_criteria.json``), the prediction's simulated design (``design.npz`` + ``design.json``)
and the prediction (``prediction.json``). Each carries a fingerprint of the recording's manifest,
the profile and the options that shape it; a killed run restarted on the same recording
(wizard resume, or ``--from-recording`` with the same ``--out`` and ``--force``) loads them
instead of recomputing, and a checkpoint whose fingerprint differs is ignored. Files are written
atomically (temporary name, then rename) and read without pickles.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
import math
import os
import resource
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.calibration.collect import SlitCollection
from thintact_sdk.calibration.prediction import PredictionDesign
from thintact_sdk.calibration.slits import ChannelSlits, SlitStack
from thintact_sdk.calibration.solver import SolveReport
from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import NoiseSpec, Profile
from thintact_sdk.formats.safe_arrays import read_npz
from thintact_sdk.formats.safe_json import loads as safe_loads
from thintact_sdk.host.memory import return_free_heap
from thintact_sdk.reconstruction.joint_filter import JointFilter
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.simulation.simulator import Simulator

STAGE_DIR = "stages"
CHECKPOINT_FORMAT = "thintact-calibration-stage/1"

STAGE_WEIGHTS: dict[str, float] = {
    "slit frames and solve": 0.5,
    "health": 0.8,
    "joint filter": 0.1,
    "decoder and tau": 1.0,
    "noise criteria": 0.15,
    "prediction design": 0.8,
    "prediction": 0.2,
    "bundle and report": 0.05,
}
"""Relative work of each stage, for the estimate of what is left: the shares of the stages'
wall time in ``tools/bench_calibration_paper.py``'s paper-size run (docs/calibration.md,
section "Paper-size calibration time"), rounded; the shares move with the sensor and scene
size, and health with the prediction's design run beside the filter and τ selection, so the
estimate is a guide, refined as each stage finishes."""


CHECKPOINT_CLASSES: frozenset[str] = frozenset({
    "thintact_sdk.calibration.health:HealthReport",
    "thintact_sdk.calibration.health:NoiseEstimate",
    "thintact_sdk.calibration.health:Defect",
    "thintact_sdk.calibration.ghost:GhostScan",
    "thintact_sdk.calibration.selection:TauSelection",
    "thintact_sdk.calibration.tau:TauCurve",
    "thintact_sdk.calibration.tau:CrossValidation",
    "thintact_sdk.calibration.validation:ValidationResult",
    "thintact_sdk.reconstruction.scene_prior:ScenePrior",
})
"""The dataclasses a checkpoint may hold (:func:`encode_object`); a file naming any other
class is refused, so a checkpoint never makes the reader import or build anything else."""


def encode_object(obj: Any, arrays: dict[str, np.ndarray]) -> Any:
    """``obj`` (a tree of the :data:`CHECKPOINT_CLASSES` dataclasses, lists, tuples, dicts with
    any hashable keys, numpy arrays and scalars) as JSON-able data; arrays go into ``arrays``
    (for an npz) under the names the data refers to. Non-finite floats are tagged (JSON has
    none). Inverse: :func:`decode_object`."""
    if obj is None or isinstance(obj, bool | str):
        return obj
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        v = float(obj)
        return v if math.isfinite(v) else {"float": repr(v)}
    if isinstance(obj, np.ndarray):
        key = f"a{len(arrays)}"
        arrays[key] = obj
        return {"array": key}
    if isinstance(obj, list):
        return [encode_object(v, arrays) for v in obj]
    if isinstance(obj, tuple):
        return {"tuple": [encode_object(v, arrays) for v in obj]}
    if isinstance(obj, dict):
        return {"dict": [[encode_object(k, arrays), encode_object(v, arrays)] for k, v in obj.items()]}
    name = f"{type(obj).__module__}:{type(obj).__qualname__}"
    if dataclasses.is_dataclass(obj) and name in CHECKPOINT_CLASSES:
        return {"class": name, "fields": {f.name: encode_object(getattr(obj, f.name), arrays)
                                          for f in dataclasses.fields(obj)}}
    raise CalibrationError(f"cannot checkpoint a {name} (not one of the checkpoint classes)")


def decode_object(data: Any, arrays: dict[str, np.ndarray]) -> Any:
    """The object :func:`encode_object` encoded (``arrays``: the npz's arrays).

    Raises
    ------
    CalibrationError
        A class outside :data:`CHECKPOINT_CLASSES`, an unknown tag or a missing array.
    """
    if data is None or isinstance(data, bool | int | float | str):
        return data
    if isinstance(data, list):
        return [decode_object(v, arrays) for v in data]
    if not isinstance(data, dict) or len(data) not in (1, 2):
        raise CalibrationError(f"checkpoint: unexpected value {str(data)[:80]}")
    if "float" in data:
        return float(str(data["float"]))
    if "array" in data:
        if str(data["array"]) not in arrays:
            raise CalibrationError(f"checkpoint: array {data['array']} missing")
        return arrays[str(data["array"])]
    if "tuple" in data:
        return tuple(decode_object(v, arrays) for v in data["tuple"])
    if "dict" in data:
        return {decode_object(k, arrays): decode_object(v, arrays) for k, v in data["dict"]}
    name = str(data.get("class"))
    if name not in CHECKPOINT_CLASSES:
        raise CalibrationError(f"checkpoint: class {name} refused (not one of the checkpoint classes)")
    module, _, qualname = name.partition(":")
    cls = getattr(importlib.import_module(module), qualname)
    values = {k: decode_object(v, arrays) for k, v in dict(data["fields"]).items()}
    init = {f.name for f in dataclasses.fields(cls) if f.init}
    obj = cls(**{k: v for k, v in values.items() if k in init})
    for k, v in values.items():
        if k not in init:
            object.__setattr__(obj, k, v)
    return obj


def peak_rss_mib() -> float:
    """This process's peak resident memory so far (MiB)."""
    kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return float(kib) / (1024.0 * 1024.0) if sys.platform == "darwin" else float(kib) / 1024.0


@dataclass
class StageLog:
    """Wall time and peak memory of each stage, announced through ``status``."""

    stages: list[str]
    status: Callable[[str], None] | None = None
    done: list[dict[str, Any]] = field(default_factory=list)
    start: float = field(default_factory=time.monotonic)

    def estimate_left_s(self, next_index: int) -> float | None:
        """Seconds the stages from ``next_index`` on should take, from the finished ones'
        time per unit of :data:`STAGE_WEIGHTS` (None before any stage finished)."""
        timed = [d for d in self.done if not d.get("resumed")]
        w_done = sum(STAGE_WEIGHTS.get(d["stage"], 1.0) for d in timed)
        if not timed or w_done <= 0:
            return None
        rate = sum(d["seconds"] for d in timed) / w_done
        return rate * sum(STAGE_WEIGHTS.get(s, 1.0) for s in self.stages[next_index:])

    @contextmanager
    def stage(self, name: str, detail: str = "") -> Iterator[dict[str, Any]]:
        """Time the ``with`` block as stage ``name``; the yielded dict may get ``resumed``."""
        k = self.stages.index(name) if name in self.stages else len(self.done)
        if self.status is not None:
            so_far = time.monotonic() - self.start
            left = self.estimate_left_s(k)
            est = "" if left is None else f", about {left:.0f} s left"
            self.status(f"[{k + 1}/{len(self.stages)}] {detail or name} ({so_far:.0f} s so far{est})")
        t0 = time.monotonic()
        entry: dict[str, Any] = {"stage": name, "start_s": round(t0 - self.start, 3)}
        yield entry
        # what the stage freed goes back to the system before the next stage allocates
        # (host.memory: glibc otherwise keeps freed frames in its heaps)
        return_free_heap()
        entry["seconds"] = round(time.monotonic() - t0, 3)
        entry["peak_rss_mib"] = round(peak_rss_mib(), 1)
        self.done.append(entry)

    def to_json(self) -> list[dict[str, Any]]:
        return [dict(d) for d in self.done]


def fingerprint(recording_root: Path, profile_hash: str, options: dict[str, Any]) -> str:
    """sha256 of the recording's manifest, the profile hash and ``options`` (JSON)."""
    h = hashlib.sha256()
    manifest = recording_root / "manifest.json"
    h.update(manifest.read_bytes() if manifest.is_file() else str(recording_root).encode())
    h.update(profile_hash.encode())
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    return h.hexdigest()


def _atomic_write(path: Path, write: Callable[[Any], None], mode: str = "wb") -> None:
    tmp = path.with_name(path.name + ".partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, mode) as f:
            write(f)
        os.replace(tmp, path)
    except OSError as err:
        raise CalibrationError(f"cannot write the calibration checkpoint {path}: {err}") from None


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = safe_loads(path.read_text(encoding="utf-8"), f"{path}:")
    except Exception:  # noqa: BLE001 - an unreadable checkpoint is recomputed, never trusted
        return None
    return data if isinstance(data, dict) else None


@dataclass
class Checkpoints:
    """The stage checkpoints of one bundle directory (see the module docstring)."""

    directory: Path
    key: str

    def _valid(self, name: str) -> dict[str, Any] | None:
        meta = _read_json(self.directory / f"{name}.json")
        if meta is None or meta.get("format") != CHECKPOINT_FORMAT or meta.get("fingerprint") != self.key:
            return None
        return meta

    def _meta(self, name: str, body: dict[str, Any]) -> None:
        text = json.dumps({"format": CHECKPOINT_FORMAT, "fingerprint": self.key, **body},
                          default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)) + "\n"
        _atomic_write(self.directory / f"{name}.json", lambda f: f.write(text), "w")

    # -- slit collection and solve ---------------------------------------------------------
    def save_solve(self, collection: SlitCollection, sm: SystemMatrices, reports: list[SolveReport]) -> None:
        """``solve.npz`` (every array of the collection and matrices) + ``solve.json``."""
        arrays: dict[str, np.ndarray] = {"dark_dn": collection.dark_dn, "Po": sm.Po, "Qo": sm.Qo,
                                         "Pc": sm.Pc, "Qc": sm.Qc}
        for c, ch in enumerate(collection.channels):
            for o, st in (("h", ch.horizontal), ("v", ch.vertical)):
                for a in ("index", "profile", "left", "right", "energy"):
                    arrays[f"c{c}{o}_{a}"] = getattr(st, a)
        _atomic_write(self.directory / "solve.npz", lambda f: np.savez(f, **arrays))  # type: ignore[arg-type]
        self._meta("solve", {
            "channels": [{"n_rows": ch.n_rows, "n_cols": ch.n_cols, "meta": ch.meta} for ch in collection.channels],
            "dark_source": collection.dark_source, "exposure_us": collection.exposure_us,
            "validation": collection.validation,
            "saturated": {str(k): v for k, v in collection.saturated.items()},
            "frame_scale": {str(k): v for k, v in collection.frame_scale.items()},
            "slit_frames": collection.slit_frames, "frame_gains": collection.frame_gains,
            "sm_meta": sm.meta,
            "reports": [{"iterations": r.iterations, "converged": r.converged,
                         "residual_history": r.residual_history, "change_history": r.change_history}
                        for r in reports],
        })

    def load_solve(self) -> tuple[SlitCollection, SystemMatrices, list[SolveReport]] | None:
        """The checkpointed collection, matrices and solve reports, or None."""
        meta = self._valid("solve")
        if meta is None:
            return None
        try:
            a = read_npz(self.directory / "solve.npz", what="calibration checkpoint")
            channels = []
            for c, info in enumerate(meta["channels"]):
                stacks = [SlitStack(*(a[f"c{c}{o}_{k}"] for k in ("index", "profile", "left", "right", "energy")))
                          for o in ("h", "v")]
                channels.append(ChannelSlits(stacks[0], stacks[1], int(info["n_rows"]), int(info["n_cols"]),
                                             meta=dict(info["meta"])))
            collection = SlitCollection(
                channels, a["dark_dn"], str(meta["dark_source"]), meta["exposure_us"],
                [int(i) for i in meta["validation"]],
                {int(k): float(v) for k, v in meta["saturated"].items()},
                {int(k): float(v) for k, v in meta["frame_scale"].items()},
                int(meta["slit_frames"]), dict(meta["frame_gains"]),
            )
            sm = SystemMatrices(a["Po"], a["Qo"], a["Pc"], a["Qc"], dict(meta["sm_meta"]))
            reports = [SolveReport(int(r["iterations"]), bool(r["converged"]), list(r["residual_history"]),
                                   list(r["change_history"])) for r in meta["reports"]]
        except Exception:  # noqa: BLE001 - a damaged checkpoint is recomputed
            return None
        return collection, sm, reports

    # -- joint filter ----------------------------------------------------------------------
    def save_filter(self, jf: JointFilter | None, tau_table: dict[str, float], tau: float) -> None:
        if jf is not None:
            _atomic_write(self.directory / "filter.npz",
                          lambda f: np.savez(f, phi_f=jf.phi_f, phi_s=jf.phi_s))
        self._meta("filter", {"has_filter": jf is not None, "meta": None if jf is None else jf.meta,
                              "tau_table": tau_table, "tau": tau})

    def load_filter(self) -> tuple[JointFilter | None, dict[str, float], float] | None:
        meta = self._valid("filter")
        if meta is None:
            return None
        try:
            jf = None
            if meta["has_filter"]:
                a = read_npz(self.directory / "filter.npz", what="calibration checkpoint")
                jf = JointFilter(a["phi_f"], a["phi_s"], dict(meta["meta"]))
            return jf, {str(k): float(v) for k, v in meta["tau_table"].items()}, float(meta["tau"])
        except Exception:  # noqa: BLE001 - a damaged checkpoint is recomputed
            return None

    # -- health, decoder and τ -------------------------------------------------------------
    def save_object(self, name: str, obj: Any) -> None:
        """``<name>.npz`` (its arrays) + ``<name>.json`` (the rest, :func:`encode_object`)."""
        arrays: dict[str, np.ndarray] = {}
        body = encode_object(obj, arrays)
        _atomic_write(self.directory / f"{name}.npz", lambda f: np.savez(f, **arrays))  # type: ignore[arg-type]
        self._meta(name, {"object": body})

    def load_object(self, name: str) -> Any | None:
        """The object :meth:`save_object` stored as ``name``, or None (absent, of another
        recording or options, or damaged: then the stage is recomputed)."""
        meta = self._valid(name)
        if meta is None or "object" not in meta:
            return None
        try:
            a = read_npz(self.directory / f"{name}.npz", what="calibration checkpoint")
            return decode_object(meta["object"], dict(a))
        except Exception:  # noqa: BLE001 - a damaged checkpoint is recomputed
            return None

    # -- prediction ------------------------------------------------------------------------
    def save_design(self, design: PredictionDesign) -> None:
        """``design.npz`` (the simulated matrices, the gains, the simulated dark capture) +
        ``design.json`` (seed, averaged noise and the generator's state after the design, so
        the prediction's validation frames draw what they would have drawn)."""
        sm = design.design
        arrays = {"Po": sm.Po, "Qo": sm.Qo, "Pc": sm.Pc, "Qc": sm.Qc, "gains": np.asarray(design.gains),
                  "dark_dn": design.dark_dn}
        _atomic_write(self.directory / "design.npz", lambda f: np.savez(f, **arrays))  # type: ignore[arg-type]
        state = design.rng.bit_generator.state
        self._meta("design", {"seed": design.seed, "noise": design.noise.model_dump(), "sm_meta": sm.meta,
                              "bit_generator": str(state["bit_generator"]),
                              "state": {k: str(v) for k, v in state["state"].items()},
                              "has_uint32": int(state["has_uint32"]), "uinteger": str(state["uinteger"])})

    def load_design(self, profile: Profile) -> PredictionDesign | None:
        """The design :meth:`save_design` stored for ``profile``, or None."""
        meta = self._valid("design")
        if meta is None:
            return None
        try:
            a = read_npz(self.directory / "design.npz", what="calibration checkpoint")
            if meta["bit_generator"] != "PCG64":
                return None
            rng = np.random.Generator(np.random.PCG64())
            rng.bit_generator.state = {
                "bit_generator": "PCG64", "state": {k: int(v) for k, v in meta["state"].items()},
                "has_uint32": int(meta["has_uint32"]), "uinteger": int(meta["uinteger"])}
            sm = SystemMatrices(a["Po"], a["Qo"], a["Pc"], a["Qc"], dict(meta["sm_meta"]))
            return PredictionDesign(Simulator(profile), a["gains"], NoiseSpec.model_validate(meta["noise"]),
                                    a["dark_dn"], sm, rng, int(meta["seed"]))
        except Exception:  # noqa: BLE001 - a damaged checkpoint is recomputed
            return None

    def save_json(self, name: str, body: dict[str, Any]) -> None:
        self._meta(name, {"body": body})

    def load_json(self, name: str) -> dict[str, Any] | None:
        meta = self._valid(name)
        body = None if meta is None else meta.get("body")
        return body if isinstance(body, dict) else None

    def remove(self) -> None:
        """Delete the checkpoints (the bundle is written)."""
        shutil.rmtree(self.directory, ignore_errors=True)
