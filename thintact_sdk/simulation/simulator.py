"""The ThinTact forward simulator: scene (display values) → sensor signal.

Stages, in order (CONTRACTS §4 baseline plus the effects of ``profile.physics``, §5):

1. scene-stage effects on the ``N × M × C`` display values (e.g. ``display_gamma``,
   ``scene_blur``);
2. the imaging kernel: box integration over every sensor pixel's and every scene pixel's
   square of ``cos^q θ/H² · T(m)``; kernel-stage effects (``diffraction``,
   ``pixel_angular_response``, ``refraction``, ``mask_misalignment``, ``mask_leakage``,
   ``geometry``) set the kernel's parameters through their declaration's ``kernel``.
   Separable physics uses ``Y_c = Σ_k P_k X_c Q_kᵀ``
   (:mod:`~thintact_sdk.simulation.separable`, rotated masks
   :mod:`~thintact_sdk.simulation.rotated`, refraction, with or without rotation and
   diffraction, :mod:`~thintact_sdk.simulation.refracted`); ``direct=True`` forces the
   dense direct path (:mod:`~thintact_sdk.simulation.direct`);
3. signal-stage effects, linear (e.g. ``sensor_blur``, ``color_crosstalk``, ``veiling_glare``);
4. **the gain enters here**: ``L = gain_dn_per_unit[c] · signal`` (DN above black);
5. DN-stage effects (e.g. ``stray_light``, ``sensor_gamma``, ``saturation``).

Stages 1, 3 and 5 apply every effect of ``profile.physics`` that declares that stage, in
its declared order, through its ``forward`` (:func:`thintact_sdk.simulation.effects.stage_effects`):
an effect added with :func:`thintact_sdk.simulation.effects.register_effect` needs nothing here.

Units: the kernel output is the pixel-averaged irradiance per unit scene radiance
(dimensionless, an unbounded open aperture would give π); it is the same for every frame
of a profile. :meth:`Simulator.forward` returns stage 1-3 in these units, with the DN
effects (if any) applied at :meth:`Simulator.reference_gain` and divided back out;
:meth:`Simulator.predict_dn` takes the per-channel gain explicitly and returns DN.
"""

from __future__ import annotations

import functools
import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import replace
from typing import Any, TypeAlias, TypeVar, overload

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.host.build_threads import per_channel_by_wavelength
from thintact_sdk.interfaces import ImagingModel
from thintact_sdk.simulation import refracted as sim_refracted
from thintact_sdk.simulation import refracted_blocked as sim_refracted_blocked
from thintact_sdk.simulation import rotated as sim_rotated
from thintact_sdk.simulation import tiled as sim_tiled
from thintact_sdk.simulation.axis import mask_cell_edges_mm
from thintact_sdk.simulation.direct import DirectKernel, build_direct_kernel
from thintact_sdk.simulation.effects import (
    EFFECTS,
    Stage,
    diffraction,
    mask_leakage,
    resolve_physics,
    stage_effects,
    window_blocker,
)
from thintact_sdk.simulation.params import KernelParams, kernel_params
from thintact_sdk.simulation.radiometry import SeparableExpansion
from thintact_sdk.simulation.separable import (
    SeparableKernel,
    SeparableTerm,
    axis_term_matrices,
    compress_terms,
)
from thintact_sdk.simulation.tiled import TiledKernel

WHITE_FRACTION = 0.6
"""Default DN level of the brightest all-white pixel, as a fraction of (saturation - black)."""


ImagingKernel: TypeAlias = SeparableKernel | TiledKernel | DirectKernel
"""What :func:`get_kernel` returns: ``apply(scenes F×N×M×C, precision) -> F×R×S×C`` signal
and an ``info`` dict; the separable one also has its ``terms`` per channel (a tiled one has
them per sensor window)."""

_KERNEL_CACHE: OrderedDict[KernelParams, ImagingKernel] = OrderedDict()
_CACHE_SIZE = 4


SIDE_BY_SIDE_FAMILY_BYTES = 64 * 1024**2
"""A rotated diffraction kernel builds its wavelengths side by side (on the build threads)
only while one wavelength's displacement family is at most this; larger, one after another
(each wavelength's build holds its profiles and terms)."""


def clear_kernel_cache() -> None:
    """Forget every cached kernel and radiometric expansion (frees memory)."""
    _KERNEL_CACHE.clear()
    _cached_expansion.cache_clear()


