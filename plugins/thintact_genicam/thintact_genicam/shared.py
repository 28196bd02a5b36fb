"""One harvesters ``Harvester`` per GenTL producer, shared by every camera of the process.

A producer (``.cti``) is a shared library with one GenTL system per process: loading it in
a second ``Harvester`` while the first is open finds no devices, so two cameras on one
producer (the two fingers of a gripper) must share one. The harvester is created on the
first :func:`acquire_harvester` of a producer and reset when the last user releases it.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from thintact_sdk.errors import DeviceError

_LOCK = threading.Lock()
_SHARED: dict[Path, tuple[Any, int]] = {}


def acquire_harvester(cti: Path) -> Any:
    """The harvester of producer ``cti`` (loaded on first use); release it when done.

    Raises
    ------
    DeviceError
        When the producer cannot be loaded.
    """
    from harvesters.core import Harvester

    with _LOCK:
        entry = _SHARED.get(cti)
        if entry is not None:
            _SHARED[cti] = (entry[0], entry[1] + 1)
            return entry[0]
        h = Harvester()
        try:
            h.add_file(str(cti), check_existence=True, check_validity=True)
            h.update()
        except Exception as err:  # noqa: BLE001 - any producer failure is reported as such
            _reset_quietly(h)
            raise DeviceError(f"GenTL producer {cti} failed to load: {err}") from None
        _SHARED[cti] = (h, 1)
        return h


def release_harvester(cti: Path, harvester: Any) -> None:
    """Give back a harvester from :func:`acquire_harvester`; the last user resets it."""
    with _LOCK:
        entry = _SHARED.get(cti)
        if entry is None or entry[0] is not harvester:
            _reset_quietly(harvester)  # already dropped (e.g. after a fault): just reset
            return
        if entry[1] > 1:
            _SHARED[cti] = (harvester, entry[1] - 1)
            return
        del _SHARED[cti]
    _reset_quietly(harvester)


def _reset_quietly(harvester: Any) -> None:
    try:
        harvester.reset()
    except Exception:  # noqa: BLE001 - resetting a vanished producer fails in many ways
        pass
