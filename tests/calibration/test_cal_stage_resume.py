"""Issue 36: health and the decoder/τ choice are checkpointed like the solve and the filter: a
run killed in a later stage resumes without recomputing them, with the same figures; the
checkpoint codec restores the objects exactly and refuses any class it does not know."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thintact_sdk.calibration.stages import Checkpoints, decode_object, encode_object
from thintact_sdk.calibration.tau import TauCurve
from thintact_sdk.errors import CalibrationError
from thintact_sdk.reconstruction.scene_prior import ScenePrior
from thintact_sdk.reconstruction.t2s import SystemMatrices


def test_the_codec_restores_nested_objects_and_refuses_other_classes(tmp_path: Path) -> None:
    prior = ScenePrior(1.0, 4.0)
    curve = TauCurve("gcv", [1e-3, 1e-2], [float("nan"), 2.5], 1e-2, "mean PSNR dB", "why")
    obj = {"curves": [(prior, curve)], prior: float("-inf"), "x": np.arange(6.0).reshape(2, 3),
           "t": (1, "a", None, True)}
    cp = Checkpoints(tmp_path, "key")
    cp.save_object("thing", obj)
    back = cp.load_object("thing")
    assert back[prior] == float("-inf") and back["t"] == (1, "a", None, True)
    np.testing.assert_array_equal(back["x"], obj["x"])
    p2, c2 = back["curves"][0]
    assert p2 == prior and c2.taus == curve.taus and np.isnan(c2.values[0]) and c2.values[1] == 2.5
    assert Checkpoints(tmp_path, "other key").load_object("thing") is None
    with pytest.raises(CalibrationError, match="checkpoint"):
        encode_object(Path("/x"), {})
    with pytest.raises(CalibrationError, match="refused"):
        decode_object({"class": "subprocess:Popen", "fields": {"args": "true"}}, {})


def test_a_crash_in_the_prediction_resumes_without_recomputing_health_or_the_choice(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration import pipeline
    from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    opts = CalibrationOptions(filter_steps=0, filter_scenes=8)
    write_slit_recording(tmp_path / "rec", synthetic_profile(), synthetic_matrices(), np.random.default_rng(0),
                         [make_scene("gelsight", 24, 32, 2), make_scene("smooth_color", 24, 32)])
    rec = Recording(tmp_path / "rec")
    whole = calibrate_recording(rec, tmp_path / "whole", opts, report=False)
    real_predict = pipeline.predict_from_design

    def crash(*a, **k):  # type: ignore[no-untyped-def]
        raise RuntimeError("killed in the prediction stage")

    monkeypatch.setattr(pipeline, "predict_from_design", crash)
    with pytest.raises(RuntimeError):
        calibrate_recording(rec, tmp_path / "cal", opts, report=False)
    assert (tmp_path / "cal" / "stages" / "health.npz").is_file()
    assert (tmp_path / "cal" / "stages" / "selection.json").is_file()

    def never(*a, **k):  # type: ignore[no-untyped-def]
        raise AssertionError("recomputed a finished stage")

    monkeypatch.setattr(pipeline, "predict_from_design", real_predict)
    assert (tmp_path / "cal" / "stages" / "design.npz").is_file()
    for name in ("collect_slits", "solve_matrices", "build_bundle", "assess", "select", "noise_curves_of",
                 "design_for_prediction"):
        monkeypatch.setattr(pipeline, name, never)
    again = calibrate_recording(rec, tmp_path / "cal", opts, report=False)
    assert not (tmp_path / "cal" / "stages").exists()
    meta = {d: json.loads((tmp_path / d / "calibration.json").read_text()) for d in ("whole", "cal")}
    stages = {s["stage"]: s for s in meta["cal"]["metrics"]["stages"]}
    assert stages["health"].get("resumed") and stages["decoder and tau"].get("resumed")
    # the prediction's design and the reported noise criteria too (the design with its
    # generator's state: the prediction's validation frames draw what they drew)
    assert stages["prediction design"].get("resumed") and stages["noise criteria"].get("resumed")
    assert "resumed" not in stages["prediction"]
    for key in ("health", "tau_selection", "psnr_db", "judged_psnr_db", "verdict", "predicted_psnr_db"):
        assert meta["cal"]["metrics"][key] == meta["whole"]["metrics"][key], key
    assert meta["cal"]["decoder"] == meta["whole"]["decoder"]
    np.testing.assert_array_equal(again.health.chi2_map, whole.health.chi2_map)
    for v0, v1 in zip(whole.validation, again.validation, strict=True):
        np.testing.assert_array_equal(v0.estimate, v1.estimate)


def test_the_health_forward_over_lit_rows_or_columns_is_the_forward() -> None:
    from thintact_sdk.calibration.health import _forward_lit

    rng = np.random.default_rng(0)
    c, r, s, n, m = 3, 20, 24, 9, 11
    sm = SystemMatrices(*(rng.standard_normal(shape) for shape in ((c, r, n), (c, s, m), (c, r, n), (c, s, m))), {})
    row, col, dense = np.zeros((n, m, c)), np.zeros((n, m, c)), rng.random((n, m, c))
    row[4] = 0.8
    col[:, 7, 1] = 0.5
    for x in (row, col, dense, np.zeros((n, m, c))):
        want = sm.forward(x)
        got = np.moveaxis(_forward_lit(sm, x), 0, 2)  # channel first (C × R × S)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * max(1.0, np.abs(want).max()))


def test_health_and_selection_run_side_by_side_and_the_noise_first_changes_nothing(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The calibration's two lanes: health (its noise measured first) beside the filter and τ
    selection. Health from the noise measured first equals health in one go, and the stages
    of the two lanes overlap in time."""
    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration.collect import collect_slits
    from thintact_sdk.calibration.health import assess, measure_noise
    from thintact_sdk.calibration.pipeline import (
        CalibrationOptions,
        calibrate_recording,
        solve_matrices,
    )
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    profile = synthetic_profile()
    write_slit_recording(tmp_path / "rec", profile, synthetic_matrices(), np.random.default_rng(1),
                         [make_scene("gelsight", 24, 32, 2), make_scene("smooth_color", 24, 32)])
    rec = Recording(tmp_path / "rec")
    collection = collect_slits(rec)
    sm, _ = solve_matrices(collection, CalibrationOptions(), rec.profile)
    whole = assess(rec, collection, sm, 1)
    noise = measure_noise(rec, collection, sm, 1)
    split = assess(rec, collection, sm, 1, noise=noise)
    assert noise == whole.noise
    np.testing.assert_array_equal(split.chi2_map, whole.chi2_map)
    assert split.slit_chi2 == whole.slit_chi2 and split.defects == whole.defects

    out = calibrate_recording(rec, tmp_path / "cal", CalibrationOptions(filter_steps=0, filter_scenes=8),
                              report=False)
    stages = {s["stage"]: s for s in out.bundle.meta["metrics"]["stages"]}
    health, filt = stages["health"], stages["joint filter"]
    assert health["start_s"] < filt["start_s"] + filt["seconds"]
    assert filt["start_s"] < health["start_s"] + health["seconds"]
    assert {"prediction design", "prediction"} <= set(stages)


