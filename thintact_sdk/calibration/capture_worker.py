"""Calibration work done while the wizard is still capturing (pipelined calibration).

A production line spends most of a unit's time capturing (the paper's 923 patterns, 100
frames each at 30 fps: about 51 minutes) while the computer waits. :class:`CaptureWorker`
takes that time: as each pattern is written it compresses the slit frames
(:class:`~thintact_sdk.calibration.collect.SlitCompressor`), solves the system matrices as
soon as the last slit is in (Algorithms 2-3, while the validation scenes are captured), and
simulates the design's own calibration for the prediction from the white frame's signal
level (:func:`~thintact_sdk.calibration.prediction.design_for_prediction`). What is left
after the last pattern is the joint filter, the health check, the decoder and τ choice and the
end of the prediction (:func:`~thintact_sdk.calibration.pipeline.calibrate_recording` with the
worker's :class:`Prepared`).

Two threads: one follows the recording (compression, then the solve), one the prediction's
design and then the decoders' backend measurement on the design's matrices
(:func:`warm_backends`). numpy releases the interpreter lock in its kernels, so on two cores
they run beside the capture. A failure in either is kept and the pipeline computes that part itself after
the capture (nothing is lost, only the head start).
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.calibration.collect import SlitCollection, SlitCompressor, white_frame_signal
from thintact_sdk.calibration.prediction import (
    PredictionDesign,
    design_for_prediction,
    design_signals,
)
from thintact_sdk.calibration.solver import SolveReport, solve_collection
from thintact_sdk.calibration.validation import (
    calibration_decoders,
    make_decoder,
    needs_joint_filter,
    takes_scene_prior,
)
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording
from thintact_sdk.host.blas import blas_threads
from thintact_sdk.host.memory import return_free_heap
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices


@dataclass
class Prepared:
    """What the capture worker finished before the capture ended (each part None when it
    did not: the pipeline then computes it).

    Attributes
    ----------
    solved
        ``(collection, matrices, reports)`` of the slit scan, as the pipeline's first stage.
    design
        The prediction's simulated design (white-frame signal level).
    priors
        Per calibration decoder that takes a scene prior, the prior (``None``: plain Tikhonov)
        :func:`design_priors` chose on the design's own validation frames; the unit then
        cross-validates only plain Tikhonov and that prior. ``None`` when not searched.
    seconds
        Wall time of each part, measured in the worker (``compress``, ``solve``, ``design``,
        ``backends``: :func:`warm_backends`, ``priors``).
    errors
        What went wrong in a part that was then left to the pipeline.
    """

    solved: tuple[SlitCollection, SystemMatrices, list[SolveReport]] | None = None
    design: PredictionDesign | None = None
    priors: dict[str, ScenePrior | None] | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    errors: dict[str, str] = field(default_factory=dict)


class CaptureWorker:
    """Follows a capture directory as the wizard writes it (module docstring).

    Parameters
    ----------
    profile
        The device profile (the capture's).
    capture_dir
        The recording the wizard writes.
    options
        The calibration's :class:`~thintact_sdk.calibration.pipeline.CalibrationOptions`.
    frames_averaged
        Frames averaged per pattern (the noise of the prediction).
    slits
        Slit frames the plan holds (the solve starts when that many are in).
    validation
        The plan's validation scenes, ``(label, N × M × C scene)``: with them the scene priors
        are chosen on the design during the capture (:func:`design_priors`).
    """

    def __init__(self, profile: Profile, capture_dir: Path, options: Any, frames_averaged: int,
                 slits: int, validation: list[tuple[str, np.ndarray]] | None = None) -> None:
        self.profile, self.capture_dir, self.options = profile, Path(capture_dir), options
        self.validation = list(validation or [])
        self.frames_averaged, self.slits = max(1, int(frames_averaged)), int(slits)
        self.compressor = SlitCompressor(profile, options.rank)
        self.prepared = Prepared()
        self._pings: queue.Queue[bool] = queue.Queue()
        self._done = 0
        self._design_thread: threading.Thread | None = None
        self._thread = threading.Thread(target=self._follow, name="calibrate-capture", daemon=True)
        self._thread.start()

    def frame_written(self) -> None:
        """The wizard wrote (or found, resuming) another pattern."""
        self._pings.put(True)

    def finish(self, timeout_s: float | None = None) -> Prepared:
        """Wait for the worker (the capture is complete) and return what it prepared."""
        self._pings.put(False)
        self._thread.join(timeout_s)
        if self._design_thread is not None:
            self._design_thread.join(timeout_s)
        prep, comp = self.prepared, self.compressor
        if prep.solved is not None:
            if comp.broken is not None or sorted(comp.slits) != comp.slits:
                prep.errors["slits"] = f"collected again after the capture: {comp.broken or 'slit order'}"
                prep.solved = None
            else:  # the frames after the last slit (the validation scenes) are in now
                prep.solved[0].validation = sorted(comp.validation)
        # the compressed images are in the collection's stacks (or collected again from the
        # recording): not held beside them while the calibration runs (0.4 GB at paper size)
        comp.release()
        return prep

    def _follow(self) -> None:
        prep, comp = self.prepared, self.compressor
        t_compress = 0.0
        final = False
        try:
            while not final:
                final = not self._pings.get()
                while not self._pings.empty():  # take every ping that came meanwhile at once
                    final = (not self._pings.get()) or final
                t0 = time.monotonic()
                view = Recording(self.capture_dir, profile=self.profile)
                for i in range(self._done, len(view)):
                    comp.add(view, i)
                    if self._design_thread is None and self.options.predict:
                        self._maybe_start_design(view, i)
                self._done = len(view)
                return_free_heap()  # what this pass, the solve and the design thread freed meanwhile
                t_compress += time.monotonic() - t0
                if len(comp.slits) >= self.slits and prep.solved is None and comp.broken is None:
                    prep.seconds["compress"] = round(t_compress, 3)
                    self._solve()
        except (ThinTactError, OSError, ValueError) as err:
            prep.errors["slits"] = str(err)

    def _solve(self) -> None:
        t0 = time.monotonic()
        collection = self.compressor.slit_collection()
        o = self.options
        sm, reports = solve_collection(collection, self.profile, o.method, o.max_iter, o.tol)
        self.prepared.solved = (collection, sm, reports)
        self.prepared.seconds["solve"] = round(time.monotonic() - t0, 3)

    def _maybe_start_design(self, view: Recording, i: int) -> None:
        """Start the prediction's design when frame ``i`` is the white frame (after a dark
        frame): each new frame is looked at once, the whole view only then."""
        scene = view.scene(i)
        if not self.compressor.dark_frames or scene is None or not scene.size or float(scene.min()) < 0.999:
            return
        white = white_frame_signal(view)
        if white is None:
            return
        signal = white[0]

        def run() -> None:
            t0 = time.monotonic()
            try:
                self.prepared.design = design_for_prediction(
                    self.profile, None, self.frames_averaged, white_signal_dn=signal,
                    method=self.options.method, max_iter=self.options.max_iter,
                    tol=self.options.tol, rank=self.options.rank)
            except (ThinTactError, ValueError, np.linalg.LinAlgError) as err:
                self.prepared.errors["design"] = str(err)
            self.prepared.seconds["design"] = round(time.monotonic() - t0, 3)
            if self.prepared.design is not None:
                t0 = time.monotonic()
                try:
                    warm_backends(self.profile, self.prepared.design.design)
                except (ThinTactError, ValueError, np.linalg.LinAlgError) as err:
                    self.prepared.errors["backends"] = str(err)
                self.prepared.seconds["backends"] = round(time.monotonic() - t0, 3)
                if self.validation and self.options.tau is None:
                    t0 = time.monotonic()
                    try:
                        self.prepared.priors = design_priors(self.profile, self.prepared.design, self.validation)
                    except (ThinTactError, ValueError, np.linalg.LinAlgError) as err:
                        self.prepared.errors["priors"] = str(err)
                    self.prepared.seconds["priors"] = round(time.monotonic() - t0, 3)

        self._design_thread = threading.Thread(target=run, name="calibrate-design", daemon=True)
        self._design_thread.start()


WARM_FILTER_SCENES = 8
"""Training scenes of the joint filter :func:`warm_backends` trains on the design's matrices for
a decoder that needs one: the backend measurement needs a filter of the unit's shape, and its
accuracy check (each backend against float64 on probe scenes) does not depend on how well the
filter was trained."""


def warm_backends(profile: Profile, design: SystemMatrices) -> None:
    """Have the array backend of every calibration decoder measured on the design's simulated
    matrices (the unit's shapes), under the thread setting the calibration decodes with after
    the capture (one BLAS thread: the τ selection and the prediction run on its lanes); a
    decoder that needs a joint filter gets one trained on those matrices
    (:data:`WARM_FILTER_SCENES` scenes, the profile's noise). The measurements are cached per
    host and shape (:mod:`~thintact_sdk.reconstruction.decoders.backend_selection`), so the
    decoders built after the last pattern are built directly; the first unit of a shape on a
    station no longer measures them then. What is measured is speed and accuracy on probe
    scenes, both set by the shapes and the design, not by this unit's defects."""
    from thintact_sdk.reconstruction.filter_training import train_joint_filter, training_scenes

    plain = CalibrationBundle.create(profile, design, None, tau=1.0, source="simulator")
    with blas_threads(1):
        for name in calibration_decoders():
            bundle = plain
            if needs_joint_filter(name):
                n, m = design.scene_shape
                jf = train_joint_filter(design, training_scenes(n, m, count=WARM_FILTER_SCENES, seed=0),
                                        noise=profile.noise, steps=0, seed=0)
                bundle = CalibrationBundle.create(profile, design, jf, tau=1.0, source="simulator")
            kwargs: dict[str, Any] = {"prior": None} if takes_scene_prior(name) else {}
            make_decoder(profile, bundle, name, **kwargs)


DESIGN_PRIOR_SEED = 1
"""Seed of the sensor noise of the design's validation frames in :func:`design_priors` (a
stream of its own: the prediction's frames, drawn from the design's, are not changed)."""


def design_priors(profile: Profile, design: PredictionDesign,
                  validation: list[tuple[str, np.ndarray]]) -> dict[str, ScenePrior | None] | None:
    """The scene prior each calibration decoder that takes one would deploy on a unit built
    exactly to the design, chosen as the unit's own choice is
    (:func:`~thintact_sdk.calibration.tau.cross_validate_prior`: plain Tikhonov and every
    candidate, τ cross-validated, the median scene must gain) on the design's simulated
    frames of the plan's validation scenes; ``None`` where the scenes do not make two folds.

    A scene prior describes the scenes (their DCT power), which the design's frames show as
    the unit's do, at the unit's signal level and the profile's noise. The capture worker
    runs this while the wizard captures, so after the last pattern the unit cross-validates
    plain Tikhonov and this prior alone instead of every candidate (at the paper's size the
    nine candidates cost about 150 CPU-seconds), and deploys the prior only where it also wins
    on the unit's own frames."""
    from thintact_sdk.calibration.tau import cross_validate_prior, enough_folds, tau_grid

    labels = [label for label, _ in validation]
    scenes = [np.asarray(x, np.float32) for _, x in validation]
    if not enough_folds(scenes):
        return None
    signals = design_signals(design, scenes, np.random.default_rng(DESIGN_PRIOR_SEED))
    bundle = CalibrationBundle.create(profile, design.design, None, tau=1.0, source="simulator")
    grid = tau_grid(design.design)
    out: dict[str, ScenePrior | None] = {}
    with blas_threads(1):
        for name in calibration_decoders():
            if not takes_scene_prior(name) or needs_joint_filter(name):
                continue
            cv = cross_validate_prior(lambda prior, n=name: make_decoder(profile, bundle, n, prior=prior),  # type: ignore[misc]
                                      name, signals, scenes, labels, grid, workers=1)
            out[name] = None if cv is None else cv.prior
    return out
