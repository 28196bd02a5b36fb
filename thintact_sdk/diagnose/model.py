"""The forward model the diagnosis fits: simulator + post effects + gains + DN effects.

Prediction of one frame (all arrays ``F × R × S × C``)::

    A   = simulator irradiance with the optical effects          (arbitrary units)
    A'  = crosstalk(A) + glare·mean(A)                            (post effects)
    L_c = g_c·A'_c + stray_c(x, y)                                (DN, linear; g_c free)
    DN  = black + min(FS·(L/FS)^gamma, level − black)             (DN effects)

The per-channel gains ``g_c`` (and the stray-light polynomial when that effect is on)
are solved in closed form (weighted least squares, Gauss-Newton when gamma ≠ 1) at every
evaluation: they are nuisances, never findings.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.diagnose.candidates import CANDIDATES, STRAY_TERMS, crosstalk_matrix
from thintact_sdk.diagnose.data import DiagnosisData
from thintact_sdk.diagnose.stats import VarianceFn
from thintact_sdk.profile import Profile

#: simulate(profile_with_physics, scenes F×N×M×C) -> irradiance F×R×S×C
SimulateFn = Callable[[Profile, np.ndarray], np.ndarray]
Values = dict[str, np.ndarray]


def default_simulate(profile: Profile, scenes: np.ndarray) -> np.ndarray:
    """Noiseless irradiance of every scene from the project's simulator."""
    from thintact_sdk.imaging.simulator import Simulator

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
        ``C × B`` closed-form coefficients (gain first, then stray-light terms), per channel.
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
    """

    def __init__(
        self,
        data: DiagnosisData,
        simulate: SimulateFn,
        variance_fn: VarianceFn,
        sys_frac: float = 1e-3,
        exclude: np.ndarray | None = None,
        cache_size: int = 24,
    ) -> None:
        self.data = data
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
        f, r, s, c = m.shape
        y = np.linspace(-1.0, 1.0, r)[:, None] * np.ones((1, s))
        x = np.ones((r, 1)) * np.linspace(-1.0, 1.0, s)[None, :]
        self.stray_basis = np.stack([x**a * y**b for a, b in STRAY_TERMS])  # T × R × S
        self.base_physics = dict(self.profile.physics)
        self.weights = np.zeros_like(m)
        self.set_reference(None)

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
        phys = {k: v for k, v in self.base_physics.items() if k not in CANDIDATES or CANDIDATES[k].domain == "optical"}
        for name, vec in values.items():
            cand = CANDIDATES[name]
            if cand.domain == "optical":
                phys[name] = cand.to_params(vec, self.profile)
        return phys

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
    def _post(self, irr: np.ndarray, values: Values) -> np.ndarray:
        out = irr
        if "color_crosstalk" in values and out.shape[3] == 3:
            out = np.einsum("ck,frsk->frsc", crosstalk_matrix(values["color_crosstalk"]), out)
        if "veiling_glare" in values:
            out = out + float(values["veiling_glare"][0]) * out.mean(axis=(1, 2), keepdims=True)
        return out

    def _dn(self, lin: np.ndarray, values: Values) -> tuple[np.ndarray, np.ndarray]:
        """DN-domain map h(L) and its derivative h'(L)."""
        fs = self.full_scale
        if "sensor_gamma" in values:
            g = float(values["sensor_gamma"][0])
            lp = np.maximum(lin, 1e-6 * fs)
            out = fs * (lp / fs) ** g
            der = g * out / lp
        else:
            out = lin.copy()
            der = np.ones_like(lin)
        if "saturation" in values:
            lev = float(values["saturation"][0]) - self.black
            clip = out >= lev
            out = np.where(clip, lev, out)
            der = np.where(clip, 0.0, der)
        return out, der

    def columns(self, values: Values) -> list[np.ndarray]:
        """Per channel, the ``B × F × R × S`` closed-form columns (gain, stray terms)."""
        sig = self._post(self.irradiance(values), values)
        f = sig.shape[0]
        cols = []
        for c in range(sig.shape[3]):
            cc = [sig[..., c]]
            if "stray_light" in values:
                cc += [np.broadcast_to(b[None], (f, *b.shape)) for b in self.stray_basis]
            cols.append(np.stack(cc))
        return cols

    def evaluate(self, values: Values, beta: np.ndarray | None = None) -> Evaluation:
        """Predict the recording for ``values``; gains (and stray light) solved unless
        ``beta`` is given."""
        cols = self.columns(values)
        meas = self.data.measured_dn - self.black
        w = self.weights
        n_b = cols[0].shape[0]
        beta_out = np.zeros((len(cols), n_b)) if beta is None else np.array(beta, np.float64)
        lin = np.empty_like(meas)
        for c, bc in enumerate(cols):
            if beta is None:
                beta_out[c] = self._solve_channel(bc, meas[..., c], w[..., c], values)
            lin[..., c] = np.tensordot(beta_out[c], bc, axes=1)
        out, _ = self._dn(lin, values)
        pred = self.black + out
        chi2 = float(np.sum(w * (self.data.measured_dn - pred) ** 2))
        return Evaluation(pred, chi2, beta_out, lin)

    def _solve_channel(self, cols: np.ndarray, meas: np.ndarray, w: np.ndarray, values: Values) -> np.ndarray:
        b = cols.reshape(cols.shape[0], -1)
        wv = w.ravel()
        y = meas.ravel()
        a = (b * wv) @ b.T
        beta = np.linalg.lstsq(a, (b * wv) @ y, rcond=None)[0]
        if "sensor_gamma" not in values and "saturation" not in values:
            return beta
        for _ in range(6):
            lin = beta @ b
            out, der = self._dn(lin, values)
            jac = b * der
            a = (jac * wv) @ jac.T
            step = np.linalg.lstsq(a + 1e-12 * np.eye(len(beta)), (jac * wv) @ (y - out), rcond=None)[0]
            beta = beta + step
            if np.all(np.abs(step) <= 1e-7 * (np.abs(beta) + 1e-9)):
                break
        return beta

    def nuisance_directions(self, values: Values, ev: Evaluation) -> list[np.ndarray]:
        """Per channel ``B × F × R × S`` derivatives of the prediction w.r.t. the closed-form
        coefficients (what a score test must project out)."""
        _, der = self._dn(ev.linear_dn, values)
        return [bc * der[None, ..., c] for c, bc in enumerate(self.columns(values))]
