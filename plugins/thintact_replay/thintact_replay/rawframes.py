"""Compatibility names: the raw-frame extension of recordings is a core format,
:mod:`thintact_sdk.formats.raw_frames`."""

from thintact_sdk.plugin_support import PIXEL_FORMAT_FIELD, RAW_FIELD, load_raw_data, save_raw_frame

__all__ = ["PIXEL_FORMAT_FIELD", "RAW_FIELD", "load_raw_data", "save_raw_frame"]
