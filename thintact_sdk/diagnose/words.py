"""Plain words for findings: what the model left out, and what recording would tell two
equally good explanations apart."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from thintact_sdk.profile import Profile


def _max_angle_deg(p: Profile) -> float:
    half_s = 0.5 * math.hypot(p.sensor.rows, p.sensor.cols) * p.sensor.pixel_pitch_um * 1e-3
    half_x = 0.5 * math.hypot(p.scene.rows, p.scene.cols) * p.scene.pixel_pitch_um * 1e-3
    return math.degrees(math.atan((half_s + half_x) / p.geometry.total_mm))


def describe_effect(name: str, params: dict[str, Any], p: Profile) -> str:
    """One sentence: the physics the model left out, with its fitted size."""
    d_mm = p.geometry.mask_to_sensor_mm
    if name == "diffraction":
        wl = [float(x) for x in params["wavelength_nm"]]
        blur = [math.sqrt(w * 1e-6 * d_mm) * 1e3 for w in wl]
        return (
            f"Fresnel diffraction at the mask: with wavelengths {', '.join(f'{w:.0f}' for w in wl)} nm "
            f"the {p.mask.feature_um:g} um cells blur by about {min(blur):.0f}-{max(blur):.0f} um "
            f"(sqrt(λ·d)) over the {d_mm:g} mm gap; the model assumed sharp geometric shadows."
        )
    if name == "pixel_angular_response":
        e = float(params["exponent"])
        th = _max_angle_deg(p)
        drop = 1.0 - math.cos(math.radians(th)) ** e
        return (
            f"The pixels respond less to oblique light than the model assumed: an extra cos^{e:.2f} "
            f"of the angle of incidence, {drop:.0%} less signal at the steepest ray ({th:.0f}°)."
        )
    if name == "refraction":
        n = float(params["n_scene_side"])
        z = p.geometry.scene_to_mask_mm
        return (
            f"The {z:g} mm scene-to-mask gap is a medium of refractive index {n:.3f} (elastomer, "
            f"glass), not air: rays bend at the mask, so the scene looks about {z / n:.2f} mm away "
            "near the axis; the model assumed straight rays in air."
        )
    if name == "mask_misalignment":
        return (
            f"The mask is turned by {float(params['angle_deg']):+.3f}° and shifted by "
            f"({float(params['dx_um']):+.1f}, {float(params['dy_um']):+.1f}) um relative to the sensor; "
            "the model assumed it centred and square."
        )
    if name == "mask_leakage":
        return (
            f"The closed mask cells pass {float(params['transmittance']):.2%} of the light; the "
            "model assumed them opaque."
        )
    if name == "geometry":
        z, d = float(params["scene_to_mask_mm"]), float(params["mask_to_sensor_mm"])
        return (
            f"The gaps differ from the profile: scene-to-mask {z:.3f} mm (profile "
            f"{p.geometry.scene_to_mask_mm:g}), mask-to-sensor {d:.3f} mm (profile "
            f"{p.geometry.mask_to_sensor_mm:g}); the shadow of the mask is magnified differently."
        )
    if name == "sensor_blur":
        s = float(params["sigma_um"])
        return (
            f"Light spreads between neighbouring pixels: a Gaussian blur of σ = {s:.1f} um "
            f"({s / p.sensor.pixel_pitch_um:.2f} pixels) in the sensor plane (optical/electrical "
            "crosstalk); the model assumed independent pixels."
        )
    if name == "scene_blur":
        s = float(params["sigma_um"])
        return (
            f"The scene is blurred before it reaches the mask: a Gaussian of σ = {s:.1f} um "
            f"({s / p.scene.pixel_pitch_um:.2f} scene pixels), e.g. a diffuser or scattering in the "
            "elastomer; the model assumed sharp scene pixels."
        )
    if name == "display_gamma":
        return (
            f"The display is not linear: emitted radiance = value^{float(params['gamma']):.3f}; the "
            "model assumed radiance proportional to the value."
        )
    if name == "color_crosstalk":
        m = np.asarray(params["matrix"], float)
        off = m - np.diag(np.diag(m))
        i, j = np.unravel_index(int(np.argmax(np.abs(off))), off.shape)
        ch = "RGB"
        return (
            f"The colour channels leak into each other (largest: {off[i, j]:+.1%} of {ch[j]} appears "
            f"in {ch[i]}); the model assumed pure channels."
        )
    if name == "veiling_glare":
        return (
            f"A uniform veil adds {float(params['fraction']):.2%} of each frame's mean signal to "
            "every pixel (glare inside the sensor stack); the model had no such veil."
        )
    if name == "sensor_gamma":
        return (
            f"The sensor response is not linear: DN − black = FS·(L/FS)^{float(params['gamma']):.3f}; "
            "the model assumed DN proportional to light."
        )
    if name == "saturation":
        return (
            f"Pixels clip at {float(params['level_dn']):.0f} DN, below the declared saturation "
            f"{p.noise.saturation_dn:g} DN; the model let them rise further."
        )
    if name == "stray_light":
        means = [float(x) for x in params["mean_dn"]]
        return (
            f"Light that never passed the mask adds a smooth, scene-independent glow of "
            f"{', '.join(f'{x:.1f}' for x in means)} DN (R, G, B) on average; the model had none."
        )
    return f"{name}: {params}"


_PAIR_HINTS: dict[frozenset[str], str] = {
    frozenset({"geometry", "refraction"}): (
        "a measured gap (or a second recording with the scene at another distance), or scenes with "
        "bright content far off-axis, where Snell's law departs from a changed straight-ray distance"
    ),
    frozenset({"diffraction", "sensor_blur"}): (
        "single-colour frames: diffraction blurs red more than blue, pixel crosstalk is colour-blind"
    ),
    frozenset({"display_gamma", "sensor_gamma"}): (
        "uniform grey frames at several display levels and one level at several exposures: "
        "display gamma bends the first series only, sensor gamma both"
    ),
    frozenset({"scene_blur", "sensor_blur"}): (
        "fine slits and checkers at several scales: scene blur softens the scene, sensor blur the "
        "mask's shadow, which stays sharp for a white scene under scene blur"
    ),
    frozenset({"diffraction", "scene_blur"}): (
        "a white frame: diffraction still softens the mask's shadow, scene blur leaves it unchanged"
    ),
    frozenset({"veiling_glare", "stray_light"}): (
        "a dark frame and a bright frame: glare scales with the frame's mean signal, stray light "
        "does not"
    ),
    frozenset({"pixel_angular_response", "geometry"}): (
        "a white frame and narrow slits near the edge of the scene: the angular response only "
        "dims, a changed geometry also moves the shadows"
    ),
}


def tell_apart(a: str, b: str, frame_hint: str) -> str:
    """What recording would separate effects ``a`` and ``b``."""
    base = _PAIR_HINTS.get(frozenset({a, b}))
    txt = f"To tell {a} from {b}: "
    if base:
        txt += base + "; "
    return txt + frame_hint
