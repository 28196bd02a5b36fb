"""Errors of the mask plugin (all :class:`thintact_sdk.errors.ThinTactError`: one CLI line, exit 2)."""

from __future__ import annotations

from thintact_sdk.errors import ThinTactError


class MaskDesignError(ThinTactError):
    """A mask design, design file, GA setting or checkpoint cannot be used."""
