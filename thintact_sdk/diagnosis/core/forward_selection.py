"""The loop both diagnoses run to name effects: greedy forward selection by an information
criterion.

Round by round, the diagnosis (an :class:`EffectSearch`) proposes the candidate effects it
fitted at the current model, each a :class:`Tried`: its name, ``dchi2`` (how much it lowers
−2 log-likelihood, χ² units; ``None`` when it was not fitted) and ``k`` (the parameters it
adds). A candidate *clears* the :class:`InformationCriterion` when ``dchi2 > k·ln n +
margin`` (its BIC drops by more than ``margin``) and the diagnosis *admits* it (a rule of its
own: an amplitude floor, a share of the excess χ²); when it admits none, it may still
*reconsider* the ones that clear the criterion with a costlier check of its own (imaging: a
refit on each half of the frames). The cleared candidate with the largest
BIC gain ``dchi2 − k·ln n`` is accepted, together with the alternatives the diagnosis names;
the loop ends when none clears, when the diagnosis has nothing left to try or stops (a time
budget), or when ``max_effects`` effects are accepted.

The forward model, the data, the vocabulary and how a candidate is fitted belong to the
diagnosis (imaging: :mod:`~thintact_sdk.diagnosis.imaging.select`; tactile:
:mod:`~thintact_sdk.diagnosis.tactile.press_engine`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np


class Tried(Protocol):
    """One candidate fitted in a round."""

    @property
    def name(self) -> str: ...

    @property
    def dchi2(self) -> float | None: ...

    @property
    def k(self) -> int: ...


T = TypeVar("T", bound=Tried)


@dataclass(frozen=True)
class InformationCriterion:
    """BIC with a margin: an effect of ``k`` parameters must lower χ² by more than
    ``k·ln n + margin`` (``ln_n``: the log of the number of values fitted)."""

    ln_n: float
    margin: float

    @classmethod
    def for_values(cls, n_values: int, margin: float) -> InformationCriterion:
        """The criterion for a fit to ``n_values`` values (at least 2 counted)."""
        return cls(float(np.log(max(n_values, 2))), float(margin))

    def threshold(self, k: int) -> float:
        """The Δχ² that ``k`` parameters must exceed."""
        return k * self.ln_n + self.margin

    def gain(self, t: Tried) -> float:
        """The BIC gain ``dchi2 − k·ln n`` (−ΔBIC; 0 for Δχ² when not fitted)."""
        return (t.dchi2 or 0.0) - t.k * self.ln_n

    def clears(self, t: Tried) -> bool:
        """True when ``t`` was fitted and its Δχ² exceeds :meth:`threshold`."""
        return t.dchi2 is not None and t.dchi2 > self.threshold(t.k)

    def rivals(self, best: T, tried: Sequence[T], tol: float) -> list[T]:
        """The other candidates of ``tried`` that clear the criterion with a BIC gain within
        ``tol`` of ``best``'s: equally good explanations the data cannot tell apart."""
        floor = self.gain(best) - tol
        return [t for t in tried
                if t is not best and t.dchi2 is not None and self.gain(t) > floor and self.clears(t)]


class EffectSearch(Protocol[T]):
    """What a diagnosis supplies to :func:`forward_select`."""

    def has_candidates(self) -> bool:
        """True while effects are left to try."""
        ...

    def propose(self) -> list[T] | None:
        """One round: the candidates fitted at the current model (in the order ties are broken);
        ``None`` stops the selection (e.g. the time budget is spent)."""
        ...

    def admits(self, t: T) -> bool:
        """The diagnosis's own rule beyond the criterion (asked only of candidates that
        clear it, in order)."""
        ...

    def reconsider(self, tried: list[T]) -> list[T]:
        """No candidate of the round was admitted: those of ``tried`` (each clearing the
        criterion) the diagnosis admits on a second, costlier look; empty when none."""
        ...

    def review(self, tried: list[T], cleared: list[T]) -> None:
        """Called every round once ``cleared`` is known, before accepting or stopping."""
        ...

    def alternatives(self, best: T, cleared: list[T], tried: list[T]) -> list[T]:
        """The candidates named beside ``best`` as explaining the data as well."""
        ...

    def accept(self, best: T, alternatives: list[T], threshold: float) -> None:
        """Add ``best`` to the model (``threshold``: the Δχ² it had to exceed)."""
        ...

    def settle(self, tried: list[T]) -> None:
        """No candidate of the last round cleared: record why."""
        ...


def forward_select(search: EffectSearch[T], criterion: InformationCriterion,
                   max_effects: int) -> int:
    """Run the greedy selection (module docstring); returns how many effects were accepted."""
    accepted = 0
    while search.has_candidates() and accepted < max_effects:
        tried = search.propose()
        if tried is None:
            break
        cleared = [t for t in tried if criterion.clears(t) and search.admits(t)]
        clearing = [t for t in tried if criterion.clears(t)]
        if not cleared and clearing:
            cleared = search.reconsider(clearing)
        search.review(tried, cleared)
        if not cleared:
            search.settle(tried)
            break
        best = sorted(cleared, key=lambda t: -criterion.gain(t))[0]
        search.accept(best, search.alternatives(best, cleared, tried), criterion.threshold(best.k))
        accepted += 1
    return accepted
