"""Finding GenTL producers (``.cti`` files) and enumerating their devices.

A producer is named by the profile (``camera.settings.cti``), on the command line, or by
the GenTL standard environment variable ``GENICAM_GENTL64_PATH`` (directories separated
by ``os.pathsep``, each searched for ``*.cti``).
"""

from __future__ import annotations

import importlib.util
import logging
import os
from pathlib import Path
from typing import Any

from thintact_sdk.errors import DeviceError, DeviceNotFoundError

GENTL_PATH_ENV = "GENICAM_GENTL64_PATH"


def quiet_harvesters() -> None:
    """Keep harvesters from printing tracebacks for faults this plugin reports as errors.

    Left alone when the user configures harvesters' logging (``HARVESTERS_LOGGING_CONFIG``).
    """
    if "HARVESTERS_LOGGING_CONFIG" not in os.environ:
        logging.getLogger("harvesters.core").setLevel(logging.CRITICAL)


def producers_from_env() -> list[Path]:
    """Every ``*.cti`` in the directories listed in ``GENICAM_GENTL64_PATH``."""
    found: list[Path] = []
    for d in os.environ.get(GENTL_PATH_ENV, "").split(os.pathsep):
        if d and Path(d).is_dir():
            found.extend(sorted(Path(d).glob("*.cti")))
        elif d.endswith(".cti") and Path(d).is_file():
            found.append(Path(d))
    return found


def viky_producer() -> Path | None:
    """The ``viky.cti`` virtual producer shipped with the ``genicam`` wheel, if installed."""
    spec = importlib.util.find_spec("genicam")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "viky.cti"
    return path if path.is_file() else None


def resolve_producer(cti: str | os.PathLike[str] | None) -> Path:
    """The producer to load: ``cti`` when given, else the only one on ``GENICAM_GENTL64_PATH``.

    Raises
    ------
    DeviceNotFoundError
        When the named file does not exist, or none / several are found on the path.
    """
    if cti:
        path = Path(cti).expanduser()
        if not path.is_file():
            raise DeviceNotFoundError(
                f"GenTL producer {path} not found; install the camera vendor's SDK or set "
                "camera.settings.cti to its .cti file"
            )
        return path
    env = producers_from_env()
    if len(env) == 1:
        return env[0]
    if not env:
        raise DeviceNotFoundError(
            "no GenTL producer: set camera.settings.cti to the vendor's .cti file "
            f"(or {GENTL_PATH_ENV})"
        )
    raise DeviceNotFoundError(
        f"{len(env)} GenTL producers on {GENTL_PATH_ENV} ({', '.join(p.name for p in env)}); "
        "name one in camera.settings.cti"
    )


def list_devices(cti: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """Devices a producer offers: ``id``, ``vendor``, ``model``, ``serial``, ``name``, ``access``.

    Raises
    ------
    DeviceError
        When the producer cannot be loaded.
    """
    from harvesters.core import Harvester

    quiet_harvesters()
    h = Harvester()
    try:
        try:
            h.add_file(str(cti), check_existence=True, check_validity=True)
            h.update()
        except Exception as err:  # noqa: BLE001 - any producer failure is reported as such
            raise DeviceError(f"GenTL producer {cti} failed to load: {err}") from None
        out = []
        for info in h.device_info_list:
            out.append(
                {
                    "id": _prop(info, "id_"),
                    "vendor": _prop(info, "vendor"),
                    "model": _prop(info, "model"),
                    "serial": _prop(info, "serial_number"),
                    "name": _prop(info, "display_name"),
                    "access": _prop(info, "access_status"),
                }
            )
        return out
    finally:
        h.reset()


def _prop(info: Any, name: str) -> Any:
    try:
        return getattr(info, name)
    except Exception:  # noqa: BLE001 - producers may not implement every info query
        return None
