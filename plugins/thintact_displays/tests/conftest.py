"""Fixtures of the thintact_displays plugin's tests, which run alone from the repository root
(``python -m pytest plugins/thintact_displays/tests``) as well as in the whole suite."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _private_user_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Per-host caches (e.g. the decoders' measured backends) go to a session directory,
    never to the user's ~/.cache."""
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg-cache"))
    os.environ.pop("THINTACT_CACHE_DIR", None)
    os.environ.pop("THINTACT_BACKEND", None)
