"""Peak resident memory of one child process, for the tools that report it.

``getrusage(...).ru_maxrss`` does not measure a child on its own on Linux: Python's
``subprocess`` starts children with ``vfork``/``exec``, and ``exec`` folds the high-water
mark of the memory the child leaves (the *parent's*) into the child's ``ru_maxrss``; with
``RUSAGE_CHILDREN`` it is moreover the largest of every child ever waited for. A tool that
renders a paper-size recording in its own process and then runs ``thintact diagnose`` as
a child read 8.91 GiB for every child after it (the slow tests, one pytest process, after
the rotated mask's recording), whatever the child used; a child that allocates nothing read
2.82 GiB under a parent that had touched 2.8 GiB. ``VmHWM`` of ``/proc/<pid>/status`` is
the high-water mark of the child's own address space since its ``exec``: that is what these
tools report.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

_WRAPPER = r"""
import atexit, os, runpy, sys
sys.path.insert(0, sys.argv[1])
from peak_memory import own_peak_gib
sys.path.pop(0)

def _write_peak():
    with open(os.environ["THINTACT_PEAK_FILE"], "w") as f:
        f.write(repr(own_peak_gib()))

atexit.register(_write_peak)
module = sys.argv[2]
sys.argv = [module, *sys.argv[3:]]
runpy.run_module(module, run_name="__main__", alter_sys=True)
"""


def own_peak_gib() -> float:
    """This process's peak resident memory (GiB) since its ``exec``: ``VmHWM`` of
    ``/proc/self/status``."""
    with open("/proc/self/status") as f:
        kib = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    return kib / 2**20


def run_module_with_peak(module: str, args: list[str], env: dict[str, str] | None = None,
                         ) -> tuple[subprocess.CompletedProcess[str], float]:
    """``python -m module args…`` in a child process; ``(completed process, the child's own
    peak resident memory in GiB)``. Output is captured as text; the child's exit status is
    its own (``SystemExit`` from the module's ``main`` included); the peak is NaN when the child
    died before it could write it (killed by a signal)."""
    with tempfile.TemporaryDirectory(prefix="thintact-peak-") as tmp:
        peak_file = Path(tmp) / "peak_gib"
        child_env = {**(os.environ if env is None else env), "THINTACT_PEAK_FILE": str(peak_file)}
        cmd = [sys.executable, "-c", _WRAPPER, str(Path(__file__).resolve().parent), module, *args]
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False, env=child_env)
        peak = float(peak_file.read_text()) if peak_file.exists() else float("nan")
    return proc, peak
