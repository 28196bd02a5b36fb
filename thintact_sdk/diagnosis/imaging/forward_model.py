"""The forward model the diagnosis fits: simulator + post effects + gains + DN effects.

Prediction of one frame (all arrays ``F × R × S × C``)::

    A   = simulator irradiance with the optical effects          (arbitrary units)
    A'  = post effects' forward(A), in stage order                (e.g. crosstalk, glare)
    L_c = g_c·A'_c + Σ_t b_ct·basis_t(x, y)                       (DN, linear; g_c, b free)
    DN  = black + h(L), h the DN effects' responses chained       (e.g. gamma, then a clip)

Which effects are optical, post, DN or linear, their forward maps, DN responses and
additive bases are the effects' own declarations (:class:`thintact_sdk.simulation.effects.FitSpec`);
nothing here names an effect. The per-channel gains ``g_c`` (and the linear effects'
coefficients) are solved in closed form (weighted least squares, Gauss-Newton when a DN
effect is on) at every evaluation: they are nuisances, never findings.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES, Candidate
from thintact_sdk.diagnosis.imaging.recording_data import DiagnosisData
from thintact_sdk.diagnosis.imaging.stats import (
    FitStats,
    VarianceFn,
    default_variance_fn,
    fit_stats,
    valid_pixels,
)
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.effects import STAGES

#: simulate(profile_with_physics, scenes F×N×M×C) -> irradiance F×R×S×C
SimulateFn = Callable[[Profile, np.ndarray], np.ndarray]
Values = dict[str, np.ndarray]


def optical_physics(profile: Profile, values: Values) -> dict[str, dict[str, Any]]:
    """The ``physics`` section the simulator gets for effect ``values`` on ``profile``: the
    profile's own optical effects (and any it names that the diagnosis does not fit), with the
    optical effects of ``values`` set or added."""
    phys = {k: v for k, v in profile.physics.items() if k not in CANDIDATES or CANDIDATES[k].domain == "optical"}
    for name, vec in values.items():
        cand = CANDIDATES[name]
        if cand.domain == "optical":
            phys[name] = cand.to_params(vec, profile)
    return phys


def default_simulate(profile: Profile, scenes: np.ndarray) -> np.ndarray:
    """Noiseless irradiance of every scene from the project's simulator."""
    from thintact_sdk.simulation.simulator import Simulator

    return np.asarray(Simulator(profile).forward_batch(scenes), np.float64)


@dataclass
class Evaluation:
    """One evaluated model.

    Attributes
    ----------
    pred_dn
        ``F × R × S × C`` predicted raw DN.
    chi2
        Σ over fit pixels of w·(measured − predicted)² (w from the reference variance,
        systematic allowance included).
    beta
        ``C × B`` closed-form coefficients per channel: the gain first, then the terms of
        each linear-domain effect (:meth:`DiagnosisModel.linear_slices`).
    linear_dn
        ``F × R × S × C`` linear signal L before the DN effects.
    """

    pred_dn: np.ndarray
    chi2: float
    beta: np.ndarray
    linear_dn: np.ndarray


