"""The sensor's 10 coloured LEDs and Phong shading of the membrane (paper §V, §VI-C).

Layout (our documented choice; the paper only says "10 side-illuminating LEDs around the
mask, red, green, blue and white"): three red LEDs on the +x edge, three green on the
upper-left (azimuth 120°), three blue on the lower-left (azimuth 240°), and one white on
the +y edge. Each LED group spreads ±15° in azimuth. The LEDs sit at the rim of a 3 mm
elastomer and light the membrane at a low elevation (default 35°); at the scale of the
sensing field they are treated as distant (directional) lights, which is what the
paper's simulation of "ideal tactile images" for photometric stereo assumes.

Frame: z points from the membrane towards the camera (into the elastomer). A membrane
indented by ``depth_mm(x, y)`` (towards the camera) has the camera-facing normal
``n ∝ (−∂d/∂x, −∂d/∂y, 1)``; the camera looks along −z (view vector v = (0, 0, 1)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class LED:
    """One LED: colour (linear R, G, B weights) and direction (azimuth, elevation, degrees)."""

    color: tuple[float, float, float]
    azimuth_deg: float
    elevation_deg: float

    def direction(self) -> np.ndarray:
        """Unit vector from the membrane towards the LED, shape ``(3,)``."""
        a, e = np.deg2rad(self.azimuth_deg), np.deg2rad(self.elevation_deg)
        return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def default_leds(elevation_deg: float = 35.0) -> list[LED]:
    """The 10-LED layout described in the module docstring."""
    red, green, blue, white = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 1.0, 1.0)
    leds: list[LED] = []
    for color, az in ((red, 0.0), (green, 120.0), (blue, 240.0)):
        for spread in (-15.0, 0.0, 15.0):
            leds.append(LED(color, az + spread, elevation_deg))
    leds.append(LED(white, 90.0, elevation_deg))
    return leds


@dataclass
class PhongShading:
    """Phong reflectance of the white membrane under a set of LEDs.

    Intensity in channel c::

        I_c = albedo · (ambient + k_d Σ_k w_k,c max(0, n·l_k)) + k_s Σ_k w_k,c max(0, r_k·v)^α

    scaled by ``gain`` so that the flat white membrane sits at ``flat_level`` in its
    brightest channel, and clipped to [0, 1] (display units).
    """

    leds: list[LED] = field(default_factory=default_leds)
    ambient: float = 0.08
    k_diffuse: float = 1.0
    k_specular: float = 0.15
    shininess: float = 10.0
    flat_level: float = 0.5

    def __post_init__(self) -> None:
        flat = self._raw(np.zeros((1, 1)), np.zeros((1, 1)), np.ones((1, 1)))
        self.gain = self.flat_level / float(flat.max())

    def _raw(self, gx: np.ndarray, gy: np.ndarray, albedo: np.ndarray) -> np.ndarray:
        norm = np.sqrt(gx**2 + gy**2 + 1.0)
        n = np.stack([-gx / norm, -gy / norm, 1.0 / norm], axis=-1)  # ... × 3
        out = np.zeros(gx.shape + (3,))
        for led in self.leds:
            lvec = led.direction()
            ndotl = n @ lvec
            diffuse = self.k_diffuse * np.clip(ndotl, 0.0, None)
            rz = 2.0 * ndotl * n[..., 2] - lvec[2]  # r·v with v = (0, 0, 1)
            spec = self.k_specular * np.clip(rz, 0.0, None) ** self.shininess
            spec = np.where(ndotl > 0, spec, 0.0)
            w = np.asarray(led.color)
            out += (albedo * diffuse)[..., None] * w + spec[..., None] * w
        return out + self.ambient * albedo[..., None]

    def shade(self, gx: np.ndarray, gy: np.ndarray, albedo: np.ndarray | None = None) -> np.ndarray:
        """Shade a surface given its depth gradients.

        Parameters
        ----------
        gx, gy
            ``N × M`` slopes ∂d/∂x, ∂d/∂y of the indentation depth (mm per mm).
        albedo
            ``N × M`` reflectance in [0, 1] (1 white membrane, ≈ 0 black markers).

        Returns
        -------
        numpy.ndarray
            ``N × M × 3`` float32 in [0, 1].
        """
        if albedo is None:
            albedo = np.ones_like(gx)
        return np.clip(self.gain * self._raw(gx, gy, albedo), 0.0, 1.0).astype(np.float32)
