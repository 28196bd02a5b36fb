"""First-order solvers shared by the iterative decoders: the power method for the largest
eigenvalue of a symmetric positive semi-definite operator, and Nesterov's accelerated gradient
with a fixed step.

Backend-agnostic: the arrays only need ``+ - *``, ``.sum()`` and a ``sum_squares`` function
(numpy arrays, torch tensors, the decoders' :class:`ArrayBackend` arrays).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np


def largest_eigenvalue(apply_op: Callable[[Any], Any], start: Any, iterations: int,
                       sum_squares: Callable[[Any], Any]) -> float:
    """λ_max of a symmetric PSD operator by the power method (Rayleigh quotient of the last
    normalised iterate), at least 1e-30.

    Parameters
    ----------
    apply_op
        ``x -> A x``.
    start
        Starting vector (any shape ``apply_op`` takes; e.g. seeded Gaussian).
    iterations
        Power iterations.
    sum_squares
        ``x -> Σ x²`` for the array type.
    """
    x, lam = start, 0.0
    for _ in range(iterations):
        x = x / np.sqrt(sum_squares(x))
        y = apply_op(x)
        lam = float((x * y).sum())
        x = y
    return max(lam, 1e-30)


def nesterov(gradient: Callable[[Any], Any], zero: Any, step: float, iterations: int) -> Any:
    """Nesterov's accelerated gradient from ``zero`` with a fixed ``step`` (``1/L``).

    Parameters
    ----------
    gradient
        ``z -> ∇f(z)``.
    zero
        The starting point (all zeros, shaped like the solution).
    step
        Step size, ``1/L`` for an ``L``-smooth objective.
    iterations
        Iterations.

    Returns
    -------
    The last iterate ``x`` (not the extrapolated point).
    """
    x = zero
    z, t = x, 1.0
    for _ in range(iterations):
        x_new = z - step * gradient(z)
        t_new = (1.0 + np.sqrt(1.0 + 4.0 * t * t)) / 2.0
        z = x_new + ((t - 1.0) / t_new) * (x_new - x)
        x, t = x_new, t_new
    return x