class DiagnosisModel:
    """Evaluates predictions of a recording for sets of effect values.

    Parameters
    ----------
    data
        The recording's frames.
    simulate
        Irradiance from a profile with optical physics (default: the project simulator).
    variance_fn
        Noise variance at predicted raw DN (``noise_variance_dn``).
    sys_frac
        Systematic-error allowance: relative model error (of the signal) added in quadrature
        to the noise for fitting and decisions (not for the reported χ²).
    exclude
        Optional ``R × S`` mask of sensor pixels left out of the fits (defects).
    cache_size
        Simulator results kept (each ``F × R × S × C`` float64).
    held
        ``{effect: parameter indices}`` held at their null value in every fit: parameters
        whose kernels the simulator cannot build on this device within the diagnosis's
        memory (e.g. a rotated mask's angle at the paper's size); the effect's other
        parameters are still screened and fitted.
    """

    def __init__(
        self,
        data: DiagnosisData,
        simulate: SimulateFn,
        variance_fn: VarianceFn,
        sys_frac: float = 1e-3,
        exclude: np.ndarray | None = None,
        cache_size: int = 24,
        held: Mapping[str, tuple[int, ...]] | None = None,
    ) -> None:
        self.data = data
        self.held: dict[str, tuple[int, ...]] = {k: tuple(v) for k, v in (held or {}).items()}
        self.profile = data.profile
        self.simulate = simulate
        self.variance_fn = variance_fn
        self.sys_frac = sys_frac
        self.cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self.cache_size = cache_size
        self.n_sim = 0
        self.sim_seconds = 0.0
        #: estimated seconds of one simulation on the simulator's slow (direct) path
        self.slow_sim_s = 10.0
        noise = self.profile.noise
        self.black = float(noise.black_level_dn)
        self.full_scale = float(noise.saturation_dn) - self.black
        m = data.measured_dn
        self.fit_mask = m < float(noise.saturation_dn) - 0.5
        if exclude is not None:
            self.fit_mask &= ~exclude[None, :, :, None]
        self.n_fit = int(self.fit_mask.sum())
        self._bases: dict[str, np.ndarray] = {}
        self.weights = np.zeros_like(m)
        self.set_reference(None)

    def free(self, cand: Candidate, include_slow: bool = True) -> list[int]:
        """Indices of ``cand``'s parameters a fit may vary: not held (:attr:`held`) and,
        unless ``include_slow``, not on the simulator's slow path (``slow_params``)."""
        held = self.held.get(cand.name, ())
        return [i for i in range(cand.k)
                if i not in held and (include_slow or i not in cand.slow_params)]

    # ------------------------------------------------------------------ variance
    def variance(self, pred_dn: np.ndarray) -> np.ndarray:
        """Noise variance (DN²) at predicted raw DN, the contract's σ²."""
        return np.asarray(self.variance_fn(pred_dn, self.profile.noise), np.float64)

    def set_reference(self, pred_dn: np.ndarray | None) -> None:
        """Fix the fit weights 1/(σ² + (sys_frac·signal)²) at a reference prediction
        (the measurement itself, clipped, when None)."""
        ref = pred_dn if pred_dn is not None else np.maximum(self.data.measured_dn, self.black)
        var = self.variance(ref) + (self.sys_frac * (ref - self.black)) ** 2
        self.weights = np.where(self.fit_mask, 1.0 / np.maximum(var, 1e-9), 0.0)

    # ------------------------------------------------------------------ simulation
    def optical_physics(self, values: Values) -> dict[str, dict[str, Any]]:
        """The ``physics`` section handed to the simulator for these values."""
        return optical_physics(self.profile, values)

    def irradiance(self, values: Values) -> np.ndarray:
        """``F × R × S × C`` simulator irradiance for the optical part of ``values``."""
        import time

        phys = self.optical_physics(values)
        key = json.dumps(phys, sort_keys=True)
        hit = self.cache.get(key)
        if hit is not None:
            self.cache.move_to_end(key)
            return hit
        t0 = time.perf_counter()
        irr = np.asarray(self.simulate(self.profile.with_physics(phys), self.data.scenes), np.float64)
        self.sim_seconds += time.perf_counter() - t0
        self.n_sim += 1
        self.cache[key] = irr
        while len(self.cache) > self.cache_size:
            self.cache.popitem(last=False)
        return irr

    # ------------------------------------------------------------------ evaluation
    def _in_order(self, values: Values, domain: str) -> list[tuple[Candidate, np.ndarray]]:
        """The ``domain`` effects of ``values`` in their stage order."""
        found = [(CANDIDATES[n], v) for n, v in values.items() if CANDIDATES[n].domain == domain]
        return sorted(found, key=lambda cv: (STAGES.index(cv[0].spec.stage), cv[0].spec.order))

    def basis(self, name: str) -> np.ndarray:
        """``T × R × S`` additive terms of the linear-domain effect ``name``."""
        if name not in self._bases:
            make = CANDIDATES[name].fit.basis
            assert make is not None, f"{name}: a linear-domain effect declares its basis"
            _, r, s, _ = self.data.measured_dn.shape
            self._bases[name] = np.asarray(make(r, s), np.float64)
        return self._bases[name]

    def linear_slices(self, values: Values) -> dict[str, slice]:
        """Where each linear-domain effect's coefficients sit in a row of ``beta``."""
        out: dict[str, slice] = {}
        at = 1
        for cand, _v in self._in_order(values, "linear"):
            t = self.basis(cand.name).shape[0]
            out[cand.name] = slice(at, at + t)
            at += t
        return out

    def _post(self, irr: np.ndarray, values: Values) -> np.ndarray:
        out = irr
        for cand, vec in self._in_order(values, "post"):
            assert cand.spec.forward is not None
            out = cand.spec.forward(out, cand.to_params(vec, self.profile), self.profile)
        return out

    def _dn(self, lin: np.ndarray, values: Values) -> tuple[np.ndarray, np.ndarray]:
        """DN-domain map h(L) and its derivative h'(L) (the DN effects' responses chained)."""
        out = lin.copy()
        der = np.ones_like(lin)
        for cand, vec in self._in_order(values, "dn"):
            respond = cand.fit.dn_response
            assert respond is not None, f"{cand.name}: a DN-domain effect declares dn_response"
            out, d = respond(out, vec, self.profile)
            der = der * d
        return out, der

    def has_dn_effects(self, values: Values) -> bool:
        """True when a DN-domain effect is on (the gains then need Gauss-Newton)."""
        return any(CANDIDATES[n].domain == "dn" for n in values)

    def columns(self, values: Values) -> list[list[np.ndarray]]:
        """Per channel, the ``B`` closed-form columns (gain, linear terms), each ``F × R × S``
        (a linear term's is a broadcast view of its ``R × S`` basis image: at the paper's size
        12 frames of stray light's six terms would be 0.9 GB per channel as copies)."""
        sig = self._post(self.irradiance(values), values)
        f = sig.shape[0]
        extra = [self.basis(c.name) for c, _v in self._in_order(values, "linear")]
        cols = []
        for c in range(sig.shape[3]):
            cc = [sig[..., c]]
            for basis in extra:
                cc += [np.broadcast_to(b[None], (f, *b.shape)) for b in basis]
            cols.append(cc)
        return cols

    def evaluate(self, values: Values, beta: np.ndarray | None = None) -> Evaluation:
        """Predict the recording for ``values``; gains (and stray light) solved unless
        ``beta`` is given."""
        cols = self.columns(values)
        meas = self.data.measured_dn - self.black
        w = self.weights
        n_b = len(cols[0])
        beta_out = np.zeros((len(cols), n_b)) if beta is None else np.array(beta, np.float64)
        lin = np.empty_like(meas)
        for c, bc in enumerate(cols):
            if beta is None:
                beta_out[c] = self._solve_channel(bc, meas[..., c], w[..., c], values)
            lin[..., c] = _combine(beta_out[c], bc)
        out, _ = self._dn(lin, values)
        pred = self.black + out
        chi2 = float(np.sum(w * (self.data.measured_dn - pred) ** 2))
        return Evaluation(pred, chi2, beta_out, lin)

    def _solve_channel(self, cols: list[np.ndarray], meas: np.ndarray, w: np.ndarray,
                       values: Values) -> np.ndarray:
        """Weighted least squares for one channel's coefficients (Gauss-Newton through the
        DN effects), from normal equations summed column pair by column pair (no stacked
        copy of the columns)."""
        a, rhs = _normal_equations(cols, w, w * meas)
        beta = np.linalg.lstsq(a, rhs, rcond=None)[0]
        if not self.has_dn_effects(values):
            return beta
        for _ in range(6):
            out, der = self._dn(_combine(beta, cols), values)
            a, rhs = _normal_equations(cols, w * der * der, w * der * (meas - out))
            step = np.linalg.lstsq(a + 1e-12 * np.eye(len(beta)), rhs, rcond=None)[0]
            beta = beta + step
            if np.all(np.abs(step) <= 1e-7 * (np.abs(beta) + 1e-9)):
                break
        return beta

    def nuisance_directions(self, values: Values, ev: Evaluation) -> list[np.ndarray]:
        """Per channel ``B × F × R × S`` derivatives of the prediction w.r.t. the closed-form
        coefficients (what a score test must project out)."""
        _, der = self._dn(ev.linear_dn, values)
        return [np.stack(bc) * der[None, ..., c] for c, bc in enumerate(self.columns(values))]


