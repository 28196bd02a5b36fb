"""The machine a figure was measured on: a one-line summary and the host's capabilities.

:func:`host_capabilities` answers what decides which arithmetic is fast here (SIMD level,
native bfloat16, BLAS and its threads, torch threads, GPUs); :func:`host_fingerprint` is a
short stable key of those properties, used to cache per-host choices such as a decoder's
backend. Everything here is read from ``/proc/cpuinfo``, numpy's and torch's own reports and,
when installed, ``threadpoolctl``; nothing is measured.
"""

from __future__ import annotations

import hashlib
import os
import platform
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from typing import Any

# CPU flags (Linux /proc/cpuinfo names) that mean bfloat16 matrix products run in hardware:
# AVX512-BF16 (Cooper Lake, Zen 4+), AMX-BF16 (Sapphire Rapids+), Arm BF16 (e.g. Graviton 3).
NATIVE_BF16_FLAGS = ("avx512_bf16", "amx_bf16", "bf16")
_SIMD_ORDER = (("amx_bf16", "AMX"), ("avx512_bf16", "AVX512_BF16"), ("avx512f", "AVX512"),
               ("avx2", "AVX2"), ("avx", "AVX"), ("sse4_2", "SSE4.2"), ("asimd", "NEON"))


@dataclass(frozen=True)
class HostCapabilities:
    """What the host offers for dense linear algebra.

    Attributes
    ----------
    cpu_model
        CPU model name.
    cores
        Logical CPUs the OS reports.
    simd
        Widest vector extension found (``"AVX512"``, ``"AVX2"``, ``"NEON"``, …).
    native_bf16
        True when the CPU has bfloat16 arithmetic in hardware (one of
        :data:`NATIVE_BF16_FLAGS`, or torch reports an AMX / AVX512-BF16 kernel level).
    blas
        numpy's BLAS with its thread count, e.g. ``"scipy-openblas 0.3.31 (2 threads)"``.
    torch
        ``"2.13.0+cpu, 2 threads, kernels AVX2"`` or ``None`` when torch is absent.
    gpus
        Accelerators torch can use (``"cuda:0 NVIDIA H100"``, ``"mps"``); empty without.
    flags
        The CPU flags among the SIMD / bfloat16 ones that were checked.
    """

    cpu_model: str
    cores: int
    simd: str
    native_bf16: bool
    blas: str
    torch: str | None
    gpus: tuple[str, ...] = ()
    flags: tuple[str, ...] = field(default_factory=tuple)

    def lines(self) -> list[str]:
        """Human-readable ``name: value`` lines (for ``thintact doctor`` and the benches)."""
        return [
            f"CPU: {self.cpu_model}, {self.cores} logical cores",
            f"SIMD: {self.simd}; native bfloat16: {'yes' if self.native_bf16 else 'no'}"
            f" (flags: {' '.join(self.flags) or 'none'})",
            f"BLAS (numpy): {self.blas}",
            f"torch: {self.torch or 'not installed'}",
            f"GPU: {', '.join(self.gpus) if self.gpus else 'none'}",
        ]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return asdict(self)


def cpu_flags(cpuinfo: str | None = None) -> set[str]:
    """The flag words of the first CPU in ``/proc/cpuinfo`` (``flags`` or Arm ``Features``)."""
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="utf-8") as f:
                cpuinfo = f.read()
        except OSError:
            return set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            return set(value.split())
    return set()


def has_native_bf16(flags: set[str], torch_capability: str | None = None) -> bool:
    """bfloat16 in hardware: a CPU flag of :data:`NATIVE_BF16_FLAGS` or a torch kernel level
    (``torch.backends.cpu.get_cpu_capability()``) naming AMX or AVX512-BF16."""
    if any(f in flags for f in NATIVE_BF16_FLAGS):
        return True
    cap = (torch_capability or "").upper()
    return "AMX" in cap or "BF16" in cap


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def blas_description() -> str:
    """numpy's BLAS library, version and threads (threadpoolctl when installed, else the
    OpenBLAS thread getters of :mod:`thintact_sdk.host.blas`)."""
    import numpy as np

    try:
        from threadpoolctl import threadpool_info

        pools = [p for p in threadpool_info() if p.get("user_api") == "blas"]
        if pools:
            return "; ".join(f"{p.get('internal_api')} {p.get('version')} ({p.get('num_threads')} threads)"
                             for p in pools)
    except ImportError:
        pass
    name, version = "unknown BLAS", ""
    try:
        cfg = np.show_config(mode="dicts")["Build Dependencies"]["blas"]  # type: ignore[index]
        name, version = str(cfg.get("name", name)), str(cfg.get("version", ""))
    except (TypeError, KeyError, AttributeError):
        pass
    from thintact_sdk.host.blas import openblas_threads

    threads = openblas_threads()
    tail = f" ({threads} threads)" if threads else ""
    return f"{name} {version}".strip() + tail


