"""Direct generation of the T2S system matrices from the mask vector φ (paper §III-C-2).

The paper builds ``Pc`` (and ``Qc``) by an affine map of φ: along the centre line of the
striped area (scene point straight above the sensor pixel) the slope is
``k_c = δ_scene / δ_sensor``; the stripes (loci of one mask cell) run with slope
``k_stripe = −d·δ_scene / (z·δ_sensor)``; along the centre line the matrix reads an
effective length ``l_mask = R·δ_sensor`` of the vector; and the striped area fades out at
its boundary, approximated with a sigmoid of width ``d_stripe``.

This module derives exactly that picture from the ray geometry of CONTRACTS §4, one axis
at a time. The ray from scene coordinate ``y_n`` to sensor coordinate ``y_r`` crosses the
mask at ``m = (z·y_r + d·y_n) / H``: an affine function of the two indices whose level
lines are the stripes (slope ``k_stripe``) and whose diagonal ``y_r = y_n`` is the centre
line (slope ``k_c``). Each matrix entry averages φ over the mask footprint of the sensor
pixel (width ``z·p/H``) and the scene pixel (width ``d·q/H``), a trapezoid, exactly; cells
outside the K-cell mask read 0 (closed). The fade is the paper's sigmoid of the offset
``|y_r − y_n|`` in sensor pixels with full width at half maximum ``d_stripe_px``.

Units: the returned matrices are relative irradiance per display unit per scene pixel,
scaled so that a white scene (all ones) seen through a fully open mask gives 1 at the
sensor centre, i.e. ``2·(Po·1)[centre]·(Qo·1)[centre] = 1``; multiply by the white level
in DN to obtain DN above black. ``Po X Qoᵀ + Pc X Qcᵀ`` is then the measurement through
the mask ``M = (1·1ᵀ + φ_rows φᵀ)/2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from thintact_sdk.errors import InvalidShapeError, InvalidValueError
from thintact_sdk.formats.profiles import Profile

#: Line-source falloff of the baseline physics, (1 + (Δ/H)²)^(-3/2), has its half maximum
#: at Δ = 0.766·H; the stripe FWHM for d_stripe_scale = 1 is therefore 2·0.766·H.
_HALF_MAX_OVER_H = math.sqrt(2.0 ** (2.0 / 3.0) - 1.0)

#: Default multiplier of the physical FWHM and softness of the sigmoid (its scale parameter as
#: a fraction of d_stripe), tuned jointly against the exact baseline physics (CONTRACTS §4):
#: the relative Frobenius difference of the T2S operator from the simulator's best two-term
#: fit (after one scale) is 1.5 % (golden-mini), 3.0 % (golden-wide) and 4.7 %
#: (virtual-finger), and the golden baseline irradiance is reproduced to 0.28 % (mini) and
#: 0.47 % (wide) relative RMS after one gain per channel; see docs/masks.md.
DEFAULT_D_STRIPE_SCALE = 0.78
SIGMOID_SOFTNESS = 0.28

#: Step (um) of the table of the footprint-averaged pattern behind
#: :meth:`DirectGenerator.uniform_scene_profiles`.
PROFILE_TABLE_STEP_UM = 0.05

#: Shifts × sensor pixels × scene pixels gathered at once by ``uniform_scene_profiles``.
_PROFILE_CHUNK_ELEMENTS = 4_000_000


@dataclass(frozen=True)
class StripeParameters:
    """The paper's parameters of the striped area of one system matrix.

    Attributes
    ----------
    k_c
        Slope of the centre line, sensor rows per scene row (``δ_scene / δ_sensor``).
    k_stripe
        Slope of the stripes, sensor rows per scene row (``−d·δ_scene / (z·δ_sensor)``).
    l_mask_um
        Effective length of φ read along the centre line, um (``R·δ_sensor``).
    d_stripe_px
        Full width at half maximum of the striped area, sensor pixels.
    """

    k_c: float
    k_stripe: float
    l_mask_um: float
    d_stripe_px: float


@dataclass(frozen=True)
class AxisGeometry:
    """One axis (y for ``P``, x for ``Q``) of a separable lensless device.

    Attributes
    ----------
    n_sensor
        Sensor pixels along the axis (R or S).
    sensor_pitch_um
        Sensor pixel pitch p, um.
    n_scene
        Scene pixels along the axis (N or M).
    scene_pitch_um
        Scene pixel pitch q, um.
    feature_um
        Mask cell side δ, um.
    K
        Number of mask cells along the axis.
    z_mm
        Scene-to-mask distance, mm.
    d_mm
        Mask-to-sensor distance, mm.
    mask_shift_um
        Shift of the mask pattern along the axis, um: the pattern is read at ``m − shift``
        (``dx_um`` / ``dy_um`` of the ``mask_misalignment`` effect, CONTRACTS §5).
    turn_blur_um
        Width (um) of the range of shifts a turned mask's pattern takes along this axis
        across the other axis: the separable model reads the pattern averaged over it (see
        :meth:`rows_of`); 0 for an unturned mask.
    """

    n_sensor: int
    sensor_pitch_um: float
    n_scene: int
    scene_pitch_um: float
    feature_um: float
    K: int  # noqa: N815 - the paper's symbol
    z_mm: float
    d_mm: float
    mask_shift_um: float = 0.0
    turn_blur_um: float = 0.0

    @classmethod
    def rows_of(cls, profile: Profile, K: int | None = None) -> AxisGeometry:  # noqa: N803
        """The y axis of ``profile`` (rows: ``P``, R × N); ``K`` overrides the mask length.

        The profile's ``physics`` is honoured: ``geometry`` replaces z and d,
        ``mask_misalignment.dy_um`` shifts the pattern, and its ``angle_deg`` θ as far as a
        separable model can: a mask turned by θ reads the y pattern (cells ``δ/cos θ``) at
        the shift ``dy + tan θ·(m_x − dx)``, which varies with the column's mask-plane
        coordinate ``m_x = α·x`` (α = z/H) across the sensor. The separable matrices take the
        mean over the sensor's columns: the shift's centre ``dy − tan θ·dx`` and the pattern
        averaged over its spread ``2·|tan θ|·α·S·p/2`` (``turn_blur_um``, exact: a third box in
        the footprint). What no separable model holds (the shift's dependence on the column)
        is ``SystemMatrices.direct``'s ``meta["unmodelled_angle_deg"]``.
        """
        return cls._of(profile, K, along_rows=True)

    @classmethod
    def cols_of(cls, profile: Profile, K: int | None = None) -> AxisGeometry:  # noqa: N803
        """The x axis of ``profile`` (columns: ``Q``, S × M); ``K`` overrides the mask length.

        Honours ``physics`` like :meth:`rows_of`: the x pattern of a turned mask is read at
        ``dx − tan θ·(m_y − dy)``, centred at ``dx + tan θ·dy`` and spread over
        ``2·|tan θ|·α·R·p/2`` across the sensor's rows.
        """
        return cls._of(profile, K, along_rows=False)

    @classmethod
    def _of(cls, profile: Profile, K: int | None, along_rows: bool) -> AxisGeometry:  # noqa: N803
        """:meth:`rows_of` (``along_rows``) or :meth:`cols_of`: the axis' pixels, the pose's
        distances, and the turn's mean shift and spread across the other axis' sensor extent."""
        pose = MaskPose.of(profile)
        t = math.tan(math.radians(pose.angle_deg))
        alpha = pose.z_mm / (pose.z_mm + pose.d_mm)
        n_sensor, n_other = ((profile.sensor.rows, profile.sensor.cols) if along_rows
                             else (profile.sensor.cols, profile.sensor.rows))
        n_scene = profile.scene.rows if along_rows else profile.scene.cols
        shift_um = pose.dy_um - t * pose.dx_um if along_rows else pose.dx_um + t * pose.dy_um
        half_other_um = alpha * n_other * profile.sensor.pixel_pitch_um / 2.0
        return cls(n_sensor, profile.sensor.pixel_pitch_um, n_scene, profile.scene.pixel_pitch_um,
                   profile.mask.feature_um / math.cos(math.radians(pose.angle_deg)),
                   profile.mask.K if K is None else int(K), pose.z_mm, pose.d_mm, shift_um,
                   2.0 * abs(t) * half_other_um)

    @property
    def h_mm(self) -> float:
        """H = z + d, mm."""
        return self.z_mm + self.d_mm

    def stripe_parameters(self, d_stripe_px: float | None = None) -> StripeParameters:
        """The paper's k_c, k_stripe, l_mask and d_stripe for this axis."""
        k_c = self.scene_pitch_um / self.sensor_pitch_um
        return StripeParameters(
            k_c=k_c,
            k_stripe=-self.d_mm * k_c / self.z_mm,
            l_mask_um=self.n_sensor * self.sensor_pitch_um,
            d_stripe_px=self.default_d_stripe_px() if d_stripe_px is None else float(d_stripe_px),
        )

    def default_d_stripe_px(self) -> float:
        """FWHM of the striped area in sensor pixels: ``2·0.766·H / p`` × the tuned scale."""
        return DEFAULT_D_STRIPE_SCALE * 2.0 * _HALF_MAX_OVER_H * self.h_mm * 1e3 / self.sensor_pitch_um


@dataclass(frozen=True)
class MaskPose:
    """Where the mask really is, from a profile's ``physics`` (CONTRACTS §5).

    Attributes
    ----------
    z_mm, d_mm
        Scene-to-mask and mask-to-sensor distances, mm (``geometry`` effect, else nominal).
    dx_um, dy_um
        Shift of the pattern along x (columns) and y (rows), um (``mask_misalignment``).
    angle_deg
        Rotation of the pattern, degrees (``mask_misalignment``). Quarter turns and mirror
        images are written into the profile as rewritten ``phi`` and ``phi_rows`` instead
        (:mod:`thintact_sdk.reconstruction.mask_orientation`, :mod:`thintact_sdk.calibration.pose`),
        so only the small residual turn appears here.
    """

    z_mm: float
    d_mm: float
    dx_um: float = 0.0
    dy_um: float = 0.0
    angle_deg: float = 0.0

    @classmethod
    def of(cls, profile: Profile) -> MaskPose:
        """The pose described by ``profile.physics`` (nominal geometry, no shift when absent)."""
        from thintact_sdk.simulation.effects import resolve_physics
        from thintact_sdk.simulation.effects.geometry import distances_mm

        physics = resolve_physics(profile.physics)
        g = physics.get("geometry", {})
        z, d = distances_mm(profile.geometry.scene_to_mask_mm, profile.geometry.mask_to_sensor_mm,
                            g.get("scene_to_mask_mm"), g.get("mask_to_sensor_mm"))
        mis = physics.get("mask_misalignment", {})
        return cls(z, d, float(mis.get("dx_um", 0.0)), float(mis.get("dy_um", 0.0)),
                   float(mis.get("angle_deg", 0.0)))


def _centred(n: int, pitch_um: float) -> np.ndarray:
    """Pixel-centre coordinates (um) of ``n`` pixels centred on the axis (CONTRACTS §1)."""
    return (np.arange(n, dtype=np.float64) - (n - 1) / 2.0) * pitch_um


def _ramp2(t: np.ndarray) -> np.ndarray:
    return 0.5 * np.square(np.maximum(t, 0.0))


def _trapezoid_cdf(x: np.ndarray, a: float, b: float) -> np.ndarray:
    """CDF at ``x`` of the sum of two centred uniform variables of widths ``a`` and ``b``."""
    s, t = (a + b) / 2.0, abs(a - b) / 2.0
    return (_ramp2(x + s) - _ramp2(x + t) - _ramp2(x - t) + _ramp2(x - s)) / (a * b)


def _ramp3(t: np.ndarray) -> np.ndarray:
    return np.power(np.maximum(t, 0.0), 3) / 6.0


def _three_box_cdf(x: np.ndarray, a: float, b: float, w: float) -> np.ndarray:
    """CDF at ``x`` of the sum of three centred uniform variables of widths ``a``, ``b``, ``w``
    (``w`` > 0): the mean of :func:`_trapezoid_cdf` over ``[x − w/2, x + w/2]``, in closed form."""
    s, t = (a + b) / 2.0, abs(a - b) / 2.0

    def antiderivative(u: np.ndarray) -> np.ndarray:
        return (_ramp3(u + s) - _ramp3(u + t) - _ramp3(u - t) + _ramp3(u - s)) / (a * b)

    return (antiderivative(x + w / 2.0) - antiderivative(x - w / 2.0)) / w


def crossing_points_um(axis: AxisGeometry) -> np.ndarray:
    """``n_sensor × n_scene``: where the ray from each scene pixel centre to each sensor pixel
    centre crosses the mask, ``(z·y_r + d·y_n) / H`` (um, unshifted)."""
    z_um, d_um = axis.z_mm * 1e3, axis.d_mm * 1e3
    y_sensor = _centred(axis.n_sensor, axis.sensor_pitch_um)[:, None]
    y_scene = _centred(axis.n_scene, axis.scene_pitch_um)[None, :]
    return (z_um * y_sensor + d_um * y_scene) / (z_um + d_um)


def _footprint_weights(axis: AxisGeometry, m_um: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact share of each mask cell in the trapezoid footprint centred at ``m_um`` (any shape,
    pattern frame, um): the first cell index (``m_um.shape``, int) and the weights
    ``(n_cells,) + m_um.shape`` of it and the next ``n_cells − 1`` cells."""
    h_um = axis.h_mm * 1e3
    a_um = axis.z_mm * 1e3 * axis.sensor_pitch_um / h_um  # footprint of the sensor pixel on the mask
    b_um = axis.d_mm * 1e3 * axis.scene_pitch_um / h_um  # footprint of the scene pixel on the mask
    w_um = axis.turn_blur_um
    half_um = (a_um + b_um + w_um) / 2.0
    delta = axis.feature_um
    lo_cell = np.floor((m_um - half_um) / delta + axis.K / 2.0).astype(np.int64)
    n_cells = int(math.ceil(2.0 * half_um / delta)) + 1
    weights = np.empty((n_cells,) + m_um.shape)

    def cdf(x: np.ndarray) -> np.ndarray:
        if w_um > 1e-9:  # a turned mask: the footprint also spans the turn's shifts
            return _three_box_cdf(x, a_um, b_um, w_um)
        return _trapezoid_cdf(x, a_um, b_um)

    for ell in range(n_cells):
        left_um = (lo_cell + ell - axis.K / 2.0) * delta - m_um
        weights[ell] = cdf(left_um + delta) - cdf(left_um)
    return lo_cell, weights


class DirectGenerator:
    """Precomputed affine map φ → system matrix for one axis.

    The coding matrix is ``A ∘ fade ∘ Σ_l w_l · φ[j0 + l]`` (shape ``n_sensor × n_scene``),
    with the cell index ``j0`` and the exact footprint weights ``w_l`` fixed by the geometry,
    so a new φ costs one gather and a weighted sum.

    Parameters
    ----------
    axis
        The axis geometry.
    d_stripe_px
        FWHM of the striped area, sensor pixels (default :meth:`AxisGeometry.default_d_stripe_px`).
    """

    def __init__(self, axis: AxisGeometry, d_stripe_px: float | None = None) -> None:
        self.axis = axis
        self.stripe = axis.stripe_parameters(d_stripe_px)
        if not self.stripe.d_stripe_px > 0:
            raise InvalidValueError(f"d_stripe_px must be > 0, got {self.stripe.d_stripe_px}")
        y_sensor = _centred(axis.n_sensor, axis.sensor_pitch_um)[:, None]
        y_scene = _centred(axis.n_scene, axis.scene_pitch_um)[None, :]
        # where the ray crosses the mask, in the (shifted) pattern's frame
        m_um = crossing_points_um(axis) - axis.mask_shift_um
        lo_cell, weights = _footprint_weights(axis, m_um)
        n_cells = weights.shape[0]
        # φ is padded with closed cells so that every index lands inside the padded vector
        self._pad = int(max(0, -lo_cell.min(), lo_cell.max() + n_cells - axis.K)) + 1
        self._index = (lo_cell[None] + np.arange(n_cells)[:, None, None] + self._pad)
        self._weights = weights
        offset_px = (y_sensor - y_scene) / axis.sensor_pitch_um
        half_px = self.stripe.d_stripe_px / 2.0
        soft_px = SIGMOID_SOFTNESS * self.stripe.d_stripe_px
        self.fade = 0.5 * (1.0 + np.tanh((half_px - np.abs(offset_px)) / (2.0 * soft_px)))
        # amplitude: Σ_n fade at the sensor centre (y = 0) makes the white open response 1
        centre_fade = 0.5 * (1.0 + np.tanh((half_px - np.abs(y_scene[0] / axis.sensor_pitch_um))
                                           / (2.0 * soft_px)))
        self.amplitude = 1.0 / (math.sqrt(2.0) * float(centre_fade.sum()))
        self._scaled_fade = self.amplitude * self.fade

    def _padded(self, phi: np.ndarray) -> np.ndarray:
        phi = np.asarray(phi, dtype=np.float64)
        if phi.shape[-1] != self.axis.K:
            raise InvalidShapeError(f"phi has {phi.shape[-1]} entries, the mask has K={self.axis.K}")
        pad = [(0, 0)] * (phi.ndim - 1) + [(self._pad, self._pad)]
        return np.pad(phi, pad)

    def coding(self, phi: np.ndarray) -> np.ndarray:
        """Coding matrix (``Pc`` or ``Qc``), ``n_sensor × n_scene``, from φ (``(K,)`` ±1)."""
        padded = self._padded(phi)
        acc = self._weights[0] * padded[self._index[0]]
        for ell in range(1, self._weights.shape[0]):
            acc += self._weights[ell] * padded[self._index[ell]]
        acc *= self._scaled_fade
        return acc

    def open(self) -> np.ndarray:
        """Open matrix (``Po`` or ``Qo``), ``n_sensor × n_scene``: φ ≡ 1 on the K cells."""
        return self.coding(np.ones(self.axis.K))

    def uniform_scene_profiles(self, phi: np.ndarray, shifts_um: np.ndarray,
                               feature_um: float | None = None,
                               sensor_index: np.ndarray | None = None) -> np.ndarray:
        """``(2, T, n_sensor)``: open and coding profiles of a uniform scene (``P·1``), the
        pattern shifted by each of ``shifts_um`` (``(T,)``, um, instead of the axis' own
        shift) and with cells of ``feature_um`` (default the axis' own); only the sensor
        pixels ``sensor_index`` (then ``(2, T, len(sensor_index))``) when given.

        One row of the flat field of a slightly turned mask (:mod:`thintact_sdk.calibration.pose`)
        is the product of such profiles at shifts that vary along the other axis. The
        footprint-averaged pattern is tabulated every :data:`PROFILE_TABLE_STEP_UM` and read
        by linear interpolation (relative error under 1e-4 of a cell's contrast).
        """
        axis = self.axis if feature_um is None else replace(self.axis, feature_um=float(feature_um))
        phi = np.asarray(phi, np.float64)
        if phi.shape != (axis.K,):
            raise InvalidShapeError(f"phi has shape {phi.shape}, the mask has K={axis.K}")
        shifts = np.asarray(shifts_um, np.float64)
        m0 = crossing_points_um(axis)
        fade = self._scaled_fade
        if sensor_index is not None:
            m0, fade = m0[sensor_index], fade[sensor_index]
        lo = float(m0.min() - shifts.max()) - 2 * PROFILE_TABLE_STEP_UM
        hi = float(m0.max() - shifts.min()) + 2 * PROFILE_TABLE_STEP_UM
        grid = np.arange(lo, hi + PROFILE_TABLE_STEP_UM, PROFILE_TABLE_STEP_UM)
        lo_cell, weights = _footprint_weights(axis, grid)
        pad = int(max(0, -lo_cell.min(), lo_cell.max() + weights.shape[0] - axis.K)) + 1
        tables = []
        for vec in (np.ones(axis.K), phi):
            padded = np.pad(vec, pad)
            table = np.zeros(grid.size)
            for ell in range(weights.shape[0]):
                table += weights[ell] * padded[lo_cell + ell + pad]
            tables.append(table)
        out = np.empty((2, shifts.size, m0.shape[0]))
        chunk = max(1, _PROFILE_CHUNK_ELEMENTS // m0.size)  # bounded memory on large sensors
        for i in range(0, shifts.size, chunk):
            pos = (m0[None] - shifts[i:i + chunk, None, None] - lo) / PROFILE_TABLE_STEP_UM
            i0 = np.floor(pos).astype(np.int64)
            frac = pos - i0
            for k, table in enumerate(tables):
                values = table[i0] + frac * (table[i0 + 1] - table[i0])
                out[k, i:i + chunk] = np.einsum("tsn,sn->ts", values, fade)
        return out


def direct_system_matrices(
    phi: np.ndarray, profile: Profile, d_stripe_px: float | None = None,
    phi_rows: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The paper's direct generation of ``Po, Qo, Pc, Qc`` from the mask vector φ.

    Parameters
    ----------
    phi
        ``(K,)`` entries ±1 along x (columns); also used along y unless ``phi_rows`` is given
        (the paper's φ1 = φ2 = φ). K may differ from the profile's own mask (the mask is
        centred on the axis either way).
    profile
        Device profile: sensor and scene grids, mask feature size, distances z and d.
    d_stripe_px
        FWHM of the striped area in sensor pixels, the same on both axes; ``None`` uses the
        physical default ``2·0.766·H / p`` (times :data:`DEFAULT_D_STRIPE_SCALE`).
    phi_rows
        ``(K,)`` ±1 along y (rows), default ``phi``.

    Returns
    -------
    Po, Qo, Pc, Qc
        ``R × N``, ``S × M``, ``R × N``, ``S × M`` float64 in relative irradiance per display
        unit (a white scene through a fully open mask gives 1 at the sensor centre).

    Notes
    -----
    The profile's ``physics`` is honoured where a separable model can: the ``geometry``
    distances, the ``mask_misalignment`` shift, and its rotation as the separable mean over
    the sensor (:meth:`AxisGeometry.rows_of`); a turned mask is not separable, and the part
    of the turn no separable model holds is left out.
    """
    phi_arr = np.asarray(phi)
    rows_phi = phi_arr if phi_rows is None else np.asarray(phi_rows)
    for name, vec in (("phi", phi_arr), ("phi_rows", rows_phi)):
        if vec.ndim != 1 or vec.shape != phi_arr.shape or vec.size == 0:
            raise InvalidShapeError(f"{name} must be a non-empty (K,) vector, got shape {vec.shape}")
        if not np.all(np.abs(vec) == 1):
            raise InvalidShapeError(f"{name} entries must be +1 or -1")
    k = int(phi_arr.shape[0])
    gen_p = DirectGenerator(AxisGeometry.rows_of(profile, k), d_stripe_px)
    gen_q = DirectGenerator(AxisGeometry.cols_of(profile, k), d_stripe_px)
    return gen_p.open(), gen_q.open(), gen_p.coding(rows_phi), gen_q.coding(phi_arr)