def _combine(beta: np.ndarray, cols: list[np.ndarray]) -> np.ndarray:
    """``Σ_b beta[b]·cols[b]`` (``F × R × S``)."""
    out = beta[0] * cols[0]
    for b, col in zip(beta[1:], cols[1:], strict=True):
        out += b * col
    return out


def _normal_equations(cols: list[np.ndarray], weight: np.ndarray, weighted_y: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``A[i, j] = Σ weight·cols[i]·cols[j]`` and ``rhs[i] = Σ weighted_y·cols[i]`` over every
    pixel value, one weighted column in memory at a time."""
    n = len(cols)
    a = np.empty((n, n))
    rhs = np.empty(n)
    for i, ci in enumerate(cols):
        wci = weight * ci
        rhs[i] = float(np.einsum("fij,fij->", weighted_y, ci))
        for j in range(i + 1):
            a[i, j] = a[j, i] = float(np.einsum("fij,fij->", wci, cols[j]))
    return a, rhs


def evaluate_self_weighted(model: DiagnosisModel, values: Values) -> Evaluation:
    """Evaluate with weights taken at the model's own prediction (two passes)."""
    model.set_reference(None)
    ev = model.evaluate(values)
    model.set_reference(ev.pred_dn)
    return model.evaluate(values)


def clip_level_dn(profile: Profile, values: Values) -> float | None:
    """The lowest clip level (absolute DN) an effect of ``values`` declares, if any."""
    levels = [
        clip(v, profile) for n, v in values.items()
        if (clip := CANDIDATES[n].fit.clip_level_dn) is not None
    ]
    return min(levels) if levels else None


def contract_fit(model: DiagnosisModel, pred_dn: np.ndarray, values: Values
                 ) -> tuple[np.ndarray, np.ndarray, FitStats]:
    """``(variance DN², valid mask, statistics)`` of ``pred_dn`` against ``model``'s recording
    as CONTRACTS §6 defines them (noise-model χ², no systematic allowance; saturated and
    clipped pixels left out)."""
    data = model.data
    var = model.variance(pred_dn)
    valid = valid_pixels(data.measured_dn, pred_dn, data.profile.noise, clip_level_dn(data.profile, values))
    return var, valid, fit_stats(data.measured_dn, pred_dn, var, valid)


def full_size_stats(data: DiagnosisData, values: Values, simulate: SimulateFn, sys_frac: float) -> FitStats:
    """CONTRACTS §6 statistics of ``values`` on every frame of ``data`` (gains refitted,
    weights at the model's own prediction; the model is dropped afterwards: one evaluation
    of a whole paper-size recording)."""
    model = DiagnosisModel(data, simulate, default_variance_fn(), sys_frac=sys_frac, cache_size=1)
    return contract_fit(model, evaluate_self_weighted(model, values).pred_dn, values)[2]