def _torch_summary() -> tuple[str | None, str | None, tuple[str, ...]]:
    try:
        import torch
    except ImportError:
        return None, None, ()
    cap = None
    try:
        cap = str(torch.backends.cpu.get_cpu_capability())
    except AttributeError:
        pass
    gpus: list[str] = []
    if torch.cuda.is_available():
        gpus += [f"cuda:{i} {torch.cuda.get_device_name(i)}" for i in range(torch.cuda.device_count())]
    mps = getattr(torch.backends, "mps", None)
    if mps is not None and mps.is_available():
        gpus.append("mps")
    desc = f"{torch.__version__}, {torch.get_num_threads()} threads, kernels {cap or '?'}"
    return desc, cap, tuple(gpus)


@lru_cache(maxsize=1)
def host_capabilities() -> HostCapabilities:
    """The capabilities of this host (read once per process)."""
    flags = cpu_flags()
    torch_desc, torch_cap, gpus = _torch_summary()
    simd = next((name for flag, name in _SIMD_ORDER if flag in flags), platform.machine() or "?")
    checked = tuple(sorted(f for f in flags if f in {flag for flag, _ in _SIMD_ORDER} | set(NATIVE_BF16_FLAGS)
                           | {"fma", "f16c"}))
    return HostCapabilities(
        cpu_model=_cpu_model(), cores=os.cpu_count() or 1, simd=simd,
        native_bf16=has_native_bf16(flags, torch_cap), blas=blas_description(), torch=torch_desc,
        gpus=gpus, flags=checked,
    )


def host_fingerprint(caps: HostCapabilities | None = None) -> str:
    """16 hex digits identifying the host's arithmetic: CPU model, cores, SIMD flags, BLAS,
    numpy and torch versions and GPUs (thread counts are part of BLAS/torch descriptions)."""
    import numpy as np

    c = caps or host_capabilities()
    key = "|".join([c.cpu_model, str(c.cores), ",".join(c.flags), c.blas, c.torch or "-",
                    ",".join(c.gpus), np.__version__, platform.machine()])
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def kernel_threads_now() -> str:
    """The kernel threads products run on at this moment, in this thread: OpenBLAS's (process
    wide) and torch's (this thread's), e.g. ``"blas 1, torch 1"``. Unlike the counts in
    :func:`host_capabilities` (read once per process) this follows a hold such as
    :func:`thintact_sdk.host.compute_threads.single_threaded_kernels`, so a measurement keyed by it
    is reused only under the same threads."""
    from thintact_sdk.host.blas import openblas_threads
    from thintact_sdk.host.compute_threads import loaded_torch

    torch = loaded_torch()
    torch_threads = str(torch.get_num_threads()) if torch is not None else "-"
    return f"blas {openblas_threads() or '-'}, torch {torch_threads}"


def machine_summary() -> str:
    """CPU model, core count, memory, BLAS settings and library versions in one line."""
    caps = host_capabilities()
    mem = ""
    try:
        with open("/proc/meminfo", encoding="utf-8") as f:
            kb = int(f.readline().split()[1])
            mem = f", {kb / 1024**2:.0f} GiB RAM"
    except (OSError, ValueError, IndexError):
        pass
    import numpy as np

    parts = [f"{caps.cpu_model}, {caps.cores} cores{mem}, {caps.simd}, native bf16 "
             f"{'yes' if caps.native_bf16 else 'no'}", f"Python {platform.python_version()}",
             f"numpy {np.__version__} ({caps.blas})"]
    if caps.torch is not None:
        parts.append(f"torch {caps.torch}")
    parts.append(f"GPU {', '.join(caps.gpus) if caps.gpus else 'none'}")
    parts.append(f"OPENBLAS_CORETYPE={os.environ.get('OPENBLAS_CORETYPE', '(unset)')}")
    parts.append(f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '(unset)')}")
    return "; ".join(parts)
