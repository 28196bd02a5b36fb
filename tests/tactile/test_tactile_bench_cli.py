"""`thintact bench tactile` is wired into the CLI (the benchmark itself is too slow for tests)."""

from __future__ import annotations

from thintact_sdk.apps.cli.main import build_parser


def test_bench_tactile_arguments():
    args = build_parser().parse_args(["bench", "tactile", "--presses", "1", "--skip-latency",
                                      "--decoder", "flatcam"])
    assert args.presses == 1 and args.skip_latency and args.decoder == "flatcam"
    assert args.profile == "virtual-finger" and args.latency_profile == "thintact-paper"
    assert callable(args.func)


def test_calibrate_tactile_arguments():
    args = build_parser().parse_args(["calibrate-tactile", "--profile", "virtual-finger"])
    assert args.presses == 12 and args.ball_radius_mm == 1.5 and args.recording is None


def test_latency_decoder_from_a_bundle_directory_or_an_in_memory_bundle():
    """``--latency-bundle DIR`` decodes with the named decoder on that bundle (frames rendered
    with its matrices); without a bundle on disk, ``--decoder`` runs on an in-memory bundle of
    the directly generated matrices (instead of the flatcam default)."""
    from pathlib import Path

    from thintact_sdk.apps.benchmarks.tactile_accuracy import _latency_decoder
    from thintact_sdk.formats.profiles import load_profile
    from thintact_sdk.reconstruction.bundle import find_latest

    profile = load_profile("virtual-mini")
    bundle_dir = find_latest(Path(__file__).resolve().parents[2] / "thintact_sdk" / "data" / "calibrations"
                             / "virtual-mini")
    dec, sm, how = _latency_decoder(profile, "t2s-closed-form", bundle_dir)
    assert dec.name == "t2s-closed-form" and str(bundle_dir) in how
    assert sm is not None and sm.sensor_shape == (128, 160)
    no_bundle = profile.model_copy(update={"decoder": None}, deep=True)
    no_bundle = no_bundle.model_copy(update={"camera": no_bundle.camera.model_copy(update={"plugin": "uvc"})})
    dec, sm, how = _latency_decoder(no_bundle, "t2s-closed-form")
    assert dec.name == "t2s-closed-form" and "in-memory bundle" in how and sm is not None
