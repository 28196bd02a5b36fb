"""Noise model and the ``thintact simulate`` command."""

from __future__ import annotations

import numpy as np
import pytest

from thintact_sdk.apps.cli.main import main
from thintact_sdk.formats.profiles import NoiseSpec, load_profile
from thintact_sdk.simulation.noise import noise_variance_dn, signal_to_dn

NOISE = NoiseSpec(black_level_dn=64.0, read_noise_dn=2.0, electrons_per_dn=4.0, saturation_dn=4095.0)


def test_noiseless_is_black_plus_signal_clipped():
    s = np.array([[-100.0, 0.0, 12.3, 5000.0]])
    assert np.allclose(signal_to_dn(s, NOISE), [[0.0, 64.0, 76.3, 4095.0]])


def test_noise_statistics_match_variance_model():
    rng = np.random.default_rng(0)
    sig = np.full((200_000,), 800.0)
    dn = signal_to_dn(sig, NOISE, rng)
    assert np.all(dn == np.round(dn))
    assert dn.mean() == pytest.approx(864.0, abs=0.05)
    want = noise_variance_dn(np.array(864.0), NOISE)
    assert want == pytest.approx(800 / 4 + 4 + 1 / 12)
    assert dn.var() == pytest.approx(float(want), rel=0.02)


def test_clip_at_lower_saturation_level():
    dn = signal_to_dn(np.array([3000.0]), NOISE, np.random.default_rng(1), saturation_dn=2000.0)
    assert dn[0] == 2000.0


def _scenes(profile, f=2):
    rng = np.random.default_rng(2)
    return rng.random((f, profile.scene.rows, profile.scene.cols, 3)).astype(np.float32)


def test_cli_simulate_irradiance_and_dn(tmp_path, capsys):
    prof = load_profile("virtual-mini")
    x = _scenes(prof)
    np.save(tmp_path / "s.npy", x)
    assert main(["simulate", "--profile", "virtual-mini", "--scenes", str(tmp_path / "s.npy"),
                 "--out", str(tmp_path / "y.npy")]) == 0
    y = np.load(tmp_path / "y.npy")
    assert y.shape == (2, 128, 160, 3) and y.dtype == np.float64
    assert main(["simulate", "--profile", "virtual-mini", "--scenes", str(tmp_path / "s.npy"),
                 "--out", str(tmp_path / "dn.npy"), "--noise", "--seed", "3", "--gain", "20000"]) == 0
    assert "gain: 20000" in capsys.readouterr().out
    dn = np.load(tmp_path / "dn.npy")
    expected = 64 + 20000 * y
    assert np.abs(dn - expected).mean() < 3 * np.sqrt(np.mean(noise_variance_dn(expected, NOISE)))
    assert np.all(dn == np.round(dn))


def test_the_library_frames_are_the_commands(tmp_path, capsys):
    """``simulate_scenes`` returns the frames ``thintact simulate --noise`` writes (same seed),
    and its default gain is the one the command prints."""
    from thintact_sdk.simulation.scene_batch import simulate_scenes

    prof = load_profile("virtual-mini")
    np.save(tmp_path / "s.npy", _scenes(prof))
    assert main(["simulate", "--profile", "virtual-mini", "--scenes", str(tmp_path / "s.npy"),
                 "--out", str(tmp_path / "dn.npy"), "--noise", "--seed", "5"]) == 0
    printed = capsys.readouterr().out
    steps: list[tuple[int, int]] = []
    made = simulate_scenes(prof, tmp_path / "s.npy", noise=True, seed=5,
                           progress=lambda done, total: steps.append((done, total)))
    np.testing.assert_array_equal(np.load(tmp_path / "dn.npy"), made.frames)
    assert made.gain is not None and f"gain: {made.gain:.6g} DN" in printed
    assert steps == [(1, 2), (2, 2)]
    plain = simulate_scenes(prof, _scenes(prof))
    assert plain.gain is None and plain.frames.shape == (2, 128, 160, 3)


def test_cli_default_gain_puts_white_at_60_percent(tmp_path, capsys):
    prof = load_profile("virtual-mini")
    np.save(tmp_path / "w.npy", np.ones((1, prof.scene.rows, prof.scene.cols, 3)))
    assert main(["simulate", "--profile", "virtual-mini", "--scenes", str(tmp_path / "w.npy"),
                 "--out", str(tmp_path / "y.npy")]) == 0
    y = np.load(tmp_path / "y.npy")
    out = capsys.readouterr().out
    assert main(["simulate", "--profile", "virtual-mini", "--scenes", str(tmp_path / "w.npy"),
                 "--out", str(tmp_path / "dn.npy"), "--noise"]) == 0
    gain = float(capsys.readouterr().out.split("gain:")[1].split()[0])
    assert gain * y.max() == pytest.approx(0.6 * (4095 - 64), rel=1e-5)
    assert out


@pytest.mark.parametrize("problem", ["missing", "shape"])
def test_cli_simulate_user_errors(tmp_path, capsys, problem):
    path = tmp_path / "s.npy"
    if problem == "shape":
        np.save(path, np.zeros((1, 10, 10, 3)))
    rc = main(["simulate", "--profile", "virtual-mini", "--scenes", str(path),
               "--out", str(tmp_path / "y.npy")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("thintact: error:") and "Traceback" not in err
