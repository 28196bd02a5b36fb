"""Calibrating the photometric-stereo LUT from ball presses (paper: a 3 mm ball).

Two sources of ground-truth slopes:

* a ball of known radius pressed where the image says (real sensors, recordings): the
  press centre is found in the colour change, the press depth by fitting the slope
  magnitude of the ball's cap smoothed by the elastomer (``tactile.elastomer_sigma_mm``)
  to the colour-change magnitude, then refined once through the LUT (integrate its slopes
  to depth, refit the depth, recalibrate);
* the tactile simulator's own slopes (virtual sensors): the press is commanded, so the
  ground truth is known exactly, elastomer smoothing included.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.special import k0e, k1e

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.tactile.calibration.ball_eval import (
    contact_radius_of_press,
    read_contact_radius_mm,
    rim_circle,
)
from thintact_sdk.tactile.interpretation.colour_change import colour_change, fill_masked
from thintact_sdk.tactile.interpretation.gradient_model import GRADIENT_MODELS
from thintact_sdk.tactile.interpretation.grid import (
    TactileParams,
    bin_image,
    binned_params,
    working_factor,
)
from thintact_sdk.tactile.interpretation.markers import detect_markers
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut
from thintact_sdk.tactile.interpretation.poisson import integrate_gradients
from thintact_sdk.tactile.simulation.elastomer import smoothed_in_frame
from thintact_sdk.tactile.simulation.indenters import Sphere
from thintact_sdk.tactile.simulation.membrane import TactileScene, TactileSimulator

CALIBRATION_BALL_RADIUS_MM = 1.5
MIN_PRESSES_TO_CHOOSE = 12
"""``model="auto"`` compares the table and the network only from this many presses on."""


@dataclass
class BallPress:
    """One calibration press: the image and what is known about its slopes.

    Attributes
    ----------
    image
        ``N × M × 3`` membrane image (reconstructed or simulated), display units.
    grad_x, grad_y
        ``N × M`` known slopes (mm per mm), or None to derive them from the ball model.
    contact_radius_mm
        With known slopes: the press's true contact radius (mm), when known (a simulated
        press), so the calibration can measure how far inside it the contact region reads
        (``meta["contact_rim_mm"]`` of :func:`calibrate_from_presses`).
    """

    image: np.ndarray
    grad_x: np.ndarray | None = None
    grad_y: np.ndarray | None = None
    contact_radius_mm: float | None = None


_EDGE_MARGIN_RADII = 1.5
"""Press centres stay this many ball radii inside the field's edges."""
_DEPTH_RANGE_RADII = (0.2, 2.0 / 3.0)
"""Default press depths as fractions of the ball radius (0.3-1.0 mm for the 1.5 mm ball)."""


def _field_half_mm(params: TactileParams) -> tuple[float, float]:
    """Half width and half height of the membrane field in mm."""
    return (params.cols / 2) * params.mm_per_px, (params.rows / 2) * params.mm_per_px


def ball_radius_for_field(profile: Profile, ball_radius_mm: float = CALIBRATION_BALL_RADIUS_MM) -> float:
    """The calibration ball radius (mm) to simulate on ``profile``: ``ball_radius_mm``, or a
    smaller ball when that one does not fit (centres :data:`_EDGE_MARGIN_RADII` radii inside
    the edges, with room to move: a third of the shorter half side at most)."""
    half_w, half_h = _field_half_mm(TactileSimulator.for_profile(profile).params)
    return min(ball_radius_mm, min(half_w, half_h) / (_EDGE_MARGIN_RADII + 1.5))


def random_ball_presses(
    profile: Profile,
    count: int = 12,
    ball_radius_mm: float | None = None,
    depth_range_mm: tuple[float, float] | None = None,
    seed: int = 0,
) -> list[tuple[TactileScene, dict[str, float]]]:
    """Simulated ball presses at random places and depths inside the field.

    Parameters
    ----------
    ball_radius_mm
        Ball radius in mm; None: the 1.5 mm calibration ball, or a smaller one on a field
        too small for it (:func:`ball_radius_for_field`).
    depth_range_mm
        Press depths drawn uniformly in this range (mm); None: 0.2-0.67 ball radii.

    Returns
    -------
    list of (scene, press)
        ``press`` holds ``x_mm``, ``y_mm``, ``depth_mm``, ``ball_radius_mm``.

    Raises
    ------
    CalibrationError
        An explicit ``ball_radius_mm`` too large for the field (the message gives the
        largest that fits).
    """
    sim = TactileSimulator.for_profile(profile)
    p = sim.params
    radius = ball_radius_for_field(profile) if ball_radius_mm is None else float(ball_radius_mm)
    field_w, field_h = _field_half_mm(p)
    half_w = field_w - _EDGE_MARGIN_RADII * radius
    half_h = field_h - _EDGE_MARGIN_RADII * radius
    if not (radius > 0 and half_w > 0 and half_h > 0):
        largest = min(field_w, field_h) / _EDGE_MARGIN_RADII
        raise CalibrationError(
            f"a ball of radius {radius:g} mm does not fit in the {2 * field_w:.3g} x "
            f"{2 * field_h:.3g} mm field of profile {profile.name!r}; use a ball radius below "
            f"{largest:.3g} mm"
        )
    if depth_range_mm is None:
        depth_range_mm = (_DEPTH_RANGE_RADII[0] * radius, _DEPTH_RANGE_RADII[1] * radius)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        press = {
            "x_mm": float(rng.uniform(-half_w, half_w)),
            "y_mm": float(rng.uniform(-half_h, half_h)),
            "depth_mm": float(rng.uniform(*depth_range_mm)),
            "ball_radius_mm": radius,
        }
        scene = sim.press(Sphere(radius), press["depth_mm"], (press["x_mm"], press["y_mm"]))
        out.append((scene, press))
    return out


