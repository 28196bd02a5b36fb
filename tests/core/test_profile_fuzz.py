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
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from thintact_sdk.cli.main import main
from thintact_sdk.errors import ProfileError
from thintact_sdk.profile import SHIPPED_PROFILE_DIR, Profile, profile_from_dict

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


def test_zz_outcome_counts() -> None:
    """Runs last in this module: every fuzzed input ended as a clean error or a valid profile."""
    total = sum(OUTCOMES.values())
    print(f"\nprofile fuzz: {total} inputs: {dict(OUTCOMES)}")
    if total == 0:
        pytest.skip("run with the fuzz tests of this module")
    assert OUTCOMES["other"] == 0
    assert OUTCOMES["clean_error"] > 0 and OUTCOMES["valid"] > 0