def _expansion(kp: KernelParams) -> SeparableExpansion:
    h = kp.z_mm + kp.d_mm
    margin = 2 * max(kp.pitch_um, kp.scene_pitch_um) * 1e-3
    return _cached_expansion(h, kp.q, kp.grid_x().max_offset_mm() + margin,
                             kp.grid_y().max_offset_mm() + margin, kp.rank_tol)


@functools.lru_cache(maxsize=4)
def _cached_expansion(h_mm: float, q: float, half_x_mm: float, half_y_mm: float,
                      rel_tol: float) -> SeparableExpansion:
    """One expansion per geometry, shared by every kernel built for it (with the factor
    values it memoises: the diagnosis rebuilds kernels of one device hundreds of times)."""
    return SeparableExpansion.build(h_mm, q, half_x_mm, half_y_mm, rel_tol=rel_tol)


def build_separable_kernel(kp: KernelParams) -> SeparableKernel | TiledKernel:
    """Build the ``P_k``, ``Q_k`` of every channel for separable physics (per sensor window
    for a large rotated mask)."""
    if not kp.separable:
        raise ThinTactError("internal: separable kernel requested for non-separable physics")
    if kp.windowed and kp.n_scene_side != 1.0:
        raise ThinTactError("a sensor window's kernel is built for straight rays only (the refracted "
                            "kernel has no sensor offset)")
    if kp.n_scene_side != 1.0:
        return sim_refracted.build_refracted_kernel(kp)
    h = kp.z_mm + kp.d_mm
    alpha, beta = kp.z_mm / h, kp.d_mm / h
    exp = _expansion(kp)
    gx, gy = kp.grid_x(), kp.grid_y()
    k = len(kp.phi)
    feature_mm = kp.feature_um * 1e-3
    edges_x = mask_cell_edges_mm(k, feature_mm) + kp.dx_um * 1e-3
    edges_y = mask_cell_edges_mm(k, feature_mm) + kp.dy_um * 1e-3
    phi_x = np.asarray(kp.phi, float)
    phi_y = np.asarray(kp.phi_rows, float)
    info = {"rank": float(exp.rank), "radiometric_rel_error": exp.rel_error}
    if kp.angle_deg != 0.0:
        return _build_rotated_kernel(kp, exp, info)
    if kp.wavelengths_nm is None:
        c_o, c_c = mask_leakage.intensity_coefficients(kp.leakage)
        mx = axis_term_matrices(gx, alpha, beta, edges_x, np.stack([np.ones(k), phi_x]),
                                exp.fx_derivs, kp.n_sub)
        my = axis_term_matrices(gy, alpha, beta, edges_y, np.stack([np.ones(k), phi_y]),
                                exp.gy_derivs, kp.n_sub)
        terms = []
        for part, v, coef in (("open", 0, c_o), ("coding", 1, c_c)):
            if coef == 0:
                continue
            for ll in range(exp.rank):
                terms.append(SeparableTerm(coef * my[v, ll], mx[v, ll], part))
        terms = compress_terms(terms, kp.compress_tol)
        info["terms"] = float(len(terms))
        return SeparableKernel([terms] * kp.channels, info)
    a_o, a_c = mask_leakage.amplitude_coefficients(kp.leakage)

    def build(lam: float) -> list[SeparableTerm]:
        mats = []
        for grid, edges, phi, fac in ((gx, edges_x, phi_x, exp.fx_derivs),
                                      (gy, edges_y, phi_y, exp.gy_derivs)):
            lo, hi = grid.crossing_span_mm(alpha, beta)
            pad = 4 * grid.sensor_pitch_mm + 4 * grid.scene_pitch_mm
            fe, fv = diffraction.axis_intensity_profiles(
                edges, phi, lo - pad, hi + pad, lam, kp.z_mm, kp.d_mm)
            mats.append(axis_term_matrices(grid, alpha, beta, fe, fv, fac, kp.n_sub))
        mx, my = mats
        coefs = (("open", 0, a_o**2), ("open", 1, a_c**2),
                 ("coding", 2, 2 * a_o * a_c), ("coding", 3, -2 * a_o * a_c))
        terms = []
        for part, v, coef in coefs:
            if coef == 0:
                continue
            for ll in range(exp.rank):
                terms.append(SeparableTerm(coef * my[v, ll], mx[v, ll], part))
        return compress_terms(terms, kp.compress_tol)

    # one wavelength after another: this kernel also runs at the paper's size (memory)
    per_channel = per_channel_by_wavelength(kp.wavelengths_nm, kp.channels, build, threads=1)
    info["terms"] = float(max(len(t) for t in per_channel))
    return SeparableKernel(per_channel, info)


