"""The white frame is the sum of the slits: dark level and per-frame gains from that rule.

Light from a linear display adds up: the all-white scene is the sum of all row slits, and of
all column slits. With every scene row (column) shown once as a full-brightness slit:

- **dark level without a dark frame**: each raw frame is ``signal + dark``, so
  ``Σ_i Y_hi − Y_white = (N − 1)·dark`` pixel by pixel (and ``M − 1`` for columns): the
  level that must be subtracted (black level, stray light, LCD glow) is measured, not
  assumed;
- **per-frame gains** (exposure or brightness changes that the recording does not record):
  ``Y_white ≈ Σ_i x_i Y_hi`` with ``x_i = g_white / g_i``; the ``x`` are the least-squares
  solution, computed from the compressed slits (Gram matrix of ``n × n`` inner products).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thintact_sdk.calibration.classify import ChannelRole, classify_scene
from thintact_sdk.calibration.slits import SlitStack
from thintact_sdk.formats.recording import Recording

UNIT_TOL = 1e-4
GAIN_IMPROVEMENT = 0.5
"""``auto`` applies the gains when they remove at least this share of the white-fit residual."""


def _unit(role: ChannelRole) -> bool:
    return role.profile is not None and bool(np.all(np.abs(role.profile - 1.0) <= UNIT_TOL))


def unit_slit_frames(roles: dict[int, list[ChannelRole]], kind: str, count: int) -> list[int] | None:
    """Frames that light every scene row (``hslit``) or column (``vslit``) exactly once at 1.0
    in every channel, ordered by row/column; None when the set is incomplete or mixed."""
    by_index: dict[int, list[int]] = {}
    for i, r in roles.items():
        if all(x.kind == kind and _unit(x) for x in r) and len({x.index for x in r}) == 1:
            by_index.setdefault(r[0].index, []).append(i)
    if sorted(by_index) != list(range(count)) or any(len(v) != 1 for v in by_index.values()):
        return None
    return [by_index[k][0] for k in range(count)]


def find_white(recording: Recording, candidates: list[int]) -> int | None:
    """The first frame among ``candidates`` whose scene is 1.0 everywhere."""
    for i in candidates:
        scene = recording.scene(i)
        if scene is not None and bool(np.all(np.abs(scene - 1.0) <= UNIT_TOL)):
            return i
    return None


def _raw(recording: Recording, i: int) -> np.ndarray:
    m = np.asarray(recording.measurement(i), np.float64)
    return m if m.ndim == 3 else m[..., None]


def dark_from_white(recording: Recording, white: int, slit_sets: list[list[int]]) -> np.ndarray:
    """``(Σ_i Y_i − Y_white) / (n − 1)`` averaged over the complete slit sets (``R × S × C`` DN)."""
    y_white = _raw(recording, white)
    total = np.zeros_like(y_white)
    weight = 0
    for frames in slit_sets:
        acc = np.zeros_like(y_white)
        for i in frames:
            acc += _raw(recording, i)
        total += acc - y_white
        weight += len(frames) - 1
    return total / weight


@dataclass
class GainFit:
    """Per-frame gain correction of one orientation.

    Attributes
    ----------
    factors
        ``(n,)`` multiplier of each slit (by stack position): nominal gain / frame gain, the
        nominal gain being the slits' geometric mean.
    improvement
        Share of the white-fit residual removed by the factors (0..1).
    """

    factors: np.ndarray
    improvement: float


def fit_white_gains(stacks: list[SlitStack], whites: list[np.ndarray]) -> GainFit:
    """Least-squares ``x`` with ``white_c ≈ Σ_i x_i Y_ci`` over all channels ``c``.

    Parameters
    ----------
    stacks
        One stack per channel, same slits in the same order (complete unit slit sets).
    whites
        Per channel the white frame's signal, oriented like the stack's images (``A × B``).
    """
    n = stacks[0].count
    gram = np.zeros((n, n))
    rhs = np.zeros(n)
    energy = 0.0
    for st, w in zip(stacks, whites, strict=True):
        k = st.left.shape[2]
        # ⟨Y_i, Y_j⟩ = Σ_kl (L_iᵀL_j)_kl (R_iᵀR_j)_kl, both Gram matrices by one BLAS product each
        lf = st.left.transpose(0, 2, 1).reshape(n * k, -1)
        rf = st.right.transpose(0, 2, 1).reshape(n * k, -1)
        ll = (lf @ lf.T).reshape(n, k, n, k)
        rr = (rf @ rf.T).reshape(n, k, n, k)
        gram += np.einsum("ikjl,ikjl->ij", ll, rr)
        wr = np.matmul(w, st.right)  # n × A × k
        rhs += np.einsum("iak,iak->i", st.left, wr)
        energy += float(np.sum(w * w))
    ridge = 1e-6 * np.trace(gram) / n
    x = np.linalg.solve(gram + ridge * np.eye(n), rhs + ridge)
    ones = np.ones(n)

    def resid(v: np.ndarray) -> float:
        return float(energy - 2.0 * rhs @ v + v @ gram @ v)

    r1, rx = resid(ones), resid(x)
    if np.any(x <= 0):
        return GainFit(ones, 0.0)
    # the white frame's own gain is no better a reference than any other frame's: keep the
    # slits' geometric-mean gain (the nominal exposure) as the reference
    x = x / float(np.exp(np.mean(np.log(x))))
    return GainFit(x, (r1 - rx) / r1 if r1 > 0 else 0.0)


def apply_gains(stack: SlitStack, factors: np.ndarray) -> None:
    """Scale slit ``i`` of ``stack`` (by position) by ``factors[i]`` in place."""
    stack.left *= factors[:, None, None]
    stack.energy *= factors**2


def roles_of(recording: Recording, frames: list[int]) -> dict[int, list[ChannelRole]]:
    """Scene roles of ``frames`` (convenience for tests)."""
    out = {}
    for i in frames:
        scene = recording.scene(i)
        if scene is not None:
            out[i] = classify_scene(scene)
    return out
