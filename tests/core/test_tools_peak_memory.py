"""``tools/peak_memory.py``: a child's own peak memory, not its parent's.

The paper-size tools report a child's peak resident memory against the issue's 8 GB. With
``ru_maxrss`` a child started by a process that had used a lot of memory read the parent's
peak (every diagnosis after the rotated mask's in-process render read 8.91 GiB).
"""

from __future__ import annotations

import importlib.util
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest


@pytest.fixture(scope="module")
def peak_memory(repo_root: Path) -> Any:
    spec = importlib.util.spec_from_file_location("peak_memory", repo_root / "tools" / "peak_memory.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _touch(gib: float) -> None:
    """Make this process's resident high-water mark at least ``gib`` (then free it)."""
    a = np.ones(int(gib * 2**30) // 8)
    del a


def test_child_peak_is_its_own_after_a_large_parent(peak_memory: Any) -> None:
    _touch(0.75)
    assert peak_memory.own_peak_gib() >= 0.7
    # (on Linux a child's ru_maxrss, which the tools read before, says >= 0.7 here)
    proc, peak = peak_memory.run_module_with_peak("json.tool", ["--help"])
    assert proc.returncode == 0 and "json.tool" in proc.stdout
    assert 0.001 < peak < 0.2


def _run_script(peak_memory: Any, tmp_path: Path, name: str, text: str) -> tuple[Any, float]:
    (tmp_path / f"{name}.py").write_text(text)
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    return peak_memory.run_module_with_peak(name, [], env=env)


def test_child_peak_counts_what_the_child_allocates(peak_memory: Any, tmp_path: Path) -> None:
    proc, peak = _run_script(peak_memory, tmp_path, "alloc_child",
                             "import numpy as np, sys\na = np.ones(int(0.3 * 2**30) // 8)\nsys.exit(3)\n")
    assert proc.returncode == 3  # the child's own exit status
    assert 0.3 <= peak < 0.5


def test_child_killed_before_it_could_say_reads_nan(peak_memory: Any, tmp_path: Path) -> None:
    proc, peak = _run_script(peak_memory, tmp_path, "killed_child",
                             "import os, signal\nos.kill(os.getpid(), signal.SIGKILL)\n")
    assert proc.returncode == -9
    assert math.isnan(peak)
    failed, peak_f = _run_script(peak_memory, tmp_path, "failing_child", "raise ValueError('bad input')\n")
    assert failed.returncode == 1 and "bad input" in failed.stderr
    assert peak_f > 0  # an ordinary error still reaches atexit
