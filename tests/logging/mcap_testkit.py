"""Deterministic frames for the MCAP log tests (no decoding: fast and exact)."""

from __future__ import annotations

import numpy as np

from thintact_sdk.formats.profiles import Profile, load_profile
from thintact_sdk.frames import RawFrame, TactileFrame

PERIOD_NS = 33_000_000
T0_NS = 5_000_000_000


def mini_profile() -> Profile:
    return load_profile("virtual-mini")


def raw_frame(i: int, shape: tuple[int, int] = (256, 320)) -> RawFrame:
    """Frame ``i``: a uint16 12-bit mosaic whose values depend on ``i``."""
    rng = np.random.default_rng(i)
    data = rng.integers(0, 4096, size=shape, dtype=np.uint16)
    return RawFrame(data=data, timestamp_ns=T0_NS + i * PERIOD_NS, frame_id=100 + i,
                    pixel_format="BayerRG12")


def tactile_frame(i: int, with_force: bool = False) -> TactileFrame:
    """Frame ``i``'s tactile frame (50 × 64 scene of virtual-mini, 6 markers)."""
    rng = np.random.default_rng(1000 + i)
    positions = rng.random((6, 2), dtype=np.float32) * 10
    positions[0] = np.nan
    return TactileFrame(
        image=rng.random((50, 64, 3), dtype=np.float32),
        depth_mm=rng.random((50, 64), dtype=np.float32) * 0.8,
        marker_positions_mm=positions,
        marker_displacements_mm=rng.normal(0, 0.1, (6, 2)).astype(np.float32),
        contact=bool(i % 2),
        contact_area_mm2=float(i) * 1.5,
        timestamp_ns=T0_NS + i * PERIOD_NS,
        frame_id=100 + i,
        shear_direction_rad=0.25 * i,
        latency_ms=12.5,
        force_n=np.array([0.1 * i, -0.2, 1.0 + i]) if with_force else None,
        slip_ratio=0.1 * i if with_force else None,
    )
