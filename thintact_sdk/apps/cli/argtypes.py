"""Argument types shared by the subcommands (``type=`` of :meth:`argparse.ArgumentParser.add_argument`).

Each converts the option's text or raises :class:`argparse.ArgumentTypeError`, which the
CLI prints as one line naming the option, with exit status 2, before any work is done.
Numbers must be finite: ``nan`` and ``inf`` are refused everywhere.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

MAX_SEED = 2**63 - 1
"""Largest noise seed accepted (numpy generators take any non-negative integer; this keeps
seeds storable as a signed 64-bit number)."""


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _int(text: str) -> int:
    try:
        return int(text, 10)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def finite_float(text: str) -> float:
    """Any finite number."""
    return _float(text)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """A finite number ≥ 0."""
    value = _float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def int_range(low: int, high: int | None = None) -> Callable[[str], int]:
    """An integer in ``[low, high]`` (no upper bound when ``high`` is None)."""

    def convert(text: str) -> int:
        value = _int(text)
        if value < low or (high is not None and value > high):
            bound = f"between {low} and {high}" if high is not None else f">= {low}"
            raise argparse.ArgumentTypeError(f"must be an integer {bound}, got {text!r}")
        return value

    convert.__name__ = f"int_range({low}, {high})"
    return convert


def float_range(low: float, high: float) -> Callable[[str], float]:
    """A finite number in ``[low, high]``."""

    def convert(text: str) -> float:
        value = _float(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be between {low:g} and {high:g}, got {text!r}")
        return value

    convert.__name__ = f"float_range({low}, {high})"
    return convert


def fraction(text: str) -> float:
    """A finite number in ``(0, 1]`` (a scale factor, a share of something)."""
    value = _float(text)
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be > 0 and <= 1, got {text!r}")
    return value


positive_int = int_range(1)
"""An integer ≥ 1 (frame counts, iterations)."""

port = int_range(0, 65535)
"""A TCP port: 1-65535, or 0 for one the system picks."""

non_negative_int = int_range(0)
"""An integer ≥ 0."""

seed = int_range(0, MAX_SEED)
"""A random seed: an integer in 0..2**63-1."""


KEY_VALUE_HELP = ("KEY=VALUE, VALUE read as YAML 1.2: 30, 2.5e3, true, null, [1, 2], {a: 1}, "
                  "'quoted text' or plain text (yes/no/on/off stay text); an empty VALUE is the "
                  "empty string; only the first '=' splits (a=b=c sets a to 'b=c')")
"""How every ``KEY=VALUE`` option of the CLI reads its value (one parser: :func:`key_value`)."""


def _yaml12_loader() -> type:
    """The SDK's safe YAML loader (:class:`thintact_sdk.formats.safe_yaml.SafeLoader`: bounded aliases,
    no duplicate keys, core-schema tags only) resolving plain scalars by the YAML 1.2 core
    schema (as JSON does: ``2.5e3`` is a number, ``yes``/``on`` are text), not PyYAML's YAML
    1.1 rules."""
    import re

    import yaml

    from thintact_sdk.formats.safe_yaml import SafeLoader

    class Loader(SafeLoader):
        pass

    Loader.yaml_implicit_resolvers = {}  # drop the YAML 1.1 resolvers, add the 1.2 core ones
    rules = [
        ("tag:yaml.org,2002:null", r"^(?:~|null|Null|NULL|)$", "~nN"),
        ("tag:yaml.org,2002:bool", r"^(?:true|True|TRUE|false|False|FALSE)$", "tTfF"),
        ("tag:yaml.org,2002:int", r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$", "-+0123456789"),
        ("tag:yaml.org,2002:float",
         r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
         r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$", "-+.0123456789"),
    ]
    for tag, pattern, first in rules:
        Loader.add_implicit_resolver(tag, re.compile(pattern), list(first))

    def construct_float(loader: yaml.SafeLoader, node: yaml.Node) -> float:
        text = loader.construct_scalar(node)  # type: ignore[arg-type]
        low = str(text).lower().lstrip("+")
        if low in (".inf", "-.inf"):
            return float(low.replace(".", ""))
        return float("nan") if low == ".nan" else float(text)

    def construct_int(loader: yaml.SafeLoader, node: yaml.Node) -> int:
        text = str(loader.construct_scalar(node))  # type: ignore[arg-type]
        return int(text, 0) if text.startswith(("0o", "0x")) else int(text, 10)

    Loader.add_constructor("tag:yaml.org,2002:float", construct_float)
    Loader.add_constructor("tag:yaml.org,2002:int", construct_int)
    return Loader


def key_value(text: str) -> tuple[str, object]:
    """``"KEY=VALUE"`` → ``(KEY, value)``, the value parsed as one YAML document.

    The key is stripped and must be non-empty without whitespace inside; the value follows
    :data:`KEY_VALUE_HELP`. YAML also reads every JSON value the same way JSON does.
    """
    import yaml

    key, sep, raw = text.partition("=")
    key = key.strip()
    if not sep or not key or any(ch.isspace() for ch in key):
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    if raw.strip() == "":
        return key, ""
    try:
        value = yaml.load(raw, Loader=_yaml12_loader())  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as err:
        from thintact_sdk.formats.safe_yaml import error_line

        shown = raw if len(raw) <= 60 else raw[:57] + "..."
        raise argparse.ArgumentTypeError(
            f"{key}: value {shown!r} is not valid YAML ({error_line(err)})") from None
    except RecursionError:
        raise argparse.ArgumentTypeError(f"{key}: value nested too deeply") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{key}: expected a finite number, got {raw!r}")
    return key, value


def key_values(pairs: list[tuple[str, object]] | None) -> dict[str, object]:
    """The ``(key, value)`` pairs of a repeated :func:`key_value` option as a dict (last wins)."""
    return dict(pairs or [])


GRADIENT_MODELS = ("auto", "lut", "mlp", "cnn")
"""``--model`` choices of the tactile calibration commands: the library's
``gradient_model.GRADIENT_MODELS`` spelt out, so that building the parser imports no
tactile code (a test holds the two equal)."""
