"""Real2Sim against the simulation ``diagnose-tactile`` fitted to the sensor (issue 29 item 4):
the fitted sim domain, the generator file carrying the fitted section, and the held-out
annotation-free figures of every row."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import ThinTactError
from thintact_sdk.tactile.calibration.press_pack import evaluate_pack, load_press_pack
from thintact_sdk.tactile.learning import Real2SimTranslator
from thintact_sdk.tactile.learning.domains import RealPresses
from thintact_sdk.tactile.learning.evaluate import ball_figures, translate_pack
from thintact_sdk.tactile.learning.fitted_domain import fitted_simulated_presses

DATA = resources.files("thintact_sdk") / "data" / "gelsight"
FITTED = Path(str(DATA / "gelsight-fitted-tactile.yaml"))
PACK = Path(str(DATA / "gelsight_ball_presses.npz"))


def test_fitted_sim_domain_looks_like_the_sensor_it_was_fitted_to() -> None:
    real = RealPresses.from_pack(PACK)
    sim = fitted_simulated_presses(FITTED, real.reference, 6, 2.0, 0.1245, seed=2)
    assert sim.shape == (7, 120, 160, 3) and sim.dtype == np.float32
    assert 0.0 <= sim.min() and sim.max() <= 1.0
    # the fitted background carries the sensor's colour and field: its flat frame is the
    # real no-contact frame's colour to a few per cent
    np.testing.assert_allclose(sim[0].mean(axis=(0, 1)), real.reference.mean(axis=(0, 1)), atol=0.05)
    # and every press changes the image
    assert all(np.abs(s - sim[0]).max() > 0.05 for s in sim[1:])


def test_fitted_sim_domain_refuses_other_pixel_sizes_and_other_files(tmp_path: Path) -> None:
    real = RealPresses.from_pack(PACK)
    with pytest.raises(ThinTactError, match="0.1245 mm/px"):
        fitted_simulated_presses(FITTED, real.reference, 2, 2.0, 0.2)
    other = tmp_path / "profile.yaml"
    other.write_text("tactile:\n  mm_per_px: 0.1245\n", encoding="utf-8")
    with pytest.raises(ThinTactError, match="profile.yaml.*simulation_effects"):
        fitted_simulated_presses(other, real.reference, 2, 2.0, 0.1245)
    code = tmp_path / "evil.yaml"
    code.write_text("!!python/object/apply:os.system ['echo pwned']\n", encoding="utf-8")
    with pytest.raises(ThinTactError, match="evil.yaml"):
        fitted_simulated_presses(code, real.reference, 2, 2.0, 0.1245)


def test_generator_trained_on_the_fitted_simulation_gives_every_held_out_row(tmp_path: Path,
                                                                            capsys) -> None:
    out = tmp_path / "r2s"
    assert main(["real2sim", "train", "--real", str(PACK), "--out", str(out), "--iterations", "2",
                 "--sim-presses", "3", "--sim-model", str(FITTED), "--device", "cpu"]) == 0
    err = capsys.readouterr().err
    assert "iteration 2/2" in err  # progress lines when stderr is not a terminal
    tr = Real2SimTranslator.load(out / "generator.pt")
    assert tr.meta["sim_model_section"]["tactile"]["simulation_effects"]["effects"]
    assert tr.meta["train_presses"] == [0, 2, 4, 6]

    rows = ball_figures(PACK, tr, model="lut")
    assert list(rows) == ["real", "real2sim", "real2sim+fitted-sim-lut", "real+fitted-sim-lut"]
    for res in rows.values():
        assert res["train"] == [0, 2, 4, 6] and res["test"] == [1, 3, 5, 7]
        s = res["summary"]
        assert s["presses"] == 4 and np.isfinite(s["depth_rms_mm"]) and s["depth_rms_mm"] > 0
    # the real row is exactly `thintact tactile evaluate` on the same split
    direct = evaluate_pack(load_press_pack(PACK), 2.0, 0.1245, [0, 2, 4, 6], "lut")
    assert rows["real"]["summary"] == direct["summary"]
    # the translated pack keeps the annotation and the names, images as uint8
    pack = load_press_pack(PACK)
    moved = translate_pack(pack, tr)
    assert moved.images.dtype == np.uint8 and moved.images.shape == pack.images.shape
    assert moved.names == pack.names and np.array_equal(moved.radii_px, pack.radii_px)