def test_slits_compressed_as_they_arrive_equal_the_collection_of_the_finished_recording(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The wizard's streaming collection (:class:`SlitCompressor`): frames taken as the
    recording grows give exactly what :func:`collect_slits` gives on the finished recording;
    a recording that breaks what streaming assumes is collected again."""
    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration.collect import SlitCompressor, collect_slits
    from thintact_sdk.calibration.pipeline import CalibrationOptions, solve_matrices
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    profile = synthetic_profile()
    write_slit_recording(tmp_path / "rec", profile, synthetic_matrices(), np.random.default_rng(2),
                         [make_scene("gelsight", 24, 32, 2)])
    full = Recording(tmp_path / "rec")
    streamed = SlitCompressor(full.profile)
    for i in range(len(full)):  # a fresh view per frame, as the wizard's worker opens them
        streamed.add(Recording(tmp_path / "rec"), i)
    assert streamed.broken is None
    got = streamed.finish(full)
    want = collect_slits(full)
    assert got.validation == want.validation and got.slit_frames == want.slit_frames
    np.testing.assert_array_equal(got.dark_dn, want.dark_dn)
    a, _ = solve_matrices(got, CalibrationOptions(), full.profile)
    b, _ = solve_matrices(want, CalibrationOptions(), full.profile)
    for name in ("Po", "Qo", "Pc", "Qc"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # released once its collection is made (the wizard's worker, issue 36's memory): the
    # compressed images go; a later collection is taken from the recording, never half-made
    streamed.release()
    assert streamed.acc is None and streamed.broken is not None
    with pytest.raises(CalibrationError):
        streamed.slit_collection()
    np.testing.assert_array_equal(streamed.finish(full).dark_dn, want.dark_dn)
    # a slit before the dark frame breaks the streaming assumption: collected again
    late = SlitCompressor(full.profile)
    slit = next(i for i in range(len(full)) if i not in want.validation and full.scene(i).any())
    late.add(full, slit)
    for i in range(len(full)):
        late.add(full, i)
    assert late.broken is not None
    again = late.finish(full)
    np.testing.assert_array_equal(again.dark_dn, want.dark_dn)


def test_slits_compressed_on_two_threads_equal_one_thread_and_name_the_first_dead_frame(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """:func:`collect_slits` compresses frames on ``COLLECT_WORKERS`` threads and adds them in
    order (issue 36): the collection one thread makes, and the first dead slit in the
    recording's order is the one a refusal names, wherever the threads were."""
    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration import collect
    from thintact_sdk.calibration.collect import collect_slits
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    write_slit_recording(tmp_path / "rec", synthetic_profile(), synthetic_matrices(), np.random.default_rng(3),
                         [make_scene("gelsight", 24, 32, 2)])
    rec = Recording(tmp_path / "rec")
    seen: list[str] = []
    two = collect_slits(rec, progress=lambda done, total, what: seen.append(what))
    monkeypatch.setattr(collect, "COLLECT_WORKERS", 1)
    one = collect_slits(Recording(tmp_path / "rec"))
    assert len(seen) == two.slit_frames == one.slit_frames
    assert seen == sorted(seen, key=lambda w: [fr.label for fr in rec.frames].index(w))  # in order
    for a, b in zip(two.channels, one.channels, strict=True):
        for sa, sb in ((a.horizontal, b.horizontal), (a.vertical, b.vertical)):
            np.testing.assert_array_equal(sa.index, sb.index)
            np.testing.assert_array_equal(sa.left, sb.left)
            np.testing.assert_array_equal(sa.right, sb.right)
    # two dead slits: the first in the recording's order is named
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    slits = [i for i in range(len(rec)) if i not in one.validation and rec.scene(i).any()]
    for i in (slits[5], slits[2]):
        path = tmp_path / "rec" / manifest["frames"][i]["measurement"]
        np.save(path, np.zeros_like(np.load(path)))
    monkeypatch.setattr(collect, "COLLECT_WORKERS", 2)
    with pytest.raises(CalibrationError, match=f"slit frame {slits[2]} "):
        collect_slits(Recording(tmp_path / "rec"))



def test_the_noise_criteria_take_the_decoder_the_choice_built(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The reported GCV and discrepancy curves reuse the plain decoder the τ choice built
    (issue 36: building it again took about 6 s at the paper's size, after the choice) and
    come out as from a decoder built afresh."""
    import copy

    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration import selection as selection_module
    from thintact_sdk.calibration.collect import collect_slits
    from thintact_sdk.calibration.health import measure_noise
    from thintact_sdk.calibration.pipeline import CalibrationOptions, build_bundle, solve_matrices
    from thintact_sdk.calibration.selection import (
        add_noise_curves,
        has_noise_curves,
        select,
        validation_frames,
    )
    from thintact_sdk.calibration.validation import calibration_decoders
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    profile = synthetic_profile()
    # four distinct scenes (smooth_color has no index): two folds, so cross-validation chooses
    # and the curves are left to add_noise_curves
    scenes = [make_scene(k, 24, 32, s) for k, s in (("gelsight", 2), ("smooth_color", 1), ("gelsight", 5),
                                                     ("checker", 0))]
    write_slit_recording(tmp_path / "rec", profile, synthetic_matrices(), np.random.default_rng(3), scenes)
    rec = Recording(tmp_path / "rec")
    collection = collect_slits(rec)
    opts = CalibrationOptions(filter_steps=0, filter_scenes=8)
    sm, _ = solve_matrices(collection, opts, rec.profile)
    bundle, _ = build_bundle(rec.profile, sm, opts, 1, "recording", collection.exposure_us)
    frames = validation_frames(rec, collection, rec.profile.noise.saturation_dn)
    noise = measure_noise(rec, collection, sm, 1)
    built: dict[str, object] = {}
    chosen = select(rec.profile, bundle, frames, noise, noise_criteria_curves=False, built=built)
    assert set(built) == set(calibration_decoders())
    assert chosen.criterion == "cross-validation" and not has_noise_curves(chosen)
    afresh = copy.deepcopy(chosen)
    add_noise_curves(rec.profile, bundle, frames, noise, afresh)

    def no_build(*a, **k):  # type: ignore[no-untyped-def]
        raise AssertionError("the chosen decoder was built again")

    monkeypatch.setattr(selection_module, "make_decoder", no_build)
    add_noise_curves(rec.profile, bundle, frames, noise, chosen, decoder=built[chosen.decoder])
    got = {c.criterion: c for c in chosen.curves if c.criterion in ("gcv", "discrepancy")}
    want = {c.criterion: c for c in afresh.curves if c.criterion in ("gcv", "discrepancy")}
    assert set(got) == set(want) == {"gcv", "discrepancy"}
    for name, curve in want.items():
        np.testing.assert_allclose(got[name].values, curve.values, rtol=1e-6)



def test_the_noise_criteria_and_the_prediction_start_once_the_decoder_is_certain(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # the scene priors only replace plain Tikhonov by scoring higher: once plain t2s leads,
    # the decoder's name is certain and the work that needs only the name starts beside the
    # priors (issue 36); the bundle is the one a run without the early start writes
    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration import pipeline
    from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    scenes = [make_scene(k, 24, 32, s) for k, s in (("gelsight", 2), ("smooth_color", 1), ("gelsight", 5),
                                                     ("checker", 0))]
    write_slit_recording(tmp_path / "rec", synthetic_profile(), synthetic_matrices(), np.random.default_rng(3),
                         scenes)
    rec = Recording(tmp_path / "rec")
    # the decoder imposed (its τ and scene prior still chosen): certain after plain Tikhonov
    opts = CalibrationOptions(filter_steps=0, filter_scenes=8, decoder="t2s-closed-form")
    events: list[tuple[str, str]] = []
    real_select, real_curves, real_predict = pipeline.select, pipeline.noise_curves_of, pipeline.predict_from_design

    def spy_select(*a, on_decoder=None, **k):  # type: ignore[no-untyped-def]
        def told(name: str) -> None:
            events.append(("told", name))
            on_decoder(name)

        out = real_select(*a, on_decoder=None if on_decoder is None else told, **k)
        events.append(("chosen", out.decoder))
        return out

    def spy_curves(profile, bundle, frames, noise, name, decoder=None):  # type: ignore[no-untyped-def]
        events.append(("noise criteria", name))
        assert decoder is not None  # the plain decoder the choice built
        return real_curves(profile, bundle, frames, noise, name, decoder)

    def spy_predict(profile, design, labels, truths, name, **k):  # type: ignore[no-untyped-def]
        events.append(("prediction", name))
        return real_predict(profile, design, labels, truths, name, **k)

    monkeypatch.setattr(pipeline, "select", spy_select)
    monkeypatch.setattr(pipeline, "noise_curves_of", spy_curves)
    monkeypatch.setattr(pipeline, "predict_from_design", spy_predict)
    calibrate_recording(rec, tmp_path / "early", opts, report=False)
    told = [e for e in events if e[0] == "told"]
    chosen = [e for e in events if e[0] == "chosen"]
    assert told and chosen and told[0][1] == chosen[0][1] == "t2s-closed-form"
    assert events.index(told[0]) < events.index(chosen[0])  # told while the priors still ran
    assert {e for e in events if e[0] in ("noise criteria", "prediction")} == {
        ("noise criteria", "t2s-closed-form"), ("prediction", "t2s-closed-form")}

    events.clear()
    monkeypatch.setattr(pipeline, "select", lambda *a, on_decoder=None, **k: spy_select(*a, **k))
    calibrate_recording(rec, tmp_path / "late", opts, report=False)
    assert not [e for e in events if e[0] == "told"]
    meta = {d: json.loads((tmp_path / d / "calibration.json").read_text()) for d in ("early", "late")}
    for key in ("tau_selection", "psnr_db", "judged_psnr_db", "verdict", "predicted_psnr_db"):
        assert meta["early"]["metrics"][key] == meta["late"]["metrics"][key], key


def test_the_filter_free_decoders_are_chosen_while_the_joint_filter_trains(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # the T2S closed form needs no joint filter: its cross-validation runs while the filter
    # trains, and the bundle is the one a run that trains the filter first writes (issue 36)
    import threading

    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration import pipeline, selection
    from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    scenes = [make_scene(k, 24, 32, s) for k, s in (("gelsight", 2), ("smooth_color", 1), ("gelsight", 5),
                                                     ("checker", 0))]
    write_slit_recording(tmp_path / "rec", synthetic_profile(), synthetic_matrices(), np.random.default_rng(3),
                         scenes)
    rec = Recording(tmp_path / "rec")
    opts = CalibrationOptions(filter_steps=0, filter_scenes=8)
    t2s_done = threading.Event()
    seen: dict[str, bool] = {}
    real_build, real_cv, real_select = pipeline.build_bundle, selection.cross_validate, pipeline.select

    def spy_cv(decoder, name, *a, **k):  # type: ignore[no-untyped-def]
        out = real_cv(decoder, name, *a, **k)
        if name == "t2s-closed-form":
            t2s_done.set()
        return out

    def slow_build(*a, **k):  # type: ignore[no-untyped-def]
        # a run that trains the filter before choosing never sets the event: 20 s lost, and the test fails
        seen["t2s cross-validated before the filter was trained"] = t2s_done.wait(20.0)
        return real_build(*a, **k)

    monkeypatch.setattr(selection, "cross_validate", spy_cv)
    monkeypatch.setattr(pipeline, "build_bundle", slow_build)
    calibrate_recording(rec, tmp_path / "beside", opts, report=False)
    assert seen == {"t2s cross-validated before the filter was trained": True}

    def filter_first(profile, bundle, *a, filtered=None, **k):  # type: ignore[no-untyped-def]
        return real_select(profile, filtered(), *a, **k)  # every decoder on the full bundle

    monkeypatch.setattr(pipeline, "build_bundle", real_build)
    monkeypatch.setattr(pipeline, "select", filter_first)
    calibrate_recording(rec, tmp_path / "first", opts, report=False)
    meta = {d: json.loads((tmp_path / d / "calibration.json").read_text()) for d in ("beside", "first")}
    assert meta["beside"]["decoder"] == meta["first"]["decoder"]
    for key in ("tau_selection", "psnr_db", "judged_psnr_db", "verdict", "predicted_psnr_db"):
        assert meta["beside"]["metrics"][key] == meta["first"]["metrics"][key], key


def test_the_capture_measures_every_calibration_decoders_backend(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """During the capture the backends of every calibration decoder are measured on the
    design's matrices, the joint-filter decoder's too on a filter trained on them (issue 36:
    measuring it after the last pattern took about 20 s at the paper's size, before the τ
    choice could start); the unit's own decoders are then built from the cache."""
    import json

    from cal_testkit import synthetic_matrices, synthetic_profile

    from thintact_sdk.calibration.capture_worker import warm_backends
    from thintact_sdk.calibration.validation import calibration_decoders
    from thintact_sdk.reconstruction.decoders import backend_selection

    monkeypatch.setenv("THINTACT_CACHE_DIR", str(tmp_path))
    warm_backends(synthetic_profile(), synthetic_matrices())
    measured = json.loads((tmp_path / "decoder-backends.json").read_text())
    names = {key.split("|")[1] for key in measured}
    assert names == set(calibration_decoders()) and "thintact-noniterative" in names
    assert all("|blas 1," in key for key in measured)  # the calibration lanes' one BLAS thread
    # a later build of the same shapes takes the cached choice: nothing is measured again
    monkeypatch.setattr(backend_selection, "measure_backends", lambda *a, **k: (_ for _ in ()).throw(
        AssertionError("measured again")))
    warm_backends(synthetic_profile(), synthetic_matrices(seed=4))


def test_a_resume_after_the_capture_narrows_the_prior_search_as_the_first_run_did(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # the priors the capture worker chose on the design are checkpointed: a wizard run killed
    # after the capture resumes without the worker and still cross-validates plain Tikhonov
    # and the design's prior alone; a run without that checkpoint searches every prior
    from cal_testkit import synthetic_matrices, synthetic_profile, write_slit_recording

    from thintact_sdk.calibration import pipeline
    from thintact_sdk.calibration.capture_worker import Prepared
    from thintact_sdk.calibration.pipeline import CalibrationOptions, calibrate_recording
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.simulation.scenes import make_scene

    opts = CalibrationOptions(filter_steps=0, filter_scenes=8)
    write_slit_recording(tmp_path / "rec", synthetic_profile(), synthetic_matrices(), np.random.default_rng(0),
                         [make_scene("gelsight", 24, 32, 2), make_scene("smooth_color", 24, 32)])
    rec = Recording(tmp_path / "rec")
    prepared = Prepared(priors={"t2s-closed-form": ScenePrior(1.5, 3.0), "t2s-other": None})
    seen: list[object] = []

    def killed(*a, design_priors=None, **k):  # type: ignore[no-untyped-def]
        seen.append(design_priors)
        raise RuntimeError("killed while choosing the decoder")

    monkeypatch.setattr(pipeline, "select", killed)
    with pytest.raises(RuntimeError):
        calibrate_recording(rec, tmp_path / "cal", opts, report=False, prepared=prepared)
    assert (tmp_path / "cal" / "stages" / "design_priors.json").is_file()
    with pytest.raises(RuntimeError):
        calibrate_recording(rec, tmp_path / "cal", opts, report=False)  # resumed: no worker
    with pytest.raises(RuntimeError):
        calibrate_recording(rec, tmp_path / "fresh", opts, report=False)
    assert seen == [prepared.priors, prepared.priors, None]
