"""Fixtures of the robustness tests: the tiny device's clean recording and bundle (made once
per session and copied per test), and the outcome counter of the fuzz tests."""

from __future__ import annotations

import shutil
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import rob_kit  # noqa: E402


@pytest.fixture(scope="session")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The tiny device: ``profile``, ``scenes``, ``meas``, ``recording`` and ``bundle`` paths."""
    root = tmp_path_factory.mktemp("tiny")
    profile = rob_kit.tiny_profile()
    scenes = rob_kit.scenes(3)
    meas = rob_kit.measurements(profile, scenes)
    rec = rob_kit.write_recording(root / "recording", profile, scenes, meas)
    bundle = rob_kit.write_bundle(root / "bundle", profile)
    profile_file = root / "robust-tiny.json"
    shutil.copy(rec / "profile.json", profile_file)
    np.save(root / "scenes.npy", scenes)
    return rob_kit.Kit(profile=profile, scenes=scenes, meas=meas, recording=rec, bundle=bundle,
                       profile_file=profile_file, scenes_file=root / "scenes.npy")


@pytest.fixture
def rec_copy(tiny: dict[str, Any], tmp_path: Path) -> Path:
    """A private copy of the tiny device's clean recording."""
    return Path(shutil.copytree(tiny["recording"], tmp_path / "rec"))


@pytest.fixture
def bundle_copy(tiny: dict[str, Any], tmp_path: Path) -> Path:
    """A private copy of the tiny device's calibration bundle."""
    return Path(shutil.copytree(tiny["bundle"], tmp_path / "cal"))


def pytest_terminal_summary(terminalreporter: Any) -> None:
    if not rob_kit.FUZZ_OUTCOMES:
        return
    terminalreporter.section("fuzz outcomes")
    total: Counter[str] = Counter()
    for target, counts in sorted(rob_kit.FUZZ_OUTCOMES.items()):
        total.update(counts)
        terminalreporter.write_line(f"{target:28s} {sum(counts.values()):5d} inputs  {dict(counts)}")
    terminalreporter.write_line(f"{'all':28s} {sum(total.values()):5d} inputs  {dict(total)}")
