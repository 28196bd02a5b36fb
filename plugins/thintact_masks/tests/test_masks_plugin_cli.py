"""Plugin discovery through the registry and the ``thintact mask`` CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mask_profiles import make_profile

from thintact_sdk.apps.cli.main import main
from thintact_sdk.device.registry import get_registry
from thintact_sdk.formats.profiles import read_profile_file, write_profile
from thintact_sdk.interfaces import MaskDesigner


def test_registry_provides_the_three_designers() -> None:
    reg = get_registry(reload=True)
    comps = reg.components("mask")
    for name in ("mls", "random", "ga"):
        assert comps[name].plugin == "thintact-masks"
        designer = reg.create("mask", name)
        assert isinstance(designer, MaskDesigner)
    mask = reg.create("mask", "mls").design(765, 20.0)
    assert mask.K == 765 and mask.pattern().shape == (765, 765)


def test_ga_designer_runs_through_the_registry(tmp_path) -> None:
    prof_path = write_profile(make_profile(), tmp_path / "tiny.yaml")
    ga = get_registry().create("mask", "ga")
    mask = ga.design(40, 60.0, profile=str(prof_path), population=6, generations=2, seed=1)
    assert mask.K == 40 and mask.design == "ga"
    assert mask.provenance["generations"] == 2
    with pytest.raises(Exception, match="needs profile"):
        ga.design(40, 60.0)


@pytest.fixture
def tiny_profile_file(tmp_path):
    return write_profile(make_profile(), tmp_path / "tiny.yaml")


def test_optimize_show_compare_apply(tmp_path, tiny_profile_file, capsys) -> None:
    out = tmp_path / "run"
    rc = main(["mask", "optimize", "--profile", str(tiny_profile_file), "--population", "6",
               "--generations", "2", "--out", str(out), "--no-progress"])
    assert rc == 0
    rec = json.loads((out / "design.json").read_text())
    assert rec["format"] == "thintact-mask-design/1" and rec["K"] == 40
    assert len(rec["history"]["best"]) == 3
    assert set(rec["baselines"]) == {"mls", "random"}
    assert (out / "fitness.png").stat().st_size > 1000
    # re-running the finished run resumes from the checkpoint and gives the same design
    assert main(["mask", "optimize", "--profile", str(tiny_profile_file), "--population", "6",
                 "--generations", "2", "--out", str(out), "--no-progress"]) == 0
    assert json.loads((out / "design.json").read_text())["phi"] == rec["phi"]

    png = tmp_path / "mask.png"
    assert main(["mask", "show", str(out / "design.json"), "--out", str(png), "--cell-px", "3"]) == 0
    import cv2

    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (120, 120)
    phi = np.asarray(rec["phi"])
    np.testing.assert_array_equal(img[::3, ::3] > 0, np.outer(phi, phi) > 0)

    capsys.readouterr()
    assert main(["mask", "compare", "--profile", str(tiny_profile_file), str(out / "design.json"),
                 "--json", "--exact"]) == 0
    tables = json.loads(capsys.readouterr().out)
    scores = {s["name"]: s for s in tables["direct generation"]}
    assert {"mls", "random", "run", "profile"} <= set(scores)
    assert scores["run"]["fitness"] == pytest.approx(rec["fitness"])
    exact = {s["name"]: s for s in tables["exact simulator"]}
    for name, s in scores.items():  # direct generation is close to the exact physics
        assert exact[name]["fitness"] == pytest.approx(s["fitness"], rel=0.05)

    new_profile = tmp_path / "with_ga.yaml"
    assert main(["mask", "apply", str(out / "design.json"), "--profile", str(tiny_profile_file),
                 "--out", str(new_profile)]) == 0
    assert read_profile_file(new_profile).mask.phi == rec["phi"]


def test_scaled_run(tmp_path, capsys) -> None:
    out = tmp_path / "scaled"
    assert main(["mask", "optimize", "--profile", "virtual-mini", "--scale", "0.25",
                 "--population", "4", "--generations", "1", "--out", str(out),
                 "--no-progress"]) == 0
    rec = json.loads((out / "design.json").read_text())
    assert rec["scale"] == 0.25 and rec["K"] == 32
    assert rec["device"]["sensor"][:2] == [32, 40]


def test_design_command_writes_mls(tmp_path) -> None:
    path = tmp_path / "mls.json"
    assert main(["mask", "design", "--kind", "mls", "--K", "765", "--feature-um", "20",
                 "--out", str(path)]) == 0
    rec = json.loads(path.read_text())
    assert rec["design"] == "mls" and len(rec["phi"]) == 765


@pytest.mark.parametrize("argv", [
    ["mask", "show", "/nonexistent/design.json", "--out", "x.png"],
    ["mask", "optimize", "--profile", "no-such-profile", "--out", "{tmp}/o"],
    ["mask", "optimize", "--profile", "virtual-mini", "--scale", "2", "--out", "{tmp}/o"],
    ["mask", "optimize", "--profile", "virtual-mini", "--population", "1", "--out", "{tmp}/o"],
    ["mask", "optimize", "--profile", "virtual-mini", "--frames", "0", "--out", "{tmp}/o"],
    ["mask", "compare", "--profile", "virtual-mini", "{tmp}/bad.json"],
    ["mask", "design", "--kind", "nope", "--K", "10", "--feature-um", "20", "--out", "{tmp}/d.json"],
])
def test_user_errors_exit_2_with_one_line(tmp_path, capsys, argv) -> None:
    (tmp_path / "bad.json").write_text('{"format": "something-else"}')
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # a bad number is refused by its option's type: argparse's "thintact mask ACTION: error: argument ..."
    assert len(err) == 1 and err[0].startswith(("thintact: error:", f"thintact mask {argv[1]}: error: argument"))


def test_resuming_a_different_run_exits_2(tmp_path, tiny_profile_file, capsys) -> None:
    out = str(tmp_path / "r")
    base = ["mask", "optimize", "--profile", str(tiny_profile_file), "--population", "4",
            "--generations", "1", "--out", out, "--no-progress"]
    assert main(base) == 0
    assert main(base + ["--seed", "9"]) == 2
    assert "different run" in capsys.readouterr().err


def test_shipped_designs_load_and_beat_their_baselines() -> None:
    from thintact_masks.design_io import DESIGNS_DIR, load_design

    files = sorted(DESIGNS_DIR.glob("*.json"))
    assert files, "no shipped designs"
    for f in files:
        mask, rec = load_design(f.stem)  # shipped designs resolve by name
        assert mask.design == "ga" and mask.K == rec["K"] == len(rec["phi"])
        assert rec["fitness"] > rec["baselines"]["mls"]["fitness"]
        assert rec["fitness"] > rec["baselines"]["random"]["fitness"]
        assert rec["history"]["best"][-1] == pytest.approx(rec["fitness"])
        assert f.stat().st_size < 2_000_000


def test_pattern_png_at_a_path_that_is_not_utf8(tmp_path) -> None:
    """cv2.imwrite crashed the process on such a path; the PNG is encoded in memory."""
    import os

    import cv2
    from thintact_masks.design_io import render_mask_png

    from thintact_sdk.interfaces import Mask

    mask = Mask(phi=np.array([1, -1, 1, 1, -1, -1, 1], np.int8), feature_um=20.0)
    p = render_mask_png(mask, os.fsdecode(os.fsencode(tmp_path) + b"/pattern_\xff.png"), cell_px=2)
    img = cv2.imdecode(np.fromfile(p, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (2 * mask.K, 2 * mask.K) and set(np.unique(img)) == {0, 255}
    with pytest.raises(Exception, match="use a .png name"):
        render_mask_png(mask, tmp_path / "pattern.xyz")
