"""Check that the plugins a profile names exist (``thintact profile validate --strict``)."""

from __future__ import annotations

from thintact_sdk.device.registry import PluginRegistry, get_registry
from thintact_sdk.errors import PluginError, ProfileError
from thintact_sdk.formats.profiles import Profile

_SECTION_KIND = {
    "camera": "camera",
    "light": "light_controller",
    "decoder": "decoder",
    "display": "display",
}
"""Profile section → the plugin kind its ``plugin`` field names."""


def check_profile_plugins(profile: Profile, registry: PluginRegistry | None = None) -> None:
    """Raise if a ``<section>.plugin`` of ``profile`` is not an installed component.

    Raises
    ------
    ProfileError
        One line naming the file, the first unknown or ambiguous plugin's dotted field
        (``camera.plugin``) with the available names, and how many more there are.
    """
    reg = registry or get_registry()
    problems = []
    for section, kind in _SECTION_KIND.items():
        cfg = getattr(profile, section)
        if cfg is None:
            continue
        try:
            reg.get(kind, cfg.plugin)
        except PluginError as err:
            problems.append(f"{section}.plugin: {' '.join(str(err).split())}")
    if problems:
        where = profile.source or "(in memory)"
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise ProfileError(f"invalid profile {where}: {problems[0]}{more}")
