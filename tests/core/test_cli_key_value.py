"""The CLI's one KEY=VALUE parser (``--set``, ``--camera-set``): values read as YAML, errors at
parse time with exit status 2."""

from __future__ import annotations

import argparse

import pytest

from thintact_sdk.apps.cli.argtypes import key_value, key_values
from thintact_sdk.apps.cli.main import main


@pytest.mark.parametrize(("text", "expected"), [
    ("fps=0", ("fps", 0)),
    ("exposure_us=2.5e3", ("exposure_us", 2500.0)),
    ("noise=false", ("noise", False)),
    ("roi=[0, 0, 640, 480]", ("roi", [0, 0, 640, 480])),
    ('pixel_format="BayerRG12"', ("pixel_format", "BayerRG12")),
    ("pixel_format=BayerRG12", ("pixel_format", "BayerRG12")),
    ("serial='007'", ("serial", "007")),
    ("serial=007", ("serial", 7)),
    ("mode=on", ("mode", "on")),
    ("flag=yes", ("flag", "yes")),
    ("x=-1.5E-2", ("x", -0.015)),
    ("mask=0x10", ("mask", 16)),
    ("path=a=b=c", ("path", "a=b=c")),
    ("name=", ("name", "")),
    (" fps =30", ("fps", 30)),
    ("gain=null", ("gain", None)),
    ('opts={"a": 1}', ("opts", {"a": 1})),
])
def test_key_value_reads_yaml_values(text: str, expected: tuple[str, object]) -> None:
    assert key_value(text) == expected


@pytest.mark.parametrize("text", ["fps", "=3", "two words=1", "roi=[0, 1", "x=.nan", "x=-.inf"])
def test_key_value_refuses_malformed_input(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        key_value(text)


def test_key_values_last_wins() -> None:
    assert key_values([("fps", 1), ("gain", 2), ("fps", 3)]) == {"fps": 3, "gain": 2}
    assert key_values(None) == {}


@pytest.mark.parametrize("argv", [
    ["record", "--profile", "virtual-mini", "--frames", "1", "--out", "OUT", "--set", "fps"],
    ["calibrate", "--profile", "virtual-mini", "--camera-set", "roi=[1,"],
    ["view", "virtual-mini", "--set", "=1"],
])
def test_bad_key_value_exits_2_before_any_work(argv: list[str], tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err
    assert "KEY=VALUE" in err or "YAML" in err
    assert not (tmp_path / "OUT").exists()
