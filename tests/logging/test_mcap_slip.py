"""The /thintact/slip topic: slip ratio and slipping flag with their schema, read back from the
file, for synthetic frames and for the virtual finger's sheared and pure normal presses."""

from __future__ import annotations

import pytest
from mcap.reader import make_reader
from mcap_testkit import mini_profile, tactile_frame

from thintact_sdk.formats.mcap import McapLog, McapLogWriter
from thintact_sdk.formats.profiles import load_profile
from thintact_sdk.tactile.interpretation.slip import SLIPPING_RATIO


def test_slip_topic_carries_ratio_and_flag_with_its_schema(tmp_path):
    path = tmp_path / "slip.mcap"
    with McapLogWriter(path, mini_profile()) as log:
        for i in range(5):
            log.write_tactile(tactile_frame(i, with_force=i >= 1), count_frame=True)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (schema,) = [s for s in summary.schemas.values() if s.name == "thintact_msgs/msg/Slip"]
    text = schema.data.decode()
    assert "float32 slip_ratio" in text and "bool slipping" in text
    got = [(m.schema, m.message.slip_ratio, m.message.slipping)
           for m in McapLog(path).messages(["/thintact/slip"])]
    ratios = [0.1 * i for i in range(1, 5)]
    assert [g[0] for g in got] == ["thintact_msgs/msg/Slip"] * 4
    assert [g[1] for g in got] == pytest.approx(ratios)
    assert [g[2] for g in got] == [r >= SLIPPING_RATIO for r in ratios] == [False, True, True, True]
    frames = list(McapLog(path).tactile_frames())
    assert frames[0].slip_ratio is None and frames[2].slip_ratio == pytest.approx(0.2)


def test_the_virtual_finger_cycle_logs_slip_on_its_sheared_presses(tmp_path):
    from thintact_virtual.tactile_scenes import CYCLE, cycle_press, tactile_scene

    from thintact_sdk.tactile import TactileInterpreter, TactileSimulator, scene_level_lut

    profile = load_profile("virtual-finger")
    interp = TactileInterpreter(profile, scene_level_lut(profile))
    interp.set_reference(TactileSimulator.for_profile(profile).flat().scene)
    path = tmp_path / "finger.mcap"
    with McapLogWriter(path, profile, attach_calibration=False) as log:
        for k in range(1, CYCLE):
            frame = interp.interpret(tactile_scene(profile, k), 1000 * k, k)
            log.write_tactile(frame, count_frame=True)
    flags = {m.sequence: bool(m.message.slipping)
             for m in McapLog(path).messages(["/thintact/slip"])}
    assert flags == {k: cycle_press(profile, k).sheared for k in range(1, CYCLE)}
