"""The Real2Sim generator file (``thintact-real2sim/1``) and device choice."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from thintact_sdk.errors import ThinTactError
from thintact_sdk.tactile.learning.networks import ResnetGenerator

GENERATOR_FORMAT = "thintact-real2sim/1"


def select_device(name: str = "auto") -> torch.device:
    """``auto``: CUDA when present, else CPU; ``cpu``/``cuda``: as asked (CUDA must exist)."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name not in ("cpu", "cuda"):
        raise ThinTactError(f"device must be auto, cpu or cuda, not {name!r}")
    if name == "cuda" and not torch.cuda.is_available():
        raise ThinTactError("device cuda asked for, but torch sees no CUDA GPU")
    return torch.device(name)


def save_generator(path: Path, generator: ResnetGenerator, config: dict[str, Any],
                   meta: dict[str, Any]) -> Path:
    """Write the real→sim generator (weights on the CPU) atomically."""
    state = {k: v.detach().cpu() for k, v in generator.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    torch.save({"format": GENERATOR_FORMAT, "config": config, "meta": meta, "state_dict": state},
               tmp)
    tmp.replace(path)
    return path


def load_generator(path: str | Path) -> tuple[ResnetGenerator, dict[str, Any]]:
    """Read a generator file; returns the network (eval mode, CPU) and its ``meta``.

    Read with ``torch.load(weights_only=True)``: tensors, numbers, strings, dicts and lists
    only, never code from the file.

    Raises
    ------
    ThinTactError
        Naming the file: missing, unreadable or foreign, a bad network config, or weights that
        do not fit it.
    """
    p = Path(path)
    if not p.is_file():
        raise ThinTactError(f"{p}: no such Real2Sim generator file")
    try:
        blob = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several unrelated types for a bad file
        raise ThinTactError(f"{p}: not a Real2Sim generator file ({exc.__class__.__name__})") from exc
    if not isinstance(blob, dict) or blob.get("format") != GENERATOR_FORMAT:
        raise ThinTactError(f"{p}: not a {GENERATOR_FORMAT} file")
    cfg, state, meta = blob.get("config"), blob.get("state_dict"), blob.get("meta", {})
    if not isinstance(cfg, dict) or not isinstance(state, dict) or not isinstance(meta, dict):
        raise ThinTactError(f"{p}: 'config', 'state_dict' and 'meta' of a {GENERATOR_FORMAT} "
                            "file must be dicts")
    try:
        width, blocks, kernel = (int(cfg[k]) for k in ("width", "blocks", "edge_kernel"))
    except (KeyError, TypeError, ValueError) as exc:
        raise ThinTactError(f"{p}: bad network config {cfg!r}") from exc
    stored = sum(v.numel() for v in state.values() if isinstance(v, torch.Tensor))
    # a lower bound of the declared network's weights (residual blocks and edge convolutions):
    # a config the stored weights cannot fill is refused before the network is allocated
    least = 288 * width * width * blocks + 6 * width * kernel * kernel
    if min(width, blocks, kernel) < 1 or least > stored:
        raise ThinTactError(f"{p}: network config {cfg!r} does not fit the {stored} stored "
                            "weights")
    try:
        net = ResnetGenerator(width=width, blocks=blocks, edge_kernel=kernel)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise ThinTactError(f"{p}: bad network config {cfg!r}") from exc
    try:
        net.load_state_dict(state)
    except (RuntimeError, TypeError, AttributeError) as exc:
        raise ThinTactError(f"{p}: weights do not fit the declared network ({exc})") from exc
    net.eval()
    return net, dict(meta)