def build_window_kernel(kp: KernelParams) -> SeparableKernel:
    """The kernel of one sensor window (``kp`` from :func:`~thintact_sdk.simulation.tiled.window_params`)
    whose family is under the window limit, as one separable kernel (never tiled again)."""
    kern = build_separable_kernel(kp)
    if not isinstance(kern, SeparableKernel):
        raise ThinTactError(f"internal: the {kp.rows}×{kp.cols} window's kernel was tiled again")
    return kern


def _build_rotated_kernel(kp: KernelParams, exp: SeparableExpansion,
                          info: dict[str, float]) -> SeparableKernel | TiledKernel:
    """Separable kernel of a rotated mask (:mod:`~thintact_sdk.simulation.rotated`), with
    or without diffraction (one set of terms per distinct wavelength); on a device whose
    displacement family exceeds :data:`~thintact_sdk.simulation.tiled.WINDOW_FAMILY_BYTES`,
    built window by window of the sensor (:mod:`~thintact_sdk.simulation.tiled`)."""
    n_values = 2 if kp.wavelengths_nm is None else 4
    if sim_rotated.rotated_family_bytes(kp, exp.rank, n_values) > sim_tiled.WINDOW_FAMILY_BYTES:
        spans = sim_tiled.plan_windows(kp, lambda w: sim_rotated.rotated_family_bytes(w, exp.rank, n_values),
                                       sim_tiled.WINDOW_FAMILY_BYTES)  # at least 2: the whole is over the limit
        return sim_tiled.build_tiled_kernel(kp, spans, lambda w: _build_rotated_window(w, exp, dict(info)))
    return _build_rotated_window(kp, exp, info)


def rotated_build_bytes(kp: KernelParams) -> float:
    """Bytes of displacement families the rotated kernel of ``kp`` tabulates, summed over its
    sensor windows when it is built window by window: the measure of its build's work
    (0 for an unrotated mask; ``inf`` where even the smallest windows are refused).

    The build time grows about linearly with these bytes (the paper device at 0.35°: 0.31 GiB
    binned 32×, 0.68 GiB binned 16×, 1.63 GiB binned 8×; times in docs/benchmarks.md), and the
    bytes about as the square of the angle (the separable rank of each axis's displacement
    family grows with it)."""
    if kp.angle_deg == 0.0:
        return 0.0
    exp = _expansion(kp)
    n_values = 2 if kp.wavelengths_nm is None else 4

    def family(w: KernelParams) -> float:
        return sim_rotated.rotated_family_bytes(w, exp.rank, n_values)

    whole = family(kp)
    if whole <= sim_tiled.WINDOW_FAMILY_BYTES:
        return whole
    try:
        spans = sim_tiled.plan_windows(kp, family, sim_tiled.WINDOW_FAMILY_BYTES, total_limit=math.inf)
    except ThinTactError:
        return math.inf
    return float(sum(family(sim_tiled.window_params(kp, *s)) for s in spans))


def streamed_rotated_kernel(kp: KernelParams,
                            progress: Callable[[int, int], None] | None = None) -> sim_tiled.StreamedTiledKernel:
    """The rotated kernel of ``kp`` as windows built at each apply and dropped after it
    (:class:`~thintact_sdk.simulation.tiled.StreamedTiledKernel`): no limit on the windows'
    sum, one window in memory. For rendering a large rotated device once: the full paper
    device at 0.1° is 48 windows of 160 MiB families, refused by a kept tiled build.

    Raises
    ------
    ThinTactError
        For an unrotated mask or refraction (not built in windows), or when even the smallest
        windows' families exceed :data:`~thintact_sdk.simulation.tiled.WINDOW_FAMILY_BYTES`.
    """
    if kp.angle_deg == 0.0 or kp.n_scene_side != 1.0 or not kp.separable:
        raise ThinTactError("a streamed kernel is built for a rotated mask with straight rays only")
    exp = _expansion(kp)
    n_values = 2 if kp.wavelengths_nm is None else 4
    info = {"rank": float(exp.rank), "radiometric_rel_error": exp.rel_error}
    spans = sim_tiled.plan_windows(kp, lambda w: sim_rotated.rotated_family_bytes(w, exp.rank, n_values),
                                   sim_tiled.WINDOW_FAMILY_BYTES, total_limit=math.inf)
    return sim_tiled.StreamedTiledKernel(kp, spans, lambda w: _build_rotated_window(w, exp, dict(info)), progress)


