"""The one safe YAML loader (issue 30): alias bombs, duplicate keys and non-core tags are
refused naming the line, in profile files (YAML and JSON), ``--set KEY=VALUE`` options and
``thintact profile validate/show`` / ``record --profile``; every refusal is one line."""

from __future__ import annotations

import argparse
import json
import re
import tracemalloc
from pathlib import Path

import pytest
import yaml

from thintact_sdk.apps.cli.argtypes import key_value
from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import ProfileError
from thintact_sdk.formats import safe_yaml as yaml_safe
from thintact_sdk.formats.profiles import SHIPPED_PROFILE_DIR, load_profile

MINI_TEXT = (SHIPPED_PROFILE_DIR / "virtual-mini.yaml").read_text()


def laughs(levels: int = 9, fanout: int = 10, flow: bool = False) -> str:
    """A "billion laughs" document: ``levels`` anchors, each aliasing the previous ``fanout``
    times (``fanout**levels`` leaves once expanded); block style, or one flow mapping."""
    names = [f"l{i}" for i in range(levels)]
    items = [f"{names[0]}: &{names[0]} [" + ", ".join(["lol"] * fanout) + "]"]
    items += [f"{names[i]}: &{names[i]} [" + ", ".join([f"*{names[i - 1]}"] * fanout) + "]"
              for i in range(1, levels)]
    return "{" + ", ".join(items) + "}" if flow else "\n".join(items) + "\n"


def _one_line(err: str) -> str:
    assert err.endswith("\n") and err.count("\n") == 1, repr(err)
    assert "Traceback" not in err
    return err


def _limit_line(levels: int = 9, fanout: int = 10) -> int:
    """The line of the alias whose expansion crosses MAX_EXPANDED_NODES in :func:`laughs`."""
    total, size = 0, 0
    for i in range(levels):
        size = 1 + (fanout if i == 0 else fanout * size)
        if total + size > yaml_safe.MAX_EXPANDED_NODES:
            return i + 1  # crossed inside anchor line i + 1 (1-based)
        total += size + 1  # the value and its key
    raise AssertionError("never crosses the limit")


# -- the loader itself ---------------------------------------------------------------


def test_billion_laughs_refused_naming_the_line_without_allocating() -> None:
    tracemalloc.start()
    try:
        with pytest.raises(yaml.YAMLError) as err:
            yaml_safe.load(laughs())
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    line = yaml_safe.error_line(err.value)
    assert f"on line {_limit_line()} makes the document larger than 1000000 nodes" in line, line
    assert peak < 20 * 2**20, peak  # a few thousand nodes composed, not a billion


def test_documents_below_the_limit_still_load_with_aliases() -> None:
    doc = yaml_safe.load(laughs(levels=3, fanout=3))
    assert doc["l2"] == [[["lol"] * 3] * 3] * 3


def test_recursive_alias_refused() -> None:
    with pytest.raises(yaml.YAMLError) as err:
        yaml_safe.load("a: &x\n  - 1\n  - *x\n")
    assert yaml_safe.error_line(err.value) == (
        "alias *x on line 3 lies inside its own anchor &x (line 1): recursive documents are refused")


@pytest.mark.parametrize(("text", "expected"), [
    ("sensor:\n  rows: 1\n  cols: 2\n  rows: 3\n", "duplicate key 'rows' on line 4 (first on line 2)"),
    ("a: 1\nb: 2\na: 3\n", "duplicate key 'a' on line 3 (first on line 1)"),
    ("{a: 1, b: 2, a: 3}\n", "duplicate key 'a' on line 1, column 14 (first on column 2)"),
    ("1: a\n1.0: b\n", "duplicate key 1.0 on line 2 (first on line 1)"),
])
def test_duplicate_keys_refused_naming_both_lines(text: str, expected: str) -> None:
    with pytest.raises(yaml.YAMLError) as err:
        yaml_safe.load(text)
    assert yaml_safe.error_line(err.value) == expected


@pytest.mark.parametrize(("text", "tag"), [
    ("x: !!python/object/apply:os.system ['touch /tmp/thintact-pwned']\n", "!!python/object/apply:os.system"),
    ("x: !!binary aGk=\n", "!!binary"),
    ("x: !!set {a: null}\n", "!!set"),
    ("x: !!timestamp 2024-01-01\n", "!!timestamp"),
    ("x: !local 1\n", "!local"),
])
def test_tags_outside_the_core_schema_refused(text: str, tag: str) -> None:
    with pytest.raises(yaml.YAMLError) as err:
        yaml_safe.load(text)
    assert yaml_safe.error_line(err.value).startswith(f"tag {tag} on line 1 is not allowed"), err.value
    assert not Path("/tmp/thintact-pwned").exists()


def test_core_values_and_dates_as_text() -> None:
    assert yaml_safe.load("a: !!str 1\nb: 2024-01-01\nc: [1, 2.5, true, null]\n") == {
        "a": "1", "b": "2024-01-01", "c": [1, 2.5, True, None]}
    with pytest.raises(yaml.YAMLError, match="merge key '<<' on line 2"):
        yaml_safe.load("base: &b {k: 1}\nd: {<<: *b}\n")


