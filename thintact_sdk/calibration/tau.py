"""Choosing the Tikhonov τ from the unit's own frames.

Three criteria, each a curve over a log grid of τ:

``cross-validation``
    The validation scenes are split into two folds (identical scenes, e.g. ``white`` and
    ``val_white``, always in the same fold). τ is tuned on one fold and the other fold is
    scored with it, and vice versa: the held-out PSNR of every scene comes from a τ that never
    saw that scene. The τ written into the bundle is then the best over all scenes. Every
    *distinct* scene weighs the same in these means: repeats of one scene (the recording's
    ``white`` and the wizard's ``val_white``) share one scene's weight. Counted twice, the
    white scene — whose PSNR still rises 7 dB between the τ the presses want and 5× that —
    pulled the choice to 6.8e4 DN² and cost unseen scenes 0.35 dB (docs/calibration.md).
    **Per channel**: leaving out one distinct scene at a time, one τ and one τ per channel
    (each the best mean PSNR of its channel) are tuned on the other scenes and the left-out
    scene is scored with both; the bundle gets a τ per channel only when the mean held-out
    gain exceeds its standard error, else one τ for all.
``gcv``
    Generalised cross-validation, which needs no scene: ``GCV(τ) = mean(r²/σ²) / (1 − tr(H)/n)²``
    with ``r = Y − A X̂_τ`` the residual of the full T2S model, ``σ²`` the noise model's
    variance at the measured level, ``H = A·decode_τ`` the influence operator (its trace by
    Hutchinson's estimator with fixed Rademacher probes) and ``n`` the number of measured values.
``discrepancy``
    Morozov's principle: the largest τ whose residual is not above the noise,
    ``mean(r²/σ²) ≤ 1``, with ``σ²`` from the noise measured on the slit frames.

Every decoder used here must be linear in the measurement and expose ``set_tau`` (the
closed-form decoders that declare the trait ``calibration-candidate`` do).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.calibration.validation import score_psnr
from thintact_sdk.reconstruction.filter_training import scene_for_channels
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices

TAU_STEPS_PER_DECADE = 2
"""Resolution of the coarse τ grid; :func:`refine` adds :data:`FINE_STEPS_PER_DECADE` points
per decade around the coarse optimum."""
FINE_STEPS_PER_DECADE = 8
MIN_SCENES_PER_FOLD = 2
"""Cross-validation needs this many distinct scenes in each fold (a τ tuned on one scene is
that scene's, not the unit's)."""


@dataclass
class TauCurve:
    """One criterion's curve and choice.

    Attributes
    ----------
    criterion
        ``cross-validation``, ``gcv``, ``discrepancy`` or ``simulated``.
    taus
        The grid, DN² (units of the system matrices squared).
    values
        The criterion at each τ (``unit`` says what it is).
    tau
        The τ the criterion chose (NaN when it cannot choose, ``note`` says why).
    unit
        What ``values`` are: ``mean PSNR dB`` (higher is better), ``GCV`` (lower is better),
        ``mean r²/σ²`` (target 1).
    note
        Anything a reader must know (e.g. "the residual never reaches the noise").
    """

    criterion: str
    taus: list[float]
    values: list[float]
    tau: float
    unit: str
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict (numbers rounded to 4 significant digits)."""
        return {"criterion": self.criterion, "tau": _sig(self.tau), "unit": self.unit,
                "taus": [_sig(t) for t in self.taus], "values": [_sig(v) for v in self.values],
                "note": self.note}


