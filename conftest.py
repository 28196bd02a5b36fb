"""What every test of the repository shares, the core's (``tests/``) and each plugin's
(``plugins/<plugin>/tests/``, also when run alone from the repository root): a private cache."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _private_user_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Per-host caches (e.g. the decoders' measured backends) go to a session directory (one
    per test process), never to the user's ~/.cache."""
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg-cache"))
    os.environ.pop("THINTACT_CACHE_DIR", None)
    os.environ.pop("THINTACT_BACKEND", None)
