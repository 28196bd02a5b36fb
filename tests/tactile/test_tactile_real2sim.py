"""Real2Sim: CycleGAN training that resumes bit-identically, the generator file, inference,
the tactile pipeline hook and the held-out evaluation's split discipline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
from thintact_sdk.tactile.learning import Real2SimTranslator
from thintact_sdk.tactile.learning.domains import RealPresses, sensor_profile, simulated_presses
from thintact_sdk.tactile.learning.evaluate import evaluate_real2sim
from thintact_sdk.tactile.learning.train import Real2SimTrainer, TrainConfig
from thintact_sdk.tactile.simulation.indenters import Sphere
from thintact_sdk.tactile.simulation.membrane import TactileSimulator

TINY = dict(batch=2, crop=16, width=4, blocks=1, edge_kernel=3, checkpoint_every=2)


def _domains() -> tuple[np.ndarray, np.ndarray]:
    sim = simulated_presses(sensor_profile(24, 32, 0.25), 3, 1.0, seed=3)
    rng = np.random.default_rng(0)
    real = np.clip(sim[::-1] * 0.8 + 0.15 + 0.02 * rng.standard_normal(sim.shape), 0, 1)
    return real.astype(np.float32), sim


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, weights_only=True)["state_dict"]


def test_resumed_training_is_bit_identical_to_an_uninterrupted_run(tmp_path: Path) -> None:
    real, sim = _domains()
    straight = Real2SimTrainer(real, sim, tmp_path / "a", TrainConfig(iterations=4, **TINY), "cpu")
    straight.run()
    first = Real2SimTrainer(real, sim, tmp_path / "b", TrainConfig(iterations=2, **TINY), "cpu")
    first.run()
    second = Real2SimTrainer(real, sim, tmp_path / "b", TrainConfig(iterations=4, **TINY), "cpu")
    assert second.resume() and second.iteration == 2
    second.run()
    a, b = _weights(tmp_path / "a" / "generator.pt"), _weights(tmp_path / "b" / "generator.pt")
    assert a.keys() == b.keys()
    assert all(np.isfinite(r["cycle"]) and np.isfinite(r["d"]) for r in straight.history)
    for k in a:
        assert torch.equal(a[k], b[k]), k
    # the training moved the weights at all
    fresh = Real2SimTrainer(real, sim, tmp_path / "c", TrainConfig(iterations=4, **TINY), "cpu")
    moved = [not torch.equal(v, fresh.model.real_to_sim.state_dict()[k]) for k, v in a.items()]
    assert any(moved)


def test_resume_refuses_a_checkpoint_of_another_network(tmp_path: Path) -> None:
    real, sim = _domains()
    Real2SimTrainer(real, sim, tmp_path, TrainConfig(iterations=2, **TINY), "cpu").run()
    other = Real2SimTrainer(real, sim, tmp_path, TrainConfig(iterations=2, **{**TINY, "width": 6}),
                            "cpu")
    with pytest.raises(ThinTactError, match="width=4"):
        other.resume()
    (tmp_path / "checkpoint.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ThinTactError, match="unreadable checkpoint"):
        Real2SimTrainer(real, sim, tmp_path, TrainConfig(iterations=2, **TINY), "cpu").resume()


def test_translator_keeps_any_image_size_and_range(tmp_path: Path) -> None:
    real, sim = _domains()
    Real2SimTrainer(real, sim, tmp_path, TrainConfig(iterations=1, **TINY), "cpu").run()
    tr = Real2SimTranslator.load(tmp_path / "generator.pt", "cpu")
    for shape in ((30, 42, 3), (2, 24, 32, 3)):
        out = tr(np.random.default_rng(1).random(shape, dtype=np.float32))
        assert out.shape == shape and out.dtype == np.float32
        assert np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1
    with pytest.raises(ThinTactError, match="H×W×3"):
        tr(np.zeros((8, 8)))


def test_bad_generator_files_are_clear_errors(tmp_path: Path) -> None:
    bad = tmp_path / "g.pt"
    bad.write_bytes(b"\x00garbage")
    with pytest.raises(ThinTactError, match="not a Real2Sim generator"):
        Real2SimTranslator.load(bad)
    torch.save({"format": "something-else"}, bad)
    with pytest.raises(ThinTactError, match="thintact-real2sim/1"):
        Real2SimTranslator.load(bad)
    with pytest.raises(ThinTactError, match="no such"):
        Real2SimTranslator.load(tmp_path / "missing.pt")


def test_profile_real2sim_setting_puts_the_translator_in_the_interpreter(tmp_path: Path) -> None:
    """``tactile.real2sim`` is loaded by the interpreter, and the translation is applied to
    every image before photometric stereo (an inverting translator changes the depth)."""
    real, sim = _domains()
    Real2SimTrainer(real, sim, tmp_path, TrainConfig(iterations=1, **TINY), "cpu").run()
    base = load_profile("virtual-finger")
    tac = base.tactile.model_copy(update={"real2sim": str(tmp_path / "generator.pt")})
    interp = TactileInterpreter.for_profile(base.model_copy(update={"tactile": tac}))
    assert isinstance(interp.translator, Real2SimTranslator)

    sim_ = TactileSimulator.for_profile(base)
    flat, press = sim_.flat().scene, sim_.press(Sphere(2.0), 0.8).scene
    plain = TactileInterpreter.for_profile(base)
    inverted = TactileInterpreter(base, plain.lut, translator=lambda im: 1.0 - im)
    identity = TactileInterpreter(base, plain.lut, translator=lambda im: im)
    depths = []
    for it in (plain, identity, inverted):
        it.set_reference(flat)
        depths.append(it.depth_from_image(press))
    np.testing.assert_array_equal(depths[0], depths[1])
    assert np.abs(depths[0] - depths[2]).max() > 0.05


def test_evaluation_refuses_presses_the_generator_was_trained_on(
    tmp_path: Path, shared_dir: Path
) -> None:
    pack = shared_dir / "data" / "taxim_gelsight_ball_small" / "dataPack_small.npz"
    rc = main(["real2sim", "train", "--real", str(pack), "--out", str(tmp_path),
               "--iterations", "1", "--sim-presses", "2", "--device", "cpu"])
    assert rc == 0
    tr = Real2SimTranslator.load(tmp_path / "generator.pt")
    assert tr.meta["train_presses"] == list(range(0, 49, 2))
    with pytest.raises(ThinTactError, match="training set"):
        evaluate_real2sim(pack, tr, train=list(range(0, 10)))
    assert RealPresses.from_pack(pack).images.shape == (49, 120, 160, 3)


def test_cli_train_rejects_bad_input_with_exit_2(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.npz"
    np.savez(bad, imgs=np.zeros((2, 8, 8)))
    assert main(["real2sim", "train", "--real", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "imgs" in capsys.readouterr().err
