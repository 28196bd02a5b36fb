"""Radiometric factor of the simulator and its low-rank separable expansion.

A Lambertian scene point seen from a sensor point at lateral offset ``(dx, dy)`` (mm)
across a gap ``H`` gives the irradiance factor ``cos^q(theta) / H²`` with
``cos(theta) = H / sqrt(H² + dx² + dy²)`` (``q = 4`` for the baseline, ``4 + p`` with a
pixel angular response ``cos^p``). It is radial, hence not separable, but smooth: on the
rectangle of offsets a device can see it is approximated by a short sum
``Σ_l f_l(dx)·g_l(dy)`` (a skeleton / cross approximation on Chebyshev nodes, truncated
where the singular values drop below ``rel_tol`` of the largest). With refraction the factor
is still radial but has no closed form: :class:`TabulatedRadial` gives it (and its
derivatives) from a spline in ``ρ²`` and the same expansion is built from it.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline


def radial_factor(dx_mm: np.ndarray, dy_mm: np.ndarray, h_mm: float, q: float) -> np.ndarray:
    """``cos^q(theta) / H²`` in 1/mm² for lateral offsets ``dx_mm``, ``dy_mm`` (broadcast)."""
    rho2 = np.asarray(dx_mm) ** 2 + np.asarray(dy_mm) ** 2
    return h_mm ** (q - 2) / (h_mm**2 + rho2) ** (q / 2)


@dataclass(frozen=True)
class TabulatedRadial:
    """A radial function ``F(ρ²)`` given by a cubic spline in ``r2 = ρ²`` (mm²).

    Build with :meth:`from_samples`; the spline's error is of order (step in ρ²)⁴ times the
    fourth derivative (the functions tabulated here are analytic in ``ρ²``).
    """

    spline: CubicSpline

    @classmethod
    def from_samples(cls, rho_mm: np.ndarray, values: np.ndarray) -> TabulatedRadial:
        """From values at ``rho_mm`` (increasing, starting at 0); tabulated in ``ρ²``."""
        return cls(CubicSpline(np.asarray(rho_mm, float) ** 2, np.asarray(values, float)))

    def value(self, r2: np.ndarray) -> np.ndarray:
        """``F(r2)``."""
        return np.asarray(self.spline(r2))

    def d1(self, r2: np.ndarray) -> np.ndarray:
        """``dF/d(ρ²)``."""
        return np.asarray(self.spline(r2, 1))

    def d2(self, r2: np.ndarray) -> np.ndarray:
        """``d²F/d(ρ²)²``."""
        return np.asarray(self.spline(r2, 2))


def _chebyshev_nodes(half_mm: float, n: int) -> np.ndarray:
    k = np.arange(n)
    return half_mm * np.cos(np.pi * (k + 0.5) / n)


MEMO_BYTES = 64 * 1024**2
"""Largest total size of the factor values one expansion keeps for reuse."""


@dataclass
class SeparableExpansion:
    """``radial_factor(dx, dy) ≈ Σ_l fx(dx)[l] · gy(dy)[l]`` on ``|dx| ≤ half_x``, ``|dy| ≤ half_y``.

    Build with :meth:`build`; evaluate the factors with :meth:`fx` and :meth:`gy`
    (and their derivatives, used for the first-order correction inside a pixel pair).
    """

    h_mm: float
    q: float
    x_nodes: np.ndarray
    y_nodes: np.ndarray
    left: np.ndarray  # (n_y, L): multiplies radial_factor(dx, y_nodes)
    right: np.ndarray  # (n_x, L): multiplies radial_factor(x_nodes, dy)
    rel_error: float
    radial: TabulatedRadial | None = None
    #: ``_derivs`` results by (axis, offsets): kernels of one device evaluate the factors at
    #: the same pixel-pair offsets again and again (every trial of a diagnosis)
    _memo: dict[tuple[bool, tuple[int, ...], bytes], tuple[np.ndarray, np.ndarray, np.ndarray]] \
        = field(default_factory=dict, repr=False, compare=False)
    #: kernel builds evaluate both axes on separate threads (``imaging/build_threads.py``)
    _memo_lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    @classmethod
    def build(
        cls, h_mm: float, q: float, half_x_mm: float, half_y_mm: float,
        rel_tol: float = 1e-7, n_nodes: int = 96, radial: TabulatedRadial | None = None,
    ) -> SeparableExpansion:
        """Expansion of ``cos^q/H²`` (or of ``radial`` when given) over offsets up to
        ``half_x_mm``, ``half_y_mm`` (mm)."""
        xn = _chebyshev_nodes(max(half_x_mm, 1e-6) * 1.02, n_nodes)
        yn = _chebyshev_nodes(max(half_y_mm, 1e-6) * 1.02, n_nodes)

        def factor(dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
            if radial is None:
                return radial_factor(dx, dy, h_mm, q)
            return radial.value(dx**2 + dy**2)

        kmat = factor(xn[:, None], yn[None, :])
        u, s, vt = np.linalg.svd(kmat)
        rank = int(np.sum(s > rel_tol * s[0]))
        rank = max(rank, 1)
        inv_sqrt = 1.0 / np.sqrt(s[:rank])
        left = vt[:rank].T * inv_sqrt  # (n_y, L)
        right = u[:, :rank] * inv_sqrt  # (n_x, L)
        exp = cls(h_mm, q, xn, yn, left, right, 0.0, radial)
        # measured error on an off-node test grid
        tx = np.linspace(-xn.max(), xn.max(), 61)
        ty = np.linspace(-yn.max(), yn.max(), 53)
        approx = exp.fx(tx) @ exp.gy(ty).T
        exact = factor(tx[:, None], ty[None, :])
        exp.rel_error = float(np.max(np.abs(approx - exact)) / np.max(exact))
        return exp

    @property
    def rank(self) -> int:
        """Number of separable terms L."""
        return int(self.left.shape[1])

    def fx(self, dx_mm: np.ndarray) -> np.ndarray:
        """``(..., L)`` x-factors at offsets ``dx_mm`` (any shape)."""
        return self._derivs(np.asarray(dx_mm, float), self.y_nodes, self.left)[0]

    def gy(self, dy_mm: np.ndarray) -> np.ndarray:
        """``(..., L)`` y-factors at offsets ``dy_mm`` (any shape)."""
        return self._derivs(np.asarray(dy_mm, float), self.x_nodes, self.right)[0]

    def fx_derivs(self, dx_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(f, f', f'')`` of the x-factors at ``dx_mm``, each ``(..., L)`` (analytic)."""
        return self._derivs(np.asarray(dx_mm, float), self.y_nodes, self.left)

    def gy_derivs(self, dy_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(g, g', g'')`` of the y-factors at ``dy_mm``, each ``(..., L)`` (analytic)."""
        return self._derivs(np.asarray(dy_mm, float), self.x_nodes, self.right)

    def _derivs(self, t: np.ndarray, nodes: np.ndarray, weights: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Memoised :meth:`_evaluate` (read-only results, at most :data:`MEMO_BYTES`)."""
        key = (weights is self.left, t.shape, np.ascontiguousarray(t).tobytes())
        with self._memo_lock:
            hit = self._memo.get(key)
        if hit is not None:
            return hit
        out = self._evaluate(t, nodes, weights)
        for a in out:
            a.setflags(write=False)
        size = sum(a.nbytes for a in out)
        if size <= MEMO_BYTES:
            with self._memo_lock:
                held = sum(a.nbytes for v in self._memo.values() for a in v)
                while self._memo and held + size > MEMO_BYTES:
                    old = self._memo.pop(next(iter(self._memo)))
                    held -= sum(a.nbytes for a in old)
                self._memo[key] = out
        return out

    def _evaluate(self, t: np.ndarray, nodes: np.ndarray, weights: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        flat = t.ravel()
        # pixel-pair offsets repeat a lot on regular grids: evaluate each value once
        uniq, inverse = np.unique(np.round(flat, 12), return_inverse=True)
        if uniq.size < 0.8 * flat.size:
            f, df, d2f = self._derivs_flat(uniq, nodes, weights)
            shape = t.shape + (weights.shape[1],)
            return (f[inverse].reshape(shape), df[inverse].reshape(shape),
                    d2f[inverse].reshape(shape))
        f, df, d2f = self._derivs_flat(flat, nodes, weights)
        shape = t.shape + (weights.shape[1],)
        return f.reshape(shape), df.reshape(shape), d2f.reshape(shape)

    def _derivs_flat(self, t: np.ndarray, nodes: np.ndarray, weights: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        q, h = self.q, self.h_mm
        tt = t[:, None]
        if self.radial is not None:
            r2 = tt**2 + nodes**2
            f1 = self.radial.d1(r2)
            k = self.radial.value(r2)
            dk = 2 * tt * f1
            d2k = 2 * f1 + 4 * tt**2 * self.radial.d2(r2)
            return k @ weights, dk @ weights, d2k @ weights
        inv = 1.0 / (h**2 + tt**2 + nodes**2)
        half_q = q / 2
        k = inv * inv if half_q == 2.0 else inv**half_q
        k *= h ** (q - 2)
        dk = -q * tt * k * inv
        d2k = -q * k * inv + q * (q + 2) * tt**2 * k * inv**2
        return k @ weights, dk @ weights, d2k @ weights
