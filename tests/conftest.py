"""Shared fixtures: paths to the repository, ../shared, and the golden profiles; calibration
reports' figures built but not rasterised outside the tests marked ``report_figures``."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("THINTACT_SHARED", REPO.parent / "shared"))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.skip(f"../shared not found at {SHARED}")
    return SHARED


@pytest.fixture(scope="session")
def golden_dir(shared_dir: Path) -> Path:
    return shared_dir / "golden" / "baseline"




_PLACEHOLDER_PNG = ("data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNkYPhfDwAChwGA"
                    "60e6kgAAAABJRU5ErkJggg==")
"""A 1×1 PNG standing in for a calibration report figure."""
_RASTERISE: list[Any] = []
"""``unit_report._png`` as shipped, kept while the session replaces it."""


def _unrasterised_png(fig: Any) -> str:
    """``unit_report._png`` without ``savefig``: the figure is built (every plotting call runs)
    and closed, and a 1×1 PNG stands in for it. Rasterising the report's figures is most of a
    small test device's calibration; the tests marked ``report_figures`` rasterise them."""
    import matplotlib.pyplot as plt

    plt.close(fig)
    return _PLACEHOLDER_PNG


@pytest.fixture(scope="session", autouse=True)
def _report_figures_unrasterised() -> Iterator[None]:
    """For the whole session, module fixtures included (they calibrate before any
    function-scoped fixture runs)."""
    from thintact_sdk.calibration import unit_report

    _RASTERISE[:] = [unit_report._png]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(unit_report, "_png", _unrasterised_png)
        yield


@pytest.fixture(autouse=True)
def _report_figures_rasterised_when_marked(request: pytest.FixtureRequest) -> Iterator[None]:
    """A test marked ``report_figures`` writes the calibration report's real figures."""
    if request.node.get_closest_marker("report_figures") is None:
        yield
        return
    from thintact_sdk.calibration import unit_report

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(unit_report, "_png", _RASTERISE[0])
        yield
