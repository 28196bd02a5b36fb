"""``thintact demo --show`` opens the drawn figure (it was closed before the window opened)."""

from __future__ import annotations

from pathlib import Path

import pytest

from thintact_sdk.apps.cli.main import main


def test_show_opens_the_drawn_figure(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import matplotlib.pyplot as plt

    seen: list[int] = []

    def fake_show(*args: object, **kwargs: object) -> None:  # what a window would display
        seen.extend(sum(1 for ax in plt.figure(n).axes if ax.images) for n in plt.get_fignums())

    monkeypatch.setattr(plt, "show", fake_show)
    assert main(["demo", "--profile", "virtual-mini", "--out", str(tmp_path / "d"), "--show"]) == 0
    assert seen and max(seen) >= 6, seen  # the figure's image panels were there to show
    assert not plt.get_fignums()  # and closed afterwards