@dataclass
class CrossValidation:
    """Two-fold cross-validation of τ over validation scenes for one decoder.

    Attributes
    ----------
    decoder
        Decoder name.
    curve
        Mean PSNR over all scenes against τ (its ``tau`` is the deployed choice).
    labels
        Scene labels, in order.
    folds
        Fold index (0 or 1) of each scene.
    fold_tau
        τ chosen on each fold.
    held_out_psnr
        Per label: PSNR (dB) with the τ chosen on the *other* fold.
    held_out_estimates
        Per label: the ``N × M × C`` reconstruction at that τ.
    channel_tau
        Deployed τ per channel (DN²), ``None`` when one τ for all channels scored better held out.
    channel_fold_tau
        For each distinct scene left out, the τ per channel tuned on the others (``[]`` for a
        one-channel device or fewer than three distinct scenes).
    held_out_shared_db, held_out_channel_db, channel_gain_se_db
        Leave-one-scene-out mean PSNR with one τ and with a τ per channel, and the standard
        error of the mean gain; ``channel_tau`` is set when the gain exceeds it.
    tau_spread
        16th and 84th percentiles (DN²) of the τ the same criterion chooses on bootstrap
        resamples of the distinct scenes: how well the scenes determine τ (NaN with fewer
        than three distinct scenes).
    prior, fold_prior, prior_curves, prior_held_out_db, plain_held_out_db
        Set by :func:`cross_validate_prior`: the deployed scene prior (``None``: plain
        Tikhonov), the prior each fold's τ was tuned with, each candidate prior's mean-PSNR
        curve and held-out mean PSNR (dB), and plain Tikhonov's held-out mean PSNR (dB).
    plain
        Set by :func:`cross_validate_prior` when a prior is deployed: plain Tikhonov's own
        cross-validation (the unit is judged against its design on it, see
        :func:`thintact_sdk.calibration.selection.select`).
    """

    decoder: str
    curve: TauCurve
    labels: list[str]
    folds: list[int]
    fold_tau: list[float]
    held_out_psnr: dict[str, float] = field(default_factory=dict)
    held_out_estimates: dict[str, np.ndarray] = field(default_factory=dict)
    channel_tau: list[float] | None = None
    channel_fold_tau: list[list[float]] = field(default_factory=list)
    held_out_shared_db: float = float("nan")
    held_out_channel_db: float = float("nan")
    channel_gain_se_db: float = float("nan")
    tau_spread: tuple[float, float] = (float("nan"), float("nan"))
    prior: ScenePrior | None = None
    fold_prior: list[ScenePrior | None] = field(default_factory=list)
    prior_curves: list[tuple[ScenePrior, TauCurve]] = field(default_factory=list)
    prior_held_out_db: dict[ScenePrior, float] = field(default_factory=dict)
    plain_held_out_db: float = float("nan")
    plain: CrossValidation | None = None

    @property
    def held_out_mean_db(self) -> float:
        """Mean held-out PSNR (dB): the cross-validated estimate of this decoder's quality."""
        return float(np.mean(list(self.held_out_psnr.values())))


def _sig(x: float) -> float:
    return float(f"{x:.4g}") if np.isfinite(x) else float("nan")


def tau_grid(sm: SystemMatrices, lo: float = 1e-9, hi: float = 1e-1) -> np.ndarray:
    """Log grid of τ, ``lo … hi`` × the largest ``σ_P² σ_Q²`` of the coding matrices (DN²)."""
    unit = 0.0
    for c in range(sm.channels):
        sp = np.linalg.norm(np.asarray(sm.Pc[c], np.float64), 2)
        sq = np.linalg.norm(np.asarray(sm.Qc[c], np.float64), 2)
        unit = max(unit, float(sp * sq) ** 2)
    decades = np.log10(hi / lo)
    count = int(round(decades * TAU_STEPS_PER_DECADE)) + 1
    return unit * np.logspace(np.log10(lo), np.log10(hi), count)


def refine(taus: np.ndarray, best: float) -> np.ndarray:
    """``taus`` plus a finer grid over ± one coarse step around ``best`` (sorted, unique)."""
    step = 10.0 ** (1.0 / TAU_STEPS_PER_DECADE)
    count = int(round(2 * FINE_STEPS_PER_DECADE / TAU_STEPS_PER_DECADE)) + 1
    fine = best * np.logspace(-np.log10(step), np.log10(step), count)
    return np.unique(np.concatenate([taus, fine]))


def _scene_key(x: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(np.asarray(x, np.float32)).tobytes()).hexdigest()


