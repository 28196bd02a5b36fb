"""Indenter shapes pressed into the elastomer (paper §VI-C: sphere, chamfered prism, ...).

Every indenter describes the gap between its tip and the plane through its lowest point,
``gap_mm(u_mm, v_mm) >= 0``, in its own frame (u along the indenter's length axis, v across,
both in mm, origin at the tip centre); ``inf`` where the indenter has no material.
Pressing it ``depth_mm`` into a flat membrane indents the membrane by
``max(0, depth_mm - gap_mm)`` (rigid indenter, before elastomer smoothing).
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np


class Indenter(abc.ABC):
    """A rigid indenter; subclasses define the tip gap profile in mm."""

    name: str = "indenter"

    @abc.abstractmethod
    def gap_mm(self, u_mm: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        """Gap between the tip and its lowest plane, mm; ``inf`` outside the indenter.

        Parameters
        ----------
        u_mm, v_mm
            Arrays of the same shape, coordinates in the indenter frame in mm.
        """

    def indentation_mm(
        self,
        x_mm: np.ndarray,
        y_mm: np.ndarray,
        depth_mm: float,
        center_mm: tuple[float, float] = (0.0, 0.0),
        angle_deg: float = 0.0,
    ) -> np.ndarray:
        """Rigid indentation of the membrane (mm, ≥ 0) on the grid ``x_mm × y_mm``.

        Parameters
        ----------
        x_mm, y_mm
            ``N × M`` membrane coordinates in mm (CONTRACTS §1 axes).
        depth_mm
            How far the tip is pressed below the undeformed membrane, mm.
        center_mm
            (x, y) of the tip centre in mm.
        angle_deg
            Rotation of the indenter's u axis from +x towards +y, degrees.
        """
        a = np.deg2rad(angle_deg)
        dx = x_mm - center_mm[0]
        dy = y_mm - center_mm[1]
        u = np.cos(a) * dx + np.sin(a) * dy
        v = -np.sin(a) * dx + np.cos(a) * dy
        gap = self.gap_mm(u, v)
        return np.clip(depth_mm - gap, 0.0, None)


@dataclass
class Sphere(Indenter):
    """A ball of radius ``radius_mm`` (paper: 4 mm sphere; LUT calibration: 3 mm ball)."""

    radius_mm: float = 2.0
    name: str = "sphere"

    def gap_mm(self, u_mm: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        r2 = u_mm**2 + v_mm**2
        rr = self.radius_mm**2
        out = np.full(np.shape(r2), np.inf)
        inside = r2 < rr
        out[inside] = self.radius_mm - np.sqrt(rr - r2[inside])
        return out


@dataclass
class Cylinder(Indenter):
    """A cylinder lying on its side: axis along u, ``length_mm`` long, ``radius_mm`` round."""

    radius_mm: float = 1.5
    length_mm: float = 8.0
    name: str = "cylinder"

    def gap_mm(self, u_mm: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        rr = self.radius_mm**2
        out = np.full(np.shape(u_mm), np.inf)
        inside = (v_mm**2 < rr) & (np.abs(u_mm) <= self.length_mm / 2)
        out[inside] = self.radius_mm - np.sqrt(rr - v_mm[inside] ** 2)
        return out


@dataclass
class ChamferedPrism(Indenter):
    """A rectangular prism whose flat face ``length_mm × width_mm`` (outer size) has all
    four edges chamfered at 45° by ``chamfer_mm``; beyond the chamfer the sides are vertical."""

    length_mm: float = 6.0
    width_mm: float = 4.0
    chamfer_mm: float = 1.0
    name: str = "chamfered_prism"

    def gap_mm(self, u_mm: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        du = np.abs(u_mm) - (self.length_mm / 2 - self.chamfer_mm)
        dv = np.abs(v_mm) - (self.width_mm / 2 - self.chamfer_mm)
        gap = np.clip(np.maximum(du, dv), 0.0, None)
        outside = (np.abs(u_mm) > self.length_mm / 2) | (np.abs(v_mm) > self.width_mm / 2)
        return np.where(outside, np.inf, gap)


@dataclass
class CubeEdge(Indenter):
    """A cube pressed edge-first: a 90° wedge along u (faces at 45°), ``length_mm`` long."""

    length_mm: float = 8.0
    side_mm: float = 5.0
    name: str = "cube_edge"

    def gap_mm(self, u_mm: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        half_width = self.side_mm / np.sqrt(2.0)
        gap = np.abs(v_mm)
        outside = (np.abs(u_mm) > self.length_mm / 2) | (np.abs(v_mm) > half_width)
        return np.where(outside, np.inf, gap)


@dataclass
class Texture(Indenter):
    """A flat stamp ``size_mm`` square carrying a sinusoidal grating along u:
    gap = amplitude·(1 − cos(2πu/period))/2 (ridges touch first)."""

    period_mm: float = 1.0
    amplitude_mm: float = 0.2
    size_mm: float = 8.0
    name: str = "texture"

    def gap_mm(self, u_mm: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        gap = self.amplitude_mm * 0.5 * (1.0 - np.cos(2 * np.pi * u_mm / self.period_mm))
        outside = (np.abs(u_mm) > self.size_mm / 2) | (np.abs(v_mm) > self.size_mm / 2)
        return np.where(outside, np.inf, gap)


@dataclass
class Text(Indenter):
    """A stamp with raised letters: the letters touch first, the plate between them is
    ``relief_mm`` higher. Letters are ``height_mm`` tall (Hershey simplex font)."""

    text: str = "TAC"
    height_mm: float = 3.0
    relief_mm: float = 0.3
    stroke_mm: float = 0.5
    name: str = "text"

    def gap_mm(self, u_mm: np.ndarray, v_mm: np.ndarray) -> np.ndarray:
        import cv2

        res_mm = 0.02  # raster of the letter shapes
        font = cv2.FONT_HERSHEY_SIMPLEX
        scale = self.height_mm / res_mm / 22.0  # Hershey simplex capitals ≈ 22 px at scale 1
        thick = max(1, int(round(self.stroke_mm / res_mm)))
        (tw, th), base = cv2.getTextSize(self.text, font, scale, thick)
        pad = thick + 4
        img = np.zeros((th + base + 2 * pad, tw + 2 * pad), np.uint8)
        cv2.putText(img, self.text, (pad, pad + th), font, scale, 255, thick, cv2.LINE_AA)
        h_px, w_px = img.shape
        cu = (np.asarray(u_mm) / res_mm + w_px / 2).round().astype(int)
        cv = (np.asarray(v_mm) / res_mm + h_px / 2).round().astype(int)
        inside = (cu >= 0) & (cu < w_px) & (cv >= 0) & (cv < h_px)
        ink = np.zeros(np.shape(u_mm))
        ink[inside] = img[cv[inside], cu[inside]] / 255.0
        gap = self.relief_mm * (1.0 - ink)
        return np.where(inside, gap, np.inf)


INDENTERS: dict[str, type[Indenter]] = {
    "sphere": Sphere,
    "cylinder": Cylinder,
    "chamfered_prism": ChamferedPrism,
    "cube_edge": CubeEdge,
    "texture": Texture,
    "text": Text,
}


def make_indenter(name: str, **params: float | str) -> Indenter:
    """Build an indenter by name (``sphere``, ``cylinder``, ``chamfered_prism``,
    ``cube_edge``, ``texture``, ``text``) with its dataclass parameters."""
    if name not in INDENTERS:
        from thintact_sdk.errors import ThinTactError

        raise ThinTactError(f"unknown indenter {name!r}; one of {', '.join(INDENTERS)}")
    return INDENTERS[name](**params)  # type: ignore[arg-type]
