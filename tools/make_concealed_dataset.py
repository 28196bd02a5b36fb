#!/usr/bin/env python
"""Recordings with concealed physics, to prove ``thintact diagnose``.

Each case is rendered with the project's most faithful path (the simulator with the case's
effects, then the sensor noise model) on a 128×160 device like ``golden/baseline/mini``,
24 frames (the golden scenes plus grey levels, single colours, checkers, a USAF chart,
random pixels and GelSight presses). The recording's ``profile.json`` has **empty
physics**: the effects are hidden from the tool. The truth is written next to the
recording, outside it::

    OUT/<case>/recording/      thintact-recording/1 (uint16 measurements)
    OUT/<case>/truth.json      {"case", "physics", "defects", "gains_dn_per_unit", "note"}

Cases: single effects at clear amplitudes, some below the per-pixel noise (visible only in
aggregate), pairs and triples (rotation with diffraction, rotation with refraction), none at
all, and defects outside the vocabulary (a dust speck: a small
dark Gaussian blot on the sensor; a dim column).

Usage::

    python tools/make_concealed_dataset.py --out /tmp/concealed            # every case
    python tools/make_concealed_dataset.py --out /tmp/c --cases clean diffraction
    python tools/make_concealed_dataset.py --list
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
GOLDEN_MINI = REPO.parent / "shared" / "golden" / "baseline" / "mini"
N_FRAMES = 24
WHITE_FRACTION = 0.6  # brightest all-white pixel at this fraction of (saturation - black)
CHANNEL_GAIN = (1.0, 0.93, 0.82)

CASES: dict[str, dict[str, Any]] = {
    "clean": {"physics": {}, "note": "nothing hidden"},
    "diffraction": {"physics": {"diffraction": {"wavelength_nm": [625.0, 530.0, 465.0]}}},
    "pixel_angular_response": {"physics": {"pixel_angular_response": {"exponent": 3.0}}},
    "refraction": {"physics": {"refraction": {"n_scene_side": 1.41}}},
    "mask_misalignment": {"physics": {"mask_misalignment": {"angle_deg": 0.3, "dx_um": 4.0, "dy_um": -3.0}}},
    "mask_shift": {"physics": {"mask_misalignment": {"angle_deg": 0.0, "dx_um": 6.0, "dy_um": 0.0}}},
    "mask_leakage": {"physics": {"mask_leakage": {"transmittance": 0.03}}},
    "geometry": {"physics": {"geometry": {"scene_to_mask_mm": 4.95, "mask_to_sensor_mm": 1.04}}},
    "sensor_gamma": {"physics": {"sensor_gamma": {"gamma": 0.92}}},
    "saturation": {"physics": {"saturation": {"level_dn": 2200.0}}},
    "sensor_blur": {"physics": {"sensor_blur": {"sigma_um": 6.0}}},
    "scene_blur": {"physics": {"scene_blur": {"sigma_um": 25.0}}},
    "display_gamma": {"physics": {"display_gamma": {"gamma": 1.15}}},
    "color_crosstalk": {
        "physics": {"color_crosstalk": {"matrix": [[1, 0.04, 0.01], [0.03, 1, 0.03], [0.0, 0.05, 1]]}}
    },
    "veiling_glare": {"physics": {"veiling_glare": {"fraction": 0.03}}},
    "stray_light": {"physics": {"stray_light": {"mean_dn": [40.0, 30.0, 20.0]}}},
    # below the per-pixel noise: only the aggregate over all pixels and frames reveals them
    "subnoise_leakage": {"physics": {"mask_leakage": {"transmittance": 0.006}}, "subnoise": True},
    "subnoise_sensor_blur": {"physics": {"sensor_blur": {"sigma_um": 5.0}}, "subnoise": True},
    "subnoise_stray_light": {"physics": {"stray_light": {"mean_dn": [8.0, 6.0, 5.0]}}, "subnoise": True},
    "subnoise_glare": {"physics": {"veiling_glare": {"fraction": 0.01}}, "subnoise": True},
    # pairs
    "pair_diffraction_shift": {
        "physics": {
            "diffraction": {"wavelength_nm": [625.0, 530.0, 465.0]},
            "mask_misalignment": {"angle_deg": 0.0, "dx_um": 5.0, "dy_um": -4.0},
        }
    },
    "pair_gamma_stray": {
        "physics": {"sensor_gamma": {"gamma": 0.93}, "stray_light": {"mean_dn": [30.0, 25.0, 20.0]}}
    },
    "pair_angular_leakage": {
        "physics": {"pixel_angular_response": {"exponent": 4.0}, "mask_leakage": {"transmittance": 0.02}}
    },
    "mask_rotation_035": {"physics": {"mask_misalignment": {"angle_deg": 0.35, "dx_um": 0.0, "dy_um": 0.0}},
                          "note": "the rotation an independent renderer saw recovered as 0.304 deg"},
    "pair_rotation_diffraction": {
        "physics": {
            "diffraction": {"wavelength_nm": [625.0, 530.0, 465.0]},
            "mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0},
        }
    },
    "pair_rotation_refraction": {
        "physics": {
            "refraction": {"n_scene_side": 1.41},
            "mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0},
        }
    },
    "pair_sensor_blur_leakage": {
        "physics": {"sensor_blur": {"sigma_um": 4.0}, "mask_leakage": {"transmittance": 0.025}},
        "note": "issue 34: a 4 um blur beside leakage was read as 1.0 um and put below the floor",
        "blur_by_scipy": True,
    },
    "pair_sensor_blur_leakage_1pct": {
        "physics": {"sensor_blur": {"sigma_um": 5.0}, "mask_leakage": {"transmittance": 0.01}},
        "note": "greedy selection took a scene blur first, which the sensor blur makes unnecessary",
        "blur_by_scipy": True,
    },
    # triples
    "triple_rotation_diffraction_stray": {
        "physics": {
            "diffraction": {"wavelength_nm": [625.0, 530.0, 465.0]},
            "mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0},
            "stray_light": {"mean_dn": [30.0, 25.0, 20.0]},
        }
    },
    "triple_rotation_refraction_gamma": {
        "physics": {
            "refraction": {"n_scene_side": 1.41},
            "mask_misalignment": {"angle_deg": 0.3, "dx_um": 0.0, "dy_um": 0.0},
            "sensor_gamma": {"gamma": 0.93},
        }
    },
    # defects outside the vocabulary
    "dust": {"physics": {}, "defects": [{"kind": "dust", "row": 40, "col": 110, "sigma_px": 2.5, "depth": 0.5}]},
    "dim_column": {"physics": {}, "defects": [{"kind": "column", "col": 57, "factor": 0.94}]},
}


def frame_scenes(n: int, m: int) -> tuple[list[str], np.ndarray]:
    """The 24 frames: ``(labels, F × N × M × 3 float32 display values)``."""
    from thintact_sdk.simulation import scenes as lib

    labels: list[str] = []
    imgs: list[np.ndarray] = []
    gold = GOLDEN_MINI / "scenes.npy"
    if gold.is_file():
        g = np.load(gold)
        glab = json.loads((GOLDEN_MINI / "labels.json").read_text())
        if g.shape[1:3] == (n, m):
            labels += list(glab)
            imgs += [x for x in g.astype(np.float32)]
    if not imgs:
        labels += ["white", "checker_8", "random_0", "smooth_color"]
        imgs += [lib.white(n, m), lib.checker(n, m, 8), lib.random_pixels(n, m, 0), lib.smooth_color(n, m)]
    extra: list[tuple[str, np.ndarray]] = [
        ("grey_25", np.full((n, m, 3), 0.25, np.float32)),
        ("grey_50", np.full((n, m, 3), 0.5, np.float32)),
        ("grey_75", np.full((n, m, 3), 0.75, np.float32)),
        ("red", np.dstack([np.ones((n, m)), np.zeros((n, m)), np.zeros((n, m))]).astype(np.float32)),
        ("blue", np.dstack([np.zeros((n, m)), np.zeros((n, m)), np.ones((n, m))]).astype(np.float32)),
        ("checker_16", lib.checker(n, m, 16)),
        ("checker_2", lib.checker(n, m, 2)),
        ("usaf", lib.usaf(n, m)),
        ("random_1", lib.random_pixels(n, m, 1)),
        ("random_2", lib.random_pixels(n, m, 2)),
        ("gelsight_ref", lib.gelsight(n, m, -1)),
        ("gelsight_0", lib.gelsight(n, m, 0)),
        ("gelsight_3", lib.gelsight(n, m, 3)),
        ("gelsight_7", lib.gelsight(n, m, 7)),
        ("gelsight_12", lib.gelsight(n, m, 12)),
    ]
    for lab, img in extra:
        if len(imgs) >= N_FRAMES:
            break
        labels.append(lab)
        imgs.append(img.astype(np.float32))
    return labels[:N_FRAMES], np.stack(imgs[:N_FRAMES])


def defect_map(rows: int, cols: int, defects: list[dict[str, Any]]) -> np.ndarray:
    """``R × S`` multiplicative response map of the defects (1 = healthy pixel)."""
    out = np.ones((rows, cols))
    yy, xx = np.mgrid[0:rows, 0:cols]
    for d in defects:
        if d["kind"] == "dust":
            r2 = (yy - d["row"]) ** 2 + (xx - d["col"]) ** 2
            out *= 1.0 - d["depth"] * np.exp(-r2 / (2.0 * d["sigma_px"] ** 2))
        elif d["kind"] == "column":
            out[:, d["col"]] *= d["factor"]
        else:
            raise ValueError(f"unknown defect kind {d['kind']!r}")
    return out


def base_profile() -> Any:
    """The device: golden-mini optics (shared golden profile, else the shipped virtual-mini)."""
    from thintact_sdk.formats.profiles import load_profile, read_profile_file

    gp = GOLDEN_MINI / "profile.json"
    prof = read_profile_file(gp) if gp.is_file() else load_profile("virtual-mini")
    return prof.with_physics({})


def make_case(name: str, out_dir: Path, seed: int = 0) -> Path:
    """Render case ``name`` into ``out_dir/name``; returns that directory."""
    from thintact_sdk.formats.recording import RecordingWriter
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    spec = CASES[name]
    prof = base_profile()
    labels, scenes = frame_scenes(prof.scene.rows, prof.scene.cols)
    fs = prof.noise.saturation_dn - prof.noise.black_level_dn
    base_white = Simulator(prof).linear_batch(scenes[:1])[0]
    gains = [WHITE_FRACTION * fs * g / float(base_white[..., c].max()) for c, g in enumerate(CHANNEL_GAIN)]
    physics = dict(spec["physics"])
    scipy_blur = physics.pop("sensor_blur", None) if spec.get("blur_by_scipy") else None
    sim = Simulator(prof.with_physics(physics))
    signal = sim.predict_signal_dn(scenes, gains)
    if scipy_blur is not None:
        # the sensor blur rendered independently of the simulator's own effect: scipy's
        # Gaussian filter (weights sampled at the pixel offsets, mirrored edges)
        from scipy.ndimage import gaussian_filter

        s_px = scipy_blur["sigma_um"] / prof.sensor.pixel_pitch_um
        signal = gaussian_filter(signal, sigma=(0, s_px, s_px, 0), mode="reflect", truncate=5.0)
    dmap = defect_map(prof.sensor.rows, prof.sensor.cols, spec.get("defects", []))
    signal = signal * dmap[None, :, :, None]
    rng = np.random.default_rng(seed + sum(map(ord, name)))
    case_dir = out_dir / name
    rec_dir = case_dir / "recording"
    if rec_dir.exists():
        shutil.rmtree(rec_dir)  # a fresh recording, never appended to an old one
    writer = RecordingWriter(rec_dir, prof)
    # a saturating pixel clips its final value (after the noise), like a real ADC
    level = spec["physics"].get("saturation", {}).get("level_dn")
    for i, (lab, sc) in enumerate(zip(labels, scenes, strict=True)):
        dn = signal_to_dn(signal[i], prof.noise, rng, saturation_dn=level)
        writer.add(np.round(dn).astype(np.uint16), scene=sc, label=lab)
    truth = {
        "case": name,
        "physics": spec["physics"],
        "defects": spec.get("defects", []),
        "subnoise": bool(spec.get("subnoise", False)),
        "gains_dn_per_unit": gains,
        "note": spec.get("note", ""),
        "effect_rms_dn": _effect_rms(prof, scenes, gains, signal / dmap[None, :, :, None]),
    }
    (case_dir / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return case_dir


def _effect_rms(prof: Any, scenes: np.ndarray, gains: list[float], signal: np.ndarray) -> float:
    from thintact_sdk.simulation.simulator import Simulator

    base = Simulator(prof).predict_signal_dn(scenes, gains)
    return float(np.sqrt(np.mean((signal - base) ** 2)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, help="output directory")
    ap.add_argument("--cases", nargs="*", help="case names (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    args = ap.parse_args(argv)
    if args.list:
        for k, v in CASES.items():
            print(f"{k:26s} {json.dumps(v.get('physics'))} {json.dumps(v.get('defects', []))}")
        return 0
    if args.out is None:
        ap.error("--out is required")
    names = args.cases or list(CASES)
    bad = [n for n in names if n not in CASES]
    if bad:
        print(f"unknown case(s) {bad}; use --list", file=sys.stderr)
        return 2
    for n in names:
        d = make_case(n, args.out, args.seed)
        print(f"{n}: {d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
