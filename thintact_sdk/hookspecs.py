"""pluggy hook specifications: what a ThinTact plugin can provide.

A plugin is any importable module or object registered under the entry-point group
``thintact`` that implements some of these hooks (decorated with
:data:`thintact_sdk.hookimpl`). Each hook returns a list of :class:`Component`.

Factory conventions (what ``Component.factory`` is called with):

========================  =====================================================
hook                      factory signature
========================  =====================================================
thintact_cameras          ``factory(profile: Profile, settings: dict) -> Camera``
thintact_light_controllers ``factory(port: str | None, settings: dict) -> LightController``
thintact_masks            ``factory() -> MaskDesigner``
thintact_decoders         ``factory(profile: Profile, settings: dict) -> Decoder``
thintact_displays         ``factory(profile: Profile, settings: dict) -> Display``
thintact_cli_commands     ``factory(subparsers) -> None`` (adds argparse subcommands)
thintact_benchmarks       ``factory(parser) -> None`` (a ``thintact bench NAME``: adds its
                          arguments and ``set_defaults(func=run)``)
thintact_device_listers   ``factory(parser) -> lister`` (a section of ``thintact devices``:
                          adds its options to the command's parser, returns
                          ``lister(args) -> (data, lines)``: its JSON-able section, printed
                          under the component's name by ``--json``, and its text lines, a
                          heading first; ``args.timeout`` bounds one enumeration, seconds)
========================  =====================================================
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pluggy

PROJECT = "thintact"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)

KINDS = ("camera", "light_controller", "mask", "decoder", "display", "cli_command", "benchmark",
         "device_lister")


@dataclass
class Component:
    """One thing a plugin provides.

    Attributes
    ----------
    name
        Unique name within its kind, used in profiles (``camera.plugin: genicam``).
    factory
        Callable building the component (signature per kind, see module docstring).
    description
        One line shown by ``thintact plugins``.
    plugin
        Name of the providing plugin (filled in by the plugin manager).
    traits
        What the core may rely on without knowing the plugin, from :data:`TRAITS`
        (e.g. a camera with ``"simulated"`` renders a simulated world, so a simulated
        photometric LUT is valid for it).
    """

    name: str
    factory: Callable[..., Any]
    description: str = ""
    plugin: str = ""
    traits: tuple[str, ...] = ()


TRAITS = {
    "simulated": "camera: frames are rendered by the simulator (the virtual sensor)",
    "calibration-candidate": "decoder: the calibration cross-validates it on the unit's frames and may "
                             "recommend it; the first one registered is the calibration's default",
    "tau-key=FIELD": "decoder: reads its Tikhonov tau from calibration.json field FIELD (default: tau)",
    "scene-prior": "decoder: takes a ScenePrior (setting prior); the calibration fits one for it",
    "joint-filter": "decoder: needs the bundle's trained joint filter (filter.npz)",
}
"""Traits a component may declare, and what each promises. A trait is a word, or
``key=value`` for one that carries a value (:func:`trait_value`)."""


def trait_value(traits: tuple[str, ...], key: str) -> str | None:
    """The value of trait ``key=value`` among ``traits``; ``None`` when not declared."""
    for trait in traits:
        if trait.startswith(f"{key}="):
            return trait[len(key) + 1:]
    return None


class ThinTactSpec:
    """The hooks. Every hook returns a list of :class:`Component`."""

    @hookspec
    def thintact_cameras(self) -> list[Component]:
        """Camera backends."""
        return []

    @hookspec
    def thintact_light_controllers(self) -> list[Component]:
        """LED controllers."""
        return []

    @hookspec
    def thintact_masks(self) -> list[Component]:
        """Mask designs."""
        return []

    @hookspec
    def thintact_decoders(self) -> list[Component]:
        """Reconstruction algorithms."""
        return []

    @hookspec
    def thintact_displays(self) -> list[Component]:
        """Displays for the calibration wizard."""
        return []

    @hookspec
    def thintact_cli_commands(self) -> list[Component]:
        """Extra ``thintact`` subcommands."""
        return []

    @hookspec
    def thintact_benchmarks(self) -> list[Component]:
        """Extra ``thintact bench`` benchmarks (a plugin benchmarks what it provides)."""
        return []

    @hookspec
    def thintact_device_listers(self) -> list[Component]:
        """Sections of ``thintact devices`` (e.g. the GenTL producers and their devices)."""
        return []
