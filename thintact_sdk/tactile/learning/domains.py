"""The two unpaired image domains Real2Sim learns to map between.

* real: tactile images of a physical sensor (a ``dataPack``-style ``.npz``: ``imgs``
  ``P × H × W × 3`` uint8 presses and ``f0`` the no-contact frame, as Taxim ships its
  GelSight data);
* sim: the SDK's tactile simulation of the same sensor (same grid and pixel size, no
  markers on a marker-free gel), ball presses at random places and depths.

Images are ``H × W × 3`` float32 in [0, 1] (display units) everywhere outside the networks.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile, SceneSpec, TactileConfig, load_profile
from thintact_sdk.formats.safe_arrays import array_size_limit, read_npz
from thintact_sdk.tactile.interpretation.grid import TactileParams
from thintact_sdk.tactile.simulation.indenters import Sphere
from thintact_sdk.tactile.simulation.membrane import TactileScene, TactileSimulator


@dataclass
class RealPresses:
    """Real press images and their no-contact frame.

    Attributes
    ----------
    images
        ``P × H × W × 3`` float32 in [0, 1].
    reference
        ``H × W × 3`` float32 no-contact frame.
    source
        Where they came from (for reports).
    """

    images: np.ndarray
    reference: np.ndarray
    source: str

    @classmethod
    def from_pack(cls, path: str | Path) -> RealPresses:
        """Read a ``dataPack``-style ``.npz`` (``imgs``, ``f0``; other members are not read).

        Read with :func:`thintact_sdk.formats.safe_arrays.read_npz`: never unpickles, refuses declared
        sizes beyond the memory there is.

        Raises
        ------
        ThinTactError
            Naming the file (and member): not a press pack, damaged, a pickled or non-numeric
            member, wrong shapes, or NaN/Inf values.
        """
        p = Path(path)
        # the images are converted to float32 below: keep room for that copy (4× a uint8 pack)
        pack = read_npz(p, what="tactile press pack with 'imgs' and 'f0'",
                        members=("imgs", "f0"), kinds="uif", limit=array_size_limit() // 5)
        imgs, f0 = pack["imgs"], pack["f0"]
        if imgs.ndim != 4 or imgs.shape[-1] != 3 or f0.shape != imgs.shape[1:]:
            raise ThinTactError(
                f"{p}: 'imgs' must be P×H×W×3 and 'f0' H×W×3, got {imgs.shape} and {f0.shape}")
        scale = 255.0 if imgs.dtype == np.uint8 else 1.0
        images = imgs.astype(np.float32) / scale
        reference = f0.astype(np.float32) / scale
        for name, arr in (("imgs", images), ("f0", reference)):
            if not np.isfinite(arr).all():
                raise ThinTactError(f"{p}: '{name}' holds NaN or Inf values")
        return cls(images, reference, str(p))

    def subset(self, indices: list[int]) -> np.ndarray:
        """The press images at ``indices`` (``len × H × W × 3``)."""
        return self.images[np.asarray(indices, dtype=np.int64)]


def sensor_profile(rows: int, cols: int, mm_per_px: float, elastomer_sigma_mm: float = 0.25,
                   name: str = "real2sim-sensor") -> Profile:
    """A profile of a lens-based tactile sensor's image grid for the tactile simulator
    (only ``scene`` and ``tactile`` matter; the rest is the virtual finger's)."""
    return load_profile("virtual-finger").model_copy(
        update={
            "name": name,
            "scene": SceneSpec(rows=rows, cols=cols, pixel_pitch_um=mm_per_px * 1000),
            "tactile": TactileConfig.model_validate(
                {"mm_per_px": mm_per_px, "elastomer_sigma_mm": elastomer_sigma_mm}),
        },
        deep=True,
    )


def ball_presses(
    profile: Profile,
    count: int,
    ball_radius_mm: float,
    depth_range_mm: tuple[float, float],
    rng: np.random.Generator,
) -> tuple[TactileScene, list[TactileScene]]:
    """The flat membrane and ``count`` marker-free presses of a ball at random places (the
    ball inside the field by half its radius) and depths, on ``profile``'s grid."""
    params = TactileParams.from_profile(profile)
    sim = TactileSimulator(params, markers=False)
    half_w = params.cols / 2 * params.mm_per_px - 0.5 * ball_radius_mm
    half_h = params.rows / 2 * params.mm_per_px - 0.5 * ball_radius_mm
    if half_w <= 0 or half_h <= 0:
        raise ThinTactError(
            f"a {2 * ball_radius_mm:g} mm ball does not fit the {params.cols}×{params.rows} px "
            f"field at {params.mm_per_px:g} mm/px")
    presses = []
    for _ in range(count):
        centre = (float(rng.uniform(-half_w, half_w)), float(rng.uniform(-half_h, half_h)))
        presses.append(sim.press(Sphere(ball_radius_mm), float(rng.uniform(*depth_range_mm)),
                                 centre))
    return sim.flat(), presses


def simulated_presses(
    profile: Profile,
    count: int,
    ball_radius_mm: float,
    depth_range_mm: tuple[float, float] = (0.4, 1.5),
    seed: int = 0,
    noise_std: float = 0.01,
) -> np.ndarray:
    """The sim domain: ``count`` marker-free ball presses at random places and depths
    (:func:`ball_presses`), plus the flat membrane as image 0, each with Gaussian camera
    noise of ``noise_std`` (display units; a real camera's images are never exactly uniform,
    and an exactly uniform training crop makes instance normalisation's gradient blow up to
    NaN).

    Returns
    -------
    numpy.ndarray
        ``(count + 1) × H × W × 3`` float32 in [0, 1].
    """
    rng = np.random.default_rng(seed)
    flat, presses = ball_presses(profile, count, ball_radius_mm, depth_range_mm, rng)
    return with_camera_noise([flat.scene] + [p.scene for p in presses], noise_std, rng)


def with_camera_noise(images: list[np.ndarray], noise_std: float, rng: np.random.Generator
                      ) -> np.ndarray:
    """``images`` stacked, plus Gaussian noise of ``noise_std`` (display units), clipped to
    [0, 1]: ``N × H × W × 3`` float32."""
    stack = np.stack(images).astype(np.float64)
    stack += noise_std * rng.standard_normal(stack.shape)
    return np.clip(stack, 0.0, 1.0).astype(np.float32)

