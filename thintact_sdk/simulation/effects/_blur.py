"""Gaussian blurs between pixel values (shared by ``scene_blur`` and ``sensor_blur``).

A pixel value is the integral of a continuous image over the pixel's square; the two planes
discretise a Gaussian blur of that image differently because their images differ:

* **scene** (``convention="integrated"``): a display is piecewise constant over its pixels. Blurring
  that image by a Gaussian of σ and integrating again moves, from pixel 0 into pixel k, the
  fraction (per axis, σ in pixels, Φ the normal CDF)

      w_k = ∫_{-1/2}^{1/2} [Φ((k + ½ − u)/σ) − Φ((k − ½ − u)/σ)] du = I(k+1) − 2 I(k) + I(k−1),

  with I(x) = ∫ Φ(x/σ) dx = σ (t Φ(t) + φ(t)), t = x/σ (exact for a piecewise-constant image).
* **sensor** (``convention="sampled"``): the irradiance on the sensor is smooth across a pixel
  (mask shadows blurred by the scene pixels' extent), so the pixel values are samples of the
  box-filtered irradiance J at the pixel centres, and the blurred pixel value
  ``(G ∗ J)(x_k)`` is, by the midpoint rule, ``Σ_j G((k − j)·pitch)·J_j``: the Gaussian
  sampled at the pixel offsets, normalised. Integrating the Gaussian over the pixels as
  well would filter by the pixel's box twice. This is also the convention of the independent
  renderer the diagnosis is tested against: a 4 um blur sampled on 10 um pixels moves 4.04 %
  of a pixel's light into each neighbour, which the integrated kernel moves at σ = 1.0 um (so
  that kernel read a 4 um blur as 1.0 um). A sampled blur well below a pixel moves almost
  nothing (3 um on 10 um pixels: 0.4 % into each neighbour): such a blur does not show in
  pixel values by this convention.

Edges are mirrored about the border (scipy's ``reflect``), so a uniform image stays uniform.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

import numpy as np
from scipy.ndimage import correlate1d
from scipy.special import ndtr

#: how a plane's Gaussian is discretised between pixel values (module docstring)
Convention = Literal["integrated", "sampled"]

#: the plane each effect blurs and its convention
PLANE_CONVENTION: dict[str, Convention] = {"scene": "integrated", "sensor": "sampled"}


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


def sampled_gaussian_weights(sigma_px: float) -> np.ndarray:
    """``2h+1`` weights ``w_{-h..h}`` (sum 1): the Gaussian of ``sigma_px`` pixels sampled at the
    integer offsets (``h = ⌈5σ⌉``, beyond which the weights are below 4e-6 of the centre's)."""
    if sigma_px <= 0:
        return np.ones(1)
    h = max(int(np.ceil(5.0 * sigma_px)), 1)
    x = np.arange(-h, h + 1, dtype=float)
    w = np.exp(-0.5 * (x / sigma_px) ** 2)
    return w / w.sum()


def block_weights(fine: np.ndarray, block: int) -> np.ndarray:
    """Weights between ``block``-pixel block means of a blur whose weights between the pixels
    are ``fine`` (``2h+1``, centred): from block 0 into block K,
    ``w_K = (1/b) Σ_{t=−(b−1)}^{b−1} (b − |t|) fine(K·b + t)`` (every pixel pair of the two
    blocks; exact for a signal uniform within each block, as block means assume)."""
    if block <= 1:
        return fine
    h = fine.size // 2
    big = -(-(h + block - 1) // block)  # blocks reached
    t = np.arange(-(block - 1), block)
    tri = (block - np.abs(t)) / block
    w = np.zeros(2 * big + 1)
    for i, k in enumerate(range(-big, big + 1)):
        d = k * block + t
        inside = np.abs(d) <= h
        w[i] = float(np.sum(tri[inside] * fine[d[inside] + h]))
    return w / w.sum()


def gaussian_weights(sigma_px: float, convention: Convention, block: int = 1) -> np.ndarray:
    """The weights of ``convention`` (:func:`pixel_gaussian_weights` for ``"integrated"``,
    :func:`sampled_gaussian_weights` for ``"sampled"``); with ``block`` > 1 the array's pixels
    are ``block``-pixel means of the pixels the convention is defined on (a diagnosis's binned
    copy; ``sigma_px`` in those pixels): the sampled weights are taken on the fine pixels and
    summed over the blocks (:func:`block_weights`)."""
    if convention == "integrated":
        return pixel_gaussian_weights(sigma_px)
    if convention == "sampled":
        return block_weights(sampled_gaussian_weights(sigma_px * block), block)
    raise ValueError(f"unknown blur convention {convention!r}")


def blur_pixels(a: np.ndarray, sigma_px: float, axes: tuple[int, ...],
                convention: Convention = "integrated", block: int = 1) -> np.ndarray:
    """Blur pixel array ``a`` along ``axes`` by ``sigma_px`` pixels (mirrored edges), with the
    weights of ``convention`` (``block``: :func:`gaussian_weights`)."""
    out = np.asarray(a, float)
    if sigma_px <= 0:
        return out
    w = gaussian_weights(sigma_px, convention, block)
    for ax in axes:
        out = correlate1d(out, w, axis=ax, mode="reflect")
    return out


def blur_matrix(n: int, sigma_px: float, convention: Convention = "integrated",
                block: int = 1) -> np.ndarray:
    """``n × n`` matrix B with ``B @ v`` the blur of the length-``n`` pixel vector ``v``."""
    return blur_pixels(np.eye(n), sigma_px, (0,), convention, block)


def blur_by_um(images: np.ndarray, sigma_um: float, pitch_um: float,
               convention: Convention = "integrated", block: int = 1) -> np.ndarray:
    """Blur ``F × rows × cols × C`` pixel images by ``sigma_um`` (pixel pitch ``pitch_um``)
    with the weights of ``convention`` (``block``: :func:`gaussian_weights`); unchanged (same
    object) for σ ≤ 0."""
    if sigma_um <= 0:
        return images
    return blur_pixels(images, sigma_um / pitch_um, (1, 2), convention, block)


def block_pixels(geometry: Any) -> int:
    """How many of the recording's pixels a side of this sensor's pixel spans: the
    ``block_pixels`` a diagnosis's binned copy of a profile declares (1 otherwise)."""
    return int(getattr(geometry, "block_pixels", None) or 1)


def plane_blur_hooks(plane: Literal["scene", "sensor"]) -> tuple[Callable[..., np.ndarray], Callable[..., Any]]:
    """``(forward, separable_terms)`` of a Gaussian blur effect with parameter ``sigma_um`` in the
    profile's ``plane``: the scene (blur acts on the scene, right of ``P``/``Q``) or the sensor
    (blur acts on the measurement, left of ``P``/``Q``), discretised by the plane's
    :data:`PLANE_CONVENTION`."""
    convention = PLANE_CONVENTION[plane]

    def forward(images: np.ndarray, params: Any, profile: Any) -> np.ndarray:
        geometry = getattr(profile, plane)
        return blur_by_um(images, params["sigma_um"], geometry.pixel_pitch_um, convention,
                          block_pixels(geometry))

    def terms(params: Any, profile: Any) -> Callable[[np.ndarray, np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
        geometry = getattr(profile, plane)
        s = params["sigma_um"] / geometry.pixel_pitch_um
        b = block_pixels(geometry)
        rows, cols = blur_matrix(geometry.rows, s, convention, b), blur_matrix(geometry.cols, s, convention, b)
        if plane == "scene":
            return lambda p, q: [(p @ rows, q @ cols)]
        return lambda p, q: [(rows @ p, cols @ q)]

    return forward, terms
