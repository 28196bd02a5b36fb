"""Compatibility names: the virtual optical bench lives in the core,
:mod:`thintact_sdk.device.virtual_bench` (the virtual display and camera plugins share it)."""

from thintact_sdk.plugin_support import (
    REFERENCE_EXPOSURE_US,
    SceneSlot,
    get_scene_slot,
    signal_scale_dn,
    white_level_dn,
)

__all__ = ["REFERENCE_EXPOSURE_US", "SceneSlot", "get_scene_slot", "signal_scale_dn", "white_level_dn"]
