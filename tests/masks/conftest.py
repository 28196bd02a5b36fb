"""Fixtures of the mask tests: a tiny device for fast GA and direct-generation checks."""

from __future__ import annotations

import pytest
from mask_profiles import make_profile

from thintact_sdk.formats.profiles import Profile


@pytest.fixture
def tiny_profile() -> Profile:
    return make_profile()
