"""ThinTact mask designs: MLS baseline, seeded random and the paper's GA optimiser.

Components of kind ``mask`` (``factory() -> MaskDesigner``):

- ``mls``: 255-length maximal-length sequence repeated to K (the paper's baseline);
- ``random``: seeded uniform ±1;
- ``ga``: genetic-algorithm optimisation of φ for a device profile (paper §III-C).
"""

from __future__ import annotations

from typing import Any

from thintact_masks.errors import MaskDesignError
from thintact_masks.mls import MLSDesigner, RandomDesigner
from thintact_sdk import Component, hookimpl
from thintact_sdk.interfaces import Mask, MaskDesigner
from thintact_sdk.plugin_support import Profile, load_profile

__all__ = ["GADesigner", "MLSDesigner", "MaskDesignError", "RandomDesigner", "thintact_masks"]


class GADesigner(MaskDesigner):
    """Genetic-algorithm mask optimisation for one device.

    Options of :meth:`design`: ``profile`` (required: name, file or Profile), ``population``,
    ``generations``, ``seed``, ``scale``, ``out_dir`` (checkpoints, design.json, fitness.png),
    ``fitness`` (a :class:`thintact_masks.fitness.FitnessSettings`), ``progress``.
    """

    name = "ga"

    def design(self, K: int, feature_um: float, **options: Any) -> Mask:  # noqa: N803
        from thintact_masks.fitness import FitnessSettings
        from thintact_masks.ga import GAConfig
        from thintact_masks.optimize import optimize_mask

        if options.get("profile") is None:
            raise MaskDesignError("the ga mask designer needs profile=<name, file or Profile>")
        profile: Profile = load_profile(options["profile"])
        if abs(float(feature_um) - profile.mask.feature_um) > 1e-9:
            profile = profile.model_copy(
                update={"mask": profile.mask.model_copy(update={"feature_um": float(feature_um)})})
        config = GAConfig(population=int(options.get("population", 200)),
                          generations=int(options.get("generations", 2000)),
                          seed=int(options.get("seed", 0)))
        settings = options.get("fitness") or FitnessSettings()
        mask, _ = optimize_mask(profile, config, K, settings, float(options.get("scale", 1.0)),
                                options.get("out_dir"), options.get("progress"))
        return mask

    def stored_design(self, device: str) -> tuple[Mask, dict[str, Any]] | None:
        """The shipped GA design of ``device`` (``designs/<device>-ga.json``), if there is one."""
        from thintact_masks.design_io import DESIGNS_DIR, load_design

        path = DESIGNS_DIR / f"{device}-ga.json"
        return load_design(path) if path.is_file() else None


@hookimpl
def thintact_masks() -> list[Component]:
    return [
        Component("mls", MLSDesigner, "255-length MLS repeated to K (the paper's baseline)"),
        Component("random", RandomDesigner, "seeded uniform random +1/-1 vector"),
        Component("ga", GADesigner, "genetic-algorithm optimised phi for a device (paper III-C)"),
    ]


def _register_mask_command(subparsers: Any) -> None:
    from thintact_masks.cli import register

    register(subparsers)


@hookimpl
def thintact_cli_commands() -> list[Component]:
    return [Component("mask", _register_mask_command,
                      "thintact mask: design, optimise (GA), show, compare and apply mask patterns")]