def press_contact_radius_mm(press: Mapping[str, float]) -> float:
    """The contact radius (mm) of a press of :func:`random_ball_presses`: ``√(2Rp − p²)``."""
    return contact_radius_of_press(float(press["ball_radius_mm"]), float(press["depth_mm"]))


def ball_slopes(
    shape: tuple[int, int],
    center_rc: tuple[float, float],
    contact_radius_px: float,
    ball_radius_px: float,
    rim_fraction: float = 0.9,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slopes of a ball's cap inside its contact circle.

    Parameters
    ----------
    shape
        ``(N, M)`` image size.
    center_rc
        (row, col) of the circle centre, px.
    contact_radius_px, ball_radius_px
        Contact circle and ball radius, px.
    rim_fraction
        Only pixels within this fraction of ``min(contact, 0.95·ball)`` radius are trusted
        (the rim is blurred by the elastomer and the slope diverges at r → R).

    Returns
    -------
    (grad_x, grad_y, inside)
        ``N × M`` slopes ∂d/∂x, ∂d/∂y (dimensionless) and the trusted-pixel mask.
    """
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    x, y = cc - center_rc[1], rr - center_rc[0]
    r2 = x**2 + y**2
    radius = rim_fraction * min(contact_radius_px, 0.95 * ball_radius_px)
    inside = r2 < radius**2
    root = np.sqrt(np.clip(ball_radius_px**2 - r2, 1e-9, None))
    gx = np.where(inside, -x / root, 0.0)
    gy = np.where(inside, -y / root, 0.0)
    return gx, gy, inside


def find_press_circle(
    change: np.ndarray, marker_mask: np.ndarray | None = None, blur_px: float = 3.0
) -> tuple[tuple[float, float], float]:
    """Locate a ball press in a colour-change image.

    The colour-change magnitude is blurred (a press is a bright ring or disc, background
    clutter is thinner or weaker), its maximum seeds the press, and the region above half
    that maximum connected to it, holes filled, gives the centre (magnitude-weighted
    centroid) and the radius (of the circle with its area). A region cut by the frame's
    edge is only part of the press (its centroid lies inside the frame, its area is short):
    its circle is fitted instead to the region's rim away from the frame's edge
    (:func:`~thintact_sdk.tactile.calibration.ball_eval.rim_circle`; the centre may lie
    outside the frame).

    Parameters
    ----------
    change
        ``N × M × C`` colour minus background (any number of channels C ≥ 1), or ``N × M``
        for a one-channel image.
    marker_mask
        Pixels to ignore (markers).
    blur_px
        Gaussian blur of the magnitude, px.

    Returns
    -------
    ((row, col), radius_px)

    Raises
    ------
    CalibrationError
        When no press stands out.
    """
    from scipy.ndimage import binary_fill_holes, label

    arr = np.asarray(change, np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3 or arr.shape[0] < 3 or arr.shape[1] < 3 or arr.shape[2] < 1:
        raise CalibrationError(
            f"a press image must be N × M or N × M × C, got shape {'×'.join(map(str, arr.shape))}")
    mag = np.linalg.norm(arr, axis=2).astype(np.float32)
    if marker_mask is not None:
        mag = fill_masked(mag, marker_mask, 2.0)
    blurred = cv2.GaussianBlur(mag, (0, 0), blur_px)
    peak = float(blurred.max())
    if peak <= 3.0 * float(np.median(blurred)) or peak < 1e-3:
        raise CalibrationError("no press found in the frame: press the ball into the membrane")
    labels, _ = label(blurred > 0.5 * peak)
    seed = np.unravel_index(int(np.argmax(blurred)), blurred.shape)
    region = binary_fill_holes(labels == labels[seed])
    area = float(region.sum())
    if area < 20:
        raise CalibrationError(f"press too small ({area:.0f} px): press the ball deeper")
    radius = float(np.sqrt(area / np.pi))
    circle = rim_circle(region, radius)
    if circle is not None:
        return circle
    rr, cc = np.nonzero(region)
    w = blurred[rr, cc]
    centre = (float((w * rr).sum() / w.sum()), float((w * cc).sum() / w.sum()))
    return centre, radius


BALL_MODELS = ("auto", "rigid", "sink-in")
"""Ball-press models of :func:`calibrate_from_presses` (``auto``: chosen per sensor)."""
MIN_PRESSES_TO_CHOOSE_BALL = 8
"""``ball_model="auto"`` chooses between the models from this many ball presses on (every
fourth press validates: two at least); below it the rigid cap is kept."""
SKIRT_LENGTHS_RADII = (0.1, 0.2, 0.3, 0.45, 0.65, 0.9)
"""Candidate sink-in decay lengths ``L`` tried by ``ball_model="auto"``, in ball radii."""
_MAX_CONTACT_RADII = 0.95
"""The sink-in model's contact radius stays below this many ball radii (the cap's slope at
the rim, ``a/√(R² − a²)``, is 3 there: steeper than a membrane image resolves)."""
_DEPTH_STEP_MM = 0.025


def _reach_mm(shape: tuple[int, ...], mm_per_px: float) -> float:
    """The diagonal of a ``shape`` frame in mm: no contact circle seen whole is wider."""
    return math.hypot(shape[0], shape[1]) * float(mm_per_px)


@dataclass(frozen=True)
class BallModel:
    """The shape a ball of known radius ``R`` presses into the gel, fitted per press.

    ``kind == "rigid"``: the rigid cap ``d(r) = √(R² − r²) − (R − p)`` for ``r < a``, 0
    outside (``p`` the press depth, the per-press parameter, ``a = √(2Rp − p²)``).

    ``kind == "sink-in"``: the gel outside the contact dips too. Inside the contact radius
    ``a`` the surface is the ball, ``d(r) = s + √(R² − r²) − (R − h)``; outside it is the
    skirt ``d(r) = g·L·K₀(r/L)/K₁(a/L)``, ``K₀``, ``K₁`` the modified Bessel functions of
    the second kind, ``g = a/√(R² − a²)`` the cap's slope at the rim and
    ``s = g·L·K₀(a/L)/K₁(a/L)`` the skirt's depth there, so depth and slope are continuous
    at ``r = a``. The per-press parameter is the cap height ``h`` (``a = √(2Rh − h²)``); the
    press depth is ``h + s``. Form: a thin elastic layer bonded to a rigid base (a gel on
    glass) behaves outside the load as a membrane on an elastic (Winkler–Pasternak)
    foundation, ``∇²d = d/L²``, whose axisymmetric decaying solution is ``K₀(r/L)``: the
    dip falls off as ``e^{−r/L}/√r`` over ``L`` ~ the layer's thickness, where an elastic
    half-space (Hertz) decays as ``1/r``. ``skirt_mm`` is ``L`` in mm (> 0), one value per
    sensor, chosen by :func:`calibrate_from_presses`.

    Both are then smoothed by the elastomer Gaussian (``params.elastomer_sigma_mm``).
    """

    kind: str = "rigid"
    skirt_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("rigid", "sink-in"):
            raise CalibrationError(f"ball model must be 'rigid' or 'sink-in', not {self.kind!r}")
        if self.kind == "sink-in" and not (np.isfinite(self.skirt_mm) and self.skirt_mm > 0):
            raise CalibrationError(
                f"the sink-in model needs a skirt length > 0 mm, got {self.skirt_mm!r}")

    @property
    def label(self) -> str:
        return "rigid" if self.kind == "rigid" else f"sink-in L={self.skirt_mm:.3g} mm"

    def parameters(self, ball_radius_mm: float, reach_mm: float | None = None) -> np.ndarray:
        """The per-press parameter's grid (mm): rigid, press depths up to 0.95 R; sink-in,
        cap heights up to that of a contact radius of :data:`_MAX_CONTACT_RADII` R; and, with
        ``reach_mm`` (the frame's diagonal in mm), no deeper than a cap whose contact circle
        spans it (a deeper press could not be seen whole in any frame that size).

        Raises
        ------
        CalibrationError
            The grid is empty: a ball so large that even a contact spanning the frame is
            shallower than the grid's first press (0.05 mm); the radius is likely wrong.
        """
        r = float(ball_radius_mm)
        top = 0.95 * r if self.kind == "rigid" else r * (1 - np.sqrt(1 - _MAX_CONTACT_RADII**2))
        if reach_mm is not None and reach_mm < r:
            a2 = float(reach_mm) * float(reach_mm)
            top = min(top, a2 / (r + math.sqrt(max(r * r - a2, 0.0))))  # R - √(R² - a²), stably
        if not top >= 0.05:
            frame = f" a contact spanning the whole {reach_mm:.3g} mm frame would be" \
                if reach_mm is not None else " its presses would be"
            raise CalibrationError(
                f"ball radius {r:g} mm:{frame} at most {top:.2g} mm deep, under the 0.05 mm the "
                "fit starts from: check the ball radius (mm)")
        return np.arange(0.05, top + 1e-9, _DEPTH_STEP_MM)

    def rigid_depth(self, dist_mm: np.ndarray, param_mm: float, ball_radius_mm: float
                    ) -> tuple[np.ndarray, float, float]:
        """``(depth, press_mm, contact_radius_mm)`` before the elastomer blur, at the
        distances ``dist_mm`` (mm) from the centre, for the per-press parameter."""
        big_r = float(ball_radius_mm)
        h = min(float(param_mm), big_r)
        a = float(np.sqrt(max(2 * big_r * h - h * h, 0.0)))
        cap = np.sqrt(np.clip(big_r**2 - dist_mm**2, 0.0, None)) - (big_r - h)
        if self.kind == "rigid" or a <= 0:
            return np.clip(cap, 0.0, None), h, a
        length = self.skirt_mm
        g = a / np.sqrt(max(big_r**2 - a * a, 1e-12))
        scale = g * length / float(k1e(a / length))  # K(x) = k·e(x)·e^{−x}: no underflow
        r = np.maximum(dist_mm, a) / length
        skirt = scale * k0e(r) * np.exp(a / length - r)
        sink = float(scale * k0e(a / length))
        return np.where(dist_mm < a, cap + sink, skirt), h + sink, a

    def depth(self, shape: tuple[int, int], center_rc: tuple[float, float], param_mm: float,
              ball_radius_mm: float, params: TactileParams) -> np.ndarray:
        """Model depth (mm, ``N × M``) of one press, smoothed by the elastomer (over the gel
        beyond the frame too: :mod:`~thintact_sdk.tactile.simulation.elastomer`)."""
        def sharp(rr: np.ndarray, cc: np.ndarray) -> np.ndarray:
            dist = np.hypot(rr - center_rc[0], cc - center_rc[1]) * params.mm_per_px
            return self.rigid_depth(dist, param_mm, ball_radius_mm)[0]

        return smoothed_in_frame(sharp, shape, params.elastomer_sigma_mm / params.mm_per_px)

    def as_meta(self) -> dict[str, Any]:
        return {"model": self.kind, "skirt_length_mm": self.skirt_mm}


RIGID = BallModel()


def calibrate_from_presses(
    profile: Profile,
    reference: np.ndarray,
    presses: list[BallPress],
    ball_radius_mm: float = CALIBRATION_BALL_RADIUS_MM,
    bins: int = 32,
    meta: dict[str, Any] | None = None,
    max_work_mm: float = 0.13,
    smooth_px: float = 1.0,
    refine_rounds: int = 1,
    model: str = "lut",
    mlp_steps: int = 1500,
    stage: Callable[[str], None] | None = None,
    ball_model: str | BallModel = "auto",
    cnn_options: Mapping[str, Any] | None = None,
) -> PhotometricLUT:
    """Calibrate a LUT from ball presses against a no-contact reference image.

    Parameters
    ----------
    profile
        The device (scene grid, pixel size, markers).
    reference
        ``N × M × 3`` no-contact image.
    presses
        Press images with known slopes, or without (ball model from the found circle).
    ball_radius_mm
        Radius of the calibration ball (used with the ball model).
    bins
        LUT nodes per colour axis.
    meta
        Extra provenance stored with the LUT.
    max_work_mm, smooth_px
        Work on the grid binned and smoothed as the interpreter does (same defaults).
    refine_rounds
        Ball-model presses only: rounds of self-consistent refinement. Each round integrates
        the current LUT's slopes to depth, fits the press of the ball model to it, and
        recalibrates with that model's slopes over the whole image.
    model
        The gradient model: ``"lut"`` (colour change → slope table), ``"mlp"`` (the per-pixel
        colour + position network of
        :mod:`~thintact_sdk.tactile.interpretation.gradient_model`, the table kept beside
        it), ``"cnn"`` (the convolutional network there, which also reads a pixel's
        surroundings) or ``"auto"``: the three are fitted on all presses but every fourth
        (validation presses) and the one with the lowest slope RMS error on the validation
        presses' trusted pixels is refitted on all presses and stored
        (``meta["gradient_model"]``, figures in ``meta["validation"]``). ``"auto"`` with
        fewer than :data:`MIN_PRESSES_TO_CHOOSE` presses keeps the table (one or two
        validation presses do not tell the models apart; the networks, which also see the
        position, need presses all over the gel).
    mlp_steps
        Training steps of the per-pixel network.
    cnn_options
        Keyword arguments of
        :func:`~thintact_sdk.tactile.interpretation.gradient_model.train_cnn` for the
        convolutional network (``steps``, ``width``, ``dilations``, ...); its defaults
        otherwise.
    stage
        Called with a short message as each stage starts (progress for long runs).
    ball_model
        Ball-model presses only: the shape the ball presses into the gel (:class:`BallModel`):
        ``"rigid"`` (the elastomer-smoothed cap), ``"sink-in"`` or a :class:`BallModel`
        (fixed skirt length), or ``"auto"`` (default): the rigid cap and the sink-in model
        with each skirt length of :data:`SKIRT_LENGTHS_RADII` compete on the calibration
        presses alone: a table calibrated on all presses but every fourth, with each
        candidate, reconstructs the held-out fourth, scored by the annotation-free figures
        of :mod:`~thintact_sdk.tactile.calibration.ball_eval`,
        ``√((sphere/R − 1)² + (contact ratio − 1)²)`` (medians; the contact region not
        grown: the growth, ``meta["contact_rim_mm"]``, is measured on the chosen model
        afterwards); the lowest score wins.
        ``"sink-in"`` chooses the skirt length the same way among the sink-in candidates.
        Fewer than :data:`MIN_PRESSES_TO_CHOOSE_BALL` presses: the rigid cap (``"auto"``)
        or the middle candidate length (``"sink-in"``). Stored as ``meta["ball_model"]``
        (model, skirt length in mm, how chosen, each candidate's figures).

    The result's ``meta["press_report"]`` holds, per ball-model press, the circle found
    (centre px, radius mm), the press depth, contact radius and (sink-in) skirt depth at the
    contact's rim of the model fit the table was calibrated with (mm), and warnings: a
    circle at least as wide as the ball with the rigid model (``radius ≥ ball radius``: the
    ball radius or ``tactile.mm_per_px`` is wrong, or the gel sinks in beyond the contact),
    a fitted press at a bound of the model's range, a press touching the frame's edge; and
    ``contact_rim_mm``, how far inside the model's rim the contact region reads on that
    press (:func:`contact_rim_offset`). Their median (clipped at 0) is
    ``meta["contact_rim_mm"]``, by which the interpreter grows its contact regions.
    """
    say = stage or (lambda _msg: None)
    if model not in GRADIENT_MODELS:
        raise CalibrationError(
            f"gradient model must be one of {', '.join(GRADIENT_MODELS)}, not {model!r}")
    if not isinstance(ball_model, BallModel) and ball_model not in BALL_MODELS:
        raise CalibrationError(
            f"ball model must be one of {', '.join(BALL_MODELS)}, not {ball_model!r}")
    full = TactileParams.from_profile(profile)
    factor = working_factor(full, max_work_mm)
    params = binned_params(full, factor)
    sigma = max(0.5, 0.3 * params.marker_diameter_mm / params.mm_per_px)
    reference = bin_image(reference, factor)
    ref_det = detect_markers(reference, params)
    background = fill_masked(reference, ref_det.mask, sigma)
    feats: list[np.ndarray] = []
    gxs: list[np.ndarray] = []
    gys: list[np.ndarray] = []
    valids: list[np.ndarray] = []
    images: list[np.ndarray] = []
    ball: list[_BallFit] = []
    known_rims: list[float | None] = []
    rng = np.random.default_rng(0)
    say(f"{len(presses)} presses: finding the ball in each")
    for n_press, press in enumerate(presses):
        img = bin_image(press.image, factor)
        det = detect_markers(img, params)
        change = colour_change(img, background, det.mask, sigma, smooth_px)
        if press.grad_x is None or press.grad_y is None:
            try:
                center, radius_px = find_press_circle(change, det.mask)
            except CalibrationError as err:
                raise CalibrationError(f"press {n_press}: {err}") from None
            rr, cc = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
            far = (rr - center[0]) ** 2 + (cc - center[1]) ** 2 > (1.6 * radius_px) ** 2
            flat = far & (rng.random(far.shape) < 0.1)
            valid = ~det.mask & (~far | flat)
            ball.append(_BallFit(n_press, len(feats), center, radius_px, valid))
            gx: np.ndarray = np.zeros(img.shape[:2], np.float32)  # set by the ball model
            gy: np.ndarray = gx
        else:
            gx, gy = bin_image(press.grad_x, factor), bin_image(press.grad_y, factor)
            if smooth_px > 0:  # the slopes the smoothed colours stand for
                gx = cv2.GaussianBlur(gx, (0, 0), smooth_px)
                gy = cv2.GaussianBlur(gy, (0, 0), smooth_px)
            moving = np.hypot(gx, gy) > 1e-3
            valid = (moving | (rng.random(gx.shape) < 0.1)) & ~det.mask
            if press.contact_radius_mm is not None:  # the taught shape is the slopes' own
                depth = np.clip(integrate_gradients(gx, gy, params.mm_per_px), 0.0, None)
                known_rims.append(_rim_offset(depth, float(press.contact_radius_mm), params))
        feats.append(change)
        images.append(background + change)
        gxs.append(gx)
        gys.append(gy)
        valids.append(valid)
    info: dict[str, Any] = {
        "profile": profile.name,
        "profile_hash": profile.content_hash(),
        "presses": len(presses),
        "ball_radius_mm": ball_radius_mm,
        "slopes_from": "ball model" if presses and presses[0].grad_x is None else "simulator",
        "work_mm_per_px": params.mm_per_px,
    }
    info.update(meta or {})
    fitter = _BallFitter(feats, gxs, gys, valids, ball, ball_radius_mm, params, bins,
                         smooth_px, refine_rounds)
    chosen = RIGID
    if ball:
        chosen, choice = _choose_ball_model(fitter, ball_model, say)
        info["ball_model"] = {**chosen.as_meta(), **choice}
        say(f"ball model {chosen.label}: fitting each press")
        fitter.first_fit(chosen, range(len(ball)))
    say("fitting the colour → slope table")
    lut = calibrate_lut(feats, gxs, gys, valids, bins=bins, meta=info)
    for _ in range(refine_rounds if ball else 0):
        say("refining the ball fits through the table")
        fitter.refine(lut, chosen, range(len(ball)))
        lut = calibrate_lut(feats, gxs, gys, valids, bins=bins, meta=info)
        lut.meta["refine_rounds"] = refine_rounds
    if ball:
        report = [fitter.entry(k, chosen) for k in range(len(ball))]
        shape = feats[0].shape[:2]
        rims = [contact_rim_offset(chosen, shape, f.center, f.param_mm, ball_radius_mm, params,
                                   smooth_px) for f in ball]
        for entry, rim in zip(report, rims, strict=True):
            entry["contact_rim_mm"] = None if rim is None else round(rim, 4)
        lut.meta["press_report"] = report
        known_rims += rims
    measured = [r for r in known_rims if r is not None]
    if measured:
        lut.meta["contact_rim_mm"] = round(max(0.0, float(np.median(measured))), 4)
    if model == "lut" or (model == "auto" and len(presses) < MIN_PRESSES_TO_CHOOSE):
        lut.meta["gradient_model"] = "lut"
        return lut
    return _attach_network(lut, model, feats, images, gxs, gys, valids, bins,
                           mlp_steps, dict(cnn_options or {}), say)


def contact_rim_offset(bm: BallModel, shape: tuple[int, int], centre_rc: tuple[float, float],
                       param_mm: float, ball_radius_mm: float, params: TactileParams,
                       smooth_px: float) -> float | None:
    """How far (mm) the contact region reads inside the rim of the shape ``bm`` teaches the
    sensor (:mod:`~thintact_sdk.tactile.interpretation.contact_region`, step 4): the model's
    contact radius minus the radius the contact measure reads on the model's press (after
    the elastomer and the calibration's own ``smooth_px`` smoothing, on ``params``'s grid of
    ``shape``; the rim circle where the frame cuts it). Negative when the measure reads
    outside the rim; None when the press has no contact or the measure finds none.

    The shape the table is taught is this smoothed one, so the reconstruction's rims are
    smoothed as much; the calibration stores the median over its presses as
    ``meta["contact_rim_mm"]`` and the interpreter grows its contact region by it."""
    if not np.isfinite(param_mm):
        return None
    _, _, true_mm = bm.rigid_depth(np.zeros(1), param_mm, ball_radius_mm)
    depth = bm.depth(shape, centre_rc, param_mm, ball_radius_mm, params)
    if smooth_px > 0:
        depth = cv2.GaussianBlur(depth, (0, 0), smooth_px, borderType=cv2.BORDER_REPLICATE)
    return _rim_offset(depth, true_mm, params)


def _rim_offset(depth_mm: np.ndarray, true_radius_mm: float, params: TactileParams
                ) -> float | None:
    """``true_radius_mm`` minus the radius the contact measure reads on ``depth_mm`` (on
    ``params``'s grid; None when either is 0)."""
    mm = params.mm_per_px
    read = read_contact_radius_mm(depth_mm, mm, params.contact_threshold_mm, mm)
    if not (true_radius_mm > 0 and read > 0):
        return None
    return float(true_radius_mm - read)


@dataclass
class _BallFit:
    """A ball-model press of :func:`calibrate_from_presses`: its index among the presses and
    in the feature lists, the circle found (px), the trusted pixels and the current fit."""

    press: int
    slot: int
    center: tuple[float, float]
    radius_px: float
    trusted: np.ndarray
    param_mm: float = float("nan")


class _BallFitter:
    """Fits a :class:`BallModel` to the ball presses and writes its slopes into the target
    lists of :func:`calibrate_from_presses` (in place)."""

    def __init__(self, feats: list[np.ndarray], gxs: list[np.ndarray], gys: list[np.ndarray],
                 valids: list[np.ndarray], ball: list[_BallFit], ball_radius_mm: float,
                 params: TactileParams, bins: int, smooth_px: float, refine_rounds: int) -> None:
        self.feats, self.gxs, self.gys, self.valids, self.ball = feats, gxs, gys, valids, ball
        self.radius, self.params, self.bins = ball_radius_mm, params, bins
        self.smooth_px, self.rounds = smooth_px, refine_rounds

    def _set(self, fit: _BallFit, depth: np.ndarray, valid: np.ndarray) -> None:
        gy, gx = np.gradient(depth, self.params.mm_per_px)
        if self.smooth_px > 0:
            gx = cv2.GaussianBlur(gx.astype(np.float32), (0, 0), self.smooth_px)
            gy = cv2.GaussianBlur(gy.astype(np.float32), (0, 0), self.smooth_px)
        self.gxs[fit.slot], self.gys[fit.slot], self.valids[fit.slot] = gx, gy, valid

    def first_fit(self, bm: BallModel, which: Any) -> None:
        """Fit the model to the colour change of the presses ``which`` (indices of ``ball``)."""
        for k in which:
            fit = self.ball[k]
            fit.param_mm, cap = _fit_model_to_change(
                self.feats[fit.slot], fit.center, fit.radius_px, self.radius, self.params,
                self.smooth_px, bm)
            self._set(fit, cap, fit.trusted)

    def refine(self, lut: PhotometricLUT, bm: BallModel, which: Any) -> None:
        """Refit the model to the depth ``lut`` reconstructs for the presses ``which``."""
        for k in which:
            fit = self.ball[k]
            gx, gy = lut.lookup(self.feats[fit.slot])
            depth = integrate_gradients(gx, gy, self.params.mm_per_px)
            fit.param_mm, refit = _fit_model_to_depth(depth, fit.center, fit.radius_px,
                                                      self.radius, self.params, bm)
            self._set(fit, refit, fit.trusted)

    def calibrate(self, bm: BallModel, which: list[int]) -> PhotometricLUT:
        """A table calibrated on the presses ``which`` only, with ``bm`` (first fit, then the
        refinement rounds)."""
        self.first_fit(bm, which)
        slots = [self.ball[k].slot for k in which]

        def table() -> PhotometricLUT:
            return calibrate_lut([self.feats[s] for s in slots], [self.gxs[s] for s in slots],
                                 [self.gys[s] for s in slots], [self.valids[s] for s in slots],
                                 bins=self.bins)

        lut = table()
        for _ in range(self.rounds):
            self.refine(lut, bm, which)
            lut = table()
        return lut

    def score(self, lut: PhotometricLUT, which: list[int]) -> dict[str, Any]:
        """The figures of the presses ``which`` reconstructed with ``lut`` (as the
        interpreter does: table slopes, free-boundary integration, depth ≥ 0)."""
        from thintact_sdk.tactile.calibration.ball_eval import press_figures, summarise

        figs = []
        for k in which:
            gx, gy = lut.lookup(self.feats[self.ball[k].slot])
            depth = np.clip(integrate_gradients(gx, gy, self.params.mm_per_px), 0.0, None)
            figs.append(press_figures(depth, gx, gy, self.radius, self.params.mm_per_px,
                                      self.params.contact_threshold_mm,
                                      smooth_mm=self.params.mm_per_px))
        s = summarise(figs, self.radius)
        sphere = s["sphere_radius_median_mm"] / self.radius
        contact = s["contact_ratio_median"]
        score = (float(np.hypot(sphere - 1.0, contact - 1.0))
                 if contact is not None and np.isfinite(sphere) else float("inf"))
        return {"sphere_over_radius": round(float(sphere), 4),
                "contact_ratio": None if contact is None else round(float(contact), 4),
                "depth_rms_mm": s["depth_rms_mm"], "slope_rms": s["slope_rms"],
                "score": score}

    def entry(self, k: int, bm: BallModel) -> dict[str, Any]:
        """One press of the calibration report (see :func:`calibrate_from_presses`)."""
        fit = self.ball[k]
        mm = self.params.mm_per_px
        _, press, contact = bm.rigid_depth(np.zeros(1), fit.param_mm, self.radius)
        grid = bm.parameters(self.radius, _reach_mm((self.params.rows, self.params.cols), mm))
        warnings = []
        if bm.kind == "rigid" and fit.radius_px * mm >= self.radius:
            warnings.append(
                f"circle radius {fit.radius_px * mm:.2f} mm >= ball radius {self.radius:g} mm: "
                "not physical for this ball (check --ball-radius-mm and tactile.mm_per_px, or "
                "a gel that sinks in: --ball-model sink-in)")
        if fit.param_mm >= float(grid[-1]) - 1e-9:
            warnings.append(f"press depth at the fit's upper bound ({press:.2f} mm, contact "
                            f"radius {contact:.2f} mm of a {self.radius:g} mm ball)")
        elif fit.param_mm <= float(grid[0]) + 1e-9:
            warnings.append(f"press depth at the fit's lower bound ({press:.2f} mm)")
        rows, cols = self.feats[fit.slot].shape[:2]
        c, r = fit.center, fit.radius_px
        if c[0] - r <= 0 or c[1] - r <= 0 or c[0] + r >= rows - 1 or c[1] + r >= cols - 1:
            warnings.append("the press touches the frame's edge")
        out = {"press": fit.press, "centre_rc": [round(c[0], 2), round(c[1], 2)],
               "circle_radius_mm": round(r * mm, 4), "press_mm": round(press, 4),
               "contact_radius_mm": round(contact, 4)}
        if bm.kind == "sink-in":
            out["sink_in_mm"] = round(press - fit.param_mm, 4)
        out["warnings"] = warnings
        return out


def _choose_ball_model(fitter: _BallFitter, ball_model: str | BallModel,
                       say: Callable[[str], None]) -> tuple[BallModel, dict[str, Any]]:
    """The ball model of :func:`calibrate_from_presses` and how it was chosen."""
    if isinstance(ball_model, BallModel):
        return ball_model, {"chosen_by": "given"}
    if ball_model == "rigid":
        return RIGID, {"chosen_by": "given"}
    lengths = [round(f * fitter.radius, 4) for f in SKIRT_LENGTHS_RADII]
    sink = [BallModel("sink-in", L) for L in lengths]
    n = len(fitter.ball)
    if n < MIN_PRESSES_TO_CHOOSE_BALL:
        default = RIGID if ball_model == "auto" else sink[len(sink) // 2]
        return default, {"chosen_by": f"default (fewer than {MIN_PRESSES_TO_CHOOSE_BALL} presses)"}
    candidates = ([RIGID] if ball_model == "auto" else []) + sink
    val = [k for k in range(n) if k % 4 == 3]
    fit = [k for k in range(n) if k % 4 != 3]
    rows: list[dict[str, Any]] = []
    for bm in candidates:
        say(f"ball model {bm.label}: table on {len(fit)} presses, scored on {len(val)}")
        rows.append({**bm.as_meta(), **fitter.score(fitter.calibrate(bm, fit), val)})
    best = int(np.argmin([r["score"] for r in rows]))
    return candidates[best], {"chosen_by": "validation", "score": rows[best]["score"],
                              "validation_presses": [fitter.ball[k].press for k in val],
                              "candidates": rows}


def _window(dist_mm: np.ndarray, bm: BallModel, param_mm: float, radius_px: float,
            ball_radius_mm: float, params: TactileParams, rims: float, blurs: float
            ) -> np.ndarray:
    """Pixels a fit compares: the rigid cap within ``rims`` contact radii (as before), the
    sink-in model within ``rims`` radii of the circle found in the image (the skirt is where
    the colour changes), plus ``blurs`` elastomer sigmas."""
    if bm.kind == "rigid":
        extent = np.sqrt(max(2 * ball_radius_mm * param_mm - param_mm**2, 1e-6))
    else:
        extent = radius_px * params.mm_per_px
    return dist_mm < rims * extent + blurs * params.elastomer_sigma_mm


def _fit_model_to_change(
    change: np.ndarray, center_rc: tuple[float, float], radius_px: float, ball_radius_mm: float,
    params: TactileParams, smooth_px: float, bm: BallModel,
) -> tuple[float, np.ndarray]:
    """``(parameter_mm, depth)``: the model press whose slope magnitude, times a free scale,
    best matches the colour-change magnitude (for moderate slopes the colour change grows
    about linearly with the slope)."""
    mag = np.linalg.norm(change, axis=2)
    rr, cc = np.mgrid[0 : mag.shape[0], 0 : mag.shape[1]]
    dist_mm = np.hypot(rr - center_rc[0], cc - center_rc[1]) * params.mm_per_px
    best: tuple[float, float, np.ndarray] | None = None
    for press in bm.parameters(ball_radius_mm, _reach_mm(mag.shape, params.mm_per_px)):
        model = bm.depth(mag.shape, center_rc, float(press), ball_radius_mm, params)
        gy, gx = np.gradient(model, params.mm_per_px)
        slope = np.hypot(gx, gy).astype(np.float32)
        if smooth_px > 0:
            slope = cv2.GaussianBlur(slope, (0, 0), smooth_px)
        w = _window(dist_mm, bm, float(press), radius_px, ball_radius_mm, params, 2.0, 3.0)
        ss = float((slope[w] ** 2).sum())
        if ss <= 0:
            continue
        k = float((slope[w] * mag[w]).sum()) / ss
        err = float(((mag[w] - k * slope[w]) ** 2).sum()) / max(int(w.sum()), 1)
        if best is None or err < best[0]:
            best = (err, float(press), model)
    if best is None:
        raise CalibrationError("cannot fit the ball press: press the ball deeper")
    return best[1], best[2]


def _fit_model_to_depth(
    depth_mm: np.ndarray, center_rc: tuple[float, float], radius_px: float,
    ball_radius_mm: float, params: TactileParams, bm: BallModel,
) -> tuple[float, np.ndarray]:
    """``(parameter_mm, depth)``: the model press that best fits ``depth_mm`` (least
    squares within 2.5 contact radii, or circle radii for the sink-in model)."""
    best: tuple[float, float, np.ndarray] | None = None
    rr, cc = np.mgrid[0 : depth_mm.shape[0], 0 : depth_mm.shape[1]]
    dist_mm = np.hypot(rr - center_rc[0], cc - center_rc[1]) * params.mm_per_px
    for press in bm.parameters(ball_radius_mm, _reach_mm(depth_mm.shape, params.mm_per_px)):
        model = bm.depth(depth_mm.shape, center_rc, float(press), ball_radius_mm, params)
        window = _window(dist_mm, bm, float(press), radius_px, ball_radius_mm, params, 2.5, 2.0)
        err = float(np.mean((model[window] - depth_mm[window]) ** 2))
        if best is None or err < best[0]:
            best = (err, float(press), model)
    assert best is not None
    return best[1], best[2]


def _attach_network(
    lut: PhotometricLUT, model: str, feats: list[np.ndarray], images: list[np.ndarray],
    gxs: list[np.ndarray], gys: list[np.ndarray], valids: list[np.ndarray], bins: int,
    mlp_steps: int, cnn_options: dict[str, Any], say: Callable[[str], None],
) -> PhotometricLUT:
    """Fit the network ``model`` (``"mlp"``, ``"cnn"``) on the presses' targets; with
    ``model == "auto"`` first fit the table and both networks on all presses but every
    fourth, compare their slope RMS on the held-out fourth, and keep the best (the table
    when it wins). ``mlp_steps``, ``cnn_options``: as :func:`calibrate_from_presses`."""
    from thintact_sdk.tactile.interpretation.gradient_model import train_cnn, train_mlp

    def pick(seq: list[np.ndarray], idx: list[int]) -> list[np.ndarray]:
        return [seq[i] for i in idx]

    def train(kind: str, idx: list[int], what: str) -> Any:
        args = (pick(feats, idx), pick(images, idx), pick(gxs, idx), pick(gys, idx),
                pick(valids, idx))
        if kind == "mlp":
            say(f"{what}: training the per-pixel network on {len(idx)} presses")
            return train_mlp(*args, steps=mlp_steps)
        say(f"{what}: training the convolutional network on {len(idx)} presses")
        return train_cnn(*args, **cnn_options, progress=lambda d, t: say(
            f"{what}: convolutional network, step {d}/{t}"))

    chosen = model
    if model == "auto":
        val = [i for i in range(len(feats)) if i % 4 == 3]
        fit = [i for i in range(len(feats)) if i % 4 != 3]
        say(f"validation: table and networks fitted on {len(fit)} presses, "
            f"compared on {len(val)}")
        candidates: dict[str, Any] = {
            "lut": calibrate_lut(pick(feats, fit), pick(gxs, fit), pick(gys, fit),
                                 pick(valids, fit), bins=bins)}
        for kind in ("mlp", "cnn"):
            candidates[kind] = train(kind, fit, "validation")
        errors: dict[str, list[np.ndarray]] = {k: [] for k in candidates}
        for i in val:
            m = valids[i]
            for kind, cand in candidates.items():
                ex, ey = (cand.lookup(feats[i]) if kind == "lut"
                          else cand.predict(feats[i], images[i]))
                errors[kind].append(np.hypot(ex - gxs[i], ey - gys[i])[m])
        rms = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in errors.items()}
        lut.meta["validation"] = {"presses": val,
                                  **{f"slope_rms_{k}": v for k, v in rms.items()}}
        chosen = min(rms, key=lambda k: rms[k])  # ties: the table, then the smaller network
        if chosen == "lut":
            lut.meta["gradient_model"] = "lut"
            return lut
    lut.net = train(chosen, list(range(len(feats))), "final")
    lut.meta["gradient_model"] = chosen
    return lut


def smoothed_ball_depth(
    shape: tuple[int, int], center_rc: tuple[float, float], press_mm: float,
    ball_radius_mm: float, params: TactileParams,
) -> np.ndarray:
    """Depth (mm, ``N × M``) of a ball pressed ``press_mm`` at ``center_rc`` (px), smoothed by
    the elastomer Gaussian (``params.elastomer_sigma_mm``), as the tactile simulator does."""
    return RIGID.depth(shape, center_rc, press_mm, ball_radius_mm, params)


def fit_ball_to_change(
    change: np.ndarray, center_rc: tuple[float, float], ball_radius_mm: float,
    params: TactileParams, smooth_px: float = 1.0,
) -> np.ndarray:
    """First estimate of a ball press from the image alone: the smoothed rigid ball cap
    whose slope magnitude, times a free scale, best matches the colour-change magnitude (for
    moderate slopes the colour change grows about linearly with the slope; press depths
    0.05 mm to 0.95 ball radii in 0.025 mm steps).

    Returns
    -------
    numpy.ndarray
        ``N × M`` model depth in mm.
    """
    return _fit_model_to_change(change, center_rc, 0.0, ball_radius_mm, params, smooth_px,
                                RIGID)[1]


def fit_smoothed_ball(
    depth_mm: np.ndarray, center_rc: tuple[float, float], ball_radius_mm: float,
    params: TactileParams,
) -> np.ndarray:
    """The smoothed rigid ball-cap depth map whose press depth best fits ``depth_mm`` (least
    squares within 2.5 contact radii of the centre; press depths 0.05 mm to 0.95 ball radii
    in 0.025 mm steps)."""
    return _fit_model_to_depth(depth_mm, center_rc, 0.0, ball_radius_mm, params, RIGID)[1]


def scene_level_lut(profile: Profile, presses: int = 12, seed: int = 0) -> PhotometricLUT:
    """A LUT calibrated on the tactile simulator's own scenes (no lensless imaging):
    what a virtual sensor uses until ``thintact calibrate-tactile`` stores one."""
    sim = TactileSimulator.for_profile(profile)
    ref = sim.flat().scene
    data = random_ball_presses(profile, presses, seed=seed)
    items = [BallPress(s.scene, s.grad_x, s.grad_y, press_contact_radius_mm(p))
             for s, p in data]
    return calibrate_from_presses(profile, ref, items, meta={"source": "tactile-simulator"})
