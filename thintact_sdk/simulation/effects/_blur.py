"""Gaussian blur of pixel-integrated images (shared by ``scene_blur`` and ``sensor_blur``).

A pixel value is the integral of a continuous image over the pixel's square. Blurring the
continuous image by a Gaussian of σ and integrating again moves, from a uniformly lit pixel 0
into pixel k, the fraction (per axis, σ in pixels, Φ the normal CDF)

    w_k = ∫_{-1/2}^{1/2} [Φ((k + ½ − u)/σ) − Φ((k − ½ − u)/σ)] du = I(k+1) − 2 I(k) + I(k−1),

with I(x) = ∫ Φ(x/σ) dx = σ (t Φ(t) + φ(t)), t = x/σ. Sampling the Gaussian at pixel centres
instead would make a blur well below one pixel vanish (e.g. 3 um on 10 um pixels moves 12 %
of the light into each neighbour, not 0.4 %). Edges are mirrored about the border (scipy's
``reflect``), so a uniform image stays uniform.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from scipy.ndimage import correlate1d
from scipy.special import ndtr


def pixel_gaussian_weights(sigma_px: float) -> np.ndarray:
    """``2h+1`` weights ``w_{-h..h}`` (sum 1) of a Gaussian blur of ``sigma_px`` pixels between
    pixel-integrated values."""
    if sigma_px <= 0:
        return np.ones(1)
    h = int(np.ceil(5.0 * sigma_px)) + 1
    x = np.arange(-h - 1, h + 2, dtype=float)
    t = x / sigma_px
    antiderivative = sigma_px * (t * ndtr(t) + np.exp(-0.5 * t * t) / np.sqrt(2.0 * np.pi))
    w = antiderivative[2:] - 2.0 * antiderivative[1:-1] + antiderivative[:-2]
    return w / w.sum()


def blur_pixels(a: np.ndarray, sigma_px: float, axes: tuple[int, ...]) -> np.ndarray:
    """Blur pixel-integrated array ``a`` along ``axes`` by ``sigma_px`` pixels (mirrored edges)."""
    out = np.asarray(a, float)
    if sigma_px <= 0:
        return out
    w = pixel_gaussian_weights(sigma_px)
    for ax in axes:
        out = correlate1d(out, w, axis=ax, mode="reflect")
    return out


def blur_matrix(n: int, sigma_px: float) -> np.ndarray:
    """``n × n`` matrix B with ``B @ v`` the blur of the length-``n`` pixel vector ``v``."""
    return blur_pixels(np.eye(n), sigma_px, axes=(0,))


def blur_by_um(images: np.ndarray, sigma_um: float, pitch_um: float) -> np.ndarray:
    """Blur ``F × rows × cols × C`` pixel-integrated images by ``sigma_um`` (pixel pitch
    ``pitch_um``); unchanged (same object) for σ ≤ 0."""
    if sigma_um <= 0:
        return images
    return blur_pixels(images, sigma_um / pitch_um, axes=(1, 2))


def plane_blur_hooks(plane: Literal["scene", "sensor"]) -> tuple[Callable[..., np.ndarray], Callable[..., Any]]:
    """``(forward, separable_terms)`` of a Gaussian blur effect with parameter ``sigma_um`` in the
    profile's ``plane``: the scene (blur acts on the scene, right of ``P``/``Q``) or the sensor
    (blur acts on the measurement, left of ``P``/``Q``)."""

    def forward(images: np.ndarray, params: Any, profile: Any) -> np.ndarray:
        return blur_by_um(images, params["sigma_um"], getattr(profile, plane).pixel_pitch_um)

    def terms(params: Any, profile: Any) -> Callable[[np.ndarray, np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
        geometry = getattr(profile, plane)
        s = params["sigma_um"] / geometry.pixel_pitch_um
        rows, cols = blur_matrix(geometry.rows, s), blur_matrix(geometry.cols, s)
        if plane == "scene":
            return lambda p, q: [(p @ rows, q @ cols)]
        return lambda p, q: [(rows @ p, cols @ q)]

    return forward, terms
