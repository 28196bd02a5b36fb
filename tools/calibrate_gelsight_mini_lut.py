"""Regenerate thintact_sdk/data/gelsight/gelsight-mini-lut.npz (the gelsight-mini profile's LUT).

Calibrated from the 8 real GelSight ball presses vendored in thintact_sdk/data/gelsight/
(Taxim, MIT, 4.00 mm ball, 0.1245 mm/px) with the SDK's image-only ball-press calibration
(press found in the image, smoothed-cap fit, one refinement), exactly as
`thintact calibrate-tactile --profile gelsight-mini` does on a live unit.

    python tools/calibrate_gelsight_mini_lut.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.tactile.calibration.ball_press import BallPress, calibrate_from_presses
from thintact_sdk.tactile.calibration.gelsight_eval import GELSIGHT_BALL_RADIUS_MM

DATA = Path(__file__).resolve().parents[1] / "thintact_sdk" / "data" / "gelsight"


def main() -> None:
    profile = load_profile("gelsight-mini")
    with np.load(DATA / "gelsight_ball_presses.npz", allow_pickle=False) as z:
        f0 = z["f0"].astype(np.float32) / 255.0
        presses = [BallPress(img.astype(np.float32) / 255.0) for img in z["imgs"]]
        names = [str(n) for n in z["names"]]
    lut = calibrate_from_presses(
        profile, f0, presses, GELSIGHT_BALL_RADIUS_MM, bins=24,
        meta={"source": "Taxim dataPack_small.npz (MIT, (c) 2021 CMURoboTouch): "
                        + ", ".join(names),
              "made_by": "tools/calibrate_gelsight_mini_lut.py"},
    )
    path = lut.save(DATA / "gelsight-mini-lut.npz")
    print(f"wrote {path} ({lut.meta['calibration_pixels']} pixels)")


if __name__ == "__main__":
    main()
