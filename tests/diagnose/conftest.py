"""Fixtures of the diagnosis tests: concealed-effect recordings, rendered once per session."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import pytest


def load_concealed_tool(repo_root: Path) -> Any:
    """``tools/make_concealed_dataset.py`` as a module."""
    spec = importlib.util.spec_from_file_location(
        "make_concealed_dataset", repo_root / "tools" / "make_concealed_dataset.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def concealed_case(repo_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Any:
    """``case_dir(name)``: the case rendered (once) by the concealed-dataset tool."""
    tool = load_concealed_tool(repo_root)
    root = tmp_path_factory.mktemp("concealed")
    made: dict[str, Path] = {}

    def case_dir(name: str) -> Path:
        if name not in made:
            made[name] = tool.make_case(name, root)
        return made[name]

    return case_dir


@pytest.fixture(scope="session")
def concealed(concealed_case: Any) -> Any:
    """``make(case) -> (report, truth, diagnosis)``, each case diagnosed once."""
    from thintact_sdk.diagnosis.imaging import diagnose, load_diagnosis_data

    done: dict[str, Any] = {}

    def make(case: str) -> Any:
        if case not in done:
            d_case = concealed_case(case)
            truth = json.loads((d_case / "truth.json").read_text())
            d = diagnose(load_diagnosis_data(d_case / "recording"))
            done[case] = (d.report, truth, d)
        return done[case]

    return make
