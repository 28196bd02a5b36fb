"""``saturation``: pixels clip at ``level_dn`` (absolute DN, black included), below the
profile's declared ``saturation_dn``."""

from __future__ import annotations

import numpy as np

from thintact_sdk.physics._spec import EffectSpec, ParamSpec

SPEC = EffectSpec(
    name="saturation",
    stage="dn",
    description="pixels stop responding above a level lower than the declared saturation",
    params={"level_dn": ParamSpec("DN", None, (0.0, 1e6), "clip level (absolute DN); None = saturation_dn")},
)


def apply(signal_dn: np.ndarray, level_dn: float | None, black_level_dn: float) -> np.ndarray:
    """Clip a signal in DN above black at ``level_dn - black_level_dn``."""
    if level_dn is None:
        return signal_dn
    return np.minimum(signal_dn, level_dn - black_level_dn)
