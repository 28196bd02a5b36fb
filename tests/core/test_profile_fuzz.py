"""Property-based fuzzing of profiles (issue 18): dict mutations, YAML/JSON text mutations,
and ``thintact profile validate`` / ``show`` through the CLI entry point in-process.

Invariant: a bad input gets one ProfileError (exit 2) naming the file or the field; a valid
input validates with finite numbers; nothing else ever happens. Outcomes are counted and
the last test checks (and prints) the counts.
"""

from __future__ import annotations

import copy
import json
import math
from collections import Counter
from datetime import timedelta
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from thintact_sdk.apps.cli.main import main
from thintact_sdk.errors import ProfileError
from thintact_sdk.formats.profiles import SHIPPED_PROFILE_DIR, Profile, profile_from_dict

settings.register_profile(
    "thintact-fuzz",
    max_examples=150,
    deadline=timedelta(seconds=10),
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
FUZZ = settings.get_profile("thintact-fuzz")

OUTCOMES: Counter[str] = Counter()
"""``clean_error`` / ``valid`` / ``other`` over every fuzzed input of this module."""

BASE: dict[str, Any] = yaml.safe_load((SHIPPED_PROFILE_DIR / "virtual-mini.yaml").read_text())
BASE["light"] = {"plugin": "serial-led", "port": "/dev/null", "intensities": [0.5, 0.5]}
BASE["physics"] = {"sensor_gamma": {}}


def _leaf_paths(d: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix] if prefix else []
    if isinstance(d, dict):
        for k, v in d.items():
            out += _leaf_paths(v, (*prefix, k))
    elif isinstance(d, list) and d and not isinstance(d[0], int):
        for i, v in enumerate(d[:3]):
            out += _leaf_paths(v, (*prefix, i))
    return out


PATHS = _leaf_paths(BASE) + [("physics", "diffraction"), ("physics", "nonsense"), ("camera", "extra")]

hostile = st.one_of(
    st.none(), st.booleans(),
    st.integers(min_value=-(10**40), max_value=10**40),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
    st.sampled_from(["../x", "/etc/passwd", "a/b", "", "R", "virtual", "acme:virtual", "1e999"]),
    st.lists(st.one_of(st.integers(-3, 3), st.floats(), st.text(max_size=3)), max_size=5),
    st.dictionaries(st.text(max_size=8), st.one_of(st.integers(), st.floats(), st.text(max_size=4)),
                    max_size=3),
)


def _set(d: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    d = copy.deepcopy(d)
    cur: Any = d
    for k in path:
        if isinstance(cur, dict) or (isinstance(cur, list) and isinstance(k, int) and k < len(cur)):
            if k is path[-1]:
                cur[k] = value
            elif k in cur if isinstance(cur, dict) else True:
                cur = cur[k]
            else:
                return d  # an earlier mutation removed this branch
        else:
            return d
    return d


def _all_finite(x: Any) -> bool:
    if isinstance(x, float):
        return math.isfinite(x)
    if isinstance(x, dict):
        return all(_all_finite(v) for v in x.values())
    if isinstance(x, (list, tuple)):
        return all(_all_finite(v) for v in x)
    return True


def _check_valid(prof: Profile) -> None:
    d = prof.contract_dict()
    assert _all_finite({k: d[k] for k in ("sensor", "scene", "mask", "geometry", "noise")})
    assert math.isfinite(prof.geometry.total_mm) and prof.mask.K >= 1
    assert len(prof.content_hash()) == 64


@FUZZ
@given(mutations=st.lists(st.tuples(st.sampled_from(PATHS), hostile), min_size=1, max_size=3))
def test_dict_mutations_validate_or_fail_cleanly(mutations: list[tuple[tuple[Any, ...], Any]]) -> None:
    d = BASE
    for path, value in mutations:
        d = _set(d, path, value)
    try:
        prof = profile_from_dict(d, where="fuzz.yaml")
    except ProfileError as err:
        msg = str(err)
        assert "fuzz.yaml" in msg and msg.count("\n") < 40, msg
        OUTCOMES["clean_error"] += 1
        return
    except Exception:
        OUTCOMES["other"] += 1
        raise
    _check_valid(prof)
    OUTCOMES["valid"] += 1


def _mutate_text(text: str, edits: list[tuple[int, int, str]]) -> str:
    for pos, cut, insert in edits:
        p = pos % (len(text) + 1)
        text = text[:p] + insert + text[p + cut:]
    return text


@FUZZ
@given(
    fmt=st.sampled_from(["yaml", "json"]),
    edits=st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 40),
                             st.text(alphabet=st.characters(), max_size=12)), max_size=4),
    raw_tail=st.one_of(st.just(b""), st.just(b""), st.just(b""), st.binary(max_size=8)),
    command=st.sampled_from(["validate", "show", "validate --strict"]),
)
def test_cli_validate_and_show_on_mutated_files(tmp_path_factory: pytest.TempPathFactory, fmt: str,
                                                edits: list[tuple[int, int, str]], raw_tail: bytes,
                                                command: str) -> None:
    text = json.dumps(BASE, indent=1) if fmt == "json" else yaml.safe_dump(BASE, sort_keys=False)
    data = _mutate_text(text, edits).encode("utf-8", "surrogatepass") + raw_tail
    f = tmp_path_factory.mktemp("fuzz") / f"p.{fmt}"
    f.write_bytes(data)
    argv = ["profile", *command.split(), str(f)]
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse only: never for a file's content
        OUTCOMES["other"] += 1
        raise AssertionError(f"argparse exit {exc.code} for {argv}") from None
    except Exception:
        OUTCOMES["other"] += 1
        raise
    if rc == 0:
        OUTCOMES["valid"] += 1
        prof = profile_from_dict(
            json.loads(data) if fmt == "json" else yaml.safe_load(data.decode("utf-8")))
        _check_valid(prof)
    elif rc == 2:
        OUTCOMES["clean_error"] += 1
    else:
        OUTCOMES["other"] += 1
        raise AssertionError(f"exit {rc} for {argv}")