def _build_rotated_window(kp: KernelParams, exp: SeparableExpansion,
                          info: dict[str, float]) -> SeparableKernel:
    """:func:`_build_rotated_kernel` on one piece of sensor (the whole or a window)."""
    if kp.wavelengths_nm is None:
        px, py, pairs = sim_rotated.geometric_profiles(kp)
        terms = sim_rotated.rotated_terms(kp, exp, px, py, pairs)
        info["terms"] = float(len(terms))
        return SeparableKernel([terms] * kp.channels, info)

    def build(lam: float) -> list[SeparableTerm]:
        px, py, pairs = sim_rotated.diffraction_profiles(kp, lam)
        return sim_rotated.rotated_terms(kp, exp, px, py, pairs)

    # wavelengths side by side only while each one's family is small: side by side holds every
    # wavelength's terms at once, for little gain in time once a family is large
    parallel = sim_rotated.rotated_family_bytes(kp, exp.rank, 4) <= SIDE_BY_SIDE_FAMILY_BYTES
    per_channel = per_channel_by_wavelength(kp.wavelengths_nm, kp.channels, build, None if parallel else 1)
    info["terms"] = float(max(len(t) for t in per_channel))
    return SeparableKernel(per_channel, info)


def get_kernel(kp: KernelParams, progress: Callable[[int, int], None] | None = None) -> ImagingKernel:
    """The (cached) kernel for these parameters: separable (whole or tiled) or direct.

    ``progress(done, total)`` is called while a long build runs step by step (the blocked
    refracted kernel of a wide device, minutes to an hour); other builds do not call it."""
    if kp.windowed and not kp.separable:
        raise ThinTactError("a sensor window's kernel is built on the separable path only (the direct "
                            "kernel has no sensor offset)")
    if kp.separable:
        return _separable_kernel(kp, progress)
    hit = _cache_get(kp)
    if hit is not None:
        return hit
    return _cache_put(kp, build_direct_kernel(kp))


def _separable_kernel(kp: KernelParams, progress: Callable[[int, int], None] | None = None) -> ImagingKernel:
    hit = _cache_get(kp)
    if isinstance(hit, SeparableKernel | TiledKernel) or (isinstance(hit, DirectKernel) and kp.n_scene_side != 1.0):
        return hit
    if sim_refracted_blocked.blocked_wanted(kp):  # a wide refracting device: filled block by block
        return _cache_put(kp, sim_refracted_blocked.build_blocked_refracted_kernel(kp, progress))
    if kp.wavelengths_nm is None and kp.leakage != 0.0:
        # geometric leakage only rescales the open and coding halves: reuse the t = 0 kernel
        base = _separable_kernel(replace(kp, leakage=0.0))
        assert not isinstance(base, DirectKernel)  # the blocked refracted kernel carries its leakage
        kern = _rescaled_for_leakage(base, kp.leakage)
    else:
        kern = build_separable_kernel(kp)
    return _cache_put(kp, kern)


def _cache_get(kp: KernelParams) -> ImagingKernel | None:
    hit = _KERNEL_CACHE.get(kp)
    if hit is not None:
        _KERNEL_CACHE.move_to_end(kp)
    return hit


K = TypeVar("K", bound=SeparableKernel | TiledKernel | DirectKernel)


def _cache_put(kp: KernelParams, kern: K) -> K:
    _KERNEL_CACHE[kp] = kern
    while len(_KERNEL_CACHE) > _CACHE_SIZE:
        _KERNEL_CACHE.popitem(last=False)
    return kern


@overload
def _rescaled_for_leakage(base: SeparableKernel, transmittance: float) -> SeparableKernel: ...


@overload
def _rescaled_for_leakage(base: TiledKernel, transmittance: float) -> TiledKernel: ...


