"""Tactile pipeline: membrane simulation, photometric stereo, Poisson depth, markers.

Two calls cover most programs::

    from thintact_sdk import tactile
    sim = tactile.TactileSimulator.for_profile(profile)
    press = sim.press(tactile.Sphere(2.0), depth_mm=0.5)      # scene + ground truth
    interp = tactile.TactileInterpreter.for_profile(profile)  # device LUT (or simulated)
    interp.set_reference(sim.flat().scene)                    # no-contact image
    frame = interp.interpret(press.scene)                     # TactileFrame

See ``docs/tactile.md``.
"""

from thintact_sdk.tactile.calibration.ball_press import (
    CALIBRATION_BALL_RADIUS_MM,
    BallPress,
    ball_slopes,
    calibrate_from_presses,
    find_press_circle,
    random_ball_presses,
    scene_level_lut,
)
from thintact_sdk.tactile.calibration.store import (
    calibration_roots,
    calibrations_root,
    device_lut_path,
    find_lut,
    load_device_lut,
    lut_for_profile,
    save_device_lut,
)
from thintact_sdk.tactile.interpretation.colour_change import fill_masked
from thintact_sdk.tactile.interpretation.grid import TactileParams, pixel_grid_mm
from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
from thintact_sdk.tactile.interpretation.markers import (
    MarkerDetection,
    MarkerTracker,
    detect_markers,
    marker_lattice_mm,
    mean_shear,
)
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut
from thintact_sdk.tactile.interpretation.poisson import integrate_gradients
from thintact_sdk.tactile.simulation.indenters import (
    INDENTERS,
    ChamferedPrism,
    CubeEdge,
    Cylinder,
    Indenter,
    Sphere,
    Text,
    Texture,
    make_indenter,
)
from thintact_sdk.tactile.simulation.lighting import LED, PhongShading, default_leds
from thintact_sdk.tactile.simulation.membrane import TactileScene, TactileSimulator, simulate_press

__all__ = [
    "CALIBRATION_BALL_RADIUS_MM",
    "INDENTERS",
    "LED",
    "BallPress",
    "ChamferedPrism",
    "CubeEdge",
    "Cylinder",
    "Indenter",
    "MarkerDetection",
    "MarkerTracker",
    "PhongShading",
    "PhotometricLUT",
    "Sphere",
    "TactileInterpreter",
    "TactileParams",
    "TactileScene",
    "TactileSimulator",
    "Text",
    "Texture",
    "ball_slopes",
    "calibrate_from_presses",
    "calibrate_lut",
    "calibration_roots",
    "calibrations_root",
    "default_leds",
    "detect_markers",
    "device_lut_path",
    "fill_masked",
    "find_lut",
    "find_press_circle",
    "integrate_gradients",
    "load_device_lut",
    "lut_for_profile",
    "make_indenter",
    "marker_lattice_mm",
    "mean_shear",
    "pixel_grid_mm",
    "random_ball_presses",
    "save_device_lut",
    "scene_level_lut",
    "simulate_press",
]
