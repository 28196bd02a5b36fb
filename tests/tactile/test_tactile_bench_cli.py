"""`thintact bench tactile` is wired into the CLI (the benchmark itself is too slow for tests)."""

from __future__ import annotations

from thintact_sdk.cli.main import build_parser


def test_bench_tactile_arguments():
    args = build_parser().parse_args(["bench", "tactile", "--presses", "1", "--skip-latency",
                                      "--decoder", "flatcam"])
    assert args.presses == 1 and args.skip_latency and args.decoder == "flatcam"
    assert args.profile == "virtual-finger" and args.latency_profile == "thintact-paper"
    assert callable(args.func)


def test_calibrate_tactile_arguments():
    args = build_parser().parse_args(["calibrate-tactile", "--profile", "virtual-finger"])
    assert args.presses == 12 and args.ball_radius_mm == 1.5 and args.recording is None
