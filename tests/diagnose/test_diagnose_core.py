"""The engine imaging and tactile share (thintact_sdk.diagnosis.core): the forward-selection
loop and its BIC criterion, the residual axes, the report skeleton."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from thintact_sdk.diagnosis.core.forward_selection import InformationCriterion, forward_select
from thintact_sdk.diagnosis.core.report_sections import SECTIONS, diagnosis_report, finding_entry
from thintact_sdk.diagnosis.core.residual_axes import binned_chi2, chi2_in, mean_z_map


@dataclass
class _T:
    name: str
    dchi2: float | None
    k: int


class _Search:
    """Candidates with a fixed Δχ² each, the same every round; ``veto`` is never admitted."""

    def __init__(self, gains: dict[str, tuple[float | None, int]], veto: str = "",
                 second_look: str = "") -> None:
        self.gains, self.veto, self.second_look = gains, veto, second_look
        self.accepted: list[tuple[str, list[str], float]] = []
        self.settled = False
        self.reviews: list[list[str]] = []
        self.reconsidered: list[list[str]] = []

    def has_candidates(self) -> bool:
        return len(self.accepted) < len(self.gains)

    def propose(self) -> list[_T]:
        done = {a[0] for a in self.accepted}
        return [_T(n, d, k) for n, (d, k) in self.gains.items() if n not in done]

    def admits(self, t: _T) -> bool:
        return t.name != self.veto

    def reconsider(self, tried: list[_T]) -> list[_T]:
        self.reconsidered.append([t.name for t in tried])
        return [t for t in tried if t.name == self.second_look]

    def review(self, tried: list[_T], cleared: list[_T]) -> None:
        self.reviews.append([t.name for t in cleared])

    def alternatives(self, best: _T, cleared: list[_T], tried: list[_T]) -> list[_T]:
        return InformationCriterion(np.log(100.0), 10.0).rivals(best, tried, tol=5.0)

    def accept(self, best: _T, alternatives: list[_T], threshold: float) -> None:
        self.accepted.append((best.name, [a.name for a in alternatives], threshold))

    def settle(self, tried: list[_T]) -> None:
        self.settled = True


def test_effects_are_accepted_by_bic_gain_until_none_clears() -> None:
    crit = InformationCriterion.for_values(100, margin=10.0)  # ln n ≈ 4.61
    search = _Search({"a": (30.0, 1), "b": (40.0, 3), "c": (12.0, 1), "d": (None, 1)})
    n = forward_select(search, crit, max_effects=5)
    # a gains 25.4, b 26.2: b first; c needs 14.6 and never clears; d was not fitted
    assert [a[0] for a in search.accepted] == ["b", "a"]
    assert n == 2 and search.settled
    assert search.accepted[0][1] == ["a"]  # within 5 of b's gain and clearing: a rival
    assert search.accepted[0][2] == pytest.approx(3 * np.log(100) + 10)
    assert search.reviews == [["a", "b"], ["a"], []]


def test_admission_rule_max_effects_and_a_stop() -> None:
    crit = InformationCriterion.for_values(100, margin=10.0)
    search = _Search({"a": (30.0, 1), "b": (40.0, 3)}, veto="b")
    forward_select(search, crit, max_effects=1)
    assert [a[0] for a in search.accepted] == ["a"] and not search.settled

    class _Stops(_Search):
        def propose(self) -> None:  # type: ignore[override]
            return None

    stops = _Stops({"a": (30.0, 1)})
    assert forward_select(stops, crit, max_effects=3) == 0 and not stops.settled


def test_a_second_look_only_when_nothing_is_admitted() -> None:
    """``reconsider`` sees only the candidates that clear the criterion, and only in a round
    whose admission rule admitted none; what it returns is accepted like a cleared one."""
    crit = InformationCriterion.for_values(100, margin=10.0)
    search = _Search({"a": (30.0, 1), "b": (40.0, 3), "c": (12.0, 1)}, veto="b", second_look="b")
    forward_select(search, crit, max_effects=5)
    # round 1: a admitted (b vetoed); round 2: b vetoed, nothing else clears -> second look
    assert [a[0] for a in search.accepted] == ["a", "b"]
    assert search.reconsidered == [["b"]]  # round 3: c clears nothing, nothing to look at
    none = _Search({"b": (40.0, 3)}, veto="b")
    forward_select(none, crit, max_effects=5)
    assert none.accepted == [] and none.settled and none.reconsidered == [["b"]]


def test_report_skeleton_keeps_section_order_and_places_extras() -> None:
    f = finding_entry("x", {"p": 1}, 1.0, 2.0, "because", ("y",), delta_bic=-3.0)
    assert list(f) == ["effect", "params", "rms_dn_after", "chi2_per_dof_after", "delta_bic",
                       "evidence", "alternatives"]
    rep = diagnosis_report(noise_rms_dn=1.0, baseline={}, located={}, findings=[f], final={},
                           unexplained={}, head={"format": "f"},
                           after={"findings": {"rounds": []}}, tail={"seconds": 1})
    assert list(rep) == ["format", "noise_rms_dn", "baseline", "located", "findings", "rounds",
                         "final", "unexplained", "seconds"]
    assert set(SECTIONS) <= set(rep)
    with pytest.raises(KeyError, match="not a report section"):
        diagnosis_report(noise_rms_dn=1.0, baseline={}, located={}, findings=[], final={},
                         unexplained={}, after={"nowhere": {}})


def test_residual_axes() -> None:
    z = np.zeros((2, 3, 4, 3))
    z[0, 1, 2, :] = 2.0
    valid = np.ones(z.shape, bool)
    valid[1] = False
    m = mean_z_map(z, valid)
    assert m[1, 2] == pytest.approx(2.0) and m[0, 0] == 0.0
    x = np.array([0.1, 0.5, 0.6, 5.0])
    y = np.array([1.0, 2.0, 4.0, 8.0])
    chi, n = binned_chi2(x, y, np.array([0.0, 0.4, 1.0, np.inf]))
    assert chi[:2].tolist() == [1.0, 3.0] and n.tolist() == [1, 2, 1] and chi[2] == 8.0
    assert np.isnan(chi2_in(y, np.zeros(4, bool)))
    assert chi2_in(y, x > 0.4) == pytest.approx(14 / 3)
