"""The diagnosis's generic optimisers and its deadline, on problems with known answers
(no simulator), and the rule that neither they nor the selection policy name an effect."""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np
import pytest

from thintact_sdk.diagnosis.imaging import candidates, optimise, select, words
from thintact_sdk.diagnosis.imaging import engine as run
from thintact_sdk.diagnosis.imaging import forward_model as model
from thintact_sdk.diagnosis.imaging.candidates import CANDIDATES
from thintact_sdk.diagnosis.imaging.deadline import Deadline, DeadlineExpired


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@dataclass
class Ev:
    pred_dn: np.ndarray
    chi2: float


def _problem(truth: np.ndarray) -> tuple[optimise.WeightedData, object]:
    """3 channels; channel c is ``x[c]·exp(−t/x[3])`` (x[0..2] a channel block, x[3] shared)."""
    t = np.linspace(0.0, 4.0, 50)

    def model(x: np.ndarray) -> np.ndarray:
        return np.stack([x[c] * np.exp(-t / x[3]) for c in range(3)], axis=-1)

    data = optimise.WeightedData(model(truth), np.full((50, 3), 1e8))  # χ² in noise units

    def evaluate(x: np.ndarray) -> Ev:
        p = model(x)
        return Ev(p, float(np.sum(data.weights * (data.measured - p) ** 2)))

    return data, evaluate


def test_deadline_expires_checks_and_shares() -> None:
    clock = FakeClock()
    d = Deadline.after(10.0, clock)
    assert not d.expired() and d.remaining_s() == pytest.approx(10.0) and d.allows(9.0)
    half = d.share(0.5)
    clock.t += 6.0
    assert half.expired() and not d.expired() and not d.allows(5.0)
    d.check("fit")
    clock.t += 5.0
    with pytest.raises(DeadlineExpired, match="fit stopped"):
        d.check("fit")
    assert not Deadline.never().expired() and Deadline.never().share(0.1).remaining_s() == np.inf


def test_levenberg_marquardt_recovers_a_channel_block_and_a_shared_parameter() -> None:
    truth = np.array([2.0, 1.5, 0.7, 1.3])
    data, evaluate = _problem(truth)
    x0 = np.array([1.0, 1.0, 1.0, 1.0])
    box = optimise.Box(np.full(4, 0.1), np.full(4, 10.0))
    x, ev = optimise.levenberg_marquardt(
        evaluate, x0, evaluate(x0), data, box, np.full(4, 1e-4), range(4), Deadline.never(), 40,
        channel_blocks=[[0, 1, 2]],
    )
    np.testing.assert_allclose(x, truth, rtol=1e-4)
    assert ev.chi2 < 1.0


def test_optimisers_stop_at_an_expired_deadline_and_keep_the_start() -> None:
    data, evaluate = _problem(np.array([2.0, 1.5, 0.7, 1.3]))
    x0 = np.ones(4)
    box = optimise.Box(np.full(4, 0.1), np.full(4, 10.0))
    gone = Deadline(end=0.0, clock=lambda: 1.0)
    x, _ = optimise.levenberg_marquardt(evaluate, x0, evaluate(x0), data, box, np.full(4, 1e-4),
                                        range(4), gone, 40)
    np.testing.assert_array_equal(x, x0)


def test_parabola_finds_the_vertex_and_line_search_the_best_multiple() -> None:
    def evaluate(x: np.ndarray) -> Ev:
        return Ev(x.copy(), float((x[0] - 0.3) ** 2 + 1.0))

    box = optimise.Box(np.array([-5.0]), np.array([5.0]))
    x, ev = optimise.parabola(evaluate, np.array([0.0]), evaluate(np.array([0.0])), 0, 0.5, box)
    assert x[0] == pytest.approx(0.3) and ev.chi2 == pytest.approx(1.0)
    x, _ = optimise.line_search(evaluate, np.array([0.0]), evaluate(np.array([0.0])),
                                np.array([0.15]), box, Deadline.never())
    assert x[0] == pytest.approx(0.3)  # t = 2 of (1, 0.5, 2, 4, 8)
    small = optimise.Box(np.array([-5.0]), np.array([0.1]))
    x, _ = optimise.parabola(evaluate, np.array([0.0]), evaluate(np.array([0.0])), 0, 0.5, small)
    assert x[0] == pytest.approx(0.1)  # the bound holds


def test_bounded_quadratic_keeps_one_sided_parameters_on_their_side() -> None:
    h = np.eye(2)
    a, gain = optimise.bounded_quadratic(np.array([-1.0, 2.0]), h, (False, True))
    np.testing.assert_allclose(a, [0.0, 2.0], atol=1e-9)
    assert gain == pytest.approx(4.0)
    a, _ = optimise.bounded_quadratic(np.array([-1.0, 2.0]), h, (True, True))
    np.testing.assert_allclose(a, [-1.0, 2.0], atol=1e-9)


def test_diagnosis_modules_name_no_effect() -> None:
    """What is particular to an effect lives in its declaration (thintact_sdk.simulation.effects)."""
    for module in (optimise, select, model, candidates, words, run):
        src = inspect.getsource(module)
        named = [n for n in CANDIDATES if f'"{n}"' in src or f"'{n}'" in src]
        assert named == [], f"{module.__name__} special-cases {named}"


def test_optical_candidate_out_of_reach_is_not_line_searched():
    """An optical candidate is line-searched only while LINE_SEARCH_REACH times its score can
    reach the n_fit-th best line-search Δχ² of the round; cheap domains always are."""
    def res(name: str, score: float, dchi2: float | None = None) -> select.CandidateResult:
        return select.CandidateResult(name, CANDIDATES[name].k, score, np.zeros(CANDIDATES[name].k),
                                      dchi2=dchi2)

    fitted = [res("geometry", 9e5, 1e6), res("sensor_blur", 4e5, 5e5)]
    reach = select.LINE_SEARCH_REACH
    assert select._out_of_reach(res("mask_misalignment", 0.9 * 5e5 / reach), fitted, 2)
    assert not select._out_of_reach(res("mask_misalignment", 1.1 * 5e5 / reach), fitted, 2)
    assert not select._out_of_reach(res("mask_misalignment", 1.0), fitted[:1], 2)  # a slot is free
    assert CANDIDATES["stray_light"].domain != "optical"
    assert not select._out_of_reach(res("stray_light", 1.0), fitted, 2)
