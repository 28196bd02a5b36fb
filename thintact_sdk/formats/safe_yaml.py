"""One safe YAML loader for every YAML the SDK reads from a user (profiles, ``KEY=VALUE``).

:class:`SafeLoader` is a :class:`yaml.SafeLoader` that, on top of never constructing
Python objects:

- **bounds alias expansion**: the document is counted as it would be once every alias
  (``*a``) is expanded into a copy of its anchor (``&a``), and refused past
  :data:`MAX_EXPANDED_NODES` nodes, naming the line of the alias that crossed the limit. A
  "billion laughs" document (nested anchors, each aliased ten times by the next) is refused
  after composing a few thousand nodes, before anything of its expanded size exists; an alias
  inside its own anchor (a recursive document) is refused too;
- **refuses duplicate mapping keys**, naming the key, its line and the first one's line
  (PyYAML would silently keep the last value);
- **refuses tags outside the YAML core schema** (null, bool, int, float, str, seq, map):
  ``!!binary``, ``!!timestamp``, ``!!set``, ``!!omap``, ``!!pairs``, ``!!python/...`` and
  local tags are refused naming the tag and its line. Dates are read as text (as YAML 1.2
  does), and the YAML 1.1 merge key ``<<`` is refused.

Errors are :class:`yaml.YAMLError` subclasses (:class:`yaml.MarkedYAMLError`), so callers
that already catch ``yaml.YAMLError`` keep working; :func:`error_line` renders any of them
as one line.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import yaml
from yaml.composer import ComposerError
from yaml.constructor import ConstructorError, SafeConstructor
from yaml.events import AliasEvent
from yaml.nodes import MappingNode, Node

from thintact_sdk.errors import ThinTactError

MAX_EXPANDED_NODES = 1_000_000
"""Most nodes (scalars, sequences, mappings) a document may hold with every alias expanded.

A profile holds a few tens of thousands at most (two 16384-entry mask vectors); a million
plain Python scalars in lists is of the order of 100 MB."""

CORE_TAGS = (
    "tag:yaml.org,2002:null",
    "tag:yaml.org,2002:bool",
    "tag:yaml.org,2002:int",
    "tag:yaml.org,2002:float",
    "tag:yaml.org,2002:str",
    "tag:yaml.org,2002:seq",
    "tag:yaml.org,2002:map",
)
"""The tags of the YAML 1.2 core schema, the only ones :class:`SafeLoader` constructs."""

_MERGE_TAG = "tag:yaml.org,2002:merge"


def _line(node_or_event: Any) -> int:
    """1-based line of a node or event's start."""
    mark = getattr(node_or_event, "start_mark", None)
    return mark.line + 1 if mark is not None else 0


def _short_tag(tag: str) -> str:
    return "!!" + tag[len("tag:yaml.org,2002:"):] if tag.startswith("tag:yaml.org,2002:") else tag


