"""Everything the simulator's imaging kernel depends on: :class:`KernelParams` (also the
kernel cache key) and :func:`kernel_params`, which builds it from a profile and the
kernel-stage effects' declarations.

Its own module so that the kernel builders (:mod:`~thintact_sdk.simulation.separable`,
:mod:`~thintact_sdk.simulation.rotated`, :mod:`~thintact_sdk.simulation.direct`) and
:mod:`~thintact_sdk.simulation.simulator`, which dispatches to them, import it without a cycle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.axis import AxisGrid
from thintact_sdk.simulation.effects import stage_effects


@dataclass(frozen=True)
class KernelParams:
    """Everything the imaging kernel depends on (the cache key).

    ``rows × cols`` sensor pixels centred on the optical axis, or, with ``row_offset_px`` /
    ``col_offset_px`` (pixels, the window centre's offset from the axis), a window of a larger
    sensor (:class:`~thintact_sdk.simulation.tiled.TiledKernel`)."""

    rows: int
    cols: int
    pitch_um: float
    scene_rows: int
    scene_cols: int
    scene_pitch_um: float
    feature_um: float
    phi: tuple[int, ...]
    phi_rows: tuple[int, ...]
    z_mm: float
    d_mm: float
    q: float
    leakage: float
    wavelengths_nm: tuple[float, ...] | None
    angle_deg: float
    dx_um: float
    dy_um: float
    n_scene_side: float
    channels: int
    n_sub: int
    rank_tol: float
    force_direct: bool = False
    compress_tol: float = 1e-5
    row_offset_px: float = 0.0
    col_offset_px: float = 0.0

    @property
    def separable(self) -> bool:
        """True unless the direct path is forced (every effect has a separable kernel)."""
        return not self.force_direct

    @property
    def windowed(self) -> bool:
        """True for a window of a larger sensor (its centre off the optical axis)."""
        return self.row_offset_px != 0.0 or self.col_offset_px != 0.0

    def grid_x(self) -> AxisGrid:
        return AxisGrid(self.cols, self.pitch_um * 1e-3, self.scene_cols, self.scene_pitch_um * 1e-3,
                        self.col_offset_px * self.pitch_um * 1e-3)

    def grid_y(self) -> AxisGrid:
        return AxisGrid(self.rows, self.pitch_um * 1e-3, self.scene_rows, self.scene_pitch_um * 1e-3,
                        self.row_offset_px * self.pitch_um * 1e-3)


def kernel_params(profile: Profile, physics: dict[str, dict[str, Any]],
                  n_sub: int | None = None, rank_tol: float = 1e-7,
                  force_direct: bool = False) -> KernelParams:
    """The kernel parameters of a profile with resolved physics (``n_sub=None``: 2 when a
    pixel pair is under 1 % of H across, else 4).

    The baseline (CONTRACTS §4) comes from the profile; every kernel-stage effect in
    ``physics`` then sets the fields its declaration's ``kernel`` names.
    """
    fields: dict[str, Any] = {
        "z_mm": profile.geometry.scene_to_mask_mm, "d_mm": profile.geometry.mask_to_sensor_mm,
        "q": 4.0, "leakage": 0.0, "wavelengths_nm": None, "angle_deg": 0.0, "dx_um": 0.0,
        "dy_um": 0.0, "n_scene_side": 1.0,
    }
    for spec in stage_effects("kernel"):
        if spec.name in physics and spec.kernel is not None:
            fields.update(spec.kernel(physics[spec.name], profile))
    if n_sub is None:
        pair_mm = (profile.sensor.pixel_pitch_um + profile.scene.pixel_pitch_um) * 1e-3
        n_sub = 2 if pair_mm < 0.01 * (fields["z_mm"] + fields["d_mm"]) else 4
    return KernelParams(
        rows=profile.sensor.rows, cols=profile.sensor.cols,
        pitch_um=profile.sensor.pixel_pitch_um,
        scene_rows=profile.scene.rows, scene_cols=profile.scene.cols,
        scene_pitch_um=profile.scene.pixel_pitch_um,
        feature_um=profile.mask.feature_um,
        phi=tuple(profile.mask.phi), phi_rows=tuple(profile.mask.rows_vector),
        channels=len(profile.sensor.channels), n_sub=n_sub, rank_tol=rank_tol,
        force_direct=force_direct, **fields,
    )