def _rescaled_for_leakage(base: SeparableKernel | TiledKernel,
                          transmittance: float) -> SeparableKernel | TiledKernel:
    """The t = 0 kernel with the open half scaled by (1 + t) and the coding half by (1 - t)
    (window by window for a tiled kernel)."""
    if isinstance(base, TiledKernel):
        return TiledKernel([replace(w, kernel=_rescaled_for_leakage(w.kernel, transmittance))
                            for w in base.windows], base.rows, base.cols, dict(base.info))
    c_o, c_c = mask_leakage.intensity_coefficients(transmittance)
    scale = {"open": c_o / 0.5, "coding": c_c / 0.5}
    done: dict[int, list[SeparableTerm]] = {}
    per_channel = []
    for ts in base.terms:
        if id(ts) not in done:
            done[id(ts)] = [SeparableTerm(t.P * scale[t.part], t.Q, t.part) for t in ts
                            if scale[t.part] != 0.0]
        per_channel.append(done[id(ts)])
    return SeparableKernel(per_channel, dict(base.info))


class Simulator(ImagingModel):
    """Forward model of a ThinTact device with the effects listed in ``profile.physics``.

    Parameters
    ----------
    profile
        The device profile.
    n_sub
        Sub-intervals per pixel for the moments of the smooth factor's Taylor expansion
        (default: 2 when a pixel pair spans under 1 % of H, else 4).
    rank_tol
        Relative truncation of the separable expansion of the radiometric factor.
    direct
        Use the direct (dense, non-separable) path even for separable physics.
    precision
        Arithmetic of the separable forward: ``"float64"`` (default) or ``"float32"``
        (about twice as fast at full size, relative error ~1e-7). Outputs are float64.
    stream_windows
        A rotated mask too large for one build is built window by window at every forward
        call and each window dropped after it (:func:`streamed_rotated_kernel`): one window's
        memory and no limit on their number, the build's time at each call. For rendering a
        large rotated device once; ``False`` (default) keeps the windows (and refuses a
        build whose windows sum above :data:`~thintact_sdk.simulation.tiled.TILED_FAMILY_BYTES`).

    Notes
    -----
    Kernels are cached by their parameters (module-level, a few entries), so building a
    ``Simulator`` for a profile whose physics only changes post-kernel effects is cheap.
    """

    def __init__(self, profile: Profile, *, n_sub: int | None = None, rank_tol: float = 1e-7,
                 direct: bool = False, precision: str = "float64", stream_windows: bool = False) -> None:
        if precision not in ("float64", "float32"):
            raise ThinTactError(f"precision must be 'float64' or 'float32', got {precision!r}")
        self.precision = precision
        self.profile = profile
        self.physics = resolve_physics(profile.physics)
        self.kernel_params = kernel_params(profile, self.physics, n_sub, rank_tol, direct)
        if self.kernel_params.wavelengths_nm is not None and not self.kernel_params.separable:
            raise ThinTactError(
                "physics: diffraction cannot be simulated on the forced direct path (it has "
                "no diffraction model)"
            )
        self._kernel: ImagingKernel | sim_tiled.StreamedTiledKernel | None = None
        kp = self.kernel_params
        self._stream = stream_windows and kp.separable and kp.angle_deg != 0.0 and kp.n_scene_side == 1.0 \
            and rotated_build_bytes(kp) > sim_tiled.WINDOW_FAMILY_BYTES
        self._ref_gain: float | None = None

    # -- kernel ---------------------------------------------------------------------------
    @property
    def kernel(self) -> ImagingKernel | sim_tiled.StreamedTiledKernel:
        """The imaging kernel (built on first use, shared through the cache; a streamed one is
        built at each forward call, never cached)."""
        return self.build_kernel()

    def build_kernel(self, progress: Callable[[int, int], None] | None = None
                     ) -> ImagingKernel | sim_tiled.StreamedTiledKernel:
        """Build the imaging kernel now (what :attr:`kernel` does on first use), calling
        ``progress(done, total)`` during a build long enough to report steps (the blocked
        refracted kernel of a wide device); a kernel already built is returned at once."""
        if self._kernel is None:
            self._kernel = streamed_rotated_kernel(self.kernel_params) if self._stream \
                else get_kernel(self.kernel_params, progress)
        return self._kernel

    @property
    def separable(self) -> bool:
        """True when the imaging kernel is a sum of separable terms."""
        return self.kernel_params.separable

    @property
    def n_channels(self) -> int:
        return self.kernel_params.channels

    def _check(self, scenes: np.ndarray) -> np.ndarray:
        x = np.asarray(scenes, dtype=float)
        want = (self.profile.scene.rows, self.profile.scene.cols, self.n_channels)
        if x.ndim != 4 or x.shape[1:] != want:
            raise ThinTactError(
                f"scenes must be F × {want[0]} × {want[1]} × {want[2]} for profile "
                f"{self.profile.name!r}, got shape {tuple(x.shape)}"
            )
        return x

    # -- stages ---------------------------------------------------------------------------
    def _apply_stage(self, stage: Stage, x: np.ndarray) -> np.ndarray:
        """Apply the effects of ``stage`` that the physics switches on, in their order."""
        for spec in stage_effects(stage):
            if spec.name in self.physics and spec.forward is not None:
                x = spec.forward(x, self.physics[spec.name], self.profile)
        return x

    def _scene_stage(self, x: np.ndarray) -> np.ndarray:
        return self._apply_stage("scene", x)

    def _signal_stage(self, y: np.ndarray) -> np.ndarray:
        return self._apply_stage("signal", y)

    def _dn_stage(self, signal_dn: np.ndarray) -> np.ndarray:
        return self._apply_stage("dn", signal_dn)

    @property
    def has_dn_effects(self) -> bool:
        return any(EFFECTS[e].stage == "dn" for e in self.physics)

    def linear_batch(self, scenes: np.ndarray) -> np.ndarray:
        """Stages 1-3: ``F × N × M × C`` → ``F × R × S × C`` linear signal (simulator units)."""
        x = self._scene_stage(self._check(scenes))
        return self._signal_stage(self.kernel.apply(x, self.precision))

    def linear_window(self, scenes: np.ndarray, span: tuple[int, int, int, int]) -> np.ndarray:
        """Stages 1-3 on sensor rows ``row0:row1`` and columns ``col0:col1`` only (``span``):
        ``F × N × M × C`` → ``F × (row1-row0) × (col1-col0) × C`` linear signal (simulator
        units), the same numbers as those pixels of :meth:`linear_batch` (to the compression
        tolerance). The window's own kernel is built for the call and dropped (a window of a
        rotated mask whose whole-sensor kernel is refused builds in seconds; one refused for
        its terms is built as its quadrants, :func:`~thintact_sdk.simulation.tiled.build_window_pieces`).

        Raises
        ------
        ThinTactError
            When an effect after the kernel reads beyond its pixel (``reads_beyond_pixel``:
            a sensor blur, veiling glare), or the kernel has no windows (refraction).
        """
        blocker = window_blocker(self.physics)
        if blocker is not None:
            raise ThinTactError(f"physics: {blocker}")
        if not self.separable:
            raise ThinTactError("physics: the direct (non-separable) kernel has no sensor windows")
        r0, r1, c0, c1 = span
        x = self._scene_stage(self._check(scenes))
        out = np.empty((x.shape[0], r1 - r0, c1 - c0, x.shape[3]))
        for w in sim_tiled.build_window_pieces(self.kernel_params, span, build_window_kernel):
            out[:, w.row0 - r0 : w.row1 - r0, w.col0 - c0 : w.col1 - c0] = w.kernel.apply(x, self.precision)
        return self._signal_stage(out)

    # -- public API -----------------------------------------------------------------------
    def reference_gain(self, white_level_dn: float | None = None) -> float:
        """DN per simulator unit that puts the brightest pixel of the all-white scene
        (linear signal, stages 1-3, any channel) at ``white_level_dn`` DN above black
        (default 0.6·(saturation - black))."""
        nz = self.profile.noise
        level = WHITE_FRACTION * (nz.saturation_dn - nz.black_level_dn) if white_level_dn is None \
            else float(white_level_dn)
        if self._ref_gain is None:
            white = np.ones((1, self.profile.scene.rows, self.profile.scene.cols, self.n_channels))
            self._ref_gain = float(np.max(self.linear_batch(white)))
        if self._ref_gain <= 0:
            raise ThinTactError("the all-white scene gives no signal: check the mask and geometry")
        return level / self._ref_gain

    def forward_batch(self, scenes: np.ndarray) -> np.ndarray:
        """``F × N × M × C`` scenes → ``F × R × S × C`` float64 signal (simulator units).

        DN-defined effects are applied at :meth:`reference_gain` and converted back to units.
        """
        y = self.linear_batch(scenes)
        if not self.has_dn_effects:
            return y
        g = self.reference_gain()
        return self._dn_stage(y * g) / g

    def forward(self, scene: np.ndarray) -> np.ndarray:
        """``N × M × C`` scene → ``R × S × C`` float64 signal (simulator units)."""
        return self.forward_batch(np.asarray(scene)[None])[0]

    def predict_signal_dn(self, scenes: np.ndarray, gain_dn_per_unit: Any) -> np.ndarray:
        """Expected signal in DN above black, every effect applied, before noise and before
        clipping to the declared saturation.

        Parameters
        ----------
        scenes
            ``F × N × M × C`` (or ``N × M × C``) display values.
        gain_dn_per_unit
            ``(C,)`` or scalar: DN per simulator unit (stage 4).
        """
        x = np.asarray(scenes)
        single = x.ndim == 3
        y = self.linear_batch(x[None] if single else x)
        g = np.broadcast_to(np.asarray(gain_dn_per_unit, float), (self.n_channels,))
        out = self._dn_stage(y * g)
        return out[0] if single else out

    def signal_dn_from_linear(self, linear: np.ndarray, gain_dn_per_unit: Any) -> np.ndarray:
        """Stages 4-5 on a linear signal from :meth:`linear_batch` (``F × R × S × C``):
        ``gain · linear`` then the DN effects; DN above black."""
        g = np.broadcast_to(np.asarray(gain_dn_per_unit, float), (self.n_channels,))
        return self._dn_stage(np.asarray(linear, float) * g)

    def predict_dn(self, scenes: np.ndarray, gain_dn_per_unit: Any) -> np.ndarray:
        """Expected (noiseless) DN, black level included, clipped to ``[0, saturation_dn]``."""
        nz = self.profile.noise
        s = self.predict_signal_dn(scenes, gain_dn_per_unit)
        return np.clip(s + nz.black_level_dn, 0.0, nz.saturation_dn)

    def separable_terms(self, channel: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """``[(P: R × N, Q: S × M)]`` with ``forward(X)[..., c] = Σ_k P_k X_c Q_kᵀ``.

        Raises
        ------
        ThinTactError
            When the physics is not separable per channel (the forced direct path, colour
            crosstalk, display gamma, DN-defined effects).
        """
        o, c = self.open_coding_terms(channel)
        return o + c

    def open_coding_terms(
        self, channel: int
    ) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[tuple[np.ndarray, np.ndarray]]]:
        """The separable expansion split into the all-open half (T = 1/2) and the coding
        half (φφᵀ/2); with diffraction the squared-field terms are "open" and the
        aperture-coding cross terms "coding" (the split they tend to as λ → 0)."""
        ph = self.physics
        mapped = [s for st in ("scene", "signal") for s in stage_effects(st) if s.name in ph]
        blockers = [e for e in ph if EFFECTS[e].stage != "kernel" and EFFECTS[e].separable_terms is None]
        kernel = self.kernel if self.separable else None
        if not isinstance(kernel, SeparableKernel) or blockers:
            why = "the forced direct path" if not self.separable \
                else "a rotated mask built window by window of the sensor" if isinstance(kernel, TiledKernel) \
                else ", ".join(blockers)
            raise ThinTactError(f"the physics of {self.profile.name!r} is not separable ({why})")
        if not 0 <= channel < self.n_channels:
            raise ThinTactError(f"channel {channel} out of range 0..{self.n_channels - 1}")
        maps = [s.separable_terms(ph[s.name], self.profile) for s in mapped if s.separable_terms]
        open_t: list[tuple[np.ndarray, np.ndarray]] = []
        coding_t: list[tuple[np.ndarray, np.ndarray]] = []
        for t in kernel.terms[channel]:
            terms = [(t.P, t.Q)]
            for split in maps:
                terms = [out for p, q in terms for out in split(p, q)]
            (open_t if t.part == "open" else coding_t).extend(terms)
        return open_t, coding_t

    def info(self) -> dict[str, float]:
        """Figures about the kernel (rank of the radiometric expansion and its error)."""
        return dict(self.kernel.info)


def white_level_gain(sim: Simulator, fraction: float = WHITE_FRACTION) -> float:
    """Gain (DN per unit) putting the all-white maximum at ``fraction·(saturation - black)``."""
    nz = sim.profile.noise
    return sim.reference_gain(fraction * (nz.saturation_dn - nz.black_level_dn))


__all__ = [
    "ImagingKernel", "KernelParams", "Simulator", "WHITE_FRACTION", "clear_kernel_cache", "get_kernel",
    "kernel_params", "white_level_gain",
]