class SafeLoader(yaml.SafeLoader):
    """A :class:`yaml.SafeLoader` with bounded alias expansion, no duplicate keys and only
    the core-schema tags (see the module docstring). One instance reads one stream."""

    max_expanded_nodes: int = MAX_EXPANDED_NODES
    """Limit on the expanded node count of one document (a subclass may lower it)."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self._expanded = 0
        self._sizes: dict[int, int] = {}
        self._aliases = 0

    # -- composition: count the expanded document -------------------------------------
    def compose_document(self) -> Node | None:
        self._expanded = 0
        self._sizes = {}
        self._aliases = 0
        return super().compose_document()  # type: ignore[no-any-return]

    def _count(self, n: int, where: Any, what: str) -> None:
        self._expanded += n
        if self._expanded > self.max_expanded_nodes:
            raise ComposerError(
                None, None,
                f"{what} on line {_line(where)} makes the document larger than "
                f"{self.max_expanded_nodes} nodes with its aliases expanded (a 'billion laughs' "
                "document?)",
                where.start_mark,
            )

    def compose_node(self, parent: Node | None, index: Any) -> Node | None:
        if self.check_event(AliasEvent):
            event = self.peek_event()
            target = self.anchors.get(event.anchor)
            if target is not None:
                size = self._sizes.get(id(target))
                if size is None:  # the anchor is still open: the alias lies inside it
                    raise ComposerError(
                        None, None,
                        f"alias *{event.anchor} on line {_line(event)} lies inside its own anchor "
                        f"&{event.anchor} (line {_line(target)}): recursive documents are refused",
                        event.start_mark,
                    )
                self._aliases += 1
                self._count(size, event, f"alias *{event.anchor}")
            return super().compose_node(parent, index)  # type: ignore[no-any-return]
        start = self._expanded
        event = self.peek_event()
        node = super().compose_node(parent, index)
        self._count(1, event, "the node")
        self._sizes[id(node)] = self._expanded - start
        return node  # type: ignore[no-any-return]

    # -- construction: duplicate keys, merge keys --------------------------------------
    def construct_mapping(self, node: MappingNode, deep: bool = False) -> dict[Any, Any]:
        if not isinstance(node, MappingNode):
            raise ConstructorError(None, None, f"expected a mapping, found {node.id}", node.start_mark)
        first: dict[Any, Node] = {}
        for key_node, _ in node.value:
            if key_node.tag == _MERGE_TAG:
                raise ConstructorError(
                    None, None, f"merge key '<<' on line {_line(key_node)} is not part of the "
                    "YAML core schema; write the keys out", key_node.start_mark)
            key = self.construct_object(key_node, deep=True)
            try:
                hash(key)
            except TypeError:
                raise ConstructorError(
                    None, None, f"a {type(key).__name__} cannot be a mapping key (line "
                    f"{_line(key_node)})", key_node.start_mark) from None
            if key in first:
                here, there = _line(key_node), _line(first[key])
                if here == there:  # a flow mapping on one line: the columns tell them apart
                    here_at = f"line {here}, column {key_node.start_mark.column + 1}"
                    there_at = f"column {first[key].start_mark.column + 1}"
                else:
                    here_at, there_at = f"line {here}", f"line {there}"
                raise ConstructorError(
                    None, None, f"duplicate key {key!r} on {here_at} (first on {there_at})",
                    key_node.start_mark)
            first[key] = key_node
        return super().construct_mapping(node, deep=deep)  # type: ignore[no-any-return]

    def construct_undefined(self, node: Node) -> Any:
        raise ConstructorError(
            None, None, f"tag {_short_tag(node.tag)} on line {_line(node)} is not allowed: only "
            "the YAML core schema (null, bool, int, float, str, seq, map)", node.start_mark)


# only the core-schema constructors; everything else goes to construct_undefined
SafeLoader.yaml_constructors = {
    tag: SafeConstructor.yaml_constructors[tag] for tag in CORE_TAGS
}
SafeLoader.yaml_constructors[None] = SafeLoader.construct_undefined  # type: ignore[index]
SafeLoader.yaml_multi_constructors = {}
# dates stay text (YAML 1.2); '<<' still resolves to the merge tag, to be refused by name
SafeLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in rules if tag != "tag:yaml.org,2002:timestamp"]
    for first, rules in yaml.SafeLoader.yaml_implicit_resolvers.items()
}


def load(text: str | bytes, loader: type[SafeLoader] = SafeLoader) -> Any:
    """The one YAML document in ``text``, read by ``loader`` (:class:`SafeLoader` or a subclass).

    Raises
    ------
    yaml.YAMLError
        Not YAML, several documents, too large once aliases are expanded, a duplicate key
        or a tag outside the core schema; :func:`error_line` gives one line for it.
    """
    ld = loader(text)
    try:
        return ld.get_single_data()
    finally:
        ld.dispose()


def read_file(path: str | os.PathLike[str], what: str, error: type[ThinTactError], max_bytes: int,
              as_json: bool = False) -> Any:
    """The document of the YAML (or, ``as_json``, JSON) file ``path``, read as :func:`load` /
    :func:`load_json` read text.

    Raises
    ------
    error
        One line naming ``what`` and the file: larger than ``max_bytes``, unreadable, not
        UTF-8, not YAML/JSON (the line), nested too deeply, or an integer Python does not
        convert.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > max_bytes:
            raise error(f"cannot read {what} {p}: {size} bytes, over the {max_bytes} bytes a "
                        f"{what} may hold")
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise error(f"cannot read {what} {p}: not UTF-8 text (byte {err.start})") from None
    except OSError as err:
        raise error(f"cannot read {what} {p}: {err.strerror or err}") from None
    try:
        return load_json(text) if as_json else load(text)
    except yaml.YAMLError as err:
        raise error(f"cannot parse {what} {p}: {error_line(err)}") from None
    except RecursionError:
        raise error(f"cannot parse {what} {p}: nested too deeply") from None
    except ValueError as err:  # JSON errors, an integer of more digits than Python converts
        raise error(f"cannot parse {what} {p}: {' '.join(str(err).split())}") from None


def error_line(err: yaml.YAMLError) -> str:
    """One line for a YAML error: the problem and where (``line L, column C``)."""
    if isinstance(err, yaml.MarkedYAMLError):
        problem = err.problem or err.context or "not valid YAML"
        mark = err.problem_mark or err.context_mark
        located = mark is None or "line " in problem
        text = problem if located else f"{problem} (line {mark.line + 1}, column {mark.column + 1})"
        if err.context and err.problem and "line" not in err.problem:
            text = f"{err.context}: {text}"
        return " ".join(text.split())
    return " ".join(str(err).split()) or type(err).__name__


def dump_json(obj: Any, indent: int | None = 1) -> str:
    """``obj`` as JSON text every strict reader takes: a non-finite number (NaN, ±inf: a figure
    that could not be measured) is written as ``null``, numpy numbers and arrays as numbers
    and lists, tuples as lists. Raises ``TypeError`` on anything else ``json`` cannot write."""

    def clean(x: Any) -> Any:
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if hasattr(x, "tolist") and callable(x.tolist):  # numpy scalar or array
            return clean(x.tolist())
        if isinstance(x, float) and not math.isfinite(x):
            return None
        return x

    return json.dumps(clean(obj), indent=indent, allow_nan=False)


class DuplicateKeyError(ValueError):
    """A JSON object repeats a key (:func:`load_json`)."""


def load_json(text: str) -> Any:
    """JSON text → Python, refusing an object that repeats a key (``json`` keeps the last).

    Raises
    ------
    json.JSONDecodeError
        Not JSON.
    DuplicateKeyError
        A repeated key; the message names it and, where the text can be located, the lines
        of both occurrences.
    """

    def pairs(items: list[tuple[str, Any]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k, v in items:
            if k in out:
                raise DuplicateKeyError(k)
            out[k] = v
        return out

    try:
        return json.loads(text, object_pairs_hook=pairs)
    except DuplicateKeyError as dup:
        key = dup.args[0]
        # JSON without NaN/Infinity is YAML: let the YAML loader find both lines
        try:
            load(text)
        except (yaml.YAMLError, RecursionError) as err:
            line = error_line(err) if isinstance(err, yaml.YAMLError) else ""
            if line.startswith("duplicate key"):
                raise DuplicateKeyError(line) from None
        raise DuplicateKeyError(f"duplicate key {key!r}") from None

