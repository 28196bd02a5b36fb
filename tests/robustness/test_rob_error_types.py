"""Bad user data raises a ThinTactError naming what is wrong (the CLI then prints one line and
exits 2), never a bare ValueError that the CLI would report as an internal error. The new
error types also derive from ValueError, so code that caught that still works."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from thintact_sdk.errors import InvalidShapeError, InvalidValueError, ThinTactError
from thintact_sdk.pixels.bayer import bin_bayer
from thintact_sdk.reconstruction.metrics import psnr
from thintact_sdk.reconstruction.tikhonov import TikhonovSolver
from thintact_sdk.simulation.scenes import make_scene

CASES: list[tuple[str, Callable[[], object], type, str]] = [
    ("odd mosaic", lambda: bin_bayer(np.zeros((3, 4), np.uint16), "RGGB"), InvalidShapeError, "even"),
    ("unknown CFA", lambda: bin_bayer(np.zeros((4, 4), np.uint16), "XYZW"), InvalidValueError,
     "unknown Bayer pattern"),
    ("unknown scene", lambda: make_scene("nope", 8, 8), InvalidValueError, "unknown scene"),
    ("negative tau", lambda: TikhonovSolver(np.eye(3), np.eye(3), -1.0), InvalidValueError, "tau"),
    ("psnr shapes", lambda: psnr(np.zeros((2, 2)), np.zeros((3, 3))), InvalidShapeError, "shape"),
]


@pytest.mark.parametrize(("label", "call", "kind", "words"), CASES, ids=[c[0] for c in CASES])
def test_core_user_data_errors_are_thintact_errors(label: str, call: Callable[[], object], kind: type,
                                                    words: str) -> None:
    with pytest.raises(kind, match=words) as info:
        call()
    assert isinstance(info.value, ThinTactError) and isinstance(info.value, ValueError)


def test_plugin_user_data_errors_are_thintact_errors() -> None:
    from thintact_serial_led.protocol import level_to_wire

    from thintact_sdk.reconstruction.decoders.backend import ArrayBackend
    from thintact_sdk.reconstruction.decoders.shapes import check_measurement_shape

    with pytest.raises(InvalidShapeError, match="measurement must be 4×5×3"):
        check_measurement_shape(np.zeros((4, 4, 3)), (4, 5), 3)
    with pytest.raises(InvalidValueError, match="backend must be"):
        ArrayBackend("jax")
    with pytest.raises(InvalidValueError, match=r"LED level 1.5 outside \[0, 1\]"):
        level_to_wire(1.5)


def test_a_sensor_with_a_bad_decoder_setting_fails_with_a_thintact_error() -> None:
    """Through the robot API: an invalid decoder setting in the profile is a user error."""
    import thintact_sdk
    from thintact_sdk.formats.profiles import load_profile

    profile = load_profile("virtual-mini")
    data = profile.contract_dict()
    data["decoder"] = {"plugin": "thintact-noniterative", "settings": {"fold": "sideways"}}
    from thintact_sdk.formats.profiles import profile_from_dict

    bad = profile_from_dict(data, where="test")
    with pytest.raises(ThinTactError, match="fold must be"):
        thintact_sdk.open(bad).decoder  # noqa: B018 - building the decoder is the point
