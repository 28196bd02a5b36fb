"""Concealed-pose flat fields made with the exact simulator (issue 32): the estimate must be
right or say it is unsure, never confidently wrong.

A 200-cell random φ (and a different φ_rows) of 20 um cells on a 128×160 sensor of 10 um
pixels (the mask 4 mm, the sensor sees about 1.3 mm of it), mounted in one of the 8 ways,
turned by up to 3° more, shifted by up to 1 mm, with the true pixel pitch up to ±10 % off the
profile's (the shadow's scale off by as much; the pose is told the pitch is unknown). The scene
grid is coarse (6×8 pixels of 126 um: the same lit area, so the same flat field) to keep the
rotated-mask simulator fast. One capture with the profile's noise, peaking at 2000 DN.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from independent_device import mounted_profile, small_profile

from thintact_sdk.calibration.pose import PoseEstimate
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.reconstruction.mask_orientation import ORIENTATIONS, Orientation
from thintact_sdk.simulation.simulator import Simulator

WHITE_DN = 2000.0


def nominal_profile(rows: int = 128, cols: int = 160, shared_sequence: bool = False) -> Profile:
    """The design the pose is told (its pitch 10 um, z 4.8 mm)."""
    p = small_profile(("G",), rows=rows, cols=cols, k=200, scene=(6, 8))
    p = p.model_copy(update={"scene": p.scene.model_copy(update={"pixel_pitch_um": 126.0})})
    if shared_sequence:
        d = p.contract_dict()
        d["mask"]["phi_rows"] = list(d["mask"]["phi"])
        p = Profile.model_validate(d)
    return p


@dataclass(frozen=True)
class ConcealedCase:
    orientation: Orientation
    angle_deg: float
    dx_um: float
    dy_um: float
    pitch_factor: float

    def label(self) -> str:
        return (f"{self.orientation.name} {self.angle_deg:+.2f}° ({self.dx_um:+.0f}, {self.dy_um:+.0f}) um "
                f"pitch×{self.pitch_factor:.3f}")


def random_cases(n: int, seed: int) -> list[ConcealedCase]:
    """``n`` cases, the mountings in turn (all 8 when n ≥ 8), the rest of the pose uniform."""
    rng = np.random.default_rng(seed)
    return [ConcealedCase(ORIENTATIONS[i % 8], float(rng.uniform(-3, 3)), float(rng.uniform(-1000, 1000)),
                          float(rng.uniform(-1000, 1000)), float(rng.uniform(0.9, 1.1))) for i in range(n)]


def truth_profile(nominal: Profile, case: ConcealedCase) -> Profile:
    t = mounted_profile(nominal, case.orientation, case.angle_deg, case.dx_um, case.dy_um,
                        nominal.geometry.scene_to_mask_mm)
    return t.model_copy(update={"sensor": t.sensor.model_copy(update={
        "pixel_pitch_um": nominal.sensor.pixel_pitch_um * case.pitch_factor})})


def flat_field(truth: Profile, rng: np.random.Generator | None) -> np.ndarray:
    """The simulator's flat field of ``truth`` (DN above black), noisy when ``rng`` is given."""
    lin = Simulator(truth).linear_batch(np.ones((1, truth.scene.rows, truth.scene.cols, 1)))[0, ..., 0]
    flat = lin / float(lin.max()) * WHITE_DN
    if rng is None:
        return flat
    e = truth.noise.electrons_per_dn
    return np.round(rng.poisson(np.clip(flat, 0, None) * e) / e + rng.normal(0, truth.noise.read_noise_dn, flat.shape))


def judge(est: PoseEstimate, nominal: Profile, truth: Profile, case: ConcealedCase) -> str:
    """``"right"``, ``"unsure"`` (whatever it found) or ``"WRONG"`` (confident and wrong: the
    mounted mask differs, the turn is off by more than 0.25°, an offset by more than half a
    cell, or the pitch by more than 1 %)."""
    vx, vy = est.orientation.apply(np.asarray(nominal.mask.phi), np.asarray(nominal.mask.rows_vector))
    same_mask = np.array_equal(vx, truth.mask.phi) and np.array_equal(vy, truth.mask.rows_vector)
    half_cell = nominal.mask.feature_um / 2
    close = (abs(est.angle_deg - case.angle_deg) <= 0.25 and abs(est.dx_um - case.dx_um) <= half_cell
             and abs(est.dy_um - case.dy_um) <= half_cell
             and abs(est.pixel_pitch_um / truth.sensor.pixel_pitch_um - 1) <= 0.01)
    if not est.confident:
        return "unsure"
    return "right" if same_mask and close else "WRONG"
