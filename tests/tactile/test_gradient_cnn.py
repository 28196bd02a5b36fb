"""The convolutional gradient model (issue 29 item 3): inference equal to the torch network
it was trained as and to the layers' definition, on one kernel thread where a stream holds
them, files read without trusting them, stored beside the LUT, and it
reads slopes that a per-pixel model cannot tell apart."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thintact_sdk.errors import CalibrationError
from thintact_sdk.tactile.calibration.ball_eval import ball_cap
from thintact_sdk.tactile.interpretation.gradient_model import (
    GRADIENT_MODELS,
    ConvGradient,
    describe_validation,
    mlp_inputs,
    train_cnn,
    train_mlp,
)
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT, calibrate_lut, net_path

MM = 0.1


def _saturating_press(shape, centre, press, radius=2.0):
    """A ball press whose colour change stops growing with the slope at 45° (as a
    GelSight-type gel's nearly does): the colour holds the slope's direction and
    ``min(|g|, 1)``."""
    _, gx, gy, _ = ball_cap(shape, centre, press, radius, MM)
    mag = np.hypot(gx, gy)
    sat = np.minimum(mag, 1.0) / np.maximum(mag, 1e-9)
    change = np.stack([gx * sat, gy * sat, -0.5 * (gx + gy) * sat], -1).astype(np.float32) * 0.2
    return change, (0.5 + change).astype(np.float32), gx.astype(np.float32), gy.astype(np.float32)


def _presses(n, seed, shape=(48, 64)):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        centre = (rng.uniform(16, shape[0] - 16), rng.uniform(16, shape[1] - 16))
        out.append(_saturating_press(shape, centre, rng.uniform(0.6, 1.6)))
    return [list(v) for v in zip(*out, strict=True)]


def _small_net(steps=30):
    change, image, gx, gy = _presses(3, 0)
    valid = [np.ones(c.shape[:2], bool) for c in change]
    return train_cnn(change, image, gx, gy, valid, width=8, dilations=(1, 2), steps=steps,
                     crop=32), change[0], image[0]


def _direct_conv3(h, w, b, d):
    """The dilated 3 × 3 cross-correlation by its definition, edges replicated."""
    n, m = h.shape[:2]
    p = np.pad(h, ((d, d), (d, d), (0, 0)), mode="edge").astype(np.float64)
    out = np.broadcast_to(b.astype(np.float64), (n, m, w.shape[-1])).copy()
    for i in range(3):
        for j in range(3):
            out += p[i * d:i * d + n, j * d:j * d + m] @ w[i, j].astype(np.float64)
    return out


def test_inference_is_the_torch_network_it_was_trained_as():
    import torch

    net, change, image = _small_net()
    layers: list[torch.nn.Module] = []
    cin = 8
    for k, d in enumerate(net.dilations):
        conv = torch.nn.Conv2d(cin, 8, 3, padding=d, dilation=d, padding_mode="replicate")
        conv.weight.data = torch.from_numpy(net.weights[f"w{k}"].transpose(3, 2, 0, 1).copy())
        conv.bias.data = torch.from_numpy(net.weights[f"b{k}"])
        layers += [conv, torch.nn.Tanh()]
        cin = 8
    last = torch.nn.Conv2d(cin, 2, 1)
    n = len(net.dilations)
    last.weight.data = torch.from_numpy(net.weights[f"w{n}"].T.copy()[:, :, None, None])
    last.bias.data = torch.from_numpy(net.weights[f"b{n}"])
    ref = torch.nn.Sequential(*layers, last)
    x = torch.from_numpy(mlp_inputs(change, image).transpose(2, 0, 1)[None].copy())
    with torch.no_grad():
        want = ref(x)[0].numpy().transpose(1, 2, 0)
    got = net._forward(change, image)
    assert float(np.abs(want).max()) > 1e-3
    np.testing.assert_allclose(got, want, atol=1e-5)
    # and the layers' definition, in float64 numpy
    h = mlp_inputs(change, image)
    for k, d in enumerate(net.dilations):
        h = np.tanh(_direct_conv3(h, net.weights[f"w{k}"], net.weights[f"b{k}"], d))
    direct = h @ net.weights[f"w{n}"] + net.weights[f"b{n}"]
    np.testing.assert_allclose(got, direct, atol=1e-5)
    assert got.dtype == np.float32 and got.shape == change.shape[:2] + (2,)


def test_inference_takes_one_kernel_thread_where_a_stream_holds_them():
    import threading

    import torch

    from thintact_sdk.host.compute_threads import single_threaded_kernels

    net, change, image = _small_net()
    seen: dict[str, int] = {}

    def run(key):
        torch.set_num_threads(2)
        net._forward(change, image)
        seen[key] = torch.get_num_threads()

    before = torch.get_num_threads()
    try:
        worker = threading.Thread(target=run, args=("free",))
        worker.start()
        worker.join()
        with single_threaded_kernels():
            worker = threading.Thread(target=run, args=("held",))
            worker.start()
            worker.join()
    finally:
        torch.set_num_threads(before)
    assert seen == {"free": 2, "held": 1}


def test_round_trip_flat_reference_and_grid(tmp_path):
    net, change, image = _small_net()
    gx, gy = net.predict(change, image)
    assert gx.shape == change.shape[:2] and gx.dtype == np.float32
    zx, zy = net.predict(np.zeros_like(change), image - change)
    assert float(np.abs(zx).max()) == 0.0 and float(np.abs(zy).max()) == 0.0
    back = ConvGradient.load(net.save(tmp_path / "net.npz"))
    assert back.dilations == (1, 2) and back.shape == change.shape[:2]
    np.testing.assert_array_equal(back.predict(change, image)[0], gx)
    with pytest.raises(CalibrationError, match="working grid"):
        back.predict(change[:-1], image[:-1])


def test_a_stream_runs_the_network_once_per_frame():
    """The interpreter hands the network ``background + change``; its no-contact answer is
    reused although ``(background + change) - change`` rounds off the background, and
    recomputed for another reference frame."""
    net, change, image = _small_net()
    background = (image - change).astype(np.float32)
    calls = []
    forward = net._forward
    net._forward = lambda c, i: calls.append(1) or forward(c, i)  # type: ignore[method-assign]
    rng = np.random.default_rng(1)
    for _ in range(4):
        frame_change = (change * rng.uniform(0.5, 1.5)).astype(np.float32)
        colour = background + frame_change
        assert float(np.abs((colour - frame_change) - background).max()) > 0  # it does round
        net.predict(frame_change, colour)
    assert len(calls) == 4 + 1  # one per frame, one for the background
    net.predict(change, background + 4e-3 + change)  # the next reference frame: an 8-bit step
    assert len(calls) == 5 + 2

def _write(p, **arrays):
    np.savez(p, **arrays)
    return p


@pytest.mark.parametrize("damage, match", [
    ("object", "w0"),
    ("missing layer", "missing w2"),
    ("dilation", "dilations"),
    ("channels", "layers w1/b1"),
    ("non-finite", "non-finite"),
])
def test_damaged_network_files_are_refused(tmp_path, damage, match):
    net, _, _ = _small_net(steps=1)
    arrays = {k: v.copy() for k, v in net.weights.items()}
    arrays["dilations"] = np.array(net.dilations)
    arrays["shape"] = np.array(net.shape)
    if damage == "object":
        arrays["w0"] = np.array([object()], dtype=object)
    elif damage == "missing layer":
        del arrays["w2"]
    elif damage == "dilation":
        arrays["dilations"] = np.array([1, 1000])
    elif damage == "channels":
        arrays["w1"] = arrays["w1"][:, :, :4]
    else:
        arrays["b0"][0] = np.nan
    with pytest.raises(CalibrationError, match=match):
        ConvGradient.load(_write(tmp_path / "bad.npz", **arrays))


def test_lut_stores_the_convolutional_network_beside_it(tmp_path):
    net, change, image = _small_net()
    lut = calibrate_lut([change], [change[..., 0]], [change[..., 1]],
                        [np.ones(change.shape[:2], bool)], bins=8)
    lut.meta["mlp_file"] = "stale.mlp.npz"  # from an earlier network: not this one's
    lut.net = net
    p = lut.save(tmp_path / "lut.npz")
    meta = json.loads(p.with_suffix(".json").read_text())
    assert meta["gradient_model"] == "cnn" and meta["cnn_file"] == "lut.cnn.npz"
    assert "mlp_file" not in meta and meta["cnn"]["receptive_field_px"] == 7
    back = PhotometricLUT.load(p)
    assert isinstance(back.net, ConvGradient)
    np.testing.assert_array_equal(back.lookup(change, image)[0], lut.lookup(change, image)[0])
    for hostile in ([1], {"cnn": 1}, None):  # not a name: refused, never a TypeError
        bad = {**meta, "gradient_model": hostile}
        p.with_suffix(".json").write_text(json.dumps(bad))
        with pytest.raises(CalibrationError, match="gradient_model"):
            PhotometricLUT.load(p)
    p.with_suffix(".json").write_text(json.dumps({**meta, "cnn": "not provenance"}))
    assert PhotometricLUT.load(p).net.meta == {}
    p.with_suffix(".json").write_text(json.dumps(meta))
    net_path(p, "cnn").unlink()
    with pytest.raises(CalibrationError, match="lut.cnn.npz"):
        PhotometricLUT.load(p)


def test_context_reads_the_slopes_a_per_pixel_model_cannot():
    """Where the colour saturates with the slope, the per-pixel network reads a ball's
    steep flanks short; the convolutional one reads them from the shading around them."""
    change, image, gx, gy = _presses(10, 1)
    valid = [np.ones(c.shape[:2], bool) for c in change]
    test = _presses(3, 2)
    mlp = train_mlp(change, image, gx, gy, valid, hidden=16, steps=800)
    cnn = train_cnn(change, image, gx, gy, valid, width=16, steps=1000, crop=40)

    def steep_rms(model):
        errs = []
        for c, i, tx, ty in zip(*test, strict=True):
            px, py = model.predict(c, i)
            steep = np.hypot(tx, ty) > 1.0
            errs.append(np.hypot(px - tx, py - ty)[steep])
        return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))

    e_mlp, e_cnn = steep_rms(mlp), steep_rms(cnn)
    # measured: 0.30 against 0.57 where the slope is over 1
    assert e_cnn < 0.7 * e_mlp, (e_cnn, e_mlp)


def test_validation_line_and_cli_choices():
    from thintact_sdk.apps.cli.argtypes import GRADIENT_MODELS as CLI_CHOICES

    assert CLI_CHOICES == GRADIENT_MODELS
    line = describe_validation({"presses": [3], "slope_rms_lut": 0.2, "slope_rms_mlp": 0.19,
                                "slope_rms_cnn": 0.15})
    assert line == "table 0.200, per-pixel network 0.190, convolutional network 0.150"


def test_auto_compares_three_models_and_stores_the_best(tmp_path):
    """``calibrate_from_presses(model="auto")`` fits the table and both networks on three
    quarters of the presses, stores each one's validation slope RMS and keeps the lowest;
    the stored LUT reads back with that model."""
    from thintact_sdk.tactile.calibration.ball_press import BallPress, calibrate_from_presses
    from thintact_sdk.tactile.calibration.press_pack import pack_profile

    change, image, gx, gy = _presses(12, 3)
    profile = pack_profile(change[0].shape[:2], MM)
    lines: list[str] = []
    lut = calibrate_from_presses(profile, np.full_like(image[0], 0.5),
                                 [BallPress(i, x, y) for i, x, y in zip(image, gx, gy, strict=True)],
                                 bins=12, model="auto", mlp_steps=200, cnn_options={"steps": 300},
                                 stage=lines.append)
    val = lut.meta["validation"]
    assert val["presses"] == [3, 7, 11]
    rms = {k: val[f"slope_rms_{k}"] for k in ("lut", "mlp", "cnn")}
    assert lut.meta["gradient_model"] == min(rms, key=lambda k: rms[k])
    assert any("convolutional network, step 300/300" in line for line in lines)
    back = PhotometricLUT.load(lut.save(tmp_path / "lut.npz"))
    assert back.meta["gradient_model"] == lut.meta["gradient_model"]
    assert (back.net is None) == (lut.meta["gradient_model"] == "lut")
    with pytest.raises(CalibrationError, match="cnn"):
        calibrate_from_presses(profile, image[0], [BallPress(image[0], gx[0], gy[0])],
                               model="convnet")


@pytest.mark.parametrize("shape,crop", [((320, 427), 64), ((120, 160), 64), ((40, 30), 64),
                                        ((70, 64), 64)])
def test_crops_count_every_pixel_alike_edges_included(shape, crop):
    """The chance that a training crop covers a pixel, times the pixel's weight, is the same
    everywhere: a pixel on the frame's edge counts as much as one in the middle (crops drawn
    uniformly inside the grid cover the edge ``crop`` times less often)."""
    from thintact_sdk.tactile.interpretation.gradient_model import _crop_plan

    ch, cw = min(crop, shape[0]), min(crop, shape[1])
    rows_from, cols_from, weight = _crop_plan(shape, ch, cw)
    assert rows_from.min() == 0 and rows_from.max() == shape[0] - ch
    assert cols_from.min() == 0 and cols_from.max() == shape[1] - cw
    chance = np.zeros(shape)
    for r0 in np.unique(rows_from):
        for c0 in np.unique(cols_from):
            p = np.mean(rows_from == r0) * np.mean(cols_from == c0)
            chance[r0:r0 + ch, c0:c0 + cw] += p
    np.testing.assert_allclose(chance * weight, ch * cw / (shape[0] * shape[1]), rtol=1e-5)
    # every pixel is covered at least as often as a crop's own share of the origins, the
    # corner included (drawing origins inside the grid covers a corner crop² times less)
    least = float(np.prod([1.0 if c == n else c / (n + c - 1)  # a whole-axis crop covers all
                           for n, c in zip(shape, (ch, cw), strict=True)]))
    assert chance.min() == pytest.approx(least) and chance[0, 0] == pytest.approx(least)


@pytest.mark.parametrize("kind", ["mlp", "cnn"])
def test_a_network_wider_than_any_calibration_makes_is_refused(tmp_path, kind):
    """A file declaring a 300-channel layer would make every frame allocate rows × cols × 300
    floats: refused when the calibration is read, naming the file."""
    from thintact_sdk.tactile.interpretation.gradient_model import MAX_WIDTH, MLPGradient

    wide = MAX_WIDTH + 44
    p = tmp_path / f"{kind}.npz"
    if kind == "mlp":
        np.savez_compressed(p, w0=np.zeros((8, wide), np.float32), b0=np.zeros(wide, np.float32),
                            w1=np.zeros((wide, wide), np.float32), b1=np.zeros(wide, np.float32),
                            w2=np.zeros((wide, 2), np.float32), b2=np.zeros(2, np.float32),
                            shape=np.array([4, 4]))
        loader = MLPGradient.load
    else:
        np.savez_compressed(p, w0=np.zeros((3, 3, 8, wide), np.float32), b0=np.zeros(wide, np.float32),
                            w1=np.zeros((wide, 2), np.float32), b1=np.zeros(2, np.float32),
                            dilations=np.array([1]), shape=np.array([4, 4]))
        loader = ConvGradient.load
    with pytest.raises(CalibrationError, match=rf"{kind}\.npz: a layer of {wide} channels"):
        loader(p)
    # the widest allowed still loads
    if kind == "cnn":
        np.savez_compressed(p, w0=np.zeros((3, 3, 8, MAX_WIDTH), np.float32),
                            b0=np.zeros(MAX_WIDTH, np.float32), w1=np.zeros((MAX_WIDTH, 2), np.float32),
                            b1=np.zeros(2, np.float32), dilations=np.array([1]), shape=np.array([4, 4]))
        assert ConvGradient.load(p).weights["w0"].shape[-1] == MAX_WIDTH