def test_json_duplicate_keys_refused_naming_both_lines() -> None:
    assert yaml_safe.load_json('{"a": 1, "b": {"a": 2}}') == {"a": 1, "b": {"a": 2}}
    with pytest.raises(yaml_safe.DuplicateKeyError, match=r"^duplicate key 'c' on line 3 \(first on line 2\)$"):
        yaml_safe.load_json('{"a": 1,\n "b": {"c": 1,\n  "c": 2}}')


# -- profiles ------------------------------------------------------------------------


def _bomb_profile(tmp_path: Path) -> tuple[Path, int]:
    f = tmp_path / "bomb.yaml"
    head = MINI_TEXT.rstrip("\n") + "\n"
    f.write_text(head + laughs())
    return f, head.count("\n") + _limit_line()


def test_bomb_profile_refused_by_load_profile(tmp_path: Path) -> None:
    f, line = _bomb_profile(tmp_path)
    with pytest.raises(ProfileError) as err:
        load_profile(f)
    msg = str(err.value)
    assert msg.startswith(f"cannot parse profile {f}: alias *l") and f"on line {line} " in msg, msg
    assert "\n" not in msg


@pytest.mark.parametrize("command", [["profile", "validate"], ["profile", "show"]])
def test_bomb_profile_refused_by_the_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         command: list[str]) -> None:
    f, line = _bomb_profile(tmp_path)
    assert main([*command, str(f)]) == 2
    out = capsys.readouterr()
    err = _one_line(out.err)
    assert str(f) in err and f"on line {line} " in err and "1000000 nodes" in err, err
    assert out.out == ""


def test_bomb_profile_refused_by_record(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f, line = _bomb_profile(tmp_path)
    out = tmp_path / "rec"
    assert main(["record", "--profile", str(f), "--frames", "1", "--out", str(out)]) == 2
    err = _one_line(capsys.readouterr().err)
    assert f"on line {line} " in err, err
    assert not out.exists()


def test_bomb_in_a_json_profile_is_not_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "bomb.json"
    f.write_text(laughs(flow=True))
    assert main(["profile", "validate", str(f)]) == 2
    err = _one_line(capsys.readouterr().err)
    assert f"cannot parse profile {f}: Expecting" in err, err


def test_duplicate_keys_in_profiles_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    y = tmp_path / "dup.yaml"
    y.write_text(MINI_TEXT.replace("name: virtual-mini\n", "name: virtual-mini\nname: other\n"))
    assert main(["profile", "validate", str(y)]) == 2
    err = _one_line(capsys.readouterr().err)
    assert "duplicate key 'name' on line 4 (first on line 3)" in err and str(y) in err, err

    d = yaml.safe_load(MINI_TEXT)
    text = json.dumps(d, indent=1)
    j = tmp_path / "dup.json"
    j.write_text(text.replace('"rows": 128,', '"rows": 128,\n  "rows": 256,'))
    first = text.splitlines().index('  "rows": 128,') + 1
    assert main(["profile", "validate", str(j)]) == 2
    err = _one_line(capsys.readouterr().err)
    assert f"duplicate key 'rows' on line {first + 1} (first on line {first})" in err, err


def test_oversized_profile_file_refused_before_reading(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import thintact_sdk.formats.profiles as prof

    f = tmp_path / "big.yaml"
    f.write_text(MINI_TEXT)
    monkeypatch.setattr(prof, "MAX_PROFILE_BYTES", 100)
    with pytest.raises(ProfileError, match=r"big\.yaml: \d+ bytes, over the 100 bytes a profile may hold"):
        load_profile(f)


# -- KEY=VALUE options ---------------------------------------------------------------


def test_key_value_bomb_refused_naming_the_line() -> None:
    with pytest.raises(argparse.ArgumentTypeError) as err:
        key_value("scenes=" + laughs(flow=True))
    msg = str(err.value)
    assert msg.startswith("scenes: value '{l0: &l0 [lol") and "on line 1 makes the document larger" in msg, msg
    assert "\n" not in msg


@pytest.mark.parametrize(("text", "expected"), [
    ("opts={a: 1, a: 2}", "duplicate key 'a' on line 1, column 8 (first on column 2)"),
    ("opts=!!python/name:os.system", "tag !!python/name:os.system on line 1 is not allowed"),
])
def test_key_value_duplicate_keys_and_tags_refused(text: str, expected: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=re.escape(expected)):
        key_value(text)


def test_cli_set_bomb_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "rec"
    rc = main(["record", "--profile", "virtual-mini", "--frames", "1", "--out", str(out),
               "--set", "scenes=" + laughs(flow=True)])
    assert rc == 2
    err = _one_line(capsys.readouterr().err)
    assert "argument --set" in err and "makes the document larger than 1000000 nodes" in err, err
    assert not out.exists()


def test_dump_json_writes_what_strict_readers_take():
    """Figures that could not be measured are null, not NaN (which strict JSON readers
    refuse); numpy numbers and arrays are plain numbers and lists."""
    import numpy as np

    from thintact_sdk.formats.safe_yaml import dump_json

    text = dump_json({"a": float("nan"), "b": [np.float32(1.5), float("inf")],
                      "c": np.arange(3), "d": (np.int64(2), -float("inf")), "e": "x"})

    def refuse(token: str) -> None:
        raise AssertionError(f"non-standard JSON constant {token}")

    assert json.loads(text, parse_constant=refuse) == {
        "a": None, "b": [1.5, None], "c": [0, 1, 2], "d": [2, None], "e": "x"}
    with pytest.raises(TypeError):
        dump_json({"f": object()})
