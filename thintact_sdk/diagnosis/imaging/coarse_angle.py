"""A large device's mask angle, fitted on coarser blocks of its sensor.

The paper's device (1024×1280 sensor → 400×512 scene) is diagnosed on its sensor binned
8×8 (:mod:`~thintact_sdk.diagnosis.imaging.binning`). There a rotated mask's kernel is too costly to
screen (:func:`~thintact_sdk.diagnosis.imaging.binning.screening_limits` holds the angle at 0): its
displacement families sum to 1.6 GiB at 0.35°, a build takes over a minute, and every step of a fit
rebuilds it. The work of a rotated build grows with the sensor's pixels and about as the
square of the angle (:func:`~thintact_sdk.simulation.simulator.rotated_build_bytes`).

Binning is exact for the imaging kernel: the block mean of a rotated device is the same
rotated device with the block's pitch. So the angle is fitted on blocks coarse enough for
its builds to be cheap (32×32 on the paper's device, a fifth of the 8×8 build's bytes), with every
effect the binned selection accepted held at its values and the gains solved. It is a
one-parameter search: χ² at two small probe angles (cheap builds) and at the start give a
parabola, whose vertex is evaluated next; then successive parabolas through the three best
angles, until the step is under :data:`ANGLE_TOL_DEG`. The angle is accepted by the
selection's own rule there (Δχ² above ``ln n + margin`` for its one parameter, a change of
the prediction above the amplitude floor); the diagnosis then evaluates it on its own binned
data for the report (:func:`~thintact_sdk.diagnosis.imaging.engine.diagnose`).

The other effects are not refitted with the angle: a rotation about the axis displaces the
pattern oppositely on either side of it, which a shift, a scale (geometry) or a blur does
not, so their fits barely absorb it (the paper-size cases of ``tools/diagnose_paper_size.py``
measure what is left).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.imaging.binning import bin_data, binned_profile, binned_variance_fn
from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES
from thintact_sdk.diagnosis.imaging.deadline import Deadline
from thintact_sdk.diagnosis.imaging.forward_model import (
    DiagnosisModel,
    Evaluation,
    SimulateFn,
    Values,
    default_simulate,
)
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile

EFFECT = "mask_misalignment"
"""The effect whose angle this stage fits (its fit vector's first parameter)."""

COARSE_FAMILY_BYTES = 0.5 * 1024**3
"""Largest rotated build (its displacement families summed over its sensor windows, at
:data:`PROBE_ANGLE_DEG`) the coarse blocks may need: 0.31 GiB on the paper's device
binned 32×32; 0.68 GiB binned 16×16 (their build times: docs/benchmarks.md, history)."""

PROBE_ANGLE_DEG = 0.35
"""The angle at which the coarse block size is chosen (a typical assembly error)."""

MIN_COARSE_SIDE = 8
"""The coarse sensor keeps at least this many pixels on its shorter side."""

SCORE_STEP_DEG = 0.05
"""The two probe angles around the start: cheap builds that give the first parabola."""

ANGLE_TOL_DEG = 0.002
"""The search stops when its next angle is this close to one already evaluated."""

MAX_ANGLE_DEG = 1.5
"""The search stays within ± this (the build's work grows as the angle squared)."""

MAX_EVALUATIONS = 8
"""Angles evaluated at most (the start and the probes included)."""

COARSE_BUDGET_S = 240.0
"""Default wall-clock budget of the stage (s)."""

FINE_WINDOWS = 6
"""Sensor windows on which an angle's change is measured at full resolution
(:func:`window_amplitude`), spread over the device's window plan."""

FINE_FRAMES = 4
"""Frames those windows are evaluated on."""


@dataclass
class CoarseAngleInput:
    """What :func:`~thintact_sdk.diagnosis.imaging.engine.diagnose` needs to fit a held angle on coarser blocks.

    Attributes
    ----------
    data
        The unbinned recording.
    bin_factor
        The block side ``b`` of the diagnosis's binned copy; the coarse side is a multiple.
    simulate
        The simulator function (``None``: the model's default).
    budget_s
        Wall-clock budget of the stage.
    family_limit
        :data:`COARSE_FAMILY_BYTES`.
    """

    data: DiagnosisData
    bin_factor: int
    simulate: SimulateFn | None = None
    budget_s: float = COARSE_BUDGET_S
    family_limit: float = COARSE_FAMILY_BYTES


@dataclass(frozen=True)
class AngleTrial:
    """One evaluated angle: χ² on the coarse blocks (fit weights) and the evaluation's seconds."""

    angle_deg: float
    chi2: float
    seconds: float


@dataclass
class CoarseAngle:
    """What the stage did (``report.json`` ``binned.coarse_angle``).

    Attributes
    ----------
    factor
        The coarse block side (0 when no block size keeps the rotated build small enough).
    rows, cols
        The coarse sensor's size.
    trials
        Every evaluated angle, in order.
    angle_deg
        The best angle (the start when nothing improved).
    dchi2, threshold
        Its improvement over the start on the coarse blocks, and what one parameter must earn
        there (``ln n + margin``).
    amplitude_fraction, amp_floor
        Its rms change of the prediction over the rms signal, and the floor it must reach.
    fine_amplitude, fine_where
        The same change measured on windows of the unbinned sensor (:func:`window_amplitude`)
        when the coarse blocks' change is under the floor, and where it was measured: the
        coarse blocks average a rotation's displacement of the pattern away, as 8×8 blocks do
        a mask shift's (:func:`~thintact_sdk.diagnosis.imaging.binning.unbinned_amplitude_fn`).
    accepted
        Whether the angle clears both.
    confirmed_dchi2
        Its improvement on the diagnosis's own binned data (set by the diagnosis; None until
        evaluated there).
    dropped
        Named effects (or the mask's shift) that no longer earned their threshold with the
        rotation in the model: they had stood in for it.
    shift_um, shift_dchi2, shift_threshold, shift_amplitude, shift_kept
        The joint refit of the angle with the mask's shift (None when not run): the shift,
        its Δχ² against the same angle without it, its threshold, its change, and whether
        it was kept.
    note
        Why it did not run, or how the search ended.
    seconds
        Wall-clock seconds of the stage.
    """

    factor: int
    rows: int = 0
    cols: int = 0
    trials: list[AngleTrial] = field(default_factory=list)
    angle_deg: float = 0.0
    dchi2: float = 0.0
    threshold: float = 0.0
    amplitude_fraction: float = 0.0
    amp_floor: float = 0.0
    fine_amplitude: float | None = None
    fine_where: str = ""
    accepted: bool = False
    confirmed_dchi2: float | None = None
    dropped: list[str] = field(default_factory=list)
    shift_um: tuple[float, float] | None = None
    shift_dchi2: float = 0.0
    shift_threshold: float = 0.0
    shift_amplitude: float | None = None
    shift_kept: bool = False
    note: str = ""
    seconds: float = 0.0

    @property
    def ran(self) -> bool:
        """Whether any angle was evaluated."""
        return bool(self.trials)

    def summary(self) -> str:
        """One sentence on what the stage found."""
        if not self.ran:
            return f"The mask's angle was not screened: {self.note}"
        where = f"on the sensor binned {self.factor}×{self.factor} ({self.rows}×{self.cols} blocks)"
        if self.accepted:
            text = (f"The mask's angle, fitted {where} over {len(self.trials)} angles: {self.angle_deg:+.4f}° "
                    f"(Δχ² {self.dchi2:.0f} there, threshold {self.threshold:.0f}; a change of "
                    f"{self.amplitude_fraction:.1e} of the signal{self._fine()}).")
            if self.dropped:
                what = " and ".join(self.dropped)
                text += (f" With the rotation in the model, {what} no longer earned "
                         + ("its threshold there (it had stood in for the rotation) and was dropped."
                            if len(self.dropped) == 1 else
                            "their thresholds there (they had stood in for the rotation) and were dropped."))
            if self.shift_um is not None:
                text += (f" Refitted with the mask's shift there: ({self.shift_um[0]:+.2f}, {self.shift_um[1]:+.2f}) um, "
                         f"Δχ² {self.shift_dchi2:.0f} (threshold {self.shift_threshold:.0f})"
                         + (", kept." if self.shift_kept else ", not kept (set to 0)."))
            if self.confirmed_dchi2 is not None:
                text += f" On the diagnosis's binned data it lowers χ² by {self.confirmed_dchi2:.0f}."
            return text
        return (f"The mask's angle was screened {where} over {len(self.trials)} angles: the best, "
                f"{self.angle_deg:+.4f}°, lowers χ² by {self.dchi2:.0f} (threshold {self.threshold:.0f}) "
                f"and changes the prediction by {self.amplitude_fraction:.1e} of the signal{self._fine()} "
                f"(floor {self.amp_floor:.0e}): no rotation is named. {self.note}").rstrip()

    def _fine(self) -> str:
        if self.fine_amplitude is None:
            return ""
        return f", {self.fine_amplitude:.1e} {self.fine_where}"

    def evidence(self, diagnosis_bin: int) -> str:
        """The sentence a finding's evidence gets for an angle fitted here."""
        return (f" Its angle was fitted on the sensor binned {self.factor}×{self.factor}, where a rotated "
                f"kernel builds in seconds (binned {diagnosis_bin}×{diagnosis_bin}, where the other effects "
                f"were fitted, each build would take minutes): there it lowers χ² by {self.dchi2:.0f} "
                f"(threshold {self.threshold:.0f}) over {len(self.trials)} angles evaluated.")

    def screened_evidence(self) -> str:
        """The sentence a mask-shift finding gets when the angle was screened here and not named."""
        return (f" Its angle was screened on the sensor binned {self.factor}×{self.factor}: the best, "
                f"{self.angle_deg:+.4f}°, lowers χ² by {self.dchi2:.0f} there (threshold {self.threshold:.0f}), "
                "so it stays 0.")

    def to_json(self) -> dict[str, object]:
        """The stage as ``report.json`` reports it."""
        return {
            "summary": self.summary(), "ran": self.ran, "factor": self.factor,
            "rows": self.rows, "cols": self.cols,
            "angle_deg": round(self.angle_deg, 5), "accepted": self.accepted,
            "dchi2": round(self.dchi2, 1), "threshold": round(self.threshold, 1),
            "amplitude_fraction": float(f"{self.amplitude_fraction:.3g}"),
            "fine_amplitude": None if self.fine_amplitude is None else float(f"{self.fine_amplitude:.3g}"),
            "fine_where": self.fine_where,
            "confirmed_dchi2": None if self.confirmed_dchi2 is None else round(self.confirmed_dchi2, 1),
            "dropped": list(self.dropped),
            "shift": None if self.shift_um is None else {
                "dx_um": round(self.shift_um[0], 4), "dy_um": round(self.shift_um[1], 4),
                "dchi2": round(self.shift_dchi2, 1), "threshold": round(self.shift_threshold, 1),
                "amplitude_fraction": None if self.shift_amplitude is None else float(f"{self.shift_amplitude:.3g}"),
                "kept": self.shift_kept},
            "trials": [{"angle_deg": round(t.angle_deg, 5), "chi2": round(t.chi2, 1),
                        "seconds": round(t.seconds, 2)} for t in self.trials],
            "note": self.note, "seconds": round(self.seconds, 1),
        }


def coarse_factor(profile: Profile, bin_factor: int, limit: float = COARSE_FAMILY_BYTES,
                  probe_deg: float = PROBE_ANGLE_DEG) -> int:
    """The smallest multiple of ``bin_factor`` (above it) dividing the sensor's rows and
    columns whose binned device's rotated build at ``probe_deg`` needs at most ``limit``
    bytes of displacement families, keeping :data:`MIN_COARSE_SIDE` pixels a side; 0 when none."""
    from thintact_sdk.simulation.effects import resolve_physics
    from thintact_sdk.simulation.params import kernel_params
    from thintact_sdk.simulation.simulator import rotated_build_bytes

    rows, cols = profile.sensor.rows, profile.sensor.cols
    probe = {EFFECT: {"angle_deg": probe_deg, "dx_um": 0.0, "dy_um": 0.0}}
    f = bin_factor
    while True:
        f += bin_factor
        if min(rows, cols) // f < MIN_COARSE_SIDE:
            return 0
        if rows % f or cols % f:
            continue
        kp = kernel_params(binned_profile(profile, f), resolve_physics({**dict(profile.physics), **probe}))
        if rotated_build_bytes(kp) <= limit:
            return f


def next_angle(trials: dict[float, float]) -> float:
    """The next angle of a successive-parabola search over ``{angle: χ²}`` (≥ 3 angles): the
    vertex of the parabola through the three lowest, kept within four times their span of
    them (a step downhill of twice that span when the three are not convex)."""
    pts = sorted(sorted(trials.items(), key=lambda t: t[1])[:3])
    (a, fa), (b, fb), (c, fc) = pts
    span = max(c - a, 1e-9)
    num = (b - a) ** 2 * (fb - fc) - (b - c) ** 2 * (fb - fa)
    den = (b - a) * (fb - fc) - (b - c) * (fb - fa)
    convex = (fb - fa) / max(b - a, 1e-12) < (fc - fb) / max(c - b, 1e-12)
    if convex and den != 0.0:
        x = b - 0.5 * num / den
    else:
        best = min(pts, key=lambda t: t[1])[0]
        x = best - 2 * span if best == a else best + 2 * span
    x = float(np.clip(x, a - 4 * span, c + 4 * span))
    return float(np.clip(x, -MAX_ANGLE_DEG, MAX_ANGLE_DEG))


def coarse_angle_stage(
    spec: CoarseAngleInput,
    values: Values,
    named: list[str],
    *,
    sys_frac: float,
    margin: float,
    amp_floor: float,
    progress: Callable[[str], None] | None = None,
) -> tuple[CoarseAngle, Values]:
    """Fit the mask's angle on coarse blocks with every other effect at ``values``.

    When the angle is accepted, the effects the selection named (``named``) are checked
    against it there, weakest first: one that no longer earns its threshold with the
    rotation in the model (it stood in for the rotation on the binned data, e.g. a veil or
    a small shift) is dropped, a mask shift set back to 0; the angle is then searched again
    from its fit.

    Returns
    -------
    (stage, values)
        What the stage did, and the values after it (unchanged unless the angle was accepted).
    """
    t0 = time.perf_counter()
    say = progress or (lambda _m: None)
    full = spec.data.profile
    f = coarse_factor(full, spec.bin_factor, spec.family_limit)
    if not f:
        return CoarseAngle(0, note=(
            f"no multiple of the {spec.bin_factor}×{spec.bin_factor} blocks dividing the "
            f"{full.sensor.rows}×{full.sensor.cols} sensor (keeping {MIN_COARSE_SIDE} blocks a side) brings "
            f"a {PROBE_ANGLE_DEG:g}° rotated build under {spec.family_limit / 1024**3:.2f} GiB of families")), values
    data = bin_data(spec.data, f)
    model = DiagnosisModel(data, spec.simulate or default_simulate, binned_variance_fn(f), sys_frac=sys_frac,
                           cache_size=3)
    null = CANDIDATES[EFFECT].null(full)
    start_vec = np.asarray(values.get(EFFECT, null), float)
    stage = CoarseAngle(f, data.profile.sensor.rows, data.profile.sensor.cols, amp_floor=amp_floor)
    say(f"fitting the mask's angle on the sensor binned {f}×{f}")
    model.set_reference(None)
    model.set_reference(model.evaluate(values).pred_dn)
    deadline = Deadline.after(spec.budget_s)
    ln_n = float(math.log(max(model.n_fit, 2)))
    search = _AngleSearch(model, stage, say)
    e0 = model.evaluate(values)
    best, ev = search.run(values, float(start_vec[0]), SCORE_STEP_DEG, deadline, spec.budget_s)
    sig = (e0.pred_dn - model.black)[model.fit_mask]
    signal_rms = float(np.sqrt(np.mean(sig * sig))) if sig.size else 1.0
    d = (ev.pred_dn - e0.pred_dn)[model.fit_mask]
    stage.angle_deg = float(best[EFFECT][0])
    stage.dchi2 = e0.chi2 - ev.chi2
    stage.threshold = ln_n + margin
    stage.amplitude_fraction = float(np.sqrt(np.mean(d * d))) / max(signal_rms, 1e-12) if d.size else 0.0
    stage.accepted = stage.angle_deg != float(start_vec[0]) and stage.dchi2 > stage.threshold \
        and stage.amplitude_fraction > amp_floor
    if not stage.accepted and stage.dchi2 > stage.threshold and stage.angle_deg != float(start_vec[0]):
        say("the angle's change is under the floor on the coarse blocks: measuring it on unbinned windows")
        fine = window_amplitude(spec.data, model.optical_physics(values), model.optical_physics(best),
                                e0.beta[:, 0], spec.bin_factor)
        if fine is not None:
            stage.fine_amplitude, stage.fine_where = fine
            stage.accepted = stage.fine_amplitude > amp_floor
    if stage.accepted:
        pruned, ev_p = _prune_stand_ins(model, best, ev, named, ln_n, margin, stage, say)
        if pruned is not best and not deadline.expired():
            say("searching the angle again without the effects it replaced")
            best, ev = search.run(pruned, stage.angle_deg, 4 * ANGLE_TOL_DEG, deadline, spec.budget_s, ev_p)
            stage.angle_deg = float(best[EFFECT][0])
        elif pruned is not best:
            best, ev = pruned, ev_p
        if not deadline.expired():
            best, ev = _refit_with_shift(spec, model, best, ev, ln_n, margin, amp_floor, stage, deadline, say)
            stage.angle_deg = float(best[EFFECT][0])
        stage.dchi2 = e0.chi2 - ev.chi2
    stage.seconds = time.perf_counter() - t0
    say(stage.summary())
    return stage, (best if stage.accepted else values)


def window_amplitude(data: DiagnosisData, before: dict[str, dict[str, Any]], after: dict[str, dict[str, Any]],
                     gains: np.ndarray, bin_factor: int, n_windows: int = FINE_WINDOWS,
                     n_frames: int = FINE_FRAMES) -> tuple[float, str] | None:
    """The rms change of the kernel's output between two optical physics (``after`` rotated)
    over its rms signal, on ``n_windows`` windows of the sensor at full resolution.

    The whole sensor's rotated kernel at full resolution is refused beyond a few hundredths
    of a degree on the paper's device (0.1°: 48 windows, 6.6 GiB of families), but each of its
    windows builds in seconds: the windows are taken evenly from the device's window plan
    (row-major, so they span its rows and columns, centre and edges), the kernels of both
    physics built there, and the change measured on ``n_frames`` frames with each channel
    weighted by its gain (``gains``, DN per simulator unit), as the diagnosis's amplitude is.
    Scene-stage and post-kernel effects are left out of both (they act alike on either).
    Where even the windows are refused the sensor is binned 2×2, 4×4, ... up to
    ``bin_factor``. Returns ``(fraction, where)``, or None when nothing finer than
    ``bin_factor`` builds.
    """
    from thintact_sdk.diagnosis.imaging.recording_data import subset_frames
    from thintact_sdk.simulation.effects import resolve_physics
    from thintact_sdk.simulation.params import kernel_params
    from thintact_sdk.simulation.simulator import build_window_kernel, streamed_rotated_kernel
    from thintact_sdk.simulation.tiled import build_window_pieces, spread_windows, window_params

    scenes = subset_frames(data, n_frames).scenes
    f = 1
    while f < bin_factor:
        prof = binned_profile(data.profile, f) if f > 1 else data.profile
        kp_b, kp_a = (kernel_params(prof.with_physics(ph), resolve_physics(ph)) for ph in (before, after))
        try:
            spans = streamed_rotated_kernel(kp_a).spans
        except ThinTactError:
            f *= 2
            continue
        pick = spread_windows(spans, n_windows)
        g = np.asarray(gains, float)[None, None, None, :]
        num = den = 0.0
        for span in pick:  # a window refused for its terms is taken in quadrants
            for w in build_window_pieces(kp_a, span, build_window_kernel):
                y_a = w.kernel.apply(scenes, "float32") * g
                kern_b = build_window_kernel(window_params(kp_b, w.row0, w.row1, w.col0, w.col1))
                y_b = kern_b.apply(scenes, "float32") * g
                num += float(np.sum((y_a - y_b) ** 2))
                den += float(np.sum(y_b * y_b))
        where = (f"on {len(pick)} of {len(spans)} windows of the unbinned sensor" if f == 1 else
                 f"on {len(pick)} of {len(spans)} windows of the sensor binned {f}×{f}")
        return math.sqrt(num / max(den, 1e-300)), where
    return None


JOINT_ITERATIONS = 4
"""Levenberg-Marquardt iterations of the joint angle-and-shift refit on the coarse blocks."""


def _refit_with_shift(spec: CoarseAngleInput, model: DiagnosisModel, values: Values, ev: Evaluation,
                      ln_n: float, margin: float, amp_floor: float, stage: CoarseAngle, deadline: Deadline,
                      say: Callable[[str], None]) -> tuple[Values, Evaluation]:
    """Refit the angle together with the mask's shift on the coarse blocks (Levenberg-Marquardt,
    finite differences, each step a rotated build). With the angle held, the 8×8 selection
    judged a shift against a model without the rotation, whose residual hides it (a 5/−3 µm
    shift beside a −0.2° turn on the paper's device went unnamed, and the angle alone came out
    −0.191°). The shift is kept when it earns its two parameters' threshold there and its change
    reaches the amplitude floor (on windows of the unbinned sensor when the blocks average it
    away); otherwise it is set to 0 and the refitted angle kept."""
    from thintact_sdk.diagnosis.imaging import optimise
    from thintact_sdk.diagnosis.imaging.select import Trial

    say("refitting the mask's angle with its shift on the coarse blocks")
    trial = Trial(model, values, (EFFECT,))
    x, ev_j = optimise.levenberg_marquardt(
        trial, trial.pack(values), ev, trial.data, trial.box, 0.01 * trial.step, [0, 1, 2], deadline,
        JOINT_ITERATIONS)
    fitted = trial.unpack(x)
    vec = np.asarray(fitted[EFFECT], float)
    no_shift = {**fitted, EFFECT: np.array([vec[0], 0.0, 0.0])}
    ev_0 = model.evaluate(no_shift)
    stage.shift_dchi2 = ev_0.chi2 - ev_j.chi2
    stage.shift_threshold = 2 * ln_n + margin
    stage.shift_um = (float(vec[1]), float(vec[2]))
    keep = bool(np.any(vec[1:])) and stage.shift_dchi2 > stage.shift_threshold
    if keep:
        sig = (ev_0.pred_dn - model.black)[model.fit_mask]
        d = (ev_j.pred_dn - ev_0.pred_dn)[model.fit_mask]
        amp = float(np.sqrt(np.mean(d * d)) / max(float(np.sqrt(np.mean(sig * sig))), 1e-12)) if d.size else 0.0
        if amp <= amp_floor:
            fine = window_amplitude(spec.data, model.optical_physics(no_shift), model.optical_physics(fitted),
                                    ev_j.beta[:, 0], spec.bin_factor)
            amp = fine[0] if fine is not None else amp
        stage.shift_amplitude = amp
        keep = amp > amp_floor
    stage.shift_kept = keep
    say(f"mask shift with the angle: ({vec[1]:+.2f}, {vec[2]:+.2f}) um, Δχ² {stage.shift_dchi2:.0f} "
        f"(threshold {stage.shift_threshold:.0f}): {'kept' if keep else 'set to 0'}")
    return (fitted, ev_j) if keep else (no_shift, ev_0)


def _prune_stand_ins(model: DiagnosisModel, values: Values, ev: Evaluation, named: list[str], ln_n: float,
                     margin: float, stage: CoarseAngle, say: Callable[[str], None]) -> tuple[Values, Evaluation]:
    """Backward elimination with the rotation in the model: drop, weakest first, each named
    effect (or the mask's shift) whose removal costs less than its threshold on the coarse
    blocks; ``values`` itself is returned when nothing is dropped."""
    cur, cur_ev = values, ev
    while True:
        trials: list[tuple[float, float, str, Values, Evaluation]] = []
        for name in named:
            if name not in cur:
                continue
            if name == EFFECT:
                vec = np.array(cur[EFFECT], float)
                if not np.any(vec[1:]):
                    continue
                vec[1:] = 0.0
                without = {**cur, EFFECT: vec}
                k = len(vec) - 1
            else:
                without = {n: v for n, v in cur.items() if n != name}
                k = CANDIDATES[name].k
            e = model.evaluate(without)
            trials.append((e.chi2 - cur_ev.chi2, k * ln_n + margin, name, without, e))
        weak = [t for t in trials if t[0] < t[1]]
        if not weak:
            return cur, cur_ev
        cost, thr, name, cur, cur_ev = min(weak, key=lambda t: t[0] - t[1])
        what = "the mask's shift" if name == EFFECT else name
        stage.dropped.append(what)
        say(f"with the rotation, {what} earns Δχ² {cost:.0f} on the coarse blocks (threshold {thr:.0f}): dropped")


class _AngleSearch:
    """The one-parameter search of the angle on the coarse model (every evaluation recorded in
    the stage's trials)."""

    def __init__(self, model: DiagnosisModel, stage: CoarseAngle, say: Callable[[str], None]) -> None:
        self.model, self.stage, self.say = model, stage, say

    def run(self, values: Values, start: float, probe: float, deadline: Deadline, budget_s: float,
            ev_start: Evaluation | None = None) -> tuple[Values, Evaluation]:
        """Successive parabolas from ``start`` (and ``start ± probe``); the best values and
        their evaluation."""
        base = np.asarray(values.get(EFFECT, CANDIDATES[EFFECT].null(self.model.profile)), float).copy()
        evals: dict[float, Evaluation] = {}
        chi2: dict[float, float] = {}
        f = self.stage.factor

        def at(angle: float) -> Values:
            vec = base.copy()
            vec[0] = angle
            return {**values, EFFECT: vec}

        def evaluate(angle: float) -> None:
            ts = time.perf_counter()
            ev = self.model.evaluate(at(angle))
            dt = time.perf_counter() - ts
            evals[angle], chi2[angle] = ev, ev.chi2
            self.stage.trials.append(AngleTrial(angle, ev.chi2, dt))
            self.say(f"mask angle {angle:+.4f}° on {f}×{f} blocks: χ² {ev.chi2:.1f} ({dt:.1f} s)")

        if ev_start is not None:
            evals[start], chi2[start] = ev_start, ev_start.chi2
        for a in (start, start - probe, start + probe):
            if a not in chi2:
                evaluate(a)
        n_max = len(chi2) + MAX_EVALUATIONS - 3
        self.stage.note = f"The search used its {MAX_EVALUATIONS} angles."
        while len(chi2) < n_max:
            nxt = next_angle(chi2)
            if min(abs(nxt - a) for a in chi2) < ANGLE_TOL_DEG:
                self.stage.note = f"The search converged (its next step was under {ANGLE_TOL_DEG:g}°)."
                break
            # a rotated build's work grows about as the angle squared: predict it from the largest so far
            done = max(self.stage.trials, key=lambda t: abs(t.angle_deg))
            cost = max(t.seconds for t in self.stage.trials) * max(1.0, (nxt / max(abs(done.angle_deg), 1e-6)) ** 2)
            if not deadline.allows(cost):
                self.stage.note = (f"The search stopped at its {budget_s:.0f} s budget (the next angle, "
                                   f"{nxt:+.4f}°, would take about {cost:.0f} s).")
                break
            evaluate(nxt)
        best = min(chi2, key=lambda a: chi2[a])
        return at(best), evals[best]
