"""Fixtures of the masks plugin's tests, which run alone from the repository root
(``python -m pytest plugins/thintact_masks/tests``) as well as in the whole suite: a tiny
device for fast GA and fitness checks."""

from __future__ import annotations

import pytest
from mask_profiles import make_profile

from thintact_sdk.formats.profiles import Profile


@pytest.fixture
def tiny_profile() -> Profile:
    return make_profile()