def test_cli_errors_name_the_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "broken.yaml"
    f.write_bytes(yaml.safe_dump(BASE).encode()[:-40] + b"\xff: [")
    assert main(["profile", "validate", str(f)]) == 2
    assert str(f) in capsys.readouterr().err
    OUTCOMES["clean_error"] += 1


YAML_FUZZ = settings(max_examples=40, deadline=None, database=None,
                     suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
YAML_LIMIT = 600
"""The alias-expansion limit during the YAML structure fuzz, lowered so that the fuzz reaches
it (the base profile alone is about 230 nodes)."""
SCALARS = ["1", "-3", "0.5", "1e400", ".nan", "x", "''", "null", "true", "R", "virtual", "!!str 7"]
KEYS = ["rows", "cols", "a", "b", "plugin", "1", "rows"]


def _flow(leaf: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
    return st.recursive(
        leaf,
        lambda ch: st.one_of(
            st.lists(ch, max_size=6).map(lambda xs: "[" + ", ".join(xs) + "]"),
            st.lists(st.tuples(st.sampled_from(KEYS), ch), max_size=4).map(
                lambda kv: "{" + ", ".join(f"{k}: {v}" for k, v in kv) + "}"),
        ),
        max_leaves=10,
    )


@st.composite
def yaml_profiles(draw: st.DrawFn) -> tuple[str, bool]:
    """A profile's YAML text with anchors, aliases (expanding to up to thousands of nodes),
    flow values (duplicate keys among them) put in for some fields, and maybe a repeated
    top-level key; and whether that key was repeated."""
    head = []
    for i in range(draw(st.integers(0, 6))):
        if i and draw(st.integers(0, 3)) > 0:  # a "laugh": the previous anchor k times
            value = "[" + ", ".join([f"*a{i - 1}"] * draw(st.integers(2, 8))) + "]"
        else:
            value = draw(_flow(st.sampled_from(SCALARS + [f"*a{j}" for j in range(i)])))
            if value.startswith("*"):  # YAML allows no anchor on an alias ("&a1 *a0")
                value = f"[{value}]"
        head.append(f"x{i}: &a{i} {value}")
    refs = [f"*a{j}" for j in range(len(head))]
    d = copy.deepcopy(BASE)
    values = []
    for n, path in enumerate(draw(st.lists(st.sampled_from(PATHS), max_size=2))):
        d = _set(d, path, f"@@{n}@@")
        values.append(draw(_flow(st.sampled_from(SCALARS + refs))))
    text = yaml.safe_dump(d, sort_keys=False)
    for n, v in enumerate(values):
        text = text.replace(f"'@@{n}@@'", v)
    repeat = draw(st.booleans()) and draw(st.integers(0, 3)) == 0
    tail = "name: again\n" if repeat else ""
    return "\n".join(head) + ("\n" if head else "") + text + tail, repeat


def _expanded_size(text: str) -> int:
    """Nodes of the document with every alias expanded (an oracle independent of yaml_safe:
    PyYAML's composer shares aliased nodes; sizes are summed over the shared graph)."""
    sizes: dict[int, int] = {}

    def size(node: yaml.Node) -> int:
        if id(node) not in sizes:
            if isinstance(node, yaml.SequenceNode):
                sizes[id(node)] = 1 + sum(size(c) for c in node.value)
            elif isinstance(node, yaml.MappingNode):
                sizes[id(node)] = 1 + sum(size(k) + size(v) for k, v in node.value)
            else:
                sizes[id(node)] = 1
        return sizes[id(node)]

    root = yaml.compose(text, Loader=yaml.SafeLoader)
    return 0 if root is None else size(root)


@YAML_FUZZ
@given(doc=yaml_profiles(), command=st.sampled_from(["load", "validate", "show"]))
def test_yaml_structure_fuzz_valid_or_one_clean_line(tmp_path_factory: pytest.TempPathFactory,
                                                     capsys: pytest.CaptureFixture[str],
                                                     doc: tuple[str, bool], command: str) -> None:
    from thintact_sdk.formats import safe_yaml as yaml_safe
    from thintact_sdk.formats.profiles import load_profile

    text, repeated = doc
    f = tmp_path_factory.mktemp("yfuzz") / "p.yaml"
    f.write_text(text)
    try:
        expanded = _expanded_size(text)
    except yaml.YAMLError:
        expanded = 0  # not YAML at all: the loader must say so too
    old = yaml_safe.SafeLoader.max_expanded_nodes
    yaml_safe.SafeLoader.max_expanded_nodes = YAML_LIMIT
    try:
        if command == "load":
            try:
                prof = load_profile(f)
            except ProfileError as err:
                msg, rc = str(err), 2
            else:
                msg, rc = "", 0
        else:
            capsys.readouterr()
            rc = main(["profile", command, str(f)])
            msg = capsys.readouterr().err
            assert rc != 2 or (msg.endswith("\n") and msg.count("\n") == 1), msg
            msg = msg.removeprefix("thintact: error: ").rstrip("\n")
    except Exception:
        OUTCOMES["other"] += 1
        raise
    finally:
        yaml_safe.SafeLoader.max_expanded_nodes = old
    if rc == 0:
        OUTCOMES["valid"] += 1
        assert not repeated and expanded <= YAML_LIMIT, (expanded, text)
        if command == "load":
            _check_valid(prof)
        return
    OUTCOMES["clean_error"] += 1
    assert rc == 2 and "\n" not in msg and str(f) in msg and "Traceback" not in msg, msg
    event("too large" if f"larger than {YAML_LIMIT} nodes" in msg else
          "duplicate key" if "duplicate key" in msg else "other refusal")
    if expanded > YAML_LIMIT:
        assert f"larger than {YAML_LIMIT} nodes" in msg or "duplicate key" in msg or "tag" in msg, msg
    elif repeated:
        assert "duplicate key" in msg, msg


def test_zz_outcome_counts() -> None:
    """Runs last in this module: every fuzzed input ended as a clean error or a valid profile."""
    total = sum(OUTCOMES.values())
    print(f"\nprofile fuzz: {total} inputs: {dict(OUTCOMES)}")
    if total == 0:
        pytest.skip("run with the fuzz tests of this module")
    assert OUTCOMES["other"] == 0
    assert OUTCOMES["clean_error"] > 0 and OUTCOMES["valid"] > 0