def assign_folds(scenes: Sequence[np.ndarray]) -> list[int]:
    """Fold 0 or 1 for each scene: distinct scenes alternate, identical scenes share a fold."""
    keys: dict[str, int] = {}
    out = []
    for x in scenes:
        key = _scene_key(x)
        if key not in keys:
            keys[key] = len(keys) % 2
        out.append(keys[key])
    return out


def scene_weights(scenes: Sequence[np.ndarray]) -> np.ndarray:
    """Weight of each scene in a τ criterion: ``1 / (copies of that scene)``, so every
    distinct scene counts once however often it was recorded."""
    keys = [_scene_key(x) for x in scenes]
    return np.array([1.0 / keys.count(k) for k in keys])


def weighted_mean(table: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean over the rows of ``table`` (scenes × τ)."""
    return np.asarray((weights[:, None] * table).sum(axis=0) / weights.sum())


def shared_decode(decoder: Any, signals: Sequence[np.ndarray]) -> Callable[[int], np.ndarray]:
    """``decode(i)``: ``decoder.decode(signals[i])`` at the decoder's current τ.

    A decoder with ``project`` / ``decode_projected`` (the τ-free big products and the rest
    of the solve, e.g. :class:`~thintact_sdk.reconstruction.decoders.t2s_closed_form.T2SClosedFormDecoder`)
    has every signal projected once here, so a sweep over τ decodes each frame from its
    projection instead of repeating those products per τ (the same figures up to float rounding).
    """
    if hasattr(decoder, "project") and hasattr(decoder, "decode_projected"):
        projected = [decoder.project(y) for y in signals]
        return lambda i: np.asarray(decoder.decode_projected(projected[i]))
    return lambda i: np.asarray(decoder.decode(signals[i]))


def _mse_table(decode: Callable[[int], np.ndarray], decoder: Any, truths: Sequence[np.ndarray],
               taus: np.ndarray) -> np.ndarray:
    """Mean squared error of every frame at every τ, per channel: ``scenes × τ × C``
    (estimates clipped to [0, 1], display units; ``decode`` as :func:`shared_decode` made
    for ``decoder``)."""
    table = np.empty((len(truths), len(taus), 0))
    tru: list[np.ndarray] = []
    for j, tau in enumerate(taus):
        decoder.set_tau(float(tau))
        for i in range(len(truths)):
            est = np.asarray(decode(i), np.float64)
            if not tru:  # the channel count is the decoder's
                channels = est.shape[-1] if est.ndim == 3 else 1
                tru = [scene_for_channels(np.asarray(x, np.float32), channels).astype(np.float64)
                       for x in truths]
                table = np.empty((len(truths), len(taus), channels))
            est = np.clip(est, 0.0, 1.0).reshape(tru[i].shape)
            table[i, j] = np.mean((est - tru[i]) ** 2, axis=(0, 1))
    return table


def _db(mse: np.ndarray) -> np.ndarray:
    """PSNR (dB, data range 1) of mean squared errors (∞ for 0, as :func:`psnr`)."""
    with np.errstate(divide="ignore"):
        return np.asarray(-10.0 * np.log10(mse))


def _refined_table(decode: Callable[[int], np.ndarray], decoder: Any, truths: Sequence[np.ndarray],
                   taus: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The τ grid refined around its best weighted mean PSNR, and the ``scenes × τ × C`` MSE."""
    mse = _mse_table(decode, decoder, truths, taus)
    fine = refine(taus, float(taus[int(np.argmax(weighted_mean(_db(mse.mean(axis=2)), weights)))]))
    extra = np.setdiff1d(fine, taus)
    if extra.size:  # (an empty table has no channel axis to join on)
        taus = np.concatenate([taus, extra])
        mse = np.concatenate([mse, _mse_table(decode, decoder, truths, extra)], axis=1)
    order = np.argsort(taus)
    return taus[order], mse[:, order]


def cross_validate(decoder: Any, name: str, signals: Sequence[np.ndarray],
                   truths: Sequence[np.ndarray], labels: Sequence[str],
                   taus: np.ndarray, min_per_fold: int = MIN_SCENES_PER_FOLD) -> CrossValidation | None:
    """Two-fold cross-validation of τ; ``None`` when the scenes do not make two folds of
    ``min_per_fold`` distinct scenes each.

    Parameters
    ----------
    decoder
        A decoder with ``set_tau`` and ``decode`` (``R × S × C`` DN above black → ``N × M × C``).
    signals, truths, labels
        Measured signals (DN above black, float32), displayed scenes, frame labels.
    taus
        τ grid (DN²).
    """
    if not enough_folds(truths, min_per_fold):
        return None
    folds = assign_folds(truths)
    weights = scene_weights(truths)
    fold_arr = np.asarray(folds)
    # every frame projected once (shared_decode): the grid, its refinement and the held-out
    # estimates below all decode from the same projections
    decode = shared_decode(decoder, signals)
    taus, mse = _refined_table(decode, decoder, truths, taus, weights)
    table = _db(mse.mean(axis=2))
    fold_tau = [float(taus[int(np.argmax(weighted_mean(table[fold_arr == f], weights[fold_arr == f])))])
                for f in (0, 1)]
    mean = weighted_mean(table, weights)
    curve = TauCurve("cross-validation", [float(t) for t in taus], [float(v) for v in mean],
                     float(taus[int(np.argmax(mean))]), "mean PSNR dB (each distinct scene once)",
                     f"two folds of {int(np.sum(fold_arr == 0))} and {int(np.sum(fold_arr == 1))} "
                     "scenes; each scene is scored with the tau tuned on the other fold")
    out = CrossValidation(name, curve, list(labels), folds, fold_tau)
    out.tau_spread = bootstrap_spread(taus, table, [_scene_key(x) for x in truths], weights)
    if np.isfinite(out.tau_spread[0]):
        curve.note += (f"; bootstrap over the distinct scenes: 68 % of resamples choose "
                       f"{out.tau_spread[0]:.3g}-{out.tau_spread[1]:.3g}")
    fold_taus: list[Any] = list(fold_tau)
    deployed: Any = curve.tau
    if mse.shape[2] > 1:
        _per_channel(out, taus, mse, [_scene_key(x) for x in truths], weights)
        if out.channel_tau is not None:
            deployed = out.channel_tau
            fold_taus = [[float(taus[int(np.argmax(weighted_mean(_db(mse[fold_arr == f, :, c]),
                                                                   weights[fold_arr == f])))])
                          for c in range(mse.shape[2])] for f in (0, 1)]
    for f in (0, 1):
        decoder.set_tau(fold_taus[1 - f])
        for i in (int(k) for k in np.flatnonzero(fold_arr == f)):
            est = np.asarray(decode(i), np.float32)
            out.held_out_estimates[labels[i]] = est
            out.held_out_psnr[labels[i]] = score_psnr(est, truths[i])
    decoder.set_tau(deployed)
    return out


PRIOR_ALPHAS = (0.5, 1.0, 1.5)
PRIOR_KNEES = (4.0, 8.0, 16.0)
"""The scene priors (:class:`~thintact_sdk.reconstruction.scene_prior.ScenePrior`, weights
``(1 + k/k0)^α`` per DCT axis) :func:`cross_validate_prior` compares with plain Tikhonov."""


def default_priors() -> list[ScenePrior]:
    """Every combination of :data:`PRIOR_ALPHAS` and :data:`PRIOR_KNEES`."""
    return [ScenePrior(a, k) for a in PRIOR_ALPHAS for k in PRIOR_KNEES]


def cross_validate_prior(make: Callable[[ScenePrior | None], Any], name: str, signals: Sequence[np.ndarray],
                         truths: Sequence[np.ndarray], labels: Sequence[str], taus: np.ndarray,
                         priors: Sequence[ScenePrior] | None = None,
                         min_per_fold: int = MIN_SCENES_PER_FOLD,
                         workers: int = 2) -> CrossValidation | None:
    """Choose a scene prior by cross-validation, as decoders are chosen.

    Plain Tikhonov (``make(None)``) and each prior ``p`` (``make(p)``) are cross-validated over
    τ exactly as :func:`cross_validate` does (two folds: τ tuned on one fold, the other scored
    with it, so no scene is scored with a τ tuned on it). The candidate with the best held-out
    mean PSNR is deployed, with its τ (and τ per channel where that scored better), provided it
    also raises the median distinct scene's held-out PSNR (:func:`median_scene_gain`).

    Choosing the prior *and* τ on each fold of three scenes instead was measured and rejected:
    on the issue's unit it picked priors whose τ differed by 30× between the folds, so the
    held-out scores were noise, the decision flipped with the candidate grid and, per scene, the
    unit fell below its design's prediction by 2.4 dB on a healthy 64 × 80 unit
    (docs/calibration.md).

    Parameters
    ----------
    make
        Builds the decoder (``set_tau``, ``decode``) for a prior (``None``: plain Tikhonov).
    priors
        Candidate priors (default :func:`default_priors`; α = 0 ones are skipped).
    name, signals, truths, labels, taus, min_per_fold
        As for :func:`cross_validate` (``taus`` in DN², searched for every candidate).
    workers
        Candidates cross-validated at once (threads; ``make`` must be safe to call from two).
    """
    plain = cross_validate(make(None), name, signals, truths, labels, taus, min_per_fold)
    candidates = prior_candidates(priors)
    if plain is None or not candidates:
        return plain

    def one(candidate: ScenePrior) -> CrossValidation | None:
        return cross_validate(make(candidate), name, signals, truths, labels, taus, min_per_fold)

    # the candidates are independent: two at a time (numpy's kernels release the interpreter
    # lock); choose_prior takes them in order, so the choice is the one a sequential search makes
    with ThreadPoolExecutor(max_workers=max(1, int(workers)), thread_name_prefix="prior-cv") as pool:
        results = list(pool.map(one, candidates))
    return choose_prior(plain, candidates, results, labels, truths)


def prior_candidates(priors: Sequence[ScenePrior] | None = None) -> list[ScenePrior]:
    """The scene priors :func:`cross_validate_prior` compares with plain Tikhonov: ``priors``
    (default :func:`default_priors`) without the plain ones (α = 0)."""
    return [p for p in (default_priors() if priors is None else priors) if not p.is_plain]


def enough_folds(truths: Sequence[np.ndarray], min_per_fold: int = MIN_SCENES_PER_FOLD) -> bool:
    """Whether the scenes make two folds of ``min_per_fold`` distinct scenes each (else
    :func:`cross_validate` returns ``None`` without decoding)."""
    distinct = {(f, _scene_key(x)) for f, x in zip(assign_folds(truths), truths, strict=True)}
    return all(sum(1 for f, _ in distinct if f == fold) >= min_per_fold for fold in (0, 1))


def choose_prior(plain: CrossValidation, candidates: Sequence[ScenePrior],
                 results: Sequence[CrossValidation | None], labels: Sequence[str],
                 truths: Sequence[np.ndarray]) -> CrossValidation:
    """The choice of :func:`cross_validate_prior` from plain Tikhonov's cross-validation and
    each candidate's (``results[i]`` for ``candidates[i]``, ``None`` where it did not make
    two folds), taken in the candidates' order: the best held-out mean among the candidates
    that also raise the median distinct scene (:func:`median_scene_gain`), else plain."""
    plain.plain_held_out_db = plain.held_out_mean_db
    keys = [_scene_key(x) for x in truths]
    best, curves = plain, []
    for candidate, cv in zip(candidates, results, strict=True):
        if cv is None:
            continue
        cv.prior, cv.fold_prior = candidate, [candidate, candidate]
        curves.append((candidate, cv))
        typical = median_scene_gain(cv, plain, labels, keys)
        cv.curve.note += f"; median held-out gain over plain Tikhonov per distinct scene {typical:+.2f} dB"
        if typical > 0 and cv.held_out_mean_db > best.held_out_mean_db:
            best = cv
    best.prior_curves = [(p, TauCurve("cross-validation", cv.curve.taus, cv.curve.values, cv.curve.tau,
                                      cv.curve.unit, f"held out {cv.held_out_mean_db:.3f} dB"))
                         for p, cv in curves]
    best.prior_held_out_db = {p: cv.held_out_mean_db for p, cv in curves}
    best.plain_held_out_db = plain.held_out_mean_db
    if best is not plain:
        best.plain = plain
    if best.prior is None:
        best.curve.note += ("; scene prior not used: no candidate scored better held out than plain "
                            f"Tikhonov ({plain.held_out_mean_db:.3f} dB) on the mean and on the median scene")
    else:
        best.curve.note += (f"; scene prior alpha {best.prior.alpha:g}, k0 {best.prior.k0:g} chosen over "
                            f"{len(curves)} priors and plain Tikhonov by held-out mean PSNR: "
                            f"{best.held_out_mean_db:.3f} dB, plain Tikhonov {plain.held_out_mean_db:.3f} dB")
    return best


def median_scene_gain(cv: CrossValidation, reference: CrossValidation, labels: Sequence[str],
                      keys: Sequence[str]) -> float:
    """Median over the distinct scenes of ``cv``'s held-out PSNR minus ``reference``'s (dB;
    repeats of a scene averaged first).

    A mean of PSNRs can be won on one scene alone: an estimate clipped to the display range
    scores without limit on a white scene when it is too bright everywhere (on one-term,
    FlatCam-style matrices a prior did that and lost 3 dB on every press), so a prior must also
    help the median scene.
    """
    gains: dict[str, list[float]] = {}
    for label, key in zip(labels, keys, strict=True):
        a, b = cv.held_out_psnr[label], reference.held_out_psnr[label]
        gains.setdefault(key, []).append(0.0 if a == b else a - b)  # both ∞ (exact): no gain
    return float(np.median([np.mean(g) for g in gains.values()]))


BOOTSTRAP_RESAMPLES = 400
"""Resamples of :func:`bootstrap_spread` (fixed seed: a calibration is reproducible)."""


def bootstrap_spread(taus: np.ndarray, table: np.ndarray, keys: list[str], weights: np.ndarray,
                     resamples: int = BOOTSTRAP_RESAMPLES, seed: int = 0) -> tuple[float, float]:
    """16th and 84th percentiles of the criterion's τ over bootstrap resamples of the
    distinct scenes (``table``: scenes × τ PSNR dB; ``keys``: which distinct scene each row
    is; ``weights`` as in :func:`scene_weights`); NaN with fewer than three distinct scenes.

    On the issue's 128 × 160 unit (six distinct validation scenes) it is 2.16e4-3.85e4 DN²
    around the chosen 2.885e4, about ±0.13 decade: a τ chosen on them is that uncertain,
    whatever the rule (docs/calibration.md).
    """
    groups = list(dict.fromkeys(keys))
    if len(groups) < 3:
        return float("nan"), float("nan")
    key_arr = np.asarray(keys)
    per_scene = np.stack([weighted_mean(table[key_arr == g], weights[key_arr == g]) for g in groups])
    rng = np.random.default_rng(seed)
    picks = [float(taus[int(np.argmax(per_scene[rng.integers(0, len(groups), len(groups))].mean(axis=0)))])
             for _ in range(resamples)]
    lo, hi = np.percentile(np.log(picks), [16.0, 84.0])
    return float(np.exp(lo)), float(np.exp(hi))


def _per_channel(out: CrossValidation, taus: np.ndarray, mse: np.ndarray, keys: list[str],
                 weights: np.ndarray) -> None:
    """Fill ``out``'s per-channel fields by leaving out one distinct scene at a time.

    For each distinct scene, one τ and one τ per channel are tuned on all the *other* scenes
    and the left-out scene is scored with each (no scene is scored with a τ tuned on it).
    A τ per channel has three times the parameters, so it is kept only when its mean held-out
    gain exceeds one standard error of that mean (the one-standard-error rule of
    cross-validated model choice): on the test recordings a τ per channel that won by 0.04 dB
    on average — 0.43 dB on white, −0.15 dB on two other scenes — lost 0.05 dB on unseen scenes.
    """
    channel_db = _db(mse)  # scenes × τ × C
    groups = list(dict.fromkeys(keys))
    if len(groups) < 3:
        return
    key_arr = np.asarray(keys)
    gains, shared, per_channel = [], [], []
    for g in groups:
        held, rest = key_arr == g, key_arr != g
        j = int(np.argmax(weighted_mean(_db(mse[rest].mean(axis=2)), weights[rest])))
        jc = [int(np.argmax(weighted_mean(channel_db[rest, :, c], weights[rest]))) for c in range(mse.shape[2])]
        out.channel_fold_tau.append([float(taus[k]) for k in jc])
        one = float(np.mean(_db(mse[held, j].mean(axis=1))))
        each = float(np.mean(_db(np.mean([mse[held, k, c] for c, k in enumerate(jc)], axis=0))))
        shared.append(one)
        per_channel.append(each)
        gains.append(each - one)
    out.held_out_shared_db = float(np.mean(shared))
    out.held_out_channel_db = float(np.mean(per_channel))
    out.channel_gain_se_db = float(np.std(gains, ddof=1) / np.sqrt(len(gains)))
    if np.mean(gains) > out.channel_gain_se_db:
        out.channel_tau = [float(taus[int(np.argmax(weighted_mean(channel_db[:, :, c], weights)))])
                           for c in range(mse.shape[2])]


def _channel_first(a: np.ndarray) -> np.ndarray:
    """``R × S × C`` → ``C × R × S`` float32, each channel's plane contiguous."""
    return np.ascontiguousarray(np.moveaxis(np.asarray(a), 2, 0), np.float32)


class _ChannelForward:
    """``sm.forward`` per channel in float32 for :func:`noise_criteria`'s residuals and traces:
    ``[Po Pc] [X Qoᵀ; X Qcᵀ]``, one ``R × 2N`` by ``2N × S`` product per channel (the residual
    of a frame of thousands of DN against noise of a few DN loses nothing in float32; the
    curves are reported to 4 significant digits)."""

    def __init__(self, sm: SystemMatrices) -> None:
        self.left = [np.hstack([sm.Po[min(c, sm.Po.shape[0] - 1)], sm.Pc[min(c, sm.Pc.shape[0] - 1)]]
                               ).astype(np.float32) for c in range(sm.channels)]
        self.right = [(np.ascontiguousarray(sm.Qo[min(c, sm.Qo.shape[0] - 1)].T, np.float32),
                       np.ascontiguousarray(sm.Qc[min(c, sm.Qc.shape[0] - 1)].T, np.float32))
                      for c in range(sm.channels)]

    def __call__(self, scene: np.ndarray) -> Iterator[np.ndarray]:
        """Yield channel ``c``'s ``R × S`` prediction (float32) of ``scene`` (``N × M × C``)."""
        x = np.asarray(scene, np.float32)
        for c, (left, (qo, qc)) in enumerate(zip(self.left, self.right, strict=True)):
            xc = np.ascontiguousarray(x[..., c])
            yield left @ np.vstack([xc @ qo, xc @ qc])

    def adjoint(self, image: np.ndarray) -> np.ndarray:
        """``Aᵀ`` of a channel-first ``C × R × S`` image: ``Poᵀ Z Qo + Pcᵀ Z Qc`` per channel,
        ``N × M × C`` float32, so that ``⟨Z, A X⟩ = ⟨Aᵀ Z, X⟩`` for any scene ``X``."""
        n = self.left[0].shape[1] // 2
        out = []
        for c, (left, (qo, qc)) in enumerate(zip(self.left, self.right, strict=True)):
            lz = left.T @ np.asarray(image[c], np.float32)  # 2N × S: [Poᵀ Z; Pcᵀ Z]
            out.append(lz[:n] @ qo.T + lz[n:] @ qc.T)
        return np.stack(out, axis=2)


def noise_criteria(decoder: Any, sm: SystemMatrices, signals: Sequence[np.ndarray],
                   inv_var: Sequence[np.ndarray] | Callable[[np.ndarray], np.ndarray], taus: np.ndarray,
                   probes: int = 4, seed: int = 0) -> tuple[TauCurve, TauCurve]:
    """GCV and the discrepancy principle over ``signals`` (one pass over the τ grid).

    Parameters
    ----------
    decoder
        Linear decoder with ``set_tau``.
    sm
        The matrices the residual ``r = Y − A X̂_τ`` is computed with.
    inv_var
        ``1/σ²`` per measured value (DN⁻²), same shapes as ``signals``, or a function giving
        it for a signal (then only its float32 copy is ever held, one frame's at a time
        while it is made); weighting leaves the trace of the influence operator unchanged, so
        the classical GCV formula applies.
    probes
        Rademacher probes of Hutchinson's trace estimator (the same for every τ).

    Returns
    -------
    (gcv, discrepancy)
        GCV chooses its minimum; the discrepancy principle the largest τ with
        ``mean(r²/σ²) ≤ 1`` (NaN, with a note, when the residual never gets that low).
    """
    rng = np.random.default_rng(seed)
    shape = np.shape(signals[0])
    n = float(np.prod(shape))
    zs = [rng.choice(np.array([-1.0, 1.0], np.float32), size=shape) for _ in range(probes)]
    chi2 = np.empty(len(taus))
    gcv = np.empty(len(taus))
    decode = shared_decode(decoder, list(signals) + zs)
    forward = _ChannelForward(sm)
    weights = (inv_var(y) for y in signals) if callable(inv_var) else iter(inv_var)
    ws = [_channel_first(w) for w in weights]
    # the probes are needed once, for their back-projections (their decodes come from the
    # projections shared_decode took); the signals are read through channel views, not copied:
    # at the paper's size each copy of a frame is 16 MB, and these were 20 of them
    backs = [forward.adjoint(_channel_first(z)) for z in zs]
    del zs
    ys = [np.asarray(y, np.float32) for y in signals]
    for j, tau in enumerate(taus):
        decoder.set_tau(float(tau))
        acc, count = 0.0, 0
        for i, (y, w) in enumerate(zip(ys, ws, strict=True)):
            for ch, pred in enumerate(forward(decode(i))):
                r = np.subtract(y[..., ch], pred, out=pred)  # the prediction is this frame's own array
                acc += float(np.vdot(np.square(r, out=r), w[ch]))
                count += r.size
        chi2[j] = acc / count
        # zᵀ A D z = ⟨Aᵀ z, D z⟩: each probe's back-projection is taken once, not a forward per τ
        trace = float(np.mean([float(np.vdot(back, np.asarray(decode(len(ys) + i), np.float32)))
                               for i, back in enumerate(backs)]))
        gcv[j] = chi2[j] / (1.0 - min(trace, n - 1.0) / n) ** 2
    grid = [float(t) for t in taus]
    k = int(np.argmin(gcv))
    gcv_curve = TauCurve("gcv", grid, [float(v) for v in gcv], grid[k], "GCV (lower is better)",
                         f"{len(signals)} frames, {probes} Hutchinson probes")
    below = np.flatnonzero(chi2 <= 1.0)
    note = ""
    if below.size:
        tau_d = grid[int(below[-1])]
    else:
        tau_d = float("nan")
        note = (f"the residual never reaches the noise (smallest mean r²/σ² {chi2.min():.3g}): "
                "model error above the noise")
    disc = TauCurve("discrepancy", grid, [float(v) for v in chi2], tau_d, "mean r²/σ² (target 1)", note)
    return gcv_curve, disc
