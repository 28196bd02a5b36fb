"""The diagnosis's view of the effects: each registered effect that declares a
:class:`~thintact_sdk.simulation.effects.FitSpec` is a :class:`Candidate`.

Nothing about a particular effect is written here: its flat fit vector, null value,
typical step, bounds (the effect's own physical bounds unless its fit declares others),
converters and fitting hints all come from its declaration in :mod:`thintact_sdk.simulation.effects`.
``domain`` says who computes it:

- ``"optical"``: the simulator (``profile.physics``), re-simulating every frame;
- ``"post"``: a map of the simulated signal, applied with the effect's ``forward``
  without re-simulating (colour crosstalk, veiling glare);
- ``"dn"``: the digital-number domain after the gain (``dn_response``: sensor gamma, saturation);
- ``"linear"``: additive terms fitted in closed form next to the gains (stray light).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from thintact_sdk.formats.profiles import Profile
from thintact_sdk.simulation.effects import EFFECTS, DataSearch, EffectSpec, FitSpec, Proxy
from thintact_sdk.simulation.effects._spec import Domain


@dataclass(frozen=True)
class Candidate:
    """One effect as the diagnosis fits it (a view of its :class:`EffectSpec`)."""

    spec: EffectSpec

    @property
    def fit(self) -> FitSpec:
        assert self.spec.fit is not None
        return self.spec.fit

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def domain(self) -> Domain:
        return self.fit.domain

    @property
    def labels(self) -> tuple[str, ...]:
        return self.fit.labels

    @property
    def k(self) -> int:
        return self.fit.k

    @property
    def channelwise(self) -> bool:
        return self.fit.channelwise

    @property
    def signed(self) -> tuple[bool, ...]:
        return self.fit.signed

    @property
    def slow_params(self) -> tuple[int, ...]:
        return self.fit.slow_params

    @property
    def costly(self) -> bool:
        return self.fit.costly

    @property
    def joint_refit(self) -> bool:
        return self.fit.joint_refit

    @property
    def search(self) -> DataSearch | None:
        return self.fit.search

    @property
    def proxy(self) -> Proxy | None:
        return self.fit.proxy

    def null(self, p: Profile) -> np.ndarray:
        """``(k,)`` value with the effect absent."""
        return np.asarray(self.fit.null(p), np.float64)

    def step(self, p: Profile) -> np.ndarray:
        """``(k,)`` typical amplitude of the first-order signature."""
        return np.asarray(self.fit.step(p), np.float64)

    def score_step(self, p: Profile) -> np.ndarray:
        """``(k,)`` finite-difference steps of the score test (default: :meth:`step`)."""
        make = self.fit.score_step or self.fit.step
        return np.asarray(make(p), np.float64)

    def lower(self, p: Profile) -> np.ndarray:
        """``(k,)`` lower physical bounds."""
        return self.spec.fit_bounds(p)[0]

    def upper(self, p: Profile) -> np.ndarray:
        """``(k,)`` upper physical bounds."""
        return self.spec.fit_bounds(p)[1]

    def to_params(self, v: np.ndarray, p: Profile) -> dict[str, Any]:
        """The effect's parameters for the flat vector ``v``."""
        return self.fit.to_params(v, p)

    def from_params(self, d: Mapping[str, Any], p: Profile) -> np.ndarray:
        """The flat vector of the effect's parameters ``d``."""
        return np.asarray(self.fit.from_params(d, p), np.float64)


class _Candidates(Mapping[str, Candidate]):
    """Live view of :data:`thintact_sdk.simulation.effects.EFFECTS`: the effects that declare a fit,
    in registration order (an effect registered later is a candidate at once)."""

    def __getitem__(self, name: str) -> Candidate:
        spec = EFFECTS.get(name)
        if spec is None or spec.fit is None:
            raise KeyError(name)
        return Candidate(spec)

    def __iter__(self) -> Iterator[str]:
        return iter([n for n, s in EFFECTS.items() if s.fit is not None])

    def __len__(self) -> int:
        return sum(1 for s in EFFECTS.values() if s.fit is not None)


CANDIDATES: Mapping[str, Candidate] = _Candidates()
