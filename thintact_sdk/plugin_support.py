"""The core's public surface for plugin authors beyond the robot API: what camera, decoder,
display, mask, replay and LED plugins legitimately build on.

A plugin imports the core only from ``thintact_sdk`` (the robot API), ``thintact_sdk.errors``,
``.frames``, ``.interfaces``, ``.hookspecs``, ``.algorithms`` (the algorithms) and this module;
``lint-imports`` (pyproject ``[tool.importlinter]``) refuses any other core module in a plugin,
so the core can move code between its private modules without breaking a plugin. Everything
in :data:`__all__` is stable within a major version.

The names load on first use (importing this module costs nothing) and are typed for mypy.

==========================  ===============================================================
group                       names
==========================  ===============================================================
profiles                    ``Profile``, ``NoiseSpec``, ``load_profile``, ``profile_from_dict``,
                            ``write_profile``, ``available_profiles``
camera settings             ``CameraSettings``, ``parse_camera_settings`` and the settings models
pixels                      Bayer mosaics and binning helpers, ``encode_tone``
files                       ``read_npy``, ``read_npz`` (strict, no pickles), ``safe_json``,
                            ``safe_yaml``, ``Recording``, raw-frame fields, ``McapLog``
cameras                     ``camera_is_simulated``, ``channel_layout``, ``FrameGapCounter``,
                            ``bit_depth_problem``, the virtual bench's scene slots and DN scale
host                        ``host_capabilities``, ``machine_summary``, BLAS/kernel threads,
                            the GEMM roofline
CLI commands of plugins     output-path policy and argument types, ``get_registry``
==========================  ===============================================================
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names, for type checkers; at run time they load on first use
    from thintact_sdk.apps.cli.argtypes import (  # noqa: F401
        fraction,
        int_range,
        non_negative_int,
        positive_float,
        positive_int,
        seed,
    )
    from thintact_sdk.apps.cli.output_path import (  # noqa: F401
        add_force_argument,
        check_not_an_input,
        claim_output,
        file_input,
    )
    from thintact_sdk.device.camera_settings import (  # noqa: F401
        CameraSettings,
        FrameGeometrySettings,
        apply_geometry,
        crop_box,
        parse_camera_settings,
    )
    from thintact_sdk.device.cameras import (  # noqa: F401
        FrameGapCounter,
        bit_depth_problem,
        camera_is_simulated,
        channel_layout,
    )
    from thintact_sdk.device.registry import get_registry  # noqa: F401
    from thintact_sdk.device.virtual_bench import (  # noqa: F401
        REFERENCE_EXPOSURE_US,
        SceneSlot,
        get_scene_slot,
        signal_scale_dn,
        white_level_dn,
    )
    from thintact_sdk.formats import (
        safe_json,  # noqa: F401
        safe_yaml,  # noqa: F401
    )
    from thintact_sdk.formats.mcap import McapLog  # noqa: F401
    from thintact_sdk.formats.profiles import (  # noqa: F401
        NoiseSpec,
        Profile,
        available_profiles,
        load_profile,
        profile_from_dict,
        write_profile,
    )
    from thintact_sdk.formats.raw_frames import (  # noqa: F401
        PIXEL_FORMAT_FIELD,
        RAW_FIELD,
        load_raw_data,
        save_raw_frame,
    )
    from thintact_sdk.formats.recording import Recording  # noqa: F401
    from thintact_sdk.formats.safe_arrays import read_npy, read_npz  # noqa: F401
    from thintact_sdk.host.blas import blas_threads  # noqa: F401
    from thintact_sdk.host.compute_threads import prepare_worker_thread, single_threaded_kernels  # noqa: F401
    from thintact_sdk.host.machine import (  # noqa: F401
        HostCapabilities,
        host_capabilities,
        host_fingerprint,
        kernel_threads_now,
        machine_summary,
    )
    from thintact_sdk.host.roofline import measure_sgemm_gflops, roofline_ratio  # noqa: F401
    from thintact_sdk.pixels.bayer import (  # noqa: F401
        block_mean,
        mosaic_from_planes,
        mosaic_from_rgb,
        planar_frame,
    )
    from thintact_sdk.pixels.tone_curve import encode  # noqa: F401

_WHERE = {
    "fraction": "apps.cli.argtypes",
    "int_range": "apps.cli.argtypes",
    "non_negative_int": "apps.cli.argtypes",
    "positive_float": "apps.cli.argtypes",
    "positive_int": "apps.cli.argtypes",
    "seed": "apps.cli.argtypes",
    "add_force_argument": "apps.cli.output_path",
    "check_not_an_input": "apps.cli.output_path",
    "claim_output": "apps.cli.output_path",
    "file_input": "apps.cli.output_path",
    "CameraSettings": "device.camera_settings",
    "FrameGeometrySettings": "device.camera_settings",
    "apply_geometry": "device.camera_settings",
    "crop_box": "device.camera_settings",
    "parse_camera_settings": "device.camera_settings",
    "FrameGapCounter": "device.cameras",
    "bit_depth_problem": "device.cameras",
    "camera_is_simulated": "device.cameras",
    "channel_layout": "device.cameras",
    "get_registry": "device.registry",
    "REFERENCE_EXPOSURE_US": "device.virtual_bench",
    "SceneSlot": "device.virtual_bench",
    "get_scene_slot": "device.virtual_bench",
    "signal_scale_dn": "device.virtual_bench",
    "white_level_dn": "device.virtual_bench",
    "McapLog": "formats.mcap",
    "NoiseSpec": "formats.profiles",
    "Profile": "formats.profiles",
    "available_profiles": "formats.profiles",
    "load_profile": "formats.profiles",
    "profile_from_dict": "formats.profiles",
    "write_profile": "formats.profiles",
    "PIXEL_FORMAT_FIELD": "formats.raw_frames",
    "RAW_FIELD": "formats.raw_frames",
    "load_raw_data": "formats.raw_frames",
    "save_raw_frame": "formats.raw_frames",
    "Recording": "formats.recording",
    "read_npy": "formats.safe_arrays",
    "read_npz": "formats.safe_arrays",
    "blas_threads": "host.blas",
    "prepare_worker_thread": "host.compute_threads",
    "single_threaded_kernels": "host.compute_threads",
    "HostCapabilities": "host.machine",
    "host_capabilities": "host.machine",
    "host_fingerprint": "host.machine",
    "kernel_threads_now": "host.machine",
    "machine_summary": "host.machine",
    "measure_sgemm_gflops": "host.roofline",
    "roofline_ratio": "host.roofline",
    "block_mean": "pixels.bayer",
    "mosaic_from_planes": "pixels.bayer",
    "mosaic_from_rgb": "pixels.bayer",
    "planar_frame": "pixels.bayer",
    "encode": "pixels.tone_curve",
}
_MODULES = {
    "safe_json": "formats.safe_json",
    "safe_yaml": "formats.safe_yaml",
}

__all__ = sorted([*_WHERE, *_MODULES])


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(f"thintact_sdk.{_WHERE[name]}"), name)
    elif name in _MODULES:
        value = importlib.import_module(f"thintact_sdk.{_MODULES[name]}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
