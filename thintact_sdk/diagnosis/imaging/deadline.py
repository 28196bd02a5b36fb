"""One wall-clock deadline for a diagnosis, created once and handed down.

The optimisers stop gracefully when it has :meth:`Deadline.expired` (returning the best
values so far); the selection policy calls :meth:`Deadline.check`, whose
:class:`DeadlineExpired` is caught at one place (the round loop of
:func:`thintact_sdk.diagnosis.imaging.select.select_effects`), which then keeps the model it has.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable


class DeadlineExpired(Exception):  # noqa: N818 - a signal, not an error a user acts on
    """The time budget is spent (control flow inside the diagnosis; never reaches a user).

    Deliberately not a :class:`~thintact_sdk.errors.ThinTactError`: the policy catches
    simulator failures as ``ThinTactError`` and must not mistake a time-out for one.
    """


class Deadline:
    """A point in wall-clock time (``time.perf_counter`` seconds), or none (``end=inf``).

    Parameters
    ----------
    end
        ``time.perf_counter()`` value at which the budget is spent; ``math.inf`` never.
    clock
        Time source in seconds (injectable for tests).
    """

    def __init__(self, end: float = math.inf, clock: Callable[[], float] = time.perf_counter) -> None:
        self.end = float(end)
        self.clock = clock

    @classmethod
    def after(cls, seconds: float, clock: Callable[[], float] = time.perf_counter) -> Deadline:
        """A deadline ``seconds`` from now."""
        return cls(clock() + float(seconds), clock)

    @classmethod
    def never(cls) -> Deadline:
        """No time limit."""
        return cls()

    def remaining_s(self) -> float:
        """Seconds left (negative once expired; ``inf`` without a limit)."""
        return self.end - self.clock()

    def expired(self) -> bool:
        """True once the budget is spent."""
        return self.remaining_s() <= 0.0 if math.isfinite(self.end) else False

    def allows(self, seconds: float) -> bool:
        """True when at least ``seconds`` are left (e.g. for one more slow simulation)."""
        return self.remaining_s() >= seconds

    def check(self, stage: str) -> None:
        """Raise :class:`DeadlineExpired` naming ``stage`` when the budget is spent."""
        if self.expired():
            raise DeadlineExpired(f"time budget reached: {stage} stopped")

    def share(self, fraction: float) -> Deadline:
        """A sub-deadline at ``fraction`` of the time left (never later than this one)."""
        if not math.isfinite(self.end):
            return self
        now = self.clock()
        return Deadline(now + fraction * max(self.end - now, 0.0), self.clock)
