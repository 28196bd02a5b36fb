"""Real2Sim (paper §VI-C): a CycleGAN that turns real tactile images into simulation-like
ones, so photometric stereo calibrated on (or like) the simulation applies to a real sensor.

* :mod:`.networks`: ResNet generator and PatchGAN discriminator;
* :mod:`.domains`: the real and simulated image sets;
* :mod:`.train`: training with resumable checkpoints (``thintact real2sim train``);
* :mod:`.translate`: inference (a profile's ``tactile.real2sim`` plugs it into the
  :class:`~thintact_sdk.tactile.interpretation.interpreter.TactileInterpreter`);
* :mod:`.evaluate`: the paper's held-out real-press table (``thintact real2sim evaluate``).
"""

from thintact_sdk.tactile.learning.model_file import GENERATOR_FORMAT, load_generator
from thintact_sdk.tactile.learning.translate import Real2SimTranslator

__all__ = ["GENERATOR_FORMAT", "Real2SimTranslator", "load_generator"]
